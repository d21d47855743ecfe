"""
A smooth model of the output-noise spectrum for the frequency-weighted grey-box fit.

The weights of a maximum-likelihood fit must not depend on the noise of the line they weigh:
``1 / |E_k|^2`` from a lightly smoothed periodogram would favour the lines whose noise happens
to be small and bias the estimate and its covariance (seen on the simulated balance: the
low-mode damping 0.3 % off at 22 of its reported standard uncertainties). So the spectrum is a
model with few parameters fitted to many lines:

``Phi(f) = (sum_j a_j B_j(f)) * c(f)``

* ``B_j`` are the shapes the physics gives: ``|H_coil(f)|^2`` (amplifier current noise acting
  as a force at the coil), ``|H_pan(f)|^2`` (load-changer current noise, floor vibration on
  the pan) and ``1`` (sensor and ADC noise, white); ``a_j >= 0`` by non-negative least
  squares, iterated with relative weights;
* ``c(f)`` corrects what the shapes miss: the ratio of the periodogram to the fitted model,
  averaged over a wide relative band (``+/- CORRECTION_BANDWIDTH``, at least
  ``CORRECTION_MIN_LINES`` lines), so that it has many degrees of freedom per value.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy import optimize

#: Half width of the correction's average, relative to the frequency.
CORRECTION_BANDWIDTH = 0.25
#: Smallest half width of the correction's average [lines].
CORRECTION_MIN_LINES = 25


def _band_average(x: np.ndarray, relative: float, min_lines: int) -> np.ndarray:
    k = np.arange(x.size)
    half = np.maximum(int(min_lines), np.round(relative * k)).astype(int)
    c = np.concatenate(([0.0], np.cumsum(x)))
    lo = np.maximum(k - half, 0)
    hi = np.minimum(k + half + 1, x.size)
    return (c[hi] - c[lo]) / (hi - lo)


def noise_spectrum(residual: np.ndarray, shapes: Sequence[np.ndarray],
                   iterations: int = 3) -> np.ndarray:
    """
    Smooth noise spectrum of one section's output error.

    Parameters
    ----------
    residual : ndarray, shape (n,)
        Output error (measured minus simulated) at a good start.
    shapes : sequence of ndarray, shape (n // 2 + 1,)
        Spectral shapes ``B_j`` on the ``rfft`` lines (a constant is always added).
    iterations : int
        Reweighted non-negative least-squares passes.

    Returns
    -------
    ndarray, shape (n // 2 + 1,)
        ``Phi`` on the ``rfft`` lines, in the units of ``|rfft(e)|^2 / n``, positive.
    """
    e = np.asarray(residual, dtype=float)
    power = np.abs(np.fft.rfft(e)) ** 2 / max(e.size, 1)
    basis = np.column_stack([np.asarray(s, dtype=float) for s in shapes]
                            + [np.ones(power.size)])
    basis = basis / np.maximum(basis.max(axis=0), np.finfo(float).tiny)
    start = _band_average(power, CORRECTION_BANDWIDTH, CORRECTION_MIN_LINES)
    model = np.maximum(start, np.finfo(float).tiny)
    for _ in range(max(int(iterations), 1)):
        w = 1.0 / model
        # the same non-negative least squares on the QR-reduced problem (||A x - b|| and
        # ||R x - Q^T b|| differ by a constant): 3 rows instead of one per line, 50 times
        # faster on a 10 s section
        q, r = np.linalg.qr(basis * w[:, None])
        coef, _ = optimize.nnls(r, q.T @ (power * w))
        fitted = basis @ coef
        if not np.any(fitted > 0.0):
            break
        model = np.maximum(fitted, fitted.max() * 1e-12)
    ratio = _band_average(power / model, CORRECTION_BANDWIDTH, CORRECTION_MIN_LINES)
    spectrum = model * ratio
    floor = max(float(np.median(spectrum)) * 1e-9, np.finfo(float).tiny)
    return np.maximum(spectrum, floor)


def whitening_weights(residual: np.ndarray, shapes: Sequence[np.ndarray]) -> np.ndarray:
    """
    Frequency weights ``1 / sqrt(Phi)`` for :func:`~emfc_ros.core.ident.greybox.fit_greybox`.

    Parameters
    ----------
    residual : ndarray, shape (n,)
        Output error at the start.
    shapes : sequence of ndarray
        Spectral shapes (see :func:`noise_spectrum`).

    Returns
    -------
    ndarray, shape (n // 2 + 1,)
        The weights.
    """
    return 1.0 / np.sqrt(noise_spectrum(residual, shapes))
