"""
No lost start: a consumer-paced signal generator and a plant simulator in separate processes.

The two nodes are started as ``ros2 run`` starts them (``<prefix>/lib/emfc_ros/<name>``),
with the parameters ``launch/sim_experiment.launch.py`` gives them, in both orders and
with a pause of a few seconds between the two starts, and with the listener of the
measurements (a recorder) coming last: the plant answers every sample of the experiment
from sample 0, the listener gets them all and the generator reaches ``done``. A consumer that never
acknowledges puts the generator in state ``error`` on its status and on ``/diagnostics``.
"""

import ast
import json
from pathlib import Path

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
import rclpy
from std_msgs.msg import Bool, Float64MultiArray, String, UInt64
import yaml

from emfc_ros.core.blocks import Continuity, SequenceTracker
from emfc_ros.core.config import unflatten
from emfc_ros.core.signals import experiment_from_config
from emfc_ros.core.start_gate import readiness_text
from emfc_ros.nodes.convert import (
    BLOCK_QOS, CONTROL_QOS, LATCHED_QOS, msg_to_block, msg_to_description)
import ros_harness
from ros_harness import scaled

REPO = Path(__file__).resolve().parents[2]
LAUNCH_FILE = REPO / 'launch' / 'sim_experiment.launch.py'
#: The first start after an install compiles the simulator kernel (12-17 s measured).
START_TIMEOUT_S = scaled(180.0)
TIMEOUT_S = scaled(60.0)
#: The pause between the two starts [s]: longer than discovery (1-3 s), so that a window sent
#: before the consumer matched would have been lost.
PAUSE_S = 3.0
LOAD_MASS_KG = 0.1274
BLOCK_SIZE = 250

EXPERIMENT = {
    'sample_rate_Hz': 10000.0,
    'sections': ['sine', 'chirp'],
    'section.sine.duration_s': 0.3,
    'section.sine.coil.signals.s.type': 'sine',
    'section.sine.coil.signals.s.amplitude_V': 0.2,
    'section.sine.coil.signals.s.frequency_Hz': 20.0,
    'section.chirp.duration_s': 0.2,
    'section.chirp.load_changer.signals.c.type': 'chirp',
    'section.chirp.load_changer.signals.c.amplitude_V': 0.1,
    'section.chirp.load_changer.signals.c.f_start_Hz': 5.0,
    'section.chirp.load_changer.signals.c.f_stop_Hz': 200.0,
    'section.chirp.load_changer.signals.c.sweep_time_s': 0.2,
    'section.chirp.load_changer.signals.c.method': 'linear',
}


def launch_literal_parameters():
    """
    The literal parameters ``sim_experiment.launch.py`` gives each node.

    Returns
    -------
    dict
        Executable name to ``{parameter: value}`` for the parameters whose value is a
        literal (the others come from launch arguments, set by the test).
    """
    tree = ast.parse(LAUNCH_FILE.read_text())
    out = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, 'id', None) == 'Node':
            kwargs = {kw.arg: kw.value for kw in node.keywords}
            params = {}
            for d in getattr(kwargs.get('parameters'), 'elts', []):
                for key, value in zip(d.keys, d.values):
                    if isinstance(value, ast.Constant):
                        params[ast.literal_eval(key)] = value.value
            out[ast.literal_eval(kwargs['executable'])] = params
    return out


def _ros_value(value):
    return str(value).lower() if isinstance(value, bool) else str(value)


def node_argv(name, params):
    """The ``ros2 run emfc_ros <name>`` command line in namespace emfc."""
    argv = ros_harness.node_executable(name) + ['--ros-args', '-r', '__ns:=/emfc']
    for key, value in params.items():
        argv += ['-p', f'{key}:={_ros_value(value)}']
    return argv


def launch_argument_defaults():
    """
    The default of every ``DeclareLaunchArgument`` of ``sim_experiment.launch.py``.

    Those of the arguments it shares with the hardware launch are in
    ``emfc_ros/launch_support.py`` (``gate_arguments``).
    """
    out = {}
    files = (LAUNCH_FILE, REPO / 'emfc_ros' / 'launch_support.py')
    sources = '\n'.join(p.read_text() for p in files)
    for node in ast.walk(ast.parse(sources)):
        if isinstance(node, ast.Call) and getattr(node.func, 'id', None) == \
                'DeclareLaunchArgument':
            kwargs = {kw.arg: kw.value for kw in node.keywords}
            if isinstance(kwargs.get('default_value'), ast.Constant):
                out[ast.literal_eval(node.args[0])] = kwargs['default_value'].value
    return out


