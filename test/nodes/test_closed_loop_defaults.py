"""
The closed loop with the defaults, in separate processes, as the README and the docs show it.

``plant_simulator`` with only ``control.enabled:=true`` (simulator and controller at their
default 10 kHz) runs the loop on the excitation it receives; an inconsistent delay is an
error on its status at start; the README's closed-loop lines (``docs/closed_loop.md``, "Try
it") run as typed: ``ros2 run`` resolved as ``ros2 run`` resolves it, ``ros2 topic echo`` and
``ros2 param set`` done with rclpy as those commands do them.
"""

import importlib
from pathlib import Path
import re
import shlex

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from std_msgs.msg import Float64MultiArray, String
import yaml

from emfc_ros.nodes.convert import (BLOCK_QOS, block_to_msg, LATCHED_QOS, msg_to_block,
                                    msg_to_description)
import ros_harness
from ros_harness import scaled

REPO = Path(__file__).resolve().parents[2]
#: A fresh install compiles the numba kernels on the first start.
START_TIMEOUT_S = scaled(180.0)
TIMEOUT_S = scaled(30.0)
RATE_HZ = 10000.0           # the node's default sample rate


class Watcher:
    """Records the plant's measurement blocks, descriptions, status and weighing readings."""

    def __init__(self, context, namespace='/'):
        self.node = rclpy.create_node('watcher', namespace=namespace, context=context)
        self.blocks = []
        self.description = None
        self.statuses = []
        self.readings = []
        self.node.create_subscription(
            Float64MultiArray, 'measurements',
            lambda m: self.blocks.append(msg_to_block(m)), BLOCK_QOS)
        self.node.create_subscription(
            String, 'measurements/description',
            lambda m: setattr(self, 'description', msg_to_description(m)), LATCHED_QOS)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 50)
        self.node.create_subscription(DiagnosticArray, 'weighing/reading',
                                      lambda m: self.readings.extend(m.status), 100)

    def _on_diag(self, msg):
        self.statuses.extend(s for s in msg.status if 'plant_simulator' in s.name)

    def samples(self):
        return sum(b.n_samples for b in self.blocks)


def test_plant_simulator_closes_the_loop_with_the_default_rates(processes, executor,
                                                                ros_context):
    """Only control.enabled:=true: the loop holds the lever; weighing reads the current."""
    plant = processes.start(ros_harness.node_executable('plant_simulator') + [
        '--ros-args', '-p', 'control.enabled:=true'])
    weighing = processes.start(ros_harness.node_executable('weighing'))
    watcher = Watcher(ros_context)
    feeder = rclpy.create_node('feeder', context=ros_context)
    pub = feeder.create_publisher(Float64MultiArray, 'excitation', BLOCK_QOS)
    for node in (watcher.node, feeder):
        executor.add_node(node)
    # The weighing node subscribed too before the blocks flow (a CI run: it matched after
    # the first blocks, had less than its window and never read).
    assert ros_harness.spin_until(
        executor, lambda: pub.get_subscription_count() >= 1 and watcher.description is not None
        and feeder.count_subscribers('/measurements') >= 2, START_TIMEOUT_S), \
        plant.output() + weighing.output()
    ros_harness.spin_until(executor, lambda: False, 0.5)     # their matches settle
    names = watcher.description.channel_names
    assert 'coil_current_precise_A' in names and 'force_command_N' in names, plant.output()
    assert watcher.description.sample_rate_Hz == RATE_HZ
    block = 1000
    n_blocks = 30                           # 3 s of simulated time: 2 s of weighing window
    for k in range(n_blocks):
        pub.publish(block_to_msg(k * block, RATE_HZ, 1, np.zeros((2, block))))
        assert ros_harness.spin_until(executor, lambda: watcher.samples() >= (k + 1) * block,
                                      TIMEOUT_S), plant.output()
    got = np.concatenate([b.samples for b in watcher.blocks], axis=1)
    firsts = [b.first_sample_index for b in watcher.blocks]
    assert firsts == list(range(0, n_blocks * block, block))
    y = got[names.index('position_true_m')]
    # With 0 V the open-loop lever falls onto its stop (150 um); the loop holds it at 0.
    assert np.max(np.abs(y)) < 5e-6
    assert abs(np.mean(y[-block:])) < 1e-8
    force = got[names.index('force_command_N')]
    assert np.all(np.isfinite(force)) and np.std(force[-block:]) > 0.0   # the loop is live
    assert ros_harness.spin_until(executor, lambda: any(
        s.level == DiagnosticStatus.OK for s in watcher.statuses), TIMEOUT_S)
    assert not any(s.level == DiagnosticStatus.ERROR for s in watcher.statuses)
    # The weighing node, with its defaults, weighs the compensation current: no error.
    assert ros_harness.spin_until(executor, lambda: any(
        r.level != DiagnosticStatus.ERROR for r in watcher.readings), TIMEOUT_S), \
        weighing.output()
    good = [r for r in watcher.readings if r.level != DiagnosticStatus.ERROR]
    values = {kv.key: kv.value for kv in good[-1].values}
    assert np.isfinite(float(values['mass_kg']))
    assert plant.alive() and weighing.alive()


