"""
The first-order complex recursions of the modal sensitivities, compiled by numba.

:mod:`~emfc_ros.core.ident.linear_sensitivity` writes the linearised response as modal
signals ``s[n + 1] = lambda s[n] + x[n]`` and their derivatives with respect to ``lambda``,
``t[n + 1] = lambda t[n] + s[n]`` (both from 0). :func:`modal_pair` computes both in one pass
over the record. It is what ``scipy.signal.lfilter([0, 1], [1, -lambda], x)`` computes, applied
twice, with the same operations in the same order; without numba it is that call (importing
scipy.signal costs about a second, which the experiment runner does not pay otherwise).
"""

from __future__ import annotations

from typing import Callable, Optional, Tuple

import numpy as np

_JIT: Optional[Callable] = None


def modal_pair_kernel(lam: complex, x: np.ndarray, s: np.ndarray, t: np.ndarray) -> None:
    """
    Fill ``s`` and ``t`` (complex, the length of ``x``) with the two recursions (numba kernel).

    Parameters
    ----------
    lam : complex
        The mode's discrete-time eigenvalue.
    x : ndarray of float
        The drive, one value per sample.
    s, t : ndarray of complex
        Outputs: the modal signal and its derivative with respect to ``lam``.
    """
    acc_s = 0j
    acc_t = 0j
    for k in range(x.shape[0]):
        s[k] = acc_s
        t[k] = acc_t
        acc_t = lam * acc_t + acc_s
        acc_s = lam * acc_s + x[k]


def numba_available() -> bool:
    """
    Whether numba can be imported.

    Returns
    -------
    bool
        True with numba installed.
    """
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    return True


def _jitted() -> Callable:
    global _JIT
    if _JIT is None:
        import numba
        _JIT = numba.njit(cache=True, nogil=True)(modal_pair_kernel)
    return _JIT


def modal_pair(lam: complex, x: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """
    The modal signal of a drive and its derivative with respect to the eigenvalue.

    Parameters
    ----------
    lam : complex
        Discrete-time eigenvalue of the mode.
    x : ndarray
        The drive (1-D, real), one value per sample.

    Returns
    -------
    s, t : ndarray of complex
        ``s[n + 1] = lam s[n] + x[n]`` and ``t[n + 1] = lam t[n] + s[n]``, both 0 at n = 0.
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    if numba_available():
        s = np.empty(x.shape[0], dtype=complex)
        t = np.empty(x.shape[0], dtype=complex)
        _jitted()(complex(lam), x, s, t)
        return s, t
    from scipy import signal
    den = [1.0, -complex(lam)]
    s = signal.lfilter([0.0, 1.0], den, x.astype(complex))
    return s, signal.lfilter([0.0, 1.0], den, s)
