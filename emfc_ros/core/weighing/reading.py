"""
Static weighing readings: moving average of the compensation force, uncertainty, stability.

:class:`ReadingFilter` is fed blocks of compensation force [N] with their first sample index
and emits a :class:`Reading` at every reading period, aligned to absolute sample indices (a
reading closes at sample ``n`` when ``(n + 1) % period_samples == 0``), so any split of the
stream into blocks gives the same readings bit for bit.

* Reading: the mean force over the last ``averaging_time_s`` (fewer samples while the window
  fills after a start or a gap), converted to mass by a
  :class:`~emfc_ros.core.weighing.calibration.WeighingCalibration`.
* Uncertainty: the window is split into ``n_sub_blocks`` equal sub-blocks (``K``, default 10);
  the standard error of the mean is ``u_F = std(sub-block means, ddof=1) / sqrt(K)``, which
  equals ``sigma / sqrt(N)`` for white noise and stays honest for noise correlated over less
  than a sub-block (0.1 s by default). ``u_mass = sqrt((S u_F)^2 + u_cal^2)``.
* Stability: a reading is stable when its window is full and the readings of the last
  ``stability_time_s`` (default 0.5 s, that is 6 readings at 0.1 s) all had full windows and
  their spread (max - min) is below ``stability_threshold_kg`` (default 1 mg: 10 ppm of a
  100 g load, above the microgram noise of a 1 s average of the simulated balance and far
  below the transient of a load change).
* Gaps: a block whose first index is not the expected next index (lost or repeated blocks)
  resets the window and the stability history; ``gap_count`` and ``samples_lost`` say so.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
import math
from typing import List, Tuple

import numpy as np

from emfc_ros.core.weighing.calibration import WeighingCalibration
from emfc_ros.core.weighing.errors import WeighingError

#: Default stability threshold [kg] (spread of the readings over the stability window).
DEFAULT_STABILITY_THRESHOLD_KG = 1.0e-6


@dataclass(frozen=True)
class Reading:
    """
    One weighing result.

    Attributes
    ----------
    sample_index : int
        Index of the last sample of the averaging window.
    time_s : float
        ``sample_index / sample_rate`` [s].
    mass_kg : float
        Net mass [kg].
    standard_uncertainty_kg : float
        Combined standard uncertainty [kg] (statistical and calibration).
    stable : bool
        Whether the reading is stable (see the module docstring).
    averaging_time_s : float
        Length of the averaging window actually used [s] (``n_samples / sample_rate``).
    n_samples : int
        Samples averaged.
    mean_force_N : float
        Mean compensation force over the window [N] (feed it to ``zeroed``, ``tared``,
        ``adjusted``).
    force_u_N : float
        Statistical standard uncertainty of ``mean_force_N`` [N].
    window_full : bool
        Whether the window held ``averaging_time_s`` of samples.
    gap_count : int
        Gaps detected in the stream so far (each reset the window).
    steady : bool
        Whether the load was constant within the stability threshold over the window (what
        zero, tare and adjust need; :class:`ReadingFilter`: the same as its ``stable``).
    calibrated : bool
        Whether the balance had been zeroed (or given a calibration) when the reading was
        made; an uncalibrated reading is never ``stable``
        (:class:`~emfc_ros.core.weighing.pipeline.WeighingPipeline`).
    resolution_u_kg : float
        The current channel's quantisation share of the uncertainty [kg] (included in
        ``standard_uncertainty_kg``).
    motion_u_kg : float
        The lever's residual displacement share of the uncertainty [kg] (included).
    mean_position_m : float
        Mean lever-end position over the window [m] (nan when not known).
    """

    sample_index: int
    time_s: float
    mass_kg: float
    standard_uncertainty_kg: float
    stable: bool
    averaging_time_s: float
    n_samples: int
    mean_force_N: float
    force_u_N: float
    window_full: bool
    gap_count: int = 0
    steady: bool = False
    calibrated: bool = True
    resolution_u_kg: float = 0.0
    motion_u_kg: float = 0.0
    mean_position_m: float = math.nan


def _positive(name: str, value: float) -> float:
    out = float(value)
    if not (math.isfinite(out) and out > 0.0):
        raise WeighingError(f'{name}: must be finite and > 0, got {value!r}')
    return out


def _samples(name: str, duration_s: float, sample_rate_Hz: float, minimum: int = 1) -> int:
    n = int(round(_positive(name, duration_s) * sample_rate_Hz))
    if n < minimum:
        raise WeighingError(f'{name}: {duration_s!r} s is fewer than {minimum} samples at '
                            f'{sample_rate_Hz!r} Hz')
    return n


def _forces(force_N) -> np.ndarray:
    f = np.asarray(force_N, dtype=float)
    if f.ndim != 1:
        raise WeighingError(f'force_N: need a 1-D array, got shape {f.shape}')
    if not np.all(np.isfinite(f)):
        raise WeighingError('force_N: contains non-finite samples')
    return f


def window_statistics(force_N: np.ndarray, n_sub_blocks: int) -> Tuple[float, float]:
    """
    Mean and standard error of the mean from sub-block means.

    Parameters
    ----------
    force_N : ndarray
        The window [N], at least ``2 * n_sub_blocks`` samples.
    n_sub_blocks : int
        ``K``; the last ``(n // K) K`` samples are split into ``K`` sub-blocks.

    Returns
    -------
    (float, float)
        Mean over all samples [N] and ``std(sub-block means, ddof=1) / sqrt(K)`` [N].
    """
    n = force_N.size
    k = int(n_sub_blocks)
    m = n // k
    means = force_N[n - m * k:].reshape(k, m).mean(axis=1)
    return float(np.mean(force_N)), float(np.std(means, ddof=1) / math.sqrt(k))


class ReadingFilter:
    """
    Streaming moving-average weighing filter (see the module docstring).

    Parameters
    ----------
    sample_rate_Hz : float
        Sample rate of the force stream [Hz].
    calibration : WeighingCalibration
        Force to mass; replace it with :attr:`calibration` at any time (history is kept in
        force, so stability is unaffected).
    averaging_time_s : float
        Moving-average window [s] (default 1 s).
    reading_period_s : float
        Interval between readings [s] (default 0.1 s), rounded to whole samples.
    stability_time_s : float
        Window of readings for the stability test [s] (default 0.5 s), >= 0.
    stability_threshold_kg : float
        Largest spread (max - min) of the readings in that window for a stable reading [kg].
    n_sub_blocks : int
        Sub-blocks of the window for the uncertainty, >= 2 (default 10).
    """

    def __init__(self, sample_rate_Hz: float, calibration: WeighingCalibration,
                 averaging_time_s: float = 1.0, reading_period_s: float = 0.1,
                 stability_time_s: float = 0.5,
                 stability_threshold_kg: float = DEFAULT_STABILITY_THRESHOLD_KG,
                 n_sub_blocks: int = 10) -> None:
        self._fs = _positive('sample_rate_Hz', sample_rate_Hz)
        self.calibration = calibration
        self._k = int(n_sub_blocks)
        if self._k < 2 or self._k != n_sub_blocks:
            raise WeighingError(f'n_sub_blocks: need an integer >= 2, got {n_sub_blocks!r}')
        self._n = _samples('averaging_time_s', averaging_time_s, self._fs, 2 * self._k)
        self._period = _samples('reading_period_s', reading_period_s, self._fs)
        stab = float(stability_time_s)
        if not (math.isfinite(stab) and stab >= 0.0):
            raise WeighingError(f'stability_time_s: must be finite and >= 0, got '
                                f'{stability_time_s!r}')
        self._n_stable = int(round(stab * self._fs)) // self._period + 1
        self._threshold_kg = _positive('stability_threshold_kg', stability_threshold_kg)
        self._buf = np.zeros(self._n)
        self._write = 0
        self._count = 0
        self._history: deque = deque(maxlen=self._n_stable)
        self._next_index = None
        self.gap_count = 0
        self.samples_lost = 0

    @property
    def calibration(self) -> WeighingCalibration:
        """The calibration applied to new readings."""
        return self._calibration

    @calibration.setter
    def calibration(self, value: WeighingCalibration) -> None:
        if not isinstance(value, WeighingCalibration):
            raise WeighingError(f'calibration: need a WeighingCalibration, got {value!r}')
        self._calibration = value

    @property
    def sample_rate_Hz(self) -> float:
        """Sample rate [Hz]."""
        return self._fs

    @property
    def window_samples(self) -> int:
        """Samples in a full averaging window."""
        return self._n

    @property
    def period_samples(self) -> int:
        """Samples between readings."""
        return self._period

    @property
    def stability_readings(self) -> int:
        """Readings compared by the stability test (the current one included)."""
        return self._n_stable

    @property
    def next_sample_index(self):
        """The index the next block must start with (None before the first block)."""
        return self._next_index

    def reset(self) -> None:
        """Empty the window and the stability history (gap counters are kept)."""
        self._write = 0
        self._count = 0
        self._history.clear()

    def push(self, force_N, first_sample_index: int) -> List[Reading]:
        """
        Add a block of compensation force and return the readings it completes.

        Parameters
        ----------
        force_N : array_like, shape (n,)
            Compensation force [N], one value per sample.
        first_sample_index : int
            Absolute index of the first sample; a discontinuity resets the window.

        Returns
        -------
        list of Reading
            Readings closed inside this block, in order (none while the window holds fewer
            than ``2 * n_sub_blocks`` samples).

        Raises
        ------
        WeighingError
            If the block is not 1-D, holds non-finite values, or the index is not an integer.
        """
        f = _forces(force_N)
        first = int(first_sample_index)
        if first != first_sample_index:
            raise WeighingError(f'first_sample_index: need an integer, got '
                                f'{first_sample_index!r}')
        if self._next_index is not None and first != self._next_index:
            self.gap_count += 1
            self.samples_lost += max(0, first - self._next_index)
            self.reset()
        self._next_index = first + f.size
        readings = []
        pos = 0
        while pos < f.size:
            index = first + pos
            close = index + (self._period - 1 - index) % self._period
            stop = min(close - first + 1, f.size)
            self._append(f[pos:stop])
            pos = stop
            if stop == close - first + 1:
                reading = self._reading(close)
                if reading is not None:
                    readings.append(reading)
        return readings

    def _append(self, chunk: np.ndarray) -> None:
        if chunk.size >= self._n:
            self._buf[:] = chunk[-self._n:]
            self._write = 0
        else:
            end = self._write + chunk.size
            if end <= self._n:
                self._buf[self._write:end] = chunk
            else:
                split = self._n - self._write
                self._buf[self._write:] = chunk[:split]
                self._buf[:end - self._n] = chunk[split:]
            self._write = end % self._n
        self._count = min(self._count + chunk.size, self._n)

    def _window(self) -> np.ndarray:
        if self._count < self._n:
            start = (self._write - self._count) % self._n
            if start + self._count <= self._n:
                return self._buf[start:start + self._count].copy()
            return np.concatenate((self._buf[start:], self._buf[:self._write]))
        return np.concatenate((self._buf[self._write:], self._buf[:self._write]))

    def _reading(self, sample_index: int):
        if self._count < 2 * self._k:
            return None
        window = self._window()
        mean, u_force = window_statistics(window, self._k)
        full = window.size == self._n
        self._history.append((mean, full))
        cal = self._calibration
        stable = False
        if len(self._history) == self._n_stable and all(h[1] for h in self._history):
            forces = [h[0] for h in self._history]
            spread_kg = abs(cal.sensitivity_kg_per_N) * (max(forces) - min(forces))
            stable = spread_kg < self._threshold_kg
        u_mass = math.hypot(cal.sensitivity_kg_per_N * u_force,
                            float(cal.standard_uncertainty_kg(mean)))
        return Reading(sample_index=int(sample_index), time_s=sample_index / self._fs,
                       mass_kg=float(cal.mass_kg(mean)), standard_uncertainty_kg=u_mass,
                       stable=bool(stable), averaging_time_s=window.size / self._fs,
                       n_samples=int(window.size), mean_force_N=mean, force_u_N=u_force,
                       window_full=bool(full), gap_count=self.gap_count,
                       steady=bool(stable))


def settled_reading(force_N, sample_rate_Hz: float, calibration: WeighingCalibration,
                    averaging_time_s: float = 1.0, n_sub_blocks: int = 10,
                    stability_threshold_kg: float = DEFAULT_STABILITY_THRESHOLD_KG
                    ) -> Reading:
    """
    One reading from the last ``averaging_time_s`` of a recorded force signal.

    Parameters
    ----------
    force_N : array_like, shape (n,)
        Compensation force [N]; sample ``i`` is at ``i / sample_rate_Hz``.
    sample_rate_Hz : float
        Sample rate [Hz].
    calibration : WeighingCalibration
        Force to mass.
    averaging_time_s : float
        Length of the averaged tail [s] (default 1 s).
    n_sub_blocks : int
        Sub-blocks for the uncertainty, >= 2.
    stability_threshold_kg : float
        The reading is stable when the means of the two halves of the window differ by less
        than this [kg] (no drift left).

    Returns
    -------
    Reading
        With ``sample_index`` the last index of ``force_N`` and ``window_full`` True.

    Raises
    ------
    WeighingError
        If the signal is shorter than the averaging time, or an argument is invalid.
    """
    f = _forces(force_N)
    fs = _positive('sample_rate_Hz', sample_rate_Hz)
    k = int(n_sub_blocks)
    if k < 2 or k != n_sub_blocks:
        raise WeighingError(f'n_sub_blocks: need an integer >= 2, got {n_sub_blocks!r}')
    n = _samples('averaging_time_s', averaging_time_s, fs, 2 * k)
    if f.size < n:
        raise WeighingError(f'force_N: {f.size} samples, fewer than the {n} of '
                            f'averaging_time_s = {averaging_time_s!r} s')
    threshold = _positive('stability_threshold_kg', stability_threshold_kg)
    window = f[-n:]
    mean, u_force = window_statistics(window, k)
    half = n // 2
    drift_kg = abs(calibration.sensitivity_kg_per_N
                   * (np.mean(window[n - half:]) - np.mean(window[:half])))
    u_mass = math.hypot(calibration.sensitivity_kg_per_N * u_force,
                        float(calibration.standard_uncertainty_kg(mean)))
    last = f.size - 1
    return Reading(sample_index=last, time_s=last / fs, mass_kg=float(calibration.mass_kg(mean)),
                   standard_uncertainty_kg=u_mass, stable=bool(drift_kg < threshold),
                   averaging_time_s=n / fs, n_samples=n, mean_force_N=mean, force_u_N=u_force,
                   window_full=True, gap_count=0, steady=bool(drift_kg < threshold))
