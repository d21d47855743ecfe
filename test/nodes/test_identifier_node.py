"""
The identifier node over real DDS: from a bag, from live data, and refusals.

A short version of the paper's trajectory is recorded by the experiment runner (a real bag)
and by the node itself (live accumulation while the generator drives the plant).
"""

import json
from pathlib import Path
import shutil
import subprocess
import sys

import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from std_msgs.msg import String
from std_srvs.srv import Trigger
import yaml

from emfc_ros.core.model.linear import linearise
from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.paths import config_file
from emfc_ros.nodes.convert import LATCHED_QOS
from emfc_ros.nodes.identifier import IdentifierNode
from emfc_ros.nodes.plant_simulator import PlantSimulatorNode
from emfc_ros.nodes.signal_generator import SignalGeneratorNode
import ros_harness

TIMEOUT_S = 30.0
IDENTIFY_TIMEOUT_S = 300.0
SECTION_S = 2.0


def short_experiment(path: Path) -> Path:
    """The shipped trajectory with 2 s sections (sweeps shortened to match)."""
    doc = yaml.safe_load(config_file('identification_trajectory.yaml').read_text())
    experiment = doc['/**']['ros__parameters']['experiment']
    for section in experiment['section'].values():
        section['duration_s'] = SECTION_S
        for channel in ('coil', 'load_changer'):
            for signal in section.get(channel, {}).get('signals', {}).values():
                if signal['type'] == 'chirp':
                    signal['sweep_time_s'] = SECTION_S
                if signal['type'] == 'steps':
                    signal['times_s'] = [t * SECTION_S / 10.0 for t in signal['times_s']]
    path.write_text(yaml.safe_dump({'experiment': experiment}))
    return path


def options(path: Path) -> Path:
    path.write_text(yaml.safe_dump({'greybox': {'enabled': False},
                                    'static': {'enabled': False}}))
    return path


@pytest.fixture(scope='module')
def short_bag(tmp_path_factory):
    folder = tmp_path_factory.mktemp('runner')
    experiment = short_experiment(folder / 'experiment.yaml')
    plan = folder / 'plan.yaml'
    plan.write_text(yaml.safe_dump({'run': {
        'name': 'short', 'experiment_files': [str(experiment)],
        'simulator': {'balance_file': str(config_file('balance_default.yaml'))}}}))
    runner = shutil.which('emfc-experiment') or str(Path(sys.executable).parent /
                                                    'emfc-experiment')
    result = subprocess.run([runner, str(plan), '-o', str(folder / 'run'), '--no-identify'],
                            capture_output=True, text=True, timeout=600,
                            env=ros_harness.child_environment())
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    return folder / 'run' / 'bag'


class Client:
    """Calls the identifier's services and collects its results."""

    def __init__(self, context, executor):
        self.node = rclpy.create_node('identifier_client', context=context)
        self.executor = executor
        self.results = []
        self.node.create_subscription(String, 'identifier/result',
                                      lambda m: self.results.append(json.loads(m.data)),
                                      LATCHED_QOS)
        self.clients = {n: self.node.create_client(Trigger, f'identifier/{n}')
                        for n in ('identify_bag', 'start_accumulating', 'identify')}
        executor.add_node(self.node)

    def call(self, name):
        client = self.clients[name]
        assert ros_harness.spin_until(self.executor, client.service_is_ready, TIMEOUT_S)
        future = client.call_async(Trigger.Request())
        assert ros_harness.spin_until(self.executor, future.done, TIMEOUT_S)
        return future.result()

    def wait_result(self, count):
        assert ros_harness.spin_until(self.executor, lambda: len(self.results) >= count,
                                      IDENTIFY_TIMEOUT_S)
        return self.results[count - 1]


def _upper_resonance_Hz() -> float:
    """The linear model's upper mode for the pan load used here (load changer coupled)."""
    params = BalanceParameters.load_yaml(config_file('balance_default.yaml'))
    poles = linearise(loaded(params.mechanics, 0.1024, True)).poles()
    return max(root.frequency_Hz for root in poles)


