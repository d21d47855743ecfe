"""
Accurate steady-state Kalman covariance for badly scaled models.

The balance's states span many decades (angles of micro-radians, a pan force of newtons), and
:func:`scipy.linalg.solve_discrete_are` alone then returns a covariance whose Riccati residual
can be 1e-3 or worse, with a gain off by 20 %. :func:`filter_riccati` therefore solves in
diagonally scaled coordinates (scale from a first solution), and polishes with Hewer's
Newton iteration (:func:`scipy.linalg.solve_discrete_lyapunov` for the error dynamics of the
current gain), which converges quadratically to the stabilising solution.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy import linalg

#: Largest accepted relative residual of the Riccati equation.
MAX_RESIDUAL = 1.0e-9


def riccati_step(phi: np.ndarray, c: np.ndarray, q: np.ndarray, r: float,
                 p: np.ndarray) -> np.ndarray:
    """
    One step of the a-priori covariance recursion of a Kalman filter with scalar output.

    Parameters
    ----------
    phi : ndarray, shape (n, n)
        Transition matrix.
    c : ndarray, shape (n,)
        Output row.
    q : ndarray, shape (n, n)
        Process noise covariance per step.
    r : float
        Measurement noise variance.
    p : ndarray, shape (n, n)
        A-priori covariance.

    Returns
    -------
    ndarray, shape (n, n)
        The next a-priori covariance.
    """
    pc = p @ c
    return phi @ (p - np.outer(pc, pc) / (c @ pc + r)) @ phi.T + q


def residual(phi: np.ndarray, c: np.ndarray, q: np.ndarray, r: float, p: np.ndarray) -> float:
    """
    Relative residual ``max|step(P) - P| / max|P|`` of the Riccati equation.

    Parameters
    ----------
    phi, c, q, r, p
        As :func:`riccati_step`.

    Returns
    -------
    float
        The residual (0 for the exact solution).
    """
    return float(np.max(np.abs(riccati_step(phi, c, q, r, p) - p)) / np.max(np.abs(p)))


def _scaled_solution(phi, c, q, r, scale):
    inv = 1.0 / scale
    phis = inv[:, None] * phi * scale[None, :]
    cs = c * scale
    qs = inv[:, None] * q * inv[None, :]
    ps = linalg.solve_discrete_are(phis.T, cs[:, None], qs, np.array([[r]]))
    for _ in range(3):
        lp = phis @ ps @ cs / (cs @ ps @ cs + r)
        with warnings.catch_warnings():
            # an ill-conditioned Kronecker solve is judged by the Riccati residual instead
            warnings.simplefilter('ignore', linalg.LinAlgWarning)
            ps = linalg.solve_discrete_lyapunov(phis - np.outer(lp, cs),
                                                qs + r * np.outer(lp, lp), method='direct')
        ps = 0.5 * (ps + ps.T)
    return scale[:, None] * ps * scale[None, :]


def filter_riccati(phi: np.ndarray, c: np.ndarray, q: np.ndarray, r: float) -> np.ndarray:
    """
    Stabilising solution of the filter Riccati equation ``P = step(P)``.

    Parameters
    ----------
    phi, c, q, r
        As :func:`riccati_step` (``q`` positive semi-definite, ``r > 0``).

    Returns
    -------
    ndarray, shape (n, n)
        The steady-state a-priori covariance.

    Raises
    ------
    numpy.linalg.LinAlgError
        If no solution with a relative residual below :data:`MAX_RESIDUAL` is found.
    """
    p = linalg.solve_discrete_are(phi.T, c[:, None], q, np.array([[r]]))
    best, best_res = p, residual(phi, c, q, r, p)
    for _ in range(3):
        diag = np.abs(np.diag(best))
        floor = np.max(diag) * 1.0e-30
        scale = np.sqrt(np.maximum(diag, floor))
        try:
            p = _scaled_solution(phi, c, q, r, scale)
        except (ValueError, np.linalg.LinAlgError):
            break
        res = residual(phi, c, q, r, p)
        if np.all(np.isfinite(p)) and res < best_res:
            best, best_res = p, res
        if best_res < MAX_RESIDUAL:
            return best
    raise np.linalg.LinAlgError(f'the steady-state Riccati solution is inaccurate (relative '
                                f'residual {best_res:.3g})')
