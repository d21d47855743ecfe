"""Device protocol: round trips of every message, fuzzed decoders, frame limits."""

import struct
import zlib

from hypothesis import given, HealthCheck, settings, strategies as st
import numpy as np
import pytest

from emfc_ros.core.device import protocol as proto
from emfc_ros.core.device.auth import KeyFileError, load_key_file, ReplayGuard, Signer
from emfc_ros.core.device.backend import default_device_config, InputChannel, OutputChannel
from emfc_ros.core.device.errors import AuthenticationError, ProtocolError
from emfc_ros.core.device.function_generator import GeneratorSpec

CONFIG = default_device_config(
    20000.0, 800, ('coil_current_A', 'sensor_V', 'coil_setpoint_V', 'position_m'),
    safe_V=(0.5, 0.0), limits_V=(-2.0, 3.0), watchdog_timeout_s=0.25)
SPECS = [GeneratorSpec('chirp', 0.5, 1.0, 100.0, 2.0, 'linear', 0.1, gain=2.0, offset_V=0.7),
         GeneratorSpec('prbs', 0.2, prbs_order=7, prbs_hold_samples=3)]


def _roundtrip(message):
    return proto.decode_message(proto.encode_message(message))


def test_int16_and_float64_frames_round_trip():
    codes = np.arange(-6, 6, dtype=np.int16).reshape(3, 4) * 1000
    frame = proto.Frame(proto.STREAM_MEASUREMENT, 2 ** 32 - 1, 7, 2 ** 53 - 5, codes,
                        2 ** 64 - 1)
    data = proto.encode_frame(frame)
    assert len(data) == proto.FRAME_HEADER.size + codes.size * 2 + 4 == 64
    back = proto.decode_frame(data)
    assert (back.stream_id, back.sequence, back.epoch, back.first_sample_index,
            back.session, back.auth_counter) == \
        (proto.STREAM_MEASUREMENT, 2 ** 32 - 1, 7, 2 ** 53 - 5, 2 ** 64 - 1, None)
    assert back.samples.dtype == np.int16 and np.array_equal(back.samples, codes)
    values = np.array([[0.1, -2.5e-3], [1e300, -0.0]])
    back = proto.decode_frame(proto.encode_frame(
        proto.Frame(proto.STREAM_SETPOINT, 0, 1, 12, values)))
    assert back.sample_format == proto.FORMAT_FLOAT64 and np.array_equal(back.samples, values)


def test_frame_layout_is_little_endian_with_crc_last():
    data = proto.encode_frame(proto.Frame(proto.STREAM_MEASUREMENT, 5, 2, 1000,
                                          np.array([[1, -1]], dtype=np.int16), 0xABCD))
    assert data[:4] == b'EMFD'
    assert struct.unpack_from('<BBBBQIIQHH', data, 4) == (2, 1, 1, 0, 0xABCD, 5, 2, 1000, 1, 2)
    assert data[36:40] == b'\x01\x00\xff\xff'
    assert struct.unpack('<I', data[-4:])[0] == zlib.crc32(data[:-4])
    msg = proto.encode_message(proto.Message(proto.HEARTBEAT, 42, session=0x0102,
                                             body=proto.HEARTBEAT_REQUEST.pack(123456789)))
    assert struct.unpack_from('<4sBBBBB3xIQI', msg) == (b'EMFC', 2, 4, 0, 0, 0, 42, 0x0102, 8)
    assert len(msg) == 28 + 8 + 4


def test_version_1_datagrams_are_refused_with_the_reason():
    head = struct.pack('<4sBBBBII', b'EMFC', 1, proto.START, 0, 0, 1, 0)
    with pytest.raises(ProtocolError, match='version 1.*version 2'):
        proto.decode_message(head + struct.pack('<I', zlib.crc32(head)))


