"""
Periodic multisines on chosen harmonic lines of ``fs / period_samples``.

One period is synthesised with an inverse real FFT, so the spectrum over any integer number of
periods holds energy only on the chosen lines; samples are read from it at ``k mod period``.
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from emfc_ros.core.errors import SignalError
from emfc_ros.core.signals.base import as_index, check_finite, check_rate

PHASES = ('schroeder', 'random')


def select_lines(period_samples: int, sample_rate_Hz: float, *,
                 f_min_Hz: Optional[float] = None, f_max_Hz: Optional[float] = None,
                 odd_only: bool = False) -> np.ndarray:
    """
    Harmonic numbers whose frequencies ``l fs / period`` lie in [f_min_Hz, f_max_Hz].

    Parameters
    ----------
    period_samples : int
        Period length in samples.
    sample_rate_Hz : float
        Sample rate.
    f_min_Hz, f_max_Hz : float, optional
        Frequency band (default: the first harmonic up to below Nyquist).
    odd_only : bool
        Keep odd harmonics only (even ones then reveal even-order nonlinearity).

    Returns
    -------
    numpy.ndarray
        int64 harmonic numbers, ascending, in [1, period_samples / 2).

    Raises
    ------
    SignalError
        If the band holds no line.
    """
    resolution_Hz = sample_rate_Hz / period_samples
    lines = np.arange(1, (period_samples + 1) // 2, dtype=np.int64)
    freqs_Hz = lines * resolution_Hz
    keep = np.ones(lines.shape, dtype=bool)
    tol_Hz = 1e-9 * resolution_Hz
    if f_min_Hz is not None:
        keep &= freqs_Hz >= f_min_Hz - tol_Hz
    if f_max_Hz is not None:
        keep &= freqs_Hz <= f_max_Hz + tol_Hz
    if odd_only:
        keep &= (lines % 2) == 1
    lines = lines[keep]
    if lines.size == 0:
        raise SignalError(f'no harmonic of {resolution_Hz!r} Hz (fs / period_samples) lies in '
                          f'[{f_min_Hz!r}, {f_max_Hz!r}] Hz below Nyquist'
                          + (' with odd_only' if odd_only else ''))
    return lines


class Multisine:
    """
    A sum of equal-amplitude cosines on harmonic lines, scaled to an rms value.

    Parameters
    ----------
    rms_V : float
        Rms value of the signal (> 0).
    period_samples : int
        Period in samples (>= 3); the line spacing is ``fs / period_samples``.
    sample_rate_Hz : float
        Sample rate.
    lines : sequence of int, optional
        Harmonic numbers in [1, period_samples / 2); exclusive with the band.
    f_min_Hz, f_max_Hz : float, optional
        Band from which to take all lines when ``lines`` is not given.
    odd_only : bool
        With a band: odd harmonics only.
    phases : {'schroeder', 'random'}
        Schroeder phases ``-pi i (i - 1) / L`` (low crest factor) or uniform random phases.
    seed : int
        Seed of the random phases.
    """

    def __init__(self, rms_V: float, period_samples: int, sample_rate_Hz: float = 10000.0,
                 lines: Optional[Sequence[int]] = None, f_min_Hz: Optional[float] = None,
                 f_max_Hz: Optional[float] = None, odd_only: bool = False,
                 phases: str = 'schroeder', seed: int = 0) -> None:
        self.sample_rate_Hz = check_rate(sample_rate_Hz)
        self.rms_V = check_finite('rms_V', rms_V)
        if self.rms_V <= 0.0:
            raise SignalError(f'rms_V must be > 0, got {rms_V!r}')
        if isinstance(period_samples, bool) or int(period_samples) != period_samples or \
                period_samples < 3:
            raise SignalError(f'period_samples must be an integer >= 3, got {period_samples!r}')
        self.period_samples = int(period_samples)
        if phases not in PHASES:
            raise SignalError(f'phases must be one of {list(PHASES)}, got {phases!r}')
        self.phases = phases
        self.seed = int(seed)
        if lines is not None:
            if f_min_Hz is not None or f_max_Hz is not None or odd_only:
                raise SignalError('give either lines or f_min_Hz/f_max_Hz/odd_only, not both')
            arr = np.asarray(lines)
            if arr.ndim != 1 or arr.size == 0 or arr.dtype.kind not in 'iu':
                raise SignalError(f'lines must be a non-empty list of integers, got {lines!r}')
            top = (self.period_samples + 1) // 2 - 1
            if arr.min() < 1 or arr.max() > top:
                raise SignalError(f'lines must lie in [1, {top}] (below Nyquist), got {lines!r}')
            if np.unique(arr).size != arr.size:
                raise SignalError(f'lines must not repeat, got {lines!r}')
            self.lines = np.sort(arr.astype(np.int64))
        else:
            self.lines = select_lines(self.period_samples, self.sample_rate_Hz,
                                      f_min_Hz=f_min_Hz, f_max_Hz=f_max_Hz, odd_only=odd_only)
        count = self.lines.size
        if phases == 'schroeder':
            i = np.arange(1, count + 1, dtype=np.float64)
            self.phases_rad = -np.pi * i * (i - 1.0) / count
        else:
            rng = np.random.default_rng(np.random.SeedSequence(self.seed))
            self.phases_rad = rng.uniform(0.0, 2.0 * np.pi, count)
        spectrum = np.zeros(self.period_samples // 2 + 1, dtype=np.complex128)
        spectrum[self.lines] = np.exp(1j * self.phases_rad)
        period = np.fft.irfft(spectrum, n=self.period_samples)
        period *= self.rms_V / np.sqrt(np.mean(period ** 2))
        period.flags.writeable = False
        self.period = period

    @property
    def frequencies_Hz(self) -> np.ndarray:
        """Frequencies of the lines in Hz."""
        return self.lines * (self.sample_rate_Hz / self.period_samples)

    @property
    def crest_factor(self) -> float:
        """Peak over rms of one sampled period."""
        return float(np.max(np.abs(self.period)) / np.sqrt(np.mean(self.period ** 2)))

    def samples(self, k: np.ndarray) -> np.ndarray:
        """
        Evaluate the multisine at local sample indices.

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
        return self.period[k % self.period_samples]

    def __repr__(self) -> str:
        return (f'Multisine(rms_V={self.rms_V!r}, period_samples={self.period_samples!r}, '
                f'lines={self.lines.size} lines, phases={self.phases!r})')
