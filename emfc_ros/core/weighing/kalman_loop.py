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


def adaptive_block(phi, gamma, c, r, q_w, x, p, position_m, coil_force_N, window, threshold,
                   inflation, nis_ring, counters, pan_force_N, pan_force_var, innovation_m,
                   since_change, nis_alpha, w_low, w_high, switch_var):
    """
    Run the time-varying (change-adaptive) filter over one block, in place.

    The covariance ``p`` follows the Riccati recursion sample by sample. The normalised
    innovation squared ``e^2 / s`` is summed over the last ``window`` samples; when the sum
    exceeds ``threshold`` (a load change the model does not explain) the diagonal
    ``inflation`` is added to ``p`` before the update, so that the filter forgets the old
    force and converges on the new one as fast as the data allow; the ring is then cleared
    (while the transient goes on, the innovations fill it again and the change is declared
    again: the filter keeps forgetting until the model explains the data).

    The test is relative to the running mean of the normalised innovation squared (1 when the
    assumed position noise is right; an exponential average over ``1 / nis_alpha`` samples,
    updated only while the window looks quiet, each term clipped at 9 times the mean), so that
    a position noise assumed 30 % too low does not declare changes that did not happen.

    Parameters
    ----------
    phi : ndarray, shape (n, n)
        Augmented transition matrix in scaled coordinates.
    gamma : ndarray, shape (n,)
        Coil-force input column (scaled).
    c : ndarray, shape (n,)
        Output row (scaled).
    r : float
        Position noise variance [m^2].
    q_w : float
        Process noise variance of the (scaled) force state per sample.
    x : ndarray, shape (n,)
        A-priori state before the block (updated).
    p : ndarray, shape (n, n)
        A-priori covariance before the block (updated).
    position_m, coil_force_N : ndarray, shape (k,)
        Position and coil-force deviations from the operating point [m], [N].
    window : int
        Samples of the innovation test.
    threshold : float
        Limit of the windowed normalised innovation squared.
    inflation : ndarray, shape (n,)
        Diagonal added to ``p`` on a change (scaled).
    nis_ring : ndarray, shape (window,)
        The last normalised innovations squared (updated).
    counters : ndarray, shape (5,)
        ``[ring sum, samples seen, changes, samples since the last change, running mean of
        the normalised innovation squared]`` (updated).
    pan_force_N, pan_force_var : ndarray, shape (k,)
        Output: filtered force state and its variance (scaled).
    innovation_m : ndarray, shape (k,)
        Output: innovations [m].
    since_change : ndarray, shape (k,)
        Output: samples since the last declared change (this sample counts 1).
    nis_alpha : float
        Weight of a new sample in the running mean of the normalised innovation squared.
    w_low, w_high, switch_var : float
        The model's load band (scaled force): the block stops after the first sample whose
        force estimate, known to a variance below ``switch_var``, left ``[w_low, w_high]``,
        so that the caller switches to the model of that load.

    Returns
    -------
    int
        Samples processed (fewer than the block's when the caller must switch models).
    """
    n = x.shape[0]
    cp = np.empty(n)
    gain = np.empty(n)
    tmp = np.empty((n, n))
    for k in range(position_m.shape[0]):
        for i in range(n):
            acc = 0.0
            for j in range(n):
                acc += c[j] * p[j, i]
            cp[i] = acc
        s = r
        predicted = 0.0
        for i in range(n):
            s += cp[i] * c[i]
            predicted += c[i] * x[i]
        e = position_m[k] - predicted
        nu2 = e * e / s
        slot = int(counters[1]) % window
        counters[0] += nu2 - nis_ring[slot]
        nis_ring[slot] = nu2
        counters[1] += 1.0
        mean = counters[4]
        if counters[0] < 2.0 * window * mean:
            counters[4] = mean + nis_alpha * (min(nu2, 9.0 * mean) - mean)
        if counters[1] >= window and counters[0] > threshold * mean:
            for i in range(n):
                p[i, i] += inflation[i]
            for i in range(n):
                acc = 0.0
                for j in range(n):
                    acc += c[j] * p[j, i]
                cp[i] = acc
            s = r
            for i in range(n):
                s += cp[i] * c[i]
            for i in range(window):
                nis_ring[i] = 0.0
            counters[0] = 0.0
            counters[2] += 1.0
            counters[3] = 0.0
        for i in range(n):
            gain[i] = cp[i] / s
            x[i] += gain[i] * e
        # P - cP' cP / s, kept symmetric
        for i in range(n):
            for j in range(i, n):
                v = p[i, j] - cp[i] * cp[j] / s
                p[i, j] = v
                p[j, i] = v
        counters[3] += 1.0
        pan_force_N[k] = x[n - 1]
        pan_force_var[k] = p[n - 1, n - 1]
        innovation_m[k] = e
        since_change[k] = counters[3]
        # predict: x = phi x + gamma u, P = phi P phi' + Q
        u = coil_force_N[k]
        for i in range(n):
            acc = gamma[i] * u
            for j in range(n):
                acc += phi[i, j] * x[j]
            gain[i] = acc
        for i in range(n):
            x[i] = gain[i]
        for i in range(n):
            for j in range(n):
                acc = 0.0
                for m in range(n):
                    acc += phi[i, m] * p[m, j]
                tmp[i, j] = acc
        for i in range(n):
            for j in range(i, n):
                acc = 0.0
                for m in range(n):
                    acc += tmp[i, m] * phi[j, m]
                p[i, j] = acc
                p[j, i] = acc
        p[n - 1, n - 1] += q_w
        if (x[n - 1] < w_low or x[n - 1] > w_high) and p[n - 1, n - 1] < switch_var:
            return k + 1
    return position_m.shape[0]
