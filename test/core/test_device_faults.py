"""Latched device faults: from a back-end's health to faults, positions and their text."""

import socket
import time

import pytest

from emfc_ros.core.device import protocol as proto
from emfc_ros.core.device.backend import default_device_config
from emfc_ros.core.device.emulator import DeviceEmulator
from emfc_ros.core.device.faults import describe, Fault, FaultMonitor, faults_from_extra
from ros_harness import scaled

RATE = 10000.0


def test_a_clean_run_latches_nothing():
    monitor = FaultMonitor()
    health = {'device_watchdog_tripped': 0, 'device_watchdog_trip_index': -1,
              'device_underrun_samples': 120, 'device_watchdog_trips': 2, 'reconnects': 1,
              'device_silent_ms': 30}
    monitor.reset(health, epoch=3)     # counters of earlier runs are the baseline
    assert monitor.observe(health, 50000, 49000, 1.0) == []
    assert monitor.faults == ()


def test_device_watchdog_uses_the_devices_trip_record():
    monitor = FaultMonitor()
    monitor.reset({}, epoch=2)
    tripped = {'device_watchdog_tripped': 1, 'device_watchdog_trip_index': 12345}
    new = monitor.observe(tripped, 20000, 19000, 1.0)
    assert [f.kind for f in new] == ['device_watchdog']
    fault = new[0]
    assert (fault.device_index, fault.samples, fault.exact, fault.epoch) == (12345, None, True, 2)
    assert monitor.observe(tripped, 21000, 20000, 1.0) == []       # latched once
    # Experiment sample 0 at device sample 1000, 30000 samples: 11345 on were not applied.
    assert fault.experiment_range(1000, 30000) == (11345, 30000)
    text = describe([fault], 1000, 30000, RATE)
    assert 'experiment samples 11345 to 29999 not applied' in text
    assert '1.135 s to 3.000 s' in text
    # Without the device's record the host's estimate is used and said to be one.
    other = FaultMonitor()
    other.reset({})
    est = other.observe({'device_watchdog_tripped': 1}, 20000, 19000, 1.0)[0]
    assert (est.device_index, est.exact) == (20000, False)
    assert 'about experiment samples 19000' in describe([est], 1000, 30000)


def test_underruns_grow_one_fault_and_silence_or_reconnects_mean_a_lost_device():
    monitor = FaultMonitor()
    monitor.reset({'device_underrun_samples': 10, 'reconnects': 0})
    first = monitor.observe({'device_underrun_samples': 60}, 5000, 4000, 1.0)
    assert [(f.kind, f.device_index, f.samples) for f in first] == [
        ('device_underrun', 4950, 50)]
    assert monitor.observe({'device_underrun_samples': 90}, 6000, 5000, 1.0) == []
    (under,) = monitor.faults
    assert under.samples == 80
    lost = monitor.observe({'device_underrun_samples': 90, 'device_silent_ms': 1500}, 7000,
                           5000, 1.0)
    assert [(f.kind, f.device_index) for f in lost] == [('device_lost', 5000)]
    assert '1.50 s' in lost[0].message
    again = FaultMonitor()
    again.reset({'reconnects': 2})
    assert again.observe({'reconnects': 2, 'device_silent_ms': 900}, 1, 1, 1.0) == []
    assert [f.kind for f in again.observe({'reconnects': 3}, 1, 1, 1.0)] == ['device_lost']
    # The back-end's own verdict (a silence it proved), or a session the device dropped.
    for key in ('device_losses', 'sessions_lost'):
        monitor = FaultMonitor()
        monitor.reset({key: 4})
        assert monitor.observe({key: 4}, 1, 1, 1.0) == []
        (fault,) = monitor.observe({key: 5}, 1, 1, 1.0)
        assert fault.kind == 'device_lost'
        assert ('session' in fault.message) == (key == 'sessions_lost')


def test_a_driver_fault_widens_the_same_kind_and_keeps_the_driver_s_text():
    monitor = FaultMonitor()
    monitor.reset({}, epoch=1)
    first = monitor.observe({'device_underrun_samples': 2222}, 12013, 11000, 1.0)
    assert [f.kind for f in first] == ['device_underrun'] and first[0].samples == 2222
    text = 'writing the outputs: NI-DAQmx error -200290: The generation has stopped'
    assert monitor.add_reported('device_underrun', 9798, text, True) is None
    (fault,) = monitor.faults
    assert (fault.device_index, fault.samples, fault.exact) == (9798, None, True)
    assert text in fault.message and '2222 samples' in fault.message
    assert monitor.take_grown()
    # to the end of the epoch: more host-side underruns do not shrink it or drop the text
    monitor.observe({'device_underrun_samples': 5000}, 15000, 14000, 1.0)
    assert monitor.faults == (fault,)
    assert monitor.add_reported('device_underrun', 9798, text, True) is None   # said once
    lost = monitor.add_reported('device_lost', 20000, 'reading the inputs: NI-DAQmx error '
                                '-200045: The device has been removed from the system.')
    assert lost is not None and lost.samples is None and len(monitor.faults) == 2


