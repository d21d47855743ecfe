"""
The signal_generator node over real DDS: in the test's process and as a separate process.

Checks contiguous sample indices, the exact samples, the latched description, services,
and that bad parameters are refused with a reason while the node keeps running.
"""

import json
from pathlib import Path

import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from std_msgs.msg import Bool, Float64MultiArray, String, UInt64
from std_srvs.srv import Trigger
import yaml

from emfc_ros.core.blocks import Continuity, SequenceTracker
from emfc_ros.core.config import unflatten
from emfc_ros.core.signals import experiment_from_config
from emfc_ros.core.start_gate import readiness_text
from emfc_ros.nodes.convert import (
    BLOCK_QOS, CONTROL_QOS, LATCHED_QOS, msg_to_block, msg_to_description)
from emfc_ros.nodes.signal_generator import SignalGeneratorNode
import ros_harness
from ros_harness import scaled

TIMEOUT_S = scaled(15.0)

SMALL = {
    'sample_rate_Hz': 10000.0,
    'sections': ['a', 'b'],
    'section.a.duration_s': 0.05,
    'section.a.coil.signals.s.type': 'sine',
    'section.a.coil.signals.s.amplitude_V': 0.5,
    'section.a.coil.signals.s.frequency_Hz': 100.0,
    'section.b.duration_s': 0.0333,
    'section.b.load_changer.offset_V': 0.25,
    'section.b.load_changer.signals.c.type': 'chirp',
    'section.b.load_changer.signals.c.amplitude_V': 0.1,
    'section.b.load_changer.signals.c.f_start_Hz': 10.0,
    'section.b.load_changer.signals.c.f_stop_Hz': 1000.0,
    'section.b.load_changer.signals.c.sweep_time_s': 0.0333,
    'section.b.load_changer.signals.c.method': 'linear',
}


def small_overrides(**extra):
    params = [Parameter(f'experiment.{k}', value=v) for k, v in SMALL.items()]
    params += [Parameter(k, value=v) for k, v in extra.items()]
    return params


def expected_samples():
    experiment = experiment_from_config(unflatten(SMALL))
    return experiment.block(0, experiment.total_samples)


class Listener:
    """A test node that records the generator's output and acknowledges blocks."""

    def __init__(self, context, ns='', acknowledge=True):
        self.node = rclpy.create_node('listener', namespace=ns, context=context)
        self.blocks = []
        self.description = None
        self.status = None
        self.done = None
        self.tracker = SequenceTracker()
        self.kinds = []
        self.acknowledge = acknowledge
        self.ack = self.node.create_publisher(UInt64, 'excitation/consumed', CONTROL_QOS)
        # A consumer of its own announces itself ready, as the plant and the bridge do (the
        # generator's start gate with consumer pacing waits for it).
        self.ready = self.node.create_publisher(String, 'excitation/ready', LATCHED_QOS)
        self.ready.publish(String(data=readiness_text(self.node.get_fully_qualified_name(),
                                                      True)))
        self.node.create_subscription(Float64MultiArray, 'excitation', self._on_block,
                                      BLOCK_QOS)
        self.node.create_subscription(String, 'excitation/description', self._on_desc,
                                      LATCHED_QOS)
        self.node.create_subscription(String, 'signal_generator/status', self._on_status,
                                      LATCHED_QOS)
        self.node.create_subscription(Bool, 'signal_generator/done', self._on_done,
                                      LATCHED_QOS)
        self.clients = {name: self.node.create_client(Trigger, f'signal_generator/{name}')
                        for name in ('arm', 'start', 'stop')}

    def _on_block(self, msg):
        block = msg_to_block(msg, expected_channels=2)
        self.kinds.append(self.tracker.observe(block.first_sample_index, block.n_samples,
                                               block.epoch))
        self.blocks.append(block.__class__(block.first_sample_index, block.sample_rate_Hz,
                                           block.epoch, np.array(block.samples)))
        if self.acknowledge:
            self.ack.publish(UInt64(data=block.end_index))

    def _on_desc(self, msg):
        self.description = msg_to_description(msg)

    def _on_status(self, msg):
        self.status = json.loads(msg.data)

    def _on_done(self, msg):
        self.done = msg.data

    def received(self, epoch=None):
        return sum(b.n_samples for b in self.blocks if epoch is None or b.epoch == epoch)

    def call(self, executor, name, timeout_s=TIMEOUT_S):
        client = self.clients[name]
        assert ros_harness.spin_until(executor, client.service_is_ready, timeout_s), name
        future = client.call_async(Trigger.Request())
        assert ros_harness.spin_until(executor, future.done, timeout_s), name
        return future.result()


