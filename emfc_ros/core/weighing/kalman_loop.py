"""
The per-sample recursion of the steady-state Kalman filter of :mod:`.dynamic`.

Written in the subset of Python that numba compiles (plain arrays and loops):
:class:`~emfc_ros.core.weighing.dynamic.DynamicWeigher` runs :func:`kalman_block` compiled
with ``numba.njit(cache=True)`` when numba is available, else interpreted (same math).
"""

import numpy as np


def kalman_block(phi, gamma, c, gain, state, position_m, coil_force_N, pan_force_N,
                 innovation_m):
    """
    Run the filter over one block, updating ``state`` in place.

    Parameters
    ----------
    phi : ndarray, shape (n, n)
        Augmented transition matrix (last state: pan force deviation [N]).
    gamma : ndarray, shape (n,)
        Coil-force input column [state units per N].
    c : ndarray, shape (n,)
        Output row [m per state unit].
    gain : ndarray, shape (n,)
        Steady-state Kalman gain [state units per m].
    state : ndarray, shape (n,)
        A-priori state estimate before the block's first sample; overwritten with the one
        after its last sample.
    position_m : ndarray, shape (k,)
        Measured lever-end position deviations [m].
    coil_force_N : ndarray, shape (k,)
        Coil-force deviations [N], held over each sample interval.
    pan_force_N : ndarray, shape (k,)
        Output: filtered pan-force deviation per sample [N].
    innovation_m : ndarray, shape (k,)
        Output: innovation (measured minus predicted position) per sample [m].
    """
    n = state.shape[0]
    filtered = np.empty(n)
    for k in range(position_m.shape[0]):
        predicted = 0.0
        for i in range(n):
            predicted += c[i] * state[i]
        e = position_m[k] - predicted
        for i in range(n):
            filtered[i] = state[i] + gain[i] * e
        pan_force_N[k] = filtered[n - 1]
        innovation_m[k] = e
        u = coil_force_N[k]
        for i in range(n):
            acc = gamma[i] * u
            for j in range(n):
                acc += phi[i, j] * filtered[j]
            state[i] = acc
