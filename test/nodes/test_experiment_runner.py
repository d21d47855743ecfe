"""
The experiment runner's default job, end to end: nodes over real DDS, a real bag read back.

Runs the README's first line, ``./tools/experiment.sh``, as typed in the checkout (it sets up
the venv, a check that installs nothing when the venv is current, then runs
``emfc-experiment`` with no arguments: the README's ``emfc-experiment`` line, the shipped
default plan) and checks every output file, the recorded samples and the message accounting.
"""

import json
from pathlib import Path
import re
import shutil
import subprocess
import sys

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
import yaml

from emfc_ros.core.bag import read_metadata, read_streams
from emfc_ros.core.blocks import unpack
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.paths import config_file
from emfc_ros.core.run_plan import load_plan
from emfc_ros.core.signals import experiment_from_config
from emfc_ros.core.stream_counts import CUSTOM_DATA_KEY, from_mapping, problems
import readme_lines
import ros_harness
from ros_harness import scaled

REPO = Path(__file__).resolve().parents[2]


def _runner() -> str:
    return shutil.which('emfc-experiment') or str(Path(sys.executable).parent /
                                                  'emfc-experiment')


def _bag_info() -> str:
    return shutil.which('emfc-bag-info') or str(Path(sys.executable).parent / 'emfc-bag-info')


def _identify_cli() -> str:
    return shutil.which('emfc-identify') or str(Path(sys.executable).parent / 'emfc-identify')


@pytest.fixture(scope='module')
def default_run(tmp_path_factory):
    """
    The README's main job, ``./tools/experiment.sh``, run once as a user types it.

    It writes ``out/identification-<date>-<time>/`` in the checkout, as for the user; the
    folder is moved to the test's temporary folder (and an ``out/`` it created removed).
    """
    readme_lines.check_tools_venv()
    argv = readme_lines.readme_argv('./tools/experiment.sh')
    tmp_path = tmp_path_factory.mktemp('default_run')
    out_root = REPO / 'out'
    had_out = out_root.exists()
    result = subprocess.run(argv, capture_output=True, text=True, timeout=scaled(900), cwd=REPO,
                            env=ros_harness.child_environment({'EMFC_VENV': sys.prefix}))
    made = re.search(r'^emfc-experiment: identification on the simulator, output (\S+)$',
                     result.stdout, re.M)
    out = tmp_path / 'run'
    if made:
        assert Path(made.group(1)).parent == Path('out'), made.group(1)
        shutil.move(str(REPO / made.group(1)), str(out))
    if not had_out and out_root.is_dir() and not any(out_root.iterdir()):
        out_root.rmdir()
    assert made, result.stdout[-3000:] + result.stderr[-3000:]
    return out, result


@pytest.mark.slow
def test_default_job_produces_all_outputs_and_an_exact_bag(default_run):
    out, result = default_run
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    # tools/setup_env.sh found the venv current: it created and installed nothing.
    assert 'setup_env:' not in result.stderr, result.stderr
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


