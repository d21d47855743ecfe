"""
Covariances of least-squares estimates under coloured noise (no white-noise assumption).

* :func:`inverse`: the inverse of an information matrix, equilibrated first, with infinite
  variance for the parameters of a direction it does not determine;
* :func:`score_covariance`: the covariance of the score ``J^T r`` of time-domain residuals,
  estimated in the frequency domain (the heteroscedasticity-consistent estimator written over
  DFT lines, right for stationary noise of any colour);
* :func:`line_score_covariance`: the same for residuals that are weighted DFT lines, with
  Bartlett weights over neighbouring lines (leakage correlates them).

The sandwich ``H^-1 S H^-1`` with ``H = J^T J`` is formed by
:func:`~emfc_ros.core.ident.greybox.fit_greybox`.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

#: DFT lines over which the residual periodogram is averaged in the sandwich covariance.
SANDWICH_SMOOTHING_LINES = 3
#: Largest line lag of the score covariance of frequency-weighted residuals.
SCORE_LAG_LINES = 8


def inverse(h: np.ndarray) -> np.ndarray:
    """
    Inverse of an information matrix; directions it does not determine get infinity.

    Equilibrated first (``d H d`` with ``d = diag(H)^-1/2``) so that parameters of very
    different magnitude do not look singular.
    """
    diag = np.diag(h).copy()
    p = h.shape[0]
    out = np.full((p, p), np.inf)
    good = diag > 0.0
    if not np.any(good):
        return out
    d = 1.0 / np.sqrt(diag[good])
    hs = h[np.ix_(good, good)] * np.outer(d, d)
    w, v = np.linalg.eigh(hs)
    ok = w > max(w[-1], 0.0) * 1e-12
    inv = (v[:, ok] / w[ok]) @ v[:, ok].T * np.outer(d, d)
    # An undetermined direction: infinite variance for every parameter it involves.
    bad_dir = np.any(np.abs(v[:, ~ok]) > 1e-6, axis=1) if np.any(~ok) else np.zeros(d.size,
                                                                                    bool)
    inv[bad_dir, :] = np.inf
    inv[:, bad_dir] = np.inf
    out[np.ix_(good, good)] = inv
    return out


def line_score_covariance(jac: np.ndarray, residuals: np.ndarray, lengths: Sequence[int],
                          max_lag_lines: int = SCORE_LAG_LINES) -> np.ndarray:
    """
    Covariance of the score ``J^T r`` for frequency-domain residuals.

    Per section the residuals are the real then the imaginary parts of ``L`` DFT lines; line
    ``k`` adds ``s_k = J_re,k r_re,k + J_im,k r_im,k`` to the score. Lines of a finite record
    are not quite independent (the leakage of a noise transient that does not die out within
    the section correlates neighbouring lines, most at a sharp resonance of the noise), so
    ``S = sum_|l|<=Lmax (1 - |l| / (Lmax + 1)) sum_k s_k s_{k+l}^T`` (Bartlett weights over the
    line lag, a HAC estimator along frequency).

    Parameters
    ----------
    jac : ndarray, shape (m, p)
        Jacobian of the residuals.
    residuals : ndarray, shape (m,)
        Per section the real then the imaginary parts of its lines.
    lengths : sequence of int
        Residuals per section (twice its lines).
    max_lag_lines : int
        Largest line lag ``Lmax``.

    Returns
    -------
    ndarray, shape (p, p)
        The score covariance.
    """
    p = jac.shape[1]
    out = np.zeros((p, p))
    first = 0
    for n in lengths:
        half = n // 2
        re = slice(first, first + half)
        im = slice(first + half, first + n)
        first += n
        score = jac[re] * residuals[re, None] + jac[im] * residuals[im, None]
        out += score.T @ score
        for lag in range(1, min(int(max_lag_lines), half - 1) + 1):
            c = score[:-lag].T @ score[lag:]
            out += (1.0 - lag / (max_lag_lines + 1.0)) * (c + c.T)
    return out


def score_covariance(jac: np.ndarray, residuals: np.ndarray, lengths: Sequence[int],
                     smoothing_lines: int = SANDWICH_SMOOTHING_LINES) -> np.ndarray:
    """
    Covariance of the score ``J^T r`` for noise of any colour (frequency-domain HAC).

    Parameters
    ----------
    jac : ndarray, shape (m, p)
        Jacobian of the residuals.
    residuals : ndarray, shape (m,)
        The residuals, sections one after the other.
    lengths : sequence of int
        Residuals per section (they sum to ``m``); sections count as independent.
    smoothing_lines : int
        Lines over which the residual periodogram is averaged (odd).

    Returns
    -------
    ndarray, shape (p, p)
        ``S`` of the module docstring.
    """
    p = jac.shape[1]
    out = np.zeros((p, p))
    first = 0
    half = max(int(smoothing_lines) // 2, 0)
    for n in lengths:
        rs = residuals[first:first + n]
        js = jac[first:first + n]
        first += n
        if n < 2:
            continue
        rk = np.fft.rfft(rs)
        jk = np.fft.rfft(js, axis=0)
        power = np.abs(rk) ** 2
        if half:
            c = np.concatenate(([0.0], np.cumsum(power)))
            idx = np.arange(power.size)
            lo = np.maximum(idx - half, 0)
            hi = np.minimum(idx + half + 1, power.size)
            power = (c[hi] - c[lo]) / (hi - lo)
        w = np.full(power.size, 2.0)
        w[0] = 1.0
        if n % 2 == 0:
            w[-1] = 1.0
        weighted = jk * np.sqrt(w * power)[:, None]
        out += np.real(weighted.conj().T @ weighted) / float(n) ** 2
    return out
