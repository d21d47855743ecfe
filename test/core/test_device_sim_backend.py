"""The device interface, the sim back-end, the function generator and the back-end table."""

import numpy as np
import pytest

from emfc_ros.core.device import (BACKENDS, create_backend, default_device_config,
                                  DeviceBackend, DeviceConfig, DeviceConfigError, DeviceError,
                                  GeneratorSpec, OutputChannel, SimBackend, UdpBackend)
from emfc_ros.core.device.backend import from_codes, input_scaling, to_codes
from emfc_ros.core.device.function_generator import FunctionGenerator
from emfc_ros.core.device.replay_backend import ReplayBackend
from emfc_ros.core.signals import Chirp, Prbs, Sine
from emfc_ros.core.sim.converters import convert_V

RATE_HZ = 20000.0
INPUTS = ('coil_current_A', 'load_changer_current_A', 'sensor_V', 'position_m',
          'coil_setpoint_V', 'load_changer_setpoint_V')
COIL = INPUTS.index('coil_setpoint_V')
LOAD = INPUTS.index('load_changer_setpoint_V')


def _dac(v):
    return convert_V(v, 16, 10.0)


@pytest.fixture(scope='module')
def backend():
    return SimBackend(seed=5)


def _started(backend, block_size=400, **kwargs):
    backend.stop()
    backend.configure(default_device_config(RATE_HZ, block_size, INPUTS, **kwargs))
    backend.start()
    return backend


def test_table_picks_backends_by_name_and_refuses_unknown_names():
    from emfc_ros.core.device.daqmx_backend import DaqmxBackend
    assert {name: e.cls for name, e in BACKENDS.items()} == {
        'sim': SimBackend, 'udp': UdpBackend, 'replay': ReplayBackend, 'daqmx': DaqmxBackend}
    sim = create_backend('sim', seed=1)
    assert isinstance(sim, SimBackend) and isinstance(sim, DeviceBackend)
    with pytest.raises(DeviceConfigError, match="'fpga'"):
        create_backend('fpga')


def test_sim_backend_returns_contiguous_blocks_of_the_measured_channels(backend):
    epoch = _started(backend).device.epoch
    blocks = [backend.read_block() for _ in range(5)]
    assert [b.first_sample_index for b in blocks] == [0, 400, 800, 1200, 1600]
    assert all(b.epoch == epoch and b.samples.shape == (6, 400) for b in blocks)
    assert all(b.sample_rate_Hz == RATE_HZ for b in blocks)
    # no excitation yet: the outputs sit at the safe values (0 V)
    assert np.all(blocks[-1].samples[[COIL, LOAD]] == 0.0)
    assert backend.start() == epoch + 1
    assert backend.read_block().first_sample_index == 0
    backend.stop()
    assert backend.read_block() is None


def test_scaling_between_codes_and_si_is_exact_for_converter_channels():
    config = default_device_config(RATE_HZ, 10, INPUTS)
    scale, offset = input_scaling(config)
    codes = np.array([[-32768, -1, 0, 1, 32767]] * len(INPUTS), dtype=np.int16)
    values = from_codes(codes, scale, offset)
    assert np.array_equal(to_codes(values, scale, offset), codes)
    assert np.array_equal(to_codes(values * 10.0, scale, offset)[:, [0, -1]],
                          codes[:, [0, -1]])   # saturates


def test_function_generator_reuses_the_signal_core_with_gain_and_offset():
    specs = [GeneratorSpec('sine', 0.3, 50.0, phase_rad=0.2, gain=2.0, offset_V=0.5),
             GeneratorSpec('chirp', 0.2, 10.0, 400.0, 0.05, 'linear')]
    gen = FunctionGenerator(specs, RATE_HZ)
    k = np.arange(1000, 1300)
    assert np.array_equal(gen.samples(0, 1000, 300),
                          2.0 * Sine(0.3, 50.0, 0.2, RATE_HZ).samples(k) + 0.5)
    assert np.array_equal(gen.samples(1, 1000, 300),
                          Chirp(0.2, 10.0, 400.0, 0.05, RATE_HZ, 'linear').samples(k))
    prbs = FunctionGenerator([GeneratorSpec('prbs', 0.4, prbs_order=5, prbs_hold_samples=2)],
                             RATE_HZ)
    assert np.array_equal(prbs.samples(0, 0, 100),
                          Prbs(5, 2, -0.4, 0.4, RATE_HZ).samples(np.arange(100)))
    with pytest.raises(DeviceConfigError, match='Nyquist'):
        FunctionGenerator([GeneratorSpec('sine', 1.0, 0.6 * RATE_HZ)], RATE_HZ)
    with pytest.raises(DeviceConfigError, match='waveform'):
        GeneratorSpec('square')


