"""
Back-end ``'udp'``: a device on the network, spoken to with :mod:`~emfc_ros.core.device.protocol`.

One UDP socket (bound to 127.0.0.1 by default) carries everything: control requests with
request ids, timeouts and retries; heartbeats at ``heartbeat_period_s``; setpoint frames to
the device; measurement frames and responses from it. A datagram is accepted only when it
comes from the configured device address, carries this host's session id (issued by the
device at CONFIGURE) and, with a key, a valid HMAC tag and a fresh counter; everything else
is counted (``foreign``, ``wrong_session``, ``unauthenticated``, ``replayed``, ``corrupt``,
``unsolicited``, ``late_responses``) and dropped, and only accepted datagrams count as the
device being alive.

Two threads: the receiver decodes datagrams, answers waiting requests and feeds measurement
frames through a :class:`ReorderBuffer` (by sequence number, a window of a few frames and a
timeout) into the block queue that :meth:`UdpBackend.read_block` reads; the supervisor sends
heartbeats, counts missed replies and declares the device lost when it has been silent for
``device_timeout_s`` (:meth:`UdpBackend.silence_s`: measured up to the receiver's last
proof that nothing was waiting in the socket, so a stalled host is not taken for a dead
device, and bounded by ``device_timeout_s + FLOOD_GRACE_S`` whatever the host does). A
lost device, or heartbeat replies showing that it rebooted, stopped, or no longer knows our
session, is reconfigured and restarted (STOP, CONFIGURE, FUNCGEN, START) and counts a
reconnect (the stream continues in a new epoch at index 0).
"""

from __future__ import annotations

import collections
import ipaddress
from pathlib import Path
import secrets
import socket
import struct
import threading
import time
from typing import Any, Callable, Deque, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np

from emfc_ros.core.blocks import Block
from emfc_ros.core.device import protocol as proto
from emfc_ros.core.device.auth import check_key, load_key_file, ReplayGuard, Signer
from emfc_ros.core.device.backend import (check_generator_range, DeviceConfig, from_codes,
                                          input_scaling, to_codes)
from emfc_ros.core.device.errors import (AuthenticationError, DeviceConfigError, DeviceError,
                                         DeviceRefusedError, DeviceTimeoutError, ProtocolError)
from emfc_ros.core.device.function_generator import GeneratorSpec

#: A thread that has not run for this long means the host stalled [s] (the supervisor wakes
#: every 50 ms at most, the receiver's socket times out after 50 ms).
HOST_STALL_S = 0.25
#: When the receiver never finds its socket empty (a flood of datagrams), the device is
#: declared lost after ``device_timeout_s`` plus this long without a valid datagram [s].
FLOOD_GRACE_S = 1.0
SEQ_MOD = 2 ** 32
SEQ_HALF = 2 ** 31
HOST_COUNTERS = ('frames_received', 'blocks_delivered', 'blocks_overflowed', 'gaps',
                 'missing_frames', 'missing_samples', 'duplicates', 'reordered', 'late',
                 'index_discontinuities', 'corrupt', 'rejected', 'stale', 'foreign',
                 'wrong_session', 'unauthenticated', 'replayed', 'unsolicited',
                 'late_responses', 'heartbeats_sent', 'heartbeat_replies', 'heartbeat_misses',
                 'heartbeat_refusals', 'requests', 'request_retries', 'request_timeouts',
                 'reconnects', 'device_losses', 'sessions_lost', 'setpoint_frames_sent',
                 'host_stalls')
#: Counters of datagrams someone else sent (the bridge reports them as WARN).
INTRUSION_COUNTERS = ('foreign', 'wrong_session', 'unauthenticated', 'replayed',
                      'unsolicited')