def _check_results(folder: Path):
    results = yaml.safe_load((folder / 'results.yaml').read_text())
    frfs = {frf['name']: frf for frf in results['frequency_responses']}
    assert {'coil_chirp.coil', 'load_changer_chirp.pan'} <= set(frfs)
    resonances = frfs['coil_chirp.coil']['transfer_function']['resonances']
    upper = max(r['frequency_Hz'] for r in resonances)
    # Generous: 2 s sections; the full-length accuracy is the pipeline's own test.
    np.testing.assert_allclose(upper, _upper_resonance_Hz(), rtol=0.01)
    assert (folder / 'summary.md').is_file()
    assert any(p.suffix == '.png' for p in folder.iterdir())
    return results


@pytest.mark.slow
def test_identify_a_bag_and_refusals(short_bag, tmp_path, executor, ros_context):
    node = IdentifierNode(context=ros_context, parameter_overrides=[
        Parameter('bag', value=str(tmp_path / 'nothing')),
        Parameter('output_dir', value=str(tmp_path / 'out')),
        Parameter('options_file', value=str(options(tmp_path / 'options.yaml')))])
    executor.add_node(node)
    client = Client(ros_context, executor)
    refused = client.call('identify_bag')
    assert not refused.success and 'metadata.yaml' in refused.message
    refused = client.call('identify')
    assert not refused.success and 'nothing accumulated' in refused.message
    bad = node.set_parameters([Parameter('options_file', value=str(tmp_path / 'none.yaml'))])
    assert not bad[0].successful and 'none.yaml' in bad[0].reason

    assert node.set_parameters([Parameter('bag', value=str(short_bag))])[0].successful
    started = client.call('identify_bag')
    assert started.success, started.message
    busy = client.call('identify_bag')
    assert not busy.success and 'running' in busy.message
    result = client.wait_result(1)
    assert result['ok'], result
    _check_results(Path(result['output']))


@pytest.mark.slow
def test_identify_live_data_accumulated_on_request(tmp_path, executor, ros_context):
    experiment = short_experiment(tmp_path / 'experiment.yaml')
    plant = PlantSimulatorNode(context=ros_context, parameter_overrides=[
        Parameter('load_mass_kg', value=0.1024), Parameter('load_changer_coupled', value=True),
        Parameter('publish_groups', value=False), Parameter('state_rate_Hz', value=0.0)])
    generator = SignalGeneratorNode(context=ros_context, parameter_overrides=[
        Parameter('experiment_file', value=str(experiment)),
        Parameter('pacing', value='consumer'), Parameter('autostart', value=False)])
    identifier = IdentifierNode(context=ros_context, parameter_overrides=[
        Parameter('output_dir', value=str(tmp_path / 'out')),
        Parameter('options_file', value=str(options(tmp_path / 'options.yaml')))])
    for node in (plant, generator, identifier):
        executor.add_node(node)
    client = Client(ros_context, executor)
    assert ros_harness.spin_until(
        executor, lambda: generator.count_subscribers('excitation') >= 1
        and plant.count_subscribers('measurements') >= 1, TIMEOUT_S)
    assert client.call('start_accumulating').success
    start = client.node.create_client(Trigger, 'signal_generator/start')
    assert ros_harness.spin_until(executor, start.service_is_ready, TIMEOUT_S)
    future = start.call_async(Trigger.Request())
    assert ros_harness.spin_until(executor, future.done, TIMEOUT_S) and future.result().success
    total = int(4 * SECTION_S * 10000)
    assert ros_harness.spin_until(
        executor, lambda: sum(c.shape[1] for c in identifier._chunks) >= total, 120.0)
    answer = client.call('identify')
    assert answer.success, answer.message
    result = client.wait_result(1)
    assert result['ok'], result
    _check_results(Path(result['output']))
