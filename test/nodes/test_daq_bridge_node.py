"""
The daq_bridge node over real DDS and real loopback sockets.

The udp back-end talks to an in-process :class:`DeviceEmulator` (port 0, recording what it
produced); the sim back-end runs the simulated device in the node; the replay back-end plays a
bag recorded in the test. Published blocks are compared with the device's own record by
sample index.
"""

import json
import socket
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message
from std_msgs.msg import Float64MultiArray, String, UInt64
from std_srvs.srv import Trigger

from emfc_ros.core.bag import BagWriter, OfferedQos, read_streams
from emfc_ros.core.device import DeviceEmulator, Faults
from emfc_ros.core.device import protocol as proto
from emfc_ros.core.device.faults import describe
from emfc_ros.nodes.convert import (
    BLOCK_QOS, block_to_msg, LATCHED_QOS, msg_to_block, msg_to_description)
from emfc_ros.nodes.daq_bridge import DaqBridgeNode
import ros_harness
from ros_harness import scaled

TIMEOUT_S = scaled(20.0)
RATE = 10000.0
INPUTS = ['coil_setpoint_V', 'load_changer_setpoint_V', 'coil_current_A', 'position_m']
DAC_LSB_V = 20.0 / 65536


class Probe:
    """Subscribes to what the bridge publishes; publishes excitation; calls services."""

    def __init__(self, context, raw=False):
        self.node = rclpy.create_node('probe', context=context)
        self.blocks = []
        self.raw = []
        self.descriptions = []
        self.diagnostics = []
        self.acks = []
        if raw:
            self.node.create_subscription(
                Float64MultiArray, 'measurements',
                lambda m: self.raw.append((time.time_ns(), m)), BLOCK_QOS, raw=True)
        else:
            self.node.create_subscription(Float64MultiArray, 'measurements', self._on_block,
                                          BLOCK_QOS)
        self.node.create_subscription(String, 'measurements/description',
                                      self.descriptions.append, LATCHED_QOS)
        self.node.create_subscription(DiagnosticArray, '/diagnostics',
                                      self.diagnostics.append, 10)
        self.node.create_subscription(UInt64, 'excitation/consumed',
                                      lambda m: self.acks.append(m.data), 10)
        self.excitation = self.node.create_publisher(Float64MultiArray, 'excitation',
                                                     BLOCK_QOS)
        self.clients = {name: self.node.create_client(Trigger, f'daq_bridge/{name}')
                        for name in ('start', 'stop', 'emergency_stop', 'reset')}

    def _on_block(self, msg):
        b = msg_to_block(msg)
        self.blocks.append((b.first_sample_index, b.epoch, np.array(b.samples)))

    def samples(self):
        return sum(b[2].shape[1] for b in self.blocks)

    def diag(self, key):
        for msg in reversed(self.diagnostics):
            for status in msg.status:
                if status.name.startswith('daq_bridge'):
                    values = {kv.key: kv.value for kv in status.values}
                    if key in values:
                        return values[key]
        return None

    def level(self):
        """The level of the bridge's latest diagnostic status."""
        for msg in reversed(self.diagnostics):
            for status in msg.status:
                if status.name.startswith('daq_bridge'):
                    return status.level
        return None

    def latched(self, executor, kind):
        """Wait until the description reports just this fault and diagnostics say ERROR."""
        return ros_harness.spin_until(
            executor, lambda: self.faults() == [kind]
            and self.level() == DiagnosticStatus.ERROR, TIMEOUT_S)

    def faults(self):
        """Fault kinds in the latest measurement description."""
        if not self.descriptions:
            return None
        extra = json.loads(self.descriptions[-1].data)['extra']
        return [f['kind'] for f in extra['faults']]

    def call(self, executor, name):
        client = self.clients[name]
        assert ros_harness.spin_until(executor, client.service_is_ready, TIMEOUT_S)
        future = client.call_async(Trigger.Request())
        assert ros_harness.spin_until(executor, future.done, TIMEOUT_S)
        return future.result()


def bridge_params(**extra):
    params = {'sample_rate_Hz': RATE, 'block_size': 500, 'inputs': INPUTS,
              'diagnostics_period_s': 0.1, 'state_rate_Hz': 100.0}
    params.update(extra)
    return [Parameter(k, value=v) for k, v in params.items()]


def udp_bridge(ros_context, emulator, **extra):
    return DaqBridgeNode(context=ros_context, parameter_overrides=bridge_params(
        backend='udp', **{'udp.device_port': emulator.port}, **extra))


def emulator_record(emulator):
    """Frames of the emulator's latest epoch by first sample index."""
    epoch = max(f.epoch for f in emulator.sent)
    return {f.first_sample_index: f.values for f in emulator.sent if f.epoch == epoch}


def setup_nodes(executor, *nodes):
    for node in nodes:
        executor.add_node(node)


@pytest.fixture
def emulator():
    emu = DeviceEmulator(port=0, record=True, seed=3)
    emu.start()
    yield emu
    emu.stop()


