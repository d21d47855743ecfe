"""
No silent loss: owner mode at full speed, joint states recorded against what was published.

The plant simulator owns time and runs the experiment many times faster than real time,
so ``joint_states`` due at 1 kHz of simulated time would come at tens of kHz of wall time,
more than a subscriber keeps up with (DDS then drops them silently: issue 13 measured 8 215
of 40 000 recorded). The plant limits them to ``max_state_wall_rate_Hz`` of wall time and
counts the rest as ``states_decimated``: every state it says it published is in the bag,
read back by an independent reader (rosbags). Three separate processes, as ``ros2 run``
starts them: plant simulator, recorder (with ``use_sim_time`` and ``/clock``, as the README
records the launch file's experiment: the bag lasts the simulated time) and consumer-paced
signal generator.
"""

import json
from pathlib import Path
import shlex

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
import rclpy
from rosbags.highlevel import AnyReader
from std_msgs.msg import String
import yaml

from emfc_ros.core.config import unflatten
from emfc_ros.core.signals import experiment_from_config
from emfc_ros.nodes.convert import LATCHED_QOS
import readme_lines
import ros_harness
from ros_harness import scaled

REPO = Path(__file__).resolve().parents[2]
START_TIMEOUT_S = scaled(180.0)
TIMEOUT_S = scaled(120.0)
RATE_HZ = 10000.0
STATE_RATE_HZ = 1000.0
EXPERIMENT = {
    'sample_rate_Hz': RATE_HZ,
    'sections': ['chirp'],
    'section.chirp.duration_s': 8.0,
    'section.chirp.coil.offset_V': 0.0,
    'section.chirp.coil.signals.c.type': 'chirp',
    'section.chirp.coil.signals.c.amplitude_V': 0.05,
    'section.chirp.coil.signals.c.f_start_Hz': 1.0,
    'section.chirp.coil.signals.c.f_stop_Hz': 200.0,
    'section.chirp.coil.signals.c.sweep_time_s': 8.0,
    'section.chirp.coil.signals.c.method': 'logarithmic',
}


def _argv(name, params):
    argv = ros_harness.node_executable(name) + ['--ros-args', '-r', '__ns:=/emfc']
    for key, value in params.items():
        text = str(value).lower() if isinstance(value, bool) else str(value)
        argv += ['-p', f'{key}:={text}']
    return argv


def readme_recorder_argv():
    """The user docs' ``ros2 run emfc_ros recorder ... use_sim_time`` line, as argv."""
    text = readme_lines.user_docs_text().replace('\\\n', '')   # shell line continuations
    lines = [line for line in text.splitlines()
             if line.startswith('ros2 run emfc_ros recorder') and 'use_sim_time:=true' in line]
    assert len(lines) == 1, lines
    argv = shlex.split(lines[0], comments=True)
    assert argv[:4] == ['ros2', 'run', 'emfc_ros', 'recorder'], argv
    return ros_harness.node_executable('recorder') + argv[4:]


class Watcher:
    """The plant's and the recorder's diagnostics and statuses, the generator's status."""

    def __init__(self, context):
        self.node = rclpy.create_node('watcher', namespace='/emfc', context=context)
        self.plant = {}
        self.generator = {}
        self.recorder = {}
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 50)
        self.node.create_subscription(
            String, 'signal_generator/status',
            lambda m: self.generator.update(json.loads(m.data)), LATCHED_QOS)
        self.node.create_subscription(
            String, 'recorder/status',
            lambda m: self.recorder.update(json.loads(m.data)), LATCHED_QOS)

    def _on_diag(self, msg):
        for status in msg.status:
            if status.name.startswith('plant_simulator'):
                self.plant = {kv.key: kv.value for kv in status.values}


