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
    ({'target': 'bridge'}, 'run.target'),
    ({'block_size': 0}, 'run.block_size'),
    ({'simulator': {'load_mass_kg': -1.0}}, 'run.simulator.load_mass_kg'),
    ({'simulator': {'sead': 1}}, 'run.simulator.sead'),
    ({'recording': {'flush_period_s': 0.0}}, 'run.recording.flush_period_s'),
    ({'experiment_files': ['missing.yaml']}, 'run.experiment_files[0]'),
    ({'colour': 'red'}, 'run.colour'),
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