def test_udp_bridge_publishes_the_emulator_samples_with_contiguous_indices(
        executor, ros_context, emulator):
    bridge = udp_bridge(ros_context, emulator)
    probe = Probe(ros_context)
    setup_nodes(executor, bridge, probe.node)
    # The latched description and the blocks are separate topics, matched in either order.
    assert ros_harness.spin_until(executor, lambda: len(probe.blocks) >= 12
                                  and probe.descriptions, TIMEOUT_S)
    firsts = [b[0] for b in probe.blocks]
    assert firsts == list(range(firsts[0], firsts[0] + 500 * len(firsts), 500))
    assert len({b[1] for b in probe.blocks}) == 1
    record = emulator_record(emulator)
    for first, _, samples in probe.blocks:
        np.testing.assert_array_equal(samples, record[first])
    desc = msg_to_description(probe.descriptions[-1])
    assert desc.channel_names == tuple(INPUTS)
    assert [c.unit for c in desc.channels] == ['V', 'V', 'A', 'm']
    assert desc.sample_rate_Hz == RATE and desc.block_size == 500
    assert ros_harness.spin_until(executor, lambda: probe.diag('published_blocks') is not None
                                  and int(probe.diag('published_blocks')) >= 12, TIMEOUT_S)
    assert probe.diag('state') == 'running'
    assert int(probe.diag('gaps')) == 0 and int(probe.diag('foreign')) == 0
    assert float(probe.diag('arrival_to_publish_median_us')) > 0.0


def test_faults_are_reported_and_no_wrong_sample_is_published(executor, ros_context):
    faults = Faults(drop=0.04, duplicate=0.04, reorder=0.04, corrupt=0.04)
    with DeviceEmulator(port=0, record=True, seed=11, faults=faults) as emu:
        bridge = DaqBridgeNode(context=ros_context, parameter_overrides=bridge_params(
            backend='udp', block_size=100, **{'udp.device_port': emu.port}))
        probe = Probe(ros_context)
        setup_nodes(executor, bridge, probe.node)

        def all_seen():
            c = emu.all_counters()
            return len(probe.blocks) >= 200 and all(
                c[k] >= 2 for k in ('faults_dropped', 'faults_duplicated', 'faults_reordered',
                                    'faults_corrupted'))
        assert ros_harness.spin_until(executor, all_seen, 30.0)
        # A frame the device produced but the bridge never received, and a garbage datagram
        # from a foreign address, a truncated frame and a frame of the wrong channel count
        # from the device's own address: dropped and counted, the node keeps running.
        good = proto.encode_frame(proto.Frame(proto.STREAM_MEASUREMENT, 7, 1, 700,
                                              np.zeros((4, 100), dtype=np.int16), emu.session))
        wrong = proto.encode_frame(proto.Frame(proto.STREAM_MEASUREMENT, 7, 1, 700,
                                               np.zeros((3, 100), dtype=np.int16), emu.session))
        target = bridge.session.backend.local_address
        emu._sock.sendto(good[:60], target)
        emu._sock.sendto(wrong, target)
        foreign = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            foreign.sendto(b'\x00garbage', target)
        finally:
            foreign.close()
        n_before = len(probe.blocks)
        assert ros_harness.spin_until(executor, lambda: len(probe.blocks) >= n_before + 20,
                                      TIMEOUT_S)
    # The device has stopped: read what it sent, then let every block the bridge published
    # reach the probe (the count stops growing), so that holes, records and the bridge's
    # counters all describe the same stream.
    counters = emu.all_counters()
    record = emulator_record(emu)
    seen = {'n': -1, 'since': time.monotonic()}

    def settled():
        if len(probe.blocks) != seen['n']:
            seen['n'], seen['since'] = len(probe.blocks), time.monotonic()
        return time.monotonic() - seen['since'] > 1.0

    assert ros_harness.spin_until(executor, settled, TIMEOUT_S)
    firsts = [b[0] for b in probe.blocks]
    assert firsts == sorted(firsts) and len(set(firsts)) == len(firsts)
    for first, _, samples in probe.blocks:
        np.testing.assert_array_equal(samples, record[first])
    values = bridge.diagnostic_values()
    assert values['gaps'] >= 1 and values['missing_samples'] >= 100
    assert values['duplicates'] >= 1
    assert values['reordered'] >= 1
    assert values['corrupt'] >= counters['faults_corrupted'] + 1      # + the truncated one
    assert values['rejected'] >= 1 and values['foreign'] >= 1
    # Every hole in the published stream is a gap the back-end declared, no more.
    holes = sum(1 for a, b in zip(firsts, firsts[1:]) if b != a + 100)
    assert holes == values['published_gaps'] <= values['gaps']
    assert values['dropped_out_of_order_blocks'] == 0
    # ...and it is what /diagnostics said over DDS.
    assert ros_harness.spin_until(
        executor, lambda: probe.diag('corrupt') is not None
        and int(probe.diag('corrupt')) >= counters['faults_corrupted'], TIMEOUT_S)
    assert int(probe.diag('gaps')) >= 1 and int(probe.diag('duplicates')) >= 1
    assert probe.diag('state') == 'running'


def started_udp_bridge(executor, ros_context, emulator, **overrides):
    """A udp bridge on the emulator, streaming blocks, and a probe subscribed to it."""
    bridge = udp_bridge(ros_context, emulator, **overrides)
    probe = Probe(ros_context)
    setup_nodes(executor, bridge, probe.node)
    assert ros_harness.spin_until(
        executor, lambda: len(probe.blocks) >= 2 and
        probe.excitation.get_subscription_count() >= 1, TIMEOUT_S)
    return bridge, probe


