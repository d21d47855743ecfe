"""Configuration parsing: every bad key names its dotted path; the shipped config loads."""

import copy
from pathlib import Path

import numpy as np
import pytest
import yaml

from emfc_ros.core.config import unflatten
from emfc_ros.core.errors import ConfigError, WaveformFileError
from emfc_ros.core.signals import (Chirp, experiment_from_config, load_experiment_file, Prbs,
                                   Steps)

SHIPPED = Path(__file__).resolve().parents[2] / 'config' / 'identification_trajectory.yaml'
SIG = 'experiment.section.s1.coil.signals.sig'


def base():
    return {
        'sample_rate_Hz': 10000.0,
        'sections': ['s1', 's2'],
        'section': {
            's1': {'duration_s': 0.5, 'coil': {'signals': {'sig': {
                'type': 'chirp', 'amplitude_V': 0.01, 'f_start_Hz': 5.0, 'f_stop_Hz': 2000.0,
                'method': 'logarithmic'}}}},
            's2': {'duration_s': 0.25, 'load_changer': {'gain': 1, 'offset_V': 0, 'signals': {
                'st': {'type': 'steps', 'times_s': [0, 0.1], 'levels_V': [0.1, -0.1]}}}},
        },
    }


def signal(**spec):
    cfg = base()
    cfg['section']['s1']['coil']['signals']['sig'] = spec
    return cfg


def test_base_config_builds():
    exp = experiment_from_config(base())
    assert exp.channels == ('coil', 'load_changer')
    assert [s.n_samples for s in exp.sections] == [5000, 2500]
    sig = exp.sections[0].channels['coil'].signals['sig']
    assert isinstance(sig, Chirp) and sig.sweep_time_s == 0.5   # defaults to the section


def test_ints_accepted_where_floats_expected_and_wrapper_unwrapped():
    cfg = base()
    cfg['sample_rate_Hz'] = 10000
    cfg['section']['s1']['coil']['signals']['sig'] = {
        'type': 'sine', 'amplitude_V': 1, 'frequency_Hz': 50}
    exp = experiment_from_config({'experiment': cfg})
    assert exp.sample_rate_Hz == 10000.0 and exp.total_samples == 7500


def _set(cfg, dotted, value):
    keys = dotted.split('.')
    node = cfg
    for key in keys[:-1]:
        node = node[key]
    if value is DELETE:
        del node[keys[-1]]
    else:
        node[keys[-1]] = value


DELETE = object()
BAD = [
    # (dotted key to change inside `experiment`, new value, key named in the error, text)
    ('sample_rate', 1.0, 'experiment.sample_rate', 'unknown key'),
    ('sample_rate_Hz', -5.0, 'experiment.sample_rate_Hz', 'greater than 0'),
    ('sample_rate_Hz', 'fast', 'experiment.sample_rate_Hz', 'expected a number'),
    ('sample_rate_Hz', DELETE, 'experiment.sample_rate_Hz', 'missing'),
    ('channels', ['coil', 'coil'], 'experiment.channels', 'distinct'),
    ('limits', {'coil': {'min_V': 1.0, 'max_V': -1.0}}, 'experiment.limits.coil.max_V',
     'at least 1.0'),
    ('limits', {'coill': {'min_V': 1.0}}, 'experiment.limits.coill', 'unknown key'),
    ('limits', {'coil': {'minimum_V': 1.0}}, 'experiment.limits.coil.minimum_V', 'unknown'),
    ('sections', ['s1', 's3'], 'experiment.section.s3', 'not defined'),
    ('sections', ['s1'], 'experiment.section.s2', 'not listed'),
    ('sections', ['s1', 's2', 's1'], 'experiment.sections[2]', 'twice'),
    ('sections', 's1', 'experiment.sections', 'list of strings'),
    ('section.s1.duration_s', DELETE, 'experiment.section.s1.duration_s', 'missing'),
    ('section.s1.duration_s', 0.0, 'experiment.section.s1.duration_s', 'greater than'),
    ('section.s1.coill', {}, 'experiment.section.s1.coill', 'unknown key'),
    ('section.s1.coil.gain', 'x', 'experiment.section.s1.coil.gain', 'number'),
    ('section.s1.coil.offset', 0.1, 'experiment.section.s1.coil.offset', 'unknown key'),
    ('section.s1.coil.signals', [], 'experiment.section.s1.coil.signals', 'mapping'),
    (SIG[11:] + '.amplitde_V', 1.0, SIG + '.amplitde_V', 'unknown key'),
    (SIG[11:] + '.f_stop_Hz', 6000.0, SIG + '.f_stop_Hz', 'at most 5000.0'),
    (SIG[11:] + '.f_start_Hz', 0, SIG + '.f_start_Hz', 'greater than 0'),
    (SIG[11:] + '.method', 'quadratic', SIG + '.method', "['linear', 'logarithmic']"),
    (SIG[11:] + '.after_sweep', 'hold', SIG + '.after_sweep', 'repeat'),
    (SIG[11:] + '.type', 'sawtooth', SIG + '.type', 'is not one of'),
    (SIG[11:] + '.type', DELETE, SIG + '.type', 'missing'),
    (SIG[11:], 3.0, SIG, 'mapping'),
]


