"""The experiment runner's plan: parsing, merging experiments, refusals naming the key."""

from pathlib import Path

import pytest
import yaml

from emfc_ros.core.config import flatten, unflatten
from emfc_ros.core.errors import ConfigError
from emfc_ros.core.paths import config_file
from emfc_ros.core.run_plan import load_plan, merge_experiments, plan_from_mapping
from emfc_ros.core.signals import experiment_from_config


def test_shipped_default_plan_loads_and_merges_six_sections():
    plan = load_plan(config_file('experiment_default.yaml'))
    assert plan.target == 'simulator' and plan.namespace == '/emfc'
    assert plan.experiment['sections'] == [
        'coil_chirp', 'load_changer_chirp', 'coil_chirp_load_changer_steps',
        'load_changer_chirp_coil_steps', 'coil_amplifier_staircase', 'load_changer_staircase']
    experiment = experiment_from_config(plan.experiment)
    assert experiment.total_samples == 490000
    assert plan.simulator.load_mass_kg is None            # 'balance'
    assert plan.simulator.balance_file.name == 'balance_default.yaml'
    assert 'measurements' in plan.recording.topics
    assert plan.executor == 'events'


def test_flatten_inverts_unflatten():
    nested = {'a': {'b': 1, 'c': {'d': [1.0, 2.0]}}, 'e': 'x'}
    assert flatten(nested) == {'a.b': 1, 'a.c.d': [1.0, 2.0], 'e': 'x'}
    assert unflatten(flatten(nested)) == nested


def test_merging_refuses_different_rates_and_repeated_sections():
    a = {'sample_rate_Hz': 1000.0, 'sections': ['s'], 'section': {'s': {'duration_s': 1}}}
    b = dict(a, sample_rate_Hz=2000.0)
    with pytest.raises(ConfigError, match='sample_rate_Hz'):
        merge_experiments([a, b], ['a.yaml', 'b.yaml'])
    with pytest.raises(ConfigError, match="section 's' appears in two files"):
        merge_experiments([a, a], ['a.yaml', 'b.yaml'])


@pytest.mark.parametrize('change, key', [
    ({'target': 'moon'}, 'run.target'),
    ({'target': 'bridge'}, 'run.simulator'),
    ({'bridge': {'backend': 'sim'}}, 'run.bridge'),
    ({'block_size': 0}, 'run.block_size'),
    ({'simulator': {'load_mass_kg': -1.0}}, 'run.simulator.load_mass_kg'),
    ({'simulator': {'sead': 1}}, 'run.simulator.sead'),
    ({'recording': {'flush_period_s': 0.0}}, 'run.recording.flush_period_s'),
    ({'experiment_files': ['missing.yaml']}, 'run.experiment_files[0]'),
    ({'colour': 'red'}, 'run.colour'),
    ({'executor': 'multi_threaded'}, 'run.executor'),
])
def test_bad_plans_are_refused_naming_the_key(tmp_path, change, key):
    cfg = yaml.safe_load(config_file('experiment_default.yaml').read_text())['run']
    cfg.update(change)
    with pytest.raises(ConfigError) as info:
        plan_from_mapping(cfg, Path(config_file('experiment_default.yaml')).parent)
    assert info.value.key == key


def test_plan_file_without_run_mapping_is_refused(tmp_path):
    path = tmp_path / 'plan.yaml'
    path.write_text('experiment: {}\n')
    with pytest.raises(ConfigError, match='run: mapping'):
        load_plan(path)


def _bridge_cfg():
    return yaml.safe_load(config_file('experiment_bridge_emulator.yaml').read_text())['run']


def test_shipped_bridge_plans_load():
    plan = load_plan(config_file('experiment_bridge_emulator.yaml'))
    assert plan.target == 'bridge' and plan.bridge.backend == 'udp'
    assert plan.bridge.start_emulator and plan.bridge.emulator.host == '127.0.0.1'
    params = plan.bridge.parameters
    assert params['sample_rate_Hz'] == 10000.0 and 'autostart' not in params
    assert params['udp.device_host'] == '127.0.0.1'          # loopback only
    assert {'coil_setpoint_V', 'load_changer_setpoint_V', 'coil_current_A',
            'load_changer_current_A', 'position_m'} <= set(params['inputs'])
    assert plan.bridge.emulator.channels >= len(params['inputs'])
    assert experiment_from_config(plan.experiment).total_samples == 65000
    sim = load_plan(config_file('experiment_bridge_sim.yaml'))
    assert sim.bridge.backend == 'sim' and not sim.bridge.start_emulator
    assert sim.experiment == plan.experiment