def excitation_blocks(first, count, coil_V, load_V, n=500, epoch=1):
    return [block_to_msg(first + i * n, RATE, epoch,
                         np.vstack([np.full(n, coil_V), np.full(n, load_V)]))
            for i in range(count)]


def applied(probe, channel=0):
    """(index array, applied setpoint array) of the published blocks."""
    idx = np.concatenate([np.arange(f, f + s.shape[1]) for f, _, s in probe.blocks])
    val = np.concatenate([s[channel] for _, _, s in probe.blocks])
    return idx, val


def test_watchdog_drives_outputs_safe_within_one_block_and_setpoints_are_clamped(
        executor, ros_context, emulator):
    bridge, probe = started_udp_bridge(executor, ros_context, emulator, watchdog_timeout_s=0.3,
                                       output_min_V=[-1.0, -1.0], output_max_V=[1.0, 1.0],
                                       excitation_lead_s=0.05)
    # 1 s of excitation at once, coil at 2 V (beyond the 1 V limit), then silence.
    for msg in excitation_blocks(0, 20, 2.0, 0.5):
        probe.excitation.publish(msg)
    assert ros_harness.spin_until(executor, lambda: bridge.diagnostic_values()[
        'watchdog_trips'] == 1, TIMEOUT_S)
    trip = bridge.diagnostic_values()['watchdog_trip_device_index']
    assert ros_harness.spin_until(executor, lambda: probe.blocks[-1][0] > trip + 3000,
                                  TIMEOUT_S)
    idx, coil = applied(probe)
    _, load = applied(probe, 1)
    on = idx[np.abs(coil - 1.0) <= DAC_LSB_V]
    assert on.size >= 1000                        # the clamped excitation was applied...
    assert np.all(np.abs(load[np.isin(idx, on)] - 0.5) <= DAC_LSB_V)
    assert on.max() < trip + 500                  # ...and ended within one block of the trip
    assert np.all(coil[idx >= trip + 500] == 0.0)
    assert np.all(load[idx >= trip + 500] == 0.0)
    values = bridge.diagnostic_values()
    assert values['clamped_samples'] == 20 * 500  # every coil sample, no load sample
    assert values['watchdog_tripped'] == 1
    # Excitation was still queued at the trip: not applied, a latched fault.
    (fault,) = bridge.faults()
    assert fault.kind == 'excitation_watchdog' and 0 < fault.samples < 10000
    assert probe.latched(executor, 'excitation_watchdog')
    assert values['excitation_blocks'] == 20 and values['excitation_gaps'] == 0
    assert probe.acks and probe.acks == sorted(probe.acks)
    # New excitation re-arms the stream.
    for msg in excitation_blocks(10000, 4, 0.25, 0.0):
        probe.excitation.publish(msg)
    assert ros_harness.spin_until(
        executor, lambda: np.any(np.abs(applied(probe)[1] - 0.25) <= DAC_LSB_V), TIMEOUT_S)
    assert bridge.diagnostic_values()['watchdog_tripped'] == 0
    # The same stream went on after the trip: the samples between were not applied.
    assert [f.kind for f in bridge.faults()] == ['excitation_watchdog'] * 2
    assert bridge.faults()[1].device_index == trip
    # ~/reset acknowledges the faults; the level returns to what the counters say.
    assert probe.call(executor, 'reset').success
    assert ros_harness.spin_until(
        executor, lambda: probe.faults() == [] and probe.level() != DiagnosticStatus.ERROR,
        TIMEOUT_S)


def test_a_stream_taken_after_its_sample_0_is_a_latched_fault(executor, ros_context, emulator):
    # The bridge first hears an excitation stream at its sample 5000 (it began before the
    # device ran): the recorded samples 0 to 4999 were never applied, which must fail the run.
    bridge, probe = started_udp_bridge(executor, ros_context, emulator)
    for msg in excitation_blocks(5000, 4, 0.25, 0.0):
        probe.excitation.publish(msg)
    assert probe.latched(executor, 'excitation_start_missing')
    (fault,) = bridge.faults()
    assert fault.kind == 'excitation_start_missing' and fault.exact
    assert 'samples 0 to 4999' in fault.message
    # Recorded where sample 0 would have been applied, spanning the samples never applied:
    # what emfc-identify and the runner name as not applied is 0 to 4999 (it named the
    # applied ones, 5000 to the end, before issue 27).
    offset = int(bridge.diagnostic_values()['excitation_offset_samples'])
    assert (fault.device_index, fault.samples) == (offset, 5000)
    assert fault.experiment_range(offset, 400000) == (0, 5000)
    assert 'experiment samples 0 to 4999 not applied' in describe([fault], offset, 400000)
    # It was applied from there on, as mapped.
    assert ros_harness.spin_until(
        executor, lambda: np.any(np.abs(applied(probe)[1] - 0.25) <= DAC_LSB_V), TIMEOUT_S)