def test_in_process_consumer_paced_stream_is_exact_and_contiguous(executor, ros_context):
    gen = SignalGeneratorNode(context=ros_context, parameter_overrides=small_overrides(
        pacing='consumer', block_size=128, window_blocks=2, autostart=False))
    listener = Listener(ros_context)
    executor.add_node(gen)
    executor.add_node(listener.node)
    assert ros_harness.spin_until(
        executor, lambda: gen.count_subscribers('excitation') >= 1, TIMEOUT_S)
    assert listener.call(executor, 'start').success
    expected = expected_samples()
    total = expected.shape[1]
    assert total == 833
    # Topics are not ordered with respect to each other: wait for `done` and the samples.
    assert ros_harness.spin_until(
        executor, lambda: listener.done is True and listener.received() == total
        and listener.description is not None and listener.status is not None
        and listener.status['state'] == 'done', TIMEOUT_S)

    firsts = [b.first_sample_index for b in listener.blocks]
    assert firsts == list(range(0, total, 128))
    assert [b.n_samples for b in listener.blocks][-1] == total % 128
    assert listener.kinds[0] is Continuity.FIRST
    assert set(listener.kinds[1:]) == {Continuity.CONTIGUOUS}
    assert {b.epoch for b in listener.blocks} == {1}
    got = np.concatenate([b.samples for b in listener.blocks], axis=1)
    np.testing.assert_array_equal(got, expected)

    d = listener.description
    assert d.stream == 'excitation'
    assert d.sample_rate_Hz == 10000.0 and d.block_size == 128 and d.epoch == 1
    assert d.channel_names == ('coil', 'load_changer')
    assert [c.unit for c in d.channels] == ['V', 'V']
    assert d.total_samples == total
    assert d.extra['sections'] == [
        {'name': 'a', 'first_sample_index': 0, 'n_samples': 500},
        {'name': 'b', 'first_sample_index': 500, 'n_samples': 333}]


def test_consumer_pacing_holds_back_without_acknowledgements(executor, ros_context):
    gen = SignalGeneratorNode(context=ros_context, parameter_overrides=small_overrides(
        pacing='consumer', block_size=100, window_blocks=3, autostart=False,
        ack_timeout_s=30.0, consumer_timeout_s=60.0))       # no re-send in this test
    listener = Listener(ros_context, acknowledge=False)
    executor.add_node(gen)
    executor.add_node(listener.node)
    assert ros_harness.spin_until(
        executor, lambda: gen.count_subscribers('excitation') >= 1, TIMEOUT_S)
    assert listener.call(executor, 'start').success
    assert ros_harness.spin_until(executor, lambda: len(listener.blocks) >= 3, TIMEOUT_S)
    # Spin on for a while: no acknowledgement, so the window stays at 3 blocks.
    ros_harness.wait_until(lambda: False, 0.5, lambda: executor.spin_once(timeout_sec=0.02))
    assert len(listener.blocks) == 3
    # Stop, re-arm (new epoch, back to sample 0) and start again with acknowledgements.
    assert listener.call(executor, 'stop').success
    assert not listener.call(executor, 'stop').success
    arm = listener.call(executor, 'arm')
    assert arm.success and 'epoch 2' in arm.message
    listener.acknowledge = True
    assert listener.call(executor, 'start').success
    assert ros_harness.spin_until(
        executor, lambda: listener.done is True and listener.received(2) == 833, TIMEOUT_S)
    epoch2 = [b for b in listener.blocks if b.epoch == 2]
    assert epoch2[0].first_sample_index == 0
    assert listener.kinds[3] is Continuity.RESTART
    np.testing.assert_array_equal(np.concatenate([b.samples for b in epoch2], axis=1),
                                  expected_samples())


