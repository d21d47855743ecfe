"""
The device side of the UDP protocol, with the simulated balance inside and fault injection.

:class:`DeviceEmulator` binds one UDP socket (127.0.0.1 by default; other addresses only with
``allow_remote=True``) and runs one thread that answers control requests, accepts setpoint
frames from the configured host, paces the sample clock in real time and sends a measurement
frame whenever a frame's worth of samples is due, through the fault injector
(:class:`Faults`). The device core is :class:`~emfc_ros.core.device.sim_backend.SimulatedDevice`,
so the emulator produces the samples the ``sim`` back-end produces for the same seed and
excitation. ``emfc-device-emulator`` (:mod:`emfc_ros.cli.device_emulator`) runs it as a
process.
"""

from __future__ import annotations

import collections
import dataclasses
import ipaddress
import math
import random
import select
import socket
import threading
import time
from typing import Any, Callable, Deque, Dict, List, Mapping, Optional, Tuple

import numpy as np

from emfc_ros.core.device import protocol as proto
from emfc_ros.core.device.backend import from_codes
from emfc_ros.core.device.errors import DeviceConfigError, DeviceError, ProtocolError
from emfc_ros.core.device.sim_backend import CONFIGURED, RUNNING, SimulatedDevice

#: Fault options and their meaning (the CLI's ``--faults`` keys).
FAULT_KEYS = ('drop', 'duplicate', 'reorder', 'corrupt', 'delay_ms', 'stall_s',
              'stall_after_s', 'die_after_s')