def test_excitation_that_arrives_after_its_device_samples_is_a_latched_fault(
        executor, ros_context, emulator):
    # A generator (or its link) that falls more than excitation_lead_s behind the device:
    # the bridge has written the device samples of the missing excitation with the safe
    # values; the samples that come afterwards are dropped as late, which must fail the run.
    bridge, probe = started_udp_bridge(executor, ros_context, emulator)
    for msg in excitation_blocks(0, 2, 0.25, 0.0):
        probe.excitation.publish(msg)
    assert ros_harness.spin_until(
        executor, lambda: bridge.diagnostic_values()['excitation_offset_samples'] != '',
        TIMEOUT_S)
    offset = int(bridge.diagnostic_values()['excitation_offset_samples'])
    # the stream ended at its sample 1000: the bridge has written the safe values for more
    # than 2000 device samples after it
    assert ros_harness.spin_until(
        executor, lambda: bridge.diagnostic_values()['excitation_underrun_samples'] > 2000,
        TIMEOUT_S)
    assert bridge.faults() == ()                # safe values at the end of a stream: no fault
    for msg in excitation_blocks(1000, 2, 0.25, 0.0):
        probe.excitation.publish(msg)
    assert probe.latched(executor, 'excitation_late')
    (fault,) = bridge.faults()
    assert fault.exact and fault.device_index == offset + 1000, (fault, offset)
    assert 'excitation_lead_s (0.1 s)' in fault.message
    assert bridge.diagnostic_values()['excitation_late_samples'] == 1000


def test_emergency_stop_acts_within_one_block_and_latches_until_reset(
        executor, ros_context, emulator):
    bridge = udp_bridge(ros_context, emulator, excitation_mode='function_generator',
                        **{'funcgen.coil.waveform': 'constant', 'funcgen.coil.offset_V': 0.75})
    probe = Probe(ros_context)
    setup_nodes(executor, bridge, probe.node)
    assert ros_harness.spin_until(
        executor, lambda: len(probe.blocks) >= 2 and
        np.abs(probe.blocks[-1][2][0, -1] - 0.75) <= DAC_LSB_V, TIMEOUT_S)
    result = probe.call(executor, 'emergency_stop')
    assert result.success and 'latched' in result.message
    stop = bridge.diagnostic_values()['emergency_stop_device_index']
    assert ros_harness.spin_until(executor, lambda: probe.blocks[-1][0] > stop + 5000,
                                  TIMEOUT_S)
    idx, coil = applied(probe)
    assert np.all(coil[idx >= stop + 500] == 0.0)
    assert np.any(np.abs(coil[idx < stop] - 0.75) <= DAC_LSB_V)
    # Excitation during the latch is dropped and counted; the outputs stay safe.
    for msg in excitation_blocks(0, 2, 0.5, 0.5):
        probe.excitation.publish(msg)
    assert ros_harness.spin_until(
        executor, lambda: bridge.diagnostic_values()['excitation_dropped_estop'] == 2,
        TIMEOUT_S)
    assert ros_harness.spin_until(executor, lambda: probe.diag('emergency_stop') == '1',
                                  TIMEOUT_S)
    assert [f.kind for f in bridge.faults()] == ['emergency_stop']
    assert bridge.faults()[0].device_index == stop
    assert probe.latched(executor, 'emergency_stop')
    n = len(probe.blocks)
    assert ros_harness.spin_until(executor, lambda: len(probe.blocks) >= n + 4, TIMEOUT_S)
    assert all(np.all(b[2][0] == 0.0) for b in probe.blocks[n:])
    assert probe.call(executor, 'reset').success
    assert ros_harness.spin_until(
        executor, lambda: np.abs(probe.blocks[-1][2][0, -1] - 0.75) <= DAC_LSB_V, TIMEOUT_S)
    assert bridge.diagnostic_values()['emergency_stop'] == 0
    assert bridge.faults() == ()
    assert ros_harness.spin_until(executor, lambda: probe.faults() == [], TIMEOUT_S)


def test_stop_and_start_services_restart_the_stream_in_a_new_epoch(
        executor, ros_context, emulator):
    bridge = udp_bridge(ros_context, emulator)
    probe = Probe(ros_context)
    setup_nodes(executor, bridge, probe.node)
    assert ros_harness.spin_until(executor, lambda: len(probe.blocks) >= 2, TIMEOUT_S)
    statuses = []
    probe.node.create_subscription(String, 'daq_bridge/status',
                                   lambda m: statuses.append(json.loads(m.data)), LATCHED_QOS)
    assert ros_harness.spin_until(executor, lambda: statuses and
                                  statuses[-1]['state'] == 'running', TIMEOUT_S)
    # The services answer at once; the device's answer is waited for in the worker thread
    # and ~/status says how it ended.
    answer = probe.call(executor, 'stop')
    assert answer.success and 'in the background' in answer.message
    assert ros_harness.spin_until(executor, lambda: statuses[-1]['state'] == 'stopped',
                                  TIMEOUT_S)
    assert 'stopping' in [s['state'] for s in statuses]
    assert bridge.diagnostic_values()['state'] == 'stopped'
    epoch = probe.blocks[-1][1]
    assert probe.call(executor, 'start').success
    assert ros_harness.spin_until(executor, lambda: probe.blocks[-1][1] == epoch + 1,
                                  TIMEOUT_S)
    assert [b[0] for b in probe.blocks if b[1] == epoch + 1][0] == 0


