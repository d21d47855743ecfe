"""
The device side of the UDP protocol, with the simulated balance inside and fault injection.

:class:`DeviceEmulator` binds one UDP socket (127.0.0.1 by default; other addresses only with
``allow_remote=True``) and runs one thread that answers control requests, accepts setpoint
frames from its owner, paces the sample clock in real time and sends a measurement frame
whenever a frame's worth of samples is due, through the fault injector (:class:`Faults`).

Ownership: a CONFIGURE accepted when the device is idle, or its owner is lost (no valid
HEARTBEAT from it for the configuration's watchdog timeout), makes its sender the owner and
issues a random 64-bit session id. START, STOP, FUNCGEN, HEARTBEAT, RELEASE and setpoint
frames are accepted only from the owner (its address and session); only the owner's
heartbeats feed the watchdog, after they passed every check. With a key (``key``, the CLI's
``--key-file``) every datagram must carry a valid HMAC tag and a fresh counter. Everything
refused is counted (``foreign_requests``, ``foreign_datagrams``,
``unauthenticated_datagrams``, ``replayed_datagrams``, ``unsolicited_datagrams``,
``corrupt_datagrams``) and visible in STATUS, which answers anyone.

The device core is :class:`~emfc_ros.core.device.sim_backend.SimulatedDevice`, so the
emulator produces the samples the ``sim`` back-end produces for the same seed and
excitation. ``emfc-device-emulator`` (:mod:`emfc_ros.cli.device_emulator`) runs it as a
process.
"""

from __future__ import annotations

import collections
import dataclasses
import ipaddress
import math
import random
import secrets
import select
import socket
import threading
import time
from typing import Any, Callable, Deque, Dict, List, Mapping, Optional, Tuple

import numpy as np

from emfc_ros.core.device import protocol as proto
from emfc_ros.core.device.auth import check_key, ReplayGuard, Signer
from emfc_ros.core.device.backend import from_codes
from emfc_ros.core.device.errors import (AuthenticationError, DeviceConfigError, DeviceError,
                                         ProtocolError)
from emfc_ros.core.device.sim_backend import CONFIGURED, RUNNING, SimulatedDevice

#: Fault options and their meaning (the CLI's ``--faults`` keys).
FAULT_KEYS = ('drop', 'duplicate', 'reorder', 'corrupt', 'delay_ms', 'stall_s',
              'stall_after_s', 'die_after_s', 'setpoint_drop')
NETWORK_COUNTERS = ('frames_sent', 'foreign_datagrams', 'corrupt_datagrams',
                    'heartbeats_received', 'late_blocks', 'faults_dropped',
                    'faults_duplicated', 'faults_reordered', 'faults_corrupted',
                    'faults_stalled_frames', 'send_errors', 'foreign_requests',
                    'unauthenticated_datagrams', 'replayed_datagrams', 'unsolicited_datagrams',
                    'setpoint_frames_stale', 'owner_changes', 'owner_takeovers',
                    'faults_setpoint_dropped')
#: Counters of datagrams the emulator refused (what someone else, or a stale session, sent).
REFUSED_COUNTERS = ('foreign_requests', 'foreign_datagrams', 'unauthenticated_datagrams',
                    'replayed_datagrams', 'unsolicited_datagrams', 'corrupt_datagrams')
STATE_CODES = {'idle': proto.STATE_IDLE, CONFIGURED: proto.STATE_CONFIGURED,
               RUNNING: proto.STATE_RUNNING}
#: Most frames produced in one loop pass when the clock is behind (then it catches up later).
MAX_CATCH_UP_FRAMES = 16
POLL_S = 0.05


