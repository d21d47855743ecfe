"""
The simulator's per-sample chain: DAC, hold, amplifiers, motor, RK4 mechanics, stops, sensor, ADC.

Written once, in the subset of Python that numba compiles: :mod:`emfc_ros.core.sim.simulator`
runs :func:`chain_block` either compiled with ``numba.njit(cache=True, fastmath=True)`` or
interpreted (the pure Python/numpy fallback, same math, slow). Keep it free of anything numba
cannot type.

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

Layout for speed (``docs/simulator.md``, section Performance): the block is worked in chunks of
``CHUNK`` samples, each in three passes, so that the mechanics loop (the costliest part) carries
no other work: (a) the noise of the chunk, the DAC, amplifiers and pan force, (b) the RK4 steps,
(c) the sensor, ADC and outputs. Passes (a) and (c) hold no inner loops or state-dependent
branches for the usual polynomial degrees (the characteristics as scalars, the converters
branch-free with ``np.floor``), so that LLVM can vectorise parts of them; the noise is kept in
one row per stream. Sine and cosine are short Taylor polynomials while every stage of an RK4
step has ``q1**2 + q2**2 < SMALL_ANGLE_SQ`` (hence ``|q1| + |q2| < SMALL_ANGLE_RAD``), otherwise
the step is recomputed with libm.

Compilation time: only the RK4 step and the accelerations are closures of
:func:`chain_block` (numba inlines a closure's IR at every call site, which is what keeps the
mechanics loop free of calls, spills and libm); every other helper is a module-level function
compiled once (``register_jitable``) that LLVM inlines where it is small. With all helpers as
closures the first compilation took 45 s; it is about 12-15 s now (measured with an empty
``NUMBA_CACHE_DIR``; later runs load the cache).
"""

import math

import numpy as np

from emfc_ros.core.sim import rk4

# Indices into the packed parameter vector: the mechanics of rk4 (0..20), then these, the
# switches (1.0 for on) and the number of RK4 steps per sample, then from COEFFS the lengths of
# the five characteristics' coefficient lists (CHARACTERISTICS order); the lists follow from
# N_PAR on, one after the other (:func:`characteristic`). One vector keeps the kernel's
# argument count low: numba's dispatcher costs about 0.15 us per argument and call.
(DAC_LSB, DAC_LO, DAC_HI, DAC_RANGE, ADC_LSB, ADC_LO, ADC_HI, ADC_RANGE, SENSOR_RANGE,
 STOP_POS, STOP_K, STOP_D, MONITOR, NOISE_Y, NOISE_IC, NOISE_ILC, DT, USE_NOISE, QUANTISE, FOH,
 SUBSTEPS) = range(rk4.N_PAR, rk4.N_PAR + 21)
#: The characteristics packed from COEFFS on (ascending powers, ``docs/model.md``): coil and
#: load-changer amplifier [A/V**k], motor [N/(A mm**k)], sensor [V/m**k], load changer
#: [N/A**k].
CHARACTERISTICS = ('amp_coil', 'amp_lc', 'motor', 'sensor', 'load_changer')
AMP_COIL, AMP_LC, MOTOR, SENSOR, LOAD_CHANGER = range(5)
COEFFS = rk4.N_PAR + 21
N_PAR = COEFFS + len(CHARACTERISTICS)

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
THREE = np.uint64(3)
INV_2_POW_53 = 1.0 / 9007199254740992.0
# Exponent bits of a float64: all set for inf and nan (tested on the bits: fastmath assumes
# finite floats, so a floating-point test could be optimised away).
EXP_MASK = np.int64(0x7FF0000000000000)
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

#: While ``|q1| + |q2|`` [rad] stays below this at every stage of an RK4 step (so do
#: ``|q1|``, ``|q2|`` and ``|q2 - q1|``), sine and cosine are short Taylor polynomials: the first
#: omitted terms, x**7 / 5040 and x**6 / 720, are below 3e-18 relative and 3e-17 there, i.e.
#: below the rounding of the libm values. Otherwise the step is redone with ``math.sin/cos``.
SMALL_ANGLE_RAD = 5.0e-3
#: The test on the stages: ``q1**2 + q2**2 < SMALL_ANGLE_RAD**2 / 2`` implies the bound above
#: and is cheaper to evaluate.
SMALL_ANGLE_SQ = 0.5 * SMALL_ANGLE_RAD * SMALL_ANGLE_RAD
#: Samples per chunk of the three passes (scratch arrays of this length stay in the L1 cache).
CHUNK = 256