def generator_argv(experiment_file, **extra):
    params = dict(launch_literal_parameters()['signal_generator'])
    defaults = launch_argument_defaults()
    # What the launch file gives the generator from its arguments' defaults; nothing here
    # records the excitation, so one subscription (the plant's), as the docs say.
    params.update({'pacing': defaults['pacing'], 'start_gate': defaults['start_gate'],
                   'window_blocks': int(defaults['window_blocks']), 'min_subscribers': 1})
    params.update({'experiment_file': str(experiment_file), 'block_size': BLOCK_SIZE})
    params.update(extra)
    return node_argv('signal_generator', params)


def plant_argv(min_subscribers=1):
    params = dict(launch_literal_parameters()['plant_simulator'])
    # min_subscribers 1, the launch file's default: the plant waits for the test's observer
    # of measurements as it waits for a recorder.
    params.update({'load_mass_kg': LOAD_MASS_KG, 'seed': 0, 'min_subscribers': min_subscribers})
    return node_argv('plant_simulator', params)


class Observer:
    """Watches the generator's status and diagnostics and the plant's measurements."""

    def __init__(self, context, silent_consumer=False, listen=True):
        self.node = rclpy.create_node('observer', namespace='/emfc', context=context)
        self.status = None
        self.statuses = []
        self.done = None
        self.generator_diagnostics = []
        self.plant_seen = False
        self.measurements = []
        self.tracker = SequenceTracker()
        self.kinds = []
        self.description = None
        self.excitation = []
        self.node.create_subscription(String, 'signal_generator/status', self._on_status,
                                      LATCHED_QOS)
        self.node.create_subscription(Bool, 'signal_generator/done',
                                      lambda m: setattr(self, 'done', m.data), LATCHED_QOS)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 50)
        if listen:
            self.listen()
        if silent_consumer:
            # A consumer of the excitation that matches like the plant (ready, as the plant
            # announces itself) and never answers.
            self.ack = self.node.create_publisher(UInt64, 'excitation/consumed', CONTROL_QOS)
            self.ready = self.node.create_publisher(String, 'excitation/ready', LATCHED_QOS)
            self.ready.publish(String(data=readiness_text(
                self.node.get_fully_qualified_name(), True)))
            self.node.create_subscription(Float64MultiArray, 'excitation',
                                          lambda m: self.excitation.append(msg_to_block(m)),
                                          BLOCK_QOS)

    def listen(self):
        """Subscribe to the plant's measurements (as a recorder does)."""
        self.node.create_subscription(Float64MultiArray, 'measurements', self._on_block,
                                      BLOCK_QOS)
        self.node.create_subscription(
            String, 'measurements/description',
            lambda m: setattr(self, 'description', msg_to_description(m)), LATCHED_QOS)

    def _on_status(self, msg):
        self.status = json.loads(msg.data)
        self.statuses.append(self.status)

    def _on_diag(self, msg):
        for status in msg.status:
            if status.name.startswith('signal_generator'):
                self.generator_diagnostics.append(status)
            elif status.name.startswith('plant_simulator'):
                self.plant_seen = True

    def _on_block(self, msg):
        block = msg_to_block(msg)
        self.kinds.append(self.tracker.observe(block.first_sample_index, block.n_samples,
                                               block.epoch))
        self.measurements.append((block.first_sample_index, block.epoch,
                                  np.array(block.samples)))

    def measured(self):
        return sum(b[2].shape[1] for b in self.measurements)


def _write_experiment(path: Path) -> Path:
    path.write_text(yaml.safe_dump({'experiment': unflatten(EXPERIMENT)}))
    return path


def _pause(executor, seconds):
    """Spin the test's nodes for ``seconds`` (the delay between two starts)."""
    ros_harness.wait_until(lambda: False, seconds, lambda: executor.spin_once(timeout_sec=0.05))


def test_the_launch_file_gives_the_parameters_this_test_uses():
    params = launch_literal_parameters()
    defaults = launch_argument_defaults()
    assert defaults['pacing'] == 'consumer' and defaults['start_gate'] == 'applier'
    assert defaults['excitation_subscribers'] == '2' and defaults['min_subscribers'] == '1'
    assert params['plant_simulator']['time_mode'] == 'owner'