def test_sim_backend_applies_the_generator_on_the_device_clock(backend):
    _started(backend)
    backend.set_function_generator([GeneratorSpec('sine', 0.3, 50.0, gain=2.0, offset_V=0.5),
                                    GeneratorSpec('constant', offset_V=-0.25)])
    blocks = [backend.read_block() for _ in range(3)]
    k = np.arange(1200)
    coil = np.concatenate([b.samples[COIL] for b in blocks])
    assert np.array_equal(coil, _dac(2.0 * Sine(0.3, 50.0, 0.0, RATE_HZ).samples(k) + 0.5))
    assert np.all(blocks[0].samples[LOAD] == _dac(-0.25))


def test_streamed_setpoints_are_applied_sample_exactly_with_underruns_counted(backend):
    _started(backend)
    before = backend.health()['device_underrun_samples']
    ramp = np.vstack([np.linspace(-1.0, 1.0, 600), np.linspace(0.5, -0.5, 600)])
    backend.write_setpoints(100, ramp)           # starts in the middle of the first block
    blocks = [backend.read_block() for _ in range(2)]
    applied = np.hstack([b.samples[[COIL, LOAD]] for b in blocks])
    assert np.all(applied[:, :100] == 0.0)       # before the stream: safe, not an underrun
    assert np.array_equal(applied[:, 100:700], _dac(ramp))
    assert np.all(applied[:, 700:] == 0.0)       # the stream ran dry: safe value
    health = backend.health()
    assert health['device_underrun_samples'] - before == 100
    late = health['device_setpoint_late_samples']
    backend.write_setpoints(700, ramp[:, :100])  # behind the clock: late, dropped
    backend.read_block()
    assert backend.health()['device_setpoint_late_samples'] - late == 100


def test_a_late_first_frame_counts_its_unapplied_samples_as_underruns(backend):
    # The first setpoint frame comes after the device clock passed its first sample: the
    # samples behind the clock were output at the safe values, which the host must hear of.
    _started(backend)
    before = backend.health()
    backend.read_block()                         # samples 0..399 at the safe values
    ramp = np.vstack([np.linspace(-1.0, 1.0, 700), np.linspace(0.5, -0.5, 700)])
    backend.write_setpoints(100, ramp)           # 100..799: 100..399 already passed
    applied = backend.read_block().samples[[COIL, LOAD]]
    assert np.array_equal(applied, _dac(ramp[:, 300:]))
    health = backend.health()
    assert health['device_setpoint_late_samples'] - before['device_setpoint_late_samples'] \
        == 300
    assert health['device_underrun_samples'] - before['device_underrun_samples'] == 300


def test_outputs_are_clamped_to_their_limits_and_counted(backend):
    _started(backend, limits_V=(-1.0, 1.0))
    first = backend.device.index
    n = backend.device.config.block_size
    backend.write_setpoints(first, np.vstack([np.full(n, 3.0), np.full(n, -0.5)]))
    before = backend.health()['device_clamped_samples']
    block = backend.read_block()
    assert np.all(block.samples[COIL] == _dac(1.0))
    assert np.all(block.samples[LOAD] == _dac(-0.5))
    assert backend.health()['device_clamped_samples'] - before == n


@pytest.mark.parametrize('spec', [GeneratorSpec('constant', offset_V=3.0),
                                  GeneratorSpec('sine', 0.6, 10.0, offset_V=0.5),
                                  GeneratorSpec('prbs', 0.3, gain=4.0, prbs_order=5)])
