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
import math
from typing import Optional, Tuple

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
    p_value : float
        Of the portmanteau statistic over all lags, chi-square distributed for a white
        residual independent of a white input: Ljung-Box ``N (N + 2) sum r_k^2 / (N - k)``
        with ``max_lag`` degrees of freedom for the whiteness test, ``r^T V^-1 r`` with
        ``2 max_lag + 1`` for the cross-correlation (:func:`input_correlation_test`: ``V``
        the lags' covariance under the null, for any input). Small: the
        residual is not white, or depends on the input.
    """

    lags: np.ndarray
    values: np.ndarray
    bound: float
    fraction_inside: float
    p_value: float = float('nan')


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
    n = e.size
    q = n * (n + 2.0) * float(np.sum(values ** 2 / (n - np.arange(1, max_lag + 1))))
    return CorrelationTest(np.arange(1, max_lag + 1), values, bound,
                           float(np.mean(np.abs(values) <= bound)),
                           float(special.chdtrc(max_lag, q)))


#: Lags of the residual's own autocorrelation in the null covariance of the cross-correlation
#: (Bartlett's formula; the tested residual is white, or nearly, at longer lags).
BARTLETT_LAGS = 3


def input_correlation_test(residual: np.ndarray, input: np.ndarray, max_lag: int = 25,
                           confidence: float = 0.99,
                           parameter_terms: Optional[Tuple[np.ndarray, np.ndarray]] = None
                           ) -> CorrelationTest:
    """
    Cross-correlation of residuals with an input at lags -max_lag..max_lag.

    The p-value is of ``S = r^T V^-1 r``, chi-square with ``2 max_lag + 1`` degrees of
    freedom when the residual is independent of the input. ``V`` is the covariance of ``r``
    under that null. It has two parts. The noise's is Bartlett's formula,
    ``V_tt' = (1 / N) sum_k rho_e(k) rho_u(k + t' - t)`` (``|k| <= BARTLETT_LAGS``). This
    makes the test right for any input, a step's plateaus as well as a chirp; with a white
    residual it is the input's own autocorrelation. The band ``z / sqrt(N)`` (and
    ``fraction_inside``) is the usual plot of it: right only for a white input. The second
    part is the estimate's, given by ``parameter_terms``. A model fitted to data carries the
    estimation error of its parameters, ``J (theta_hat - theta)``, in every residual. A
    section that sees a parameter much better than the data that fixed it then shows that
    error correlated with its input, the right model included (issue 28: a coil-step section
    correlated at every lag through c1's statistical error). This part is ``G Cov G^T``,
    ``G`` the cross-correlation of the residual's derivatives with the input.

    Parameters
    ----------
    residual, input : ndarray
        Equally long 1-D records.
    max_lag : int
        Largest absolute lag [samples].
    confidence : float
        Two-sided confidence level of the band.
    parameter_terms : (ndarray, ndarray), optional
        ``(derivatives, covariance)``: the residual's derivatives by the fitted parameters,
        shape (n, p), treated exactly as the residual was (e.g. pre-whitened), and the
        parameters' covariance (p, p).

    Returns
    -------
    CorrelationTest
        Lags, normalised cross-correlation ``r_eu(tau)`` (``e`` lagging ``u`` for positive
        tau), band, fraction inside and p-value.

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
    d = None
    if parameter_terms is not None:
        d = np.asarray(parameter_terms[0], dtype=float).reshape(e.size, -1)
        p_cov = np.asarray(parameter_terms[1], dtype=float)
        if np.all(np.isfinite(p_cov)) and np.all(np.isfinite(d)):
            d = d - d.mean(axis=0)
        else:
            d = None
    # the noise's own autocorrelation: of the residual with the estimation error's
    # directions removed (they would count twice)
    noise = e if d is None else e - d @ np.linalg.lstsq(d, e, rcond=None)[0]
    k_e = min(BARTLETT_LAGS, e.size - 2)
    rho_e = correlation_at_lags(noise, noise, k_e)[k_e:] / float(noise @ noise)
    rho_u = correlation_at_lags(u, u, 2 * max_lag + k_e)[2 * max_lag + k_e:] / float(u @ u)
    lag = np.arange(values.size)
    shift = lag[None, :] - lag[:, None]
    cov = rho_e[0] * rho_u[np.abs(shift)]
    for k in range(1, k_e + 1):
        cov = cov + rho_e[k] * (rho_u[np.abs(shift + k)] + rho_u[np.abs(shift - k)])
    cov = cov * float(noise @ noise) / float(e @ e) / e.size
    if d is not None:
        g = np.column_stack([correlation_at_lags(d[:, i], u, max_lag) / norm
                             for i in range(d.shape[1])])
        cov = cov + g @ p_cov @ g.T
    # chi-square in the directions the covariance determines (a slowly varying input makes
    # neighbouring lags nearly the same number)
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    good = vals > 1e-9 * max(float(vals.max()), 0.0)
    if not np.any(good):
        stat, dof = math.nan, values.size
    else:
        proj = vecs[:, good].T @ values
        stat, dof = float(np.sum(proj ** 2 / vals[good])), int(np.count_nonzero(good))
    return CorrelationTest(np.arange(-max_lag, max_lag + 1), values, bound,
                           float(np.mean(np.abs(values) <= bound)),
                           float(special.chdtrc(dof, stat)))
