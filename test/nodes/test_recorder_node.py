"""
The recorder node over real DDS: in the test's process and as a separate process.

Every bag is opened by independent readers (rosbags, and mcap with mcap_ros2). Checks exact
read-back of published blocks, metadata (version 9, QoS, custom data), splitting, refusal
of bad outputs, recovery after SIGKILL, and a full disk reported as an error.
"""

import json
from pathlib import Path
import signal
import sys
import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, Float64MultiArray, String
from std_srvs.srv import Trigger
import yaml

from emfc_ros.core.bag import read_messages, read_metadata, read_streams, repair_bag
from emfc_ros.core.bag.errors import BagFormatError
from emfc_ros.core.blocks import Channel, StreamDescription
from emfc_ros.core.config import unflatten
from emfc_ros.core.signals import experiment_from_config
from emfc_ros.nodes.convert import BLOCK_QOS, block_to_msg, description_to_msg, LATCHED_QOS
from emfc_ros.nodes.recorder import RecorderNode
import ros_harness
from ros_harness import scaled

TIMEOUT_S = scaled(15.0)
REPO = Path(__file__).resolve().parents[2]
RATE_HZ = 10000.0
CHANNELS = (Channel('coil', 'V', 'coil setpoint'), Channel('current', 'A', 'coil current'),
            Channel('position', 'm', 'lever position'))


def signal_samples(first, n):
    """Deterministic test samples: every value tells its channel and index."""
    k = np.arange(first, first + n, dtype=np.float64)
    return np.vstack([np.sin(k * 1e-3), k * 1e-6, -k])


class Publisher:
    """A test node publishing a block stream, its description and joint states."""

    def __init__(self, context, ns='/t', block=1000):
        self.node = rclpy.create_node('publisher', namespace=ns, context=context)
        self.blocks = self.node.create_publisher(Float64MultiArray, 'excitation', BLOCK_QOS)
        self.desc = self.node.create_publisher(String, 'excitation/description', LATCHED_QOS)
        self.joint = self.node.create_publisher(JointState, 'joint_states', 10)
        self.block = block
        self.next_index = 0
        self.desc.publish(description_to_msg(StreamDescription(
            stream='excitation', sample_rate_Hz=RATE_HZ, block_size=block, channels=CHANNELS,
            epoch=1, source='/t/publisher', extra={'note': 'test'})))

    def publish(self, n_blocks=1):
        for _ in range(n_blocks):
            self.blocks.publish(block_to_msg(self.next_index, RATE_HZ, 1,
                                             signal_samples(self.next_index, self.block)))
            self.next_index += self.block

    def publish_joint(self, k):
        self.joint.publish(JointState(name=['lever'], position=[1e-6 * k], velocity=[0.0],
                                      effort=[0.5 * k]))


def call(executor, node, name, timeout_s=TIMEOUT_S):
    client = node.create_client(Trigger, name)
    assert ros_harness.spin_until(executor, client.service_is_ready, timeout_s), name
    future = client.call_async(Trigger.Request())
    assert ros_harness.spin_until(executor, future.done, timeout_s), name
    return future.result()


def spin_for(executor, seconds):
    ros_harness.wait_until(lambda: False, seconds, lambda: executor.spin_once(timeout_sec=0.02))


def written(recorder, topic):
    return recorder._writer.stats().messages.get(topic, 0) if recorder._writer else 0


def independent_read_counts(bag):
    """Message counts per topic through rosbags and through mcap + mcap_ros2."""
    typestore = get_typestore(Stores.ROS2_JAZZY)
    rosbags_counts = {}
    with AnyReader([bag], default_typestore=typestore) as reader:
        for conn, _, raw in reader.messages():
            reader.deserialize(raw, conn.msgtype)
            rosbags_counts[conn.topic] = rosbags_counts.get(conn.topic, 0) + 1
    mcap_counts = {}
    for name in read_metadata(bag)['relative_file_paths']:
        with open(bag / name, 'rb') as handle:
            reader = make_reader(handle, decoder_factories=[DecoderFactory()])
            for _, channel, _, decoded in reader.iter_decoded_messages():
                assert decoded is not None
                mcap_counts[channel.topic] = mcap_counts.get(channel.topic, 0) + 1
    return rosbags_counts, mcap_counts