def test_a_generator_beyond_the_output_limits_is_refused_not_clamped(backend, spec):
    _started(backend, limits_V=(-1.0, 1.0))
    with pytest.raises(DeviceConfigError, match=r'coil_V.*beyond the output limits \[-1, 1\]'):
        backend.set_function_generator([spec, GeneratorSpec()])
    # Within the limits (to the volt) it is taken.
    backend.set_function_generator([GeneratorSpec('sine', 0.5, 10.0, offset_V=0.5),
                                    GeneratorSpec()])


def test_watchdog_trip_drives_outputs_to_the_safe_value_from_its_sample(backend):
    _started(backend, safe_V=(0.25, 0.0))
    backend.set_function_generator([GeneratorSpec('constant', offset_V=1.0), GeneratorSpec()])
    device = backend.device
    assert np.all(backend.read_block().samples[COIL] == _dac(1.0))
    device.trip_watchdog(550)
    block = backend.read_block()
    assert np.all(block.samples[COIL, :150] == _dac(1.0))
    assert np.all(block.samples[COIL, 150:] == _dac(0.25))
    assert device.watchdog_tripped and device.counters['watchdog_trips'] >= 1
    backend.start()
    assert not device.watchdog_tripped


def test_invalid_configurations_are_refused_with_a_reason(backend):
    _started(backend)
    with pytest.raises(DeviceError, match='while running'):
        backend.configure(default_device_config(RATE_HZ, 100, INPUTS))
    backend.stop()
    with pytest.raises(DeviceConfigError, match='unknown input'):
        backend.configure(default_device_config(RATE_HZ, 100, ('coil_voltage_V',)))
    with pytest.raises(DeviceConfigError, match='safe_V'):
        OutputChannel('coil_V', -1.0, 1.0, 2.0)
    good = default_device_config(RATE_HZ, 100, INPUTS)
    with pytest.raises(DeviceConfigError, match='block_size'):
        DeviceConfig(RATE_HZ, 0, good.inputs, good.outputs)
    with pytest.raises(DeviceConfigError, match='2 outputs'):
        backend.configure(DeviceConfig(RATE_HZ, 100, good.inputs, good.outputs[:1]))
    fresh = SimBackend(seed=1)
    with pytest.raises(DeviceError, match='before configure'):
        fresh.start()


def test_backend_and_configuration_from_a_mapping_name_bad_keys():
    from emfc_ros.core.device.backend import device_config_from_mapping
    from emfc_ros.core.device.registry import backend_from_mapping
    from emfc_ros.core.errors import ConfigError
    sim, config = backend_from_mapping({'backend': 'sim', 'sim': {'seed': 3},
                                        'sample_rate_Hz': RATE_HZ, 'block_size': 250,
                                        'inputs': list(INPUTS[:4]),
                                        'output_safe_V': [0.1, 0.0]})
    assert isinstance(sim, SimBackend) and config == default_device_config(
        RATE_HZ, 250, INPUTS[:4], safe_V=(0.1, 0.0))
    udp, _ = backend_from_mapping({'backend': 'udp', 'udp': {
        'device_host': '127.0.0.1', 'device_port': 5999, 'retries': 2,
        'setpoint_format': 'int16'}})
    try:
        assert isinstance(udp, UdpBackend) and udp.device_address == ('127.0.0.1', 5999)
        assert udp.retries == 2 and udp.setpoint_format == 'int16'
    finally:
        udp.close()
    custom = device_config_from_mapping({'inputs': ['a_V'], 'input_units': ['V'],
                                         'input_scales': [1e-3], 'input_offsets': [0.5]})
    assert custom.inputs[0].scale == 1e-3 and custom.inputs[0].offset == 0.5
    for cfg, key in (({'backend': 'fpga'}, 'backend'), ({'blocksize': 5}, 'blocksize'),
                     ({'output_safe_V': [0.0]}, 'output_safe_V'),
                     ({'block_size': 0}, 'block_size'),
                     ({'backend': 'udp', 'udp': {'port': 1}}, 'udp.port'),
                     ({'backend': 'udp', 'udp': {'device_port': 0}}, 'udp.device_port'),
                     ({'backend': 'sim', 'balance_file': '/nonexistent.yaml'},
                      'balance_file'),
                     ({'output_safe_V': [20.0, 0.0]}, 'safe_V')):
        with pytest.raises(ConfigError, match=key):
            backend_from_mapping(cfg, 'device' if key == 'safe_V' else '')