@pytest.mark.slow
def test_the_bag_carries_simulated_time(default_run):
    """Stamps, start and duration are simulated time; /clock is recorded (issue 13)."""
    out, result = default_run
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    total, rate = 490000, 10000.0
    # An independent reader: rosbags.
    with AnyReader([out / 'bag']) as reader:
        duration_s = (reader.end_time - reader.start_time) * 1e-9
        reader_start_s, reader_end_s = reader.start_time * 1e-9, reader.end_time * 1e-9
        topics = {c.topic for c in reader.connections}
        blocks = [c for c in reader.connections if c.topic == '/emfc/measurements']
        ends, stamps = [], []
        for connection, stamp, raw in reader.messages(connections=blocks):
            msg = reader.deserialize(raw, connection.msgtype)
            block = unpack([(d.label, int(d.size), int(d.stride)) for d in msg.layout.dim],
                           int(msg.layout.data_offset), msg.data)
            ends.append((block.first_sample_index + block.n_samples) / rate)
            stamps.append(stamp * 1e-9)
    # The experiment lasts total / rate of simulated time (49 s); the wall time it took
    # was a fraction of that. The bag's stamps are that simulated time: none beyond the last
    # tick, and the last block's (below) at most one block before it.
    # (The reader's end time is the last stamp + 1 ns.)
    assert duration_s <= total / rate + 2e-9, duration_s
    assert reader_end_s <= total / rate + 2e-9 and reader_start_s >= 0.0
    assert '/clock' in topics
    # Each block is stamped with the simulated time the recorder's clock (/clock, published
    # before the outputs) had when it took the block: never more than one block (0.1 s)
    # before its last sample exists and never beyond the end. How much later a recorder on
    # a loaded machine takes it depends on the machine, so it is not bounded here.
    stamps, ends = np.array(stamps), np.array(ends)
    assert np.all(stamps >= ends - 0.1 - 1e-9), np.min(stamps - ends)
    assert np.all(stamps <= total / rate + 1e-9) and np.all(np.diff(stamps) >= 0)
    assert ends[-1] == total / rate and stamps[-1] >= total / rate - 0.1 - 1e-9
    custom = read_metadata(out / 'bag')['custom_data']
    assert custom['emfc_ros.clock'] == 'simulated'
    info = subprocess.run([_bag_info(), str(out / 'bag')], capture_output=True, text=True,
                          timeout=scaled(60))
    assert info.returncode == 0, info.stderr
    assert 'of simulated time' in info.stdout and 'Recorded (wall)' in info.stdout


@pytest.mark.slow
def test_the_main_job_accounts_for_every_message(default_run):
    """No silent loss (issue 13 item 5): per stream due, published, decimated, recorded."""
    out, result = default_run
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    custom = read_metadata(out / 'bag')['custom_data']
    counts = {c.topic: c for c in from_mapping(yaml.safe_load(custom[CUSTOM_DATA_KEY]))}
    # Read with an independent reader: rosbags.
    with AnyReader([out / 'bag']) as reader:
        recorded = {c.topic: c.msgcount for c in reader.connections}
    assert {t: c.recorded for t, c in counts.items()} == recorded
    # 490 blocks of 1000 samples: one answer, one /clock tick and (10 Hz of 10 kHz) one
    # joint state per block, all due, all published (none left out by a rate limit) and all
    # in the bag.
    for topic in ('/emfc/excitation', '/emfc/measurements', '/clock', '/emfc/joint_states'):
        c = counts[topic]
        assert c.due == 490 and c.published - c.repeated + c.decimated == c.due, c
        assert c.decimated == 0 and c.lost == 0 and c.recorded == c.published, c
    assert problems(counts.values()) == []
    run = yaml.safe_load((out / 'run.yaml').read_text())['run']
    assert run['simulator']['max_state_wall_rate_Hz_used'] == 0.0
    # The same figures in summary.md, where the user looks.
    summary = (out / 'summary.md').read_text()
    assert '## Messages per stream' in summary
    assert '| `/emfc/joint_states` | 490 | 490 | 0 | 0 | 490 | 0 |' in summary
    assert 'Every message published on the 4 counted streams is in the bag (lost 0).' in summary
    assert 'warning' not in result.stderr


def _numbers(results: dict) -> dict:
    """What an identification found, without timings and file names."""
    g = results['greybox']
    return {'status': results['status'], 'configuration': results['configuration'],
            'greybox': {k: g[k] for k in ('parameters', 'derived', 'sections', 'cost')},
            'frequency_responses': results['frequency_responses'],
            'static_characteristics': results['static_characteristics'],
            'model_parameters': results['model_parameters']}