#: How numba compiles the chain and its helpers. fastmath flags: FMA contraction and
#: reassociation (about 20 % faster), still deterministic; not 'arcp' (reciprocal instead of
#: division): LLVM applies it where a basic block divides by the same value more than once, so
#: a vectorised loop body and its scalar remainder would round differently and a sample's
#: outputs would depend on where the block boundaries fall. error_model 'numpy': a float
#: division by zero gives inf or nan instead of raising ZeroDivisionError, so divisions carry
#: no branch and loops with one vectorise (the parameters are validated: no divisor is zero).
#: nogil: the kernel releases the GIL, so that the grey-box fit simulates parameter sets in
#: threads. numba's cache key is the source file's content, not these options: they live in
#: this file so that changing them recompiles.
JIT_OPTIONS = {'fastmath': {'nnan', 'ninf', 'nsz', 'contract', 'afn', 'reassoc'},
               'error_model': 'numpy', 'nogil': True}

try:    # compiled once each and inlined by LLVM into the chain (numba), plain Python otherwise
    from numba.extending import register_jitable as _register_jitable

    def _jitable(function):
        return _register_jitable(**JIT_OPTIONS)(function)
except ImportError:     # pragma: no cover - numba is optional
    def _jitable(function):
        return function


# Module-level helpers, compiled once each (see the module docstring, Compilation time).


@_jitable
def characteristic(par, k):
    """
    Return the coefficients of characteristic ``k`` (AMP_COIL .. LOAD_CHANGER) in ``par``.

    Parameters
    ----------
    par : ndarray
        The packed parameter vector (:func:`chain_block`).
    k : int
        Index of the characteristic in CHARACTERISTICS.

    Returns
    -------
    ndarray
        A view of its coefficients in ascending powers (units in CHARACTERISTICS).
    """
    start = N_PAR
    for j in range(k):
        start += int(par[COEFFS + j])
    return par[start:start + int(par[COEFFS + k])]


@_jitable
def horner(coeffs, v):
    """
    Return ``sum_k coeffs[k] v**k`` by Horner's scheme.

    Parameters
    ----------
    coeffs : ndarray
        Coefficients in ascending powers.
    v : float
        The argument.

    Returns
    -------
    float
        The polynomial's value (0.0 for no coefficients).
    """
    acc = 0.0
    for k in range(len(coeffs) - 1, -1, -1):
        acc = acc * v + coeffs[k]
    return acc


@_jitable
def horner_d(coeffs, v):
    """
    Return the derivative of ``horner(coeffs, v)`` with respect to ``v``.

    Parameters
    ----------
    coeffs : ndarray
        Coefficients in ascending powers.
    v : float
        The argument.

    Returns
    -------
    float
        ``sum_k k coeffs[k] v**(k - 1)``.
    """
    acc = 0.0
    for k in range(len(coeffs) - 1, 0, -1):
        acc = acc * v + k * coeffs[k]
    return acc


@_jitable
def sin_small(v, v2):
    """
    Return the sine of a small angle ``v`` [rad] (``v2 = v**2``).

    Parameters
    ----------
    v : float
        The angle [rad], ``|v|`` below SMALL_ANGLE_RAD for full accuracy.
    v2 : float
        ``v**2`` [rad**2].

    Returns
    -------
    float
        The Taylor polynomial to ``v**5``.
    """
    return v + v * v2 * (-1.0 / 6.0 + v2 * (1.0 / 120.0))


@_jitable
def cos_small(v2):
    """
    Return the cosine of a small angle whose square is ``v2`` [rad**2].

    Parameters
    ----------
    v2 : float
        The angle squared [rad**2].

    Returns
    -------
    float
        The Taylor polynomial to ``v**4``.
    """
    return 1.0 + v2 * (-0.5 + v2 * (1.0 / 24.0))


