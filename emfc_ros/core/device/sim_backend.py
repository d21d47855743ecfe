"""
The simulated device: the balance simulator behind the device interface, in process.

:class:`SimulatedDevice` is the sample-clocked core of a device (output sources, clamping,
watchdog cut-off, simulator, input scaling to int16 codes). :class:`SimBackend` exposes it as a
back-end paced by the caller: every :meth:`SimBackend.read_block` simulates the next block, so
no thread is needed and runs are reproducible. The UDP device emulator
(:mod:`emfc_ros.core.device.emulator`) runs the same core on a real-time clock, so both give
the same samples for the same seed and excitation.
"""

from __future__ import annotations

from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from emfc_ros.core.blocks import Block, Continuity
from emfc_ros.core.device.backend import (check_generator_range, DeviceConfig, from_codes,
                                          input_scaling, MAX_CHANNELS, to_codes)
from emfc_ros.core.device.errors import DeviceConfigError, DeviceError
from emfc_ros.core.device.function_generator import FunctionGenerator, GeneratorSpec
from emfc_ros.core.errors import BlockError
from emfc_ros.core.excitation_queue import ExcitationQueue, fill_outputs
from emfc_ros.core.model.balance_file import load_balance

IDLE = 'idle'
CONFIGURED = 'configured'
RUNNING = 'running'
#: The simulator has two actuator inputs: coil and load-changer setpoints.
N_OUTPUTS = 2

ENGINE_COUNTERS = ('samples_sent', 'setpoint_frames_received', 'setpoint_late_samples',
                   'underrun_samples', 'clamped_samples', 'watchdog_trips',
                   'setpoint_frames_rejected')


