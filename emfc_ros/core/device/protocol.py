"""
The binary UDP protocol between host and device: block frames and control messages (version 2).

Everything is little-endian; every datagram ends in the CRC-32 (``zlib.crc32``) of all the
bytes before it. Every datagram carries the 64-bit session id the device issued to its
owner at CONFIGURE (0 before there is one). With a pre-shared key (flag bit 0 set), a
64-bit counter and a truncated HMAC-SHA256 tag (:mod:`emfc_ros.core.device.auth`) come
between the payload and the CRC. The full specification, with tables, is
``docs/device_protocol.md``.

Block frame (``MAGIC_FRAME``, both directions)::

    0  4s  magic b'EMFD'        16  I  sequence number
    4  B   version (2)          20  I  epoch
    5  B   stream id            24  Q  first sample index
    6  B   sample format        32  H  channel count C
    7  B   flags (bit 0: auth)  34  H  samples per channel N
    8  Q   session id           36     payload, channel-major, C*N samples
                                [end-28  Q counter, 16s tag: with the auth flag]
                                end-4  I  CRC-32 of bytes [0, end-4)

Control message (``MAGIC_CONTROL``)::

    0  4s  magic b'EMFC'        8   B  flags (bit 0: auth), 3 bytes padding
    4  B   version (2)          12  I  request id
    5  B   message type         16  Q  session id
    6  B   kind (0 request,     24  I  body length L
           1 response)          28     body, L bytes
    7  B   status (0 OK)        [end-28  Q counter, 16s tag: with the auth flag]
                                end-4  I  CRC-32 of bytes [0, end-4)

Every decoder raises :class:`ProtocolError` (an authentication failure:
:class:`AuthenticationError`, a subclass) and nothing else, whatever the input bytes.
"""

from __future__ import annotations

import dataclasses
import hmac
import struct
from typing import Dict, List, Optional, Sequence, Tuple
import zlib

import numpy as np

from emfc_ros.core.blocks import MAX_EXACT_INDEX
from emfc_ros.core.device.auth import AUTH_TRAILER, Signer, tag
from emfc_ros.core.device.backend import DeviceConfig, InputChannel, OutputChannel
from emfc_ros.core.device.errors import AuthenticationError, DeviceConfigError, ProtocolError
from emfc_ros.core.device.function_generator import CHIRP_METHODS, GeneratorSpec, WAVEFORMS

VERSION = 2
MAGIC_FRAME = b'EMFD'
MAGIC_CONTROL = b'EMFC'
CRC = struct.Struct('<I')
#: Largest UDP payload of IPv4 (65535 - 20 IP - 8 UDP bytes).
MAX_DATAGRAM_BYTES = 65507

FRAME_HEADER = struct.Struct('<4sBBBBQIIQHH')
#: Flag bit: the datagram carries a counter and an HMAC tag before its CRC.
FLAG_AUTH = 0x01
#: Largest session id (u64); 0 means "no session".
MAX_SESSION = 2 ** 64 - 1
STREAM_MEASUREMENT = 1
STREAM_SETPOINT = 2
STREAMS = (STREAM_MEASUREMENT, STREAM_SETPOINT)
FORMAT_INT16 = 1
FORMAT_FLOAT64 = 2
FORMAT_DTYPES = {FORMAT_INT16: np.dtype('<i2'), FORMAT_FLOAT64: np.dtype('<f8')}

CONTROL_HEADER = struct.Struct('<4sBBBBB3xIQI')
KIND_REQUEST = 0
KIND_RESPONSE = 1
CONFIGURE = 1
START = 2
STOP = 3
HEARTBEAT = 4
STATUS = 5
FUNCGEN = 6
RELEASE = 7
MESSAGE_TYPES = {CONFIGURE: 'CONFIGURE', START: 'START', STOP: 'STOP', HEARTBEAT: 'HEARTBEAT',
                 STATUS: 'STATUS', FUNCGEN: 'FUNCGEN', RELEASE: 'RELEASE'}
OK = 0
BAD_REQUEST = 1
BAD_STATE = 2
UNSUPPORTED = 3
#: CONFIGURE refused: another session owns the device and is alive.
BUSY = 4
#: The request needs the owner's session (and address).
NOT_OWNER = 5
#: The datagram's authentication does not match the device's (missing tag, no key, bad tag).
AUTH_REQUIRED = 6
STATUS_NAMES = {OK: 'OK', BAD_REQUEST: 'BAD_REQUEST', BAD_STATE: 'BAD_STATE',
                UNSUPPORTED: 'UNSUPPORTED', BUSY: 'BUSY', NOT_OWNER: 'NOT_OWNER',
                AUTH_REQUIRED: 'AUTH_REQUIRED'}