@_jitable
def convert(v, lsb, lo, hi, span, quantise):
    """
    Convert with a DAC or ADC: nearest code, clamped.

    Returns ``(code * lsb, code)``; without quantisation only the clamp to ``+/- span`` (and
    code 0).

    Parameters
    ----------
    v : float
        The converter's input [V].
    lsb : float
        Volts per code [V].
    lo, hi : float
        Lowest and highest code.
    span : float
        The converter's range [V], the clamp without quantisation.
    quantise : bool
        Round to codes; otherwise only clamp.

    Returns
    -------
    value : float
        The converted voltage [V].
    code : float
        Its code (0.0 without quantisation).
    """
    if quantise:
        code = float(math.floor(min(max(v / lsb, lo - 1.0), hi + 1.0) + 0.5))
        if code < lo:
            code = lo
        elif code > hi:
            code = hi
        return code * lsb, code
    return min(max(v, -span), span), 0.0


@_jitable
def sensor_inverse(v, code, quantise, sensor, sensor_table, adc_lo):
    """
    Return the lever-end position [m] of a sensor voltage ``v`` [V] (ADC ``code``).

    Parameters
    ----------
    v : float
        The sensor voltage [V] (used without quantisation).
    code : float
        Its ADC code (used with quantisation).
    quantise : bool
        Look the code up in ``sensor_table``; otherwise solve the characteristic by Newton's
        method.
    sensor : ndarray
        The sensor characteristic in ascending powers [V/m**k], monotonic over the range.
    sensor_table : ndarray
        The position at every ADC code [m] (entry ``code - adc_lo``).
    adc_lo : float
        The ADC's lowest code.

    Returns
    -------
    float
        The position [m].
    """
    if quantise:
        return sensor_table[int(code - adc_lo)]
    # Newton from the linear term; the characteristic is monotonic over the range.
    pos = (v - sensor[0]) / sensor[1]
    for _ in range(30):
        step = (horner(sensor, pos) - v) / horner_d(sensor, pos)
        pos = pos - step
        if abs(step) <= 1.0e-15 * abs(pos) + 1.0e-300:
            break
    return pos


@_jitable
def trig(q1, q2, taylor):
    """
    Return sin and cos of ``q1``, ``q2`` and ``q2 - q1``: short polynomials or libm.

    Parameters
    ----------
    q1, q2 : float
        Beam angles [rad].
    taylor : bool
        Use the Taylor polynomials (accurate while ``|q1| + |q2| < SMALL_ANGLE_RAD``), else
        ``math.sin`` and ``math.cos``.

    Returns
    -------
    tuple of float
        ``(sin q1, cos q1, sin q2, cos q2, sin(q2 - q1), cos(q2 - q1))``.
    """
    if taylor:
        v1 = q1 * q1
        v2 = q2 * q2
        p = q2 - q1
        vp = p * p
        return (sin_small(q1, v1), cos_small(v1), sin_small(q2, v2), cos_small(v2),
                sin_small(p, vp), cos_small(vp))
    return (math.sin(q1), math.cos(q1), math.sin(q2), math.cos(q2), math.sin(q2 - q1),
            math.cos(q2 - q1))


@_jitable
def splitmix(counter, noise_key):
    """
    Return the SplitMix64 output at ``counter`` of the stream ``noise_key``.

    Parameters
    ----------
    counter : numpy.uint64
        Position in the stream.
    noise_key : numpy.uint64
        Key of the stream (:func:`emfc_ros.core.sim.noise.noise_key`).

    Returns
    -------
    numpy.uint64
        The 64 hashed bits.
    """
    z = noise_key + counter * GOLDEN
    z = (z ^ (z >> SHIFT30)) * MIX1
    z = (z ^ (z >> SHIFT27)) * MIX2
    return z ^ (z >> SHIFT31)


@_jitable
def normal_central(p):
    """
    Return Acklam's inverse normal CDF for ``P_LOW <= p <= 1 - P_LOW``.

    Parameters
    ----------
    p : float
        A probability in that range.

    Returns
    -------
    float
        The standard normal quantile of ``p`` (relative error 1.2e-9).
    """
    q = p - 0.5
    r = q * q
    return ((((((A0 * r + A1) * r + A2) * r + A3) * r + A4) * r + A5) * q
            / (((((B0 * r + B1) * r + B2) * r + B3) * r + B4) * r + 1.0))


@_jitable
def normal_tail(p):
    """
    Return the same outside, ``p < P_LOW`` or ``p > 1 - P_LOW`` (relative error 1.2e-9).

    Parameters
    ----------
    p : float
        A probability in (0, 1) outside the central range.

    Returns
    -------
    float
        The standard normal quantile of ``p``.
    """
    q = math.sqrt(-2.0 * math.log(min(p, 1.0 - p)))
    v = ((((((C0 * q + C1) * q + C2) * q + C3) * q + C4) * q + C5)
         / ((((D0 * q + D1) * q + D2) * q + D3) * q + 1.0))
    return v if p < 0.5 else -v


