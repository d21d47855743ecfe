"""
The simulator's per-sample chain: DAC, hold, amplifiers, motor, RK4 mechanics, stops, sensor, ADC.

Written once, in the subset of Python that numba compiles: :mod:`emfc_ros.core.sim.simulator`
runs :func:`chain_block` either compiled with ``numba.njit(cache=True)`` or interpreted (the
pure Python/numpy fallback, same math, slow). Keep it free of anything numba cannot type.

Chain per sample ``n`` (period ``dt``, see ``docs/simulator.md``):

1. DAC: setpoint ``u[:, n]`` rounded to the nearest code of ``lsb = 2 range / 2**bits`` and
   clamped to the codes ``[-2**(bits-1), 2**(bits-1) - 1]`` (without quantisation: clamped to
   +/- range);
2. hold: zero-order (the DAC value over ``[t_n, t_n + dt)``) or first-order (a ramp from the
   previous DAC value at ``t_n`` to this one at ``t_n + dt``: one sample of delay);
3. amplifiers: ``I = clip(I(U) + noise_I[n], +/- limit)`` (noise held over the sample);
4. load changer force on the pan ``F_p = F(I_lc)``; coil force ``F_c = k(y) I_c`` at every RK4
   stage; stop force at the lever end when ``|y| > stop``;
5. ``substeps`` RK4 steps of the two-beam mechanics;
6. outputs at ``t_n``, before integrating the interval: sensor ``U(clip(y + noise_y, range))``
   through the ADC, the current monitors (``monitor_V_per_A I``) through the ADC, and the
   quantities a user computes from them.
"""

import math

import numpy as np

from emfc_ros.core.sim import rk4

# Indices into the packed parameter vector: the mechanics of rk4 (0..20), then these.
(DAC_LSB, DAC_LO, DAC_HI, DAC_RANGE, ADC_LSB, ADC_LO, ADC_HI, ADC_RANGE, SENSOR_RANGE,
 STOP_POS, STOP_K, STOP_D, MONITOR, NOISE_Y, NOISE_IC, NOISE_ILC, DT) = range(
    rk4.N_PAR, rk4.N_PAR + 17)
N_PAR = rk4.N_PAR + 17

# Rows of the output array (the reference rows only when the array has them).
(OUT_U_COIL, OUT_U_LC, OUT_I_COIL, OUT_I_LC, OUT_SENSOR, OUT_POS, OUT_F_COIL, OUT_F_LC,
 OUT_POS_TRUE, OUT_F_PAN, OUT_F_COIL_TRUE) = range(11)
N_MEASURED = 8
N_OUT = 11

# Counter-based noise (see emfc_ros.core.sim.noise): SplitMix64 outputs at counters 3 i + 1,
# 3 i + 2, 3 i + 3 of sample i, each turned into a standard normal by Acklam's inverse normal CDF.
GOLDEN = np.uint64(0x9E3779B97F4A7C15)
MIX1 = np.uint64(0xBF58476D1CE4E5B9)
MIX2 = np.uint64(0x94D049BB133111EB)
SHIFT11 = np.uint64(11)
SHIFT27 = np.uint64(27)
SHIFT30 = np.uint64(30)
SHIFT31 = np.uint64(31)
ONE = np.uint64(1)
TWO = np.uint64(2)
THREE = np.uint64(3)
INV_2_POW_53 = 1.0 / 9007199254740992.0
P_LOW = 0.02425
A0, A1, A2 = -3.969683028665376e+01, 2.209460984245205e+02, -2.759285104469687e+02
A3, A4, A5 = 1.383577518672690e+02, -3.066479806614716e+01, 2.506628277459239e+00
B0, B1, B2 = -5.447609879822406e+01, 1.615858368580409e+02, -1.556989798598866e+02
B3, B4 = 6.680131188771972e+01, -1.328068155288572e+01
C0, C1, C2 = -7.784894002430293e-03, -3.223964580411365e-01, -2.400758277161838e+00
C3, C4, C5 = -2.549732539343734e+00, 4.374664141464968e+00, 2.938163982698783e+00
D0, D1, D2, D3 = 7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e+00, \
    3.754408661907416e+00

MM_PER_M = 1.0e3

#: Below this angle [rad] sin and cos use short Taylor polynomials (the first omitted terms,
#: x**7 / 5040 and x**6 / 720, are below 3e-18 relative and 3e-17 there); the stops keep the
#: angles below about 3e-3 rad.
SMALL_ANGLE_RAD = 5.0e-3


