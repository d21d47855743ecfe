"""The NI-DAQmx groundwork: the default wiring table and the error codes the project acts on."""

import subprocess
import sys

import numpy as np
import pytest

from emfc_ros.core.device import daqmx_errors
from emfc_ros.core.device.backend import DEFAULT_INPUTS, DEFAULT_OUTPUTS
from emfc_ros.core.device.daqmx_wiring import (AI_RANGES_V, ai_wiring_by_name, DEFAULT_AI_WIRING,
                                               DEFAULT_AO_WIRING, range_for, resolution_V)
from emfc_ros.core.device.faults import KINDS
from emfc_ros.core.model.balance_file import load_balance


def test_every_default_input_and_output_has_one_terminal():
    wiring = ai_wiring_by_name()
    assert set(DEFAULT_INPUTS) <= set(wiring)
    terminals = [w.terminal for w in DEFAULT_AI_WIRING]
    assert len(set(terminals)) == len(terminals)
    assert all(t in {f'ai{i}' for i in range(8)} for t in terminals)
    assert tuple(name for name, _ in DEFAULT_AO_WIRING) == DEFAULT_OUTPUTS
    assert [t for _, t in DEFAULT_AO_WIRING] == ['ao0', 'ao1']


def test_the_scaling_matches_the_default_balance_and_the_units():
    conv = load_balance().converters
    wiring = ai_wiring_by_name()
    for name in ('coil_current_A', 'load_changer_current_A'):
        np.testing.assert_allclose(wiring[name].units_per_V, 1.0 / conv.current_monitor_V_per_A)
    for wire in DEFAULT_AI_WIRING:
        assert wire.name.endswith('_' + wire.unit)
        assert wire.range_V in AI_RANGES_V
    # the full position range of the sensor fits the input range
    assert conv.sensor_range_m / wiring['position_m'].units_per_V <= wiring['position_m'].range_V


@pytest.mark.parametrize('limit, expected', [(0.05, 0.1), (0.1, 0.1), (0.11, 0.2), (3.0, 5.0),
                                             (10.0, 10.0)])
def test_range_for_picks_the_smallest_range_that_holds_the_signal(limit, expected):
    assert range_for(limit) == expected


@pytest.mark.parametrize('limit', [0.0, -1.0, 10.5])
def test_range_for_refuses_what_no_range_holds(limit):
    with pytest.raises(ValueError, match='range'):
        range_for(limit)


def test_resolution_is_one_step_of_sixteen_bits():
    np.testing.assert_allclose(resolution_V(10.0), 20.0 / 65536.0)


def test_the_codes_are_ni_daqmx_codes_of_the_same_name():
    # NI's own table, from the nidaqmx client (the daqmx extra, installed by the setup)
    from nidaqmx.error_codes import DAQmxErrors
    codes = {k: v for k, v in vars(daqmx_errors).items() if k.isupper() and isinstance(v, int)}
    assert len(codes) >= 10
    for name, code in codes.items():
        assert DAQmxErrors(code).name == name
        assert daqmx_errors.text(code) != f'NI-DAQmx error {code}.'
    assert set(daqmx_errors.FAULT_OF_CODE.values()) <= set(KINDS)
    assert daqmx_errors.text(-1) == 'NI-DAQmx error -1.'


def test_the_package_does_not_need_nidaqmx():
    # with nidaqmx unimportable, the device layer and the bridge's settings still load
    code = ('import sys; sys.modules["nidaqmx"] = None; sys.modules["grpc"] = None\n'
            'import emfc_ros.core.device.registry, emfc_ros.core.device.daqmx_wiring\n'
            'import emfc_ros.core.device.daqmx_errors, emfc_ros.core.device.bridge_session\n'
            'print("ok")')
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == 'ok'