@_jitable
def normals(counter0, m, zz, p_tmp, bits, tails, noise_key):
    """
    Fill ``zz[r, j]`` with the standard normal at counter ``counter0 + 3 j + r``.

    In passes that vectorise: the SplitMix64 hashes of the ``3 m`` consecutive counters into
    ``bits`` (53 bits each), their conversion to ``p`` in (0, 1), the central rational
    function for all; then the flat indices of the tail values (about 5 %) are gathered into
    ``tails`` without a branch and only those are recomputed (a loop with the tail function
    under a branch would be vectorised by computing it, with its logarithm, for every value).

    Parameters
    ----------
    counter0 : numpy.uint64
        Counter of ``zz[0, 0]``.
    m : int
        Columns to fill, at most ``zz.shape[1]``.
    zz : ndarray, shape (3, width)
        Filled in its first ``m`` columns: one row per noise stream (sensor, coil current,
        load-changer current).
    p_tmp : ndarray, shape (3, width)
        Scratch, the probabilities.
    bits : ndarray of numpy.uint64, shape (>= 3 m,)
        Scratch, the hashes.
    tails : ndarray of numpy.int64, shape (>= 3 m,)
        Scratch, the flat indices of the tail values.
    noise_key : numpy.uint64
        Key of the noise streams.
    """
    for k in range(3 * m):
        bits[k] = splitmix(counter0 + np.uint64(k), noise_key) >> SHIFT11
    for r in range(3):
        p_r = p_tmp[r, :m]
        for j in range(m):
            p_r[j] = (float(np.int64(bits[3 * j + r])) + 0.5) * INV_2_POW_53
    for r in range(3):
        p_r = p_tmp[r, :m]
        z_r = zz[r, :m]
        for j in range(m):
            z_r[j] = normal_central(p_r[j])
    width = zz.shape[1]
    n_tails = 0
    for r in range(3):
        for j in range(m):
            p = p_tmp[r, j]
            tails[n_tails] = r * width + j
            n_tails += int((p < P_LOW) | (p > 1.0 - P_LOW))
    z_flat = zz.reshape(-1)
    p_flat = p_tmp.reshape(-1)
    for k in range(n_tails):
        i = tails[k]
        z_flat[i] = normal_tail(p_flat[i])


@_jitable
def current(coeffs, v, n_i, limit):
    """
    Return the amplifier current ``clip(I(v) + n_i, +/- limit)`` [A].

    Parameters
    ----------
    coeffs : ndarray
        The amplifier characteristic in ascending powers [A/V**k].
    v : float
        The amplifier's input [V].
    n_i : float
        The current noise of the sample [A].
    limit : float
        The amplifier's current limit [A].

    Returns
    -------
    float
        The current [A].
    """
    return min(max(horner(coeffs, v) + n_i, -limit), limit)


@_jitable
def code_of(v, lsb, lo, hi):
    """
    Return the converter's code: nearest, clamped (branch-free, so that loops vectorise).

    Parameters
    ----------
    v : float
        The converter's input [V].
    lsb : float
        Volts per code [V].
    lo, hi : float
        Lowest and highest code.

    Returns
    -------
    float
        The code, an integer value in ``[lo, hi]``.
    """
    return min(max(np.floor(min(max(v / lsb, lo - 1.0), hi + 1.0) + 0.5), lo), hi)