@dataclasses.dataclass
class Faults:
    """
    Faults the emulator injects into its measurement stream.

    Each frame suffers at most one of drop, duplicate, reorder, corrupt, drawn with the given
    probabilities (their sum must not exceed 1).

    Attributes
    ----------
    drop : float
        Probability that a frame is not sent.
    duplicate : float
        Probability that a frame is sent twice.
    reorder : float
        Probability that a frame is held back and sent after the next frame that is sent.
    corrupt : float
        Probability that one byte of a frame is flipped (the CRC then fails).
    delay_ms : float
        Latency added to every frame [ms] (order kept).
    stall_s : float
        Once, ``stall_after_s`` after START, send no frames for this long; the frames sampled
        meanwhile are lost (a stalled DMA). Control requests are still answered.
    stall_after_s : float
        When the stall begins, after START [s].
    die_after_s : float
        Close the socket and stop answering this long after the emulator started [s]
        (0: never).
    setpoint_drop : float
        Probability that a valid setpoint frame of the owner is lost on its way in (as on
        the link): the device then fills the gap with the safe values.
    """

    drop: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    corrupt: float = 0.0
    delay_ms: float = 0.0
    stall_s: float = 0.0
    stall_after_s: float = 1.0
    die_after_s: float = 0.0
    setpoint_drop: float = 0.0

    def __post_init__(self) -> None:
        for key in FAULT_KEYS:
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                    not math.isfinite(value) or value < 0:
                raise DeviceConfigError(f'fault {key} must be a finite number >= 0, got '
                                        f'{value!r}')
        probs = (self.drop, self.duplicate, self.reorder, self.corrupt)
        if any(p > 1 for p in probs) or sum(probs) > 1.0 + 1e-12 or self.setpoint_drop > 1:
            raise DeviceConfigError(f'fault probabilities must be in [0, 1] with a sum <= 1, '
                                    f'got {probs}')

    @classmethod
    def parse(cls, text: str) -> 'Faults':
        """
        Parse ``'drop=0.01,duplicate=0.01,delay_ms=5'``.

        Parameters
        ----------
        text : str
            Comma-separated ``key=value`` pairs; keys are :data:`FAULT_KEYS`.

        Returns
        -------
        Faults
            The faults.

        Raises
        ------
        DeviceConfigError
            On an unknown key or a bad value.
        """
        values: Dict[str, float] = {}
        for item in filter(None, (s.strip() for s in text.split(','))):
            key, sep, value = item.partition('=')
            key = key.strip()
            if not sep or key not in FAULT_KEYS:
                raise DeviceConfigError(f'fault {item!r}: expected key=value with key one of '
                                        f'{FAULT_KEYS}')
            try:
                values[key] = float(value)
            except ValueError:
                raise DeviceConfigError(f'fault {key}: {value!r} is not a number') from None
        return cls(**values)


def check_bind_host(host: str, allow_remote: bool = False) -> str:
    """
    Check that a bind address is loopback (unless remote access is allowed explicitly).

    Parameters
    ----------
    host : str
        An IP address literal (``'localhost'`` means 127.0.0.1).
    allow_remote : bool
        Accept any address.

    Returns
    -------
    str
        The address literal.

    Raises
    ------
    DeviceConfigError
        If the address is not an IP literal, or not loopback without ``allow_remote``.
    """
    if host == 'localhost':
        host = '127.0.0.1'
    try:
        addr = ipaddress.ip_address(host)
    except ValueError:
        raise DeviceConfigError(f'bind address must be an IP address, got {host!r}') from None
    if not addr.is_loopback and not allow_remote:
        raise DeviceConfigError(f'bind address {host} is not loopback; pass allow_remote '
                                f'(--allow-remote) to expose the emulator on a network')
    return str(addr)


@dataclasses.dataclass
class SentFrame:
    """
    A measurement frame as produced, before fault injection (kept when recording).

    Attributes
    ----------
    epoch, sequence, first_sample_index : int
        Header fields.
    codes : numpy.ndarray
        int16 codes, shape ``(inputs, n)``.
    values : numpy.ndarray
        The codes scaled to SI values with the active configuration.
    fate : str
        What the fault injector did: ``'sent'``, ``'dropped'``, ``'duplicated'``,
        ``'reordered'``, ``'corrupted'`` or ``'stalled'``.
    """

    epoch: int
    sequence: int
    first_sample_index: int
    codes: np.ndarray
    values: np.ndarray
    fate: str = 'sent'