def test_recorded_stream_reads_back_exactly_with_metadata(executor, ros_context, tmp_path):
    pub = Publisher(ros_context)
    executor.add_node(pub.node)
    bag = tmp_path / 'exp1'
    recorder = RecorderNode(context=ros_context, parameter_overrides=[
        Parameter('output', value=str(bag)), Parameter('discovery_period_s', value=0.05)])
    executor.add_node(recorder)
    assert ros_harness.spin_until(
        executor, lambda: {'/t/excitation', '/t/excitation/description', '/t/joint_states'}
        <= set(recorder._recorded), TIMEOUT_S)
    assert ros_harness.spin_until(
        executor, lambda: pub.blocks.get_subscription_count() >= 1
        and pub.joint.get_subscription_count() >= 1, TIMEOUT_S)
    assert '/rosout' not in recorder._recorded
    assert '/parameter_events' not in recorder._recorded
    n_blocks = 60
    for i in range(n_blocks):
        pub.publish()
        pub.publish_joint(i)
        executor.spin_once(timeout_sec=0.0)
    assert ros_harness.spin_until(
        executor, lambda: written(recorder, '/t/excitation') == n_blocks
        and written(recorder, '/t/joint_states') == n_blocks
        and '/t/publisher' in recorder._node_parameters, TIMEOUT_S)
    result = call(executor, pub.node, '/recorder/stop')
    assert result.success, result.message
    assert '0 dropped' in result.message
    assert not call(executor, pub.node, '/recorder/stop').success

    streams = read_streams(bag)
    assert set(streams) == {'/t/excitation'}
    s = streams['/t/excitation']
    assert s.first_sample_index == 0 and s.gaps == [] and s.duplicates == 0
    assert s.sample_rate_Hz == RATE_HZ and s.epoch == 1 and s.stream == 'excitation'
    assert s.channel_names == ('coil', 'current', 'position')
    assert s.channel_units == ('V', 'A', 'm')
    np.testing.assert_array_equal(s.samples, signal_samples(0, n_blocks * 1000))
    np.testing.assert_array_equal(s.sample_index, np.arange(n_blocks * 1000))
    np.testing.assert_array_equal(s.block_first_index, np.arange(0, n_blocks * 1000, 1000))
    assert np.all(np.diff(s.block_receive_time_ns) >= 0)

    joints = list(read_messages(bag, '/t/joint_states'))
    assert [m.effort[0] for _, m in joints] == [0.5 * k for k in range(n_blocks)]

    rosbags_counts, mcap_counts = independent_read_counts(bag)
    assert rosbags_counts == mcap_counts
    assert rosbags_counts['/t/excitation'] == n_blocks
    assert rosbags_counts['/t/excitation/description'] == 1

    meta = read_metadata(bag)
    assert meta['version'] == 9 and meta['storage_identifier'] == 'mcap'
    assert meta['relative_file_paths'] == ['exp1_0.mcap']
    topics = {t['topic_metadata']['name']: t for t in meta['topics_with_message_count']}
    blocks_topic = topics['/t/excitation']
    assert blocks_topic['message_count'] == n_blocks
    assert blocks_topic['topic_metadata']['type'] == 'std_msgs/msg/Float64MultiArray'
    assert blocks_topic['topic_metadata']['type_description_hash'].startswith('RIHS01_')
    [qos] = blocks_topic['topic_metadata']['offered_qos_profiles']
    # DDS discovery does not carry history and depth: rosbag2 records them the same way.
    assert (qos['reliability'], qos['durability']) == ('reliable', 'volatile')
    assert (qos['history'], qos['depth']) == ('unknown', 0)
    assert qos['deadline'] == {'sec': 9223372036, 'nsec': 854775807}
    [qos] = topics['/t/excitation/description']['topic_metadata']['offered_qos_profiles']
    assert qos['durability'] == 'transient_local'
    custom = meta['custom_data']
    assert custom['emfc_ros.version'] == '0.1.0'
    assert int(custom['emfc_ros.start_time_ns']) > 0
    experiment = yaml.safe_load(custom['emfc_ros.experiment'])
    assert experiment['stream'] == 'excitation' and experiment['extra'] == {'note': 'test'}
    params = yaml.safe_load(custom['emfc_ros.node_parameters'])
    assert params['/t/publisher']['ros__parameters']['use_sim_time'] is False
    assert '/recorder' not in params
    # The readers see the same metadata through the storage files.
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        conn = next(c for c in reader.connections if c.topic == '/t/excitation')
        assert conn.ext.offered_qos_profiles[0].reliability.name == 'RELIABLE'


