"""
The daq_bridge's decisions, without ROS: one device session.

A :class:`BridgeSession` owns everything the bridge decides: starting, stopping and retrying
the device, where each excitation sample goes on the device's clock (the offset, the
acceptance rules, the jump guard, the remap after a device restart), the setpoints written
ahead of the device, the safety state machine (excitation watchdog, emergency stop, safe
outputs confirmed by the device) and the latched faults, the effort command, the counters.
It publishes through a :class:`BridgeOutputs` (the node, or a test's recorder) and reads time
from injected clocks, so that every fault path runs deterministically without DDS
(``test/core/test_bridge_session.py``).

Thread model. Three threads call a session:

- the caller's (a node's executor): :meth:`on_excitation`, :meth:`on_command`,
  :meth:`tick`, :meth:`poll_host_paced`, :meth:`autostart_tick`, the service calls
  (:meth:`request_start`, :meth:`request_stop`, :meth:`emergency_stop`, :meth:`reset`);
- the session's worker (:class:`~emfc_ros.core.device.jobs.DeviceJobs`): every request that
  waits for the device (configure and start, stop, safe outputs, generator changes), one at
  a time in the order asked;
- the session's reader thread (back-ends that are not host-paced): :meth:`on_device_block`
  for each block the device delivers.

The stream state is guarded by one re-entrant lock, held only for bookkeeping: never while
waiting for the device, never while publishing a block.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from typing import Any, Callable, Dict, List, Optional, Tuple

import numpy as np

from emfc_ros.core.blocks import Block, Channel, SequenceTracker, StreamDescription
from emfc_ros.core.device import protocol
from emfc_ros.core.device.bridge_health import COUNTERS, diagnostic_level, percentiles_us
from emfc_ros.core.device.bridge_outputs import BridgeOutputs
from emfc_ros.core.device.bridge_safety import SafetyPath
from emfc_ros.core.device.bridge_settings import BridgeSettings
from emfc_ros.core.device.bridge_stream import StreamPath
from emfc_ros.core.device.clock import device_index_at
from emfc_ros.core.device.errors import DeviceConfigError, DeviceError, DeviceRefusedError
from emfc_ros.core.device.faults import describe, FaultMonitor
from emfc_ros.core.device.function_generator import GeneratorSpec
from emfc_ros.core.device.jobs import DeviceJobs
from emfc_ros.core.device_contract import EffortCommand, measurement_groups
from emfc_ros.core.excitation_queue import ExcitationQueue, JumpGuard

__all__ = ['BridgeOutputs', 'BridgeSession', 'RETRY_PERIOD_S']

#: Autostart retries a device that does not answer this often [s].
RETRY_PERIOD_S = 5.0
#: Latency samples kept for the percentiles on /diagnostics.
LATENCY_WINDOW = 20000


class BridgeSession(StreamPath, SafetyPath):
    """
    One device session of the bridge (module docstring).

    Parameters
    ----------
    settings : BridgeSettings
        The back-end and everything it runs with.
    outputs : BridgeOutputs
        Where outputs go.
    source : str
        The node's name, in the descriptions.
    clock_ns : callable
        Monotonic clock [ns] (device-index estimates, watchdogs, latency).
    time_ns : callable
        The clock the descriptions' ``start_time_ns`` and joint-state stamps use [ns].
    """

    def __init__(self, settings: BridgeSettings, outputs: BridgeOutputs, source: str = '',
                 clock_ns: Callable[[], int] = time.monotonic_ns,
                 time_ns: Callable[[], int] = time.time_ns) -> None:
        self.settings = settings
        self.backend = settings.backend
        self.config = settings.device
        self.runtime = dict(settings.runtime)
        self.specs: List[GeneratorSpec] = list(settings.specs)
        self._out = outputs
        self._source = source
        self._clock_ns = clock_ns
        self._time_ns = time_ns
        cfg = self.config
        self.rate = cfg.sample_rate_Hz
        self.safe = cfg.safe_values_V
        self._lo = np.array([c.min_V for c in cfg.outputs])[:, None]
        self._hi = np.array([c.max_V for c in cfg.outputs])[:, None]
        self.rows = {n: i for i, n in enumerate(cfg.input_names)}
        self.groups = measurement_groups(cfg.input_names, [c.unit for c in cfg.inputs])
        self._lock = threading.RLock()
        self._start_lock = threading.Lock()
        self._jobs = DeviceJobs('daq-bridge-device')
        self._early: List[Tuple[Block, np.ndarray, int]] = []
        self._worker_faults: List[Tuple[str, Optional[int], str, bool]] = []
        self._retry_at: Optional[float] = None
        self._start_refused = False
        self.autostart_active = False
        self.holding = False
        self.wanted = 0
        self.error = ''
        self.last_error = ''
        self.state = 'idle'
        self.counts: Dict[str, int] = collections.Counter()
        self._latency_ns: collections.deque = collections.deque(maxlen=LATENCY_WINDOW)
        self._age_ns: collections.deque = collections.deque(maxlen=LATENCY_WINDOW)
        self._reader: Optional[threading.Thread] = None
        self._reader_stop = threading.Event()
        self.estop = False
        self.tripped = False
        self.monitor = FaultMonitor()
        self._safe_failed = ''
        self.command = EffortCommand()
        self.last_position_m = 0.0
        self._logged_at: Dict[str, float] = {}
        # a latched fault that grew, not yet in the description; when it was last published
        self._grown_pending = False
        self._grown_at = -math.inf
        self._reset_stream_state()

    # -- time and logging ------------------------------------------------------------------

    def _log(self, level: str, message: str, throttle_s: float = 0.0, key: str = '') -> None:
        """A log line; one with a ``key`` at most once per ``throttle_s`` (repeats dropped)."""
        if throttle_s > 0.0:
            now = self._now_s()
            if now - self._logged_at.get(key, -math.inf) < throttle_s:
                return
            self._logged_at[key] = now
        self._out.log(level, message)

    def _now_s(self) -> float:
        return self._clock_ns() * 1e-9

    def device_index_now(self) -> int:
        """
        The device's sample index now, from the epoch's START-anchored monotonic clock.

        Returns
        -------
        int
            The estimate.
        """
        return device_index_at(self._clock_ns(), self._anchor_ns, self.rate)

    def _lead_samples(self) -> int:
        return max(int(math.ceil(self.runtime['excitation_lead_s'] * self.rate)), 1)

    # -- status ------------------------------------------------------------------------------

    def _set_state(self, state: str) -> None:
        self.state = state
        self._out.status_changed()

    def status_values(self) -> Dict[str, Any]:
        """
        What ``~/status`` says: the state and why.

        Returns
        -------
        dict
            ``state``, ``error``, ``last_error``, ``stream_epoch``, ``faults`` (count),
            ``device_busy`` (a request to the device under way).
        """
        return {'state': self.state, 'error': self.error, 'last_error': self.last_error,
                'stream_epoch': self.epoch if self.epoch is not None else -1,
                'faults': len(self.monitor.faults), 'device_busy': self._jobs.pending()}

    def readiness(self, matched: int, topic: str) -> Tuple[bool, str]:
        """
        Whether excitation arriving now is applied, and if not what the bridge waits for.

        Parameters
        ----------
        matched : int
            Subscriptions to the measurements now.
        topic : str
            The measurements' topic name (for the message).

        Returns
        -------
        (bool, str)
            Ready, and what it waits for ('' when ready).
        """
        if not self.backend.applies_excitation:
            return False, f'applies no excitation ({self.backend.name} back-end)'
        if self.holding:
            return False, (f'waits for {self.wanted} subscription(s) to {topic} before '
                           f'starting the device (a recorder; {matched} matched)')
        if self.state == 'running':
            return True, ''
        if self.state == 'error' or self.error:
            return False, f'refuses: {self.last_error or self.error}'
        return False, {'starting': 'waits for the device to start',
                       'stopping': 'waits for the device to stop'}.get(
            self.state, f'waits for a start (state {self.state}: call ~/start)')

    # -- starting and stopping ---------------------------------------------------------------

    def begin(self, autostart: bool, min_subscribers: int) -> None:
        """
        Start now, once ``min_subscribers`` listeners matched, or not at all.

        Parameters
        ----------
        autostart : bool
            Start the device without a ``~/start``.
        min_subscribers : int
            Listeners to the measurements to wait for first (0: none).
        """
        self.wanted = int(min_subscribers)
        self.holding = autostart and self.wanted > 0
        self._out.status_changed()
        if not autostart:
            return
        self.autostart_active = True
        if self.holding:
            self._log('info', f'waiting for {self.wanted} subscription(s) to measurements '
                              'before starting')
        else:
            self.request_start('autostart')

    def request_start(self, why: str) -> str:
        """
        Queue a start in the worker; say what happens.

        Parameters
        ----------
        why : str
            Who asks (``autostart``, ``~/start``), for the log.

        Returns
        -------
        str
            The answer.
        """
        if self.state == 'running':
            return 'already running'
        self._set_state('starting')
        self._jobs.submit('start', self._start_job, why)
        return ('start requested: configuring and starting the device in the background; '
                '~/status says when it runs (state running) or why not (state error)')

    def start_now(self, why: str = '~/start') -> Tuple[bool, str]:
        """
        Start and wait for the answer (in the caller's thread; tests, shutdown paths).

        Parameters
        ----------
        why : str
            Who asks.

        Returns
        -------
        (bool, str)
            Whether it runs, and what happened.
        """
        return self._jobs.submit('start', self._start_job, why).result(timeout=60.0)

    def _start_job(self, why: str) -> Tuple[bool, str]:
        self._start_refused = False
        ok, message = self._start()
        if ok:
            self._retry_at = None
            self._log('info', f'{why}: {message}')
        elif why == 'autostart' and self.autostart_active and self._start_refused:
            self._retry_at = None
            self._log('error', f'{message}; not retried (the device refused the '
                               'configuration: fix the parameters, for example inputs '
                               'for a device with fewer analog inputs, and restart the '
                               'node or call ~/start)')
        elif why == 'autostart' and self.autostart_active:
            self._retry_at = self._now_s() + RETRY_PERIOD_S
            self._log('error', f'{message}; retrying every {RETRY_PERIOD_S} s', 30.0,
                               'retry')
        else:
            self._log('error', message)
        return ok, message

    def autostart_tick(self, matched: int) -> None:
        """
        Autostart: once listeners matched (``min_subscribers``), and retries of a silent device.

        Parameters
        ----------
        matched : int
            Subscriptions to the measurements now.
        """
        if not self.autostart_active:
            return
        if self.holding:
            if matched < self.wanted:
                return
            self.end_hold()
            if self.state in ('running', 'starting'):     # started through ~/start
                return
            self._log('info', f'{matched} subscription(s) to measurements matched: '
                              'starting')
            self.request_start('autostart')
            return
        due = self._retry_at
        if due is not None and self._now_s() >= due and not self._jobs.pending('start'):
            self._retry_at = None
            if self.state != 'running':
                self.request_start('autostart')

    def end_hold(self) -> None:
        """Stop waiting for listeners and subscribe to the excitation."""
        if self.holding:
            self.holding = False
            self._out.open_excitation()

    def cancel_retry(self) -> None:
        """No more autostart retries (a ``~/stop``, shutdown)."""
        self.autostart_active = False
        self._retry_at = None

    def _reset_stream_state(self) -> None:
        self.epoch: Optional[int] = None
        self._expected: Optional[int] = None
        self.last_end: Optional[int] = None
        self._t_start = self._now_s()
        self._anchor_ns = self._clock_ns()
        self._start_time_ns = 0
        self._write_index: Optional[int] = None
        self.offset: Optional[int] = None
        #: The device's clock restarted under a running excitation stream (a remap follows).
        self._device_restarted = False
        self._exc_tracker = SequenceTracker()
        self._jump_guard = JumpGuard()
        self._exc_received_end = 0
        self.queue = ExcitationQueue(self.safe)
        self._acked = -1
        self._last_excitation: Optional[float] = None
        # device index after the last excitation sample written to the device (its setpoints
        # play out until then: the excitation watchdog counts from there too)
        self._exc_written_end: Optional[int] = None

    def _start(self) -> Tuple[bool, str]:
        with self._start_lock:          # a retry in its thread and a ~/start call
            return self._start_locked()

    def _start_locked(self) -> Tuple[bool, str]:
        if self.state == 'running':
            return True, 'already running'
        try:
            self.backend.configure(self.config)
            specs = self._safe_specs() if self.estop else self.specs
            if self.estop or self.settings.mode == 'function_generator':
                self.backend.set_function_generator(specs)
            # The START request waits for the device: not with the lock the executor's
            # callbacks take (no block of the new epoch is read before the state is reset).
            epoch = self.backend.start()
            with self._lock:
                self._reset_stream_state()
                self.tripped = False
                self._start_time_ns = self._time_ns()
                self.epoch = epoch
                self.monitor.reset(self._health(), epoch)
                if self.estop:             # the e-stop is still latched: still a fault
                    self.monitor.add('emergency_stop', 0, None,
                                     'emergency stop latched: outputs at their safe values')
        except (DeviceError, DeviceConfigError) as exc:
            # The device answered no (or the configuration cannot work): trying again in
            # 5 s gives the same answer, so autostart stops and says so.
            self._start_refused = isinstance(exc, DeviceConfigError) or (
                isinstance(exc, DeviceRefusedError)
                and exc.status in (protocol.BAD_REQUEST, protocol.UNSUPPORTED))
            self.last_error = f'start failed: {exc}'
            with self._lock:
                self.counts['excitation_not_running'] += len(self._early)
                self._early = []
                self._set_state('error')
            return False, self.last_error
        self.error = ''
        self._reader_stop.clear()
        with self._lock:        # the excitation kept during the start first, in order
            self._set_state('running')
            early, self._early = self._early, []
            for block, samples, clipped in early:
                self._take_excitation(block, samples, clipped)
        self.publish_descriptions()
        if not self.backend.host_paced:        # host-paced: the caller's timer reads
            self._reader = threading.Thread(target=self._read_loop, daemon=True,
                                            name='daq-bridge-reader')
            self._reader.start()
        return True, f'started: epoch {epoch}'

    def _stop(self) -> Tuple[bool, str]:
        """Stop the acquisition (worker thread, or close): waits for the device."""
        if self.state not in ('running', 'stopping', 'done'):
            return True, 'not running'
        self._reader_stop.set()
        if self._reader is not None:
            self._reader.join(5.0)
            self._reader = None
        try:
            self.backend.stop()
        except DeviceError as exc:
            self.last_error = f'stop: {exc}'
            self._set_state('stopped')
            return False, self.last_error
        self._set_state('stopped')
        return True, 'stopped: outputs at their safe values'

    def request_stop(self) -> str:
        """
        Queue a stop in the worker; say what happens.

        Returns
        -------
        str
            The answer.
        """
        if self.state not in ('running', 'starting', 'stopping', 'done'):
            return 'not running'
        if self.state == 'running':
            self._set_state('stopping')
        self._jobs.submit('stop', self._stop)
        return ('stop requested: stopping the device in the background (its outputs go to '
                'their safe values); ~/status says when it has (state stopped)')

    def close(self) -> bool:
        """
        Stop the acquisition and release the back-end.

        Returns
        -------
        bool
            False when a device request still ran at the end (logged).
        """
        self.cancel_retry()
        idle = self._jobs.close(timeout_s=10.0)
        if not idle:
            self._log('warning', 'a device request still runs at shutdown')
        try:
            self._stop()
        finally:
            try:
                self.backend.close()
            except (DeviceError, OSError):
                pass
        return idle

    # -- descriptions and diagnostics --------------------------------------------------------

    def descriptions(self) -> Dict[str, StreamDescription]:
        """
        The description of the measurements and of each group, by relative topic.

        Returns
        -------
        dict
            ``measurements`` and ``measurements/<group>`` to their descriptions.
        """
        cfg = self.config
        channels = tuple(Channel(c.name, c.unit, f'device input {i}: code * {c.scale:g} + '
                                                 f'{c.offset:g} {c.unit}')
                         for i, c in enumerate(cfg.inputs))
        extra = {'backend': self.backend.name, 'excitation_mode': self.settings.mode,
                 'start_monotonic_ns': int(self._anchor_ns),
                 'excitation_epoch': self._exc_tracker.epoch,
                 'excitation_offset_samples': self.offset,
                 'outputs': [{'name': c.name, 'min_V': c.min_V, 'max_V': c.max_V,
                              'safe_V': c.safe_V} for c in cfg.outputs],
                 'faults': [f.to_dict() for f in self.monitor.faults],
                 'resolution': self.settings.resolution}
        extra.update(self.settings.pan)
        extra.update(self.backend.description_extra())
        rows = {'measurements': tuple(range(len(channels)))}
        rows.update({f'measurements/{g}': r for g, r in self.groups.items()})
        return {topic: StreamDescription(topic.rsplit('/', 1)[-1], self.rate, cfg.block_size,
                                         tuple(channels[i] for i in r), epoch=self.epoch or 0,
                                         start_time_ns=self._start_time_ns,
                                         source=self._source, extra=extra)
                for topic, r in rows.items()}

    def publish_descriptions(self) -> None:
        """Publish the descriptions (they changed)."""
        self._out.publish_descriptions(self.descriptions())

    def diagnostic_values(self) -> Dict[str, Any]:
        """
        Everything ``/diagnostics`` reports, as one mapping.

        Returns
        -------
        dict
            Counter and state names (units in the names) to values.
        """
        values: Dict[str, Any] = {'state': self.state, 'backend': self.backend.name,
                                  'excitation_mode': self.settings.mode}
        try:
            values.update(self.backend.health())
        except (DeviceError, OSError) as exc:
            values['health_error'] = str(exc)
        tracker = self._exc_tracker.counters()
        values.update({f'excitation_{k}': v for k, v in tracker.items() if k != 'blocks'})
        q = self.queue.counters()
        values.update({'excitation_underrun_samples': q['underrun_samples'],
                       'excitation_gap_filled_samples': q['gap_filled_samples'],
                       'excitation_queued_samples': q['queued_samples']})
        for key in COUNTERS:
            values[key] = self.counts.get(key, 0)
        values['command_watchdog_trips'] = self.command.watchdog_trips
        for key in ('watchdog_trip_device_index', 'emergency_stop_device_index'):
            if key in self.counts:
                values[key] = self.counts[key]
        med, p99 = percentiles_us(list(self._latency_ns))
        age_med, age_p99 = percentiles_us(list(self._age_ns))
        values['faults'] = describe(self.monitor.faults) or 'none'
        values.update({'watchdog_tripped': int(self.tripped),
                       'emergency_stop': int(self.estop),
                       'sample_rate_Hz': self.rate,
                       'stream_epoch': self.epoch if self.epoch is not None else -1,
                       'device_next_index': self.last_end or 0,
                       'excitation_offset_samples': self.offset
                       if self.offset is not None else '',
                       'command_N': self.command.effort_N,
                       'latency_blocks': len(self._latency_ns),
                       'arrival_to_publish_median_us': f'{med:.1f}',
                       'arrival_to_publish_p99_us': f'{p99:.1f}',
                       'sample_age_at_publish_median_us': f'{age_med:.1f}',
                       'sample_age_at_publish_p99_us': f'{age_p99:.1f}',
                       'last_error': self.last_error, 'error': self.error})
        return values

    def diagnostic_status(self) -> Tuple[int, str, Dict[str, Any]]:
        """
        The level, message and values of ``/diagnostics``.

        Returns
        -------
        (int, str, dict)
            Level (0 OK, 1 WARN, 2 ERROR), message, values.
        """
        values = self.diagnostic_values()
        faults = self.monitor.faults
        level, message = diagnostic_level(values, self.backend.intrusion_counters,
                                          describe(faults[:1]), len(faults))
        return level, message, values