def test_a_device_that_comes_back_is_reconnected(executor, ros_context):
    emu = DeviceEmulator(port=0, record=True, seed=5)
    port = emu.start()
    bridge = DaqBridgeNode(context=ros_context, parameter_overrides=bridge_params(
        backend='udp', **{'udp.device_port': port, 'udp.device_timeout_s': 0.3}))
    probe = Probe(ros_context)
    setup_nodes(executor, bridge, probe.node)
    try:
        assert ros_harness.spin_until(executor, lambda: len(probe.blocks) >= 2, TIMEOUT_S)
        emu.stop()
        emu = DeviceEmulator(port=port, record=True, seed=6)
        emu.start()
        epoch = probe.blocks[-1][1]
        assert ros_harness.spin_until(
            executor, lambda: sum(1 for b in probe.blocks if b[1] > epoch) >= 3, TIMEOUT_S)
        assert bridge.diagnostic_values()['reconnects'] >= 1
        # A lost device is a fault, latched across the reconnect.
        assert [f.kind for f in bridge.faults()] == ['device_lost']
        new = [b for b in probe.blocks if b[1] > epoch]
        assert new[0][0] == 0
        record = emulator_record(emu)
        for first, _, samples in new:
            np.testing.assert_array_equal(samples, record[first])
    finally:
        emu.stop()


def test_sim_backend_streams_contiguous_blocks_and_refuses_bad_input(executor, ros_context):
    bridge = DaqBridgeNode(context=ros_context, parameter_overrides=bridge_params(
        backend='sim', block_size=1000))
    probe = Probe(ros_context)
    setup_nodes(executor, bridge, probe.node)
    assert ros_harness.spin_until(
        executor, lambda: len(probe.blocks) >= 8 and
        probe.excitation.get_subscription_count() >= 1, TIMEOUT_S)
    firsts = [b[0] for b in probe.blocks]
    assert firsts[0] % 1000 == 0
    assert firsts == list(range(firsts[0], firsts[0] + 1000 * len(firsts), 1000))
    good = block_to_msg(0, RATE, 1, np.zeros((2, 100)))
    bad = [block_to_msg(0, RATE, 1, np.zeros((3, 100))),           # wrong channel count
           block_to_msg(0, 5000.0, 1, np.zeros((2, 100))),         # wrong rate
           block_to_msg(0, RATE, 1, np.full((2, 100), np.nan))]    # NaN
    broken = block_to_msg(0, RATE, 1, np.zeros((2, 100)))
    broken.layout.data_offset = 0                                  # malformed layout
    for msg in bad + [broken, good]:
        probe.excitation.publish(msg)
    assert ros_harness.spin_until(
        executor, lambda: bridge.diagnostic_values()['excitation_blocks'] == 1, TIMEOUT_S)
    values = bridge.diagnostic_values()
    assert values['excitation_malformed'] == 4
    assert 'data_offset' in values['last_error']
    n = len(probe.blocks)
    assert ros_harness.spin_until(executor, lambda: len(probe.blocks) >= n + 2, TIMEOUT_S)

    # Parameters: run-time ones are checked, start-up ones refused with a reason.
    results = bridge.set_parameters([Parameter('watchdog_timeout_s', value=-1.0)])
    assert not results[0].successful and 'watchdog_timeout_s' in results[0].reason
    results = bridge.set_parameters([Parameter('sample_rate_Hz', value=20000.0)])
    assert not results[0].successful and 'read-only' in results[0].reason
    results = bridge.set_parameters([Parameter('funcgen.coil.waveform', value='square')])
    assert not results[0].successful and 'waveform' in results[0].reason
    assert bridge.set_parameters([Parameter('watchdog_timeout_s', value=2.0)])[0].successful


def test_a_block_sent_again_is_acknowledged_again(executor, ros_context):
    # A consumer-paced generator that did not hear the acknowledgement sends the window
    # again: the bridge drops it (counted) and says again how far the device is.
    bridge = DaqBridgeNode(context=ros_context, parameter_overrides=bridge_params(
        backend='sim', block_size=100))
    probe = Probe(ros_context)
    setup_nodes(executor, bridge, probe.node)
    assert ros_harness.spin_until(
        executor, lambda: len(probe.blocks) >= 2 and
        probe.excitation.get_subscription_count() >= 1
        and probe.node.count_publishers('excitation/consumed') >= 1, TIMEOUT_S)
    window = excitation_blocks(0, 2, 0.1, 0.0)
    for msg in window:
        probe.excitation.publish(msg)
    assert ros_harness.spin_until(executor, lambda: probe.acks and probe.acks[-1] == 1000,
                                  TIMEOUT_S), probe.acks
    n = len(probe.acks)
    for msg in window:
        probe.excitation.publish(msg)
    assert ros_harness.spin_until(executor, lambda: len(probe.acks) >= n + 2, TIMEOUT_S)
    assert probe.acks[n:] == [1000, 1000]
    values = bridge.diagnostic_values()
    assert values['excitation_blocks'] == 2 and values['excitation_duplicates'] == 2


def test_invalid_start_up_parameters_leave_a_running_node_that_says_why(
        executor, ros_context):
    bridge = DaqBridgeNode(context=ros_context, parameter_overrides=bridge_params(
        backend='fpga'))
    probe = Probe(ros_context)
    setup_nodes(executor, bridge, probe.node)
    assert ros_harness.spin_until(executor, lambda: probe.diag('error') is not None,
                                  TIMEOUT_S)
    assert 'backend' in probe.diag('error') and probe.diag('state') == 'error'
    result = probe.call(executor, 'start')
    assert not result.success and 'backend' in result.message


