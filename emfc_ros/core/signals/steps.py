"""Piecewise-constant signals: constants, steps and staircases."""

from __future__ import annotations

from typing import Sequence, Union

import numpy as np

from emfc_ros.core.errors import SignalError
from emfc_ros.core.signals.base import as_index, check_finite, check_rate


class Constant:
    """
    A constant voltage.

    Parameters
    ----------
    value_V : float
        The value.
    sample_rate_Hz : float
        Sample rate.
    """

    def __init__(self, value_V: float, sample_rate_Hz: float = 10000.0) -> None:
        self.sample_rate_Hz = check_rate(sample_rate_Hz)
        self.value_V = check_finite('value_V', value_V)

    def samples(self, k: np.ndarray) -> np.ndarray:
        """
        Evaluate at local sample indices.

        Parameters
        ----------
        k : numpy.ndarray
            int64 sample indices >= 0.

        Returns
        -------
        numpy.ndarray
            float64 samples, same shape as ``k``.
        """
        k = as_index(k)
        return np.full(k.shape, self.value_V)

    def __repr__(self) -> str:
        return f'Constant(value_V={self.value_V!r})'


class Steps:
    """
    Piecewise-constant levels switched at given times.

    Level ``i`` holds from sample ``round(times_s[i] * fs)`` until the next switch; before
    the first time the output is 0 V.

    Parameters
    ----------
    times_s : sequence of float
        Switching times, >= 0, strictly increasing (after rounding to samples).
    levels_V : sequence of float
        One level per time.
    sample_rate_Hz : float
        Sample rate.
    """

    def __init__(self, times_s: Union[Sequence[float], np.ndarray],
                 levels_V: Union[Sequence[float], np.ndarray],
                 sample_rate_Hz: float = 10000.0) -> None:
        self.sample_rate_Hz = check_rate(sample_rate_Hz)
        times = np.asarray(times_s, dtype=np.float64)
        levels = np.asarray(levels_V, dtype=np.float64)
        if times.ndim != 1 or times.size == 0 or times.shape != levels.shape:
            raise SignalError(f'times_s and levels_V must be non-empty lists of equal length, '
                              f'got {times.size} times and {levels.size} levels')
        if not (np.isfinite(times).all() and np.isfinite(levels).all()):
            raise SignalError('times_s and levels_V must be finite')
        if times[0] < 0.0:
            raise SignalError(f'times_s must be >= 0, got {times[0]!r}')
        starts = np.round(times * self.sample_rate_Hz).astype(np.int64)
        if np.any(np.diff(starts) <= 0):
            raise SignalError('times_s must be strictly increasing by at least one sample')
        self.times_s = times
        self.levels_V = levels
        self.start_samples = starts
        self._table = np.concatenate(([0.0], levels))

    def samples(self, k: np.ndarray) -> np.ndarray:
        """
        Evaluate at local sample indices.

        Parameters
        ----------
        k : numpy.ndarray
            int64 sample indices >= 0.

        Returns
        -------
        numpy.ndarray
            float64 samples, same shape as ``k``.
        """
        k = as_index(k)
        return self._table[np.searchsorted(self.start_samples, k, side='right')]

    def __repr__(self) -> str:
        return f'Steps(times_s={self.times_s.tolist()!r}, levels_V={self.levels_V.tolist()!r})'


def staircase(start_V: float, step_V: float, count: int, dwell_s: float,
              sample_rate_Hz: float = 10000.0, *, start_time_s: float = 0.0,
              up_and_down: bool = False) -> Steps:
    """
    Build a staircase of ``count`` levels ``start_V + i step_V``, each held for ``dwell_s``.

    Useful for static characteristics; ``up_and_down`` appends the same levels descending
    (without repeating the top) to expose hysteresis.

    Parameters
    ----------
    start_V : float
        First level.
    step_V : float
        Increment between levels (may be negative).
    count : int
        Number of levels, >= 1.
    dwell_s : float
        Time per level, > 0.
    sample_rate_Hz : float
        Sample rate.
    start_time_s : float
        Time of the first level (0 V before it).
    up_and_down : bool
        Return along the same levels.

    Returns
    -------
    Steps
        The staircase.
    """
    if isinstance(count, bool) or int(count) != count or count < 1:
        raise SignalError(f'count must be an integer >= 1, got {count!r}')
    dwell_s = check_finite('dwell_s', dwell_s)
    if dwell_s <= 0.0:
        raise SignalError(f'dwell_s must be > 0, got {dwell_s!r}')
    start_V = check_finite('start_V', start_V)
    step_V = check_finite('step_V', step_V)
    index = np.arange(int(count), dtype=np.float64)
    if up_and_down and count > 1:
        index = np.concatenate((index, index[-2::-1]))
    levels = start_V + index * step_V
    times = check_finite('start_time_s', start_time_s) + np.arange(index.size) * dwell_s
    return Steps(times, levels, sample_rate_Hz)