@pytest.mark.slow
def test_identify_cli_reproduces_the_main_job_and_needs_the_pan_load(default_run, tmp_path):
    out, result = default_run
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    custom = read_metadata(out / 'bag')['custom_data']
    options = yaml.safe_load(custom['emfc_ros.identification_options'])
    assert options['greybox']['sections'][0] == 'coil_chirp'
    plant = yaml.safe_load(custom['emfc_ros.plant_configuration'])
    assert 0.05 < plant['load_mass_kg'] < 0.2 and plant['load_changer_coupled'] is True
    # `emfc-identify BAG` as a user types it reproduces the main job's identification
    again = tmp_path / 'again'
    ident = subprocess.run([_identify_cli(), str(out / 'bag'), '-o', str(again)],
                           capture_output=True, text=True, timeout=scaled(600),
                           env=ros_harness.child_environment(), cwd=tmp_path)
    assert ident.returncode == 0, ident.stdout[-3000:] + ident.stderr[-3000:]
    first = yaml.safe_load((out / 'identification' / 'results.yaml').read_text())
    second = yaml.safe_load((again / 'results.yaml').read_text())
    assert _numbers(second) == _numbers(first)
    assert first['status']['success'] is True
    assert 'plant_configuration' in first['configuration']['source']
    assert (out / 'identification' / 'summary.md').read_text().count(
        '**Identification succeeded**') == 1
    # without the runner's plant configuration and the node parameters, the plant
    # simulator's measurement description still says what was on the pan
    blind = tmp_path / 'blind'
    strip_plant_configuration(out / 'bag', blind)
    told = subprocess.run([_identify_cli(), str(blind), '-o', str(tmp_path / 'told')],
                          capture_output=True, text=True, timeout=scaled(600),
                          env=ros_harness.child_environment(), cwd=tmp_path)
    assert told.returncode == 0, told.stdout[-2000:] + told.stderr[-2000:]
    back = yaml.safe_load((tmp_path / 'told' / 'results.yaml').read_text())
    assert back['configuration']['source'].startswith(
        'load_mass_kg from measurement description')
    assert back['greybox']['parameters']['c2_Nm_per_rad']['value'] == \
        first['greybox']['parameters']['c2_Nm_per_rad']['value']


def strip_plant_configuration(bag: Path, copy: Path) -> None:
    """Copy a bag without the runner's plant configuration and the recorded node parameters."""
    shutil.copytree(bag, copy)
    meta = yaml.safe_load((copy / 'metadata.yaml').read_text())
    custom = meta['rosbag2_bagfile_information']['custom_data']
    for key in ('emfc_ros.plant_configuration', 'emfc_ros.node_parameters'):
        custom.pop(key)
    (copy / 'metadata.yaml').write_text(yaml.safe_dump(meta))


def short_experiment(path: Path, section_s: float = 3.0) -> Path:
    """The shipped trajectory with 3 s sections (sweeps and steps shortened to match)."""
    doc = yaml.safe_load(config_file('identification_trajectory.yaml').read_text())
    experiment = doc['/**']['ros__parameters']['experiment']
    for section in experiment['section'].values():
        section['duration_s'] = section_s
        for channel in ('coil', 'load_changer'):
            for signal in section.get(channel, {}).get('signals', {}).values():
                if signal['type'] == 'chirp':
                    signal['sweep_time_s'] = section_s
                if signal['type'] == 'steps':
                    signal['times_s'] = [t * section_s / 10.0 for t in signal['times_s']]
    path.write_text(yaml.safe_dump({'experiment': experiment}))
    return path


@pytest.mark.slow
def test_a_failed_identification_exits_1_and_keeps_bag_and_report(tmp_path):
    # The plan owns the pan load (run.simulator.load_mass_kg); its identification options
    # configure the pan 0.1 kg heavier than the simulated one, which is the same to the
    # model as a pan load told 0.1 kg wrong: the identified mass matrix contradicts it.
    nominal = BalanceParameters.load_yaml(str(config_file('balance_default.yaml')))
    plan = tmp_path / 'plan.yaml'
    plan.write_text(yaml.safe_dump({'run': {
        'name': 'wrong_pan', 'experiment_files': [str(short_experiment(tmp_path / 'e.yaml'))],
        'simulator': {'balance_file': str(config_file('balance_default.yaml'))},
        'identification': {'balance': {'mechanics': {
            'mp_kg': nominal.mechanics.mp_kg + 0.1}}}}}))
    out = tmp_path / 'run'
    result = subprocess.run([_runner(), str(plan), '-o', str(out)], capture_output=True,
                            text=True, timeout=scaled(900), env=ros_harness.child_environment(),
                            cwd=tmp_path)
    assert result.returncode == 1, result.stdout[-3000:] + result.stderr[-3000:]
    assert 'identification failed' in result.stderr and 'mass matrix' in result.stderr
    assert (out / 'bag' / 'metadata.yaml').is_file()
    results = yaml.safe_load((out / 'identification' / 'results.yaml').read_text())
    assert results['status']['success'] is False
    assert '**Identification FAILED**' in (out / 'summary.md').read_text()