NETWORK_COUNTERS = ('frames_sent', 'foreign_datagrams', 'corrupt_datagrams',
                    'setpoint_frames_rejected', 'heartbeats_received', 'late_blocks',
                    'faults_dropped', 'faults_duplicated', 'faults_reordered',
                    'faults_corrupted', 'faults_stalled_frames', 'send_errors')
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
    """

    drop: float = 0.0
    duplicate: float = 0.0
    reorder: float = 0.0
    corrupt: float = 0.0
    delay_ms: float = 0.0
    stall_s: float = 0.0
    stall_after_s: float = 1.0
    die_after_s: float = 0.0

    def __post_init__(self) -> None:
        for key in FAULT_KEYS:
            value = getattr(self, key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                    not math.isfinite(value) or value < 0:
                raise DeviceConfigError(f'fault {key} must be a finite number >= 0, got '
                                        f'{value!r}')
        probs = (self.drop, self.duplicate, self.reorder, self.corrupt)
        if any(p > 1 for p in probs) or sum(probs) > 1.0 + 1e-12:
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
    """

    def __init__(self, host: str = '127.0.0.1', port: int = 0, *, params: Any = None,
                 seed: int = 0, max_inputs: int = 4, faults: Optional[Faults] = None,
                 allow_remote: bool = False, record: bool = False,
                 simulator_options: Optional[Mapping[str, Any]] = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
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
        self._clock = clock
        self._sock: Optional[socket.socket] = None
        self._thread: Optional[threading.Thread] = None
        self._stop = threading.Event()
        self._die_now = threading.Event()
        self.dead = threading.Event()
        self.port = 0
        self._host_addr: Optional[Tuple] = None
        self._target: Optional[Tuple] = None
        self._configure_body = b''
        self._responses: 'collections.OrderedDict[Tuple, bytes]' = collections.OrderedDict()
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

    def _on_control(self, data: bytes, addr: Tuple) -> None:
        try:
            msg = proto.decode_message(data)
        except ProtocolError:
            self.counters['corrupt_datagrams'] += 1
            return
        if msg.is_response:
            self.counters['corrupt_datagrams'] += 1
            return
        key = (addr, msg.request_id, msg.type)
        if key in self._responses:                  # a retry: answer again, do not redo
            self._sendto(self._responses[key], addr)
            return
        if addr == self._host_addr or msg.type == proto.CONFIGURE:
            self._last_heard = self._clock()
        try:
            status, body = self._dispatch(msg, addr)
        except ProtocolError as exc:
            status, body = proto.BAD_REQUEST, str(exc).encode()
        except DeviceConfigError as exc:
            status, body = proto.BAD_REQUEST, str(exc).encode()
        except DeviceError as exc:
            status, body = proto.BAD_STATE, str(exc).encode()
        reply = proto.encode_message(proto.Message(msg.type, msg.request_id,
                                                   proto.KIND_RESPONSE, status, body[:60000]))
        self._responses[key] = reply
        while len(self._responses) > 64:
            self._responses.popitem(last=False)
        self._sendto(reply, addr)

    def _dispatch(self, msg: proto.Message, addr: Tuple) -> Tuple[int, bytes]:
        dev = self.device
        if msg.type == proto.CONFIGURE:
            config, stream_port = proto.decode_configure(msg.body)
            dev.configure(config)
            self._host_addr = addr
            self._target = (addr[0], stream_port or addr[1]) + tuple(addr[2:])
            self._configure_body = msg.body
            return proto.OK, b''
        if msg.type == proto.FUNCGEN:
            dev.set_generator(proto.decode_funcgen(msg.body))
            return proto.OK, b''
        if msg.type == proto.START:
            if addr != self._host_addr:
                raise DeviceError('START from an address that did not configure the device')
            epoch = dev.start()
            self._sequence = 0
            self._t0 = self._last_heard = self._clock()
            self._stall_done = False
            return proto.OK, proto.START_RESPONSE.pack(epoch, self.boot_id)
        if msg.type == proto.STOP:
            dev.stop()
            self._release_held()
            return proto.OK, b''
        if msg.type == proto.HEARTBEAT:
            if len(msg.body) != proto.HEARTBEAT_REQUEST.size:
                raise ProtocolError('HEARTBEAT body must be 8 bytes')
            (echo,) = proto.HEARTBEAT_REQUEST.unpack(msg.body)
            if addr == self._host_addr:
                self.counters['heartbeats_received'] += 1
            counters = dev.all_counters()
            return proto.OK, proto.encode_heartbeat_reply(proto.HeartbeatReply(
                echo, dev.index, dev.epoch, self.boot_id, STATE_CODES[dev.state],
                dev.watchdog_tripped, counters['underrun_samples'],
                counters['watchdog_trips'], dev.watchdog_trip_index))
        if msg.type == proto.STATUS:
            return proto.OK, proto.encode_status_reply(proto.StatusReply(
                dev.epoch, self.boot_id, STATE_CODES[dev.state], dev.watchdog_tripped,
                self.all_counters(), self._configure_body))
        raise ProtocolError(f'unsupported message type {msg.type}')   # pragma: no cover

    def _on_setpoints(self, data: bytes, addr: Tuple) -> None:
        if addr != self._host_addr:
            self.counters['foreign_datagrams'] += 1
            return
        try:
            frame = proto.decode_frame(data)
        except ProtocolError:
            self.counters['corrupt_datagrams'] += 1
            self.counters['setpoint_frames_rejected'] += 1
            return
        dev = self.device
        if frame.stream_id != proto.STREAM_SETPOINT or dev.state != RUNNING or \
                frame.epoch != dev.epoch or frame.samples.shape[0] != len(dev.config.outputs):
            self.counters['setpoint_frames_rejected'] += 1
            return
        samples = frame.samples
        if frame.sample_format == proto.FORMAT_INT16:
            outs = dev.config.outputs
            samples = from_codes(samples, np.array([c.scale for c in outs]),
                                 np.array([c.offset for c in outs]))
        try:
            dev.push_setpoints(frame.first_sample_index, samples)
        except (DeviceError, DeviceConfigError):
            self.counters['setpoint_frames_rejected'] += 1

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
                                codes)
            self._sequence = (self._sequence + 1) % 2 ** 32
            record = SentFrame(dev.epoch, frame.sequence, first, codes, dev.to_si(codes))
            if self.record:                     # before sending: readers may look at once
                self.sent.append(record)
            record.fate = self._emit(proto.encode_frame(frame), now)

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
