"""The in-loop controller's rates and delay: defaults that fit, refusals that say what fits."""

import numpy as np
import pytest

from emfc_ros.cli.device_emulator import _parser as emulator_parser
from emfc_ros.core.control.loop_config import loop_config, loop_timing, LoopConfig
from emfc_ros.core.device import default_device_config, SimBackend
from emfc_ros.core.errors import ConfigError


def test_the_default_delay_fits_equal_and_multiple_rates():
    loop = LoopConfig()
    assert loop.rate_Hz == 10000.0 and loop.delay_samples == 1.0
    assert loop_timing(loop, 10000.0) == (1, 1)          # the node's default rates
    assert loop_timing(loop, 20000.0) == (2, 2)
    assert loop_timing(LoopConfig(delay_samples=1.5), 20000.0) == (2, 3)


def test_a_fractional_delay_names_the_key_and_what_fits():
    with pytest.raises(ConfigError) as info:
        loop_timing(LoopConfig(delay_samples=1.5), 10000.0)
    assert info.value.key == 'control.delay_samples'
    assert 'is 1.5 samples of the simulator at sample_rate_Hz = 10000 Hz' in info.value.problem
    assert 'use control.delay_samples = 1 or 2, or sample_rate_Hz = 20000 Hz' in \
        info.value.problem
    with pytest.raises(ConfigError, match='control.delay_samples = 1, or sample_rate_Hz = '
                                          '20000 Hz'):
        loop_timing(LoopConfig(delay_samples=0.5), 10000.0)
    with pytest.raises(ConfigError) as info:
        loop_timing(LoopConfig(delay_samples=0.0), 10000.0)     # no delay at all: >= 1
    assert info.value.key == 'control.delay_samples'


def test_a_simulator_rate_that_is_no_multiple_is_refused():
    for rate in (15000.0, 5000.0):
        with pytest.raises(ConfigError) as info:
            loop_timing(LoopConfig(), rate)
        assert info.value.key == 'control.rate_Hz' and f'{rate:g} Hz' in info.value.problem


def test_the_emulator_option_runs_the_loop_at_the_bridge_default_rate():
    """``emfc-device-emulator --control-crossover-Hz 100`` and a bridge at 10 kHz."""
    args = emulator_parser().parse_args(['--control-crossover-Hz', '100'])
    loop = loop_config({'crossover_Hz': args.control_crossover_Hz,
                        'rate_Hz': args.control_rate_Hz, 'notch_Hz': args.control_notch_Hz},
                       '--control')
    device = SimBackend(seed=2, simulator_options={'control': loop, 'load_mass_kg': 0.1})
    device.configure(default_device_config(10000.0, 1000, ('position_m', 'force_command_N')))
    device.start()
    blocks = [device.read_block() for _ in range(10)]
    device.stop()
    samples = np.concatenate([b.samples for b in blocks], axis=1)
    # 0 V on the coil and 100 g on the pan: only the controller holds the lever near 0
    assert np.max(np.abs(samples[0])) < 2e-6
    assert np.std(samples[1]) > 0.0