def test_an_inconsistent_delay_is_an_error_on_the_status_at_start(
        processes, executor, ros_context):
    plant = processes.start(ros_harness.node_executable('plant_simulator') + [
        '--ros-args', '-p', 'control.enabled:=true', '-p', 'control.delay_samples:=1.5'])
    watcher = Watcher(ros_context)
    executor.add_node(watcher.node)
    assert ros_harness.spin_until(executor, lambda: watcher.statuses, START_TIMEOUT_S), \
        plant.output()
    status = watcher.statuses[0]
    assert status.level == DiagnosticStatus.ERROR
    assert status.message.startswith('control configuration refused: control.delay_samples: '
                                     '1.5 controller samples')
    assert 'sample_rate_Hz = 20000 Hz' in status.message
    assert 'control.delay_samples = 1 or 2' in status.message
    assert 'control configuration refused' in plant.output()      # and in the log
    assert plant.alive()


def _closed_loop_lines(path: Path, heading: str):
    """The bash block after ``heading`` in a Markdown file, one command per line."""
    text = path.read_text()
    start = text.index(heading)
    block = re.search(r'```bash\n(.*?)```', text[start:], re.S)
    return [line.strip() for line in block.group(1).splitlines() if line.strip()]


def _message_class(type_name: str):
    package, _, name = type_name.split('/')
    return getattr(importlib.import_module(f'{package}.msg'), name)


class Terminals:
    """Runs the documented lines as a user types them, each in its own terminal."""

    def __init__(self, processes, executor, context):
        self.processes = processes
        self.executor = executor
        self.node = rclpy.create_node('user', context=context)
        executor.add_node(self.node)
        self.started = []
        self.echoed = {}

    def run(self, line: str) -> None:
        words = shlex.split(line)
        assert words[0] == 'ros2', line
        if words[1] == 'run':
            exe = ros_harness.resolve_ros2run(words[2], words[3])
            self.started.append(self.processes.start([str(exe)] + words[4:]))
        elif words[1:3] == ['topic', 'echo']:
            topic = words[3]
            found = {}

            def typed():
                found.update(dict(self.node.get_topic_names_and_types()))
                return topic in found
            assert ros_harness.spin_until(self.executor, typed, START_TIMEOUT_S), \
                [p.output() for p in self.started]
            self.echoed[topic] = []
            self.node.create_subscription(_message_class(found[topic][0]), topic,
                                          self.echoed[topic].append, 100)
        elif words[1:3] == ['param', 'set']:
            node, name, value = words[3:6]
            client = AsyncParameterClient(self.node, node)
            assert client.wait_for_services(TIMEOUT_S)
            # `ros2 param set` reads the value as YAML
            future = client.set_parameters([Parameter(name, value=yaml.safe_load(value))])
            assert ros_harness.spin_until(self.executor, future.done, TIMEOUT_S)
            assert future.result().results[0].successful, future.result().results[0].reason
        else:
            raise AssertionError(f'no runner for {line!r}')


def _settled(values, n=10, spread_kg=1e-4):
    """The mean of the last ``n`` values once they agree within ``spread_kg``, else None."""
    if len(values) < n:
        return None
    last = np.array(values[-n:])
    return float(np.mean(last)) if np.ptp(last) < spread_kg else None


@pytest.mark.slow
def test_the_documented_closed_loop_lines_run_as_typed(processes, executor, ros_context):
    readme = _closed_loop_lines(REPO / 'docs' / 'nodes.md', '## Closed loop and weighing')
    docs = _closed_loop_lines(REPO / 'docs' / 'closed_loop.md', '### Try it (the defaults)')
    assert readme == docs and len(docs) == 4
    user = Terminals(processes, executor, ros_context)
    descriptions = []
    user.node.create_subscription(String, '/measurements/description',
                                  lambda m: descriptions.append(msg_to_description(m)),
                                  LATCHED_QOS)
    for line in docs[:3]:
        user.run(line)
    echoed = user.echoed['/weighing/reading']

    def mass():
        # the value a user reads in the echoed reading (uncalibrated: nobody zeroed)
        values = [{kv.key: kv.value for kv in m.status[0].values} for m in echoed
                  if m.status[0].level != DiagnosticStatus.ERROR]
        return [float(v['mass_kg']) for v in values]
    # the weighing window (1 s) fills and the reading settles
    assert ros_harness.spin_until(executor, lambda: _settled(mass()) is not None,
                                  START_TIMEOUT_S), [p.output() for p in user.started]
    before = _settled(mass())
    count = len(echoed)
    user.run(docs[3])                           # 50 g on the pan
    assert ros_harness.spin_until(
        executor, lambda: len(echoed) > count + 20 and _settled(mass()) is not None,
        TIMEOUT_S)
    after = _settled(mass())
    # nominal calibration from the geometry: within 0.5 % of the 50 g put on the pan
    assert after - before == pytest.approx(0.05, rel=5e-3), (before, after)
    # the plant's description says so, with the sample the 50 g came at
    assert ros_harness.spin_until(executor, lambda: descriptions and descriptions[-1].extra[
        'load_mass_kg'] == 0.05, TIMEOUT_S)
    index, kg = descriptions[-1].extra['load_changes'][-1]
    assert kg == 0.05 and index > 0
    assert all(p.alive() for p in user.started)