class SimulatedDevice:
    """
    The core of a simulated DAQ device, advanced block by block on its sample clock.

    Output ``j`` at device sample ``k`` is the function generator's value when its waveform
    is not ``'off'``, otherwise the host's setpoint stream (an :class:`ExcitationQueue`;
    samples the stream does not cover once it has begun are underruns at the safe value,
    queued samples behind the clock are dropped as late). Outputs are clamped to their
    limits, and forced to the safe values from the watchdog's trip index on. The simulator
    runs the outputs; the configured input channels are converted to int16 codes.

    Parameters
    ----------
    params : BalanceParameters, optional
        The balance; the shipped defaults when None.
    seed : int
        Simulator noise seed.
    max_inputs : int
        Most input channels a configuration may select (the device's analog inputs).
    simulator_options : mapping, optional
        Extra keyword arguments of :class:`Simulator` (``noise``, ``load_mass_kg``...), and
        ``control``: a :class:`~emfc_ros.core.control.loop_config.LoopConfig` that runs the
        position controller inside the device's sample loop (channels
        ``coil_current_precise_A`` and ``force_command_N`` join the catalogue; the outputs'
        coil setpoint is then added to the controller's), and ``load_schedule``: ``(time_s,
        mass_kg)`` pairs, the mass on the pan from that time of the device's sample clock on
        (from every START), applied at the exact sample (``load_changes`` records them).
    """

    def __init__(self, params: Any = None, seed: int = 0, *, max_inputs: int = MAX_CHANNELS,
                 simulator_options: Optional[Mapping[str, Any]] = None) -> None:
        from emfc_ros.core.sim import channels
        self.params = load_balance() if params is None else params
        self.seed = int(seed)
        self.max_inputs = int(max_inputs)
        self.simulator_options = dict(simulator_options or {})
        self.load_schedule = tuple((float(t), float(m)) for t, m in
                                   self.simulator_options.pop('load_schedule', ()) or ())
        #: ``(epoch, device sample index, mass [kg])`` of every scheduled load applied.
        self.load_changes: List[Tuple[int, int, float]] = []
        self._pending_loads: List[Tuple[int, float]] = []
        reference = bool(self.simulator_options.get('reference_channels', True))
        self.catalogue: Tuple[str, ...] = channels.channel_names(reference)
        if self.simulator_options.get('control') is not None:
            from emfc_ros.core.sim.closed_loop import EXTRA_CHANNELS
            self.catalogue += EXTRA_CHANNELS
        self.sim: Any = None
        self.config: Optional[DeviceConfig] = None
        self.state = IDLE
        self.epoch = 0
        self.index = 0
        self.generator: Optional[FunctionGenerator] = None
        self.queue: Optional[ExcitationQueue] = None
        self.watchdog_trip_index: Optional[int] = None
        #: First sample of this epoch of a refused setpoint frame (None: none refused).
        self.first_rejected_index: Optional[int] = None
        self.counters: Dict[str, int] = dict.fromkeys(ENGINE_COUNTERS, 0)
        self._gap_filled_before = 0             # gap-filled samples of earlier epochs
        #: End of the samples of this epoch produced before the first setpoint frame came: a
        #: late first frame's samples there were output at the safe values, uncounted so far.
        self._unstreamed_end = 0
        self._rows: List[int] = []
        self._scale = np.ones(0)
        self._offset = np.zeros(0)

    def warm_up(self, sample_rate_Hz: float = 10000.0) -> None:
        """
        Build the simulator now (the first build loads the compiled kernel, about a second).

        Parameters
        ----------
        sample_rate_Hz : float
            Sample rate to build it for [Hz].
        """
        if self.sim is None:
            try:
                self.sim = self._build_simulator(sample_rate_Hz)
                # compile (or load) the kernels now, on a throwaway copy: the first block of
                # a closed loop would otherwise keep the device silent past a host's timeout
                self._build_simulator(sample_rate_Hz).step_block(np.zeros((2, 1)))
            except ValueError:      # e.g. a closed loop that needs another rate: at configure
                self.sim = None

    def _build_simulator(self, sample_rate_Hz: float) -> Any:
        # the open-loop simulator, or with option ``control`` (a LoopConfig) the balance with
        # its position controller in the sample loop, as an FPGA runs it
        from emfc_ros.core.sim.simulator import Simulator
        options = dict(self.simulator_options)
        control = options.pop('control', None)
        sim = Simulator(self.params, sample_rate_Hz, self.seed, **options)
        if control is None:
            return sim
        from emfc_ros.core.sim.closed_loop import ClosedLoopSimulator
        return ClosedLoopSimulator(sim, control)

    def configure(self, config: DeviceConfig) -> None:
        """
        Accept a configuration (not while running).

        Parameters
        ----------
        config : DeviceConfig
            Inputs must name simulator channels; there must be two outputs (coil, load
            changer).

        Raises
        ------
        DeviceError
            If running.
        DeviceConfigError
            If a channel is unknown or the counts do not fit.
        """
        if self.state == RUNNING:
            raise DeviceError('configure while running: stop first')
        unknown = [n for n in config.input_names if n not in self.catalogue]
        if unknown:
            raise DeviceConfigError(f'unknown input channels {unknown}; the device has '
                                    f'{list(self.catalogue)}')
        if len(config.inputs) > self.max_inputs:
            raise DeviceConfigError(f'{len(config.inputs)} input channels requested, the device '
                                    f'has {self.max_inputs}')
        if len(config.outputs) != N_OUTPUTS:
            raise DeviceConfigError(f'the simulated balance has {N_OUTPUTS} outputs (coil, load '
                                    f'changer), got {len(config.outputs)}')
        if self.sim is None or self.sim.sample_rate_Hz != config.sample_rate_Hz:
            try:
                self.sim = self._build_simulator(config.sample_rate_Hz)
            except (TypeError, ValueError) as exc:
                raise DeviceConfigError(f'simulator: {exc}') from exc
        self.config = config
        self._rows = [self.sim.channel_names.index(n) for n in config.input_names]
        self._scale, self._offset = input_scaling(config)
        self.generator = FunctionGenerator([GeneratorSpec()] * N_OUTPUTS,
                                           config.sample_rate_Hz)
        self.state = CONFIGURED

    def set_generator(self, specs: Sequence[GeneratorSpec]) -> None:
        """
        Configure the function generator, one spec per output.

        Parameters
        ----------
        specs : sequence of GeneratorSpec
            One per output channel.

        Raises
        ------
        DeviceError
            If not configured.
        DeviceConfigError
            If the count is wrong, a signal cannot be built or its output would leave the
            channel's limits.
        """
        if self.config is None:
            raise DeviceError('function generator before configure')
        if len(specs) != len(self.config.outputs):
            raise DeviceConfigError(f'need {len(self.config.outputs)} generator specs, got '
                                    f'{len(specs)}')
        check_generator_range(specs, self.config)
        self.generator = FunctionGenerator(specs, self.config.sample_rate_Hz)

    def start(self) -> int:
        """
        Start at sample index 0 in a new epoch.

        Returns
        -------
        int
            The new epoch.

        Raises
        ------
        DeviceError
            If not configured.
        """
        if self.config is None:
            raise DeviceError('start before configure')
        self.epoch = (self.epoch + 1) % 2 ** 32
        self.index = 0
        self._unstreamed_end = 0
        if self.queue is not None:
            self._gap_filled_before += self.queue.gap_filled_samples
        self.queue = ExcitationQueue(self.config.safe_values_V)
        self.watchdog_trip_index = None
        self.first_rejected_index = None
        self._pending_loads = [(int(round(t * self.config.sample_rate_Hz)), m)
                               for t, m in self.load_schedule]
        self.state = RUNNING
        return self.epoch

    def stop(self) -> None:
        """Stop; the outputs hold their safe values."""
        if self.state == RUNNING:
            self.state = CONFIGURED

    def push_setpoints(self, first_sample_index: int, samples_V: np.ndarray) -> Continuity:
        """
        Queue host setpoints for the current epoch.

        Parameters
        ----------
        first_sample_index : int
            Device sample index of the first column.
        samples_V : numpy.ndarray
            Shape ``(outputs, n)`` [V].

        Returns
        -------
        Continuity
            How the block continued the stream (duplicates and late blocks are dropped).

        Raises
        ------
        DeviceError
            If not running.
        DeviceConfigError
            If the shape is wrong or a value is not finite.
        """
        if self.state != RUNNING or self.queue is None:
            raise DeviceError('setpoints while not running')
        samples = np.asarray(samples_V, dtype=np.float64)
        if samples.ndim != 2 or samples.shape[0] != len(self.config.outputs) or \
                not np.all(np.isfinite(samples)) or first_sample_index < 0:
            self.reject_setpoints(first_sample_index)
            raise DeviceConfigError(f'setpoints must be finite, shape ({len(self.config.outputs)},'
                                    f' n), first index >= 0; got shape {samples.shape}')
        self.counters['setpoint_frames_received'] += 1
        try:
            return self.queue.push(Block(int(first_sample_index), self.config.sample_rate_Hz,
                                         self.epoch, samples))
        except BlockError as exc:       # e.g. a jump too far ahead: refused
            self.reject_setpoints(first_sample_index)
            raise DeviceConfigError(f'setpoints refused: {exc}') from None

    def reject_setpoints(self, first_sample_index: Optional[int]) -> None:
        """
        Count a refused setpoint frame of the current epoch and record where it was.

        Parameters
        ----------
        first_sample_index : int or None
            Its first sample index, when known.
        """
        self.counters['setpoint_frames_rejected'] += 1
        if self.first_rejected_index is None and isinstance(first_sample_index, int) and \
                first_sample_index >= 0:
            self.first_rejected_index = int(first_sample_index)

    @property
    def first_gap_index(self) -> Optional[int]:
        """
        First sample of this epoch that a gap in the setpoint stream left at the safe values.

        Returns
        -------
        int or None
            None when the stream had no gap.
        """
        return None if self.queue is None else self.queue.first_gap_index

    @property
    def watchdog_tripped(self) -> bool:
        """
        Whether the watchdog holds the outputs at their safe values.

        Returns
        -------
        bool
            True from a trip until the next START.
        """
        return self.watchdog_trip_index is not None

    def trip_watchdog(self, at_sample_index: int) -> None:
        """
        Drive the outputs to their safe values from a sample index on (until START).

        Parameters
        ----------
        at_sample_index : int
            First sample at the safe value (not earlier than the next sample).
        """
        if self.watchdog_trip_index is None and self.state == RUNNING:
            self.watchdog_trip_index = max(int(at_sample_index), self.index)
            self.counters['watchdog_trips'] += 1

    def _stream(self, first: int, n: int, out: np.ndarray) -> None:
        late, underrun, self._unstreamed_end = fill_outputs(self.queue, first, n, out,
                                                            self._unstreamed_end)
        self.counters['setpoint_late_samples'] += late
        self.counters['underrun_samples'] += underrun

    def step(self, n: int) -> Tuple[int, np.ndarray, np.ndarray]:
        """
        Produce the next ``n`` samples.

        Parameters
        ----------
        n : int
            Samples.

        Returns
        -------
        first_sample_index : int
            Device index of the first sample.
        codes : numpy.ndarray
            int16 input codes, shape ``(inputs, n)``.
        outputs_V : numpy.ndarray
            Applied outputs [V] (after clamping, before the DAC), shape ``(outputs, n)``.

        Raises
        ------
        DeviceError
            If not running.
        """
        if self.state != RUNNING:
            raise DeviceError('step while not running')
        cfg = self.config
        first = self.index
        safe = cfg.safe_values_V[:, None]
        out = np.repeat(safe, n, axis=1)
        gen = self.generator
        if not all(gen.active(j) for j in range(len(cfg.outputs))):
            self._stream(first, n, out)
        for j in range(len(cfg.outputs)):
            if gen.active(j):
                out[j] = gen.samples(j, first, n)
        lo = np.array([c.min_V for c in cfg.outputs])[:, None]
        hi = np.array([c.max_V for c in cfg.outputs])[:, None]
        self.counters['clamped_samples'] += int(np.count_nonzero((out < lo) | (out > hi)))
        np.clip(out, lo, hi, out=out)
        if self.watchdog_trip_index is not None:
            out[:, max(0, min(n, self.watchdog_trip_index - first)):] = safe
        values = self._simulate(first, out)[self._rows]
        self.index += n
        self.counters['samples_sent'] += n
        return first, to_codes(values, self._scale, self._offset), out

    def _simulate(self, first: int, out: np.ndarray) -> np.ndarray:
        # the block, split where the load schedule puts a new mass on the pan
        n = out.shape[1]
        if not self._pending_loads or self._pending_loads[0][0] >= first + n:
            return self.sim.step_block(out)
        parts = []
        pos = 0
        while pos < n:
            while self._pending_loads and self._pending_loads[0][0] <= first + pos:
                _, mass = self._pending_loads.pop(0)
                self.sim.set_load(mass, self.sim.load_changer_coupled)
                self.load_changes.append((self.epoch, first + pos, mass))
            due = self._pending_loads[0][0] - first if self._pending_loads else n
            end = min(n, max(due, pos + 1))
            parts.append(self.sim.step_block(out[:, pos:end]))
            pos = end
        return np.concatenate(parts, axis=1)

    def to_si(self, codes: np.ndarray) -> np.ndarray:
        """
        Scale input codes to SI values with the active configuration.

        Parameters
        ----------
        codes : numpy.ndarray
            Shape ``(inputs, n)``.

        Returns
        -------
        numpy.ndarray
            float64 values.
        """
        return from_codes(codes, self._scale, self._offset)

    def all_counters(self) -> Dict[str, int]:
        """
        Engine counters plus the setpoint queue's (gap-filled samples since boot).

        Returns
        -------
        dict
            Counter name to value.
        """
        out = dict(self.counters)
        out['gap_filled_samples'] = self._gap_filled_before
        if self.queue is not None:
            qc = self.queue.counters()
            out.update({'setpoint_gaps': qc['gaps'], 'setpoint_duplicates': qc['duplicates'],
                        'setpoint_reordered': qc['reordered'],
                        'gap_filled_samples': self._gap_filled_before
                        + qc['gap_filled_samples']})
        return out


