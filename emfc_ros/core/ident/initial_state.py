"""
The balance's state at the start of the record, estimated from the data.

The grey-box simulation starts the record at rest under its first setpoints. A balance that
was not (a user's experiment whose first section starts at a non-zero setpoint, PRBS or a
multisine, after the balance rested at 0 V; a record cut out of a longer stream) then rings at
its low mode for seconds in the measurement and not in the simulation: the parameters are not
affected (the fit projects each section's transient out of its weighted residual), but the
time-domain fit percentage and the time plots were (a right model fitted a PRBS section to 22
%, issue 28).

The deviation of the initial state adds the free response ``y_k = C A_d^k dx0`` of the fitted
mechanics, linearised at rest and discretised at the sample rate, to the simulated position.
:func:`correct_record` estimates ``dx0`` (position and velocity of both beams, 4 numbers) by
linear least squares on the fitted sections' output error and adds that free response to the
simulated record. Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Sequence, Tuple

import numpy as np

#: The free response is computed until it has decayed to this fraction of its start.
DECAYED = 1.0e-6


@dataclass(frozen=True)
class InitialState:
    """
    The estimated initial-state deviation and what it changed.

    Attributes
    ----------
    deviation : ndarray, shape (n_states,)
        ``dx0`` in the linear model's state coordinates (beam angles [rad], rates [rad/s]).
    position_m : float
        The lever-end position it gives at the first sample [m] (``C dx0``).
    rms_before_m, rms_after_m : float
        Root-mean-square output error over the fitted sections without and with it [m].
    samples : int
        Samples over which the free response was computed (it decays within them).
    """

    deviation: np.ndarray
    position_m: float
    rms_before_m: float
    rms_after_m: float
    samples: int


def free_response_basis(a: np.ndarray, c: np.ndarray, sample_rate_Hz: float,
                        n_samples: int) -> np.ndarray:
    """
    Rows ``C A_d^k``, ``k = 0 .. K-1``: the output of an initial state, sample by sample.

    Parameters
    ----------
    a : ndarray, shape (n, n)
        Continuous-time state matrix.
    c : ndarray, shape (n,) or (1, n)
        Output row (lever-end position).
    sample_rate_Hz : float
        Sample rate [Hz].
    n_samples : int
        Most samples wanted; fewer when the response has decayed to :data:`DECAYED` sooner.

    Returns
    -------
    ndarray, shape (K, n)
        The basis (real).
    """
    from scipy import linalg as sla

    a_d = sla.expm(np.asarray(a, dtype=float) / float(sample_rate_Hz))
    row = np.asarray(c, dtype=float).reshape(-1)
    mu, v = np.linalg.eig(a_d)
    slowest = float(np.max(np.abs(mu)))
    if slowest < 1.0:
        k = int(math.ceil(math.log(DECAYED) / math.log(slowest))) if slowest > 0.0 else 1
        n_samples = min(int(n_samples), max(k, 1))
    n = int(n_samples)
    if np.linalg.cond(v) < 1.0e8:
        powers = mu[None, :] ** np.arange(n)[:, None]
        return np.real((powers * (row @ v)[None, :]) @ np.linalg.inv(v))
    out = np.empty((n, row.size))
    current = row.copy()
    for i in range(n):               # defective A_d: one product per sample
        out[i] = current
        current = current @ a_d
    return out


def correct_record(a: np.ndarray, c: np.ndarray, sample_rate_Hz: float,
                   measured: np.ndarray, simulated: np.ndarray,
                   spans: Sequence[Tuple[int, int]]) -> Tuple[np.ndarray, InitialState]:
    """
    The simulated record with the free response of the estimated initial-state deviation.

    Parameters
    ----------
    a, c : ndarray
        The fitted mechanics linearised at rest: state matrix and position output row.
    sample_rate_Hz : float
        Sample rate [Hz].
    measured, simulated : ndarray, shape (N,)
        Lever-end position over the record [m].
    spans : sequence of (first, n)
        The fitted sections (the least squares uses their samples only).

    Returns
    -------
    record : ndarray, shape (N,)
        ``simulated`` plus ``C A_d^k dx0`` (a new array).
    state : InitialState
        ``dx0`` and the error before and after.
    """
    y = np.asarray(measured, dtype=float)
    sim = np.asarray(simulated, dtype=float)
    index = np.concatenate([np.arange(first, first + n) for first, n in spans]) if spans \
        else np.arange(0)
    err = y[index] - sim[index]
    before = float(np.sqrt(np.mean(err ** 2))) if err.size else math.nan
    basis = free_response_basis(a, c, sample_rate_Hz, sim.size)
    inside = index[index < basis.shape[0]]
    out = sim.copy()
    n_states = basis.shape[1]
    if inside.size <= n_states:
        return out, InitialState(np.zeros(n_states), 0.0, before, before, basis.shape[0])
    rows = basis[inside]
    scale = np.linalg.norm(rows, axis=0)
    scale[scale == 0.0] = 1.0
    coef, *_ = np.linalg.lstsq(rows / scale, y[inside] - sim[inside], rcond=None)
    dx0 = coef / scale
    out[:basis.shape[0]] += basis @ dx0
    err = y[index] - out[index]
    after = float(np.sqrt(np.mean(err ** 2)))
    return out, InitialState(dx0, float(basis[0] @ dx0), before, after, basis.shape[0])