def chain_block(x, prev, u, first, noise_key, use_noise, quantise, foh, substeps, par,
                amp_coil, amp_lc, motor, sensor, load_changer, sensor_table, out):
    """
    Run one block of samples through the chain in place.

    Parameters
    ----------
    x : ndarray, shape (4,)
        State ``[q1, q2, q1', q2']`` [rad, rad/s]; overwritten with the state after the block.
    prev : ndarray, shape (2,)
        DAC values [V] of the sample before the block (first-order hold); overwritten with the
        block's last DAC values.
    u : ndarray, shape (2, n)
        Setpoints of the coil and load-changer amplifiers [V].
    first : int
        Sample index of the block's first sample (the noise counter).
    noise_key : numpy.uint64
        Key of the noise streams (:func:`emfc_ros.core.sim.noise.noise_key`).
    use_noise, quantise, foh : bool
        Add noise; quantise the converters (else only clamp them); first-order hold.
    substeps : int
        RK4 steps per sample.
    par : ndarray, shape (N_PAR,)
        Packed mechanics, converters and noise levels (indices above).
    amp_coil, amp_lc, motor, sensor, load_changer : ndarray
        Ascending-power coefficients of the characteristics (``docs/model.md``).
    sensor_table : ndarray, shape (2**adc_bits,)
        Inverse sensor characteristic at every ADC code ``c`` (entry ``c - ADC_LO``), used
        when ``quantise``; without quantisation the inverse is solved by Newton's method.
    out : ndarray, shape (N_MEASURED or N_OUT, n)
        Filled with the output channels (rows above).
    """
    l1 = par[rk4.L1]
    l2 = par[rk4.L2]
    l3 = par[rk4.L3]
    g = par[rk4.G]
    c1 = par[rk4.C1]
    c2 = par[rk4.C2]
    d1 = par[rk4.D1]
    d2 = par[rk4.D2]
    c12 = c1 + c2
    d12 = d1 + d2
    r1 = par[rk4.R1]
    h1 = par[rk4.H1]
    r2 = par[rk4.R2]
    h2 = par[rk4.H2]
    m3l3 = par[rk4.M3] * l3
    f_off = par[rk4.F_OFF]
    a = par[rk4.M3] * l3 + par[rk4.M2] * r2
    b = par[rk4.M2] * h2
    m11 = par[rk4.J1] + par[rk4.MP] * l1 * l1 + (par[rk4.M2] + par[rk4.M3]) * l2 * l2
    m22 = par[rk4.J2] + par[rk4.M3] * l3 * l3
    arm1 = (par[rk4.M2] + par[rk4.M3]) * l2 - par[rk4.MP] * l1
    gm1 = g * par[rk4.M1]
    gm2 = g * par[rk4.M2]
    i_coil_max = par[rk4.I_COIL_MAX]
    i_lc_max = par[rk4.I_LC_MAX]
    stop = par[STOP_POS]
    k_stop = par[STOP_K]
    d_stop = par[STOP_D]
    sensor_range = par[SENSOR_RANGE]
    monitor = par[MONITOR]
    dt = par[DT]
    h = dt / substeps
    reference = out.shape[0] > N_MEASURED
    motor_m = motor.copy()          # k(y) in powers of y in metres
    for j in range(len(motor)):
        motor_m[j] = motor[j] * MM_PER_M ** j

    def horner(coeffs, v):
        acc = 0.0
        for k in range(len(coeffs) - 1, -1, -1):
            acc = acc * v + coeffs[k]
        return acc

    def horner_d(coeffs, v):
        acc = 0.0
        for k in range(len(coeffs) - 1, 0, -1):
            acc = acc * v + k * coeffs[k]
        return acc

    def sincos(v):
        if abs(v) < SMALL_ANGLE_RAD:
            v2 = v * v
            s = v + v * v2 * (-1.0 / 6.0 + v2 * (1.0 / 120.0))
            c = 1.0 + v2 * (-0.5 + v2 * (1.0 / 24.0))
            return s, c
        return math.sin(v), math.cos(v)

    def convert(v, lsb, lo, hi, span):
        # DAC or ADC: nearest code, clamped; without quantisation only the clamp.
        if quantise:
            code = float(math.floor(min(max(v / lsb, lo - 1.0), hi + 1.0) + 0.5))
            if code < lo:
                code = lo
            elif code > hi:
                code = hi
            return code * lsb
        return min(max(v, -span), span)

    def sensor_inverse(v):
        if quantise:
            return sensor_table[int(v / par[ADC_LSB] - par[ADC_LO] + 0.5)]
        # Newton from the linear term; the characteristic is monotonic over the range.
        pos = (v - sensor[0]) / sensor[1]
        for _ in range(30):
            step = (horner(sensor, pos) - v) / horner_d(sensor, pos)
            pos = pos - step
            if abs(step) <= 1.0e-15 * abs(pos) + 1.0e-300:
                break
        return pos

    def deriv(q1, q2, w1, w2, i_coil, f_pan):
        s1, k1 = sincos(q1)
        s2, k2 = sincos(q2)
        sp = s2 * k1 - k2 * s1
        cp = k2 * k1 + s2 * s1
        m12 = l2 * (a * cp - b * sp)
        dm12 = -l2 * (a * sp + b * cp)
        y = l2 * s1 + l3 * s2
        f_end = horner(motor_m, y) * i_coil + f_off
        if y > stop:
            f_stop = -k_stop * (y - stop) - d_stop * (l2 * k1 * w1 + l3 * k2 * w2)
            if f_stop < 0.0:
                f_end += f_stop
        elif y < -stop:
            f_stop = -k_stop * (y + stop) - d_stop * (l2 * k1 * w1 + l3 * k2 * w2)
            if f_stop > 0.0:
                f_end += f_stop
        g1 = gm1 * (r1 * k1 - h1 * s1) + g * arm1 * k1
        g2 = gm2 * (r2 * k2 - h2 * s2) + g * m3l3 * k2
        # the coil force's share last: it ends the longest dependency chain
        rest1 = (k1 * l1 * f_pan - dm12 * w2 * w2 - g1
                 - c12 * q1 + c2 * q2 - d12 * w1 + d2 * w2)
        rest2 = dm12 * w1 * w1 - g2 + c2 * q1 - c2 * q2 + d2 * w1 - d2 * w2
        e1 = k1 * l2
        e2 = k2 * l3
        inv_det = 1.0 / (m11 * m22 - m12 * m12)
        return (w1, w2,
                (m22 * rest1 - m12 * rest2) * inv_det + (m22 * e1 - m12 * e2) * inv_det * f_end,
                (m11 * rest2 - m12 * rest1) * inv_det + (m11 * e2 - m12 * e1) * inv_det * f_end)

    def splitmix(counter):
        z = noise_key + counter * GOLDEN
        z = (z ^ (z >> SHIFT30)) * MIX1
        z = (z ^ (z >> SHIFT27)) * MIX2
        return z ^ (z >> SHIFT31)

    def normal(z):
        # Acklam's rational approximation of the inverse normal CDF (relative error 1.2e-9)
        p = (float(z >> SHIFT11) + 0.5) * INV_2_POW_53
        if p < P_LOW or p > 1.0 - P_LOW:
            q = math.sqrt(-2.0 * math.log(min(p, 1.0 - p)))
            v = ((((((C0 * q + C1) * q + C2) * q + C3) * q + C4) * q + C5)
                 / ((((D0 * q + D1) * q + D2) * q + D3) * q + 1.0))
            return v if p < 0.5 else -v
        q = p - 0.5
        r = q * q
        return ((((((A0 * r + A1) * r + A2) * r + A3) * r + A4) * r + A5) * q
                / (((((B0 * r + B1) * r + B2) * r + B3) * r + B4) * r + 1.0))

    def current(coeffs, v, n_i, limit):
        return min(max(horner(coeffs, v) + n_i, -limit), limit)

    q1 = x[0]
    q2 = x[1]
    w1 = x[2]
    w2 = x[3]
    p_coil = prev[0]
    p_lc = prev[1]
    n_y = 0.0
    n_ic = 0.0
    n_ilc = 0.0
    for n in range(u.shape[1]):
        v_coil = convert(u[0, n], par[DAC_LSB], par[DAC_LO], par[DAC_HI], par[DAC_RANGE])
        v_lc = convert(u[1, n], par[DAC_LSB], par[DAC_LO], par[DAC_HI], par[DAC_RANGE])
        if use_noise:
            counter = np.uint64(first + n) * THREE
            n_y = normal(splitmix(counter + ONE)) * par[NOISE_Y]
            n_ic = normal(splitmix(counter + TWO)) * par[NOISE_IC]
            n_ilc = normal(splitmix(counter + THREE)) * par[NOISE_ILC]
        if foh:
            i_coil = current(amp_coil, p_coil, n_ic, i_coil_max)
            i_lc = current(amp_lc, p_lc, n_ilc, i_lc_max)
        else:
            i_coil = current(amp_coil, v_coil, n_ic, i_coil_max)
            i_lc = current(amp_lc, v_lc, n_ilc, i_lc_max)
        f_pan = horner(load_changer, i_lc)
        # outputs at t_n
        s1, k1 = sincos(q1)
        s2, k2 = sincos(q2)
        y = l2 * s1 + l3 * s2
        y_meas = min(max(y + n_y, -sensor_range), sensor_range)
        sensor_V = convert(horner(sensor, y_meas), par[ADC_LSB], par[ADC_LO], par[ADC_HI],
                           par[ADC_RANGE])
        pos = sensor_inverse(sensor_V)
        i_coil_meas = convert(monitor * i_coil, par[ADC_LSB], par[ADC_LO], par[ADC_HI],
                              par[ADC_RANGE]) / monitor
        i_lc_meas = convert(monitor * i_lc, par[ADC_LSB], par[ADC_LO], par[ADC_HI],
                            par[ADC_RANGE]) / monitor
        out[OUT_U_COIL, n] = v_coil
        out[OUT_U_LC, n] = v_lc
        out[OUT_I_COIL, n] = i_coil_meas
        out[OUT_I_LC, n] = i_lc_meas
        out[OUT_SENSOR, n] = sensor_V
        out[OUT_POS, n] = pos
        out[OUT_F_COIL, n] = horner(motor, pos * MM_PER_M) * i_coil_meas
        out[OUT_F_LC, n] = horner(load_changer, i_lc_meas)
        if reference:
            out[OUT_POS_TRUE, n] = y
            out[OUT_F_PAN, n] = f_pan
            out[OUT_F_COIL_TRUE, n] = horner(motor, y * MM_PER_M) * i_coil
        # integrate [t_n, t_n + dt)
        ic0 = i_coil
        icm = i_coil
        ic1 = i_coil
        fp0 = f_pan
        fpm = f_pan
        fp1 = f_pan
        for s in range(substeps):
            if foh:
                # the ramp at the substep's middle and end (its start is the last end)
                fm = (s + 0.5) / substeps
                fb = (s + 1.0) / substeps
                icm = current(amp_coil, p_coil + fm * (v_coil - p_coil), n_ic, i_coil_max)
                ic1 = current(amp_coil, p_coil + fb * (v_coil - p_coil), n_ic, i_coil_max)
                fpm = horner(load_changer, current(amp_lc, p_lc + fm * (v_lc - p_lc), n_ilc,
                                                   i_lc_max))
                fp1 = horner(load_changer, current(amp_lc, p_lc + fb * (v_lc - p_lc), n_ilc,
                                                   i_lc_max))
            a1, b1, e1, f1 = deriv(q1, q2, w1, w2, ic0, fp0)
            a2, b2, e2, f2 = deriv(q1 + 0.5 * h * a1, q2 + 0.5 * h * b1,
                                   w1 + 0.5 * h * e1, w2 + 0.5 * h * f1, icm, fpm)
            a3, b3, e3, f3 = deriv(q1 + 0.5 * h * a2, q2 + 0.5 * h * b2,
                                   w1 + 0.5 * h * e2, w2 + 0.5 * h * f2, icm, fpm)
            a4, b4, e4, f4 = deriv(q1 + h * a3, q2 + h * b3, w1 + h * e3, w2 + h * f3, ic1, fp1)
            q1 = q1 + h / 6.0 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
            q2 = q2 + h / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4)
            w1 = w1 + h / 6.0 * (e1 + 2.0 * e2 + 2.0 * e3 + e4)
            w2 = w2 + h / 6.0 * (f1 + 2.0 * f2 + 2.0 * f3 + f4)
            ic0 = ic1
            fp0 = fp1
        p_coil = v_coil
        p_lc = v_lc
    x[0] = q1
    x[1] = q2
    x[2] = w1
    x[3] = w2
    prev[0] = p_coil
    prev[1] = p_lc