def test_split_by_size_gives_contiguous_files(executor, ros_context, tmp_path):
    pub = Publisher(ros_context, block=2000)
    executor.add_node(pub.node)
    bag = tmp_path / 'split'
    recorder = RecorderNode(context=ros_context, parameter_overrides=[
        Parameter('output', value=str(bag)), Parameter('discovery_period_s', value=0.05),
        Parameter('topics', value=['/t/excitation', '/t/excitation/description']),
        Parameter('max_bag_size_B', value=200_000)])
    executor.add_node(recorder)
    assert ros_harness.spin_until(
        executor, lambda: pub.blocks.get_subscription_count() >= 1, TIMEOUT_S)
    assert '/t/joint_states' not in recorder._recorded
    n_blocks = 50  # 50 x 48 kB: 2.4 MB
    for _ in range(n_blocks):
        pub.publish()
        executor.spin_once(timeout_sec=0.0)
    assert ros_harness.spin_until(
        executor, lambda: written(recorder, '/t/excitation') == n_blocks, TIMEOUT_S)
    assert call(executor, pub.node, '/recorder/stop').success
    meta = read_metadata(bag)
    files = meta['relative_file_paths']
    assert len(files) >= 8
    assert files == [f'split_{i}.mcap' for i in range(len(files))]
    assert sorted(p.name for p in bag.glob('*.mcap')) == sorted(files)
    assert sum(f['message_count'] for f in meta['files']) == meta['message_count']
    for f in meta['files']:
        assert (bag / f['path']).stat().st_size < 200_000 + 100_000
    s = read_streams(bag)['/t/excitation']
    assert s.gaps == [] and s.channel_units == ('V', 'A', 'm')
    np.testing.assert_array_equal(s.samples, signal_samples(0, n_blocks * 2000))
    rosbags_counts, mcap_counts = independent_read_counts(bag)
    assert rosbags_counts == mcap_counts == {'/t/excitation': n_blocks,
                                             '/t/excitation/description': 1}


def test_bad_outputs_are_refused_and_the_node_keeps_running(executor, ros_context, tmp_path):
    busy = tmp_path / 'busy'
    busy.mkdir()
    (busy / 'something.txt').write_text('keep me')
    blocker = tmp_path / 'a_file'
    blocker.write_text('not a folder')
    recorder = RecorderNode(context=ros_context, parameter_overrides=[
        Parameter('output', value=str(busy)), Parameter('discovery_period_s', value=0.05)])
    executor.add_node(recorder)
    assert recorder._state == 'error' and 'not empty' in recorder._error
    assert (busy / 'something.txt').read_text() == 'keep me'
    helper = rclpy.create_node('helper', context=ros_context)
    executor.add_node(helper)
    status = []
    helper.create_subscription(String, '/recorder/status',
                               lambda m: status.append(json.loads(m.data)), LATCHED_QOS)
    diagnostics = []
    helper.create_subscription(DiagnosticArray, '/diagnostics',
                               lambda m: diagnostics.extend(m.status), 10)
    assert ros_harness.spin_until(executor, lambda: status and diagnostics, TIMEOUT_S)
    assert status[-1]['state'] == 'error' and 'not empty' in status[-1]['error']
    assert diagnostics[-1].level == b'\x02' and 'not empty' in diagnostics[-1].message

    params = AsyncParameterClient(helper, '/recorder')
    assert ros_harness.spin_until(executor, params.services_are_ready, TIMEOUT_S)
    for param, needle in ((Parameter('flush_period_s', value=-1.0), 'flush_period_s'),
                          (Parameter('max_bag_size_B', value=-5), 'max_bag_size_B'),
                          (Parameter('output', value=str(blocker / 'bag')), None)):
        future = params.set_parameters([param])
        assert ros_harness.spin_until(executor, future.done, TIMEOUT_S)
        [result] = future.result().results
        assert result.successful is (needle is None), result.reason
        if needle:
            assert needle in result.reason
    start = call(executor, helper, '/recorder/start')
    assert not start.success and 'a_file' in start.message
    good = tmp_path / 'good'
    future = params.set_parameters([Parameter('output', value=str(good))])
    assert ros_harness.spin_until(executor, future.done, TIMEOUT_S)
    start = call(executor, helper, '/recorder/start')
    assert start.success, start.message
    future = params.set_parameters([Parameter('output', value=str(tmp_path / 'other'))])
    assert ros_harness.spin_until(executor, future.done, TIMEOUT_S)
    [result] = future.result().results
    assert not result.successful and 'while recording' in result.reason
    assert call(executor, helper, '/recorder/stop').success
    assert read_metadata(good)['version'] == 9