@pytest.mark.slow
@pytest.mark.parametrize('first', ['signal_generator', 'plant_simulator', 'listener_last'])
def test_any_start_order_answers_the_whole_experiment(tmp_path, processes, executor,
                                                      ros_context, first):
    experiment_file = _write_experiment(tmp_path / 'experiment.yaml')
    excitation = experiment_from_config(unflatten(EXPERIMENT))
    total = excitation.total_samples
    assert total == 5000 and total > 8 * BLOCK_SIZE      # more than one window
    observer = Observer(ros_context, listen=first != 'listener_last')
    executor.add_node(observer.node)

    if first == 'listener_last':
        # Both nodes up, nothing listens to the measurements yet (a recorder started
        # late): the plant does not take the excitation, the generator holds sample 0.
        plant = processes.start(plant_argv())
        gen = processes.start(generator_argv(experiment_file))
        # The generator names what it waits for: the plant, which waits for a listener.
        assert ros_harness.spin_until(
            executor, lambda: observer.status is not None and observer.plant_seen
            and 'plant_simulator to be ready (it waits for 1 subscription(s) to '
            '/emfc/measurements' in observer.status['waiting'], START_TIMEOUT_S), \
            f'{observer.status}\n{gen.output()}\n{plant.output()}'
        _pause(executor, PAUSE_S)
        assert observer.status['next_sample_index'] == 0, observer.status
        assert observer.status['waiting'].startswith('start gate: '), observer.status
        observer.listen()
    elif first == 'signal_generator':
        gen = processes.start(generator_argv(experiment_file))
        # Autostarted, it holds sample 0 and says so while no consumer is there.
        assert ros_harness.spin_until(
            executor, lambda: observer.status is not None
            and 'the node that applies the excitation' in observer.status['waiting'],
            START_TIMEOUT_S), gen.output()
        _pause(executor, PAUSE_S)
        assert observer.status['state'] == 'running'
        assert observer.status['next_sample_index'] == 0
        assert any(s.level == DiagnosticStatus.WARN and 'sample 0 waits for the node that '
                   'applies the excitation' in s.message for s in observer.generator_diagnostics)
        plant = processes.start(plant_argv())
    else:
        plant = processes.start(plant_argv())
        assert ros_harness.spin_until(executor, lambda: observer.plant_seen,
                                      START_TIMEOUT_S), plant.output()
        _pause(executor, PAUSE_S)
        gen = processes.start(generator_argv(experiment_file))

    assert ros_harness.spin_until(
        executor, lambda: observer.measured() >= total and observer.done is True
        and observer.status is not None and observer.status['state'] == 'done'
        and observer.status['acknowledged_sample_index'] == total,
        START_TIMEOUT_S + TIMEOUT_S), \
        f'{observer.status}\n--- generator\n{gen.output()}\n--- plant\n{plant.output()}'

    # Every excitation sample answered once, from sample 0, in one epoch.
    firsts = [b[0] for b in observer.measurements]
    assert firsts == list(range(0, total, BLOCK_SIZE))
    assert observer.kinds[0] is Continuity.FIRST
    assert set(observer.kinds[1:]) == {Continuity.CONTIGUOUS}
    assert {b[1] for b in observer.measurements} == {1}
    assert observer.measured() == total
    # The plant applied exactly the experiment's setpoints (16-bit DAC of +-10 V).
    assert ros_harness.spin_until(executor, lambda: observer.description is not None,
                                  TIMEOUT_S)
    names = observer.description.channel_names
    got = np.concatenate([b[2] for b in observer.measurements], axis=1)
    expected = excitation.block(0, total)
    np.testing.assert_allclose(got[names.index('coil_setpoint_V')], expected[0],
                               atol=20.0 / 65536)
    np.testing.assert_allclose(got[names.index('load_changer_setpoint_V')], expected[1],
                               atol=20.0 / 65536)
    assert observer.status['error'] == '' and observer.status['waiting'] == ''
    assert gen.alive() and plant.alive()
    assert gen.stop() == 0, gen.output()
    assert plant.stop() == 0, plant.output()


@pytest.mark.slow
def test_a_consumer_that_never_acknowledges_is_an_error_on_status_and_diagnostics(
        tmp_path, processes, executor, ros_context):
    experiment_file = _write_experiment(tmp_path / 'experiment.yaml')
    observer = Observer(ros_context, silent_consumer=True)
    executor.add_node(observer.node)
    gen = processes.start(generator_argv(experiment_file, ack_timeout_s=0.5,
                                         consumer_timeout_s=3.0))
    assert ros_harness.spin_until(
        executor, lambda: observer.status is not None
        and observer.status['state'] == 'error', TIMEOUT_S), \
        f'{observer.status}\n{gen.output()}'
    error = observer.status['error']
    assert 'no acknowledgement' in error and 'consumer_timeout_s 3' in error
    assert observer.status['acknowledged_sample_index'] == 0
    # The first window went out, then was sent again from sample 0 before giving up.
    assert observer.status['resends'] >= 1
    window = list(range(0, 8 * BLOCK_SIZE, BLOCK_SIZE))

    def firsts():
        return [b.first_sample_index for b in observer.excitation]

    assert ros_harness.spin_until(
        executor, lambda: firsts() == window * (observer.status['resends'] + 1), TIMEOUT_S), \
        firsts()
    assert any(s['waiting'].startswith('acknowledgement') for s in observer.statuses)
    assert ros_harness.spin_until(
        executor, lambda: any(s.level == DiagnosticStatus.ERROR and s.message == error
                              for s in observer.generator_diagnostics), TIMEOUT_S)
    assert 'consumer pacing stalled' in gen.output()
    assert observer.done is False
    assert gen.alive()
    assert gen.stop() == 0, gen.output()