@pytest.mark.slow
def test_every_published_joint_state_is_recorded_at_full_speed(tmp_path, processes,
                                                               executor, ros_context):
    experiment = tmp_path / 'experiment.yaml'
    experiment.write_text(yaml.safe_dump({'experiment': unflatten(EXPERIMENT)}))
    total = experiment_from_config(unflatten(EXPERIMENT)).total_samples
    watcher = Watcher(ros_context)
    executor.add_node(watcher.node)

    # The launch file's two nodes: the plant waits for a listener of its measurements
    # (min_subscribers 1, as sim_experiment.launch.py sets it),
    plant = processes.start(_argv('plant_simulator', {
        'time_mode': 'owner', 'load_mass_kg': 0.1274, 'state_rate_Hz': STATE_RATE_HZ,
        'publish_groups': False, 'min_subscribers': 1}))
    # and, as the launch file (start_gate applier, excitation_subscribers 2), the generator
    # waits for the plant, ready, and for the recorder's subscription to the excitation.
    generator = processes.start(_argv('signal_generator', {
        'experiment_file': str(experiment), 'pacing': 'consumer', 'block_size': 1000,
        'start_gate': 'applier', 'min_subscribers': 2}))
    assert ros_harness.spin_until(
        executor, lambda: watcher.plant and watcher.generator.get('waiting', '').startswith(
            'start gate: /emfc/plant_simulator to be ready'), START_TIMEOUT_S), \
        f'{watcher.generator}\n{generator.output()}\n{plant.output()}'
    # then the README's recorder line for that experiment, as typed (simulated time, /clock
    # recorded), in the test's folder, after the launch as the README says.
    recorder = processes.start(readme_recorder_argv(), cwd=tmp_path)
    bag = tmp_path / 'my_experiment'
    assert ros_harness.spin_until(
        executor, lambda: watcher.generator.get('state') == 'done'
        and int(watcher.plant.get('simulated_samples', 0)) == total, START_TIMEOUT_S), \
        f'{watcher.generator}\n{generator.output()}\n{plant.output()}'

    published = int(watcher.plant['states_published'])
    decimated = int(watcher.plant['states_decimated'])
    due = total // int(RATE_HZ / STATE_RATE_HZ)
    assert published + decimated == due
    # Faster than real time: the limit acted (the 8 s experiment took well under 8 s).
    assert decimated > 0 and published > 0
    # The recorder has written everything the plant published: per block one measurement
    # block, one /clock and one excitation block, the two latched descriptions, and the
    # states (its status comes once a second).
    blocks = total // 1000
    expected = 3 * blocks + 2 + published
    ros_harness.spin_until(
        executor, lambda: watcher.recorder.get('messages', 0) >= expected, TIMEOUT_S)
    assert watcher.recorder.get('dropped', 0) == 0, watcher.recorder
    assert recorder.stop() == 0, recorder.output()

    with AnyReader([Path(bag)]) as reader:
        start_ns, end_ns = reader.start_time, reader.end_time
        duration_s = (end_ns - start_ns) * 1e-9
        counts = {c.topic: c.msgcount for c in reader.connections}
        states = [c for c in reader.connections if c.topic == '/emfc/joint_states']
        stamps = []
        for connection, _, raw in reader.messages(connections=states):
            header = reader.deserialize(raw, connection.msgtype).header
            stamps.append(header.stamp.sec * 10 ** 9 + header.stamp.nanosec)
        excitation = [c for c in reader.connections if c.topic == '/emfc/excitation']
        firsts = [int(reader.deserialize(raw, c.msgtype).data[0])
                  for c, _, raw in reader.messages(connections=excitation)]
    # Every published state is in the bag, once, in order, on the 1 kHz simulated grid.
    streams = {'/emfc/joint_states': published, '/emfc/measurements': blocks,
               '/clock': blocks}
    assert {t: counts.get(t) for t in streams} == streams, \
        (json.dumps(counts), published, decimated)
    # Every excitation block is in the bag; a window the generator sent again because an
    # acknowledgement came late (a loaded machine) is there twice, which is no loss.
    assert sorted(set(firsts)) == list(range(0, total, 1000)), firsts
    # The latched descriptions (published again when an epoch starts).
    assert counts['/emfc/excitation/description'] >= 1
    assert counts['/emfc/measurements/description'] >= 1
    assert len(stamps) == published
    # Stamped with simulated time, not wall time: every receive stamp lies within the
    # experiment's 8 s of simulated time (a wall-clock stamp is decades past it). The recorder
    # stamps a message with its clock when it takes it, and rclpy's time source keeps only
    # the newest /clock: how late a recorder that falls behind the plant stamps depends on
    # the machine (a loaded CI run measured a bag of 7.7 s), so only the bounds set by the
    # simulated clock itself are checked: no stamp before 0, none beyond the last tick.
    # (The reader's end time is the last stamp + 1 ns.)
    assert 0 <= start_ns and end_ns - 1 <= total / RATE_HZ * 1e9, (start_ns, end_ns)
    assert 0 < duration_s <= total / RATE_HZ + 1e-9, duration_s
    stamps = np.array(stamps)
    assert np.all(np.diff(stamps) > 0)
    period_ns = int(1e9 / STATE_RATE_HZ)
    assert np.all(stamps % period_ns == 0)
    assert stamps[-1] < total / RATE_HZ * 1e9
    assert plant.alive() and generator.alive()