def test_declared_pan_load_reaches_the_measurement_description(executor, ros_context):
    bridge = DaqBridgeNode(context=ros_context, parameter_overrides=bridge_params(
        backend='sim', **{'pan.load_mass_kg': 0.1024, 'pan.load_changer_coupled': 'true'}))
    probe = Probe(ros_context)
    setup_nodes(executor, bridge, probe.node)
    assert ros_harness.spin_until(executor, lambda: len(probe.descriptions) >= 1, TIMEOUT_S)
    extra = msg_to_description(probe.descriptions[-1]).extra
    assert extra['load_mass_kg'] == 0.1024 and extra['load_changer_coupled'] is True


def test_the_description_states_each_input_resolution(executor, ros_context):
    """Code step from the scaling, noise from input_noise_rms (issue 15: budgets need it)."""
    bridge = DaqBridgeNode(context=ros_context, parameter_overrides=bridge_params(
        backend='sim', inputs=['position_m', 'coil_current_A'],
        input_units=['m', 'A'], input_scales=[6e-9, 3e-6], input_offsets=[0.0, 0.0],
        input_noise_rms=[2e-9, 0.0]))
    probe = Probe(ros_context)
    setup_nodes(executor, bridge, probe.node)
    assert ros_harness.spin_until(executor, lambda: len(probe.descriptions) >= 1, TIMEOUT_S)
    extra = msg_to_description(probe.descriptions[-1]).extra
    assert extra['resolution'] == {'position_m': {'step': 6e-9, 'noise_rms': 2e-9},
                                   'coil_current_A': {'step': 3e-6, 'noise_rms': 0.0}}


def test_a_wrong_input_noise_leaves_a_node_that_says_why(executor, ros_context):
    bridge = DaqBridgeNode(context=ros_context, parameter_overrides=bridge_params(
        backend='sim', input_noise_rms=[1e-9]))
    probe = Probe(ros_context)
    setup_nodes(executor, bridge, probe.node)
    assert ros_harness.spin_until(executor, lambda: probe.diag('error') is not None,
                                  TIMEOUT_S)
    assert 'input_noise_rms' in probe.diag('error') and probe.diag('state') == 'error'


def test_a_wrong_pan_declaration_leaves_a_node_that_says_why(executor, ros_context):
    bridge = DaqBridgeNode(context=ros_context, parameter_overrides=bridge_params(
        backend='sim', **{'pan.load_changer_coupled': 'maybe'}))
    probe = Probe(ros_context)
    setup_nodes(executor, bridge, probe.node)
    assert ros_harness.spin_until(executor, lambda: probe.diag('error') is not None,
                                  TIMEOUT_S)
    assert 'pan.load_changer_coupled' in probe.diag('error')
    assert probe.diag('state') == 'error'


def test_replay_republishes_a_recorded_bag_with_the_same_indices(
        executor, ros_context, tmp_path):
    # Record the sim back-end's measurements into a bag, as the recorder does (raw CDR).
    source = DaqBridgeNode(context=ros_context, parameter_overrides=bridge_params(
        backend='sim', block_size=1000))
    recorder = Probe(ros_context, raw=True)
    setup_nodes(executor, source, recorder.node)
    assert ros_harness.spin_until(executor, lambda: len(recorder.raw) >= 8
                                  and recorder.descriptions, TIMEOUT_S)
    executor.remove_node(source)
    source.destroy_node()
    executor.remove_node(recorder.node)
    recorder.node.destroy_node()
    bag = tmp_path / 'bag'
    writer = BagWriter(bag)
    writer.open()
    data = writer.add_connection('/measurements', 'std_msgs/msg/Float64MultiArray',
                                 [OfferedQos()])
    desc = writer.add_connection('/measurements/description', 'std_msgs/msg/String',
                                 [OfferedQos()])
    first_t = recorder.raw[0][0]
    writer.write(desc, first_t - 1, serialize_message(recorder.descriptions[-1]))
    for t, raw in recorder.raw:
        writer.write(data, t, raw)
    writer.close()
    recorded = read_streams(bag)['/measurements']

    replay = DaqBridgeNode(context=ros_context, parameter_overrides=[
        Parameter('backend', value='replay'), Parameter('replay.bag', value=str(bag)),
        Parameter('replay.pacing', value='receive_time'), Parameter('autostart', value=False),
        Parameter('diagnostics_period_s', value=0.1)])
    probe = Probe(ros_context)
    setup_nodes(executor, replay, probe.node)
    assert ros_harness.spin_until(executor, lambda: replay.count_subscribers('measurements')
                                  >= 1, TIMEOUT_S)
    assert probe.call(executor, 'start').success
    t0 = time.monotonic()
    assert ros_harness.spin_until(executor,
                                  lambda: probe.samples() >= recorded.n_samples, TIMEOUT_S)
    assert ros_harness.spin_until(executor, lambda: probe.descriptions, TIMEOUT_S)
    elapsed = time.monotonic() - t0
    firsts = [b[0] for b in probe.blocks]
    assert firsts == list(recorded.block_first_index)
    got = np.concatenate([b[2] for b in probe.blocks], axis=1)
    np.testing.assert_array_equal(got, recorded.samples)
    span_s = (recorded.block_receive_time_ns[-1] - recorded.block_receive_time_ns[0]) * 1e-9
    assert elapsed >= span_s * 0.9
    desc = msg_to_description(probe.descriptions[-1])
    assert desc.channel_names == recorded.channel_names
    assert desc.extra['backend'] == 'replay'


