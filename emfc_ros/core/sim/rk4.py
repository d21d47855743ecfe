"""
The plant kernel's math: fixed-step RK4 of the full nonlinear chain over a block of samples.

Written once, in the subset of Python that numba compiles: :mod:`emfc_ros.core.sim.kernel`
runs :func:`rk4_block` either compiled with ``numba.njit(cache=True)`` or as is (the pure
numpy/Python fallback). Keep it free of anything numba cannot type (no dataclasses, no
``np.linalg``), and keep it the only copy of this math in the simulator.

Chain per sample ``n`` (sample period ``dt``, setpoints held over ``[t_n, t_n + dt)``):

1. coil and load-changer amplifier: ``I = I(U)`` (polynomials), clipped to +/- the limits;
2. load changer: ``F_p = F(I_lc)``;
3. ``substeps`` RK4 steps of the mechanics (``docs/model.md``) with the coil force
   ``F_c = k(y) I_c`` re-evaluated at every stage from the current lever-end position;
4. outputs are taken at ``t_n``, before integrating the sample's interval.
"""

import math

# Indices into the packed mechanics vector (see kernel.pack_mechanics).
L1, L2, L3, MP, M1, R1, H1, J1, M2, R2, H2, J2, M3 = range(13)
C1, D1, C2, D2, F_OFF, G, I_COIL_MAX, I_LC_MAX = range(13, 21)
N_PAR = 21

# Rows of the output array.
OUT_Y, OUT_SENSOR, OUT_I_COIL, OUT_I_LC, OUT_F_COIL, OUT_F_PAN = range(6)
N_OUT = 6

MM_PER_M = 1.0e3


def rk4_block(x, u_coil, u_lc, dt, substeps, par, amp_coil, amp_lc, motor, sensor,
              load_changer, out):
    """
    Integrate one block of samples in place.

    Parameters
    ----------
    x : ndarray, shape (4,)
        State ``[q1, q2, q1', q2']`` [rad, rad/s] at the block's first sample; overwritten with
        the state at the end of the block (the next block's start).
    u_coil, u_lc : ndarray, shape (n,)
        Setpoint voltages of the coil and load-changer amplifiers [V], zero-order hold.
    dt : float
        Sample period [s].
    substeps : int
        RK4 steps per sample.
    par : ndarray, shape (N_PAR,)
        Packed mechanics and current limits (indices above).
    amp_coil, amp_lc : ndarray
        Amplifier coefficients [A/V**k].
    motor : ndarray
        Motor coefficient [N/(A mm**j)] in powers of the position in mm.
    sensor : ndarray
        Sensor coefficients [V/m**k].
    load_changer : ndarray
        Load changer coefficients [N/A**k].
    out : ndarray, shape (N_OUT, n)
        Filled with lever-end position [m], sensor voltage [V], coil current [A],
        load-changer current [A], coil force [N] and pan force [N] at each sample instant.
    """
    l1 = par[L1]
    l2 = par[L2]
    l3 = par[L3]
    g = par[G]
    c1 = par[C1]
    c2 = par[C2]
    d1 = par[D1]
    d2 = par[D2]
    f_off = par[F_OFF]
    a = par[M3] * l3 + par[M2] * par[R2]
    b = par[M2] * par[H2]
    m11 = par[J1] + par[MP] * l1 * l1 + (par[M2] + par[M3]) * l2 * l2
    m22 = par[J2] + par[M3] * l3 * l3
    arm1 = (par[M2] + par[M3]) * l2 - par[MP] * l1
    grav1 = par[M1]
    grav2 = par[M2]
    h = dt / substeps

    def horner(coeffs, x):
        # sum_k coeffs[k] x**k, ascending powers
        acc = 0.0
        for k in range(coeffs.shape[0] - 1, -1, -1):
            acc = acc * x + coeffs[k]
        return acc

    def deriv(q1, q2, w1, w2, i_coil, f_pan):
        s1 = math.sin(q1)
        k1 = math.cos(q1)
        s2 = math.sin(q2)
        k2 = math.cos(q2)
        phi = q2 - q1
        sp = math.sin(phi)
        cp = math.cos(phi)
        m12 = l2 * (a * cp - b * sp)
        dm12 = -l2 * (a * sp + b * cp)
        y = l2 * s1 + l3 * s2
        f_end = horner(motor, y * MM_PER_M) * i_coil + f_off
        g1 = g * (grav1 * (par[R1] * k1 - par[H1] * s1) + arm1 * k1)
        g2 = g * (grav2 * (par[R2] * k2 - par[H2] * s2) + par[M3] * l3 * k2)
        r1 = (k1 * (l2 * f_end + l1 * f_pan) - dm12 * w2 * w2 - g1
              - (c1 + c2) * q1 + c2 * q2 - (d1 + d2) * w1 + d2 * w2)
        r2 = (l3 * k2 * f_end + dm12 * w1 * w1 - g2
              + c2 * q1 - c2 * q2 + d2 * w1 - d2 * w2)
        det = m11 * m22 - m12 * m12
        return w1, w2, (m22 * r1 - m12 * r2) / det, (m11 * r2 - m12 * r1) / det

    q1 = x[0]
    q2 = x[1]
    w1 = x[2]
    w2 = x[3]
    for n in range(u_coil.shape[0]):
        i_coil = min(max(horner(amp_coil, u_coil[n]), -par[I_COIL_MAX]), par[I_COIL_MAX])
        i_lc = min(max(horner(amp_lc, u_lc[n]), -par[I_LC_MAX]), par[I_LC_MAX])
        f_pan = horner(load_changer, i_lc)
        y = l2 * math.sin(q1) + l3 * math.sin(q2)
        out[OUT_Y, n] = y
        out[OUT_SENSOR, n] = horner(sensor, y)
        out[OUT_I_COIL, n] = i_coil
        out[OUT_I_LC, n] = i_lc
        out[OUT_F_COIL, n] = horner(motor, y * MM_PER_M) * i_coil
        out[OUT_F_PAN, n] = f_pan
        for _ in range(substeps):
            a1, b1, c1_, d1_ = deriv(q1, q2, w1, w2, i_coil, f_pan)
            a2, b2, c2_, d2_ = deriv(q1 + 0.5 * h * a1, q2 + 0.5 * h * b1,
                                     w1 + 0.5 * h * c1_, w2 + 0.5 * h * d1_, i_coil, f_pan)
            a3, b3, c3_, d3_ = deriv(q1 + 0.5 * h * a2, q2 + 0.5 * h * b2,
                                     w1 + 0.5 * h * c2_, w2 + 0.5 * h * d2_, i_coil, f_pan)
            a4, b4, c4_, d4_ = deriv(q1 + h * a3, q2 + h * b3, w1 + h * c3_, w2 + h * d3_,
                                     i_coil, f_pan)
            q1 = q1 + h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
            q2 = q2 + h / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
            w1 = w1 + h / 6.0 * (c1_ + 2.0 * c2_ + 2.0 * c3_ + c4_)
            w2 = w2 + h / 6.0 * (d1_ + 2.0 * d2_ + 2.0 * d3_ + d4_)
    x[0] = q1
    x[1] = q2
    x[2] = w1
    x[3] = w2
