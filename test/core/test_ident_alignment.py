"""
Measured channels on the excitation's clock, and device faults, for bags and live data.

Ground truth by construction: a record whose value is its own measurement sample index, so
that every cut can be checked number by number, for offsets and lengths drawn at random.
"""

import numpy as np
import pytest

from emfc_ros.core.device.faults import Fault
from emfc_ros.core.ident.alignment import (align, DeviceFaultError, excitation_offset,
                                           experiment_samples, refuse_faults)
from emfc_ros.core.ident.errors import IdentificationError
from emfc_ros.core.ident.live import live_recording

RATE_HZ = 10000.0


def _record(first: int, n: int) -> dict:
    """Two channels holding their measurement sample index (and its negative)."""
    index = np.arange(first, first + n, dtype=float)
    return {'position_m': index, 'coil_current_A': -index}


def _sections(n: int) -> list:
    half = n // 2
    return [{'name': 'a', 'first_sample_index': 0, 'n_samples': half},
            {'name': 'b', 'first_sample_index': half, 'n_samples': n - half}]


@pytest.mark.parametrize('seed', [11, 4242, 90001])
def test_align_puts_excitation_sample_k_at_index_k(seed):
    rng = np.random.default_rng(seed)
    first = int(rng.integers(0, 5000))
    offset = first + int(rng.integers(0, 20000))
    n = int(rng.integers(1, 50000))
    channels = _record(first, offset - first + n + int(rng.integers(0, 3000)))
    out = align(channels, first, offset, n)
    np.testing.assert_array_equal(out['position_m'], offset + np.arange(n))
    np.testing.assert_array_equal(out['coil_current_A'], -(offset + np.arange(n)))
    # without a length: to the end of the record
    rest = align(channels, first, offset)
    assert rest['position_m'][0] == offset
    assert rest['position_m'][-1] == channels['position_m'][-1]


def test_align_refuses_records_that_miss_the_start_or_the_end():
    channels = _record(1000, 5000)
    with pytest.raises(IdentificationError, match='starts at sample 1000, after the '
                       r'experiment began \(sample 400\)'):
        align(channels, 1000, 400, 100, '/emfc')
    with pytest.raises(IdentificationError, match='ends at sample 6000, before the end of '
                       r'the experiment \(sample 6001\)'):
        align(channels, 1000, 2001, 4000, '/emfc')
    assert align(channels, 1000, 2000, 4000)['position_m'][-1] == 5999


def test_excitation_offset_from_the_description():
    assert excitation_offset({}) == 0                     # the plant simulator: no offset
    assert excitation_offset({'excitation_offset_samples': 1234}) == 1234
    assert excitation_offset({'excitation_offset_samples': 7, 'excitation_epoch': 2}, 2) == 7
    with pytest.raises(IdentificationError, match='excitation_offset_samples is null.*while '
                       'the identifier was accumulating'):
        excitation_offset({'excitation_offset_samples': None}, during='the identifier was '
                          'accumulating')
    with pytest.raises(IdentificationError, match='excitation epoch 1, the excitation of '
                       'the data is epoch 2'):
        excitation_offset({'excitation_offset_samples': 7, 'excitation_epoch': 1}, 2)


def test_experiment_samples_is_the_end_of_the_last_section():
    assert experiment_samples(_sections(12345)) == 12345
    assert experiment_samples(_sections(100), at_least=150) == 150
    shuffled = _sections(800)[::-1]
    assert experiment_samples(shuffled) == 800


def test_faults_inside_the_experiment_refuse_the_data_and_outside_do_not():
    offset, n = 3000, 10000
    before = Fault('device_underrun', 0, 2000, 'late setpoints', False, 1)
    after = Fault('device_underrun', offset + n + 5, 100, 'late setpoints', False, 1)
    refuse_faults([before, after, before], offset, n, RATE_HZ)    # nothing raised
    inside = Fault('device_setpoint_gap', offset + 2500, None, 'gap filled', True, 1)
    with pytest.raises(DeviceFaultError, match='did not apply the excitation') as err:
        refuse_faults([before, inside], offset, n, RATE_HZ)
    assert 'device_setpoint_gap' in str(err.value)
    assert 'device_underrun' not in str(err.value)                # only what touches it
    unknown = Fault('emergency_stop', None, None, 'stopped', False, 1)
    with pytest.raises(DeviceFaultError, match='emergency_stop'):
        refuse_faults([unknown], offset, n, RATE_HZ)


@pytest.mark.parametrize('seed', [3, 77])
def test_live_recording_cuts_the_experiment_at_the_bridges_offset(seed):
    rng = np.random.default_rng(seed)
    offset, n = int(rng.integers(1000, 9000)), int(rng.integers(2000, 30000))
    channels = _record(0, offset + n + 2000)
    extras = [{'excitation_offset_samples': None},             # before the excitation came
              {'excitation_offset_samples': offset, 'excitation_epoch': 1, 'faults': []}]
    out = live_recording(channels, 0, _sections(n), RATE_HZ, extras, 1)
    np.testing.assert_array_equal(out['position_m'], offset + np.arange(n))


def test_live_recording_of_the_plant_simulator_keeps_every_sample():
    channels = _record(0, 5000)
    out = live_recording(channels, 0, _sections(4000), RATE_HZ, [{'load_mass_kg': 0.1}])
    np.testing.assert_array_equal(out['position_m'], np.arange(5000))
    with pytest.raises(IdentificationError, match='after the experiment began'):
        live_recording(_record(1000, 5000), 1000, _sections(4000), RATE_HZ, [{}])


def test_live_recording_refuses_a_fault_that_a_later_description_no_longer_shows():
    # the daq_bridge's ~/reset clears its latched faults from the descriptions it publishes
    # afterwards; the samples it touched stay in the data
    offset, n = 2000, 8000
    fault = Fault('emergency_stop', offset + 4000, None, '~/emergency_stop called', True, 1)
    extras = [{'excitation_offset_samples': offset, 'faults': [fault.to_dict()]},
              {'excitation_offset_samples': offset, 'faults': []}]
    with pytest.raises(DeviceFaultError, match='emergency_stop') as err:
        live_recording(_record(0, offset + n), 0, _sections(n), RATE_HZ, extras)
    assert 'experiment samples 4000' in str(err.value)
    with pytest.raises(DeviceFaultError, match='unreadable'):
        live_recording(_record(0, offset + n), 0, _sections(n), RATE_HZ,
                       [{'excitation_offset_samples': offset, 'faults': 'none'}])
    with pytest.raises(IdentificationError, match='before the end of the experiment'):
        live_recording(_record(0, offset + n - 1), 0, _sections(n), RATE_HZ, extras[1:])
