"""Tests of the dynamic weighing Kalman filter on linear simulations built here."""

import math

import numpy as np
import pytest
from scipy import linalg, signal

from emfc_ros.core.control import design_controller, plant_from_model
from emfc_ros.core.model.linear import linearise
from emfc_ros.core.model.operating_point import equilibrium
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.weighing import DynamicWeigher, WeighingCalibration, WeighingError

FS = 10.0e3
G = 9.81
STEP_AT = 2000          # sample of the 100 g step (0.2 s)
N_SAMPLES = 17000       # 1.7 s
ONE_MG_N = 1.0e-6 * G


@pytest.fixture(scope='module')
def mechanics():
    return BalanceParameters().mechanics


@pytest.fixture(scope='module')
def model(mechanics):
    return linearise(mechanics)


def _discrete(model, fs):
    """ZOH discretisation by the matrix exponential of the augmented matrix."""
    m = np.zeros((6, 6))
    m[:4, :4] = model.A
    m[:4, 4:] = model.B
    e = linalg.expm(m / fs)
    return e[:4, :4], e[:4, 4:]


@pytest.fixture(scope='module')
def closed_loop(model):
    """PID + lead loop at 50 Hz crossover, one sample of delay, 2 nm position noise."""
    ctrl = design_controller(plant_from_model(model), FS, 50.0, 40.0,
                             delay_samples=1.0).controller
    ac, bc, cc, dc = signal.tf2ss(ctrl.numerator, ctrl.denominator)
    phi, gam = _discrete(model, FS)
    pan = np.zeros(N_SAMPLES)
    pan[STEP_AT:] = 0.1 * G
    rng = np.random.default_rng(11)
    noise = 2e-9 * rng.standard_normal(N_SAMPLES)
    x, xc, u = np.zeros(4), np.zeros(ac.shape[0]), 0.0
    y_out, u_out = np.empty(N_SAMPLES), np.empty(N_SAMPLES)
    for k in range(N_SAMPLES):
        y = float(model.C[0] @ x) + noise[k]
        y_out[k], u_out[k] = y, u
        x = phi @ x + gam[:, 0] * u + gam[:, 1] * pan[k]
        u_next = -(float((cc @ xc)[0]) + float(dc[0, 0]) * y)
        xc = ac @ xc + bc[:, 0] * y
        u = u_next
    coil = model.operating_point.F_c_N + u_out
    return y_out, coil, pan


def _settle_index(value, target, tol):
    bad = np.nonzero(np.abs(value - target) > tol)[0]
    return int(bad[-1]) + 1


