"""
Back-end ``'daqmx'``: an NI multifunction DAQ device through NI's ``nidaqmx`` client.

The client talks to the local NI-DAQmx driver, or over gRPC to an NI gRPC Device Server (a
real-time target, another PC, or ``emfc-daqmx-emulator``); ``nidaqmx`` is the optional extra
``emfc_ros[daqmx]`` and is imported only when this back-end is built.

Timing: one continuous AI task on the device's onboard sample clock, and one AO task clocked
by ``/<device>/ai/SampleClock`` with regeneration off, so excitation sample ``k`` and
measurement sample ``k`` are the same tick and an output the host failed to write in time is
NI-DAQmx's underflow error, never a silent repeat. The AO task is started first and waits for
the AI clock.

The data path is the back-end's own I/O thread, started with the device (``host_paced``
False): it reads the AI samples that are there (at least ``read_period_s`` of them, waiting
for them), tops the AO buffer up to ``output_lead_s`` ahead of the device's position (from the
setpoints the host queued with :meth:`DaqmxBackend.write_setpoints`, the safe values where it
has none: counted as underruns), feeds the hardware watchdog, and queues a measurement block
whenever ``block_size`` samples are in; :meth:`DaqmxBackend.read_block` takes them.

Faults: an NI-DAQmx error that means lost or unapplied samples
(:data:`~emfc_ros.core.device.daqmx_errors.FAULT_OF_CODE`) is latched with its code and NI's
text (:meth:`take_faults`); the outputs are then driven to their safe values by an on-demand
write. Stop drives them safe the same way. Where the device has a watchdog timer (X Series
PCIe/PXIe/USB devices do), it is armed with the outputs' safe values as AO expiration states
and fed at every read, so a host that dies leaves the outputs safe after
``watchdog_timeout_s`` without any host software.
"""

from __future__ import annotations

import collections
import threading
import time
from typing import Any, Callable, Deque, Dict, List, Optional, Sequence, Tuple

import numpy as np

from emfc_ros.core.blocks import Block
from emfc_ros.core.device import daqmx_errors as codes
from emfc_ros.core.device.backend import DeviceConfig
from emfc_ros.core.device.daqmx_wiring import (ai_wiring_by_name, DEFAULT_AI_WIRING,
                                               DEFAULT_AO_WIRING, DEFAULT_DEVICE, range_for,
                                               resolution_V)
from emfc_ros.core.device.errors import DeviceConfigError, DeviceError
from emfc_ros.core.device.function_generator import GeneratorSpec
from emfc_ros.core.errors import BlockError
from emfc_ros.core.excitation_queue import ExcitationQueue, fill_outputs

#: NI-DAQmx terminal configurations by the name the option takes.
TERMINAL_CONFIGS = ('DEFAULT', 'RSE', 'NRSE', 'DIFF', 'PSEUDO_DIFF')
WATCHDOG_MODES = ('auto', 'on', 'off')
#: Most values one read returns (all channels): 1.6 MB of float64 in one gRPC message.
MAX_READ_VALUES = 200_000
#: A fault the back-end reports: kind, first device sample, message, whether exact.
ReportedFault = Tuple[str, Optional[int], str, bool]


def default_terminals() -> Tuple[str, ...]:
    """
    The analog inputs of the default inputs, in their order (``docs/daqmx.md``).

    Returns
    -------
    tuple of str
        Terminal names (``'ai0'``, ...).
    """
    return tuple(w.terminal for w in DEFAULT_AI_WIRING)


def default_units_per_V() -> Tuple[float, ...]:
    """
    SI units per volt of the default inputs' signal conditioning, in their order.

    Returns
    -------
    tuple of float
        Units per volt (A/V for the current monitors, m/V for the position output, 1 for
        voltages).
    """
    return tuple(w.units_per_V for w in DEFAULT_AI_WIRING)


def default_ranges_V() -> Tuple[float, ...]:
    """
    The input ranges of the default inputs (+/- V), in their order.

    Returns
    -------
    tuple of float
        The ranges [V].
    """
    return tuple(w.range_V for w in DEFAULT_AI_WIRING)


