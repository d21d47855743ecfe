"""
The binary UDP protocol between host and device: block frames and control messages.

Everything is little-endian; every datagram ends in the CRC-32 (``zlib.crc32``) of all the
bytes before it. The full specification, with tables, is ``docs/device_protocol.md``.

Block frame (``MAGIC_FRAME``, both directions)::

    0  4s  magic b'EMFD'        16  Q  first sample index
    4  B   version (1)          24  H  channel count C
    5  B   stream id            26  H  samples per channel N
    6  B   sample format        28     payload, channel-major, C*N samples
    7  B   flags (0)            end    I  CRC-32 of bytes [0, end)
    8  I   sequence number
    12 I   epoch

Control message (``MAGIC_CONTROL``)::

    0  4s  magic b'EMFC'        8   I  request id
    4  B   version (1)          12  I  body length L
    5  B   message type         16     body, L bytes
    6  B   kind (0 request, 1 response)
    7  B   status (0 OK)        16+L   I  CRC-32 of bytes [0, 16+L)

Every decoder raises :class:`ProtocolError` and nothing else, whatever the input bytes.
"""

from __future__ import annotations

import dataclasses
import struct
from typing import Dict, List, Optional, Sequence, Tuple
import zlib

import numpy as np

from emfc_ros.core.blocks import MAX_EXACT_INDEX
from emfc_ros.core.device.backend import DeviceConfig, InputChannel, OutputChannel
from emfc_ros.core.device.errors import DeviceConfigError, ProtocolError
from emfc_ros.core.device.function_generator import CHIRP_METHODS, GeneratorSpec, WAVEFORMS

VERSION = 1
MAGIC_FRAME = b'EMFD'
MAGIC_CONTROL = b'EMFC'
CRC = struct.Struct('<I')
#: Largest UDP payload of IPv4 (65535 - 20 IP - 8 UDP bytes).
MAX_DATAGRAM_BYTES = 65507

FRAME_HEADER = struct.Struct('<4sBBBBIIQHH')
STREAM_MEASUREMENT = 1
STREAM_SETPOINT = 2
STREAMS = (STREAM_MEASUREMENT, STREAM_SETPOINT)
FORMAT_INT16 = 1
FORMAT_FLOAT64 = 2
FORMAT_DTYPES = {FORMAT_INT16: np.dtype('<i2'), FORMAT_FLOAT64: np.dtype('<f8')}

CONTROL_HEADER = struct.Struct('<4sBBBBII')
KIND_REQUEST = 0
KIND_RESPONSE = 1
CONFIGURE = 1
START = 2
STOP = 3
HEARTBEAT = 4
STATUS = 5
FUNCGEN = 6
MESSAGE_TYPES = {CONFIGURE: 'CONFIGURE', START: 'START', STOP: 'STOP', HEARTBEAT: 'HEARTBEAT',
                 STATUS: 'STATUS', FUNCGEN: 'FUNCGEN'}
OK = 0
BAD_REQUEST = 1
BAD_STATE = 2
UNSUPPORTED = 3
STATUS_NAMES = {OK: 'OK', BAD_REQUEST: 'BAD_REQUEST', BAD_STATE: 'BAD_STATE',
                UNSUPPORTED: 'UNSUPPORTED'}

#: Device states.
STATE_IDLE = 0
STATE_CONFIGURED = 1
STATE_RUNNING = 2
STATE_NAMES = {STATE_IDLE: 'idle', STATE_CONFIGURED: 'configured', STATE_RUNNING: 'running'}

CONFIGURE_FIXED = struct.Struct('<dHHHHd')
INPUT_FIXED = struct.Struct('<dd')
OUTPUT_FIXED = struct.Struct('<ddddd')
START_RESPONSE = struct.Struct('<II')
HEARTBEAT_REQUEST = struct.Struct('<Q')
HEARTBEAT_RESPONSE = struct.Struct('<QQIIBBxxQQQ')
#: ``watchdog_trip_index`` of a HEARTBEAT response when the watchdog holds nothing.
NO_TRIP_INDEX = 2 ** 64 - 1
FUNCGEN_COUNT = struct.Struct('<H')
FUNCGEN_ENTRY = struct.Struct('<BBBBIddddddd')
STATUS_FIXED = struct.Struct('<IIBBH')
#: Device counters of the STATUS response, each a u64, in this order.
DEVICE_COUNTERS = (
    'frames_sent', 'samples_sent', 'setpoint_frames_received', 'setpoint_frames_rejected',
    'setpoint_gaps', 'setpoint_duplicates', 'setpoint_reordered', 'setpoint_late_samples',
    'underrun_samples', 'gap_filled_samples', 'clamped_samples', 'heartbeats_received',
    'watchdog_trips', 'foreign_datagrams', 'corrupt_datagrams', 'late_blocks',
    'faults_dropped', 'faults_duplicated', 'faults_reordered', 'faults_corrupted',
    'faults_stalled_frames')