def test_setpoint_gaps_and_refused_frames_are_faults_at_the_devices_record():
    monitor = FaultMonitor()
    monitor.reset({'device_gap_filled_samples': 7, 'device_setpoint_frames_rejected': 1},
                  epoch=4)
    clean = {'device_gap_filled_samples': 7, 'device_setpoint_frames_rejected': 1,
             'device_first_gap_index': -1, 'device_first_rejected_index': -1}
    assert monitor.observe(clean, 9000, 8000, 1.0) == []
    (gap,) = monitor.observe(dict(clean, device_gap_filled_samples=507,
                                  device_first_gap_index=4321), 9000, 8000, 1.0)
    assert (gap.kind, gap.device_index, gap.exact, gap.epoch) == (
        'device_setpoint_gap', 4321, True, 4)
    assert '500 setpoint samples' in gap.message
    (refused,) = monitor.observe(dict(clean, device_setpoint_frames_rejected=3,
                                      device_first_rejected_index=-1), 9500, 8000, 1.0)
    assert (refused.kind, refused.device_index, refused.exact) == (
        'device_setpoint_rejected', 9500, False)
    # Offset 1000, 10000 experiment samples: the gap from device sample 4321 on.
    assert 'experiment samples 3321 to 9999 not applied' in describe([gap], 1000, 10000)


def test_faults_round_trip_through_a_description_and_fall_inside_or_outside():
    faults = [Fault('emergency_stop', 700, None, 'e-stop', False, 1),
              Fault('device_underrun', 100, 20, 'late', False, 1)]
    back = faults_from_extra({'faults': [f.to_dict() for f in faults]})
    assert back == faults
    assert faults_from_extra({}) == []
    with pytest.raises(ValueError, match='list'):
        faults_from_extra({'faults': 'broken'})
    with pytest.raises(ValueError, match='kind'):
        faults_from_extra({'faults': [{'kind': 'bogus'}]})
    with pytest.raises(ValueError, match='malformed'):
        faults_from_extra({'faults': [{'device_index': 3}]})
    # Offset 500: the underrun at device samples 100-119 lies before the experiment.
    assert faults[1].experiment_range(500, 1000) == (0, 0)
    assert 'outside the experiment' in describe(faults[1:], 500, 1000)
    assert faults[0].experiment_range(None, 1000) is None
    assert 'device sample 700 of epoch 1' in describe(faults[:1])


def _request(sock, device, mtype, rid, body=b'', session=0):
    sock.sendto(proto.encode_message(proto.Message(mtype, rid, body=body, session=session)),
                device)
    deadline = time.monotonic() + scaled(5.0)
    while time.monotonic() < deadline:
        data, _ = sock.recvfrom(65536)
        if data[:4] != b'EMFC':
            continue                                # a measurement frame
        msg = proto.decode_message(data)
        if msg.is_response and msg.request_id == rid:
            assert msg.status == proto.OK, msg
            return msg.body
    raise AssertionError(f'no answer to request {rid}')


def test_emulator_reports_its_trip_record_in_the_heartbeat():
    """A host that goes quiet trips the emulator; its heartbeat reply carries the index."""
    config = default_device_config(watchdog_timeout_s=0.3)
    emulator = DeviceEmulator(port=0, seed=1, max_inputs=len(config.inputs))
    port = emulator.start()
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(('127.0.0.1', 0))
    sock.settimeout(1.0)
    device = ('127.0.0.1', port)
    try:
        _, session = proto.decode_configure_response(_request(
            sock, device, proto.CONFIGURE, 1, proto.encode_configure_request(config, 5, 0)))
        _request(sock, device, proto.START, 2, session=session)
        beat = proto.HEARTBEAT_REQUEST.pack(0)
        reply = proto.decode_heartbeat_reply(_request(sock, device, proto.HEARTBEAT, 3, beat,
                                                      session))
        assert not reply.watchdog_tripped and reply.watchdog_trip_index is None
        time.sleep(0.8)                             # quiet for longer than 0.3 s
        reply = proto.decode_heartbeat_reply(_request(sock, device, proto.HEARTBEAT, 4, beat,
                                                      session))
        assert reply.watchdog_tripped
        trip = reply.watchdog_trip_index
        assert trip == emulator.device.watchdog_trip_index
        assert 0 < trip <= reply.next_sample_index
        monitor = FaultMonitor()
        monitor.reset({})
        health = {'device_watchdog_tripped': 1, 'device_watchdog_trip_index': trip}
        (fault,) = monitor.observe(health, reply.next_sample_index, 0, 1.0)
        assert (fault.kind, fault.device_index, fault.exact) == ('device_watchdog', trip, True)
    finally:
        sock.close()
        emulator.stop()