def test_transition_matrix_is_the_zoh_discretisation(model):
    weigher = DynamicWeigher(model, FS)
    phi, gam = _discrete(model, FS)
    np.testing.assert_allclose(weigher.transition[:4, :4], phi, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(weigher.transition[:4, 4], gam[:, 1], rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(weigher.coil_input[:4], gam[:, 0], rtol=1e-9, atol=1e-15)
    assert weigher.transition[4, 4] == 1.0 and not np.any(weigher.transition[4, :4])


def test_gain_is_the_limit_of_the_riccati_recursion(model):
    weigher = DynamicWeigher(model, FS, 2e-9, 1e-5)
    phi, c = weigher.transition, weigher.output_row
    q = np.zeros((5, 5))
    q[4, 4] = 1e-10 / FS
    r = 4e-18
    p = np.diag([1e-12, 1e-12, 1e-8, 1e-8, 1e-4])
    for _ in range(30000):
        s = c @ p @ c + r
        k = p @ c / s
        p = phi @ (p - np.outer(k, c @ p)) @ phi.T + q
    np.testing.assert_allclose(weigher.gain, p @ c / (c @ p @ c + r), rtol=1e-6)


def test_closed_loop_step_is_weighed_before_the_moving_average(model, mechanics, closed_loop):
    y, coil, pan = closed_loop
    weigher = DynamicWeigher(model, FS)
    est = weigher.update_block_detailed(y, coil)
    t_dynamic = (_settle_index(est.pan_force_N, pan, ONE_MG_N) - STEP_AT) / FS
    # the 1-s moving average of the compensation force, as a pan force (-dF_c / r)
    r = model.static_gain_m_per_N('pan') / model.static_gain_m_per_N('coil')
    average = np.convolve(coil, np.ones(10000) / 10000)[:N_SAMPLES]
    average_pan = -(average - model.operating_point.F_c_N) / r
    t_average = (_settle_index(average_pan[10000:], pan[10000:], ONE_MG_N) + 10000
                 - STEP_AT) / FS
    assert t_dynamic < 0.3
    assert t_average > 1.0
    # settled: not right after the step, always from 0.3 s after it
    assert not est.settled[STEP_AT + 50]
    assert np.all(est.settled[STEP_AT + 3000:])
    assert np.all(est.settled[200:STEP_AT])
    # the static calibration (from nonlinear equilibria) applies to the dynamic estimate
    f_empty = equilibrium(mechanics, 0.0).F_c_N
    f_loaded = equilibrium(mechanics, 0.1).F_c_N
    cal = WeighingCalibration.nominal(mechanics).zeroed(f_empty).adjusted(f_loaded, 0.1)
    mass = weigher.mass_kg(est.pan_force_N, cal)
    np.testing.assert_allclose(mass[STEP_AT + 3000:], 0.1, atol=1e-6)
    np.testing.assert_allclose(mass[200:STEP_AT], 0.0, atol=1e-6)


def test_block_split_gives_the_same_result_bit_for_bit(model, closed_loop):
    y, coil, _ = closed_loop
    whole = DynamicWeigher(model, FS).update_block_detailed(y, coil)
    split = DynamicWeigher(model, FS)
    rng = np.random.default_rng(12)
    cuts = np.r_[0, np.sort(rng.choice(np.arange(1, N_SAMPLES), 80, replace=False)),
                 N_SAMPLES]
    cuts = np.r_[cuts[:3], cuts[2] + 1, cuts[3:]]  # include a one-sample block
    parts = [split.update_block_detailed(y[a:b], coil[a:b]) for a, b in zip(cuts[:-1],
                                                                            cuts[1:])]
    for name in ('pan_force_N', 'equivalent_force_N', 'innovation_m', 'settled'):
        joined = np.concatenate([getattr(p, name) for p in parts])
        assert np.array_equal(joined, getattr(whole, name)), name
    assert np.array_equal(DynamicWeigher(model, FS).update_block(y, coil), whole.pan_force_N)


def test_numpy_backend_matches(model, closed_loop):
    y, coil, _ = closed_loop
    fast = DynamicWeigher(model, FS).update_block(y[:3000], coil[:3000])
    slow = DynamicWeigher(model, FS, backend='numpy').update_block(y[:3000], coil[:3000])
    np.testing.assert_allclose(slow, fast, rtol=1e-12, atol=1e-15)


def test_open_loop_estimate_converges_and_equivalent_force_at_rest(model):
    fs = 2000.0
    n = int(30 * fs)
    phi, gam = _discrete(model, fs)
    d_coil, d_pan = 1e-3, 5e-3
    t = np.arange(n) / fs
    coil = np.full(n, d_coil)
    coil[: int(10 * fs)] += 2e-3 * np.sin(2 * math.pi * 1.3 * t[: int(10 * fs)])
    pan = np.where(t >= 1.0, d_pan, 0.0)
    _, y, _ = signal.dlsim((phi, gam, model.C, np.zeros((1, 2)), 1.0 / fs),
                           np.column_stack([coil, pan]))
    y = y[:, 0]
    op = model.operating_point
    weigher = DynamicWeigher(model, fs)
    est = weigher.update_block_detailed(y + op.y_m, coil + op.F_c_N)
    np.testing.assert_allclose(est.pan_force_N[int(3 * fs):], op.F_p_N + d_pan, rtol=1e-6,
                               atol=1e-9)
    # at rest (30 s: the 3.8 Hz mode has decayed) F_eq = F_c - y / G_coil(0)
    g_coil = model.static_gain_m_per_N('coil')
    np.testing.assert_allclose(est.equivalent_force_N[-1],
                               op.F_c_N + d_coil - y[-1] / g_coil, rtol=1e-9)
    np.testing.assert_allclose(y[-1], g_coil * d_coil + model.static_gain_m_per_N('pan')
                               * d_pan, rtol=1e-6)


def test_constructor_from_mechanics_and_errors(mechanics, model):
    a = DynamicWeigher(mechanics, FS)
    b = DynamicWeigher(model, FS)
    np.testing.assert_array_equal(a.gain, b.gain)
    assert 0.0 < b.pan_force_u_N < ONE_MG_N
    with pytest.raises(WeighingError, match='model_or_mechanics'):
        DynamicWeigher('model', FS)
    with pytest.raises(WeighingError, match='position_noise_m_rms'):
        DynamicWeigher(model, FS, position_noise_m_rms=0.0)
    with pytest.raises(WeighingError, match='backend'):
        DynamicWeigher(model, FS, backend='gpu')
    with pytest.raises(WeighingError, match='equal length'):
        b.update_block(np.zeros(3), np.zeros(4))
    with pytest.raises(WeighingError, match='non-finite'):
        b.update_block(np.array([np.nan]), np.zeros(1))