@pytest.mark.parametrize('change, key', [
    ({'colour': 'red'}, 'run.bridge.colour'),
    ({'backend': 'tcp'}, 'run.bridge.backend'),
    ({'backend': 'replay'}, 'run.bridge.backend'),
    ({'backend': 'sim'}, 'run.bridge.backend'),       # differs from the parameters file
    ({'pacing': 'fast'}, 'run.bridge.pacing'),
    ({'window_blocks': 0}, 'run.bridge.window_blocks'),
    ({'settle_s': -1.0}, 'run.bridge.settle_s'),
    ({'load_mass_kg': 3.0}, 'run.bridge.load_mass_kg'),
    ({'load_changer_coupled': 'yes'}, 'run.bridge.load_changer_coupled'),
    ({'parameters_file': 'missing.yaml'}, 'run.bridge.parameters_file'),
    ({'parameters': 'inputs'}, 'run.bridge.parameters'),
    ({'parameters': {'sample_rate_Hz': 20000.0}}, 'run.bridge.parameters.sample_rate_Hz'),
    ({'parameters': {'inputs': ['coil_setpoint_V', 'position_m']}},
     'run.bridge.parameters.inputs'),
    ({'parameters': {'excitation_mode': 'function_generator'}},
     'run.bridge.parameters.excitation_mode'),
    ({'parameters': {'watchdog_timeout_s': 0.3}}, 'run.bridge.parameters.watchdog_timeout_s'),
    ({'parameters': {'sim': {'load_mass_kg': 0.1}}}, 'run.bridge.parameters.sim.load_mass_kg'),
    ({'emulator': {'host': '192.0.2.1'}}, 'run.bridge.emulator.host'),
    ({'emulator': {'channels': 4}}, 'run.bridge.emulator.channels'),
    ({'emulator': {'prot': 1}}, 'run.bridge.emulator.prot'),
    ({'start_emulator': False}, 'run.bridge.emulator'),   # emulator settings without it
])
def test_bad_bridge_plans_are_refused_naming_the_key(change, key):
    cfg = _bridge_cfg()
    if isinstance(change.get('parameters'), dict):
        cfg['bridge']['parameters'].update(change.pop('parameters'))
    cfg['bridge'].update(change)
    with pytest.raises(ConfigError) as info:
        plan_from_mapping(cfg, Path(config_file('experiment_bridge_emulator.yaml')).parent)
    assert info.value.key == key, info.value


def test_a_bridge_lead_the_consumer_window_cannot_feed_is_refused():
    # Consumer pacing keeps the generator at most window_blocks ahead of what the device
    # measured; the bridge writes excitation_lead_s ahead of the newest measured block. A
    # lead of 0.5 s with the 0.4 s window left 59 000 of 65 000 samples unapplied.
    base = Path(config_file('experiment_bridge_emulator.yaml')).parent
    cfg = _bridge_cfg()
    cfg['bridge']['parameters'].update({'excitation_lead_s': 0.5, 'watchdog_timeout_s': 2.0})
    with pytest.raises(ConfigError) as info:
        plan_from_mapping(cfg, base)
    assert info.value.key == 'run.bridge.parameters.excitation_lead_s', info.value
    assert 'window_blocks >= 6' in str(info.value), info.value
    cfg['bridge']['window_blocks'] = 6           # 0.5 s lead + one 0.1 s block = 0.6 s
    assert plan_from_mapping(cfg, base).bridge.window_blocks == 6
    cfg['bridge']['parameters']['excitation_lead_s'] = 0.51
    with pytest.raises(ConfigError, match='window_blocks >= 7'):
        plan_from_mapping(cfg, base)
    cfg['bridge']['pacing'] = 'wall'            # paced to the wall clock: no window
    cfg['bridge']['lead_blocks'] = 8
    assert plan_from_mapping(cfg, base).bridge.pacing == 'wall'


def test_a_plan_for_a_real_device_declares_the_mass_on_the_pan():
    base = Path(config_file('experiment_bridge_emulator.yaml')).parent
    cfg = _bridge_cfg()
    cfg['bridge']['start_emulator'] = False
    cfg['bridge'].pop('emulator', None)
    cfg['bridge']['load_mass_kg'] = 'balance'
    with pytest.raises(ConfigError) as info:
        plan_from_mapping(cfg, base)
    assert info.value.key == 'run.bridge.load_mass_kg'
    assert 'mass pieces' in str(info.value)
    cfg['bridge']['load_mass_kg'] = 0.1
    assert plan_from_mapping(cfg, base).bridge.load_mass_kg == 0.1


def test_bridge_plan_checks_the_emulator_backend_and_the_timeout():
    base = Path(config_file('experiment_bridge_emulator.yaml')).parent
    cfg = _bridge_cfg()
    cfg['bridge'].pop('parameters_file')
    cfg['bridge']['backend'] = 'sim'
    with pytest.raises(ConfigError) as info:
        plan_from_mapping(cfg, base)
    assert info.value.key == 'run.bridge.start_emulator'
    cfg = _bridge_cfg()
    cfg['timeout_s'] = 5.0                 # the experiment takes 6.5 s on the device clock
    with pytest.raises(ConfigError) as info:
        plan_from_mapping(cfg, base)
    assert info.value.key == 'run.timeout_s'
    cfg = _bridge_cfg()
    cfg['identification'] = {'enabled': False}
    cfg['bridge']['parameters']['inputs'] = ['coil_setpoint_V', 'position_m']
    plan = plan_from_mapping(cfg, base)    # nothing to identify: any inputs will do
    assert plan.bridge.parameters['inputs'] == ['coil_setpoint_V', 'position_m']


def test_without_override_the_parameters_file_inputs_are_refused_naming_the_file(tmp_path):
    # The shipped daq_bridge_udp.yaml has every channel the identification needs ...
    cfg = _bridge_cfg()
    del cfg['bridge']['parameters']['inputs']
    shipped = Path(config_file('experiment_bridge_emulator.yaml')).parent
    assert 'load_changer_current_A' in plan_from_mapping(cfg, shipped).bridge.parameters[
        'inputs']
    # ... a parameters file without the load changer's is refused, naming the file.
    params = yaml.safe_load(Path(config_file('daq_bridge_udp.yaml')).read_text())
    params['/**']['ros__parameters']['inputs'] = ['coil_setpoint_V', 'coil_current_A',
                                                  'sensor_V', 'position_m']
    (tmp_path / 'four_inputs.yaml').write_text(yaml.safe_dump(params))
    cfg['bridge']['parameters_file'] = str(tmp_path / 'four_inputs.yaml')
    with pytest.raises(ConfigError, match='load_changer_current_A') as info:
        plan_from_mapping(cfg, shipped)
    assert info.value.key.startswith('run.bridge.parameters_file (')
    assert info.value.key.endswith('four_inputs.yaml): inputs')