def _kill_setup(tmp_path, processes, executor, ros_context, extra_args=(), prelude=''):
    bag = tmp_path / 'killed'
    code = (prelude + 'import runpy, sys\n'
            'sys.argv = ["recorder"] + sys.argv[1:]\n'
            'runpy.run_module("emfc_ros.nodes.recorder", run_name="__main__")\n')
    proc = processes.start(
        [sys.executable, '-c', code, '--ros-args', '-p', f'output:={bag}',
         '-p', 'flush_period_s:=0.5', '-p', 'discovery_period_s:=0.05',
         '-p', 'topics:=[/t/excitation,/t/excitation/description]', *extra_args],
        cwd=REPO, env={'ROS_LOG_DIR': str(tmp_path / 'roslog')})
    pub = Publisher(ros_context, block=500)
    executor.add_node(pub.node)
    assert ros_harness.spin_until(
        executor, lambda: pub.blocks.get_subscription_count() >= 1, TIMEOUT_S), proc.output()
    return bag, proc, pub


class FlushWatch:
    """The recorder's (messages of a topic, flushes) pairs from its diagnostics, in order."""

    def __init__(self, node, topic):
        self.key = f'messages {topic}'
        self.snapshots = []
        node.create_subscription(DiagnosticArray, '/diagnostics', self._take, 10)

    def _take(self, msg):
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            if status.name.startswith('recorder') and 'flushes' in values:
                self.snapshots.append((int(values.get(self.key, 0)), int(values['flushes'])))

    def flushed(self):
        """Messages written before a flush the recorder reported later: on disk."""
        best = 0
        for k, (messages, flushes) in enumerate(self.snapshots):
            if any(later > flushes for _, later in self.snapshots[k + 1:]):
                best = max(best, messages)
        return best


@pytest.mark.slow
def test_sigkill_keeps_every_flushed_block_and_repair_recovers(
        tmp_path, processes, executor, ros_context):
    bag, proc, pub = _kill_setup(tmp_path, processes, executor, ros_context)
    watch = FlushWatch(pub.node, '/t/excitation')
    # Wall-paced at 10 kHz in blocks of 500 (20 blocks/s) for 2.5 s,
    clock = rclpy.clock.Clock()
    start = clock.now().nanoseconds
    duration_s = 2.5
    while pub.next_index < duration_s * RATE_HZ:
        due = (clock.now().nanoseconds - start) * 1e-9 * RATE_HZ
        if pub.next_index <= due:
            pub.publish()
        executor.spin_once(timeout_sec=0.005)
    # until the recorder reports a flush after all of them (its flush period is 0.5 s),
    blocks = pub.next_index // 500
    assert ros_harness.spin_until(executor, lambda: watch.flushed() >= blocks, TIMEOUT_S), \
        (watch.snapshots, proc.output())
    # then 10 blocks more, not yet flushed, and SIGKILL.
    pub.publish(10)
    executor.spin_once(timeout_sec=0.0)
    flushed = watch.flushed()
    published = pub.next_index
    proc.kill()
    with pytest.raises(BagFormatError, match='emfc-bag-repair'):
        read_streams(bag)
    report = repair_bag(bag)
    assert report.repaired
    s = read_streams(bag)['/t/excitation']
    assert s.first_sample_index == 0 and s.gaps == []
    print(f'SIGKILL after {published / RATE_HZ:.2f} s of stream: recovered '
          f'{s.n_samples / RATE_HZ:.3f} s, {flushed * 500 / RATE_HZ:.3f} s reported flushed '
          f'(flush period 0.5 s)')
    # Every block the recorder had flushed is recovered, in order; nothing invented.
    assert flushed * 500 <= s.n_samples <= published, (flushed, report.summary())
    np.testing.assert_array_equal(s.samples, signal_samples(0, s.n_samples))
    assert s.channel_names == ('coil', 'current', 'position')
    assert read_metadata(bag)['custom_data']['emfc_ros.version'] == '0.1.0'
    rosbags_counts, mcap_counts = independent_read_counts(bag)
    assert rosbags_counts == mcap_counts
    assert rosbags_counts['/t/excitation'] == s.n_samples // 500


