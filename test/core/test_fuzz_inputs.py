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
from emfc_ros.core.device.auth import ReplayGuard, Signer
from emfc_ros.core.device.backend import (check_generator_range, default_device_config,
                                          device_config_from_mapping)
from emfc_ros.core.device.emulator import Faults
from emfc_ros.core.device.errors import AuthenticationError, DeviceConfigError, ProtocolError
from emfc_ros.core.device.faults import FaultMonitor, faults_from_extra
from emfc_ros.core.device.function_generator import GeneratorSpec
from emfc_ros.core.device.registry import backend_from_mapping
from emfc_ros.core.errors import BlockError, ConfigError
from emfc_ros.core.excitation_queue import ExcitationQueue
from emfc_ros.core.json_text import JsonRefused, load_json_text

FUZZ = settings(max_examples=300, deadline=None,
                suppress_health_check=[HealthCheck.too_slow])

CONFIG = default_device_config()
VALID = [
    proto.encode_frame(proto.Frame(proto.STREAM_MEASUREMENT, 7, 2, 1000,
                                   np.arange(8, dtype=np.int16).reshape(2, 4))),
    proto.encode_message(proto.Message(proto.CONFIGURE, 3,
                                       body=proto.encode_configure_request(CONFIG, 5, 0))),
    proto.encode_message(proto.Message(proto.CONFIGURE, 3, proto.KIND_RESPONSE,
                                       body=proto.CONFIGURE_RESPONSE.pack(5, 77), session=77)),
    proto.encode_message(proto.Message(proto.FUNCGEN, 4, body=proto.encode_funcgen(
        [GeneratorSpec('sine', 0.5, 10.0), GeneratorSpec('off')]))),
    proto.encode_message(proto.Message(proto.HEARTBEAT, 5, proto.KIND_RESPONSE,
                                       body=proto.encode_heartbeat_reply(proto.HeartbeatReply(
                                           1, 2, 3, 4, proto.STATE_RUNNING, True, 5, 6, 7)))),
]


def _decode_any(data: bytes, key=None):
    """Decode as the host and the device would: a frame or a message and its body."""
    if data[:4] == proto.MAGIC_FRAME:
        frame = proto.decode_frame(data, key)
        again = proto.decode_frame(proto.encode_frame(frame))
        assert (again.sequence, again.epoch, again.first_sample_index) == (
            frame.sequence, frame.epoch, frame.first_sample_index)
        np.testing.assert_array_equal(again.samples, frame.samples)
        return frame
    msg = proto.decode_message(data, key)
    assert proto.decode_message(proto.encode_message(msg)) == msg
    body = msg.body
    if msg.type == proto.CONFIGURE and not msg.is_response:
        proto.decode_configure_request(body)
    elif msg.type == proto.CONFIGURE and msg.status == proto.OK:
        proto.decode_configure_response(body)
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


KEY = bytes(range(7, 39))
SESSIONS = st.integers(0, 2 ** 64 - 1)


def _signed_examples(session, rid):
    signer = Signer(KEY)
    return [
        proto.encode_frame(proto.Frame(proto.STREAM_MEASUREMENT, rid, 2, 1000,
                                       np.arange(8, dtype=np.int16).reshape(2, 4), session),
                           signer),
        proto.encode_frame(proto.Frame(proto.STREAM_SETPOINT, rid, 2, 5, np.ones((2, 3)),
                                       session), signer),
        proto.encode_message(proto.Message(proto.FUNCGEN, rid, body=proto.encode_funcgen(
            [GeneratorSpec('sine', 0.5, 10.0), GeneratorSpec('off')]), session=session),
            signer),
        proto.encode_message(proto.Message(proto.HEARTBEAT, rid, proto.KIND_RESPONSE,
                                           body=proto.encode_heartbeat_reply(
                                               proto.HeartbeatReply(1, 2, 3, 4, 0, False, 5,
                                                                    6, None, 7, 8, 9, 10)),
                                           session=session), signer)]


@FUZZ
@given(SESSIONS, st.integers(0, 2 ** 32 - 1))
def test_authenticated_datagrams_round_trip_with_any_session(session, rid):
    for data in _signed_examples(session, rid):
        item = _decode_any(data, KEY)
        assert item.session == session and item.auth_counter is not None