class LossyListener(Listener):
    """
    A listener whose first blocks or first acknowledgements are lost.

    ``miss_blocks`` blocks are ignored as if the subscription had not matched yet;
    ``lose_acks`` acknowledgements are not published as if the generator's subscription
    had not matched the acknowledging publisher yet.
    """

    def __init__(self, context, miss_blocks=0, lose_acks=0):
        super().__init__(context)
        self.miss_blocks = miss_blocks
        self.lose_acks = lose_acks

    def _on_block(self, msg):
        if self.miss_blocks:
            self.miss_blocks -= 1
            return
        if self.lose_acks:
            self.lose_acks -= 1
            self.acknowledge = False
            super()._on_block(msg)
            self.acknowledge = True
            return
        super()._on_block(msg)


@pytest.mark.parametrize('loss', [{'miss_blocks': 3}, {'lose_acks': 3}],
                         ids=['first_window_missed', 'first_acknowledgements_lost'])
def test_consumer_pacing_sends_a_lost_window_again(executor, ros_context, loss):
    gen = SignalGeneratorNode(context=ros_context, parameter_overrides=small_overrides(
        pacing='consumer', block_size=100, window_blocks=3, autostart=False,
        ack_timeout_s=0.2))
    listener = LossyListener(ros_context, **loss)
    executor.add_node(gen)
    executor.add_node(listener.node)
    assert listener.call(executor, 'start').success
    assert ros_harness.spin_until(
        executor, lambda: listener.status is not None and listener.status['state'] == 'done'
        and listener.status['acknowledged_sample_index'] == 833, TIMEOUT_S), listener.status
    assert listener.status['resends'] >= 1 and listener.status['error'] == ''
    # The listener has the whole epoch from sample 0, each sample once.
    kept = [b for b, k in zip(listener.blocks, listener.kinds)
            if k in (Continuity.FIRST, Continuity.CONTIGUOUS)]
    assert listener.kinds[0] is Continuity.FIRST and kept[0].first_sample_index == 0
    np.testing.assert_array_equal(np.concatenate([b.samples for b in kept], axis=1),
                                  expected_samples())
    assert set(listener.kinds) - {Continuity.FIRST, Continuity.CONTIGUOUS} <= {
        Continuity.DUPLICATE}
    if 'lose_acks' in loss:
        assert listener.kinds.count(Continuity.DUPLICATE) >= 3


def test_a_subscriber_that_does_not_acknowledge_does_not_start_the_stream(
        executor, ros_context):
    # A recorder (here: a plain subscription) up before the consumer must not make the
    # generator send its first window into the void: sample 0 waits for the applier.
    gen = SignalGeneratorNode(context=ros_context, parameter_overrides=small_overrides(
        pacing='consumer', block_size=100, window_blocks=3, autostart=True))
    recorder = rclpy.create_node('recorder_like', context=ros_context)
    recorded = []
    recorder.create_subscription(Float64MultiArray, 'excitation',
                                 lambda m: recorded.append(msg_to_block(m)), BLOCK_QOS)
    statuses = []
    recorder.create_subscription(String, 'signal_generator/status',
                                 lambda m: statuses.append(json.loads(m.data)), LATCHED_QOS)
    executor.add_node(gen)
    executor.add_node(recorder)
    assert ros_harness.spin_until(
        executor, lambda: gen.count_subscribers('excitation') >= 1 and statuses
        and 'the node that applies the excitation' in statuses[-1]['waiting'], TIMEOUT_S), \
        statuses
    ros_harness.wait_until(lambda: False, 0.5, lambda: executor.spin_once(timeout_sec=0.02))
    assert recorded == [] and statuses[-1]['next_sample_index'] == 0
    assert statuses[-1]['state'] == 'running'
    listener = Listener(ros_context)
    executor.add_node(listener.node)
    assert ros_harness.spin_until(
        executor, lambda: listener.done is True and listener.received() == 833
        and sum(b.n_samples for b in recorded) == 833, TIMEOUT_S)
    assert recorded[0].first_sample_index == 0 and listener.kinds[0] is Continuity.FIRST
    assert statuses[-1]['resends'] == 0


def _set(executor, client, params):
    assert ros_harness.spin_until(executor, lambda: client.services_are_ready(), TIMEOUT_S)
    future = client.set_parameters(params)
    assert ros_harness.spin_until(executor, future.done, TIMEOUT_S)
    return future.result().results