class ReorderBuffer:
    """
    Put the frames of one stream epoch back in sequence order, and count every defect.

    A frame whose sequence number is the next expected one is delivered at once, with any
    buffered frames that follow it. A later frame waits in the buffer; when the buffer spans
    ``window`` sequence numbers or its oldest frame has waited ``timeout_s``, the missing
    frames are given up (a gap, counted with the frames and samples it lost) and delivery
    resumes at the lowest buffered frame. Frames behind the expected number are duplicates
    (delivered recently) or late (given up before); both are dropped. Counted as reordered:
    a frame that arrived after a frame with a higher sequence number and was still delivered.

    Parameters
    ----------
    window : int
        Most sequence numbers the buffer spans before it gives up on a missing frame.
    timeout_s : float
        Longest wait for a missing frame [s].
    """

    def __init__(self, window: int = 8, timeout_s: float = 0.2) -> None:
        if window < 1 or not timeout_s > 0:
            raise DeviceConfigError(f'reorder window >= 1 and timeout > 0 required, got '
                                    f'{window}, {timeout_s}')
        self.window = int(window)
        self.timeout_s = float(timeout_s)
        self.counters = dict.fromkeys(('delivered', 'gaps', 'missing_frames', 'missing_samples',
                                       'duplicates', 'reordered', 'late',
                                       'index_discontinuities'), 0)
        self.reset()

    def reset(self, next_sequence: int = 0, next_sample_index: int = 0) -> None:
        """
        Start a new epoch (counters are kept).

        Parameters
        ----------
        next_sequence : int
            Sequence number of the epoch's first frame.
        next_sample_index : int
            Sample index of the epoch's first sample.
        """
        self.next = int(next_sequence) % SEQ_MOD
        self.expected_index = int(next_sample_index)
        self.pending: Dict[int, Tuple[Any, float]] = {}
        self.max_seen: Optional[int] = None
        self._recent: Deque[int] = collections.deque(maxlen=256)
        self._recent_set: set = set()

    def push(self, sequence: int, first_sample_index: int, n_samples: int, item: Any,
             now: float) -> List[Any]:
        """
        Offer one frame.

        Parameters
        ----------
        sequence : int
            Its sequence number (u32).
        first_sample_index, n_samples : int
            Its samples' place on the sample clock.
        item : Any
            What to deliver for it.
        now : float
            Arrival time [s].

        Returns
        -------
        list
            Items now deliverable, in order (possibly empty).
        """
        sequence %= SEQ_MOD
        if (sequence - self.next) % SEQ_MOD >= SEQ_HALF:
            key = 'duplicates' if sequence in self._recent_set else 'late'
            self.counters[key] += 1
            return []
        if sequence in self.pending:
            self.counters['duplicates'] += 1
            return []
        if self.max_seen is not None and (self.max_seen - sequence) % SEQ_MOD < SEQ_HALF:
            self.counters['reordered'] += 1
        else:
            self.max_seen = sequence
        self.pending[sequence] = ((first_sample_index, n_samples, item), now)
        out = self._drain()
        while self.pending and (self.max_seen - self.next) % SEQ_MOD >= self.window:
            self._skip()
            out += self._drain()
        return out

    def expire(self, now: float) -> List[Any]:
        """
        Give up on missing frames the buffer has waited for too long.

        Parameters
        ----------
        now : float
            Current time [s].

        Returns
        -------
        list
            Items now deliverable, in order.
        """
        out: List[Any] = []
        while self.pending and now - min(t for _, t in self.pending.values()) >= self.timeout_s:
            self._skip()
            out += self._drain()
        return out

    def _skip(self) -> None:
        target = min(self.pending, key=lambda s: (s - self.next) % SEQ_MOD)
        first = self.pending[target][0][0]
        self.counters['gaps'] += 1
        self.counters['missing_frames'] += (target - self.next) % SEQ_MOD
        self.counters['missing_samples'] += max(0, first - self.expected_index)
        self.expected_index = max(self.expected_index, first)
        self.next = target

    def _drain(self) -> List[Any]:
        out = []
        while self.next in self.pending:
            (first, n, item), _ = self.pending.pop(self.next)
            if first != self.expected_index:
                self.counters['index_discontinuities'] += 1
            self.expected_index = first + n
            if len(self._recent) == self._recent.maxlen:
                self._recent_set.discard(self._recent[0])
            self._recent.append(self.next)
            self._recent_set.add(self.next)
            self.next = (self.next + 1) % SEQ_MOD
            self.counters['delivered'] += 1
            out.append(item)
        return out


def _address(value: Union[str, Tuple[str, int]]) -> Tuple[str, int]:
    if isinstance(value, str):
        host, sep, port = value.rpartition(':')
        if not sep:
            raise DeviceConfigError(f'address must be host:port, got {value!r}')
        value = (host.strip('[]'), int(port))
    host, port = value
    if host == 'localhost':
        host = '127.0.0.1'
    try:
        host = str(ipaddress.ip_address(host))
    except ValueError:
        raise DeviceConfigError(f'address host must be an IP address, got {host!r}') from None
    if not 0 <= int(port) <= 65535:
        raise DeviceConfigError(f'port must be in [0, 65535], got {port!r}')
    return host, int(port)


class _Slot:
    """A request waiting for its response."""

    def __init__(self, message_type: int, session: int, nonce: int = 0) -> None:
        self.event = threading.Event()
        self.message: Optional[proto.Message] = None
        self.type = message_type
        self.session = session
        self.nonce = nonce