@FUZZ
@given(SESSIONS, st.integers(0, 3), st.data())
def test_no_mutated_authenticated_datagram_is_ever_accepted(session, which, data):
    """Any change to a signed datagram (the CRC resealed) fails; the original passes."""
    valid = _signed_examples(session, 7)[which]
    buf = bytearray(valid)
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(buf) - 5))
        buf[i] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(8, len(buf)))
    mutated = _with_crc(bytes(buf[:cut]) + b'\0\0\0\0')
    try:
        _decode_any(mutated, KEY)
    except ProtocolError:
        pass
    else:       # accepted: only if nothing changed at all
        assert mutated == valid, mutated.hex()
    try:        # without a key nothing is authentic, but nothing escapes either
        _decode_any(mutated)
    except ProtocolError:
        pass


@FUZZ
@given(st.binary(max_size=512), st.booleans())
def test_random_bytes_with_a_key_raise_only_protocol_errors(data, with_magic):
    if with_magic:
        data = (proto.MAGIC_CONTROL if data[:1] < b'\x80' else proto.MAGIC_FRAME) + \
            bytes([proto.VERSION]) + data
    for key in (KEY, None):
        try:
            _decode_any(_with_crc(data) if with_magic else data, key)
        except AuthenticationError as exc:
            assert exc.header is None or isinstance(exc.header, tuple)
            proto.header_of_refused(exc)
        except ProtocolError:
            pass


@FUZZ
@given(st.lists(st.integers(0, 2 ** 64 - 1) | st.integers(0, 40), max_size=200),
       st.integers(1, 16))
def test_a_replay_guard_accepts_no_counter_twice(counters, window):
    guard = ReplayGuard(window)
    accepted = [c for c in counters if guard.accept(c)]
    assert len(accepted) == len(set(accepted))
    # Strictly increasing counters (a sender's) are all accepted.
    fresh = ReplayGuard(window)
    assert all(fresh.accept(c) for c in sorted(set(counters)))


_CONFIG_VALUES = st.one_of(st.none(), st.booleans(), st.integers(-2 ** 70, 2 ** 70),
                           st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=6),
                           st.lists(st.floats(allow_nan=True) | st.text(max_size=4),
                                    max_size=4))
_CONFIG_KEYS = st.sampled_from(['sample_rate_Hz', 'block_size', 'watchdog_timeout_s',
                                'inputs', 'input_units', 'input_scales', 'input_offsets',
                                'outputs', 'output_min_V', 'output_max_V', 'output_safe_V',
                                'backend', 'udp', 'sim', 'bogus'])


@FUZZ
@given(st.dictionaries(_CONFIG_KEYS, _CONFIG_VALUES, max_size=6))
def test_device_configuration_validators_raise_only_config_errors(cfg):
    try:
        config = device_config_from_mapping(cfg)
    except ConfigError:
        pass
    else:
        assert 0 < config.sample_rate_Hz <= 1e7 and 0 < config.watchdog_timeout_s <= 3600
        assert all(c.min_V <= c.safe_V <= c.max_V for c in config.outputs)
    try:
        backend, _ = backend_from_mapping(dict(cfg, backend='sim') if 'backend' in cfg
                                          else cfg)
        backend.close()
    except ConfigError:
        pass


@FUZZ
@given(st.sampled_from(['off', 'sine', 'chirp', 'prbs', 'constant', 'square']),
       st.floats(allow_nan=True, allow_infinity=True), st.floats(-1e3, 1e3),
       st.floats(allow_nan=True, allow_infinity=True), st.floats(-20.0, 20.0))
def test_generator_specs_are_valid_within_the_limits_or_refused(waveform, amplitude, freq,
                                                                gain, offset):
    try:
        spec = GeneratorSpec(waveform, amplitude, abs(freq), gain=gain, offset_V=offset)
        check_generator_range([spec, GeneratorSpec()], CONFIG)
    except DeviceConfigError:
        return
    low = spec.offset_V - (0.0 if waveform in ('off', 'constant')
                           else abs(spec.gain * spec.amplitude_V))
    high = 2 * spec.offset_V - low
    if spec.active:
        assert -10.0 - 1e-9 <= low <= high <= 10.0 + 1e-9


@FUZZ
@given(st.text(max_size=60))
def test_fault_options_parse_or_refuse(text):
    try:
        Faults.parse(text)
    except DeviceConfigError:
        pass


@FUZZ
@given(st.integers(0, 3000), st.sampled_from(['[', '{"a":']), st.booleans())
def test_json_of_any_depth_is_parsed_within_bounds_or_refused(depth, opener, close):
    closer = ']' if opener == '[' else '}'
    text = opener * depth + ('0' if opener != '[' else '') + (closer * depth if close else '')
    try:
        doc = load_json_text(text)
    except JsonRefused:
        return
    assert close and depth <= 64 and doc is not None or depth == 0