def test_frames_larger_than_a_datagram_are_refused_and_the_limit_is_exact():
    n = proto.max_samples_per_frame(4, proto.FORMAT_INT16)
    assert n == (65507 - 36 - 24 - 4) // 8 == 8180     # room for counter and tag kept
    assert proto.frame_size(4, n, proto.FORMAT_INT16, True) <= proto.MAX_DATAGRAM_BYTES
    assert proto.frame_size(4, n + 1, proto.FORMAT_INT16, True) > proto.MAX_DATAGRAM_BYTES
    with pytest.raises(ProtocolError):
        proto.encode_frame(proto.Frame(1, 0, 0, 0, np.zeros((4, n + 1), dtype=np.int16)))
    with pytest.raises(ProtocolError, match='session'):
        proto.encode_frame(proto.Frame(1, 0, 0, 0, np.zeros((1, 1), dtype=np.int16), -1))


def test_corrupted_or_truncated_frames_raise_protocol_error():
    data = proto.encode_frame(proto.Frame(1, 3, 1, 0, np.ones((2, 10), dtype=np.int16)))
    for i in range(len(data)):
        bad = bytearray(data)
        bad[i] ^= 0x40
        with pytest.raises(ProtocolError):
            proto.decode_frame(bytes(bad))
    for n in range(len(data)):
        with pytest.raises(ProtocolError):
            proto.decode_frame(data[:n])
    nan = proto.encode_frame(proto.Frame(2, 0, 1, 0, np.array([[np.nan]])))
    with pytest.raises(ProtocolError, match='non-finite'):
        proto.decode_frame(nan)


def test_configure_round_trip_keeps_channels_scaling_and_limits():
    body = proto.encode_configure(CONFIG, 4321)
    msg = _roundtrip(proto.Message(proto.CONFIGURE, 17, body=body))
    assert (msg.type, msg.request_id, msg.is_response) == (proto.CONFIGURE, 17, False)
    config, port = proto.decode_configure(msg.body)
    assert config == CONFIG and port == 4321
    assert config.inputs[0] == InputChannel('coil_current_A', 'A', 20.0 / 65536 / 100.0)
    assert config.outputs[0] == OutputChannel('coil_V', -2.0, 3.0, 0.5)


def test_configure_with_invalid_values_is_a_protocol_error():
    body = bytearray(proto.encode_configure(CONFIG))
    struct.pack_into('<d', body, 0, float('nan'))
    with pytest.raises(ProtocolError, match='sample_rate_Hz'):
        proto.decode_configure(bytes(body))
    with pytest.raises(ProtocolError, match='trailing'):
        proto.decode_configure(proto.encode_configure(CONFIG) + b'\0')