#: Device states.
STATE_IDLE = 0
STATE_CONFIGURED = 1
STATE_RUNNING = 2
STATE_NAMES = {STATE_IDLE: 'idle', STATE_CONFIGURED: 'configured', STATE_RUNNING: 'running'}

CONFIGURE_FIXED = struct.Struct('<dHHHHd')
#: CONFIGURE request: a host nonce before the configuration; response: its echo and the
#: session id.
CONFIGURE_NONCE = struct.Struct('<Q')
CONFIGURE_RESPONSE = struct.Struct('<QQ')
INPUT_FIXED = struct.Struct('<dd')
OUTPUT_FIXED = struct.Struct('<ddddd')
START_RESPONSE = struct.Struct('<II')
HEARTBEAT_REQUEST = struct.Struct('<Q')
HEARTBEAT_RESPONSE = struct.Struct('<QQIIBBxxQQQQQQQ')
#: A sample index field that holds nothing (no trip, no gap, no refused frame).
NO_INDEX = 2 ** 64 - 1
NO_TRIP_INDEX = NO_INDEX
FUNCGEN_COUNT = struct.Struct('<H')
FUNCGEN_ENTRY = struct.Struct('<BBBBIddddddd')
STATUS_FIXED = struct.Struct('<IIBBBBH')
#: Device counters of the STATUS response, each a u64, in this order.
DEVICE_COUNTERS = (
    'frames_sent', 'samples_sent', 'setpoint_frames_received', 'setpoint_frames_rejected',
    'setpoint_gaps', 'setpoint_duplicates', 'setpoint_reordered', 'setpoint_late_samples',
    'underrun_samples', 'gap_filled_samples', 'clamped_samples', 'heartbeats_received',
    'watchdog_trips', 'foreign_datagrams', 'corrupt_datagrams', 'late_blocks',
    'faults_dropped', 'faults_duplicated', 'faults_reordered', 'faults_corrupted',
    'faults_stalled_frames', 'foreign_requests', 'unauthenticated_datagrams',
    'replayed_datagrams', 'unsolicited_datagrams', 'setpoint_frames_stale', 'owner_changes',
    'owner_takeovers', 'faults_setpoint_dropped')


def _crc(data: bytes) -> bytes:
    return CRC.pack(zlib.crc32(data) & 0xFFFFFFFF)


def _check_crc(data: bytes) -> None:
    if len(data) < CRC.size:
        raise ProtocolError('datagram shorter than its CRC')
    (crc,) = CRC.unpack_from(data, len(data) - CRC.size)
    if zlib.crc32(memoryview(data)[:-CRC.size]) & 0xFFFFFFFF != crc:
        raise ProtocolError('CRC-32 mismatch')


def _seal(body: bytes, signer: Optional[Signer]) -> bytes:
    """Append counter and tag (with a signer), then the CRC-32."""
    if signer is not None:
        body = signer.trailer(body)
    return body + _crc(body)


def _check_session(session: int) -> None:
    if isinstance(session, bool) or not isinstance(session, int) or \
            not 0 <= session <= MAX_SESSION:
        raise ProtocolError(f'session id must be a u64, got {session!r}')


@dataclasses.dataclass(frozen=True)
class Frame:
    """
    One block frame.

    Attributes
    ----------
    stream_id : int
        ``STREAM_MEASUREMENT`` (device to host) or ``STREAM_SETPOINT`` (host to device).
    sequence : int
        Frame counter of the stream, u32, 0 at START, wrapping.
    epoch : int
        Stream epoch, u32 (the device increments it at every START).
    first_sample_index : int
        Device sample index of ``samples[:, 0]``.
    samples : numpy.ndarray
        Shape ``(C, N)``, int16 (raw codes) or float64 (SI values).
    session : int
        The owner's session id (u64; 0: none).
    auth_counter : int or None
        The sender's counter of an authenticated datagram (decoded frames; None when the
        datagram was not authenticated).
    """

    stream_id: int
    sequence: int
    epoch: int
    first_sample_index: int
    samples: np.ndarray
    session: int = 0
    auth_counter: Optional[int] = None

    @property
    def sample_format(self) -> int:
        """
        The format code of the samples' dtype.

        Returns
        -------
        int
            ``FORMAT_INT16`` or ``FORMAT_FLOAT64``.
        """
        return FORMAT_INT16 if self.samples.dtype.kind in 'iu' else FORMAT_FLOAT64

    @property
    def n_samples(self) -> int:
        """
        Samples per channel.

        Returns
        -------
        int
            ``N``.
        """
        return int(self.samples.shape[1])