def test_the_emulated_device_can_run_the_controller_in_its_sample_loop():
    """The sim back-end with a LoopConfig holds 0.1 kg; the precise channel streams."""
    from emfc_ros.core.control.loop_config import LoopConfig
    from emfc_ros.core.device.backend import default_input_channel
    loop = LoopConfig()          # the default in-loop design (130 Hz, no notch)
    device = SimBackend(seed=2, simulator_options={'control': loop, 'load_mass_kg': 0.1})
    # the precise current through a 16-bit device code: a window around the working point
    precise = default_input_channel('coil_current_precise_A')
    names = ('position_m', 'coil_current_precise_A', 'force_command_N')
    config = default_device_config(RATE_HZ, 1000, names)
    assert config.inputs[1].name == precise.name
    device.configure(config)
    device.start()
    blocks = [device.read_block() for _ in range(10)]
    device.stop()
    samples = np.concatenate([b.samples for b in blocks], axis=1)
    assert [b.first_sample_index for b in blocks] == list(range(0, 10000, 1000))
    # no setpoints were written: the controller alone holds the lever (open loop would fall
    # onto a stop with 0 V on the coil)
    assert np.max(np.abs(samples[0])) < 2e-6
    # and its force is the one that holds 100 g (within 2 codes of the 4 N / 32768 scaling)
    from emfc_ros.core.sim.hold_point import hold_point
    params = device.device.params
    held_N = hold_point(params, 0.1).currents_A[0] * params.motor.coefficient_N_per_A(0.0)
    np.testing.assert_allclose(np.mean(samples[2, -2000:]), held_N, rtol=0, atol=2.5e-4)
    with pytest.raises(DeviceConfigError, match='unknown input'):
        SimBackend(seed=2).configure(default_device_config(RATE_HZ, 1000, names))


def _documented_mapping():
    """The configuration mapping shown in docs/device_protocol.md section 1."""
    import pathlib
    import re

    import yaml
    text = (pathlib.Path(__file__).resolve().parents[2] / 'docs' /
            'device_protocol.md').read_text()
    block = re.search(r'```yaml\n(backend: udp.*?)```', text, re.S)
    assert block is not None, 'the mapping block is gone from docs/device_protocol.md'
    return yaml.safe_load(block.group(1))


def test_the_documented_mapping_builds_every_backend_with_its_documented_defaults():
    """Every key of the docs' mapping is an option, at its default; it builds sim and udp."""
    from emfc_ros.core.device.registry import backend_from_mapping
    cfg = _documented_mapping()
    for name, entry in BACKENDS.items():
        assert cfg[name] == {o.key: list(o.default) if isinstance(o.default, tuple)
                             else o.default for o in entry.options}, name
    udp, config = backend_from_mapping(cfg)
    try:
        assert isinstance(udp, UdpBackend) and udp.device_address == ('127.0.0.1', 5005)
        assert config.input_names == tuple(cfg['inputs']) and config.block_size == 1000
    finally:
        udp.close()
    sim, _ = backend_from_mapping(dict(cfg, backend='sim', sim={'seed': 4}))
    assert isinstance(sim, SimBackend) and sim.host_paced and sim.applies_excitation


def test_every_backend_declares_what_the_bridge_asks_of_it():
    """The node reads these instead of the name (test_layers checks it never branches)."""
    for name, entry in BACKENDS.items():
        for attribute in ('host_paced', 'applies_excitation', 'intrusion_counters'):
            assert hasattr(entry.cls, attribute), (name, attribute)
        assert entry.cls.name == name
    assert not BACKENDS['replay'].cls.applies_excitation
    assert BACKENDS['sim'].cls.host_paced and not BACKENDS['udp'].cls.host_paced
    assert 'foreign' in BACKENDS['udp'].cls.intrusion_counters