@pytest.mark.parametrize('dotted,value,key,text', BAD)
def test_bad_keys_name_the_dotted_key(dotted, value, key, text):
    cfg = base()
    _set(cfg, dotted, value)
    with pytest.raises(ConfigError) as info:
        experiment_from_config(cfg)
    assert info.value.key == key
    assert text in str(info.value)
    assert str(info.value).startswith(key + ':')


BAD_SIGNALS = [
    (dict(type='sine', amplitude_V=1.0), 'frequency_Hz', 'missing'),
    (dict(type='sine', amplitude_V=1.0, frequency_Hz=5001.0), 'frequency_Hz', 'at most'),
    (dict(type='prbs', order=32, low_V=0, high_V=1), 'order', 'at most 31'),
    (dict(type='prbs', order=1, low_V=0, high_V=1), 'order', 'at least 2'),
    (dict(type='prbs', order=7, low_V=0, high_V=1, hold_samples=0), 'hold_samples',
     'at least 1'),
    (dict(type='prbs', order=7.5, low_V=0, high_V=1), 'order', 'integer'),
    (dict(type='prbs', order=7, low_V=0), 'high_V', 'missing'),
    (dict(type='multisine', rms_V=0.1, period_samples=100, lines=[1, 50]), 'lines[1]',
     'in [1, 49]'),
    (dict(type='multisine', rms_V=0.1, period_samples=100, lines=[1, 2.5]), 'lines[1]',
     'integer'),
    (dict(type='multisine', rms_V=0.1, period_samples=100, lines=[1], odd_only=True),
     'odd_only', 'not both'),
    (dict(type='multisine', rms_V=0.1, period_samples=100, f_min_Hz=2010, f_max_Hz=2050),
     '', 'no harmonic'),
    (dict(type='multisine', rms_V=0.0, period_samples=100, f_min_Hz=10), 'rms_V',
     'greater than'),
    (dict(type='multisine', rms_V=0.1, period_samples=100, phases='flat'), 'phases',
     'schroeder'),
    (dict(type='uniform_noise', low_V=1.0, high_V=0.0), 'high_V', 'at least 1.0'),
    (dict(type='gaussian_noise', std_V=-1.0), 'std_V', 'at least 0'),
    (dict(type='gaussian_noise', std_V=1.0, seed=-3), 'seed', 'at least 0'),
    (dict(type='steps', times_s=[0, 1], levels_V=[1]), 'levels_V', 'one level per time'),
    (dict(type='steps', times_s=[0, 'a'], levels_V=[1, 2]), 'times_s[1]', 'number'),
    (dict(type='steps', times_s=[1, 0], levels_V=[1, 2]), '', 'increasing'),
    (dict(type='staircase', start_V=0, step_V=0.1, count=0, dwell_s=1), 'count', 'at least'),
    (dict(type='staircase', start_V=0, step_V=0.1, count=3, dwell_s=1, up_down=True),
     'up_down', 'unknown key'),
    (dict(type='constant'), 'value_V', 'missing'),
    (dict(type='waveform'), 'path', 'missing'),
    (dict(type='waveform', path='w.csv', column=True), 'column', 'name or index'),
    (dict(type='waveform', path='w.csv', end='loop'), 'end', 'is not one of'),
]


@pytest.mark.parametrize('spec,key,text', BAD_SIGNALS)
def test_bad_signal_specs_name_the_dotted_key(spec, key, text):
    with pytest.raises(ConfigError) as info:
        experiment_from_config(signal(**spec))
    assert info.value.key == (SIG + '.' + key if key else SIG)
    assert text in str(info.value)


def test_waveform_relative_to_base_dir_and_file_errors(tmp_path):
    (tmp_path / 'w.csv').write_text('time_s,coil_V\n0.0,0.5\n0.0001,-0.5\n')
    exp = experiment_from_config(signal(type='waveform', path='w.csv', end='repeat'),
                                 tmp_path)
    np.testing.assert_array_equal(exp.block(0, 4)[0], [0.5, -0.5, 0.5, -0.5])
    with pytest.raises(WaveformFileError) as info:
        experiment_from_config(signal(type='waveform', path='nothere.csv'), tmp_path)
    assert str(info.value).startswith(SIG + ': ') and 'nothere.csv' in str(info.value)