class DeviceEmulator:
    """
    A UDP device on loopback: control, paced measurement frames, setpoints, watchdog, faults.

    Parameters
    ----------
    host : str
        Bind address (loopback unless ``allow_remote``).
    port : int
        Bind port; 0 picks a free one (see :attr:`port` after :meth:`start`).
    params : BalanceParameters, optional
        The simulated balance; the shipped defaults when None.
    seed : int
        Simulator noise and fault random seed.
    max_inputs : int
        Analog inputs of the device (most channels a CONFIGURE may select).
    faults : Faults, optional
        Faults to inject.
    allow_remote : bool
        Permit a non-loopback bind address.
    record : bool
        Keep every produced frame in :attr:`sent` (for tests).
    simulator_options : mapping, optional
        Extra keyword arguments of the simulator.
    clock : callable
        Monotonic clock [s].
    key : bytes, optional
        Pre-shared key: every datagram must then be authenticated (HMAC-SHA256).
    """

    def __init__(self, host: str = '127.0.0.1', port: int = 0, *, params: Any = None,
                 seed: int = 0, max_inputs: int = 6, faults: Optional[Faults] = None,
                 allow_remote: bool = False, record: bool = False,
                 simulator_options: Optional[Mapping[str, Any]] = None,
                 clock: Callable[[], float] = time.monotonic,
                 key: Optional[bytes] = None) -> None:
        self.host = check_bind_host(host, allow_remote)
        self.requested_port = int(port)
        self.device = SimulatedDevice(params, seed, max_inputs=max_inputs,
                                      simulator_options=simulator_options)
        self.faults = faults or Faults()
        self.record = bool(record)
        self.sent: List[SentFrame] = []
        self.counters: Dict[str, int] = dict.fromkeys(NETWORK_COUNTERS, 0)
        self.boot_id = random.Random(seed ^ 0x5EED).getrandbits(32) ^ \
            (time.monotonic_ns() & 0xFFFFFFFF)
        self._rng = np.random.default_rng(seed)
        self._setpoint_rng = np.random.default_rng(seed + 1)
        #: First sample indices of the setpoint frames lost by the ``setpoint_drop`` fault.
        self.dropped_setpoints: List[int] = []
        self._clock = clock
        self._sock: Optional[socket.socket] = None
        self._thread: Optional[threading.Thread] = None
        self._stop = threading.Event()
        self._die_now = threading.Event()
        self.dead = threading.Event()
        self.port = 0
        self.key = None if key is None else check_key(key, 'emulator key')
        self._signer = None if key is None else Signer(self.key)
        # The owner: the address and session of the accepted CONFIGURE (none when idle or
        # released).
        self._host_addr: Optional[Tuple] = None
        self.session = 0
        self._guard = ReplayGuard()            # the owner's counters (with a key)
        self._guard_presession = ReplayGuard()  # session-0 requests (CONFIGURE, STATUS)
        self._target: Optional[Tuple] = None
        self._configure_body = b''
        self._responses: 'collections.OrderedDict[Tuple, proto.Message]' = \
            collections.OrderedDict()
        self._sequence = 0
        self._t0 = 0.0
        self._t_started = 0.0
        self._last_heard = 0.0
        self._stall_until = 0.0
        self._stall_done = False
        self._held: Optional[bytes] = None
        self._delayed: Deque[Tuple[float, bytes]] = collections.deque()
        self.error: Optional[BaseException] = None

    # -- life cycle -------------------------------------------------------------------------

    def start(self) -> int:
        """
        Build the simulator, bind the socket and start the device thread.

        Returns
        -------
        int
            The bound UDP port.
        """
        self.device.warm_up()
        family = socket.AF_INET6 if ':' in self.host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 1 << 20)
            sock.bind((self.host, self.requested_port))
        except OSError:
            sock.close()
            raise
        sock.setblocking(False)
        self._sock = sock
        self.port = sock.getsockname()[1]
        self._t_started = self._clock()
        self._thread = threading.Thread(target=self._run, name=f'emfc-emulator-{self.port}',
                                        daemon=True)
        self._thread.start()
        return self.port

    def stop(self, timeout_s: float = 5.0) -> None:
        """
        Stop the thread and close the socket.

        Parameters
        ----------
        timeout_s : float
            Longest wait for the thread [s].
        """
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout_s)
        self._close()

    def die(self) -> None:
        """Close the socket at once and stop answering (as if the device crashed)."""
        self._die_now.set()

    def stall(self, duration_s: float) -> None:
        """
        Send no measurement frames for a while (the samples of that time are lost).

        Parameters
        ----------
        duration_s : float
            Stall duration [s].
        """
        self._stall_until = self._clock() + float(duration_s)

    @property
    def address(self) -> Tuple[str, int]:
        """
        The bound address.

        Returns
        -------
        tuple
            ``(host, port)``.
        """
        return (self.host, self.port)

    def __enter__(self) -> 'DeviceEmulator':
        self.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    def all_counters(self) -> Dict[str, int]:
        """
        Device and network counters.

        Returns
        -------
        dict
            The :data:`~emfc_ros.core.device.protocol.DEVICE_COUNTERS` and a few more.
        """
        out = self.device.all_counters()
        out.update(self.counters)
        return out

    def _close(self) -> None:
        sock, self._sock = self._sock, None
        if sock is not None:
            sock.close()
        self.dead.set()

    # -- the device thread ------------------------------------------------------------------

    def _run(self) -> None:
        try:
            self._loop()
        except BaseException as exc:   # never die silently: keep it for whoever looks
            self.error = exc
        finally:
            self._close()

    def _loop(self) -> None:
        faults = self.faults
        while not self._stop.is_set():
            now = self._clock()
            if self._die_now.is_set() or (
                    faults.die_after_s and now - self._t_started >= faults.die_after_s):
                return
            wake = now + POLL_S
            if self.device.state == RUNNING:
                wake = min(wake, self._next_due())
            if self._delayed:
                wake = min(wake, self._delayed[0][0])
            readable, _, _ = select.select([self._sock], [], [], max(0.0, wake - now))
            if readable:
                self._receive()
            now = self._clock()
            if self.device.state == RUNNING:
                self._produce(now)
            self._send_delayed(now)

    def _receive(self) -> None:
        for _ in range(256):
            try:
                data, addr = self._sock.recvfrom(65536)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                self.counters['corrupt_datagrams'] += 1
                return
            if data[:4] == proto.MAGIC_CONTROL:
                self._on_control(data, addr)
            elif data[:4] == proto.MAGIC_FRAME:
                self._on_setpoints(data, addr)
            else:
                self.counters['corrupt_datagrams'] += 1

    # -- control ----------------------------------------------------------------------------

    def _owner_lost(self, now: float) -> bool:
        """No valid heartbeat from the owner for the configuration's watchdog timeout."""
        cfg = self.device.config
        return cfg is None or now - self._last_heard > cfg.watchdog_timeout_s

    def owner_alive(self) -> bool:
        """
        Whether a session owns the device and is alive (heard within the watchdog timeout).

        Returns
        -------
        bool
            True while another CONFIGURE would be refused (BUSY).
        """
        return self.session != 0 and not self._owner_lost(self._clock())

    def _is_owner(self, session: int, addr: Tuple) -> bool:
        return self.session != 0 and session == self.session and addr == self._host_addr

    def _reply(self, message: proto.Message, addr: Tuple) -> None:
        self._sendto(proto.encode_message(message, self._signer), addr)

    def _on_control(self, data: bytes, addr: Tuple) -> None:
        try:
            msg = proto.decode_message(data, self.key)
        except AuthenticationError as exc:
            self.counters['unauthenticated_datagrams'] += 1
            refused = proto.header_of_refused(exc)
            if refused is not None:     # say why, unauthenticated: it grants nothing
                why = 'this device requires authenticated requests (a key file)' \
                    if self.key is not None else \
                    'this device has no key: send unauthenticated requests'
                self._sendto(proto.encode_message(proto.Message(
                    refused.type, refused.request_id, proto.KIND_RESPONSE,
                    proto.AUTH_REQUIRED, why.encode(), refused.session)), addr)
            return
        except ProtocolError:
            self.counters['corrupt_datagrams'] += 1
            return
        if msg.is_response:
            self.counters['unsolicited_datagrams'] += 1
            return
        if self.key is not None:
            if self.session and msg.session == self.session:
                guard = self._guard
            elif msg.session == 0 or msg.type == proto.CONFIGURE:
                guard = self._guard_presession
            else:
                guard = None            # another session's request: refused below
            if guard is not None and not guard.accept(msg.auth_counter):
                self.counters['replayed_datagrams'] += 1
                return
        key = (addr, msg.session, msg.request_id, msg.type)
        if key in self._responses:                  # a retry: answer again, do not redo
            self._reply(self._responses[key], addr)
            return
        try:
            status, body, session = self._dispatch(msg, addr)
        except ProtocolError as exc:
            status, body, session = proto.BAD_REQUEST, str(exc).encode(), msg.session
        except DeviceConfigError as exc:
            status, body, session = proto.BAD_REQUEST, str(exc).encode(), msg.session
        except DeviceError as exc:
            status, body, session = proto.BAD_STATE, str(exc).encode(), msg.session
        reply = proto.Message(msg.type, msg.request_id, proto.KIND_RESPONSE, status,
                              body[:60000], session)
        self._responses[key] = reply
        while len(self._responses) > 64:
            self._responses.popitem(last=False)
        self._reply(reply, addr)

    def _refuse(self, status: int, text: str, session: int) -> Tuple[int, bytes, int]:
        self.counters['foreign_requests'] += 1
        return status, text.encode(), session

    def _dispatch(self, msg: proto.Message, addr: Tuple) -> Tuple[int, bytes, int]:
        dev = self.device
        now = self._clock()
        owner = self._is_owner(msg.session, addr)
        if msg.type == proto.STATUS:
            return proto.OK, proto.encode_status_reply(proto.StatusReply(
                dev.epoch, self.boot_id, STATE_CODES[dev.state], dev.watchdog_tripped,
                self.all_counters(), self._configure_body, self.owner_alive(),
                self.key is not None)), msg.session
        if msg.type == proto.CONFIGURE:
            return self._configure(msg, addr, owner, now)
        if not owner:
            held = 'owned by another session' if self.session else 'not configured'
            return self._refuse(proto.NOT_OWNER, f'{proto.MESSAGE_TYPES[msg.type]} refused: '
                                f'the request does not come from the owner (the device is '
                                f'{held}); CONFIGURE first', msg.session)
        if msg.type == proto.FUNCGEN:
            dev.set_generator(proto.decode_funcgen(msg.body))
            return proto.OK, b'', msg.session
        if msg.type == proto.START:
            epoch = dev.start()
            self._sequence = 0
            self._t0 = self._last_heard = now
            self._stall_done = False
            return proto.OK, proto.START_RESPONSE.pack(epoch, self.boot_id), msg.session
        if msg.type == proto.STOP:
            dev.stop()
            self._release_held()
            return proto.OK, b'', msg.session
        if msg.type == proto.RELEASE:
            dev.stop()
            self._release_held()
            self._host_addr, self._target, self.session = None, None, 0
            return proto.OK, b'', msg.session
        if msg.type == proto.HEARTBEAT:
            if len(msg.body) != proto.HEARTBEAT_REQUEST.size:
                raise ProtocolError('HEARTBEAT body must be 8 bytes')
            (echo,) = proto.HEARTBEAT_REQUEST.unpack(msg.body)
            # Only here, after every check, does the owner feed the watchdog.
            self._last_heard = now
            self.counters['heartbeats_received'] += 1
            counters = dev.all_counters()
            return proto.OK, proto.encode_heartbeat_reply(proto.HeartbeatReply(
                echo, dev.index, dev.epoch, self.boot_id, STATE_CODES[dev.state],
                dev.watchdog_tripped, counters['underrun_samples'],
                counters['watchdog_trips'], dev.watchdog_trip_index,
                counters['gap_filled_samples'], dev.first_gap_index,
                counters['setpoint_frames_rejected'], dev.first_rejected_index)), msg.session
        raise ProtocolError(f'unsupported message type {msg.type}')   # pragma: no cover

    def _configure(self, msg: proto.Message, addr: Tuple, owner: bool,
                   now: float) -> Tuple[int, bytes, int]:
        dev = self.device
        if not owner and self.session and not self._owner_lost(now):
            return self._refuse(proto.BUSY, 'CONFIGURE refused: the device is owned by a '
                                'live session (last heartbeat '
                                f'{now - self._last_heard:.2f} s ago); it is released when '
                                'the owner sends RELEASE or falls silent for the watchdog '
                                'timeout', msg.session)
        nonce, config, stream_port, config_body = proto.decode_configure_request(msg.body)
        if dev.state == RUNNING:
            if owner:
                raise DeviceError('configure while running: stop first')
            dev.stop()                  # the lost owner's run: outputs to their safe values
            self._release_held()
            self.counters['owner_takeovers'] += 1
        dev.configure(config)
        if not owner:
            self.counters['owner_changes'] += 1
        session = 0
        while session == 0:
            session = secrets.randbits(64)
        self.session = session
        self._guard = ReplayGuard()
        self._host_addr = addr
        self._target = (addr[0], stream_port or addr[1]) + tuple(addr[2:])
        self._configure_body = config_body
        self._last_heard = now
        return proto.OK, proto.CONFIGURE_RESPONSE.pack(nonce, session), session

    def _on_setpoints(self, data: bytes, addr: Tuple) -> None:
        try:
            frame = proto.decode_frame(data, self.key)
        except AuthenticationError:
            self.counters['unauthenticated_datagrams'] += 1
            return
        except ProtocolError:
            self.counters['corrupt_datagrams'] += 1
            return
        if not self._is_owner(frame.session, addr):
            self.counters['foreign_datagrams'] += 1
            return
        if self.key is not None and not self._guard.accept(frame.auth_counter):
            self.counters['replayed_datagrams'] += 1
            return
        dev = self.device
        if frame.stream_id != proto.STREAM_SETPOINT:
            self.counters['unsolicited_datagrams'] += 1
            return
        if dev.state != RUNNING or frame.epoch != dev.epoch:
            self.counters['setpoint_frames_stale'] += 1
            return
        if self.faults.setpoint_drop and self._setpoint_rng.random() < self.faults.setpoint_drop:
            self.counters['faults_setpoint_dropped'] += 1
            self.dropped_setpoints.append(frame.first_sample_index)
            return
        if frame.samples.shape[0] != len(dev.config.outputs):
            dev.reject_setpoints(frame.first_sample_index)
            return
        samples = frame.samples
        if frame.sample_format == proto.FORMAT_INT16:
            outs = dev.config.outputs
            samples = from_codes(samples, np.array([c.scale for c in outs]),
                                 np.array([c.offset for c in outs]))
        try:
            dev.push_setpoints(frame.first_sample_index, samples)
        except (DeviceError, DeviceConfigError):
            pass                        # counted and recorded by the device

    # -- the measurement stream -------------------------------------------------------------

    def _frame_samples(self) -> int:
        cfg = self.device.config
        return max(1, min(cfg.block_size,
                          proto.max_samples_per_frame(len(cfg.inputs), proto.FORMAT_INT16)))

    def _next_due(self) -> float:
        dev = self.device
        return self._t0 + (dev.index + self._frame_samples()) / dev.config.sample_rate_Hz

    def _produce(self, now: float) -> None:
        dev = self.device
        cfg = dev.config
        n = self._frame_samples()
        period_s = n / cfg.sample_rate_Hz
        for _ in range(MAX_CATCH_UP_FRAMES):
            due = self._next_due()
            if now < due:
                return
            if not dev.watchdog_tripped and now - self._last_heard > cfg.watchdog_timeout_s:
                trip_s = self._last_heard + cfg.watchdog_timeout_s - self._t0
                dev.trip_watchdog(int(math.ceil(trip_s * cfg.sample_rate_Hz)))
            first, codes, _ = dev.step(n)
            if now - due > period_s:
                self.counters['late_blocks'] += 1
            frame = proto.Frame(proto.STREAM_MEASUREMENT, self._sequence, dev.epoch, first,
                                codes, self.session)
            self._sequence = (self._sequence + 1) % 2 ** 32
            record = SentFrame(dev.epoch, frame.sequence, first, codes, dev.to_si(codes))
            if self.record:                     # before sending: readers may look at once
                self.sent.append(record)
            record.fate = self._emit(proto.encode_frame(frame, self._signer), now)

    def _emit(self, data: bytes, now: float) -> str:
        f = self.faults
        if f.stall_s and not self._stall_done and now - self._t0 >= f.stall_after_s:
            self._stall_done = True
            self._stall_until = now + f.stall_s
        if now < self._stall_until:
            self.counters['faults_stalled_frames'] += 1
            return 'stalled'
        u = self._rng.random()
        kind = 'ok'
        for name, p in (('drop', f.drop), ('duplicate', f.duplicate), ('reorder', f.reorder),
                        ('corrupt', f.corrupt)):
            if u < p:
                kind = name
                break
            u -= p
        if kind == 'drop':
            self.counters['faults_dropped'] += 1
            return 'dropped'
        if kind == 'reorder' and self._held is None:
            self.counters['faults_reordered'] += 1
            self._held = data
            return 'reordered'
        if kind == 'duplicate':
            self.counters['faults_duplicated'] += 1
            self._send(data, now)
            self._send(data, now)
        elif kind == 'corrupt':
            self.counters['faults_corrupted'] += 1
            raw = bytearray(data)
            pos = int(self._rng.integers(len(raw)))
            raw[pos] ^= int(self._rng.integers(1, 256))
            self._send(bytes(raw), now)
        else:
            kind = 'ok'
            self._send(data, now)
        self._release_held(now)
        return {'duplicate': 'duplicated', 'corrupt': 'corrupted'}.get(kind, 'sent')

    def _release_held(self, now: Optional[float] = None) -> None:
        if self._held is not None:
            held, self._held = self._held, None
            self._send(held, self._clock() if now is None else now)

    def _send(self, data: bytes, now: float) -> None:
        if self.faults.delay_ms > 0.0:
            self._delayed.append((now + self.faults.delay_ms * 1e-3, data))
        elif self._target is not None:
            self._sendto(data, self._target)
            self.counters['frames_sent'] += 1

    def _send_delayed(self, now: float) -> None:
        while self._delayed and self._delayed[0][0] <= now:
            _, data = self._delayed.popleft()
            if self._target is not None:
                self._sendto(data, self._target)
                self.counters['frames_sent'] += 1

    def _sendto(self, data: bytes, addr: Tuple) -> None:
        try:
            self._sock.sendto(data, addr)
        except OSError:
            self.counters['send_errors'] += 1