def test_effort_commands_reach_the_coil_and_time_out(executor, ros_context):
    from sensor_msgs.msg import JointState
    bridge = DaqBridgeNode(context=ros_context, parameter_overrides=bridge_params(
        backend='sim', block_size=200, command_timeout_s=0.2, excitation_lead_s=0.02))
    probe = Probe(ros_context)
    states = []
    probe.node.create_subscription(JointState, 'joint_states', states.append, 100)
    commands = probe.node.create_publisher(Float64MultiArray, 'commands', 10)
    setup_nodes(executor, bridge, probe.node)
    assert ros_harness.spin_until(
        executor, lambda: len(probe.blocks) >= 2 and commands.get_subscription_count() >= 1
        and len(states) >= 5, TIMEOUT_S)
    assert states[-1].name == ['lever'] and len(states[-1].effort) == 1
    start = probe.blocks[-1][0]
    deadline = time.monotonic() + scaled(0.6)
    while time.monotonic() < deadline:
        commands.publish(Float64MultiArray(data=[0.02]))
        ros_harness.spin_until(executor, lambda: False, 0.02)
    commands.publish(Float64MultiArray(data=[1.0, 2.0]))           # malformed: counted
    assert ros_harness.spin_until(
        executor, lambda: bridge.diagnostic_values()['command_watchdog_trips'] >= 1,
        TIMEOUT_S)
    stopped = probe.blocks[-1][0]
    assert ros_harness.spin_until(executor, lambda: probe.blocks[-1][0] > stopped + 2000,
                                  TIMEOUT_S)
    idx, coil = applied(probe)
    assert np.any(coil[(idx > start) & (idx < stopped)] > 0.01)    # force up: positive volts
    assert np.all(coil[idx > stopped + 1000] == 0.0)
    assert bridge.diagnostic_values()['command_malformed'] == 1


def test_node_process_with_the_shipped_params_file(executor, ros_context, processes,
                                                   emulator):
    import sys
    from pathlib import Path
    repo = Path(__file__).resolve().parents[2]
    proc = processes.start([sys.executable, '-m', 'emfc_ros.nodes.daq_bridge', '--ros-args',
                            '--params-file', str(repo / 'config' / 'daq_bridge_udp.yaml'),
                            '-p', f'udp.device_port:={emulator.port}'], cwd=repo)
    probe = Probe(ros_context)
    setup_nodes(executor, probe.node)
    assert ros_harness.spin_until(executor, lambda: len(probe.blocks) >= 3
                                  and probe.descriptions, TIMEOUT_S), proc.output()
    desc = msg_to_description(probe.descriptions[-1])
    assert desc.channel_names == ('coil_setpoint_V', 'load_changer_setpoint_V',
                                  'coil_current_A', 'load_changer_current_A', 'sensor_V',
                                  'position_m')
    firsts = [b[0] for b in probe.blocks]
    assert firsts == list(range(firsts[0], firsts[0] + 1000 * len(firsts), 1000))
    record = emulator_record(emulator)
    for first, _, samples in probe.blocks:
        np.testing.assert_array_equal(samples, record[first])
    assert proc.alive()
    assert proc.stop() in (0, -2)


def test_autostart_waits_for_a_device_that_is_not_there_yet(executor, ros_context):
    probe_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe_sock.bind(('127.0.0.1', 0))
    port = probe_sock.getsockname()[1]
    probe_sock.close()
    bridge = DaqBridgeNode(context=ros_context, parameter_overrides=bridge_params(
        backend='udp', **{'udp.device_port': port, 'udp.request_timeout_s': 0.05}))
    # The first attempt runs in the worker thread: the node is up at once.
    assert bridge.diagnostic_values()['state'] in ('starting', 'error')
    probe = Probe(ros_context)
    setup_nodes(executor, bridge, probe.node)
    assert ros_harness.spin_until(executor, lambda: probe.diag('state') == 'error', TIMEOUT_S)
    assert 'start failed' in bridge.diagnostic_values()['last_error']
    with DeviceEmulator(port=port, record=True, seed=8) as emu:
        assert ros_harness.spin_until(executor, lambda: len(probe.blocks) >= 2, TIMEOUT_S)
        record = emulator_record(emu)
        for first, _, samples in probe.blocks:
            np.testing.assert_array_equal(samples, record[first])
    assert bridge.diagnostic_values()['state'] == 'running'


