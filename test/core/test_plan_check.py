"""The whole plan is checked on loading: experiment files, signals, identification options."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from emfc_ros.core.errors import ConfigError
from emfc_ros.core.paths import config_file
from emfc_ros.core.plan_check import check_identification, resolve_waveform_paths
from emfc_ros.core.run_plan import load_plan
from emfc_ros.core.signals import experiment_from_config

SECTIONS = ['coil_chirp', 'load_changer_chirp']


def _plan_dir(tmp_path: Path, run_change: dict = None, experiment_change=None) -> Path:
    """A copy of the shipped default plan and its experiment files, changed as given."""
    for name in ('experiment_default.yaml', 'identification_trajectory.yaml',
                 'static_characteristics.yaml', 'balance_default.yaml'):
        (tmp_path / name).write_text(config_file(name).read_text())
    if experiment_change is not None:
        path = tmp_path / 'identification_trajectory.yaml'
        doc = yaml.safe_load(path.read_text())
        experiment_change(doc['/**']['ros__parameters']['experiment'])
        path.write_text(yaml.safe_dump(doc))
    plan = tmp_path / 'experiment_default.yaml'
    doc = yaml.safe_load(plan.read_text())
    doc['run'].update(run_change or {})
    plan.write_text(yaml.safe_dump(doc))
    return plan


def _refused(plan: Path) -> ConfigError:
    with pytest.raises(ConfigError) as info:
        load_plan(plan)
    return info.value


def _sweep(experiment: dict) -> dict:
    return experiment['section']['coil_chirp']['coil']['signals']['sweep']


def test_a_signal_error_in_an_experiment_file_names_the_file_and_the_key(tmp_path):
    plan = _plan_dir(tmp_path, experiment_change=lambda e: _sweep(e).update(
        f_stop_Hz=9000.0))                      # above fs/2 = 5 kHz
    error = _refused(plan)
    assert error.key == (f'run.experiment_files[0] ({tmp_path / "identification_trajectory.yaml"})'
                         ': experiment.section.coil_chirp.coil.signals.sweep.f_stop_Hz')
    assert '5000' in error.problem


@pytest.mark.parametrize('change, key, words', [
    (lambda e: _sweep(e).update(amplitde_V=0.1),
     'experiment.section.coil_chirp.coil.signals.sweep.amplitde_V', 'unknown key'),
    (lambda e: _sweep(e).update(type='chrip'),
     'experiment.section.coil_chirp.coil.signals.sweep.type', 'chirp'),
    (lambda e: _sweep(e).update(amplitude_V='loud'),
     'experiment.section.coil_chirp.coil.signals.sweep.amplitude_V', 'loud'),
    (lambda e: e['section']['coil_chirp'].update(duration_s=-1.0),
     'experiment.section.coil_chirp.duration_s', '-1'),
])
def test_every_signal_is_checked_on_loading(tmp_path, change, key, words):
    error = _refused(_plan_dir(tmp_path, experiment_change=change))
    assert error.key.startswith('run.experiment_files[0] (') and error.key.endswith(key)
    assert words in error.problem


def test_a_missing_waveform_file_is_refused_on_loading(tmp_path):
    def change(e):
        _sweep(e).clear()
        _sweep(e).update(type='waveform', path='missing.csv')
    error = _refused(_plan_dir(tmp_path, experiment_change=change))
    assert error.key.startswith('run.experiment_files[0]') and 'missing.csv' in str(error)


def test_waveform_paths_are_resolved_against_the_experiment_file(tmp_path):
    (tmp_path / 'waves').mkdir()
    np.savetxt(tmp_path / 'waves' / 'w.csv', np.column_stack([np.linspace(0, 0.001, 100)]),
               header='coil_V', comments='', delimiter=',')

    def change(e):
        _sweep(e).clear()
        _sweep(e).update(type='waveform', path='waves/w.csv', end='repeat')
    plan = load_plan(_plan_dir(tmp_path, experiment_change=change))
    sweep = plan.experiment['section']['coil_chirp']['coil']['signals']['sweep']
    assert sweep['path'] == str(tmp_path / 'waves' / 'w.csv')
    # the merged experiment builds from any working directory
    assert experiment_from_config(plan.experiment).total_samples == 490000
    assert resolve_waveform_paths({'sections': []}, tmp_path) == {'sections': []}


@pytest.mark.parametrize('identification, key', [
    ({'greybox': {'tolerence': 1e-6}}, 'run.identification.greybox.tolerence'),
    ({'frf': {'method': 'fft'}}, 'run.identification.frf.method'),
    ({'frf': {'lpm_degree': 'two'}}, 'run.identification.frf.lpm_degree'),
    ({'enabled': 'yes'}, 'run.identification.enabled'),
    ({'greybox': {'max_evaluations': 1.5}}, 'run.identification.greybox.max_evaluations'),
    ({'tf-fit': {}}, 'run.identification.tf-fit'),
    ({'greybox': {'sections': ['coil_chrip']}}, 'run.identification.greybox.sections[0]'),
    ({'load_mass_kg': 0.1}, 'run.identification.load_mass_kg'),
    ({'balance': {'mechanics': {'l1_m': -1.0}}}, 'run.identification.balance.mechanics.l1_m'),
])
def test_identification_options_are_checked_on_loading(tmp_path, identification, key):
    error = _refused(_plan_dir(tmp_path, {'identification': identification}))
    assert error.key == key
    if key.endswith('tolerence'):
        assert str(error).startswith('run.identification.greybox.tolerence: unknown key')


def test_identification_check_returns_the_pipeline_configuration():
    config = check_identification({'enabled': False, 'frf': {'method': 'welch'},
                                   'greybox': {'sections': SECTIONS}}, SECTIONS)
    assert config.frf.method == 'welch' and config.greybox.sections == tuple(SECTIONS)
    with pytest.raises(ConfigError, match='expected a mapping'):
        check_identification(['frf'], SECTIONS)


@pytest.mark.parametrize('run_change, key', [
    ({'recording': {'topics': ['excitation', 'measurements']}}, 'run.recording.topics'),
    ({'simulator': {'balance_file': 'nowhere.yaml'}}, 'run.simulator.balance_file'),
])
def test_recording_and_balance_are_checked_on_loading(tmp_path, run_change, key):
    error = _refused(_plan_dir(tmp_path, run_change))
    assert error.key == key


def test_absolute_topics_in_the_namespace_count(tmp_path):
    topics = ['/emfc/excitation', 'excitation/description', '/emfc/measurements',
              'measurements/description']
    plan = load_plan(_plan_dir(tmp_path, {'recording': {'topics': topics}}))
    assert list(plan.recording.topics) == topics


def test_a_bad_balance_file_is_named(tmp_path):
    (tmp_path / 'bad_balance.yaml').write_text('balance: {mechanics: {l1_m: -1.0}}\n')
    error = _refused(_plan_dir(tmp_path, {'simulator': {'balance_file': 'bad_balance.yaml'}}))
    assert error.key == 'run.simulator.balance_file' and 'l1_m' in error.problem