def chain_block(x, prev, u, first, noise_key, par, sensor_table, out):
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
    par : ndarray
        Packed mechanics, converters, noise levels, switches (``USE_NOISE``: add noise,
        ``QUANTISE``: quantise the converters, else only clamp them, ``FOH``: first-order
        hold), ``SUBSTEPS`` (RK4 steps per sample) and the characteristics (indices above,
        :func:`characteristic`).
    sensor_table : ndarray, shape (2**adc_bits,)
        Inverse sensor characteristic at every ADC code ``c`` (entry ``c - ADC_LO``), used
        when ``quantise``; without quantisation the inverse is solved by Newton's method.
    out : ndarray, shape (N_MEASURED or N_OUT, n)
        Filled with the output channels (rows above).

    Returns
    -------
    bool
        False, with nothing simulated or changed, if ``u`` holds a value that is not finite.
    """
    bits = u.view(np.int64)
    bits_c = bits[0]
    bits_l = bits[1]
    bad = 0
    for n in range(u.shape[1]):    # no early exit: the loop vectorises
        bad |= (((bits_c[n] & EXP_MASK) == EXP_MASK) | ((bits_l[n] & EXP_MASK) == EXP_MASK))
    if bad:
        return False
    l1 = par[rk4.L1]
    l2 = par[rk4.L2]
    l3 = par[rk4.L3]
    g = par[rk4.G]
    c1 = par[rk4.C1]
    c2 = par[rk4.C2]
    d1 = par[rk4.D1]
    d2 = par[rk4.D2]
    m3l3 = par[rk4.M3] * l3
    f_off = par[rk4.F_OFF]
    a = par[rk4.M3] * l3 + par[rk4.M2] * par[rk4.R2]
    b = par[rk4.M2] * par[rk4.H2]
    l2a = l2 * a
    l2b = l2 * b
    m11 = par[rk4.J1] + par[rk4.MP] * l1 * l1 + (par[rk4.M2] + par[rk4.M3]) * l2 * l2
    m22 = par[rk4.J2] + par[rk4.M3] * l3 * l3
    m11m22 = m11 * m22
    arm1 = (par[rk4.M2] + par[rk4.M3]) * l2 - par[rk4.MP] * l1
    gm1 = g * par[rk4.M1]
    gm2 = g * par[rk4.M2]
    # gravity torques g1 = gk1 cos q1 - gs1 sin q1, g2 = gk2 cos q2 - gs2 sin q2
    gk1 = gm1 * par[rk4.R1] + g * arm1
    gs1 = gm1 * par[rk4.H1]
    gk2 = gm2 * par[rk4.R2] + g * m3l3
    gs2 = gm2 * par[rk4.H2]
    i_coil_max = par[rk4.I_COIL_MAX]
    i_lc_max = par[rk4.I_LC_MAX]
    stop = par[STOP_POS]
    k_stop = par[STOP_K]
    d_stop = par[STOP_D]
    sensor_range = par[SENSOR_RANGE]
    monitor = par[MONITOR]
    dac_lsb = par[DAC_LSB]
    dac_lo = par[DAC_LO]
    dac_hi = par[DAC_HI]
    dac_range = par[DAC_RANGE]
    adc_lsb = par[ADC_LSB]
    adc_lo = par[ADC_LO]
    adc_hi = par[ADC_HI]
    adc_range = par[ADC_RANGE]
    noise_y = par[NOISE_Y]
    noise_ic = par[NOISE_IC]
    noise_ilc = par[NOISE_ILC]
    dt = par[DT]
    use_noise = par[USE_NOISE] != 0.0
    quantise = par[QUANTISE] != 0.0
    foh = par[FOH] != 0.0
    substeps = int(par[SUBSTEPS])
    amp_coil = characteristic(par, AMP_COIL)
    amp_lc = characteristic(par, AMP_LC)
    motor = characteristic(par, MOTOR)
    sensor = characteristic(par, SENSOR)
    load_changer = characteristic(par, LOAD_CHANGER)
    h = dt / substeps
    reference = out.shape[0] > N_MEASURED
    # k(y) in powers of y in metres; up to a quadratic in scalars (zero padded: the same
    # operations as Horner's scheme on the shorter polynomial)
    n_motor = len(motor)
    motor_m = np.zeros(max(n_motor, 3))
    for j in range(n_motor):
        motor_m[j] = motor[j] * MM_PER_M ** j
    km0 = motor_m[0]
    km1 = motor_m[1]
    km2 = motor_m[2]
    short_motor = n_motor <= 3
    hh = 0.5 * h
    h6 = h / 6.0

    def accel(q1, q2, w1, w2, i_coil, pan1, taylor):
        # accelerations [q1'', q2''] at one RK4 stage; pan1 = l1 F_p - gk1
        s1, k1, s2, k2, sp, cp = trig(q1, q2, taylor)
        m12 = l2a * cp - l2b * sp
        dm12 = -(l2a * sp + l2b * cp)
        y = l2 * s1 + l3 * s2
        if short_motor:
            k_y = km0 + y * (km1 + y * km2)
        else:
            k_y = horner(motor_m, y)
        f_end = k_y * i_coil + f_off
        if y > stop:
            f_stop = -k_stop * (y - stop) - d_stop * (l2 * k1 * w1 + l3 * k2 * w2)
            if f_stop < 0.0:
                f_end += f_stop
        elif y < -stop:
            f_stop = -k_stop * (y + stop) - d_stop * (l2 * k1 * w1 + l3 * k2 * w2)
            if f_stop > 0.0:
                f_end += f_stop
        # generalised forces without the lever-end force, then its share (the latest input)
        spring = c2 * (q1 - q2) + d2 * (w1 - w2)
        r1 = k1 * pan1 + gs1 * s1 - dm12 * w2 * w2 - c1 * q1 - d1 * w1 - spring
        r2 = dm12 * w1 * w1 - gk2 * k2 + gs2 * s2 + spring
        r1 = r1 + l2 * k1 * f_end
        r2 = r2 + l3 * k2 * f_end
        inv_det = 1.0 / (m11m22 - m12 * m12)
        return (m22 * r1 - m12 * r2) * inv_det, (m11 * r2 - m12 * r1) * inv_det, y

    def rk4_step(q1, q2, w1, w2, ic0, icm, ic1, pan0, panm, pan1, taylor):
        # one RK4 step; also the lever-end position at its start and the largest
        # q1**2 + q2**2 of the stages (the Taylor polynomials' argument bound)
        e1, f1, y0 = accel(q1, q2, w1, w2, ic0, pan0, taylor)
        a2 = w1 + hh * e1
        b2 = w2 + hh * f1
        q1b = q1 + hh * w1
        q2b = q2 + hh * w2
        bound = max(q1 * q1 + q2 * q2, q1b * q1b + q2b * q2b)
        e2, f2, _ = accel(q1b, q2b, a2, b2, icm, panm, taylor)
        # the RK4 sums, accumulated as the stages come (fewer values live at once)
        sq1 = w1 + 2.0 * a2
        sq2 = w2 + 2.0 * b2
        sw1 = e1 + 2.0 * e2
        sw2 = f1 + 2.0 * f2
        a3 = w1 + hh * e2
        b3 = w2 + hh * f2
        q1c = q1 + hh * a2
        q2c = q2 + hh * b2
        bound = max(bound, q1c * q1c + q2c * q2c)
        e3, f3, _ = accel(q1c, q2c, a3, b3, icm, panm, taylor)
        sq1 = sq1 + 2.0 * a3
        sq2 = sq2 + 2.0 * b3
        sw1 = sw1 + 2.0 * e3
        sw2 = sw2 + 2.0 * f3
        a4 = w1 + h * e3
        b4 = w2 + h * f3
        q1d = q1 + h * a3
        q2d = q2 + h * b3
        bound = max(bound, q1d * q1d + q2d * q2d)
        e4, f4, _ = accel(q1d, q2d, a4, b4, ic1, pan1, taylor)
        return (q1 + h6 * (sq1 + a4), q2 + h6 * (sq2 + b4), w1 + h6 * (sw1 + e4),
                w2 + h6 * (sw2 + f4), y0, bound)

    # the characteristics as scalars (zero padded: the same operations as Horner's scheme on
    # the shorter polynomial), so that passes 1 and 3 carry no inner loops
    short = (len(amp_coil) <= 3 and len(amp_lc) <= 3 and len(load_changer) <= 3
             and n_motor <= 3 and len(sensor) <= 6)
    cf = np.zeros(20)
    if short:
        for j in range(len(amp_coil)):
            cf[j] = amp_coil[j]
        for j in range(len(amp_lc)):
            cf[3 + j] = amp_lc[j]
        for j in range(len(load_changer)):
            cf[6 + j] = load_changer[j]
        for j in range(n_motor):
            cf[9 + j] = motor[j]
        for j in range(len(sensor)):
            cf[12 + j] = sensor[j]
    ac0, ac1, ac2 = cf[0], cf[1], cf[2]
    al0, al1, al2 = cf[3], cf[4], cf[5]
    lc0, lc1, lc2 = cf[6], cf[7], cf[8]
    mo0, mo1, mo2 = cf[9], cf[10], cf[11]
    se0, se1, se2, se3, se4, se5 = cf[12], cf[13], cf[14], cf[15], cf[16], cf[17]

    n_total = u.shape[1]
    chunk = min(n_total, CHUNK)
    i_c = np.empty(chunk)
    i_l = np.empty(chunk)
    f_p = np.empty(chunk)
    # DAC values, entry j + 1 for sample j of the chunk, entry 0 the sample before
    v_c = np.empty(chunk + 1)
    v_l = np.empty(chunk + 1)
    y_true = np.empty(chunk)
    s_code = np.empty(chunk)
    s_pos = np.empty(chunk)
    zz = np.zeros((3, chunk))
    p_tmp = np.empty((3, chunk))
    bits = np.empty(3 * chunk, np.uint64)
    tails = np.empty(3 * chunk, np.int64)
    q1 = x[0]
    q2 = x[1]
    w1 = x[2]
    w2 = x[3]
    v_c[0] = prev[0]
    v_l[0] = prev[1]
    # amplifier input of sample j: v_c[j + hold_off] (the previous DAC value with the FOH)
    hold_off = 0 if foh else 1
    for start in range(0, n_total, CHUNK):
        m = min(start + CHUNK, n_total) - start
        if use_noise:
            normals(np.uint64(first + start) * THREE + ONE, m, zz, p_tmp, bits, tails,
                    noise_key)
        # 1. DAC, amplifiers, pan force (independent of the state)
        # 1-D views: loops over them vectorise (2-D indexing with an offset does not)
        u_c = u[0, start:start + m]
        u_l = u[1, start:start + m]
        z_y = zz[0, :m]
        z_c = zz[1, :m]
        z_l = zz[2, :m]
        if short:
            d_c = v_c[1:m + 1]
            d_l = v_l[1:m + 1]
            if quantise:
                for j in range(m):
                    d_c[j] = code_of(u_c[j], dac_lsb, dac_lo, dac_hi) * dac_lsb
                    d_l[j] = code_of(u_l[j], dac_lsb, dac_lo, dac_hi) * dac_lsb
            else:
                for j in range(m):
                    d_c[j] = min(max(u_c[j], -dac_range), dac_range)
                    d_l[j] = min(max(u_l[j], -dac_range), dac_range)
            h_c = v_c[hold_off:hold_off + m]
            h_l = v_l[hold_off:hold_off + m]
            for j in range(m):
                vc = h_c[j]
                vl = h_l[j]
                ic = min(max(ac0 + vc * (ac1 + vc * ac2) + z_c[j] * noise_ic, -i_coil_max),
                         i_coil_max)
                il = min(max(al0 + vl * (al1 + vl * al2) + z_l[j] * noise_ilc, -i_lc_max),
                         i_lc_max)
                i_c[j] = ic
                i_l[j] = il
                f_p[j] = lc0 + il * (lc1 + il * lc2)
        else:
            for j in range(m):
                n = start + j
                v_c[j + 1] = convert(u[0, n], dac_lsb, dac_lo, dac_hi, dac_range,
                                     quantise)[0]
                v_l[j + 1] = convert(u[1, n], dac_lsb, dac_lo, dac_hi, dac_range,
                                     quantise)[0]
                i_c[j] = current(amp_coil, v_c[j + hold_off], zz[1, j] * noise_ic, i_coil_max)
                i_l[j] = current(amp_lc, v_l[j + hold_off], zz[2, j] * noise_ilc, i_lc_max)
                f_p[j] = horner(load_changer, i_l[j])
        # 2. the mechanics: the lever-end position at t_n, then integrate [t_n, t_n + dt)
        for j in range(m):
            ic0 = i_c[j]
            icm = ic0
            ic1 = ic0
            fp0 = f_p[j]
            fpm = fp0
            fp1 = fp0
            if foh:
                pc = v_c[j]
                pl = v_l[j]
                vc = v_c[j + 1]
                vl = v_l[j + 1]
                nic = zz[1, j] * noise_ic
                nil = zz[2, j] * noise_ilc
            for s in range(substeps):
                if foh:
                    # the ramp at the substep's middle and end (its start is the last end)
                    fm = (s + 0.5) / substeps
                    fb = (s + 1.0) / substeps
                    icm = current(amp_coil, pc + fm * (vc - pc), nic, i_coil_max)
                    ic1 = current(amp_coil, pc + fb * (vc - pc), nic, i_coil_max)
                    fpm = horner(load_changer, current(amp_lc, pl + fm * (vl - pl), nil,
                                                       i_lc_max))
                    fp1 = horner(load_changer, current(amp_lc, pl + fb * (vl - pl), nil,
                                                       i_lc_max))
                pan0 = l1 * fp0 - gk1
                panm = l1 * fpm - gk1
                pan1 = l1 * fp1 - gk1
                n1, n2, n3, n4, y0, bound = rk4_step(q1, q2, w1, w2, ic0, icm, ic1, pan0,
                                                     panm, pan1, True)
                if bound >= SMALL_ANGLE_SQ:
                    # outside the polynomials' range (at the stops, say): libm throughout
                    n1, n2, n3, n4, y0, bound = rk4_step(q1, q2, w1, w2, ic0, icm, ic1, pan0,
                                                         panm, pan1, False)
                if s == 0:
                    y_true[j] = y0
                q1 = n1
                q2 = n2
                w1 = n3
                w2 = n4
                ic0 = ic1
                fp0 = fp1
        # 3. sensor, ADC, monitors and the user's quantities at t_n
        if short and quantise:
            for j in range(m):
                y_meas = min(max(y_true[j] + z_y[j] * noise_y, -sensor_range), sensor_range)
                s_code[j] = code_of(se0 + y_meas * (se1 + y_meas * (se2 + y_meas * (
                    se3 + y_meas * (se4 + y_meas * se5)))), adc_lsb, adc_lo, adc_hi)
            for j in range(m):
                s_pos[j] = sensor_table[int(s_code[j] - adc_lo)]
            o_uc = out[OUT_U_COIL, start:start + m]
            o_ul = out[OUT_U_LC, start:start + m]
            o_ic = out[OUT_I_COIL, start:start + m]
            o_il = out[OUT_I_LC, start:start + m]
            o_s = out[OUT_SENSOR, start:start + m]
            o_p = out[OUT_POS, start:start + m]
            o_fc = out[OUT_F_COIL, start:start + m]
            o_fl = out[OUT_F_LC, start:start + m]
            for j in range(m):
                pos = s_pos[j]
                i_coil_meas = code_of(monitor * i_c[j], adc_lsb, adc_lo, adc_hi) * adc_lsb \
                    / monitor
                i_lc_meas = code_of(monitor * i_l[j], adc_lsb, adc_lo, adc_hi) * adc_lsb \
                    / monitor
                pm = pos * MM_PER_M
                o_uc[j] = d_c[j]
                o_ul[j] = d_l[j]
                o_ic[j] = i_coil_meas
                o_il[j] = i_lc_meas
                o_s[j] = s_code[j] * adc_lsb
                o_p[j] = pos
                o_fc[j] = (mo0 + pm * (mo1 + pm * mo2)) * i_coil_meas
                o_fl[j] = lc0 + i_lc_meas * (lc1 + i_lc_meas * lc2)
        else:
            for j in range(m):
                n = start + j
                y_meas = min(max(y_true[j] + zz[0, j] * noise_y, -sensor_range), sensor_range)
                sensor_V, sensor_code = convert(horner(sensor, y_meas), adc_lsb, adc_lo,
                                                adc_hi, adc_range, quantise)
                pos = sensor_inverse(sensor_V, sensor_code, quantise, sensor, sensor_table,
                                     adc_lo)
                i_coil_meas = convert(monitor * i_c[j], adc_lsb, adc_lo, adc_hi,
                                      adc_range, quantise)[0] / monitor
                i_lc_meas = convert(monitor * i_l[j], adc_lsb, adc_lo, adc_hi,
                                    adc_range, quantise)[0] / monitor
                out[OUT_U_COIL, n] = v_c[j + 1]
                out[OUT_U_LC, n] = v_l[j + 1]
                out[OUT_I_COIL, n] = i_coil_meas
                out[OUT_I_LC, n] = i_lc_meas
                out[OUT_SENSOR, n] = sensor_V
                out[OUT_POS, n] = pos
                out[OUT_F_COIL, n] = horner(motor, pos * MM_PER_M) * i_coil_meas
                out[OUT_F_LC, n] = horner(load_changer, i_lc_meas)
        if reference:
            for j in range(m):
                n = start + j
                y = y_true[j]
                out[OUT_POS_TRUE, n] = y
                out[OUT_F_PAN, n] = f_p[j]
                out[OUT_F_COIL_TRUE, n] = horner(motor, y * MM_PER_M) * i_c[j]
        v_c[0] = v_c[m]
        v_l[0] = v_l[m]
    x[0] = q1
    x[1] = q2
    x[2] = w1
    x[3] = w2
    prev[0] = v_c[0]
    prev[1] = v_l[0]
    return True
