"""
The replay back-end: a recorded bag's measurement blocks, with their indices and timing.

Bags are written by the core writer with messages serialised by rosbags' typestore.
"""

import time

import numpy as np
import pytest
from rosbags.typesys import get_typestore, Stores

from emfc_ros.core.bag import BagWriter, OfferedQos
from emfc_ros.core.blocks import Channel, pack, StreamDescription
from emfc_ros.core.device import create_backend, DeviceConfigError, DeviceError
from emfc_ros.core.device.backend import DeviceBackend
from emfc_ros.core.device.replay_backend import ReplayBackend
from ros_harness import scaled

TS = get_typestore(Stores.ROS2_JAZZY)
F64 = 'std_msgs/msg/Float64MultiArray'
STR = 'std_msgs/msg/String'
RATE = 1000.0
NAMES = ('coil_current_A', 'sensor_V')


def block_cdr(first, samples, epoch=1):
    t = TS.types
    dim = t['std_msgs/msg/MultiArrayDimension']
    layout = t['std_msgs/msg/MultiArrayLayout'](dim=[
        dim('channel', samples.shape[0], samples.size),
        dim('sample', samples.shape[1], samples.shape[1])], data_offset=3)
    return TS.serialize_cdr(t[F64](layout=layout, data=pack(first, RATE, epoch, samples)), F64)


def description_cdr(epoch, block_size=10):
    desc = StreamDescription('measurements', RATE, block_size,
                             (Channel(NAMES[0], 'A'), Channel(NAMES[1], 'V')), epoch=epoch)
    return TS.serialize_cdr(TS.types[STR](data=desc.to_json()), STR)


def values(first, n):
    k = np.arange(first, first + n, dtype=float)
    return np.vstack([k * 1e-3, -k])


def make_bag(path, blocks, topic='/emfc/measurements', t_step_ns=20_000_000):
    """Blocks: (first, n, epoch), received t_step_ns apart."""
    writer = BagWriter(path)
    writer.open()
    c = writer.add_connection(topic, F64, [OfferedQos()])
    d = writer.add_connection(topic + '/description', STR, [OfferedQos()])
    for epoch in sorted({e for _, _, e in blocks}):
        writer.write(d, 1, description_cdr(epoch))
    t = 1_000_000_000
    for first, n, epoch in blocks:
        writer.write(c, t, block_cdr(first, values(first, n), epoch))
        t += t_step_ns
    writer.close()
    return path


def started(backend):
    backend.configure(backend.recorded_config)
    backend.start()
    return backend


def drain(backend, limit=1000):
    out = []
    for _ in range(limit):
        block = backend.read_block(timeout_s=scaled(0.5))
        if block is None:
            break
        out.append(block)
    return out


def test_replay_returns_the_recorded_blocks_with_their_indices(tmp_path):
    bag = make_bag(tmp_path / 'bag', [(0, 10, 1), (10, 10, 1), (20, 10, 1), (30, 7, 1)])
    backend = create_backend('replay', bag=str(bag), pacing='fast')
    assert isinstance(backend, DeviceBackend)
    assert backend.recorded_config.input_names == NAMES
    assert [c.unit for c in backend.recorded_config.inputs] == ['A', 'V']
    assert backend.recorded_config.sample_rate_Hz == RATE
    assert backend.recorded_config.block_size == 10
    started(backend)
    blocks = drain(backend)
    assert [(b.first_sample_index, b.n_samples) for b in blocks] == [
        (0, 10), (10, 10), (20, 10), (30, 7)]
    for b in blocks:
        np.testing.assert_array_equal(b.samples, values(b.first_sample_index, b.n_samples))
        assert b.epoch == 1 and b.sample_rate_Hz == RATE
    health = backend.health()
    assert health['blocks_delivered'] == 4 and health['blocks_remaining'] == 0
    assert health['gaps'] == 0 and health['replays_finished'] == 1
    assert backend.finished
    # A restart replays from the beginning in a new epoch.
    assert backend.start() == 2
    again = drain(backend)
    assert [b.first_sample_index for b in again] == [0, 10, 20, 30]
    assert {b.epoch for b in again} == {2}
    backend.close()


