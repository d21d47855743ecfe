"""
A subscriber that is not scheduled for a moment, over real DDS.

Lost blocks are reported, and the flow control of the nodes that own time loses none. The
recorder runs as a separate process and is stopped (SIGSTOP) while a test publisher
sends more blocks than a block writer's history holds (BLOCK_QOS, depth 100).
"""

import os
import signal
import subprocess
import sys

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray
from test_recorder_node import Publisher, REPO, signal_samples
import yaml

from emfc_ros.core.bag import read_metadata, read_streams
from emfc_ros.nodes.convert import BLOCK_QOS, block_to_msg
from emfc_ros.nodes.flow_control import (AckFlowControl, BATCH_BYTES, EVERY_BLOCKS,
                                         MAX_BLOCKS)
from emfc_ros.nodes.plant_simulator import PlantSimulatorNode
import ros_harness
from ros_harness import scaled

TIMEOUT_S = scaled(15.0)
BLOCK = 1000
#: Sample data of one block (3 channels of float64) [B].
BLOCK_BYTES = BLOCK * 3 * 8
#: Blocks published while the recorder is stopped: three times the writer's history.
STALLED_BLOCKS = 300


class Diagnostics:
    """The last diagnostics (level, message, values) of the status whose name holds ``part``."""

    def __init__(self, node, part='recorder'):
        self.part = part
        self.level = None
        self.message = ''
        self.values = {}
        node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 100)

    def _on_diag(self, msg):
        for status in msg.status:
            if self.part in status.name:
                self.message = status.message
                self.level = status.level
                self.values = {kv.key: kv.value for kv in status.values}


def _start_recorder(tmp_path, processes, bag, topics):
    code = ('import runpy, sys\n'
            'sys.argv = ["recorder"] + sys.argv[1:]\n'
            'runpy.run_module("emfc_ros.nodes.recorder", run_name="__main__")\n')
    return processes.start(
        [sys.executable, '-c', code, '--ros-args', '-p', f'output:={bag}',
         '-p', 'discovery_period_s:=0.05', '-p', f'topics:=[{topics}]'],
        cwd=REPO, env={'ROS_LOG_DIR': str(tmp_path / 'roslog')})


def _stalled_run(tmp_path, processes, executor, ros_context, flow_control):
    """
    Record 5 blocks, stop the recorder for 1 s while 300 more are published, let it go on.

    Returns the recorder's last diagnostics (level, values), the recorded stream, the bag's
    metadata, the blocks published and the flow control of the publisher.
    """
    bag = tmp_path / 'stalled'
    proc = _start_recorder(tmp_path, processes, bag, '/t/excitation,/t/excitation/description')
    pub = Publisher(ros_context, block=BLOCK)
    executor.add_node(pub.node)
    diag = Diagnostics(pub.node)
    flow = AckFlowControl(pub.blocks if flow_control else None, timeout_s=scaled(5.0))
    assert ros_harness.spin_until(
        executor, lambda: pub.blocks.get_subscription_count() >= 1, TIMEOUT_S), proc.output()
    pub.publish(5)
    assert ros_harness.spin_until(
        executor, lambda: diag.values.get('messages /t/excitation') == '5', TIMEOUT_S), \
        (diag.values, proc.output())
    os.kill(proc.pid, signal.SIGSTOP)
    # With flow control the recorder goes on after 1 s, whatever the publisher does meanwhile
    # (from another process: a wait for acknowledgements holds this one's GIL); without, it
    # goes on once all the blocks were published, so that they overran the writer's history
    # (100) however fast this machine publishes.
    resume = subprocess.Popen(['sh', '-c', f'sleep 1; kill -CONT {proc.pid}']) \
        if flow_control else None
    try:
        for _ in range(STALLED_BLOCKS):
            pub.publish(1)
            flow.published(BLOCK_BYTES)
    finally:
        if resume is None:
            os.kill(proc.pid, signal.SIGCONT)
        else:
            assert resume.wait(timeout=TIMEOUT_S) == 0
    published = 5 + STALLED_BLOCKS
    assert ros_harness.spin_until(
        executor, lambda: int(diag.values.get('messages /t/excitation', 0))
        + int(diag.values.get('lost /t/excitation', 0)) >= published, TIMEOUT_S), \
        (diag.values, proc.output())
    level, values = diag.level, dict(diag.values)
    assert proc.stop() == 0, proc.output()
    stream = read_streams(bag, on_gap='nan')['/t/excitation']
    return level, values, stream, read_metadata(bag), published, flow


@pytest.mark.slow
def test_a_stalled_recorder_reports_the_blocks_it_lost(tmp_path, processes, executor,
                                                       ros_context):
    level, values, stream, metadata, published, flow = _stalled_run(
        tmp_path, processes, executor, ros_context, flow_control=False)
    lost = int(values['lost /t/excitation'])
    print(f'stalled 1 s, no flow control: {values["messages /t/excitation"]} of {published} '
          f'blocks recorded, {lost} reported lost')
    # The writer's history (100) overran: the blocks are gone, and the recorder says so in
    # its diagnostics (ERROR) and in the bag.
    assert flow.waits == 0 and lost > 0
    assert level == DiagnosticStatus.ERROR, values
    assert int(values['lost_messages']) == lost
    recorded = int(values['messages /t/excitation'])
    assert recorded + lost == published
    assert stream.gaps != [] and stream.first_sample_index == 0
    custom = yaml.safe_load(metadata['custom_data']['emfc_ros.lost_messages'])
    assert custom == {'/t/excitation': lost}


