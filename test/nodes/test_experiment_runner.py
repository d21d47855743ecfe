"""
The experiment runner's default job, end to end: nodes over real DDS, a real bag read back.

Runs ``emfc-experiment`` as users do (a separate process, the shipped default plan) and
checks every output file and the recorded samples.
"""

import json
from pathlib import Path
import shutil
import subprocess
import sys

import numpy as np
import pytest
import yaml

from emfc_ros.core.bag import read_metadata, read_streams
from emfc_ros.core.paths import config_file
from emfc_ros.core.run_plan import load_plan
from emfc_ros.core.signals import experiment_from_config
import ros_harness


def _runner() -> str:
    return shutil.which('emfc-experiment') or str(Path(sys.executable).parent /
                                                  'emfc-experiment')


@pytest.mark.slow
def test_default_job_produces_all_outputs_and_an_exact_bag(tmp_path):
    out = tmp_path / 'run'
    result = subprocess.run([_runner(), '-o', str(out)], capture_output=True, text=True,
                            timeout=900, env=ros_harness.child_environment(), cwd=tmp_path)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    for name in ('experiment.yaml', 'run.yaml', 'timing.json', 'summary.md',
                 'bag/metadata.yaml', 'bag/bag_0.mcap', 'identification/results.yaml',
                 'identification/summary.md', 'identification/bode_coil_chirp.coil.png',
                 'identification/bode_load_changer_chirp.pan.png'):
        assert (out / name).is_file(), name
    results = yaml.safe_load((out / 'identification' / 'results.yaml').read_text())
    assert results['n_samples'] == 490000
    assert results['greybox'] is not None and results['static_characteristics'] is not None
    timing = json.loads((out / 'timing.json').read_text())
    assert {'experiment', 'identify', 'report', 'total'} <= set(timing)
    assert '100.0 %' in result.stdout              # the progress display reached the end

    plan = load_plan(config_file('experiment_default.yaml'))
    experiment = experiment_from_config(plan.experiment)
    total = experiment.total_samples
    streams = read_streams(out / 'bag')
    excitation = streams['/emfc/excitation']
    measurements = streams['/emfc/measurements']
    assert excitation.first_sample_index == 0 and measurements.first_sample_index == 0
    assert excitation.gaps == [] and measurements.gaps == []
    assert excitation.n_samples == measurements.n_samples == total
    np.testing.assert_array_equal(excitation.samples, experiment.block(0, total))
    applied = measurements.channel('coil_setpoint_V')
    np.testing.assert_allclose(applied, excitation.channel('coil'), atol=20.0 / 65536)
    assert measurements.sample_rate_Hz == 10000.0
    assert 'position_m' in measurements.channel_names

    custom = read_metadata(out / 'bag')['custom_data']
    assert yaml.safe_load(custom['emfc_ros.experiment'])['experiment']['sections'] == \
        plan.experiment['sections']
    params = yaml.safe_load(custom['emfc_ros.node_parameters'])
    assert params['/emfc/plant_simulator']['ros__parameters']['time_mode'] == 'owner'
    run = yaml.safe_load((out / 'run.yaml').read_text())['run']
    assert 0.05 < run['simulator']['load_mass_kg_used'] < 0.2     # the balancing mass
    summary = (out / 'summary.md').read_text()
    assert 'experiment' in summary and 'Read back 490000 samples' in summary


def test_bad_plan_is_refused_with_the_key(tmp_path):
    plan = tmp_path / 'plan.yaml'
    plan.write_text('run:\n  experiment_files: [nothing.yaml]\n  target: simulator\n')
    result = subprocess.run([_runner(), str(plan), '-o', str(tmp_path / 'o')],
                            capture_output=True, text=True, timeout=120,
                            env=ros_harness.child_environment())
    assert result.returncode == 2
    assert 'run.experiment_files[0]' in result.stderr
    assert 'Traceback' not in result.stderr
