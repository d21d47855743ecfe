"""
Property-based fuzzing of what arrives from outside: device datagrams, blocks, fault records.

Whatever the bytes or values, each decoder either returns a valid object or raises its one
error class (``ProtocolError``, ``BlockError``, ``ValueError``); nothing else escapes, and a
decoded object encodes back to the same bytes. The setpoint queue keeps its invariants under
any sequence of blocks, refusals included.
"""

import struct
import zlib

from hypothesis import given, HealthCheck, settings, strategies as st
import numpy as np
import pytest

from emfc_ros.core import blocks
from emfc_ros.core.blocks import Block
from emfc_ros.core.device import protocol as proto
from emfc_ros.core.device.backend import default_device_config
from emfc_ros.core.device.errors import ProtocolError
from emfc_ros.core.device.faults import FaultMonitor, faults_from_extra
from emfc_ros.core.device.function_generator import GeneratorSpec
from emfc_ros.core.errors import BlockError
from emfc_ros.core.excitation_queue import ExcitationQueue

FUZZ = settings(max_examples=300, deadline=None,
                suppress_health_check=[HealthCheck.too_slow])

CONFIG = default_device_config()
VALID = [
    proto.encode_frame(proto.Frame(proto.STREAM_MEASUREMENT, 7, 2, 1000,
                                   np.arange(8, dtype=np.int16).reshape(2, 4))),
    proto.encode_message(proto.Message(proto.CONFIGURE, 3,
                                       body=proto.encode_configure(CONFIG, 0))),
    proto.encode_message(proto.Message(proto.FUNCGEN, 4, body=proto.encode_funcgen(
        [GeneratorSpec('sine', 0.5, 10.0), GeneratorSpec('off')]))),
    proto.encode_message(proto.Message(proto.HEARTBEAT, 5, proto.KIND_RESPONSE,
                                       body=proto.encode_heartbeat_reply(proto.HeartbeatReply(
                                           1, 2, 3, 4, proto.STATE_RUNNING, True, 5, 6, 7)))),
]


def _decode_any(data: bytes):
    """Decode as the host and the device would: a frame or a message and its body."""
    if data[:4] == proto.MAGIC_FRAME:
        frame = proto.decode_frame(data)
        again = proto.decode_frame(proto.encode_frame(frame))
        assert (again.sequence, again.epoch, again.first_sample_index) == (
            frame.sequence, frame.epoch, frame.first_sample_index)
        np.testing.assert_array_equal(again.samples, frame.samples)
        return frame
    msg = proto.decode_message(data)
    assert proto.decode_message(proto.encode_message(msg)) == msg
    body = msg.body
    if msg.type == proto.CONFIGURE and not msg.is_response:
        proto.decode_configure(body)
    elif msg.type == proto.FUNCGEN and not msg.is_response:
        proto.decode_funcgen(body)
    elif msg.type == proto.HEARTBEAT and msg.is_response:
        reply = proto.decode_heartbeat_reply(body)
        assert proto.decode_heartbeat_reply(proto.encode_heartbeat_reply(reply)) == reply
    elif msg.type == proto.STATUS and msg.is_response:
        proto.decode_status_reply(body)
    return msg


def _with_crc(data: bytes) -> bytes:
    """Re-seal mutated bytes with a valid CRC, so the checks behind the CRC are reached."""
    body = data[:-4]
    return body + struct.pack('<I', zlib.crc32(body) & 0xFFFFFFFF)


@FUZZ
@given(st.binary(max_size=2048))
def test_random_datagrams_never_escape_protocol_error(data):
    try:
        _decode_any(data)
    except ProtocolError:
        pass


@FUZZ
@given(st.sampled_from(VALID), st.data())
def test_mutated_valid_datagrams_with_a_valid_crc(valid, data):
    """Flip bytes of a valid datagram and re-seal it: the field checks must hold."""
    buf = bytearray(valid)
    for _ in range(data.draw(st.integers(1, 6))):
        i = data.draw(st.integers(0, len(buf) - 5))
        buf[i] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(8, len(buf)))
    try:
        _decode_any(_with_crc(bytes(buf[:cut]) + b'\0\0\0\0'))
    except ProtocolError:
        pass


