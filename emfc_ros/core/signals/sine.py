"""A single sine, phase computed from the sample index so that it stays exact for large k."""

from __future__ import annotations

import numpy as np

from emfc_ros.core.signals.base import as_index, check_finite, check_frequency, check_rate

TWO_PI = 2.0 * np.pi


class Sine:
    """
    ``amplitude_V * sin(2 pi frequency_Hz k / fs + phase_rad)``.

    Parameters
    ----------
    amplitude_V : float
        Peak amplitude.
    frequency_Hz : float
        Frequency in [0, fs/2].
    phase_rad : float
        Phase at k = 0.
    sample_rate_Hz : float
        Sample rate.
    """

    def __init__(self, amplitude_V: float, frequency_Hz: float, phase_rad: float = 0.0,
                 sample_rate_Hz: float = 10000.0) -> None:
        self.sample_rate_Hz = check_rate(sample_rate_Hz)
        self.amplitude_V = check_finite('amplitude_V', amplitude_V)
        self.frequency_Hz = check_frequency('frequency_Hz', frequency_Hz, self.sample_rate_Hz)
        self.phase_rad = check_finite('phase_rad', phase_rad)
        self._cycles_per_sample = self.frequency_Hz / self.sample_rate_Hz

    def samples(self, k: np.ndarray) -> np.ndarray:
        """
        Evaluate the sine at local sample indices.

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
        cycles = k * self._cycles_per_sample
        cycles -= np.floor(cycles)          # keep the argument small: exact for large k
        cycles *= TWO_PI
        cycles += self.phase_rad
        np.sin(cycles, out=cycles)
        cycles *= self.amplitude_V
        return cycles

    def __repr__(self) -> str:
        return (f'Sine(amplitude_V={self.amplitude_V!r}, frequency_Hz={self.frequency_Hz!r}, '
                f'phase_rad={self.phase_rad!r}, sample_rate_Hz={self.sample_rate_Hz!r})')