@pytest.mark.slow
def test_the_quick_plan_as_typed(tmp_path):
    """``emfc-experiment config/experiment_quick.yaml``: 10 s, the mechanics within 1 %."""
    argv = readme_lines.readme_argv('emfc-experiment config/experiment_quick.yaml')
    (tmp_path / 'config').symlink_to(REPO / 'config')     # as in the checkout
    result = subprocess.run(argv, capture_output=True, text=True, timeout=scaled(900),
                            cwd=tmp_path, env=ros_harness.child_environment())
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    made = re.search(r'^emfc-experiment: quick-identification on the simulator, output (\S+)$',
                     result.stdout, re.M)
    assert made, result.stdout[-3000:]
    out = tmp_path / made.group(1)
    results = yaml.safe_load((out / 'identification' / 'results.yaml').read_text())
    assert results['n_samples'] == 100000                  # 10 s at 10 kHz
    assert results['status']['success'] is True, results['status']
    assert (out / 'identification' / 'bode_coil_chirp.coil.png').is_file()
    assert (out / 'identification' / 'time_load_changer_chirp.png').is_file()
    greybox = results['greybox']
    truth = BalanceParameters.load_yaml(str(config_file('balance_default.yaml'))).mechanics
    for name in ('c1_Nm_per_rad', 'd1_Nms_per_rad', 'c2_Nm_per_rad', 'd2_Nms_per_rad'):
        row = greybox['parameters'][name]
        value, std = row['value'], row['standard_error']
        true = getattr(truth, name)
        assert abs(value / true - 1.0) < 0.01, (name, value, true)
        # the error is what the reported uncertainty says it may be
        assert abs(value - true) < 4.0 * std, (name, value, true, std)
    assert problems(from_mapping(yaml.safe_load(
        read_metadata(out / 'bag')['custom_data'][CUSTOM_DATA_KEY]))) == []


@pytest.mark.slow
def test_the_wait_set_executor_still_runs_the_job(tmp_path):
    """``executor: single_threaded`` (an rclpy without the EventsExecutor): all recorded."""
    plan = tmp_path / 'plan.yaml'
    plan.write_text(yaml.safe_dump({'run': {
        'name': 'wait_set', 'executor': 'single_threaded',
        'experiment_files': [str(short_experiment(tmp_path / 'e.yaml', 1.0))],
        'simulator': {'balance_file': str(config_file('balance_default.yaml'))}}}))
    out = tmp_path / 'run'
    result = subprocess.run([_runner(), str(plan), '-o', str(out), '--no-identify'],
                            capture_output=True, text=True, timeout=scaled(300),
                            env=ros_harness.child_environment(), cwd=tmp_path)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    counts = from_mapping(yaml.safe_load(
        read_metadata(out / 'bag')['custom_data'][CUSTOM_DATA_KEY]))
    assert problems(counts) == []
    measured = next(c for c in counts if c.topic == '/emfc/measurements')
    assert measured.recorded == measured.due == 40         # 4 sections of 1 s, 1000-sample blocks
    assert read_streams(out / 'bag')['/emfc/measurements'].n_samples == 40000


def test_bad_plan_is_refused_with_the_key(tmp_path):
    plan = tmp_path / 'plan.yaml'
    plan.write_text('run:\n  experiment_files: [nothing.yaml]\n  target: simulator\n')
    result = subprocess.run([_runner(), str(plan), '-o', str(tmp_path / 'o')],
                            capture_output=True, text=True, timeout=scaled(120),
                            env=ros_harness.child_environment())
    assert result.returncode == 2
    assert 'run.experiment_files[0]' in result.stderr
    assert 'Traceback' not in result.stderr