def test_funcgen_start_stop_heartbeat_status_round_trip():
    msg = _roundtrip(proto.Message(proto.FUNCGEN, 1, body=proto.encode_funcgen(SPECS)))
    assert proto.decode_funcgen(msg.body) == SPECS
    for mtype in (proto.START, proto.STOP):
        assert _roundtrip(proto.Message(mtype, 9)) == proto.Message(mtype, 9)
    start = _roundtrip(proto.Message(proto.START, 9, proto.KIND_RESPONSE,
                                     body=proto.START_RESPONSE.pack(3, 0xDEADBEEF)))
    assert proto.START_RESPONSE.unpack(start.body) == (3, 0xDEADBEEF)
    beat = proto.HEARTBEAT_REQUEST.pack(123456789)
    assert _roundtrip(proto.Message(proto.HEARTBEAT, 2, body=beat)).body == beat
    for reply in (proto.HeartbeatReply(123456789, 5000, 3, 77, proto.STATE_RUNNING, True, 12, 1,
                                       4321),
                  proto.HeartbeatReply(123456789, 5000, 3, 77, proto.STATE_RUNNING, False, 0, 1),
                  proto.HeartbeatReply(1, 5000, 3, 77, proto.STATE_RUNNING, False, 0, 1, None,
                                       250, 1200, 2, 3100)):
        msg = _roundtrip(proto.Message(proto.HEARTBEAT, 2, proto.KIND_RESPONSE,
                                       body=proto.encode_heartbeat_reply(reply)))
        assert msg.is_response and proto.decode_heartbeat_reply(msg.body) == reply
    # A trip record without the flag (or the flag without a record) is malformed.
    none = proto.NO_INDEX
    bad = proto.HEARTBEAT_RESPONSE.pack(1, 2, 3, 4, proto.STATE_RUNNING, 0, 0, 0, 17, 0, none,
                                        0, none)
    with pytest.raises(proto.ProtocolError, match='trip index'):
        proto.decode_heartbeat_reply(bad)
    bad = proto.HEARTBEAT_RESPONSE.pack(1, 2, 3, 4, proto.STATE_RUNNING, 0, 0, 0, none, 0, 17,
                                        0, none)
    with pytest.raises(proto.ProtocolError, match='without a count'):
        proto.decode_heartbeat_reply(bad)
    counters = {name: i * 1000 for i, name in enumerate(proto.DEVICE_COUNTERS)}
    status = proto.StatusReply(3, 77, proto.STATE_CONFIGURED, False, counters,
                               proto.encode_configure(CONFIG), True, True)
    msg = _roundtrip(proto.Message(proto.STATUS, 4, proto.KIND_RESPONSE,
                                   body=proto.encode_status_reply(status)))
    back = proto.decode_status_reply(msg.body)
    assert back == status and back.config() == CONFIG


def test_error_response_carries_status_and_text():
    msg = _roundtrip(proto.Message(proto.START, 5, proto.KIND_RESPONSE, proto.BAD_STATE,
                                   'start before configure'.encode()))
    assert msg.status == proto.BAD_STATE and msg.error_text() == 'start before configure'


def test_out_of_range_fields_are_refused_when_encoding():
    with pytest.raises(ProtocolError):
        proto.encode_message(proto.Message(99, 1))
    with pytest.raises(ProtocolError):
        proto.encode_frame(proto.Frame(1, 2 ** 32, 0, 0, np.zeros((1, 1), dtype=np.int16)))
    with pytest.raises(ProtocolError, match='int16'):
        proto.encode_frame(proto.Frame(1, 0, 0, 0, np.array([[40000]], dtype=np.int32)))


BODY_DECODERS = (proto.decode_configure, proto.decode_funcgen, proto.decode_heartbeat_reply,
                 proto.decode_status_reply, proto.decode_configure_request,
                 proto.decode_configure_response)
FUZZ = settings(max_examples=300, deadline=None,
                suppress_health_check=[HealthCheck.too_slow])


def _only_protocol_errors(fn, data):
    try:
        fn(data)
    except ProtocolError:
        pass


@FUZZ
@given(st.binary(max_size=200))
def test_fuzz_random_bytes_raise_only_protocol_error(data):
    for fn in (proto.decode_frame, proto.decode_message) + BODY_DECODERS:
        _only_protocol_errors(fn, data)
        _only_protocol_errors(fn, proto.MAGIC_FRAME + b'\x01' + data)
        _only_protocol_errors(fn, proto.MAGIC_CONTROL + b'\x01' + data)


def _with_crc(head: bytes) -> bytes:
    return head + struct.pack('<I', zlib.crc32(head))


@FUZZ
@given(st.integers(0, 255), st.integers(0, 255), st.integers(0, 255), st.integers(0, 2 ** 32 - 1),
       st.integers(0, 2 ** 64 - 1), st.integers(0, 65535), st.integers(0, 65535),
       st.binary(max_size=64))
def test_fuzz_frames_with_valid_crc_raise_only_protocol_error(stream, fmt, flags, seq, first,
                                                              n_ch, n_s, payload):
    head = struct.pack('<4sBBBBQIIQHH', b'EMFD', 2, stream, fmt, flags, seq, seq, 0, first,
                       n_ch, n_s)
    _only_protocol_errors(proto.decode_frame, _with_crc(head + payload))