def _crc(data: bytes) -> bytes:
    return CRC.pack(zlib.crc32(data) & 0xFFFFFFFF)


def _check_crc(data: bytes) -> None:
    if len(data) < CRC.size:
        raise ProtocolError('datagram shorter than its CRC')
    (crc,) = CRC.unpack_from(data, len(data) - CRC.size)
    if zlib.crc32(data[:-CRC.size]) & 0xFFFFFFFF != crc:
        raise ProtocolError('CRC-32 mismatch')


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
    """

    stream_id: int
    sequence: int
    epoch: int
    first_sample_index: int
    samples: np.ndarray

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


def frame_size(n_channels: int, n_samples: int, sample_format: int) -> int:
    """
    Bytes of a frame.

    Parameters
    ----------
    n_channels, n_samples : int
        Shape of the payload.
    sample_format : int
        Format code.

    Returns
    -------
    int
        Header + payload + CRC.
    """
    return (FRAME_HEADER.size + n_channels * n_samples * FORMAT_DTYPES[sample_format].itemsize
            + CRC.size)


def max_samples_per_frame(n_channels: int, sample_format: int,
                          max_bytes: int = MAX_DATAGRAM_BYTES) -> int:
    """
    Most samples per channel that fit one datagram.

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
    return max(0, min(65535, (max_bytes - FRAME_HEADER.size - CRC.size) // per))


def encode_frame(frame: Frame) -> bytes:
    """
    Serialise a frame.

    Parameters
    ----------
    frame : Frame
        The frame; float samples are sent as float64, integer ones as int16.

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
    if frame_size(*samples.shape, fmt) > MAX_DATAGRAM_BYTES:
        raise ProtocolError(f'frame of shape {samples.shape} exceeds {MAX_DATAGRAM_BYTES} bytes')
    header = FRAME_HEADER.pack(MAGIC_FRAME, VERSION, frame.stream_id, fmt, 0, frame.sequence,
                               frame.epoch, frame.first_sample_index, *samples.shape)
    body = header + np.ascontiguousarray(samples, dtype=FORMAT_DTYPES[fmt]).tobytes()
    return body + _crc(body)


def decode_frame(data: bytes) -> Frame:
    """
    Parse and check a frame.

    Parameters
    ----------
    data : bytes
        One datagram.

    Returns
    -------
    Frame
        The frame; samples are a fresh native-endian array.

    Raises
    ------
    ProtocolError
        On any malformed input (and only then).
    """
    data, (stream, fmt, _flags, seq, epoch, first, n_ch, n_s) = _open_datagram(
        data, FRAME_HEADER, MAGIC_FRAME, 'frame')
    if stream not in STREAMS:
        raise ProtocolError(f'unknown stream id {stream}')
    if fmt not in FORMAT_DTYPES:
        raise ProtocolError(f'unknown sample format {fmt}')
    if n_ch < 1 or n_s < 1:
        raise ProtocolError('frame has no samples')
    if len(data) != frame_size(n_ch, n_s, fmt):
        raise ProtocolError(f'frame length {len(data)} does not match {n_ch} x {n_s} samples')
    if first >= MAX_EXACT_INDEX:
        raise ProtocolError(f'first sample index {first} beyond 2**53')
    dtype = FORMAT_DTYPES[fmt]
    samples = np.frombuffer(data, dtype=dtype, count=n_ch * n_s, offset=FRAME_HEADER.size)
    samples = samples.astype(dtype.newbyteorder('='), copy=True).reshape(n_ch, n_s)
    if fmt == FORMAT_FLOAT64 and not np.all(np.isfinite(samples)):
        raise ProtocolError('float64 frame holds non-finite samples')
    return Frame(stream, seq, epoch, first, samples)


def _open_datagram(data: bytes, header: struct.Struct, magic: bytes,
                   what: str) -> Tuple[bytes, tuple]:
    """
    Check what every datagram starts and ends with: size, magic, version, CRC.

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

    Returns
    -------
    data : bytes
        The datagram as bytes.
    fields : tuple
        The header fields after magic and version.

    Raises
    ------
    ProtocolError
        On any malformed input.
    """
    try:
        data = bytes(data)
    except (TypeError, ValueError) as exc:
        raise ProtocolError(f'not bytes: {exc}') from None
    if len(data) < header.size + CRC.size:
        raise ProtocolError(f'{what} of {len(data)} bytes is shorter than header and CRC')
    fields = header.unpack_from(data)
    if fields[0] != magic:
        raise ProtocolError(f'bad {what} magic {fields[0]!r}')
    if fields[1] != VERSION:
        raise ProtocolError(f'unsupported {what} version {fields[1]}')
    _check_crc(data)
    return data, fields[2:]


@dataclasses.dataclass(frozen=True)
class Message:
    """
    One control message.

    Attributes
    ----------
    type : int
        ``CONFIGURE``, ``START``, ``STOP``, ``HEARTBEAT``, ``STATUS`` or ``FUNCGEN``.
    request_id : int
        u32 chosen by the host; the response carries the same id.
    kind : int
        ``KIND_REQUEST`` or ``KIND_RESPONSE``.
    status : int
        ``OK`` or an error code (responses; 0 in requests).
    body : bytes
        Type-specific body (an error response carries a UTF-8 message).
    """

    type: int
    request_id: int
    kind: int = KIND_REQUEST
    status: int = OK
    body: bytes = b''

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


def encode_message(message: Message) -> bytes:
    """
    Serialise a control message.

    Parameters
    ----------
    message : Message
        The message.

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
    body = bytes(message.body)
    if CONTROL_HEADER.size + len(body) + CRC.size > MAX_DATAGRAM_BYTES:
        raise ProtocolError(f'control body of {len(body)} bytes is too long')
    out = CONTROL_HEADER.pack(MAGIC_CONTROL, VERSION, message.type, message.kind,
                              message.status, message.request_id, len(body)) + body
    return out + _crc(out)


def decode_message(data: bytes) -> Message:
    """
    Parse and check a control message (header and CRC; the body is decoded by type).

    Parameters
    ----------
    data : bytes
        One datagram.

    Returns
    -------
    Message
        The message.

    Raises
    ------
    ProtocolError
        On any malformed input (and only then).
    """
    data, (mtype, kind, status, rid, length) = _open_datagram(
        data, CONTROL_HEADER, MAGIC_CONTROL, 'control message')
    if len(data) != CONTROL_HEADER.size + length + CRC.size:
        raise ProtocolError(f'control length {len(data)} does not match body length {length}')
    if mtype not in MESSAGE_TYPES:
        raise ProtocolError(f'unknown message type {mtype}')
    if kind not in (KIND_REQUEST, KIND_RESPONSE):
        raise ProtocolError(f'unknown message kind {kind}')
    return Message(mtype, rid, kind, status, data[CONTROL_HEADER.size:-CRC.size])


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
    Body of a HEARTBEAT response.

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
        Samples output at the safe value because the setpoint stream ran dry.
    watchdog_trips : int
        Watchdog trips since boot.
    watchdog_trip_index : int, optional
        First sample of this epoch output at the safe values by the latched watchdog (the
        trip record); None when it holds nothing.
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
                                   NO_TRIP_INDEX if reply.watchdog_trip_index is None
                                   else reply.watchdog_trip_index)


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
    echo, index, epoch, boot, state, tripped, underruns, trips, trip_index = r.unpack(
        HEARTBEAT_RESPONSE)
    r.end()
    if state not in STATE_NAMES or tripped > 1:
        raise ProtocolError(f'bad heartbeat state {state} or flag {tripped}')
    if (trip_index != NO_TRIP_INDEX) != bool(tripped):
        raise ProtocolError(f'heartbeat trip index {trip_index} disagrees with the tripped '
                            f'flag {tripped}')
    return HeartbeatReply(echo, index, epoch, boot, state, bool(tripped), underruns, trips,
                          None if trip_index == NO_TRIP_INDEX else trip_index)


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
        The active CONFIGURE body (echo of the channel scaling), empty when idle.
    """

    epoch: int
    boot_id: int
    state: int
    watchdog_tripped: bool
    counters: Dict[str, int]
    configure_body: bytes = b''

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
                              int(reply.watchdog_tripped), len(DEVICE_COUNTERS))
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
    epoch, boot, state, tripped, n = r.unpack(STATUS_FIXED)
    if state not in STATE_NAMES or tripped > 1 or n != len(DEVICE_COUNTERS):
        raise ProtocolError(f'bad status state {state}, flag {tripped} or counter count {n}')
    values = r.unpack(_COUNTERS)
    return StatusReply(epoch, boot, state, bool(tripped), dict(zip(DEVICE_COUNTERS, values)),
                       body[r.pos:])
