"""
Coherence of a fit's residual with its inputs, frequency by frequency: unmodelled dynamics.

A mode or a path the model lacks leaves, in the output error, a response to the input that
is concentrated near its frequency. In the pre-whitened residual of a right model nothing is
coherent with the input. :func:`residual_coherence` estimates the squared coherence of the
residual with each input from ``K`` non-overlapping Hann-windowed segments. For a residual
independent of the input its distribution is known whatever the input:
``P(gamma^2 >= x) = (1 - x)^(K - 1)`` (Gaussian residual; Carter, Knapp and Nuttall,
*Estimation of the magnitude-squared coherence function via overlapped FFT processing*,
1973). The smallest p-value over the tested frequencies and inputs, multiplied by their
number (Bonferroni), says whether any frequency is coherent beyond chance. The peak names
the frequency and the input. The cross-correlation test over +/-25 lags sees the same
dependence summed over all frequencies, and misses a narrow one.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Mapping, Optional, Tuple

import numpy as np

#: Fewest segments of the estimate (the null distribution's ``K``).
MIN_SEGMENTS = 32
#: Longest segment [samples]: 1024 at 10 kHz resolves 9.8 Hz.
MAX_SEGMENT = 1024


@dataclass(frozen=True)
class CoherencePeak:
    """
    The frequency where the residual is most coherent with an input.

    Attributes
    ----------
    input : str
        The input's name.
    frequency_Hz : float
        Centre of the frequency bin [Hz].
    coherence : float
        Squared coherence there (0..1).
    p_value : float
        Of the largest coherence over the tested bins and inputs (Bonferroni-corrected).
    n_bins : int
        Frequencies tested (per input).
    n_segments : int
        Segments of the estimate.
    """

    input: str
    frequency_Hz: float
    coherence: float
    p_value: float
    n_bins: int
    n_segments: int


def residual_coherence(residual: np.ndarray, inputs: Mapping[str, np.ndarray],
                       sample_rate_Hz: float, band_Hz: Tuple[float, float]
                       ) -> Optional[CoherencePeak]:
    """
    The most significant coherence of a residual with its inputs inside a band.

    Parameters
    ----------
    residual : ndarray, shape (n,)
        The residual (pre-whitened: white for a right model).
    inputs : mapping of str to ndarray
        The inputs by name, each of shape (n,) (constant ones are skipped).
    sample_rate_Hz : float
        Sample rate [Hz].
    band_Hz : (float, float)
        Frequencies tested [Hz] (bins whose centre lies inside).

    Returns
    -------
    CoherencePeak or None
        None when the record is too short for :data:`MIN_SEGMENTS` segments of 16 samples,
        no input varies or no bin lies in the band.
    """
    e = np.asarray(residual, dtype=float).ravel()
    length = MAX_SEGMENT
    while length > 16 and e.size // length < MIN_SEGMENTS:
        length //= 2
    k = e.size // length
    if k < MIN_SEGMENTS:
        return None
    freqs = np.fft.rfftfreq(length, 1.0 / sample_rate_Hz)
    keep = (freqs >= band_Hz[0]) & (freqs <= band_Hz[1]) & (freqs > 0.0)
    if not np.any(keep):
        return None
    window = np.hanning(length)

    def spectra(x: np.ndarray) -> np.ndarray:
        seg = x[:k * length].reshape(k, length)
        seg = seg - seg.mean(axis=1, keepdims=True)
        return np.fft.rfft(seg * window, axis=1)[:, keep]

    big_e = spectra(e)
    pee = np.sum(np.abs(big_e) ** 2, axis=0)
    varying = {name: np.asarray(u, dtype=float).ravel() for name, u in inputs.items()
               if np.ptp(np.asarray(u, dtype=float)) > 0.0}
    if not varying:
        return None
    tests = len(varying) * int(np.count_nonzero(keep))
    best: Optional[CoherencePeak] = None
    for name, u in varying.items():
        big_u = spectra(u)
        puu = np.sum(np.abs(big_u) ** 2, axis=0)
        with np.errstate(divide='ignore', invalid='ignore'):
            coh = np.abs(np.sum(big_e * np.conj(big_u), axis=0)) ** 2 / (pee * puu)
        coh = np.where(np.isfinite(coh), coh, 0.0)
        i = int(np.argmax(coh))
        p = min(1.0, tests * math.exp((k - 1) * math.log1p(-min(coh[i], 1.0 - 1e-16))))
        if best is None or p < best.p_value:
            best = CoherencePeak(name, float(freqs[keep][i]), float(coh[i]), p,
                                 int(np.count_nonzero(keep)), k)
    return best