@pytest.mark.slow
def test_full_disk_is_a_reported_error_and_the_process_stays_up(tmp_path, processes,
                                                                executor, ros_context):
    limit_B = 3_000_000
    prelude = ('import resource, signal\n'
               f'resource.setrlimit(resource.RLIMIT_FSIZE, ({limit_B}, {limit_B}))\n'
               'signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n')
    bag, proc, pub = _kill_setup(tmp_path, processes, executor, ros_context, prelude=prelude)
    status = []
    pub.node.create_subscription(String, '/recorder/status',
                                 lambda m: status.append(json.loads(m.data)), LATCHED_QOS)
    diagnostics = []
    pub.node.create_subscription(DiagnosticArray, '/diagnostics',
                                 lambda m: diagnostics.extend(
                                     s for s in m.status if s.name.startswith('recorder')), 10)
    pub.block = 20000  # 480 kB per block: the 3 MB limit is reached within 7 blocks
    pub.publish(3)
    first_file = bag / 'killed_0.mcap'
    # Wait for a flush to put those three blocks on disk, then fill the "disk".
    assert ros_harness.spin_until(
        executor, lambda: first_file.exists() and first_file.stat().st_size > 3 * 480_000,
        TIMEOUT_S), proc.output()
    for _ in range(9):
        pub.publish()
        spin_for(executor, 0.05)
    assert ros_harness.spin_until(
        executor, lambda: status and status[-1]['state'] == 'error', TIMEOUT_S), proc.output()
    assert 'File too large' in status[-1]['error']
    assert ros_harness.spin_until(
        executor, lambda: diagnostics and diagnostics[-1].level == b'\x02', TIMEOUT_S)
    assert 'File too large' in diagnostics[-1].message
    assert proc.alive()
    stop = call(executor, pub.node, '/recorder/stop')
    assert not stop.success and 'File too large' in stop.message
    assert proc.alive()
    repair_bag(bag)
    s = read_streams(bag)['/t/excitation']
    assert s.first_sample_index == 0 and s.gaps == [] and s.n_samples >= 3 * 20000
    np.testing.assert_array_equal(s.samples, signal_samples(0, s.n_samples))
    assert 'File too large' in proc.output()
    assert proc.stop() == 0, proc.output()
    assert proc.proc.returncode in (0, -signal.SIGINT)


SMALL_EXPERIMENT = {
    'sample_rate_Hz': 10000.0,
    'sections': ['a', 'b'],
    'section.a.duration_s': 0.05,
    'section.a.coil.signals.s.type': 'sine',
    'section.a.coil.signals.s.amplitude_V': 0.5,
    'section.a.coil.signals.s.frequency_Hz': 100.0,
    'section.b.duration_s': 0.0333,
    'section.b.load_changer.offset_V': 0.25,
    'section.b.load_changer.signals.c.type': 'constant',
    'section.b.load_changer.signals.c.value_V': 0.1,
}