@FUZZ
@given(st.integers(0, 255), st.integers(0, 255), st.integers(0, 255), st.integers(0, 70000),
       st.binary(max_size=300))
def test_fuzz_control_messages_with_valid_crc_raise_only_protocol_error(mtype, kind, status,
                                                                        length, body):
    head = struct.pack('<4sBBBBB3xIQI', b'EMFC', 2, mtype, kind, status, status & 1, 1,
                       length, length) + body
    _only_protocol_errors(proto.decode_message, _with_crc(head))
    for fn in BODY_DECODERS:
        _only_protocol_errors(fn, body)


@FUZZ
@given(st.binary(min_size=1, max_size=1), st.integers(0, 2000))
def test_fuzz_mutated_valid_bodies_raise_only_protocol_error(byte, position):
    for body in (proto.encode_configure(CONFIG), proto.encode_funcgen(SPECS),
                 proto.encode_configure_request(CONFIG, 99)):
        pos = position % len(body)
        mutated = body[:pos] + byte + body[pos + 1:]
        for fn in BODY_DECODERS:
            _only_protocol_errors(fn, mutated)
            _only_protocol_errors(fn, mutated[:pos])


@FUZZ
@given(st.integers(1, 8), st.integers(1, 300), st.integers(0, 2 ** 32 - 1),
       st.integers(0, 2 ** 53 - 1), st.integers(0, 2 ** 32 - 1), st.booleans(),
       st.integers(0, 2 ** 32 - 1))
def test_fuzz_valid_frames_round_trip(n_ch, n_s, seq, first, epoch, as_int, seed):
    rng = np.random.default_rng(seed)
    if as_int:
        samples = rng.integers(-32768, 32768, n_ch * n_s).astype(np.int16)
    else:
        samples = rng.standard_normal(n_ch * n_s) * 10.0 ** rng.integers(-300, 300, n_ch * n_s)
    frame = proto.Frame(proto.STREAM_SETPOINT, seq, epoch, first, samples.reshape(n_ch, n_s))
    back = proto.decode_frame(proto.encode_frame(frame))
    assert (back.sequence, back.epoch, back.first_sample_index) == (seq, epoch, first)
    assert back.samples.dtype == frame.samples.dtype
    assert np.array_equal(back.samples, frame.samples)


def test_configure_request_and_response_carry_nonce_and_session():
    body = proto.encode_configure_request(CONFIG, 2 ** 64 - 2, 4321)
    nonce, config, port, config_body = proto.decode_configure_request(body)
    assert (nonce, config, port) == (2 ** 64 - 2, CONFIG, 4321)
    assert config_body == proto.encode_configure(CONFIG, 4321)
    assert proto.decode_configure_response(proto.CONFIGURE_RESPONSE.pack(5, 77)) == (5, 77)
    with pytest.raises(ProtocolError, match='session id 0'):
        proto.decode_configure_response(proto.CONFIGURE_RESPONSE.pack(5, 0))


KEY = bytes(range(32))


def test_authenticated_datagrams_round_trip_and_every_mismatch_is_an_authentication_error():
    signer = Signer(KEY)
    frame = proto.Frame(proto.STREAM_SETPOINT, 3, 1, 100, np.ones((2, 5)), 42)
    data = proto.encode_frame(frame, signer)
    assert len(data) == proto.frame_size(2, 5, proto.FORMAT_FLOAT64, True)
    back = proto.decode_frame(data, KEY)
    assert back.session == 42 and back.auth_counter >= 1
    msg = proto.Message(proto.FUNCGEN, 7, body=proto.encode_funcgen(SPECS), session=42)
    signed = proto.encode_message(msg, signer)
    got = proto.decode_message(signed, KEY)
    assert got == msg and got.auth_counter > back.auth_counter   # counters increase
    # The key on one side only, another key, or any flipped bit (CRC resealed): refused.
    with pytest.raises(AuthenticationError, match='no key'):
        proto.decode_message(signed)
    with pytest.raises(AuthenticationError, match='not authenticated'):
        proto.decode_message(proto.encode_message(msg), KEY)
    with pytest.raises(AuthenticationError, match='does not match'):
        proto.decode_message(signed, bytes(32))
    for i in range(len(signed) - 4):
        bad = bytearray(signed[:-4])
        bad[i] ^= 0x01
        if i == 8:          # the flags byte: then the datagram claims no tag at all
            continue
        with pytest.raises(ProtocolError):
            proto.decode_message(_with_crc(bytes(bad)), KEY)
    # A refused request keeps its header, so that the device can say why.
    try:
        proto.decode_message(proto.encode_message(msg), KEY)
    except AuthenticationError as exc:
        refused = proto.header_of_refused(exc)
    assert (refused.type, refused.request_id, refused.session) == (proto.FUNCGEN, 7, 42)