def test_a_recorded_gap_stays_a_gap_and_is_counted(tmp_path):
    bag = make_bag(tmp_path / 'bag', [(0, 10, 1), (10, 10, 1), (40, 10, 1), (50, 10, 1)])
    backend = started(ReplayBackend(str(bag), pacing='fast'))
    blocks = drain(backend)
    assert [(b.first_sample_index, b.n_samples) for b in blocks] == [
        (0, 10), (10, 10), (40, 10), (50, 10)]
    assert not any(np.isnan(b.samples).any() for b in blocks)
    np.testing.assert_array_equal(blocks[2].samples, values(40, 10))
    assert backend.health()['gaps'] == 1 and backend.health()['missing_samples'] == 20


class FakeClock:
    """The replay's clock and sleep: time moves only when the back-end sleeps (or a test)."""

    def __init__(self):
        self.now = 100.0
        self.sleeps = []

    def __call__(self):
        return self.now

    def sleep(self, seconds):
        assert seconds > 0
        self.sleeps.append(seconds)
        self.now += seconds


def paced_arrivals(backend, clock, n):
    """The clock's time since START at which each of n blocks was returned [s]."""
    t0 = clock.now
    arrivals = []
    for _ in range(n):
        assert backend.read_block(timeout_s=1.0) is not None
        arrivals.append(clock.now - t0)
    return arrivals


def test_receive_time_pacing_follows_the_recorded_timing(tmp_path):
    bag = make_bag(tmp_path / 'bag', [(10 * i, 10, 1) for i in range(6)],
                   t_step_ns=40_000_000)
    clock = FakeClock()
    backend = started(ReplayBackend(str(bag), pacing='receive_time', clock=clock,
                                    sleep=clock.sleep))
    # Each block is returned when its recorded receive time (40 ms apart) is due: never
    # early, and not later than asked for (the waits are exactly the recorded intervals).
    arrivals = paced_arrivals(backend, clock, 6)
    np.testing.assert_allclose(arrivals, [0.04 * i for i in range(6)], atol=1e-9)
    assert len(clock.sleeps) == 5 and backend.health()['late'] == 0


def test_a_late_reader_gets_the_due_block_at_once_and_it_is_counted_late(tmp_path):
    bag = make_bag(tmp_path / 'bag', [(10 * i, 10, 1) for i in range(4)],
                   t_step_ns=40_000_000)
    clock = FakeClock()
    backend = started(ReplayBackend(str(bag), pacing='receive_time', clock=clock,
                                    sleep=clock.sleep))
    assert backend.read_block(timeout_s=1.0).first_sample_index == 0
    clock.now += 0.1                 # the reader comes back after blocks 1 and 2 were due
    assert [backend.read_block(timeout_s=1.0).first_sample_index for _ in range(2)] == [10, 20]
    assert clock.sleeps == [] and backend.health()['late'] == 2
    # Block 3 (due at 0.12 s) keeps its recorded time: the replay does not drift.
    assert backend.read_block(timeout_s=1.0).first_sample_index == 30
    np.testing.assert_allclose(clock.sleeps, [0.02], atol=1e-9)


def test_sample_clock_pacing_and_speed(tmp_path):
    # 10 blocks of 10 samples at 1 kHz: 0.1 s of signal, at speed 2: 0.05 s.
    bag = make_bag(tmp_path / 'bag', [(10 * i, 10, 1) for i in range(10)], t_step_ns=1)
    clock = FakeClock()
    backend = started(ReplayBackend(str(bag), pacing='sample_clock', speed=2.0, clock=clock,
                                    sleep=clock.sleep))
    t0 = clock.now
    blocks = [backend.read_block(timeout_s=0.5) for _ in range(10)]
    assert [b.first_sample_index for b in blocks] == list(range(0, 100, 10))
    # Block i is due when its last sample is: 10 (i + 1) samples at 1 kHz, at speed 2.
    np.testing.assert_allclose(np.cumsum(clock.sleeps), [0.005 * (i + 1) for i in range(10)],
                               atol=1e-9)
    assert clock.now - t0 == pytest.approx(0.05)