class SimBackend:
    """
    Back-end ``'sim'``: the simulated balance in process, paced by the caller.

    Each :meth:`read_block` simulates ``block_size`` samples, so blocks are always contiguous.
    There is no watchdog (nothing runs between calls); the transport counters stay 0.

    Parameters
    ----------
    params : BalanceParameters, optional
        The balance; read from ``config_path`` or the shipped defaults when None.
    seed : int
        Noise seed.
    config_path : str, optional
        A ``balance.yaml`` to read the parameters from.
    simulator_options : mapping, optional
        Extra keyword arguments of the simulator.
    """

    name = 'sim'
    #: Blocks are simulated when read: the host reads them on its clock.
    host_paced = True
    applies_excitation = True
    silence_timeout_s = 0.5
    recorded_config = None
    recorded_resolution = None
    finished = False
    intrusion_counters: Tuple[str, ...] = ()

    def __init__(self, params: Any = None, seed: int = 0, *, config_path: Optional[str] = None,
                 simulator_options: Optional[Mapping[str, Any]] = None) -> None:
        if params is None:
            params = load_balance(config_path)
        self.device = SimulatedDevice(params, seed, simulator_options=simulator_options)
        self._blocks = 0

    def configure(self, config: DeviceConfig) -> None:
        """
        Configure the simulated device.

        Parameters
        ----------
        config : DeviceConfig
            The configuration.
        """
        self.device.configure(config)

    def start(self) -> int:
        """
        Start at index 0.

        Returns
        -------
        int
            The new epoch.
        """
        return self.device.start()

    def stop(self) -> None:
        """Stop."""
        self.device.stop()

    def write_setpoints(self, first_sample_index: int, samples_V: np.ndarray) -> None:
        """
        Queue setpoints.

        Parameters
        ----------
        first_sample_index : int
            Device index of the first column.
        samples_V : numpy.ndarray
            Shape ``(outputs, n)`` [V].
        """
        self.device.push_setpoints(first_sample_index, samples_V)

    def set_function_generator(self, specs: Sequence[GeneratorSpec]) -> None:
        """
        Configure the on-device generator.

        Parameters
        ----------
        specs : sequence of GeneratorSpec
            One per output.
        """
        self.device.set_generator(specs)

    def read_block(self, timeout_s: float = 1.0) -> Optional[Block]:
        """
        Simulate and return the next block.

        Parameters
        ----------
        timeout_s : float
            Unused (the simulation does not wait).

        Returns
        -------
        Block or None
            The block in SI units; None when not running.
        """
        if self.device.state != RUNNING:
            return None
        first, codes, _ = self.device.step(self.device.config.block_size)
        self._blocks += 1
        return Block(first, self.device.config.sample_rate_Hz, self.device.epoch,
                     self.device.to_si(codes))

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
        Health counters.

        Returns
        -------
        dict
            Blocks delivered, zero transport defects, and the device counters.
        """
        out = {'frames_received': self._blocks, 'blocks_delivered': self._blocks, 'gaps': 0,
               'missing_samples': 0, 'duplicates': 0, 'reordered': 0, 'corrupt': 0, 'late': 0,
               'heartbeat_misses': 0, 'reconnects': 0}
        out.update({f'device_{k}': v for k, v in self.device.all_counters().items()})
        dev = self.device
        trip = dev.watchdog_trip_index
        out['device_watchdog_tripped'] = int(trip is not None)
        out['device_watchdog_trip_index'] = -1 if trip is None else int(trip)
        for key, index in (('device_first_gap_index', dev.first_gap_index),
                           ('device_first_rejected_index', dev.first_rejected_index)):
            out[key] = -1 if index is None else int(index)
        return out

    def description_extra(self) -> Dict[str, Any]:
        """
        What this back-end adds to the measurement description's ``extra``.

        Returns
        -------
        dict
            Nothing (the balance is in the bridge's parameters).
        """
        return {}

    def close(self) -> None:
        """Stop."""
        self.stop()