def test_replay_guard_accepts_each_counter_once_and_tolerates_reordering():
    guard = ReplayGuard(window=4)
    assert [guard.accept(c) for c in (10, 12, 11, 12, 10)] == [True, True, True, False, False]
    for c in (13, 14, 15):
        assert guard.accept(c)
    # 10 and 12 were forgotten (window 4): nothing at or below 12 is taken any more.
    assert not guard.accept(12) and not guard.accept(9) and guard.accept(16)


def test_signer_counters_increase_and_stay_above_the_wall_clock():
    clock = iter([1000, 1000, 5000, 10]).__next__
    signer = Signer(KEY, clock_ns=clock)
    assert [signer.next_counter() for _ in range(4)] == [1000, 1001, 5000, 5001]


def test_key_files_are_refused_unless_readable_private_hex_and_long(tmp_path):
    good = tmp_path / 'good.key'
    good.write_text(KEY.hex() + '\n')
    good.chmod(0o600)
    assert load_key_file(good) == KEY
    cases = {'missing.key': None, 'short.key': 'aa' * 15, 'text.key': 'not hex at all',
             'open.key': KEY.hex()}
    messages = {'missing.key': 'cannot be read', 'short.key': 'at least 16',
                'text.key': 'hexadecimal', 'open.key': 'chmod 600'}
    for name, text in cases.items():
        path = tmp_path / name
        if text is not None:
            path.write_text(text)
            path.chmod(0o644 if name == 'open.key' else 0o600)
        with pytest.raises(KeyFileError, match=messages[name]):
            load_key_file(path)
    with pytest.raises(KeyFileError, match='not a regular file'):
        load_key_file(tmp_path)


def _doc_examples():
    """The hex dumps of docs/device_protocol.md, in order, as bytes."""
    import re
    from pathlib import Path
    text = (Path(__file__).resolve().parents[2] / 'docs' / 'device_protocol.md').read_text()
    dumps, rows, inside = [], [], False
    for line in text.splitlines():
        if line.startswith('```'):
            if inside and rows:
                dumps.append(bytes.fromhex(''.join(rows)))
            inside, rows = not inside, []
        elif inside and re.match(r'^[0-9a-f]{4}  ', line):
            rows.append(''.join(line[6:53].split()))
    return dumps


def test_the_documented_examples_are_what_the_code_sends():
    frame, beat, signed = _doc_examples()
    session = 0x1122334455667788
    assert frame == proto.encode_frame(proto.Frame(
        proto.STREAM_MEASUREMENT, 5, 1, 1000,
        np.array([[100, -100, 2524, 32767], [0, 1, -1, -32768]], dtype=np.int16), session))
    message = proto.Message(proto.HEARTBEAT, 42, body=proto.HEARTBEAT_REQUEST.pack(123456789),
                            session=session)
    assert beat == proto.encode_message(message)
    key = bytes(range(32))
    assert signed == proto.encode_message(message, Signer(key, lambda: 1700000000000000000))
    assert proto.decode_message(signed, key) == message
