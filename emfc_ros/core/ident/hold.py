"""
The DAC hold between sampled force and sampled position, as a frequency response.

Its own module so that both the pipeline and the balance's frequency-domain stage
(:mod:`~emfc_ros.core.ident.balance_frf`) import it without importing each other.
"""

from __future__ import annotations

import numpy as np


def hold_factor(frequency_Hz: np.ndarray, sample_rate_Hz: float, hold: str) -> np.ndarray:
    """
    Frequency response of the DAC hold seen between sampled force and sampled position.

    Parameters
    ----------
    frequency_Hz : ndarray
        Frequencies [Hz].
    sample_rate_Hz : float
        Sample rate [Hz].
    hold : {'zoh', 'foh', 'none'}
        Zero-order hold (half-sample delay and sinc), first-order hold with one sample of
        delay (one sample delay and sinc squared) or none (1).

    Returns
    -------
    ndarray
        Complex factor; divide a measured response by it to compare with the continuous model.
    """
    x = np.asarray(frequency_Hz, dtype=float) / float(sample_rate_Hz)
    if hold == 'zoh':
        return np.exp(-1j * np.pi * x) * np.sinc(x)
    if hold == 'foh':
        return np.exp(-2j * np.pi * x) * np.sinc(x) ** 2
    return np.ones_like(x, dtype=complex)
