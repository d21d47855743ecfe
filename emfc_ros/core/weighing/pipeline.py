"""
The weighing instrument: current and position in, placed and honest readings out.

:class:`WeighingPipeline` is what the ``weighing`` node runs (``docs/weighing.md``): from
blocks of measured coil current [A] and lever-end position [m] with their first sample index
it computes the compensation force ``k(y) I`` and produces

* **readings** (:class:`~emfc_ros.core.weighing.reading.Reading`): the moving average of
  :class:`~emfc_ros.core.weighing.reading.ReadingFilter`, one per reading period, each
  released only once the samples of one more reading period (the look-ahead) are in. A
  reading is ``steady`` when the dynamic estimate stayed within the stability threshold from
  the loop's settling time (0.1 s) before its window to the end of the look-ahead (so a load
  change shortly after the window, which the window itself cannot show yet, still makes the
  reading unsteady, and so does the loop's transient after a change), ``stable`` when it is
  steady and the balance has been zeroed (an uncalibrated reading is never stable). Its
  uncertainty adds to the statistical and calibration terms the current channel's
  quantisation (:mod:`.resolution`) and the lever's residual displacement;
* **dynamic readings** (:class:`DynamicReading`): the change-adaptive Kalman estimate
  (:class:`~emfc_ros.core.weighing.dynamic.DynamicWeigher`) every ``dynamic_period_s`` of the
  sample clock, released ``settle_window_s`` after its sample, ``settled`` only if the
  estimator's flag held from the sample through that look-ahead (and the balance is zeroed).

Every output carries its sample index; any split of the stream into blocks gives the same
outputs. Zero, tare and adjust act on the latest released reading and refuse with the reason.

No ROS imports.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, replace
import math
from typing import List, Optional, Sequence, Tuple

import numpy as np

from emfc_ros.core.model.parameters import MechanicalParameters
from emfc_ros.core.records import same_clock_records
from emfc_ros.core.weighing.calibration import (nominal_sensitivity_kg_per_N,
                                                WeighingCalibration)
from emfc_ros.core.weighing.compensation import compensation_force_N
from emfc_ros.core.weighing.dynamic import DEFAULT_FORCE_RANDOM_WALK_N_PER_SQRT_S, DynamicWeigher
from emfc_ros.core.weighing.errors import WeighingError
from emfc_ros.core.weighing.reading import (DEFAULT_STABILITY_THRESHOLD_KG, Reading,
                                            ReadingFilter)
from emfc_ros.core.weighing.resolution import quantisation_bias_bound, quantisation_u


@dataclass(frozen=True)
class DynamicReading:
    """
    The dynamic (Kalman) mass estimate at one sample.

    Attributes
    ----------
    sample_index : int
        The sample it describes.
    time_s : float
        ``sample_index / sample_rate`` [s].
    mass_kg : float
        Net mass [kg].
    standard_uncertainty_kg : float
        The filter's standard deviation, the calibration's and the current channel's
        resolution, combined [kg].
    settled : bool
        The estimator's settled flag held from this sample through the look-ahead and the
        balance is zeroed (``docs/weighing.md``: the estimate does not move by more than the
        threshold until the load changes).
    calibrated : bool
        Whether the balance had been zeroed.
    changes : int
        Load changes the estimator had declared up to this sample (since the start or gap).
    """

    sample_index: int
    time_s: float
    mass_kg: float
    standard_uncertainty_kg: float
    settled: bool
    calibrated: bool
    changes: int


class _History:
    """Per-sample arrays with absolute indices (trimmed by the owner)."""

    def __init__(self, names: Sequence[str]) -> None:
        self.names = tuple(names)
        self.clear()

    def clear(self, start: Optional[int] = None) -> None:
        self.start = start
        self.data = {n: np.zeros(0) for n in self.names}

    @property
    def end(self) -> Optional[int]:
        return None if self.start is None else self.start + self.data[self.names[0]].size

    def append(self, first: int, **arrays: np.ndarray) -> None:
        if self.start is None:
            self.start = first
        for n in self.names:
            self.data[n] = np.concatenate((self.data[n], np.asarray(arrays[n], dtype=float)))

    def trim(self, before: int) -> None:
        """Forget the samples before index ``before``."""
        if self.start is None or before <= self.start:
            return
        extra = min(before - self.start, self.data[self.names[0]].size)
        for n in self.names:
            self.data[n] = self.data[n][extra:]
        self.start += extra

    def get(self, name: str, first: int, last: int) -> np.ndarray:
        """Samples ``first .. last`` (inclusive) that are held (clipped to what is held)."""
        a = max(first - self.start, 0)
        b = max(last + 1 - self.start, 0)
        return self.data[name][a:b]


class WeighingPipeline:
    """
    Readings and dynamic readings from current and position (see the module docstring).

    Parameters
    ----------
    mechanics : MechanicalParameters
        The empty balance (the dynamic estimator's model, the calibration's geometry).
    motor_coeffs_N_per_A_per_mm_pow : sequence of float
        Motor coefficients ``k(y) = sum_j k[j] (y / 1 mm)^j`` [N/A].
    sample_rate_Hz : float
        Sample rate of the stream [Hz].
    calibration : WeighingCalibration
        The initial calibration.
    calibrated : bool
        Whether that calibration is a real one (a stored zero): readings are ``stable`` only
        once it is, or after :meth:`zero`.
    averaging_time_s, reading_period_s, stability_time_s, stability_threshold_kg, n_sub_blocks
        The readings (:class:`ReadingFilter`); ``stability_time_s`` is used only without the
        dynamic estimator.
    dynamic : bool
        Run the dynamic estimator (its estimate also decides whether readings are steady).
    position_noise_m_rms : float
        Position noise per sample the estimator assumes [m rms] (sensor noise and
        quantisation: ``sqrt(sigma^2 + step^2 / 12)``).
    force_random_walk_N_per_sqrt_s : float
        The estimator's ``q`` [N/sqrt(s)].
    dynamic_period_s : float
        Interval of the dynamic readings on the sample clock [s].
    settle_threshold_kg, settle_window_s : float
        The estimator's settled test [kg], [s]; ``settle_window_s`` is also the dynamic
        readings' look-ahead.
    current_resolution : (float, float)
        The current channel's ``(step, noise_rms)`` [A] (:mod:`.resolution`).
    adaptive : bool, optional
        The estimator's change-adaptive mode; default: on, unless the current channel's
        quantisation bound at the pan exceeds ``settle_threshold_kg`` (the 16-bit monitor:
        25 mg), whose wandering error would fire the change test at constant load.
    loop_settle_s : float
        How long the loop needs after a load change until the compensation force is within
        0.1 mg of its final value [s] (the default design: under 100 ms for any step up to
        200 g, ``docs/closed_loop.md``): a reading is steady only if the load was constant
        from this long before its window on.
    """

    def __init__(self, mechanics: MechanicalParameters,
                 motor_coeffs_N_per_A_per_mm_pow: Sequence[float], sample_rate_Hz: float,
                 calibration: WeighingCalibration, *, calibrated: bool = False,
                 averaging_time_s: float = 1.0, reading_period_s: float = 0.1,
                 stability_time_s: float = 0.5,
                 stability_threshold_kg: float = DEFAULT_STABILITY_THRESHOLD_KG,
                 n_sub_blocks: int = 10, dynamic: bool = True,
                 position_noise_m_rms: float = 2.0e-9,
                 force_random_walk_N_per_sqrt_s: float = DEFAULT_FORCE_RANDOM_WALK_N_PER_SQRT_S,
                 dynamic_period_s: float = 0.01, settle_threshold_kg: float = 1.0e-6,
                 settle_window_s: float = 0.02,
                 current_resolution: Tuple[float, float] = (0.0, 0.0),
                 adaptive: Optional[bool] = None, loop_settle_s: float = 0.1) -> None:
        self._motor = tuple(float(k) for k in motor_coeffs_N_per_A_per_mm_pow)
        step, noise = (float(v) for v in current_resolution)
        self._current_u_A = quantisation_u(step, noise)
        if adaptive is None:
            # a current channel coarser than the settle threshold (its quantisation error
            # wanders with the loop's dither) would make the change test fire at constant
            # load: the quiet steady-state filter then
            bias_kg = (abs(nominal_sensitivity_kg_per_N(mechanics)) * self._motor[0]
                       * quantisation_bias_bound(step, noise))
            adaptive = bias_kg < float(settle_threshold_kg)
        self._filter = ReadingFilter(sample_rate_Hz, calibration, averaging_time_s,
                                     reading_period_s, stability_time_s, stability_threshold_kg,
                                     n_sub_blocks)
        self._fs = self._filter.sample_rate_Hz
        self._threshold_kg = float(stability_threshold_kg)
        self._calibration = calibration
        self._calibrated = bool(calibrated)
        self._weigher = None
        if dynamic:
            self._weigher = DynamicWeigher(
                mechanics, self._fs, position_noise_m_rms=position_noise_m_rms,
                force_random_walk_N_per_sqrt_s=force_random_walk_N_per_sqrt_s,
                settle_window_s=settle_window_s, settle_threshold_kg=settle_threshold_kg,
                adaptive=adaptive)
        self._dyn_period = max(1, int(round(float(dynamic_period_s) * self._fs)))
        if not (math.isfinite(float(dynamic_period_s)) and float(dynamic_period_s) > 0.0):
            raise WeighingError(f'dynamic_period_s: must be finite and > 0, got '
                                f'{dynamic_period_s!r}')
        self._dyn_lookahead = max(1, int(round(float(settle_window_s) * self._fs)))
        self._lookahead = self._filter.period_samples
        if not (math.isfinite(float(loop_settle_s)) and float(loop_settle_s) >= 0.0):
            raise WeighingError(f'loop_settle_s: must be finite and >= 0, got '
                                f'{loop_settle_s!r}')
        self._settle = int(round(float(loop_settle_s) * self._fs))
        self._k0_N_per_A = self._motor[0]
        # the static coil gain [m/N] turns a lever displacement into a spring force
        self._coil_gain_m_per_N = (self._weigher.coil_gain_m_per_N if self._weigher is not None
                                   else DynamicWeigher(mechanics, self._fs,
                                                       adaptive=False).coil_gain_m_per_N)
        self._history = _History(('position', 'pan', 'settled', 'pan_u', 'changes'))
        self._pending: deque = deque()
        self._next_index: Optional[int] = None
        self._next_dynamic: Optional[int] = None
        self._last_pan_N: Optional[float] = None
        self._changes = 0
        self._position_zero_m = 0.0
        self.last_reading: Optional[Reading] = None
        self.gap_count = 0

    # -- configuration -------------------------------------------------------------------

    @property
    def sample_rate_Hz(self) -> float:
        """Sample rate [Hz]."""
        return self._fs

    @property
    def calibration(self) -> WeighingCalibration:
        """The calibration applied to new outputs."""
        return self._calibration

    @property
    def calibrated(self) -> bool:
        """Whether the balance has been zeroed (or given a stored calibration)."""
        return self._calibrated

    @property
    def dynamic(self) -> bool:
        """Whether the dynamic estimator runs."""
        return self._weigher is not None

    @property
    def changes(self) -> int:
        """Load changes declared by the dynamic estimator so far."""
        return self._weigher.changes if self._weigher is not None else 0

    @property
    def samples_lost(self) -> int:
        """Samples missing in gaps of the stream so far."""
        return self._filter.samples_lost

    def set_calibration(self, calibration: WeighingCalibration, calibrated: bool = True) -> None:
        """
        Replace the calibration (history is kept in force).

        Parameters
        ----------
        calibration : WeighingCalibration
            The new calibration.
        calibrated : bool
            Whether it is a real one.
        """
        if not isinstance(calibration, WeighingCalibration):
            raise WeighingError(f'calibration: need a WeighingCalibration, got {calibration!r}')
        self._calibration = calibration
        self._filter.calibration = calibration
        self._calibrated = bool(calibrated)

    # -- the stream ----------------------------------------------------------------------

    def push(self, current_A, position_m,
             first_sample_index: int) -> Tuple[List[Reading], List[DynamicReading]]:
        """
        Add a block and return the readings and dynamic readings it releases.

        Parameters
        ----------
        current_A : array_like, shape (n,)
            Measured coil current [A].
        position_m : array_like, shape (n,)
            Measured lever-end position [m].
        first_sample_index : int
            Absolute index of the first sample; a discontinuity (gap) restarts the window
            and the estimator, and releases what waited for samples that will not come, as
            not stable.

        Returns
        -------
        (list of Reading, list of DynamicReading)
            In sample order.

        Raises
        ------
        WeighingError
            Arrays of different lengths, not 1-D, or not finite; a non-integer index.
        """
        current, position = same_clock_records(('current_A', 'position_m'),
                                               (current_A, position_m), WeighingError,
                                               allow_empty=True)
        if not (np.all(np.isfinite(current)) and np.all(np.isfinite(position))):
            raise WeighingError('current_A, position_m: contain non-finite samples')
        first = int(first_sample_index)
        if first != first_sample_index:
            raise WeighingError(f'first_sample_index: need an integer, got '
                                f'{first_sample_index!r}')
        readings: List[Reading] = []
        dynamic: List[DynamicReading] = []
        if self._next_index is not None and first != self._next_index:
            self._flush_after_gap(readings, dynamic)
        if current.size == 0:
            return readings, dynamic
        self._next_index = first + current.size
        if self._next_dynamic is None:
            self._next_dynamic = first + (self._dyn_period - 1 - first) % self._dyn_period
        force = compensation_force_N(current, position, self._motor)
        self._pending.extend(self._filter.push(force, first))
        if self._weigher is not None:
            before = self._weigher.changes
            est = self._weigher.update_block_detailed(position, force)
            self._last_pan_N = float(est.pan_force_N[-1])
            self._history.append(first, position=position, pan=est.pan_force_N,
                                 settled=est.settled, pan_u=est.pan_force_u_N,
                                 changes=before + np.cumsum(est.change))
        else:
            zeros = np.zeros(current.size)
            self._history.append(first, position=position, pan=zeros, settled=zeros,
                                 pan_u=zeros, changes=zeros)
        last = self._next_index - 1
        while self._pending and self._pending[0].sample_index + self._lookahead <= last:
            readings.append(self._release(self._pending.popleft(), complete=True))
        if self._weigher is not None:
            while self._next_dynamic + self._dyn_lookahead <= last:
                dynamic.append(self._dynamic_at(self._next_dynamic, complete=True))
                self._next_dynamic += self._dyn_period
        # keep what pending readings, the next dynamic reading and readings still to close
        # (their window reaches back one window and one period) need
        keep_from = min([last + 1 - self._filter.window_samples - self._filter.period_samples
                         - self._settle, self._next_dynamic]
                        + [r.sample_index - r.n_samples + 1 - self._settle
                           for r in self._pending])
        self._history.trim(keep_from)
        return readings, dynamic

    def _flush_after_gap(self, readings: List[Reading], dynamic: List[DynamicReading]) -> None:
        self.gap_count += 1
        while self._pending:
            readings.append(self._release(self._pending.popleft(), complete=False))
        end = self._history.end
        if self._weigher is not None and end is not None:
            while self._next_dynamic is not None and self._next_dynamic < end:
                dynamic.append(self._dynamic_at(self._next_dynamic, complete=False))
                self._next_dynamic += self._dyn_period
            # samples are missing: the estimator restarts from rest with its last estimate
            self._weigher.reset(self._last_pan_N)
        self._history.clear()
        self._next_dynamic = None

    def _release(self, reading: Reading, complete: bool) -> Reading:
        """The final reading: steadiness over window and look-ahead, current calibration."""
        n = reading.sample_index
        start = n - reading.n_samples + 1
        cal = self._calibration
        position = self._history.get('position', start, n)
        mean_y = float(np.mean(position)) if position.size else math.nan
        if self._weigher is not None:
            # the load constant from the loop's settling time before the window until the end
            # of the look-ahead (the dynamic estimate is quicker than the loop's force)
            pan = self._history.get('pan', start - self._settle, n + self._lookahead)
            covered = pan.size == reading.n_samples + self._lookahead + self._settle
            spread_kg = (abs(cal.sensitivity_kg_per_N * self._weigher.force_ratio)
                         * float(np.ptp(pan))) if pan.size else math.inf
            steady = bool(complete and covered and reading.window_full
                          and spread_kg < self._threshold_kg)
        else:
            steady = bool(complete and reading.steady)
        s = abs(cal.sensitivity_kg_per_N)
        resolution_u = s * self._k0_N_per_A * self._current_u_A
        motion_u = (s * abs(mean_y - self._position_zero_m) / self._coil_gain_m_per_N
                    if math.isfinite(mean_y) else 0.0)
        u = math.sqrt((cal.sensitivity_kg_per_N * reading.force_u_N) ** 2
                      + float(cal.standard_uncertainty_kg(reading.mean_force_N)) ** 2
                      + resolution_u ** 2 + motion_u ** 2)
        out = replace(reading, mass_kg=float(cal.mass_kg(reading.mean_force_N)),
                      standard_uncertainty_kg=u, steady=steady,
                      stable=steady and self._calibrated, calibrated=self._calibrated,
                      resolution_u_kg=resolution_u, motion_u_kg=motion_u,
                      mean_position_m=mean_y)
        self.last_reading = out
        return out

    def _dynamic_at(self, n: int, complete: bool) -> DynamicReading:
        cal = self._calibration
        weigher = self._weigher
        pan = float(self._history.get('pan', n, n)[0])
        u_N = float(self._history.get('pan_u', n, n)[0])
        flags = self._history.get('settled', n, n + self._dyn_lookahead)
        settled = bool(complete and flags.size == self._dyn_lookahead + 1 and np.all(flags)
                       and self._calibrated)
        equivalent = float(weigher.equivalent_force_N(pan))
        u = math.sqrt(float(weigher.mass_u_kg(u_N, cal)) ** 2
                      + float(cal.standard_uncertainty_kg(equivalent)) ** 2
                      + (abs(cal.sensitivity_kg_per_N) * self._k0_N_per_A
                         * self._current_u_A) ** 2)
        return DynamicReading(sample_index=int(n), time_s=n / self._fs,
                              mass_kg=float(cal.mass_kg(equivalent)),
                              standard_uncertainty_kg=u, settled=settled,
                              calibrated=self._calibrated,
                              changes=int(self._history.get('changes', n, n)[0]))

    # -- calibration -----------------------------------------------------------------------

    def _steady_reading(self, action: str) -> Reading:
        reading = self.last_reading
        if reading is None:
            raise WeighingError(f'{action} refused: no reading yet')
        if not reading.window_full:
            raise WeighingError(f'{action} refused: the averaging window is not full yet '
                                f'({reading.averaging_time_s:.3g} s of '
                                f'{self._filter.window_samples / self._fs:g} s); wait for a '
                                'stable reading')
        if not reading.steady:
            raise WeighingError(f'{action} refused: the reading is not stable (the load moved '
                                f'by more than {self._threshold_kg:g} kg over the window or '
                                'just after it); wait for a stable reading')
        return reading

    def _needs_zero(self, action: str) -> None:
        if not self._calibrated:
            raise WeighingError(f'{action} refused: the balance is not zeroed yet (call zero '
                                'with the empty pan first)')

    def zero(self) -> Reading:
        """
        Zero on the latest reading (empty pan); clears the tare. The balance is calibrated.

        Returns
        -------
        Reading
            The reading used.

        Raises
        ------
        WeighingError
            No reading, window not full, not steady (the message says which).
        """
        reading = self._steady_reading('zero')
        self.set_calibration(self._calibration.zeroed(reading.mean_force_N, reading.force_u_N))
        self._position_zero_m = reading.mean_position_m if math.isfinite(
            reading.mean_position_m) else 0.0
        return reading

    def tare(self) -> Reading:
        """
        Tare on the latest reading (container on the zeroed pan).

        Returns
        -------
        Reading
            The reading used.

        Raises
        ------
        WeighingError
            Not zeroed, no steady reading.
        """
        self._needs_zero('tare')
        reading = self._steady_reading('tare')
        self.set_calibration(self._calibration.tared(reading.mean_force_N, reading.force_u_N))
        return reading

    def adjust(self, reference_mass_kg: float, reference_mass_u_kg: float = 0.0) -> Reading:
        """
        Adjust the sensitivity with a reference weight on the zeroed pan.

        Parameters
        ----------
        reference_mass_kg : float
            The reference mass [kg], > 0.
        reference_mass_u_kg : float
            Its standard uncertainty [kg].

        Returns
        -------
        Reading
            The reading used.

        Raises
        ------
        WeighingError
            Not zeroed, no steady reading, or the calibration refuses.
        """
        action = f'adjust with {float(reference_mass_kg)!r} kg'
        self._needs_zero(action)
        reading = self._steady_reading(action)
        try:
            new = self._calibration.adjusted(reading.mean_force_N, float(reference_mass_kg),
                                             reading.force_u_N, float(reference_mass_u_kg))
        except WeighingError as exc:
            raise WeighingError(f'{action} refused: {exc}') from None
        self.set_calibration(new)
        return reading

    def clear_tare(self) -> None:
        """Remove the tare (net = gross)."""
        self.set_calibration(replace(self._calibration, tare_kg=0.0, tare_u_kg=0.0),
                             self._calibrated)