def frame_size(n_channels: int, n_samples: int, sample_format: int,
               authenticated: bool = False) -> int:
    """
    Bytes of a frame.

    Parameters
    ----------
    n_channels, n_samples : int
        Shape of the payload.
    sample_format : int
        Format code.
    authenticated : bool
        With counter and tag.

    Returns
    -------
    int
        Header + payload (+ counter and tag) + CRC.
    """
    return (FRAME_HEADER.size + n_channels * n_samples * FORMAT_DTYPES[sample_format].itemsize
            + (AUTH_TRAILER.size if authenticated else 0) + CRC.size)


def max_samples_per_frame(n_channels: int, sample_format: int,
                          max_bytes: int = MAX_DATAGRAM_BYTES) -> int:
    """
    Most samples per channel that fit one datagram, authenticated or not.

    Room for the counter and tag is always kept, so a frame holds the same samples with and
    without a key.

    Parameters
    ----------
    n_channels : int
        Channels.
    sample_format : int
        Format code.
    max_bytes : int
        Datagram size limit.

    Returns
    -------
    int
        At most 65535 (the u16 field).
    """
    per = n_channels * FORMAT_DTYPES[sample_format].itemsize
    room = max_bytes - FRAME_HEADER.size - AUTH_TRAILER.size - CRC.size
    return max(0, min(65535, room // per))


def encode_frame(frame: Frame, signer: Optional[Signer] = None) -> bytes:
    """
    Serialise a frame.

    Parameters
    ----------
    frame : Frame
        The frame; float samples are sent as float64, integer ones as int16.
    signer : Signer, optional
        Authenticate it with this key and counter.

    Returns
    -------
    bytes
        The datagram.

    Raises
    ------
    ProtocolError
        If a field is out of range or the frame does not fit one datagram.
    """
    samples = np.asarray(frame.samples)
    if samples.ndim != 2 or not 1 <= samples.shape[0] <= 65535 or \
            not 1 <= samples.shape[1] <= 65535:
        raise ProtocolError(f'frame samples must have shape (1..65535, 1..65535), got '
                            f'{samples.shape}')
    fmt = frame.sample_format
    if fmt == FORMAT_INT16 and (samples.min() < -32768 or samples.max() > 32767):
        raise ProtocolError('int16 frame samples outside [-32768, 32767]')
    if frame.stream_id not in STREAMS or not 0 <= frame.sequence < 2 ** 32 or \
            not 0 <= frame.epoch < 2 ** 32 or \
            not 0 <= frame.first_sample_index < MAX_EXACT_INDEX:
        raise ProtocolError('frame header field out of range')
    _check_session(frame.session)
    if frame_size(*samples.shape, fmt, True) > MAX_DATAGRAM_BYTES:
        raise ProtocolError(f'frame of shape {samples.shape} exceeds {MAX_DATAGRAM_BYTES} bytes')
    header = FRAME_HEADER.pack(MAGIC_FRAME, VERSION, frame.stream_id, fmt,
                               FLAG_AUTH if signer is not None else 0, frame.session,
                               frame.sequence, frame.epoch, frame.first_sample_index,
                               *samples.shape)
    body = header + np.ascontiguousarray(samples, dtype=FORMAT_DTYPES[fmt]).tobytes()
    return _seal(body, signer)


def decode_frame(data: bytes, key: Optional[bytes] = None) -> Frame:
    """
    Parse and check a frame.

    Parameters
    ----------
    data : bytes
        One datagram.
    key : bytes, optional
        The pre-shared key: the frame must then carry a valid tag (and must not without one).

    Returns
    -------
    Frame
        The frame; samples are a fresh native-endian array.

    Raises
    ------
    AuthenticationError
        If the authentication does not match the key.
    ProtocolError
        On any other malformed input (and only then).
    """
    data, fields, end, counter = _open_datagram(data, FRAME_HEADER, MAGIC_FRAME, 'frame', key)
    stream, fmt, _flags, session, seq, epoch, first, n_ch, n_s = fields
    if stream not in STREAMS:
        raise ProtocolError(f'unknown stream id {stream}')
    if fmt not in FORMAT_DTYPES:
        raise ProtocolError(f'unknown sample format {fmt}')
    if n_ch < 1 or n_s < 1:
        raise ProtocolError('frame has no samples')
    if end != FRAME_HEADER.size + n_ch * n_s * FORMAT_DTYPES[fmt].itemsize:
        raise ProtocolError(f'frame length {len(data)} does not match {n_ch} x {n_s} samples')
    if first >= MAX_EXACT_INDEX:
        raise ProtocolError(f'first sample index {first} beyond 2**53')
    dtype = FORMAT_DTYPES[fmt]
    samples = np.frombuffer(data, dtype=dtype, count=n_ch * n_s, offset=FRAME_HEADER.size)
    samples = samples.astype(dtype.newbyteorder('='), copy=True).reshape(n_ch, n_s)
    if fmt == FORMAT_FLOAT64 and not np.all(np.isfinite(samples)):
        raise ProtocolError('float64 frame holds non-finite samples')
    return Frame(stream, seq, epoch, first, samples, session, counter)


#: Index of the flags field among a header's fields after magic and version.
_FLAGS_FIELD = {MAGIC_FRAME: 2, MAGIC_CONTROL: 3}


def _open_datagram(data: bytes, header: struct.Struct, magic: bytes, what: str,
                   key: Optional[bytes]) -> Tuple[bytes, tuple, int, Optional[int]]:
    """
    Check what every datagram starts and ends with: size, magic, version, CRC, tag.

    Parameters
    ----------
    data : bytes
        One datagram (anything bytes() accepts).
    header : struct.Struct
        Its header layout; the first two fields are magic and version.
    magic : bytes
        The expected magic.
    what : str
        ``'frame'`` or ``'control message'``, for the error messages.
    key : bytes or None
        The pre-shared key, if any.

    Returns
    -------
    data : bytes
        The datagram as bytes.
    fields : tuple
        The header fields after magic and version.
    end : int
        Offset of the end of the payload (where counter and tag, or the CRC, begin).
    counter : int or None
        The authentication counter (None without the auth flag).

    Raises
    ------
    AuthenticationError
        If the tag is missing, unexpected or wrong.
    ProtocolError
        On any other malformed input.
    """
    try:
        data = bytes(data)
    except (TypeError, ValueError) as exc:
        raise ProtocolError(f'not bytes: {exc}') from None
    if len(data) >= 5 and data[:4] == magic and data[4] != VERSION:
        raise ProtocolError(f'unsupported {what} version {data[4]} (this side speaks '
                            f'version {VERSION}: session ids and optional authentication)')
    if len(data) < header.size + CRC.size:
        raise ProtocolError(f'{what} of {len(data)} bytes is shorter than header and CRC')
    fields = header.unpack_from(data)
    if fields[0] != magic:
        raise ProtocolError(f'bad {what} magic {fields[0]!r}')
    _check_crc(data)
    fields = fields[2:]
    end = len(data) - CRC.size
    counter = None
    if fields[_FLAGS_FIELD[magic]] & FLAG_AUTH:
        end -= AUTH_TRAILER.size
        if end < header.size:
            raise ProtocolError(f'{what} too short for its authentication tag')
        if key is None:
            raise AuthenticationError(f'authenticated {what}, but no key is configured here',
                                      fields)
        counter, received = AUTH_TRAILER.unpack_from(data, end)
        if not hmac.compare_digest(tag(key, data[:end + 8]), received):
            raise AuthenticationError(f'{what} authentication tag does not match the key',
                                      fields)
    elif key is not None:
        raise AuthenticationError(f'{what} is not authenticated, and a key is configured here',
                                  fields)
    return data, fields, end, counter


@dataclasses.dataclass(frozen=True)
class Message:
    """
    One control message.

    Attributes
    ----------
    type : int
        ``CONFIGURE``, ``START``, ``STOP``, ``HEARTBEAT``, ``STATUS``, ``FUNCGEN`` or
        ``RELEASE``.
    request_id : int
        u32 chosen by the host; the response carries the same id.
    kind : int
        ``KIND_REQUEST`` or ``KIND_RESPONSE``.
    status : int
        ``OK`` or an error code (responses; 0 in requests).
    body : bytes
        Type-specific body (an error response carries a UTF-8 message).
    session : int
        Session id (u64): the sender's session; 0 before CONFIGURE issued one. A response
        carries its request's session, a CONFIGURE response the new one.
    auth_counter : int or None
        The sender's counter (decoded authenticated messages; None otherwise).
    """

    type: int
    request_id: int
    kind: int = KIND_REQUEST
    status: int = OK
    body: bytes = b''
    session: int = 0
    auth_counter: Optional[int] = dataclasses.field(default=None, compare=False)

    @property
    def is_response(self) -> bool:
        """
        Whether this is a response.

        Returns
        -------
        bool
            ``kind == KIND_RESPONSE``.
        """
        return self.kind == KIND_RESPONSE

    def error_text(self) -> str:
        """
        The message of an error response.

        Returns
        -------
        str
            The body decoded leniently.
        """
        return self.body.decode('utf-8', 'replace')


def encode_message(message: Message, signer: Optional[Signer] = None) -> bytes:
    """
    Serialise a control message.

    Parameters
    ----------
    message : Message
        The message.
    signer : Signer, optional
        Authenticate it with this key and counter.

    Returns
    -------
    bytes
        The datagram.

    Raises
    ------
    ProtocolError
        If a field is out of range or the body is too long.
    """
    if message.type not in MESSAGE_TYPES or message.kind not in (0, 1) or \
            not 0 <= message.status <= 255 or not 0 <= message.request_id < 2 ** 32:
        raise ProtocolError('control header field out of range')
    _check_session(message.session)
    body = bytes(message.body)
    if CONTROL_HEADER.size + len(body) + AUTH_TRAILER.size + CRC.size > MAX_DATAGRAM_BYTES:
        raise ProtocolError(f'control body of {len(body)} bytes is too long')
    out = CONTROL_HEADER.pack(MAGIC_CONTROL, VERSION, message.type, message.kind,
                              message.status, FLAG_AUTH if signer is not None else 0,
                              message.request_id, message.session, len(body)) + body
    return _seal(out, signer)


def decode_message(data: bytes, key: Optional[bytes] = None) -> Message:
    """
    Parse and check a control message (header, CRC, tag; the body is decoded by type).

    Parameters
    ----------
    data : bytes
        One datagram.
    key : bytes, optional
        The pre-shared key: the message must then carry a valid tag (and must not without
        one).

    Returns
    -------
    Message
        The message.

    Raises
    ------
    AuthenticationError
        If the authentication does not match the key.
    ProtocolError
        On any other malformed input (and only then).
    """
    data, fields, end, counter = _open_datagram(data, CONTROL_HEADER, MAGIC_CONTROL,
                                                'control message', key)
    mtype, kind, status, _flags, rid, session, length = fields
    if end != CONTROL_HEADER.size + length:
        raise ProtocolError(f'control length {len(data)} does not match body length {length}')
    if mtype not in MESSAGE_TYPES:
        raise ProtocolError(f'unknown message type {mtype}')
    if kind not in (KIND_REQUEST, KIND_RESPONSE):
        raise ProtocolError(f'unknown message kind {kind}')
    return Message(mtype, rid, kind, status, data[CONTROL_HEADER.size:end], session, counter)


def header_of_refused(error: AuthenticationError) -> Optional[Message]:
    """
    The request an authentication failure refused, to answer it with ``AUTH_REQUIRED``.

    Parameters
    ----------
    error : AuthenticationError
        Raised by :func:`decode_message`.

    Returns
    -------
    Message or None
        Type, request id and session of a control request (body empty); None for anything
        else (frames, responses, unknown types).
    """
    fields = error.header
    if not fields or len(fields) != 7:
        return None
    mtype, kind, _status, _flags, rid, session, _length = fields
    if mtype not in MESSAGE_TYPES or kind != KIND_REQUEST:
        return None
    return Message(mtype, rid, KIND_REQUEST, OK, b'', session)


class _Reader:
    """Bounds-checked reading of a body; every failure is a ProtocolError."""

    def __init__(self, data: bytes) -> None:
        self.data = data
        self.pos = 0

    def unpack(self, fmt: struct.Struct) -> tuple:
        if self.pos + fmt.size > len(self.data):
            raise ProtocolError('body too short')
        out = fmt.unpack_from(self.data, self.pos)
        self.pos += fmt.size
        return out

    def text(self) -> str:
        if self.pos >= len(self.data):
            raise ProtocolError('body too short for a string')
        n = self.data[self.pos]
        raw = self.data[self.pos + 1:self.pos + 1 + n]
        if len(raw) != n:
            raise ProtocolError('body too short for a string')
        self.pos += 1 + n
        try:
            return raw.decode('utf-8')
        except UnicodeDecodeError:
            raise ProtocolError('string is not UTF-8') from None

    def end(self) -> None:
        if self.pos != len(self.data):
            raise ProtocolError(f'{len(self.data) - self.pos} trailing body bytes')


def _text(value: str) -> bytes:
    raw = value.encode('utf-8')
    if len(raw) > 255:
        raise ProtocolError(f'string {value!r} longer than 255 bytes')
    return bytes([len(raw)]) + raw


def encode_configure(config: DeviceConfig, stream_port: int = 0) -> bytes:
    """
    Body of a CONFIGURE request.

    Parameters
    ----------
    config : DeviceConfig
        The configuration.
    stream_port : int
        UDP port of the host to send measurement frames to; 0: the request's source port.

    Returns
    -------
    bytes
        The body.
    """
    out = [CONFIGURE_FIXED.pack(config.sample_rate_Hz, config.block_size, len(config.inputs),
                                len(config.outputs), stream_port, config.watchdog_timeout_s)]
    for c in config.inputs:
        out += [_text(c.name), _text(c.unit), INPUT_FIXED.pack(c.scale, c.offset)]
    for c in config.outputs:
        out += [_text(c.name), _text(c.unit),
                OUTPUT_FIXED.pack(c.scale, c.offset, c.min_V, c.max_V, c.safe_V)]
    return b''.join(out)


def decode_configure(body: bytes) -> Tuple[DeviceConfig, int]:
    """
    Parse a CONFIGURE body.

    Parameters
    ----------
    body : bytes
        The body.

    Returns
    -------
    config : DeviceConfig
        The configuration (validated).
    stream_port : int
        The host's stream port (0: the request's source port).

    Raises
    ------
    ProtocolError
        If malformed or invalid.
    """
    r = _Reader(body)
    rate, block, n_in, n_out, port, watchdog = r.unpack(CONFIGURE_FIXED)
    inputs: List[InputChannel] = []
    outputs: List[OutputChannel] = []
    try:
        for _ in range(n_in):
            name, unit = r.text(), r.text()
            inputs.append(InputChannel(name, unit, *r.unpack(INPUT_FIXED)))
        for _ in range(n_out):
            name, unit = r.text(), r.text()
            scale, offset, lo, hi, safe = r.unpack(OUTPUT_FIXED)
            outputs.append(OutputChannel(name, lo, hi, safe, unit, scale, offset))
        r.end()
        return DeviceConfig(rate, block, tuple(inputs), tuple(outputs), watchdog), port
    except DeviceConfigError as exc:
        raise ProtocolError(f'invalid configuration: {exc}') from None


def encode_configure_request(config: DeviceConfig, nonce: int, stream_port: int = 0) -> bytes:
    """
    Body of a CONFIGURE request: the host's nonce, then :func:`encode_configure`.

    Parameters
    ----------
    config : DeviceConfig
        The configuration.
    nonce : int
        A random u64 the response must echo (a replayed old response does not).
    stream_port : int
        UDP port of the host for measurement frames; 0: the request's source port.

    Returns
    -------
    bytes
        The body.
    """
    return CONFIGURE_NONCE.pack(nonce) + encode_configure(config, stream_port)


def decode_configure_request(body: bytes) -> Tuple[int, DeviceConfig, int, bytes]:
    """
    Parse a CONFIGURE request body.

    Parameters
    ----------
    body : bytes
        The body.

    Returns
    -------
    nonce : int
        The host's nonce.
    config : DeviceConfig
        The configuration (validated).
    stream_port : int
        The host's stream port (0: the request's source port).
    config_body : bytes
        The configuration part of the body (what STATUS echoes).

    Raises
    ------
    ProtocolError
        If malformed or invalid.
    """
    if len(body) < CONFIGURE_NONCE.size:
        raise ProtocolError('CONFIGURE body too short for its nonce')
    (nonce,) = CONFIGURE_NONCE.unpack_from(body)
    rest = bytes(body[CONFIGURE_NONCE.size:])
    config, port = decode_configure(rest)
    return nonce, config, port, rest


def decode_configure_response(body: bytes) -> Tuple[int, int]:
    """
    Parse an OK CONFIGURE response body.

    Parameters
    ----------
    body : bytes
        The body.

    Returns
    -------
    nonce : int
        The echoed host nonce.
    session : int
        The new session id (non-zero).

    Raises
    ------
    ProtocolError
        If malformed.
    """
    r = _Reader(bytes(body))
    nonce, session = r.unpack(CONFIGURE_RESPONSE)
    r.end()
    if session == 0:
        raise ProtocolError('CONFIGURE response with session id 0')
    return nonce, session


def encode_funcgen(specs: Sequence[GeneratorSpec]) -> bytes:
    """
    Body of a FUNCGEN request: one entry per output channel, in order.

    Parameters
    ----------
    specs : sequence of GeneratorSpec
        One per output channel.

    Returns
    -------
    bytes
        The body.
    """
    out = [FUNCGEN_COUNT.pack(len(specs))]
    for i, s in enumerate(specs):
        if not 0 <= s.prbs_order <= 255 or not 0 <= s.prbs_hold_samples < 2 ** 32:
            raise ProtocolError('PRBS order or hold out of range')
        out.append(FUNCGEN_ENTRY.pack(i, WAVEFORMS.index(s.waveform),
                                      CHIRP_METHODS.index(s.method), s.prbs_order,
                                      s.prbs_hold_samples, s.amplitude_V, s.frequency_Hz,
                                      s.f_stop_Hz, s.sweep_time_s, s.phase_rad, s.gain,
                                      s.offset_V))
    return b''.join(out)


def decode_funcgen(body: bytes) -> List[GeneratorSpec]:
    """
    Parse a FUNCGEN body.

    Parameters
    ----------
    body : bytes
        The body.

    Returns
    -------
    list of GeneratorSpec
        One per output channel, in channel order.

    Raises
    ------
    ProtocolError
        If malformed or invalid (entries must be numbered 0, 1, ... in order).
    """
    r = _Reader(body)
    (n,) = r.unpack(FUNCGEN_COUNT)
    specs = []
    for i in range(n):
        (chan, wave, method, order, hold, amp, f0, f1, sweep, phase, gain,
         offset) = r.unpack(FUNCGEN_ENTRY)
        if chan != i or wave >= len(WAVEFORMS) or method >= len(CHIRP_METHODS):
            raise ProtocolError(f'FUNCGEN entry {i}: bad channel, waveform or method code')
        try:
            specs.append(GeneratorSpec(WAVEFORMS[wave], amp, f0, f1, sweep, CHIRP_METHODS[method],
                                       phase, order, hold, gain, offset))
        except DeviceConfigError as exc:
            raise ProtocolError(f'FUNCGEN entry {i}: {exc}') from None
    r.end()
    return specs


@dataclasses.dataclass(frozen=True)
class HeartbeatReply:
    """
    Body of a HEARTBEAT response: what the device applied.

    Attributes
    ----------
    echo_ns : int
        The request's host timestamp, echoed [ns].
    next_sample_index : int
        Device sample index of the next sample to be produced.
    epoch : int
        Current stream epoch.
    boot_id : int
        Random u32 the device draws when it boots: a change means the device restarted.
    state : int
        ``STATE_IDLE``, ``STATE_CONFIGURED`` or ``STATE_RUNNING``.
    watchdog_tripped : bool
        Whether the watchdog holds the outputs at their safe values.
    underrun_samples : int
        Samples output at the safe value because the setpoint stream ran dry, or because
        its first frame came after the clock had passed them (since boot).
    watchdog_trips : int
        Watchdog trips since boot.
    watchdog_trip_index : int, optional
        First sample of this epoch output at the safe values by the latched watchdog (the
        trip record); None when it holds nothing.
    gap_filled_samples : int
        Setpoint samples the device filled with the safe values because the stream had a
        gap (frames lost or skipped; since boot).
    first_gap_index : int, optional
        First sample of this epoch filled so; None when none.
    setpoint_frames_rejected : int
        Setpoint frames of the owner's current epoch the device refused (malformed for the
        configuration; since boot).
    first_rejected_index : int, optional
        First sample of the first such frame of this epoch; None when none.
    """

    echo_ns: int
    next_sample_index: int
    epoch: int
    boot_id: int
    state: int
    watchdog_tripped: bool
    underrun_samples: int
    watchdog_trips: int
    watchdog_trip_index: Optional[int] = None
    gap_filled_samples: int = 0
    first_gap_index: Optional[int] = None
    setpoint_frames_rejected: int = 0
    first_rejected_index: Optional[int] = None


def _index_field(value: Optional[int]) -> int:
    return NO_INDEX if value is None else int(value)


def _index_value(value: int) -> Optional[int]:
    return None if value == NO_INDEX else value


def encode_heartbeat_reply(reply: HeartbeatReply) -> bytes:
    """
    Body of a HEARTBEAT response.

    Parameters
    ----------
    reply : HeartbeatReply
        The fields.

    Returns
    -------
    bytes
        The body.
    """
    return HEARTBEAT_RESPONSE.pack(reply.echo_ns, reply.next_sample_index, reply.epoch,
                                   reply.boot_id, reply.state, int(reply.watchdog_tripped),
                                   reply.underrun_samples, reply.watchdog_trips,
                                   _index_field(reply.watchdog_trip_index),
                                   reply.gap_filled_samples, _index_field(reply.first_gap_index),
                                   reply.setpoint_frames_rejected,
                                   _index_field(reply.first_rejected_index))


def decode_heartbeat_reply(body: bytes) -> HeartbeatReply:
    """
    Parse a HEARTBEAT response body.

    Parameters
    ----------
    body : bytes
        The body.

    Returns
    -------
    HeartbeatReply
        The fields.

    Raises
    ------
    ProtocolError
        If malformed.
    """
    r = _Reader(body)
    (echo, index, epoch, boot, state, tripped, underruns, trips, trip_index, gap_filled,
     first_gap, rejected, first_rejected) = r.unpack(HEARTBEAT_RESPONSE)
    r.end()
    if state not in STATE_NAMES or tripped > 1:
        raise ProtocolError(f'bad heartbeat state {state} or flag {tripped}')
    if (trip_index != NO_INDEX) != bool(tripped):
        raise ProtocolError(f'heartbeat trip index {trip_index} disagrees with the tripped '
                            f'flag {tripped}')
    if (first_gap != NO_INDEX and not gap_filled) or \
            (first_rejected != NO_INDEX and not rejected):
        raise ProtocolError('heartbeat names a first gap or refused frame without a count')
    return HeartbeatReply(echo, index, epoch, boot, state, bool(tripped), underruns, trips,
                          _index_value(trip_index), gap_filled, _index_value(first_gap),
                          rejected, _index_value(first_rejected))


@dataclasses.dataclass(frozen=True)
class StatusReply:
    """
    Body of a STATUS response.

    Attributes
    ----------
    epoch : int
        Current stream epoch.
    boot_id : int
        The device's boot id.
    state : int
        Device state code.
    watchdog_tripped : bool
        Whether the watchdog holds the outputs.
    counters : dict
        The :data:`DEVICE_COUNTERS`, by name.
    configure_body : bytes
        The active configuration (:func:`encode_configure`, echo of the channel scaling),
        empty when idle.
    owned : bool
        Whether a live session owns the device.
    authenticated : bool
        Whether the device requires authenticated datagrams (it has a key).
    """

    epoch: int
    boot_id: int
    state: int
    watchdog_tripped: bool
    counters: Dict[str, int]
    configure_body: bytes = b''
    owned: bool = False
    authenticated: bool = False

    def config(self) -> DeviceConfig:
        """
        The echoed configuration.

        Returns
        -------
        DeviceConfig
            Parsed from :attr:`configure_body`.

        Raises
        ------
        ProtocolError
            If the device is not configured or the echo is malformed.
        """
        return decode_configure(self.configure_body)[0]


_COUNTERS = struct.Struct('<' + 'Q' * len(DEVICE_COUNTERS))


def encode_status_reply(reply: StatusReply) -> bytes:
    """
    Body of a STATUS response.

    Parameters
    ----------
    reply : StatusReply
        The fields (missing counters are sent as 0).

    Returns
    -------
    bytes
        The body.
    """
    counters = [min(int(reply.counters.get(n, 0)), 2 ** 64 - 1) for n in DEVICE_COUNTERS]
    return (STATUS_FIXED.pack(reply.epoch, reply.boot_id, reply.state,
                              int(reply.watchdog_tripped), int(reply.owned),
                              int(reply.authenticated), len(DEVICE_COUNTERS))
            + _COUNTERS.pack(*counters) + reply.configure_body)


def decode_status_reply(body: bytes) -> StatusReply:
    """
    Parse a STATUS response body.

    Parameters
    ----------
    body : bytes
        The body.

    Returns
    -------
    StatusReply
        The fields.

    Raises
    ------
    ProtocolError
        If malformed.
    """
    r = _Reader(body)
    epoch, boot, state, tripped, owned, auth, n = r.unpack(STATUS_FIXED)
    if state not in STATE_NAMES or max(tripped, owned, auth) > 1 or n != len(DEVICE_COUNTERS):
        raise ProtocolError(f'bad status state {state}, flags {tripped}, {owned}, {auth} or '
                            f'counter count {n}')
    values = r.unpack(_COUNTERS)
    return StatusReply(epoch, boot, state, bool(tripped), dict(zip(DEVICE_COUNTERS, values)),
                       bytes(body[r.pos:]), bool(owned), bool(auth))