@pytest.mark.slow
def test_records_the_real_signal_generator_with_its_experiment(
        tmp_path, processes, executor, ros_context):
    config = unflatten(SMALL_EXPERIMENT)
    experiment_file = tmp_path / 'experiment.yaml'
    experiment_file.write_text(yaml.safe_dump({'experiment': config}))
    proc = processes.start(
        [sys.executable, '-m', 'emfc_ros.nodes.signal_generator', '--ros-args',
         '-r', '__ns:=/emfc', '-p', f'experiment_file:={experiment_file}',
         '-p', 'pacing:=wall', '-p', 'autostart:=false', '-p', 'block_size:=100'],
        cwd=REPO, env={'ROS_LOG_DIR': str(tmp_path / 'roslog')})
    bag = tmp_path / 'generator'
    recorder = RecorderNode(context=ros_context, namespace='/emfc', parameter_overrides=[
        Parameter('output', value=str(bag)), Parameter('discovery_period_s', value=0.05),
        Parameter('topics', value=['excitation', 'excitation/description',
                                   'signal_generator/done'])])
    executor.add_node(recorder)
    done = []
    recorder.create_subscription(Bool, '/emfc/signal_generator/done',
                                 lambda m: done.append(m.data), LATCHED_QOS)
    assert ros_harness.spin_until(
        executor, lambda: {'/emfc/excitation', '/emfc/excitation/description',
                           '/emfc/signal_generator/done'} <= set(recorder._recorded)
        and '/emfc/signal_generator' in recorder._node_parameters,
        TIMEOUT_S), proc.output()
    start = call(executor, recorder, '/emfc/signal_generator/start')
    assert start.success, start.message
    assert ros_harness.spin_until(
        executor, lambda: done and done[-1] and written(recorder, '/emfc/excitation') == 9,
        TIMEOUT_S), proc.output()
    stop = call(executor, recorder, '/emfc/recorder/stop')
    assert stop.success, stop.message

    expected = experiment_from_config(config)
    s = read_streams(bag)['/emfc/excitation']
    assert s.first_sample_index == 0 and s.gaps == [] and s.epoch == 1
    assert s.channel_names == ('coil', 'load_changer') and s.channel_units == ('V', 'V')
    assert s.sample_rate_Hz == 10000.0
    np.testing.assert_array_equal(s.samples, expected.block(0, expected.total_samples))
    custom = read_metadata(bag)['custom_data']
    described = yaml.safe_load(custom['emfc_ros.experiment'])
    assert [x['name'] for x in described['extra']['sections']] == ['a', 'b']
    assert described['start_time_ns'] > 0  # the description published at start
    params = yaml.safe_load(custom['emfc_ros.node_parameters'])
    generator = params['/emfc/signal_generator']['ros__parameters']
    assert generator['block_size'] == 100 and generator['pacing'] == 'wall'
    assert generator['experiment_file'] == str(experiment_file)
    rosbags_counts, mcap_counts = independent_read_counts(bag)
    assert rosbags_counts == mcap_counts
    assert proc.stop() == 0, proc.output()


def test_use_sim_time_stamps_messages_with_the_simulated_clock(executor, ros_context,
                                                               tmp_path):
    pub = Publisher(ros_context)
    clock_pub = pub.node.create_publisher(Clock, '/clock', 10)
    executor.add_node(pub.node)
    bag = tmp_path / 'sim'
    recorder = RecorderNode(context=ros_context, parameter_overrides=[
        Parameter('output', value=str(bag)), Parameter('discovery_period_s', value=0.05),
        Parameter('use_sim_time', value=True), Parameter('topics', value=['/t/joint_states'])])
    executor.add_node(recorder)
    sim_s = 1000

    def clock_reached():
        clock_pub.publish(Clock(clock=Time(sec=sim_s)))
        return recorder.get_clock().now().nanoseconds == sim_s * 10 ** 9

    assert ros_harness.spin_until(executor, clock_reached, TIMEOUT_S)
    assert ros_harness.spin_until(
        executor, lambda: pub.joint.get_subscription_count() >= 1, TIMEOUT_S)
    for k in range(3):
        pub.publish_joint(k)
    assert ros_harness.spin_until(
        executor, lambda: written(recorder, '/t/joint_states') == 3, TIMEOUT_S)
    assert call(executor, pub.node, '/recorder/stop').success
    stamps = [t for t, _ in read_messages(bag, '/t/joint_states')]
    assert stamps == [sim_s * 10 ** 9] * 3
    meta = read_metadata(bag)
    assert meta['starting_time']['nanoseconds_since_epoch'] == sim_s * 10 ** 9
    # The custom data say which clock stamped the bag and keep the wall start time.
    assert meta['custom_data']['emfc_ros.clock'] == 'simulated'
    assert abs(int(meta['custom_data']['emfc_ros.start_time_ns']) - time.time_ns()) < 600e9


