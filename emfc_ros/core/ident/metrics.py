"""
Fit metrics of simulated against measured outputs, and residual correlation tests.

* ``fit_percent``: MATLAB ``compare``'s normalised root-mean-square fit
  ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)``.
* Whiteness: the normalised autocorrelation ``r_ee(tau) / r_ee(0)`` of the residuals for lags
  1..max_lag should lie inside ``+/- z / sqrt(N)`` (``z = 2.576`` for 99 %), as MATLAB
  ``resid`` plots it; the fraction of lags inside the band is reported.
* Independence from the input: the normalised cross-correlation
  ``r_eu(tau) / sqrt(r_ee(0) r_uu(0))`` for lags ``-max_lag..max_lag`` against the same band.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import special

from emfc_ros.core.ident.errors import IdentificationError


@dataclass(frozen=True)
class CorrelationTest:
    """
    Normalised correlation of residuals against a confidence band.

    Attributes
    ----------
    lags : ndarray
        Lags [samples].
    values : ndarray
        Normalised correlation at each lag.
    bound : float
        Half-width of the band ``z / sqrt(N)``.
    fraction_inside : float
        Fraction of lags with ``|value| <= bound``.
    """

    lags: np.ndarray
    values: np.ndarray
    bound: float
    fraction_inside: float


def fit_percent(measured: np.ndarray, simulated: np.ndarray) -> np.ndarray:
    """
    Normalised root-mean-square fit in percent (MATLAB ``compare``).

    Parameters
    ----------
    measured, simulated : ndarray, shape (n,) or (n, outputs)
        Measured and simulated outputs.

    Returns
    -------
    float or ndarray
        ``100 (1 - ||y - y_hat|| / ||y - mean(y)||)`` per output (a float for 1-D input);
        100 is a perfect fit, it may be negative.

    Raises
    ------
    IdentificationError
        If the shapes differ.
    """
    y = np.asarray(measured, dtype=float)
    yh = np.asarray(simulated, dtype=float)
    if y.shape != yh.shape:
        raise IdentificationError(f'measured and simulated shapes differ: {y.shape} and '
                                  f'{yh.shape}')
    num = np.linalg.norm(y - yh, axis=0)
    den = np.linalg.norm(y - y.mean(axis=0), axis=0)
    with np.errstate(divide='ignore', invalid='ignore'):
        fit = 100.0 * (1.0 - num / den)
    return float(fit) if np.ndim(fit) == 0 else fit


def correlation_at_lags(a: np.ndarray, b: np.ndarray, max_lag: int) -> np.ndarray:
    """
    Cross-correlation of two equally long real records at the lags ``-max_lag..max_lag``.

    One dot product per lag: for the 25 or 50 lags of a residual test on records of 10^5
    samples it took a tenth of the time of the full correlation by FFT it replaced (the
    report's residual figures and the fit's residual tests) and has no FFT round-off.

    Parameters
    ----------
    a, b : ndarray, shape (n,)
        The records.
    max_lag : int
        Largest absolute lag [samples], below ``n``.

    Returns
    -------
    ndarray, shape (2 max_lag + 1,)
        ``c[k + max_lag] = sum_n a[n + k] b[n]`` for ``k = -max_lag .. max_lag`` (what
        ``scipy.signal.correlate(a, b, mode='full')[n - 1 - max_lag:n + max_lag]`` gives).

    Raises
    ------
    IdentificationError
        If the lengths differ or ``max_lag`` is not below them.
    """
    a = np.asarray(a, dtype=float).ravel()
    b = np.asarray(b, dtype=float).ravel()
    n = a.size
    if b.size != n:
        raise IdentificationError(f'records of {n} and {b.size} samples: the lengths differ')
    if not 0 <= max_lag < n:
        raise IdentificationError(f'max_lag {max_lag} is not in 0..{n - 1}')
    out = np.empty(2 * max_lag + 1)
    for k in range(-max_lag, max_lag + 1):
        out[k + max_lag] = a[k:] @ b[:n - k] if k >= 0 else a[:n + k] @ b[-k:]
    return out


def _band(n: int, confidence: float) -> float:
    if not 0.0 < confidence < 1.0:
        raise IdentificationError(f'confidence must be in (0, 1), got {confidence!r}')
    return float(special.ndtri(0.5 + 0.5 * confidence)) / np.sqrt(n)


def whiteness_test(residual: np.ndarray, max_lag: int = 25,
                   confidence: float = 0.99) -> CorrelationTest:
    """
    Autocorrelation of residuals at lags 1..max_lag against the confidence band.

    Parameters
    ----------
    residual : ndarray
        Residual record (1-D).
    max_lag : int
        Largest lag [samples].
    confidence : float
        Two-sided confidence level of the band.

    Returns
    -------
    CorrelationTest
        Lags 1..max_lag, normalised autocorrelation, band and fraction inside.

    Raises
    ------
    IdentificationError
        If the record is shorter than ``max_lag + 2`` or identically zero.
    """
    e = np.asarray(residual, dtype=float).ravel()
    if e.size < max_lag + 2:
        raise IdentificationError(f'residual of {e.size} samples is too short for max_lag '
                                  f'{max_lag}')
    e = e - e.mean()
    r = correlation_at_lags(e, e, max_lag)[max_lag:]
    if r[0] <= 0.0:
        raise IdentificationError('the residual is identically zero')
    values = r[1:] / r[0]
    bound = _band(e.size, confidence)
    return CorrelationTest(np.arange(1, max_lag + 1), values, bound,
                           float(np.mean(np.abs(values) <= bound)))


def input_correlation_test(residual: np.ndarray, input: np.ndarray, max_lag: int = 25,
                           confidence: float = 0.99) -> CorrelationTest:
    """
    Cross-correlation of residuals with an input at lags -max_lag..max_lag.

    Parameters
    ----------
    residual, input : ndarray
        Equally long 1-D records.
    max_lag : int
        Largest absolute lag [samples].
    confidence : float
        Two-sided confidence level of the band.

    Returns
    -------
    CorrelationTest
        Lags, normalised cross-correlation ``r_eu(tau)`` (``e`` lagging ``u`` for positive
        tau), band and fraction inside.

    Raises
    ------
    IdentificationError
        If the lengths differ, the record is too short, or a record is constant.
    """
    e = np.asarray(residual, dtype=float).ravel()
    u = np.asarray(input, dtype=float).ravel()
    if e.size != u.size:
        raise IdentificationError(f'residual and input lengths differ: {e.size} and {u.size}')
    if e.size < max_lag + 2:
        raise IdentificationError(f'records of {e.size} samples are too short for max_lag '
                                  f'{max_lag}')
    e, u = e - e.mean(), u - u.mean()
    norm = np.sqrt(float(e @ e) * float(u @ u))
    if norm <= 0.0:
        raise IdentificationError('residual or input is constant')
    values = correlation_at_lags(e, u, max_lag) / norm
    bound = _band(e.size, confidence)
    return CorrelationTest(np.arange(-max_lag, max_lag + 1), values, bound,
                           float(np.mean(np.abs(values) <= bound)))