def test_every_signal_type_builds():
    specs = {
        'a': dict(type='sine', amplitude_V=1, frequency_Hz=10),
        'b': dict(type='multisine', rms_V=0.1, period_samples=1000, f_min_Hz=10,
                  f_max_Hz=100, odd_only=True, phases='random', seed=2),
        'c': dict(type='chirp', amplitude_V=1, f_start_Hz=1, f_stop_Hz=10, method='linear',
                  after_sweep='zero', sweep_time_s=0.1, phase_rad=0.5),
        'd': dict(type='prbs', order=10, hold_samples=2, low_V=-1, high_V=1),
        'e': dict(type='uniform_noise', low_V=-1, high_V=1, seed=1),
        'f': dict(type='gaussian_noise', mean_V=0, std_V=1, seed=1),
        'g': dict(type='steps', times_s=[0.0], levels_V=[1.0]),
        'h': dict(type='staircase', start_V=0, step_V=1, count=3, dwell_s=0.1,
                  start_time_s=0.05, up_and_down=True),
        'i': dict(type='constant', value_V=0.5),
        'j': dict(type='multisine', rms_V=0.1, period_samples=1000, lines=[1, 2, 3]),
    }
    cfg = base()
    cfg['section']['s1']['coil']['signals'] = specs
    plan = experiment_from_config(cfg).sections[0].channels['coil']
    assert sorted(plan.signals) == sorted(specs)
    assert isinstance(plan.signals['d'], Prbs) and plan.signals['d'].hold_samples == 2
    assert isinstance(plan.signals['h'], Steps) and len(plan.signals['h'].levels_V) == 5


def test_shipped_trajectory_loads():
    exp = load_experiment_file(SHIPPED)
    assert exp.sample_rate_Hz == 10000.0
    assert exp.channels == ('coil', 'load_changer')
    assert [s.name for s in exp.sections] == [
        'coil_chirp', 'load_changer_chirp', 'coil_chirp_load_changer_steps',
        'load_changer_chirp_coil_steps']
    assert [s.n_samples for s in exp.sections] == [100000] * 4
    assert exp.total_samples == 400000
    peaks = [np.abs(exp.block(exp.section_start(i), 100000)).max(axis=1) for i in range(4)]
    np.testing.assert_allclose(peaks, [[0.0025, 0.0], [0.0, 0.3], [0.0015, 0.2], [0.0015, 0.2]],
                               rtol=1e-6)
    assert set(yaml.safe_load(SHIPPED.read_text())) == {'/**'}


def test_plain_yaml_and_named_node_and_dotted_keys(tmp_path):
    plain = tmp_path / 'plain.yaml'
    plain.write_text(yaml.safe_dump({'experiment': base()}))
    named = tmp_path / 'named.yaml'
    named.write_text(yaml.safe_dump({'signal_generator': {'ros__parameters': {
        'experiment': base(), 'publish_period_s': 0.1}}}))
    flat = {'experiment.sample_rate_Hz': 10000.0, 'experiment.sections': ['s1'],
            'experiment.section.s1.duration_s': 0.5,
            'experiment.section.s1.coil.signals.k.type': 'constant',
            'experiment.section.s1.coil.signals.k.value_V': 0.25}
    dotted = tmp_path / 'dotted.yaml'
    dotted.write_text(yaml.safe_dump({'/ns/gen': {'ros__parameters': flat}}))
    assert load_experiment_file(plain).total_samples == 7500
    assert load_experiment_file(named).total_samples == 7500
    exp = load_experiment_file(dotted)
    np.testing.assert_array_equal(exp.block(0, 2)[0], 0.25)
    # ROS parameters arrive flat; un-flattened they give the same experiment
    exp2 = experiment_from_config(unflatten(flat)['experiment'])
    np.testing.assert_array_equal(exp2.block(0, 5000), exp.block(0, 5000))


def test_file_errors(tmp_path):
    bad_yaml = tmp_path / 'bad.yaml'
    bad_yaml.write_text('experiment: [unclosed\n')
    with pytest.raises(ConfigError, match='invalid YAML'):
        load_experiment_file(bad_yaml)
    with pytest.raises(ConfigError, match='cannot read'):
        load_experiment_file(tmp_path / 'missing.yaml')
    none = tmp_path / 'none.yaml'
    none.write_text(yaml.safe_dump({'node': {'ros__parameters': {'rate_Hz': 1}}}))
    with pytest.raises(ConfigError, match='experiment'):
        load_experiment_file(none)
    two = tmp_path / 'two.yaml'
    two.write_text(yaml.safe_dump({n: {'ros__parameters': {'experiment': base()}}
                                   for n in ('a', 'b')}))
    with pytest.raises(ConfigError, match='several nodes'):
        load_experiment_file(two)


def test_base_is_not_mutated():
    cfg = base()
    before = copy.deepcopy(cfg)
    experiment_from_config(cfg)
    assert cfg == before