def _write_experiment(path: Path, **changes) -> Path:
    cfg = unflatten(dict(SMALL, **changes))
    path.write_text(yaml.safe_dump({'experiment': cfg}))
    return path


@pytest.mark.slow
def test_separate_process_wall_paced_refuses_bad_parameters(tmp_path, processes, executor,
                                                            ros_context):
    good = _write_experiment(tmp_path / 'good.yaml')
    proc = processes.start(ros_harness.node_executable('signal_generator') + [
        '--ros-args', '-r', '__ns:=/emfc', '-p', f'experiment_file:={good}',
        '-p', 'block_size:=250', '-p', 'pacing:=wall', '-p', 'autostart:=false'])
    listener = Listener(ros_context, ns='/emfc')
    executor.add_node(listener.node)
    params = AsyncParameterClient(listener.node, '/emfc/signal_generator')
    assert ros_harness.spin_until(executor, lambda: listener.status is not None, TIMEOUT_S), \
        proc.output()
    assert listener.status['state'] == 'armed'

    refused = {
        'block_size': Parameter('block_size', value=0),
        'pacing': Parameter('pacing', value='sometimes'),
        'duration_s': Parameter('experiment_file', value=str(_write_experiment(
            tmp_path / 'bad.yaml', **{'section.a.duration_s': -1.0}))),
        'No such file': Parameter('experiment_file', value=str(tmp_path / 'missing.yaml')),
        'ack_timeout_s out of range': Parameter('ack_timeout_s', value=0.0),
        'consumer_timeout_s out of range': Parameter('consumer_timeout_s', value=-1.0),
        'at least ack_timeout_s': Parameter('consumer_timeout_s', value=0.5),
    }
    for needle, param in refused.items():
        [result] = _set(executor, params, [param])
        assert not result.successful, param.name
        assert needle in result.reason, result.reason
    [ok] = _set(executor, params, [Parameter('block_size', value=200)])
    assert ok.successful
    assert proc.alive()

    assert ros_harness.spin_until(
        executor, lambda: listener.node.count_publishers('excitation') >= 1, TIMEOUT_S)
    assert listener.call(executor, 'start').success
    assert ros_harness.spin_until(
        executor, lambda: listener.done is True and listener.received() == 833, TIMEOUT_S)
    assert ros_harness.spin_until(      # the latched description is a topic of its own
        executor, lambda: listener.description.block_size == 200, TIMEOUT_S)
    assert [b.first_sample_index for b in listener.blocks] == list(range(0, 833, 200))
    assert set(listener.kinds[1:]) == {Continuity.CONTIGUOUS}
    np.testing.assert_array_equal(
        np.concatenate([b.samples for b in listener.blocks], axis=1), expected_samples())
    assert proc.stop() == 0, proc.output()


@pytest.mark.slow
def test_invalid_experiment_at_startup_keeps_node_alive(tmp_path, processes, executor,
                                                        ros_context):
    bad = _write_experiment(tmp_path / 'bad.yaml', **{'section.b.duration_s': 'long'})
    proc = processes.start(ros_harness.node_executable('signal_generator') + [
        '--ros-args', '-p', f'experiment_file:={bad}', '-p', 'pacing:=consumer'])
    listener = Listener(ros_context)
    executor.add_node(listener.node)
    assert ros_harness.spin_until(executor, lambda: listener.status is not None, TIMEOUT_S), \
        proc.output()
    assert listener.status['state'] == 'error'
    assert 'section.b.duration_s' in listener.status['error']
    start = listener.call(executor, 'start')
    assert not start.success and 'duration_s' in start.message
    params = AsyncParameterClient(listener.node, '/signal_generator')
    good = _write_experiment(tmp_path / 'good.yaml')
    [result] = _set(executor, params, [Parameter('experiment_file', value=str(good))])
    assert result.successful
    assert ros_harness.spin_until(
        executor, lambda: listener.node.count_publishers('excitation') >= 1, TIMEOUT_S)
    assert listener.call(executor, 'start').success
    assert ros_harness.spin_until(
        executor, lambda: listener.done is True and listener.received() == 833, TIMEOUT_S)
    assert proc.alive()
    assert proc.stop() == 0, proc.output()