@pytest.mark.slow
def test_flow_control_waits_for_a_stalled_subscriber_and_loses_nothing(
        tmp_path, processes, executor, ros_context):
    level, values, stream, metadata, published, gate = _stalled_run(
        tmp_path, processes, executor, ros_context, flow_control=True)
    print(f'stalled 1 s, flow control: {stream.n_samples // BLOCK} of '
          f'{published} blocks recorded; {gate.counters()}')
    batch = max(EVERY_BLOCKS, -(-BATCH_BYTES // BLOCK_BYTES))
    assert gate.waits == STALLED_BLOCKS // batch and gate.timeouts == 0
    assert stream.first_sample_index == 0 and stream.gaps == []
    assert stream.n_samples == published * BLOCK
    assert (stream.samples == signal_samples(0, stream.n_samples)).all()
    assert 'lost_messages' not in values and 'lost /t/excitation' not in values
    assert level == DiagnosticStatus.OK, values
    assert 'emfc_ros.lost_messages' not in metadata['custom_data']


@pytest.mark.parametrize('block_bytes, waits, skipped', [
    (80000, 5, 0),          # the plant's default measurements: a wait every 20 blocks
    (BATCH_BYTES // 30, 3, 0),      # a wait every 30 blocks
    (1000, 0, 2),           # too small to be acknowledged at once: every 50 counted
])
def test_batches_are_large_enough_for_a_prompt_acknowledgement(
        ros_context, block_bytes, waits, skipped):
    node = rclpy.create_node('flow_publisher', namespace='/t_batches', context=ros_context)
    try:
        publisher = node.create_publisher(Float64MultiArray, 'blocks', BLOCK_QOS)
        flow = AckFlowControl(publisher)
        for _ in range(100):
            flow.published(block_bytes)
        # No subscription: every wait returns at once, acknowledged.
        assert (flow.waits, flow.skipped, flow.timeouts) == (waits, skipped, 0)
        assert MAX_BLOCKS * 2 <= BLOCK_QOS.depth
    finally:
        node.destroy_node()


@pytest.mark.slow
def test_the_owner_plant_waits_for_a_stalled_recorder_and_says_so(
        tmp_path, processes, executor, ros_context):
    # The plant in owner mode (in this process), fed 100 blocks at once, while the recorder
    # (another process) is stopped until the first wait ended at its 2 s bound (counted,
    # WARN); the waits return when the recorder goes on, and the recorder loses nothing.
    bag = tmp_path / 'plant'
    proc = _start_recorder(tmp_path, processes, bag, '/flow/measurements')
    plant = PlantSimulatorNode(context=ros_context, namespace='/flow', parameter_overrides=[
        Parameter('time_mode', value='owner'), Parameter('publish_groups', value=False)])
    feeder = rclpy.create_node('feeder', namespace='/flow', context=ros_context)
    pub = feeder.create_publisher(Float64MultiArray, 'excitation', BLOCK_QOS)
    plant_diag = Diagnostics(feeder, 'plant_simulator')
    recorder_diag = Diagnostics(feeder, 'recorder')
    for node in (plant, feeder):
        executor.add_node(node)
    # The recorder matched on the plant's writer itself, not only in the graph: stopped
    # before the writer matched it, it was not waited for (every wait returned at once, the
    # recorder took the blocks from the writer's history later; a CI run saw it).
    measurements = plant._pub['measurements']
    assert ros_harness.spin_until(
        executor, lambda: pub.get_subscription_count() >= 1
        and measurements.get_subscription_count() >= 1, TIMEOUT_S), proc.output()
    hold = plant._session.sim.hold_setpoints_V[:, None]
    n_blocks = 100
    os.kill(proc.pid, signal.SIGSTOP)
    # The recorder stays stopped until the plant reports a wait that ended at its bound
    # (then the plant is not in a wait: this process runs), however long the plant took to
    # get there; the history (100) holds all the blocks.
    try:
        for k in range(n_blocks):
            pub.publish(block_to_msg(k * 1000, 10000.0, 1, np.repeat(hold, 1000, axis=1)))
        assert ros_harness.spin_until(
            executor, lambda: int(plant_diag.values.get('ack_timeouts', 0)) >= 1,
            TIMEOUT_S + scaled(10.0)), (plant_diag.values, recorder_diag.values, proc.output())
    finally:
        os.kill(proc.pid, signal.SIGCONT)
    assert ros_harness.spin_until(
        executor, lambda: int(plant_diag.values.get('blocks_out', 0)) >= n_blocks
        and int(recorder_diag.values.get('messages /flow/measurements', 0)) >= n_blocks,
        TIMEOUT_S + scaled(10.0)), (plant_diag.values, recorder_diag.values, proc.output())
    values = plant_diag.values
    print('plant flow control:', {k: v for k, v in values.items() if k.startswith('ack')})
    assert int(values['ack_waits']) == n_blocks // EVERY_BLOCKS
    assert int(values['ack_timeouts']) >= 1
    assert plant_diag.level == DiagnosticStatus.WARN and 'acknowledgements' in \
        plant_diag.message, plant_diag.message
    assert 'lost_messages' not in recorder_diag.values
    assert proc.stop() == 0, proc.output()
    stream = read_streams(bag)['/flow/measurements']
    assert stream.first_sample_index == 0 and stream.n_samples == n_blocks * 1000
    assert stream.gaps == []