def test_invalid_start_up_parameters_leave_the_node_in_error(executor, ros_context, tmp_path):
    bad = RecorderNode(context=ros_context, parameter_overrides=[
        Parameter('output', value=str(tmp_path / 'bad')),
        Parameter('flush_period_s', value=-1.0)])
    executor.add_node(bad)
    helper = rclpy.create_node('helper', context=ros_context)
    executor.add_node(helper)
    assert bad._state == 'error' and 'flush_period_s' in bad._error
    assert not (tmp_path / 'bad').exists()
    start = call(executor, helper, '/recorder/start')
    assert not start.success and 'flush_period_s' in start.message
    # An integer for a float parameter is fine (`-p max_bag_duration_s:=5`).
    good = RecorderNode(context=ros_context, namespace='/other', parameter_overrides=[
        Parameter('output', value=str(tmp_path / 'good')),
        Parameter('max_bag_duration_s', value=5)])
    executor.add_node(good)
    assert good._state == 'recording', good._error
    assert good._writer.writer.max_bag_duration_ns == 5 * 10 ** 9
    # Let the parameter fetches of the other nodes finish before stopping.
    assert ros_harness.spin_until(
        executor, lambda: {'/recorder', '/helper'} <= set(good._node_parameters)
        and not good._fetches, TIMEOUT_S)
    assert call(executor, helper, '/other/recorder/stop').success


def test_a_widened_fault_replaces_its_earlier_record_in_the_bag(executor, ros_context, tmp_path):
    """The bridge widens a fault (health estimate, then the driver's exact index): one record."""
    from emfc_ros.core.device.faults import Fault
    pub = Publisher(ros_context)
    executor.add_node(pub.node)
    bag = tmp_path / 'faults'
    recorder = RecorderNode(context=ros_context, parameter_overrides=[
        Parameter('output', value=str(bag)), Parameter('discovery_period_s', value=0.05)])
    executor.add_node(recorder)
    measured = pub.node.create_publisher(String, 'measurements/description', LATCHED_QOS)
    assert ros_harness.spin_until(
        executor, lambda: '/t/measurements/description' in recorder._recorded
        and measured.get_subscription_count() >= 1, TIMEOUT_S)
    estimate = Fault('device_underrun', 9000, 500, 'ran out of setpoints', False, 1)
    widened = Fault('device_underrun', 9250, None,
                    'ran out of setpoints; NI-DAQmx error -200290', True, 1)
    gap = Fault('device_setpoint_gap', 100, 3, 'gap', True, 1)
    for faults in ([estimate], [widened, gap]):
        measured.publish(description_to_msg(StreamDescription(
            stream='measurements', sample_rate_Hz=RATE_HZ, block_size=1000, channels=CHANNELS,
            epoch=1, source='/t/publisher',
            extra={'faults': [f.to_dict() for f in faults]})))
        assert ros_harness.spin_until(
            executor, lambda: recorder.recorded_faults() == len(faults), TIMEOUT_S)
    assert ros_harness.spin_until(
        executor, lambda: recorder.recorded_faults() == 2
        and any(r.get('exact') for r in recorder._faults.values()), TIMEOUT_S)
    assert call(executor, pub.node, '/recorder/stop').success
    faults = yaml.safe_load(read_metadata(bag)['custom_data']['emfc_ros.faults'])
    assert [(f['kind'], f['device_index'], f['exact']) for f in faults] == [
        ('device_underrun', 9250, True), ('device_setpoint_gap', 100, True)]
    assert faults[0]['topic'] == '/t/measurements/description'