def test_the_real_clock_never_returns_a_block_early(tmp_path):
    # The default clock and sleep (time.monotonic, time.sleep): only a lower bound holds on
    # a real machine (a loaded one may return blocks later; the timing is bench/ material).
    bag = make_bag(tmp_path / 'bag', [(10 * i, 10, 1) for i in range(6)],
                   t_step_ns=40_000_000)
    backend = started(ReplayBackend(str(bag), pacing='receive_time'))
    t0 = time.monotonic()
    arrivals = []
    for _ in range(6):
        assert backend.read_block(timeout_s=scaled(1.0)) is not None
        arrivals.append(time.monotonic() - t0)
    assert all(t >= 0.04 * i - 0.005 for i, t in enumerate(arrivals)), arrivals


def test_writes_are_counted_and_ignored_and_config_must_match(tmp_path):
    bag = make_bag(tmp_path / 'bag', [(0, 10, 1), (10, 10, 1)])
    backend = ReplayBackend(str(bag), pacing='fast')
    with pytest.raises(DeviceError):
        backend.start()
    wrong = type(backend.recorded_config)(2000.0, 10, backend.recorded_config.inputs,
                                          backend.recorded_config.outputs)
    with pytest.raises(DeviceConfigError, match='1000.0 Hz'):
        backend.configure(wrong)
    started(backend)
    backend.write_setpoints(0, np.zeros((2, 25)))
    backend.set_function_generator([])
    health = backend.health()
    assert health['setpoint_writes_ignored'] == 1
    assert health['setpoint_samples_ignored'] == 25
    assert health['funcgen_requests_ignored'] == 1
    assert len(drain(backend)) == 2


def test_several_recorded_epochs_play_in_order_with_new_epochs(tmp_path):
    bag = make_bag(tmp_path / 'bag', [(0, 10, 1), (10, 10, 1), (0, 10, 2), (10, 10, 2)])
    backend = started(ReplayBackend(str(bag), pacing='fast'))
    blocks = drain(backend)
    assert [(b.first_sample_index, b.epoch) for b in blocks] == [
        (0, 1), (10, 1), (0, 2), (10, 2)]


def test_bad_bag_or_options_are_refused_with_a_reason(tmp_path):
    with pytest.raises(DeviceConfigError, match='needs bag'):
        create_backend('replay')
    with pytest.raises(DeviceConfigError, match='cannot read bag'):
        ReplayBackend(str(tmp_path / 'missing'))
    bag = make_bag(tmp_path / 'bag', [(0, 10, 1)], topic='/other')
    with pytest.raises(DeviceConfigError, match='no block stream'):
        ReplayBackend(str(bag))
    assert ReplayBackend(str(bag), topic='/other').n_blocks == 1
    with pytest.raises(DeviceConfigError, match='pacing'):
        ReplayBackend(str(bag), topic='/other', pacing='warp')
    with pytest.raises(DeviceConfigError, match='speed'):
        ReplayBackend(str(bag), topic='/other', speed=0.0)


def test_loop_restarts_in_a_new_epoch(tmp_path):
    bag = make_bag(tmp_path / 'bag', [(0, 10, 1), (10, 10, 1)])
    backend = started(ReplayBackend(str(bag), pacing='fast', loop=True))
    blocks = [backend.read_block(0.5) for _ in range(5)]
    assert [(b.first_sample_index, b.epoch) for b in blocks] == [
        (0, 1), (10, 1), (0, 2), (10, 2), (0, 3)]
    backend.stop()
    assert backend.read_block(timeout_s=scaled(0.01)) is None