class UdpBackend:
    """
    Back-end ``'udp'``: a device reached over UDP.

    Parameters
    ----------
    device_address : (str, int) or str
        The device's IP address and port (``'127.0.0.1:5005'`` works too).
    bind_address : (str, int) or str
        Local address; default 127.0.0.1 and a free port.
    heartbeat_period_s : float
        Heartbeat interval [s] (10 Hz by default).
    request_timeout_s : float
        Wait for a response before a retry [s].
    retries : int
        Retries of a request after the first attempt.
    device_timeout_s : float
        Silence (no valid frame, no valid reply) after which the device counts as lost [s].
    reorder_window : int
        Sequence numbers the reorder buffer spans before it declares a gap.
    reorder_timeout_s : float
        Longest wait for a missing frame [s].
    max_queued_blocks : int
        Blocks kept for :meth:`read_block`; beyond it the oldest is dropped (counted).
    setpoint_format : {'float64', 'int16'}
        Sample format of setpoint frames (int16 uses the outputs' scale and offset).
    auto_reconnect : bool
        Reconfigure and restart a lost or rebooted device.
    clock : callable
        Monotonic clock [s].
    key : bytes, optional
        Pre-shared key: authenticate every datagram (HMAC-SHA256) and accept only
        authenticated ones.
    key_file : str or Path, optional
        Read the key from this file (:func:`~emfc_ros.core.device.auth.load_key_file`).
    """

    name = 'udp'
    host_paced = False
    applies_excitation = True
    recorded_config = None
    recorded_resolution = None
    finished = False
    intrusion_counters = INTRUSION_COUNTERS

    def __init__(self, device_address: Union[str, Tuple[str, int]] = ('127.0.0.1', 5005), *,
                 bind_address: Union[str, Tuple[str, int]] = ('127.0.0.1', 0),
                 heartbeat_period_s: float = 0.1, request_timeout_s: float = 0.2,
                 retries: int = 4, device_timeout_s: float = 0.5, reorder_window: int = 8,
                 reorder_timeout_s: float = 0.2, max_queued_blocks: int = 10000,
                 setpoint_format: str = 'float64', auto_reconnect: bool = True,
                 clock: Callable[[], float] = time.monotonic, key: Optional[bytes] = None,
                 key_file: Optional[Union[str, Path]] = None) -> None:
        if setpoint_format not in ('float64', 'int16'):
            raise DeviceConfigError(f"setpoint_format must be 'float64' or 'int16', got "
                                    f'{setpoint_format!r}')
        for name, value in (('heartbeat_period_s', heartbeat_period_s),
                            ('request_timeout_s', request_timeout_s),
                            ('device_timeout_s', device_timeout_s)):
            if not 0 < value <= 60:
                raise DeviceConfigError(f'{name} must be in (0, 60] s, got {value!r}')
        if key is not None and key_file:
            raise DeviceConfigError('give key or key_file, not both')
        if key_file:
            key = load_key_file(key_file)
        self.key = None if key is None else check_key(key, 'udp back-end key')
        self._signer = None if self.key is None else Signer(self.key)
        self.device_address = _address(device_address)
        bind = _address(bind_address)
        self.heartbeat_period_s = float(heartbeat_period_s)
        self.request_timeout_s = float(request_timeout_s)
        self.retries = int(retries)
        self.device_timeout_s = float(device_timeout_s)
        self.setpoint_format = setpoint_format
        self.auto_reconnect = bool(auto_reconnect)
        self._clock = clock
        self.counters: Dict[str, int] = dict.fromkeys(HOST_COUNTERS, 0)
        self.reorder = ReorderBuffer(reorder_window, reorder_timeout_s)
        self.config: Optional[DeviceConfig] = None
        self.specs: Optional[List[GeneratorSpec]] = None
        self.epoch: Optional[int] = None
        self.stream_epoch = 0
        self.boot_id: Optional[int] = None
        self.session = 0
        self.last_heartbeat: Optional[proto.HeartbeatReply] = None
        #: Why the device dropped our session (its refusal of a heartbeat), if it did.
        self.lost_reason = ''
        self._auth_hint = ''
        self._guards: Dict[int, ReplayGuard] = {0: ReplayGuard()}
        self._scale = np.ones(0)
        self._offset = np.zeros(0)
        self._lock = threading.Lock()
        self._blocks_ready = threading.Condition(self._lock)
        self._blocks: Deque[Block] = collections.deque(maxlen=int(max_queued_blocks))
        self._pending: Dict[int, _Slot] = {}
        self._answered: Deque[int] = collections.deque(maxlen=256)
        self._heartbeats: Dict[int, Tuple[float, int]] = {}
        self._heartbeats_missed: Deque[int] = collections.deque(maxlen=256)
        self._hb_valid_from = 0
        self._next_rid = 1
        self._setpoint_sequence = 0
        self._running = False
        self._need_recover = False
        self._session_lost = False
        self._lost = False
        now = self._clock()
        self._last_rx = now
        # The receiver's latest proof that nothing was waiting in the socket: the start of a
        # receive call that timed out without the host stalling.
        self._drained_at = now
        self._last_wake = self._awake_since = now
        self._closed = threading.Event()
        family = socket.AF_INET6 if ':' in bind[0] else socket.AF_INET
        self._sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
            self._sock.bind(bind)
        except OSError:
            self._sock.close()
            raise
        self._sock.settimeout(0.05)
        self.local_address = self._sock.getsockname()[:2]
        self._receiver = threading.Thread(target=self._receive_loop, daemon=True,
                                          name='emfc-udp-receiver')
        self._supervisor = threading.Thread(target=self._supervise_loop, daemon=True,
                                            name='emfc-udp-supervisor')
        self._receiver.start()
        self._supervisor.start()

    # -- the public interface ---------------------------------------------------------------

    def configure(self, config: DeviceConfig) -> None:
        """
        Take the device: CONFIGURE (a new session), after a STOP of our own earlier session.

        A device owned by another live session answers BUSY; the request is repeated until
        that owner has been silent for its watchdog timeout (we wait at most this
        configuration's ``watchdog_timeout_s`` plus a second).

        Parameters
        ----------
        config : DeviceConfig
            The configuration.

        Raises
        ------
        DeviceError
            If this back-end is running (stop first), or the device refuses or does not
            answer.
        """
        if self._running:
            raise DeviceError('configure while running: stop first')
        if self.session:
            try:
                self.request(proto.STOP, b'')
            except DeviceRefusedError:
                pass                # our session is gone: the CONFIGURE below takes a new one
        deadline = self._clock() + min(10.0, config.watchdog_timeout_s + 1.0)
        while True:
            try:
                self._request_configure(config)
                break
            except DeviceRefusedError as exc:
                if exc.status != proto.BUSY or self._clock() >= deadline:
                    raise
                time.sleep(min(0.1, max(0.0, deadline - self._clock())))
        with self._lock:
            self.config = config
            self.specs = None
            self._scale, self._offset = input_scaling(config)

    def _request_configure(self, config: DeviceConfig, **kwargs: Any) -> None:
        nonce = secrets.randbits(64)
        self.request(proto.CONFIGURE, proto.encode_configure_request(config, nonce, 0),
                     nonce=nonce, **kwargs)

    def set_function_generator(self, specs: Sequence[GeneratorSpec]) -> None:
        """
        Send FUNCGEN: one spec per output channel (``'off'``: follow the setpoint stream).

        Parameters
        ----------
        specs : sequence of GeneratorSpec
            The specs.

        Raises
        ------
        DeviceConfigError
            If a generator's output leaves its channel's limits.
        """
        specs = list(specs)
        if self.config is not None:
            check_generator_range(specs, self.config)
        self.request(proto.FUNCGEN, proto.encode_funcgen(specs))
        self.specs = specs

    def start(self) -> int:
        """
        Send START; the device samples from index 0 in a new epoch.

        Returns
        -------
        int
            The host's stream epoch (the ``epoch`` of the blocks): it increments at every
            START and every reconnect, so it stays unique when a rebooted device restarts
            its own epoch count.
        """
        if self.config is None:
            raise DeviceError('start before configure')
        self.request(proto.START, b'')
        self._running = True
        return self.stream_epoch

    def stop(self) -> None:
        """Send STOP (the device outputs its safe values)."""
        self._running = False
        self.request(proto.STOP, b'')

    def write_setpoints(self, first_sample_index: int, samples_V: np.ndarray) -> None:
        """
        Send setpoints as frames (split to fit datagrams) for the current epoch.

        Parameters
        ----------
        first_sample_index : int
            Device sample index of the first column.
        samples_V : numpy.ndarray
            Shape ``(outputs, n)`` [V], finite.

        Raises
        ------
        DeviceError
            If not started.
        DeviceConfigError
            If the shape is wrong or a value is not finite.
        """
        if self.config is None or self.epoch is None:
            raise DeviceError('setpoints before configure and start')
        values = np.asarray(samples_V, dtype=np.float64)
        n_out = len(self.config.outputs)
        if values.ndim != 2 or values.shape[0] != n_out or not np.all(np.isfinite(values)):
            raise DeviceConfigError(f'setpoints must be finite with shape ({n_out}, n), got '
                                    f'{values.shape}')
        if self.setpoint_format == 'int16':
            outs = self.config.outputs
            values = to_codes(values, np.array([c.scale for c in outs]),
                              np.array([c.offset for c in outs]))
            fmt = proto.FORMAT_INT16
        else:
            fmt = proto.FORMAT_FLOAT64
        step = proto.max_samples_per_frame(n_out, fmt)
        for start in range(0, values.shape[1], step):
            frame = proto.Frame(proto.STREAM_SETPOINT, self._setpoint_sequence, self.epoch,
                                int(first_sample_index) + start, values[:, start:start + step],
                                self.session)
            self._setpoint_sequence = (self._setpoint_sequence + 1) % SEQ_MOD
            self._send(proto.encode_frame(frame, self._signer))
            self.counters['setpoint_frames_sent'] += 1

    def read_block(self, timeout_s: float = 1.0) -> Optional[Block]:
        """
        Next measurement block, in sequence order, never spanning a gap.

        Parameters
        ----------
        timeout_s : float
            Longest wait [s].

        Returns
        -------
        Block or None
            One frame's samples in SI units, or None when none arrived in time.
        """
        deadline = self._clock() + max(0.0, float(timeout_s))
        with self._blocks_ready:
            while not self._blocks:
                remaining = deadline - self._clock()
                if remaining <= 0 or self._closed.is_set():
                    return None
                self._blocks_ready.wait(min(remaining, 0.05))
            return self._blocks.popleft()

    def status(self) -> proto.StatusReply:
        """
        Ask the device for its counters and configuration echo (STATUS).

        Returns
        -------
        StatusReply
            The reply.
        """
        return proto.decode_status_reply(self.request(proto.STATUS, b'').body)

    def take_faults(self) -> List[Tuple[str, Optional[int], str, bool]]:
        """
        Faults this back-end found itself: none (the bridge reads its health counters).

        Returns
        -------
        list
            Empty.
        """
        return []

    def health(self) -> Dict[str, int]:
        """
        Host counters plus what the last heartbeat reply said about the device.

        Returns
        -------
        dict
            Counter name to value (see ``docs/device_protocol.md``).
        """
        with self._lock:
            out = dict(self.counters)
            for key, value in self.reorder.counters.items():
                if key != 'delivered':
                    out[key] = value
            epoch = self.epoch
        hb = self.last_heartbeat
        out['device_underrun_samples'] = hb.underrun_samples if hb else 0
        out['device_watchdog_trips'] = hb.watchdog_trips if hb else 0
        out['device_watchdog_tripped'] = int(hb.watchdog_tripped) if hb else 0
        out['device_gap_filled_samples'] = hb.gap_filled_samples if hb else 0
        out['device_setpoint_frames_rejected'] = hb.setpoint_frames_rejected if hb else 0
        current = hb is not None and hb.epoch == epoch      # the records of this epoch only
        for key, value in (('device_watchdog_trip_index', hb.watchdog_trip_index if hb else None),
                           ('device_first_gap_index', hb.first_gap_index if current else None),
                           ('device_first_rejected_index',
                            hb.first_rejected_index if current else None)):
            out[key] = -1 if value is None else int(value)
        # Silence of the device (no valid datagram), proven by the receiver, while running.
        out['device_silent_ms'] = int(1000.0 * self.silence_s()) if self._running else 0
        out['authenticated'] = int(self.key is not None)
        return out

    @property
    def silence_timeout_s(self) -> float:
        """
        No block for this long while running counts as the device lost [s].

        Returns
        -------
        float
            ``device_timeout_s``.
        """
        return self.device_timeout_s

    def description_extra(self) -> Dict[str, Any]:
        """
        What this back-end adds to the measurement description's ``extra``.

        Returns
        -------
        dict
            Nothing (the device's address is in the bridge's parameters).
        """
        return {}

    def close(self) -> None:
        """Release the device (RELEASE stops it and ends our session; best effort), then quit."""
        if self._closed.is_set():
            return
        self._running = False
        if self.session:
            try:
                self.request(proto.RELEASE, b'', retries=1)
            except DeviceError:
                pass
        self._closed.set()
        self._receiver.join(2.0)
        self._supervisor.join(2.0)
        self._sock.close()

    def __enter__(self) -> 'UdpBackend':
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- requests ---------------------------------------------------------------------------

    def request(self, message_type: int, body: bytes, *, timeout_s: Optional[float] = None,
                retries: Optional[int] = None, nonce: int = 0) -> proto.Message:
        """
        Send a control request and wait for its response, retrying on timeout.

        Parameters
        ----------
        message_type : int
            Protocol message type.
        body : bytes
            Request body.
        timeout_s : float, optional
            Wait per attempt [s]; ``request_timeout_s`` by default.
        retries : int, optional
            Retries after the first attempt; ``retries`` by default.
        nonce : int
            CONFIGURE: the nonce in the body, which the response must echo.

        Returns
        -------
        Message
            The OK response.

        Raises
        ------
        DeviceTimeoutError
            If no response came.
        DeviceRefusedError
            If the device answered with an error status.
        """
        timeout_s = self.request_timeout_s if timeout_s is None else timeout_s
        retries = self.retries if retries is None else retries
        with self._lock:
            rid = self._take_rid()
            slot = _Slot(message_type, self.session, nonce)
            self._pending[rid] = slot
            self.counters['requests'] += 1
        message = proto.Message(message_type, rid, proto.KIND_REQUEST, proto.OK, body,
                                slot.session)
        data = proto.encode_message(message)
        try:
            for attempt in range(retries + 1):
                if self._closed.is_set():
                    break
                if attempt:
                    self.counters['request_retries'] += 1
                if self._signer is not None:    # a fresh counter for every attempt
                    data = proto.encode_message(message, self._signer)
                self._send(data)
                if slot.event.wait(timeout_s):
                    break
        finally:
            with self._lock:
                self._pending.pop(rid, None)
                self._answered.append(rid)
        msg = slot.message
        if msg is None:
            self.counters['request_timeouts'] += 1
            hint = f' ({self._auth_hint})' if self._auth_hint else ''
            raise DeviceTimeoutError(
                f'{proto.MESSAGE_TYPES[message_type]} to {self.device_address}: no response '
                f'in {retries + 1} attempts of {timeout_s} s{hint}')
        if msg.status != proto.OK:
            name = proto.STATUS_NAMES.get(msg.status, str(msg.status))
            raise DeviceRefusedError(msg.status, f'{name}: {msg.error_text()}')
        return msg

    def _take_rid(self) -> int:
        rid = self._next_rid
        self._next_rid = rid % (SEQ_MOD - 1) + 1
        return rid

    def _send(self, data: bytes) -> None:
        try:
            self._sock.sendto(data, self.device_address)
        except OSError:
            pass        # unreachable device: the timeouts and the supervisor handle it

    # -- the receiver -----------------------------------------------------------------------

    def _receive_loop(self) -> None:
        while not self._closed.is_set():
            t_call = self._clock()
            try:
                data, addr = self._sock.recvfrom(65536)
            except socket.timeout:
                data = None
                if self._clock() - t_call < HOST_STALL_S:
                    # Nothing was waiting at t_call: every datagram that arrived before it
                    # has been looked at. (A call the host stalled in proves nothing.)
                    self._drained_at = t_call
            except OSError:
                if self._closed.is_set():
                    return
                data = None
            now = self._clock()
            if data is not None:
                self._on_datagram(data, addr, now)
            with self._lock:
                self._deliver(self.reorder.expire(now))

    def _on_datagram(self, data: bytes, addr: Tuple, now: float) -> None:
        if tuple(addr[:2]) != self.device_address:
            self.counters['foreign'] += 1
            return
        magic = data[:4]
        try:
            if magic == proto.MAGIC_FRAME:
                item: Any = proto.decode_frame(data, self.key)
            elif magic == proto.MAGIC_CONTROL:
                item = proto.decode_message(data, self.key)
            else:
                self.counters['corrupt'] += 1
                return
        except AuthenticationError as exc:
            self.counters['unauthenticated'] += 1
            fields = exc.header
            if magic == proto.MAGIC_CONTROL and fields and fields[1] == proto.KIND_RESPONSE \
                    and fields[2] == proto.AUTH_REQUIRED:
                self._auth_hint = ('the device answers AUTH_REQUIRED: its key setting differs '
                                   'from the one of this host (a key file on one side only, '
                                   'or not the same key)')
            elif self.key is not None:
                self._auth_hint = 'datagrams from the device fail authentication: same key?'
            else:
                self._auth_hint = ('the device sends authenticated datagrams: give this host '
                                   'its key file')
            return
        except ProtocolError:
            self.counters['corrupt'] += 1
            return
        if magic == proto.MAGIC_FRAME:
            self._on_frame(item, now)
        else:
            self._on_response(item, now)

    def _fresh(self, session: int, counter: Optional[int]) -> bool:
        """With a key: whether a counter of this session was not seen before (lock held)."""
        if self.key is None:
            return True
        guard = self._guards.get(session)
        if guard is None:
            if len(self._guards) > 8:           # retired sessions: forget them
                self._guards = {k: v for k, v in self._guards.items()
                                if k in (0, self.session)}
            guard = self._guards[session] = ReplayGuard()
        if guard.accept(counter):
            return True
        self.counters['replayed'] += 1
        return False

    def _alive(self, now: float) -> None:
        """A valid datagram from the device (lock held)."""
        self._last_rx = now
        self._lost = False

    def _on_frame(self, frame: proto.Frame, now: float) -> None:
        with self._lock:
            if not self.session or frame.session != self.session:
                self.counters['wrong_session'] += 1
                return
            if not self._fresh(frame.session, frame.auth_counter):
                return
            self._alive(now)
            cfg = self.config
            if cfg is None or frame.stream_id != proto.STREAM_MEASUREMENT or \
                    frame.sample_format != proto.FORMAT_INT16 or \
                    frame.samples.shape[0] != len(cfg.inputs):
                self.counters['rejected'] += 1
                return
            if frame.epoch != self.epoch:
                self.counters['stale'] += 1
                return
            self.counters['frames_received'] += 1
            self._deliver(self.reorder.push(frame.sequence, frame.first_sample_index,
                                            frame.n_samples, frame, now))

    def _deliver(self, frames: List[proto.Frame]) -> None:
        # called with the lock held
        for frame in frames:
            if len(self._blocks) == self._blocks.maxlen:
                self.counters['blocks_overflowed'] += 1
            self._blocks.append(Block(frame.first_sample_index, self.config.sample_rate_Hz,
                                      self.stream_epoch, from_codes(frame.samples, self._scale,
                                                                    self._offset)))
            self.counters['blocks_delivered'] += 1
        if frames:
            self._blocks_ready.notify_all()

    def _on_response(self, msg: proto.Message, now: float) -> None:
        if not msg.is_response:
            self.counters['unsolicited'] += 1       # a device never sends requests
            return
        with self._lock:
            slot = self._pending.get(msg.request_id)
            if slot is not None and slot.event.is_set():
                slot = None
            if slot is not None and slot.type != msg.type:
                slot = None
            if slot is not None and msg.type == proto.CONFIGURE and msg.status == proto.OK:
                self._on_configured(slot, msg, now)
                return
            hb = self._heartbeats.get(msg.request_id) if msg.type == proto.HEARTBEAT else None
            sent_session = slot.session if slot is not None else \
                hb[1] if hb is not None else self.session
            if msg.session != sent_session:
                self.counters['wrong_session'] += 1
                return
            if not self._fresh(msg.session, msg.auth_counter):
                return
            if msg.type == proto.HEARTBEAT:
                self._on_heartbeat(msg, hb, now)
                return
            if slot is None:
                key = 'late_responses' if msg.request_id in self._answered else 'unsolicited'
                self.counters[key] += 1
                return
            self._alive(now)
            if msg.type == proto.START and msg.status == proto.OK:
                try:
                    epoch, boot = proto.START_RESPONSE.unpack(msg.body)
                except struct.error:
                    self.counters['corrupt'] += 1
                    return
                # before any frame of the new epoch is looked at (same socket, same order)
                self.epoch, self.boot_id = epoch, boot
                self.stream_epoch += 1
                self.reorder.reset(0, 0)
                self._hb_valid_from = self._next_rid
            slot.message = msg
            slot.event.set()

    def _on_configured(self, slot: _Slot, msg: proto.Message, now: float) -> None:
        """An OK CONFIGURE response: adopt the session it issues (lock held)."""
        try:
            nonce, session = proto.decode_configure_response(msg.body)
        except ProtocolError:
            self.counters['corrupt'] += 1
            return
        if nonce != slot.nonce or session != msg.session:
            self.counters['wrong_session'] += 1         # not the answer to this request
            return
        guard = ReplayGuard()
        if self.key is not None and not guard.accept(msg.auth_counter):
            self.counters['replayed'] += 1              # pragma: no cover (a fresh guard)
            return
        self.session = session
        self._guards = {0: self._guards.get(0) or ReplayGuard(), session: guard}
        self._session_lost = False
        self.lost_reason = ''
        self._alive(now)
        slot.message = msg
        slot.event.set()

    def _on_heartbeat(self, msg: proto.Message, sent: Optional[Tuple[float, int]],
                      now: float) -> None:
        # lock held
        if sent is None:
            late = msg.request_id in self._heartbeats_missed or \
                msg.request_id in self._answered
            self.counters['late_responses' if late else 'unsolicited'] += 1
            return
        del self._heartbeats[msg.request_id]
        self._answered.append(msg.request_id)
        self._alive(now)
        if msg.status != proto.OK:
            self.counters['heartbeat_refusals'] += 1
            if msg.status == proto.NOT_OWNER and sent[1] == self.session and self.session:
                if not self._session_lost:
                    self._session_lost = True
                    self.counters['sessions_lost'] += 1
                    self.lost_reason = msg.error_text()
                if self._running:
                    self._need_recover = True
            return
        try:
            reply = proto.decode_heartbeat_reply(msg.body)
        except ProtocolError:
            self.counters['corrupt'] += 1
            return
        self.counters['heartbeat_replies'] += 1
        self.last_heartbeat = reply
        fresh = (msg.request_id - self._hb_valid_from) % SEQ_MOD < SEQ_HALF
        if self._running and fresh and (reply.state != proto.STATE_RUNNING or
                                        reply.boot_id != self.boot_id or
                                        reply.epoch != self.epoch):
            self._need_recover = True

    # -- the supervisor ---------------------------------------------------------------------

    def silence_s(self) -> float:
        """
        How long the device has been silent, as far as the receiver can prove [s].

        From the last valid datagram to the receiver's latest look into an empty socket: a
        stalled host (whose receiver did not run) does not count its own stall as silence,
        since the datagrams the device sent meanwhile wait in the socket and are read first.

        Returns
        -------
        float
            Seconds, >= 0.
        """
        return max(0.0, self._drained_at - self._last_rx)

    def _is_lost(self, now: float) -> bool:
        if self.silence_s() > self.device_timeout_s:
            return True
        # A receiver that never finds its socket empty (a flood) proves nothing: bound it,
        # once the host has been running steadily again.
        return now - self._last_rx > self.device_timeout_s + FLOOD_GRACE_S and \
            now - self._awake_since > HOST_STALL_S

    def _supervise_loop(self) -> None:
        next_beat = self._clock()
        while not self._closed.wait(max(0.0, min(next_beat - self._clock(), 0.05))):
            now = self._clock()
            if now - self._last_wake > HOST_STALL_S:
                self._awake_since = now
                self.counters['host_stalls'] += 1
            self._last_wake = now
            if self._running and not self._lost and self._is_lost(now):
                with self._lock:
                    self._lost = True
                    self.counters['device_losses'] += 1
            if now < next_beat:
                continue
            next_beat = max(next_beat + self.heartbeat_period_s, now)
            if self.config is None or not self.session:
                continue
            self._heartbeat(now)
            if self._running and self.auto_reconnect and (self._lost or self._need_recover):
                self._recover()

    def _heartbeat(self, now: float) -> None:
        with self._lock:
            for rid, (sent, _) in list(self._heartbeats.items()):
                if now - sent >= self.heartbeat_period_s:
                    del self._heartbeats[rid]
                    self._heartbeats_missed.append(rid)
                    self.counters['heartbeat_misses'] += 1
            rid = self._take_rid()
            session = self.session
            self._heartbeats[rid] = (now, session)
            self.counters['heartbeats_sent'] += 1
        body = proto.HEARTBEAT_REQUEST.pack(time.monotonic_ns() & (2 ** 64 - 1))
        self._send(proto.encode_message(proto.Message(proto.HEARTBEAT, rid, body=body,
                                                      session=session), self._signer))

    def _recover(self) -> None:
        timeout_s = min(self.request_timeout_s, self.heartbeat_period_s)
        try:
            if not self._session_lost:
                try:
                    self.request(proto.STOP, b'', timeout_s=timeout_s, retries=0)
                except DeviceRefusedError:
                    pass
            self._request_configure(self.config, timeout_s=timeout_s, retries=1)
            if self.specs is not None:
                self.request(proto.FUNCGEN, proto.encode_funcgen(self.specs),
                             timeout_s=timeout_s, retries=1)
            self.request(proto.START, b'', timeout_s=timeout_s, retries=1)
        except DeviceError:
            return                              # still gone: try again at the next beat
        with self._lock:
            self._need_recover = False
            self._alive(self._clock())
            self._drained_at = self._last_rx
            self.counters['reconnects'] += 1