class DaqmxBackend:
    """
    Back-end ``'daqmx'`` (module docstring).

    Parameters
    ----------
    device : str
        The NI-DAQmx device name (``'Dev1'``).
    ai_terminals : sequence of str
        The analog input of each configured input, in the configuration's order (``'ai0'``).
        Left at their defaults, the three input lists follow the default wiring
        (``docs/daqmx.md``) by channel name, whatever the inputs' order.
    ai_units_per_V : sequence of float
        SI units per volt at each input (the signal conditioning's inverse gain).
    ai_range_V : sequence of float
        Each input's range, +/- [V] (one of the device's ranges).
    ai_terminal_config : str
        One of :data:`TERMINAL_CONFIGS` for every input.
    ao_terminals : sequence of str
        The analog output of each configured output, in order (``'ao0'``).
    grpc_address : str
        ``host:port`` of an NI gRPC Device Server; '' uses the local NI-DAQmx driver.
    session_prefix : str
        Prefix of the task (gRPC session) names: ``<prefix>-ai``, ``-ao``, ``-safe``,
        ``-watchdog``.
    read_period_s : float
        The AI samples are read (and the outputs topped up) in chunks of this length [s].
    output_lead_s : float
        Outputs are written this far ahead of the last AI sample read [s]: the longest host
        stall the output rides out before NI-DAQmx reports an underflow. It must be shorter
        than the bridge's ``excitation_lead_s`` (setpoints arrive that far ahead).
    input_buffer_s : float
        The AI buffer [s]: the longest host stall before NI-DAQmx reports an overflow.
    watchdog : {'auto', 'on', 'off'}
        The hardware watchdog: 'auto' where the device has one, 'on' required, 'off' none.
    clock : callable
        Monotonic clock [s].
    """

    name = 'daqmx'
    host_paced = False
    applies_excitation = True
    recorded_config = None
    recorded_resolution = None
    finished = False
    intrusion_counters: Tuple[str, ...] = ()

    def __init__(self, device: str = DEFAULT_DEVICE,
                 ai_terminals: Sequence[str] = default_terminals(),
                 ai_units_per_V: Sequence[float] = default_units_per_V(),
                 ai_range_V: Sequence[float] = default_ranges_V(),
                 ai_terminal_config: str = 'DEFAULT',
                 ao_terminals: Sequence[str] = tuple(t for _, t in DEFAULT_AO_WIRING), *,
                 grpc_address: str = '', session_prefix: str = 'emfc',
                 read_period_s: float = 0.01, output_lead_s: float = 0.5,
                 input_buffer_s: float = 2.0, watchdog: str = 'auto',
                 clock: Callable[[], float] = time.monotonic) -> None:
        if ai_terminal_config not in TERMINAL_CONFIGS:
            raise DeviceConfigError(f'ai_terminal_config must be one of {TERMINAL_CONFIGS}, '
                                    f'got {ai_terminal_config!r}')
        if watchdog not in WATCHDOG_MODES:
            raise DeviceConfigError(f'watchdog must be one of {WATCHDOG_MODES}, got '
                                    f'{watchdog!r}')
        for what, value, top in (('read_period_s', read_period_s, 1.0),
                                 ('output_lead_s', output_lead_s, 10.0),
                                 ('input_buffer_s', input_buffer_s, 600.0)):
            if not 0.0 < float(value) <= top:
                raise DeviceConfigError(f'{what} must be in (0, {top:g}] s, got {value!r}')
        if output_lead_s < 2.0 * read_period_s:
            raise DeviceConfigError(f'output_lead_s ({output_lead_s:g} s) must be at least '
                                    f'twice read_period_s ({read_period_s:g} s): the outputs '
                                    'are topped up once per read')
        try:
            import nidaqmx                              # noqa: F401 - the optional extra
        except ImportError as exc:
            raise DeviceConfigError(
                "the daqmx back-end needs NI's nidaqmx client: pip install "
                f"'emfc_ros[daqmx]' ({exc})") from None
        self.device = str(device)
        self.ai_terminals = tuple(str(t) for t in ai_terminals)
        self.ai_units_per_V = tuple(float(u) for u in ai_units_per_V)
        self.ai_range_V = tuple(float(r) for r in ai_range_V)
        self.ai_terminal_config = ai_terminal_config
        self.ao_terminals = tuple(str(t) for t in ao_terminals)
        self.grpc_address = str(grpc_address)
        self.session_prefix = str(session_prefix)
        self.read_period_s = float(read_period_s)
        self.output_lead_s = float(output_lead_s)
        self.input_buffer_s = float(input_buffer_s)
        self.watchdog_mode = watchdog
        self._clock = clock
        self.silence_timeout_s = max(0.5, 10.0 * self.read_period_s)
        self.config: Optional[DeviceConfig] = None
        self.epoch = 0
        self.hardware_watchdog = False
        self.watchdog_note = ''
        self._channel: Any = None
        self._ai: Any = None
        self._ao: Any = None
        self._dog: Any = None
        self._reader: Any = None
        self._writer: Any = None
        self._lock = threading.Lock()
        self._io = threading.RLock()          # the tasks: reader thread and control calls
        self._queue: Optional[ExcitationQueue] = None
        self._unstreamed_end = 0
        self._running = False
        self._ao_failed = False
        self._ai_failed = False
        self._read_index = 0                   # AI samples read in this epoch
        self._ao_end = 0                       # AO samples written in this epoch
        self._parts: List[np.ndarray] = []
        self._part_samples = 0
        self._ready: Deque[Block] = collections.deque()
        self._ready_cv = threading.Condition(threading.Lock())
        self._pump_stop = threading.Event()
        self._pump_thread: Optional[threading.Thread] = None
        self._max_read = 1
        self._fed_at = 0.0
        self._feed_period_s = 0.05
        self._faults: List[ReportedFault] = []
        self._last_read = clock()
        self.counters: Dict[str, int] = dict.fromkeys((
            'blocks_delivered', 'samples_read', 'samples_written', 'read_calls',
            'device_underrun_samples', 'device_setpoint_late_samples',
            'device_setpoint_frames_rejected', 'daqmx_errors', 'watchdog_feeds',
            'stale_sessions_cleared'), 0)
        self._last_code = 0

    # -- tasks ------------------------------------------------------------------------------

    def _task(self, role: str) -> Any:
        import nidaqmx
        name = f'{self.session_prefix}-{role}'
        if not self.grpc_address:
            return nidaqmx.Task(name)
        return self._fresh_session(name, lambda options: nidaqmx.Task(name,
                                                                      grpc_options=options))

    def _fresh_session(self, name: str, create: Callable[[Any], Any]) -> Any:
        """A new server session of a name; one left by a host that died is cleared first."""
        import nidaqmx
        from nidaqmx import SessionInitializationBehavior as Init
        try:
            return create(self._grpc(name, Init.INITIALIZE_SERVER_SESSION))
        except nidaqmx.DaqError as exc:
            if exc.error_code != codes.DUPLICATE_TASK:
                raise
        create(self._grpc(name, Init.ATTACH_TO_SERVER_SESSION)).close()
        self.counters['stale_sessions_cleared'] += 1
        return create(self._grpc(name, Init.INITIALIZE_SERVER_SESSION))

    def _grpc(self, name: str, behavior: Any = None) -> Any:
        import grpc
        import nidaqmx
        if self._channel is None:
            self._channel = grpc.insecure_channel(
                self.grpc_address, options=[('grpc.enable_http_proxy', 0)])
        if behavior is None:
            return nidaqmx.GrpcSessionOptions(self._channel, name)
        return nidaqmx.GrpcSessionOptions(self._channel, name, initialization_behavior=behavior)

    def _phys(self, terminals: Sequence[str]) -> str:
        return ', '.join(f'{self.device}/{t}' for t in terminals)

    def _by_name(self, config: DeviceConfig) -> None:
        """Input lists left at their defaults follow the default wiring by channel name."""
        if (self.ai_terminals, self.ai_units_per_V, self.ai_range_V) != \
                (default_terminals(), default_units_per_V(), default_ranges_V()):
            return
        wiring = ai_wiring_by_name()
        unknown = [n for n in config.input_names if n not in wiring]
        if unknown:
            raise DeviceConfigError(f'inputs {unknown} are not in the default wiring '
                                    f'({list(wiring)}): give daqmx.ai_terminals, '
                                    'daqmx.ai_units_per_V and daqmx.ai_range_V, one per input')
        wires = [wiring[n] for n in config.input_names]
        self.ai_terminals = tuple(w.terminal for w in wires)
        self.ai_units_per_V = tuple(w.units_per_V for w in wires)
        self.ai_range_V = tuple(w.range_V for w in wires)

    def _check(self, config: DeviceConfig) -> None:
        self._by_name(config)
        n_in, n_out = len(config.inputs), len(config.outputs)
        for what, values, n in (('ai_terminals', self.ai_terminals, n_in),
                                ('ai_units_per_V', self.ai_units_per_V, n_in),
                                ('ai_range_V', self.ai_range_V, n_in),
                                ('ao_terminals', self.ao_terminals, n_out)):
            if len(values) != n:
                raise DeviceConfigError(f'daqmx.{what}: need {n} values (one per configured '
                                        f'{"input" if what.startswith("ai") else "output"}), '
                                        f'got {len(values)}')
        for ch, units, rng in zip(config.inputs, self.ai_units_per_V, self.ai_range_V):
            try:
                if range_for(rng) != rng:
                    raise ValueError(f'+/-{rng:g} V is not a device range')
            except ValueError as exc:
                raise DeviceConfigError(f'daqmx.ai_range_V of {ch.name}: {exc}') from None
            if units == 0.0:
                raise DeviceConfigError(f'daqmx.ai_units_per_V of {ch.name} must not be 0')
            step = resolution_V(rng) * units
            if abs(ch.scale - step) > 1e-9 * abs(step) or ch.offset != 0.0:
                raise DeviceConfigError(
                    f'input {ch.name}: input_scales gives {ch.scale:g} {ch.unit} per code, '
                    f'but the device step at +/-{rng:g} V and {units:g} {ch.unit}/V is '
                    f'{step:g} {ch.unit} (set input_scales to it, input_offsets to 0)')

    def configure(self, config: DeviceConfig) -> None:
        """
        Create the AI, AO and watchdog tasks for a configuration (replacing earlier ones).

        Parameters
        ----------
        config : DeviceConfig
            The configuration; its input scales must be the device's 16-bit step at each
            input's range (``docs/daqmx.md``).

        Raises
        ------
        DeviceConfigError
            If the configuration and the options disagree, or NI-DAQmx refuses a setting
            (its code and text in the message).
        DeviceError
            If running.
        """
        if self._running:
            raise DeviceError('configure while running: stop first')
        self._check(config)
        self._close_tasks()
        from nidaqmx.constants import AcquisitionType, RegenerationMode, TerminalConfiguration
        from nidaqmx.stream_readers import AnalogMultiChannelReader
        from nidaqmx.stream_writers import AnalogMultiChannelWriter
        import nidaqmx
        rate = config.sample_rate_Hz
        try:
            with self._io:
                ai = self._ai = self._task('ai')
                term = getattr(TerminalConfiguration, self.ai_terminal_config)
                for ch, terminal, rng in zip(config.inputs, self.ai_terminals,
                                             self.ai_range_V):
                    ai.ai_channels.add_ai_voltage_chan(
                        f'{self.device}/{terminal}', name_to_assign_to_channel=ch.name,
                        terminal_config=term, min_val=-rng, max_val=rng)
                buffer = max(int(self.input_buffer_s * rate), 2 * config.block_size)
                ai.timing.cfg_samp_clk_timing(rate, sample_mode=AcquisitionType.CONTINUOUS,
                                              samps_per_chan=buffer)
                ai.in_stream.input_buf_size = buffer
                ao = self._ao = self._task('ao')
                for out, terminal in zip(config.outputs, self.ao_terminals):
                    ao.ao_channels.add_ao_voltage_chan(
                        f'{self.device}/{terminal}', name_to_assign_to_channel=out.name,
                        min_val=out.min_V, max_val=out.max_V)
                ao.timing.cfg_samp_clk_timing(
                    rate, source=f'/{self.device}/ai/SampleClock',
                    sample_mode=AcquisitionType.CONTINUOUS,
                    samps_per_chan=self._lead_samples(rate) * 4)
                ao.out_stream.regen_mode = RegenerationMode.DONT_ALLOW_REGENERATION
                ao.out_stream.output_buf_size = self._lead_samples(rate) * 4
                # the stream reader and writer: one call per read or write, no shape checks
                self._reader = AnalogMultiChannelReader(ai.in_stream)
                self._reader.verify_array_shape = False
                self._writer = AnalogMultiChannelWriter(ao.out_stream, auto_start=False)
                self._writer.verify_array_shape = False
        except nidaqmx.DaqError as exc:
            self._close_tasks()
            raise DeviceConfigError(f'NI-DAQmx refused the configuration: {exc}') from None
        self.config = config

    def _lead_samples(self, rate: float) -> int:
        return max(int(round(self.output_lead_s * rate)), 2)

    def _chunk_samples(self, rate: float) -> int:
        return max(int(round(self.read_period_s * rate)), 1)

    def _arm_watchdog(self) -> None:
        """The hardware watchdog with the safe values as AO expiration states, or a note."""
        self.hardware_watchdog = False
        if self.watchdog_mode == 'off':
            self.watchdog_note = ('hardware watchdog off (daqmx.watchdog): a dead host leaves '
                                  'the outputs at their last values')
            return
        import nidaqmx
        from nidaqmx.constants import WatchdogAOExpirState
        from nidaqmx.system.watchdog import WatchdogTask
        from nidaqmx.types import AOExpirationState
        name = f'{self.session_prefix}-watchdog'
        try:
            timeout = self.config.watchdog_timeout_s
            if self.grpc_address:
                dog = self._fresh_session(name, lambda options: WatchdogTask(
                    self.device, name, timeout, grpc_options=options))
            else:
                dog = WatchdogTask(self.device, name, timeout)
            try:
                dog.cfg_watchdog_ao_expir_states([
                    AOExpirationState(f'{self.device}/{t}', out.safe_V,
                                      WatchdogAOExpirState.VOLTAGE)
                    for out, t in zip(self.config.outputs, self.ao_terminals)])
                dog.start()
            except nidaqmx.DaqError:
                dog.close()
                raise
        except nidaqmx.DaqError as exc:
            if self.watchdog_mode == 'on':
                raise DeviceError(f'daqmx.watchdog is on but the device refused its watchdog '
                                  f'timer: {exc}') from None
            self.watchdog_note = (f'no hardware watchdog on {self.device} (NI-DAQmx error '
                                  f'{exc.error_code}): a dead host leaves the outputs at '
                                  'their last values')
            return
        self._dog = dog
        self.hardware_watchdog = True
        self.watchdog_note = (f'hardware watchdog armed: outputs to their safe values after '
                              f'{self.config.watchdog_timeout_s:g} s without the host')

    # -- the interface ----------------------------------------------------------------------

    def start(self) -> int:
        """
        Write the first ``output_lead_s`` of safe values, start AO (waiting), then AI.

        Returns
        -------
        int
            The new epoch.

        Raises
        ------
        DeviceError
            If not configured, or NI-DAQmx refused to start (code and text in the message).
        """
        if self.config is None:
            raise DeviceError('start before configure')
        import nidaqmx
        cfg = self.config
        lead = self._lead_samples(cfg.sample_rate_Hz)
        with self._io:
            self.stop()
            self.epoch = (self.epoch + 1) % 2 ** 32
            with self._lock:
                self._queue = ExcitationQueue(cfg.safe_values_V)
                self._unstreamed_end = 0
                self._faults = []
            self._read_index = self._ao_end = 0
            self._parts, self._part_samples = [], 0
            with self._ready_cv:
                self._ready.clear()
            # a catch-up read stays well inside gRPC's 4 MB message limit (and the buffer)
            self._max_read = max(min(int(self.input_buffer_s * cfg.sample_rate_Hz) // 2,
                                     MAX_READ_VALUES // len(cfg.inputs)),
                                 self._chunk_samples(cfg.sample_rate_Hz))
            self._feed_period_s = min(0.05, cfg.watchdog_timeout_s / 5.0)
            self._ao_failed = self._ai_failed = False
            try:
                self._arm_watchdog()
                self._writer.write_many_sample(np.ascontiguousarray(self._outputs(lead)),
                                               timeout=1.0)
                self._ao.start()
                self._ai.start()
                if self._dog is not None:
                    self._dog.reset_timer()
                    self._fed_at = self._clock()
            except nidaqmx.DaqError as exc:
                raise DeviceError(f'NI-DAQmx refused to start: {exc}') from None
            self._running = True
            self._last_read = self._clock()
            self._pump_stop = threading.Event()
            self._pump_thread = threading.Thread(target=self._pump, args=(self._pump_stop,),
                                                 daemon=True, name='emfc-daqmx-io')
            self._pump_thread.start()
        return self.epoch

    def _outputs(self, n: int) -> np.ndarray:
        """The next ``n`` output samples from the setpoint queue (safe values where none)."""
        out = np.repeat(self.config.safe_values_V[:, None], n, axis=1)
        with self._lock:
            late, underrun, self._unstreamed_end = fill_outputs(
                self._queue, self._ao_end, n, out, self._unstreamed_end)
        self.counters['device_setpoint_late_samples'] += late
        self.counters['device_underrun_samples'] += underrun
        self._ao_end += n
        self.counters['samples_written'] += n
        return out

    def stop(self) -> None:
        """Stop both tasks and drive the outputs to their safe values (on demand)."""
        self._pump_stop.set()
        pump = self._pump_thread
        if pump is not None and pump is not threading.current_thread():
            pump.join(5.0)
        with self._io:
            was = self._running
            self._running = False
            for task in (self._ai, self._ao):
                if task is not None:
                    try:
                        task.stop()
                    except Exception:      # noqa: B902 - a latched error, already reported
                        pass
            if self._dog is not None:
                try:
                    self._dog.close()
                except Exception:          # noqa: B902
                    pass
                self._dog = None
            if was or self._ao_failed:
                self._drive_safe()

    def _drive_safe(self) -> bool:
        """Write the safe values to the outputs at once, from a task of its own."""
        if self.config is None:
            return False
        try:
            with self._task('safe') as task:
                for out, terminal in zip(self.config.outputs, self.ao_terminals):
                    task.ao_channels.add_ao_voltage_chan(f'{self.device}/{terminal}',
                                                         min_val=out.min_V, max_val=out.max_V)
                task.write([[v] for v in self.config.safe_values_V], auto_start=True)
                task.stop()
            return True
        except Exception as exc:          # noqa: B902 - a driver error or a dead link
            self._report_error(exc, 'driving the outputs safe')
            return False

    def write_setpoints(self, first_sample_index: int, samples_V: np.ndarray) -> None:
        """
        Queue setpoints ``(outputs, n)`` [V] for device samples from ``first_sample_index``.

        Parameters
        ----------
        first_sample_index : int
            Device sample index of ``samples_V[:, 0]``, >= 0.
        samples_V : numpy.ndarray, shape (outputs, n)
            Setpoints per output [V], finite; clipped to the outputs' limits.

        Raises
        ------
        DeviceError
            If not started.
        DeviceConfigError
            If the shape is wrong, a value is not finite, or the queue refuses the block.
        """
        if self.config is None or self._queue is None:
            raise DeviceError('setpoints before configure and start')
        samples = np.asarray(samples_V, dtype=np.float64)
        n_out = len(self.config.outputs)
        if samples.ndim != 2 or samples.shape[0] != n_out or \
                not np.all(np.isfinite(samples)) or first_sample_index < 0:
            self.counters['device_setpoint_frames_rejected'] += 1
            raise DeviceConfigError(f'setpoints must be finite, shape ({n_out}, n), first '
                                    f'index >= 0; got shape {samples.shape}')
        lo = np.array([c.min_V for c in self.config.outputs])[:, None]
        hi = np.array([c.max_V for c in self.config.outputs])[:, None]
        try:
            with self._lock:
                self._queue.push(Block(int(first_sample_index), self.config.sample_rate_Hz,
                                       self.epoch, np.clip(samples, lo, hi)))
        except BlockError as exc:
            self.counters['device_setpoint_frames_rejected'] += 1
            raise DeviceConfigError(f'setpoints refused: {exc}') from None

    def set_function_generator(self, specs: Sequence[GeneratorSpec]) -> None:
        """
        Refuse an active generator: an NI-DAQmx device has no function generator here.

        Parameters
        ----------
        specs : sequence of GeneratorSpec
            One per output; all must be ``'off'``.

        Raises
        ------
        DeviceConfigError
            If a spec is active (the bridge's ``excitation_mode: stream`` is what works).
        """
        if any(s.active for s in specs):
            raise DeviceConfigError('the daqmx back-end streams every output: it has no '
                                    'on-device function generator (use excitation_mode '
                                    "'stream')")

    def read_block(self, timeout_s: float = 1.0) -> Optional[Block]:
        """
        The next measurement block the I/O thread completed.

        Parameters
        ----------
        timeout_s : float
            Longest wait [s].

        Returns
        -------
        Block or None
            ``block_size`` samples in SI units, or None when none was complete in time.
        """
        deadline = self._clock() + max(0.0, float(timeout_s))
        with self._ready_cv:
            while not self._ready:
                remaining = deadline - self._clock()
                if remaining <= 0.0:
                    return None
                self._ready_cv.wait(min(remaining, 0.05))
            return self._ready.popleft()

    def _pump(self, stop: threading.Event) -> None:
        """The I/O thread: reads the inputs and tops the outputs up until stopped or failed."""
        while not stop.is_set():
            with self._io:
                if not self._running or self._ai_failed:
                    return
                try:
                    self._read_chunk()
                except Exception as exc:      # noqa: B902 - never end silently: a fault
                    self._ai_failed = True
                    self._report_error(exc, 'the I/O thread')
                    return

    def _read_chunk(self) -> None:
        """One read: what is there (at least one chunk, waiting for it); complete blocks."""
        import nidaqmx
        cfg = self.config
        rate = cfg.sample_rate_Hz
        try:
            avail = int(self._ai.in_stream.avail_samp_per_chan)
            n = min(max(self._chunk_samples(rate), avail), self._max_read)
            values = np.empty((len(cfg.inputs), n))
            self._reader.read_many_sample(values, n, timeout=max(4.0 * n / rate, 0.5))
        except nidaqmx.DaqError as exc:
            if exc.error_code == codes.SAMPLES_NOT_YET_AVAILABLE:
                return
            self._ai_failed = True
            self._report_error(exc, 'reading the inputs')
            self._fail_outputs()
            return
        except Exception as exc:          # noqa: B902 - the server or the link is gone
            self._ai_failed = True
            self._report_error(exc, 'reading the inputs')
            return
        self._last_read = self._clock()
        self.counters['read_calls'] += 1
        self.counters['samples_read'] += n
        self._read_index += n
        # the device is at least where the read ended, and further by what was left behind
        self._top_up(self._read_index + max(0, avail - n))
        self._parts.append(values * np.array(self.ai_units_per_V)[:, None])
        self._part_samples += n
        while self._part_samples >= cfg.block_size:
            data = np.concatenate(self._parts, axis=1)
            block, rest = data[:, :cfg.block_size], data[:, cfg.block_size:]
            self._parts = [rest] if rest.shape[1] else []
            self._part_samples = rest.shape[1]
            first = self._read_index - self._part_samples - cfg.block_size
            self.counters['blocks_delivered'] += 1
            with self._ready_cv:
                self._ready.append(Block(first, rate, self.epoch, block))
                self._ready_cv.notify_all()

    def _top_up(self, device_index: int) -> None:
        """Write outputs to ``output_lead_s`` past the device's index; feed the watchdog."""
        if self._ao_failed:
            return
        import nidaqmx
        target = device_index + self._lead_samples(self.config.sample_rate_Hz)
        committed = self._ao_end
        try:
            if target > self._ao_end:
                self._writer.write_many_sample(
                    np.ascontiguousarray(self._outputs(target - self._ao_end)), timeout=1.0)
            now = self._clock()
            if self._dog is not None and now - self._fed_at >= self._feed_period_s:
                self._dog.reset_timer()
                self._fed_at = now
                self.counters['watchdog_feeds'] += 1
        except nidaqmx.DaqError as exc:
            self._ao_failed = True
            # an underflow stops the generation at the first sample not written in time:
            # where the samples written ended, exactly
            underflow = exc.error_code in (codes.GEN_STOPPED_TO_PREVENT_REGEN_OF_OLD_SAMPLES,
                                           codes.OUTPUT_FIFO_UNDERFLOW_2)
            self._report_error(exc, 'writing the outputs', committed if underflow else None)
            self._fail_outputs()
        except Exception as exc:          # noqa: B902 - the server or the link is gone
            self._report_error(exc, 'writing the outputs')
            self._fail_outputs()

    def _fail_outputs(self) -> None:
        """After an error: stop the AO task and drive the outputs safe (the AI goes on)."""
        if self._ao is not None:
            try:
                self._ao.stop()
            except Exception:              # noqa: B902 - its latched error, reported
                pass
        self._ao_failed = True
        if self._last_code != codes.WRITE_FAILED_BECAUSE_WATCHDOG_EXPIRED:
            self._drive_safe()      # (an expired watchdog holds them at the safe values)

    def _report_error(self, exc: BaseException, what: str,
                      exact_index: Optional[int] = None) -> None:
        code = int(getattr(exc, 'error_code', 0) or 0)
        self.counters['daqmx_errors'] += 1
        self._last_code = code
        kind = codes.FAULT_OF_CODE.get(code, 'device_lost')
        text = str(exc).strip().replace('\n', ' ')
        detail = f'NI-DAQmx error {code}' if code else \
            f'the NI-DAQmx client failed ({type(exc).__name__})'
        message = f'{what}: {detail}: {text}'
        if kind == 'device_underrun':
            message += ' (outputs driven to their safe values)'
        index = self._read_index if exact_index is None else int(exact_index)
        with self._lock:
            self._faults.append((kind, index, message, exact_index is not None))

    def take_faults(self) -> List[ReportedFault]:
        """
        The faults found since the last call (kind, device index, message, exact).

        Returns
        -------
        list of tuple
            Each once.
        """
        with self._lock:
            found, self._faults = self._faults, []
        return found

    def health(self) -> Dict[str, int]:
        """
        Counters; ``device_silent_ms`` is the time since the last AI read while running.

        Returns
        -------
        dict
            Counter name to value.
        """
        out = dict(self.counters)
        out.update({'frames_received': self.counters['blocks_delivered'], 'gaps': 0,
                    'missing_samples': 0, 'duplicates': 0, 'reordered': 0, 'corrupt': 0,
                    'late': 0, 'heartbeat_misses': 0, 'reconnects': 0,
                    'device_watchdog_tripped': int(self._last_code ==
                                                   codes.WRITE_FAILED_BECAUSE_WATCHDOG_EXPIRED),
                    'device_watchdog_trip_index': -1,
                    'hardware_watchdog': int(self.hardware_watchdog),
                    'last_daqmx_error': self._last_code})
        with self._lock:
            gap = None if self._queue is None else self._queue.first_gap_index
            out['device_gap_filled_samples'] = 0 if self._queue is None else \
                self._queue.gap_filled_samples
        out['device_first_gap_index'] = -1 if gap is None else int(gap)
        out['device_first_rejected_index'] = -1
        silent = self._clock() - self._last_read if self._running else 0.0
        out['device_silent_ms'] = int(1000.0 * max(0.0, silent))
        return out

    def description_extra(self) -> Dict[str, Any]:
        """
        The device, its wiring and its watchdog, for the measurement description.

        Returns
        -------
        dict
            ``daqmx``: device, connection, terminals, ranges, scaling, watchdog.
        """
        return {'daqmx': {
            'device': self.device,
            'connection': f'grpc {self.grpc_address}' if self.grpc_address else 'local driver',
            'ai_terminals': list(self.ai_terminals),
            'ai_range_V': list(self.ai_range_V),
            'ai_units_per_V': list(self.ai_units_per_V),
            'ai_terminal_config': self.ai_terminal_config,
            'ao_terminals': list(self.ao_terminals),
            'ao_sample_clock': f'/{self.device}/ai/SampleClock',
            'output_lead_s': self.output_lead_s,
            'hardware_watchdog': self.hardware_watchdog,
            'watchdog_note': self.watchdog_note}}

    def _close_tasks(self) -> None:
        for attr in ('_ai', '_ao', '_dog'):
            task = getattr(self, attr)
            if task is not None:
                try:
                    task.close()
                except Exception:          # noqa: B902 - best effort on the way out
                    pass
                setattr(self, attr, None)

    def close(self) -> None:
        """Stop (outputs safe), release the tasks and the gRPC channel."""
        with self._io:
            self.stop()
            self._close_tasks()
            if self._channel is not None:
                self._channel.close()
                self._channel = None