def test_min_subscribers_holds_the_start_and_the_excitation_until_a_listener(
        executor, ros_context):
    bridge = DaqBridgeNode(context=ros_context, parameter_overrides=bridge_params(
        backend='sim', min_subscribers=1))
    pub_node = rclpy.create_node('exc_pub', context=ros_context)
    excitation_pub = pub_node.create_publisher(Float64MultiArray, 'excitation', BLOCK_QOS)
    setup_nodes(executor, bridge, pub_node)
    ros_harness.spin_until(executor, lambda: False, 1.0)
    # Nobody listens to the measurements: not started, the excitation not subscribed.
    assert bridge.diagnostic_values()['state'] == 'idle'
    assert bridge.diagnostic_values()['published_blocks'] == 0
    assert excitation_pub.get_subscription_count() == 0
    probe = Probe(ros_context)
    setup_nodes(executor, probe.node)
    assert ros_harness.spin_until(executor, lambda: len(probe.blocks) >= 2, TIMEOUT_S)
    assert probe.blocks[0][0] == 0                   # the listener has it from the start
    assert bridge.diagnostic_values()['state'] == 'running'
    assert ros_harness.spin_until(
        executor, lambda: excitation_pub.get_subscription_count() >= 1, TIMEOUT_S)


def test_an_invalid_min_subscribers_is_an_error_that_says_why(executor, ros_context):
    bridge = DaqBridgeNode(context=ros_context, parameter_overrides=bridge_params(
        backend='sim', min_subscribers=-1))
    values = bridge.diagnostic_values()
    assert values['state'] == 'error'
    assert 'min_subscribers' in values['error'], values


def _readme_block(after: str):
    """The shell lines of the first ``bash`` block after a sentence of the user docs."""
    import readme_lines
    text = readme_lines.user_docs_text()
    start = text.index('```bash', text.index(after)) + len('```bash')
    block = text[start:text.index('```', start)].replace('\\\n', '')
    return [line.strip() for line in block.splitlines() if line.strip()]


def test_the_readme_key_commands_run_as_typed(executor, ros_context, processes, tmp_path):
    import shlex
    import subprocess
    from pathlib import Path
    repo = Path(__file__).resolve().parents[2]
    keygen, emulator_line, bridge_line = _readme_block('authenticate every datagram')
    (tmp_path / 'config').symlink_to(repo / 'config')
    subprocess.run(['bash', '-c', keygen], cwd=tmp_path, check=True, timeout=scaled(60),
                   env=ros_harness.child_environment())
    assert len(bytes.fromhex((tmp_path / 'device.key').read_text())) == 32
    assert (tmp_path / 'device.key').stat().st_mode & 0o777 == 0o600
    emulator = processes.start(shlex.split(emulator_line), cwd=tmp_path)
    argv = shlex.split(bridge_line)
    assert argv[:4] == ['ros2', 'run', 'emfc_ros', 'daq_bridge'], argv
    bridge = processes.start(ros_harness.node_executable('daq_bridge') + argv[4:], cwd=tmp_path)
    node = rclpy.create_node('key_probe', namespace='/emfc', context=ros_context)
    blocks, diagnostics = [], []
    node.create_subscription(Float64MultiArray, 'measurements', blocks.append, BLOCK_QOS)
    node.create_subscription(DiagnosticArray, '/diagnostics', diagnostics.append, 10)
    executor.add_node(node)

    def authenticated():
        for msg in diagnostics:
            for status in msg.status:
                values = {kv.key: kv.value for kv in status.values}
                if status.name.startswith('daq_bridge') and values.get('authenticated') == '1' \
                        and int(values.get('frames_received', 0)) > 0:
                    return True
        return False

    # A fresh install compiles the simulator kernel at the emulator's first start.
    assert ros_harness.spin_until(executor, lambda: len(blocks) >= 3 and authenticated(),
                                  180.0), emulator.output() + bridge.output()
    assert bridge.stop() in (0, -2)
    assert emulator.stop() == 0
    out = emulator.output()
    assert 'authentication: HMAC-SHA256 key device.key' in out, out
    assert 'refused datagrams: none' in out, out


def test_the_executor_keeps_running_while_the_device_does_not_answer(executor, ros_context):
    # A port nobody serves: every request to it waits its timeouts and retries (5 x 0.5 s).
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(('127.0.0.1', 0))
    port = sock.getsockname()[1]
    sock.close()
    bridge = DaqBridgeNode(context=ros_context, parameter_overrides=bridge_params(
        backend='udp', autostart=False, **{'udp.device_port': port,
                                           'udp.request_timeout_s': 0.5}))
    probe = Probe(ros_context)
    setup_nodes(executor, bridge, probe.node)
    answer = probe.call(executor, 'start')
    # The service answered while the start still waits for the device in the worker...
    assert answer.success and 'in the background' in answer.message
    assert bridge.status_values()['device_busy'], bridge.status_values()
    assert bridge.status_values()['state'] == 'starting'
    # ...and the executor goes on meanwhile: diagnostics keep coming, services answer.
    seen = len(probe.diagnostics)
    assert ros_harness.spin_until(
        executor, lambda: len(probe.diagnostics) >= seen + 3
        or not bridge.status_values()['device_busy'], TIMEOUT_S)
    assert bridge.status_values()['device_busy'], 'the start ended before 3 diagnostics'
    assert probe.call(executor, 'emergency_stop').success
    assert probe.diag('state') == 'starting'
    # In the end the start fails, with the reason, and the node stays up.
    assert ros_harness.spin_until(executor, lambda: bridge.status_values()['state'] == 'error',
                                  TIMEOUT_S)
    assert 'no response' in bridge.status_values()['last_error']