def test_the_crc_seal_reaches_the_field_checks():
    """The mutation test above is only worth something if resealed bytes pass the CRC."""
    for valid in VALID:
        assert _decode_any(_with_crc(valid)) is not None


@FUZZ
@given(st.lists(st.tuples(st.sampled_from(['channel', 'sample', 'x']),
                          st.integers(-2, 2 ** 40), st.integers(-2, 2 ** 40)),
                max_size=3),
       st.integers(-1, 5),
       st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=40))
def test_block_layouts_and_headers_never_escape_block_error(dims, offset, values):
    try:
        block = blocks.unpack(dims, offset, np.asarray(values, dtype=np.float64))
    except BlockError:
        return
    assert block.n_samples <= blocks.MAX_BLOCK_SAMPLES
    assert 0 <= block.first_sample_index < blocks.MAX_EXACT_INDEX
    assert block.sample_rate_Hz > 0


_BLOCKS = st.lists(st.tuples(st.integers(0, 2 ** 53 - 1) | st.integers(0, 3000),
                             st.integers(1, 50), st.integers(0, 2),
                             st.sampled_from([0.0, 1.0, np.nan, np.inf])),
                   max_size=40)


@FUZZ
@given(_BLOCKS, st.lists(st.integers(0, 200), max_size=40))
def test_the_setpoint_queue_keeps_its_invariants(pushes, pops):
    q = ExcitationQueue([0.0, 0.0], max_samples=5000, max_gap_samples=1000)
    reads = iter(pops)
    for first, n, epoch, value in pushes:
        samples = np.full((2, n), value)
        before = q.counters()
        try:
            q.push(Block(first, 100.0, epoch, samples))
        except BlockError:
            # Refused blocks change nothing but their counters.
            after = q.counters()
            assert after['queued_samples'] == before['queued_samples']
        assert 0 <= q.queued <= 5000
        n_read = next(reads, 0)
        head, queued = getattr(q, 'head_index', None), q.queued
        out, real = q.pop(n_read)
        assert out.shape == (2, n_read) and real == min(n_read, queued)
        assert np.all(np.isfinite(out))
        if head is not None:        # stream samples advance the index, padding does not
            assert q.head_index == head + real


_HEALTH = st.dictionaries(
    st.sampled_from(['device_watchdog_tripped', 'device_watchdog_trip_index',
                     'device_underrun_samples', 'device_silent_ms', 'reconnects']),
    st.integers(-5, 2 ** 64) | st.text(max_size=5) | st.none() | st.floats())


@FUZZ
@given(st.lists(_HEALTH, max_size=10))
def test_fault_monitor_takes_any_health_report(reports):
    monitor = FaultMonitor()
    monitor.reset({})
    kinds = []
    for health in reports:
        for fault in monitor.observe(health, 1000, 900, 0.5):
            kinds.append(fault.kind)
    # Each kind is latched once; the list the bridge publishes parses back.
    assert len(kinds) == len(set(kinds))
    assert faults_from_extra({'faults': [f.to_dict() for f in monitor.faults]}) == \
        list(monitor.faults)


@FUZZ
@given(st.recursive(st.none() | st.booleans() | st.integers() | st.text(max_size=8),
                    lambda inner: st.lists(inner, max_size=3)
                    | st.dictionaries(st.text(max_size=8), inner, max_size=3),
                    max_leaves=10))
def test_any_fault_record_is_parsed_or_refused(doc):
    try:
        faults_from_extra({'faults': doc})
    except ValueError:
        pass


@pytest.mark.parametrize('spec', [dict(amplitude_V=1e9), dict(offset_V=-1e3),
                                  dict(amplitude_V=50.0, gain=10.0)])
def test_function_generator_refuses_absurd_voltages(spec):
    with pytest.raises(ValueError, match='100 V'):
        GeneratorSpec('sine', frequency_Hz=10.0, **spec)
