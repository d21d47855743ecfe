"""
Static characteristics: plateau averaging, polynomial and motor-coefficient fits.

Synthetic data with known coefficients (the paper's Table 1 values).
"""

import warnings

import numpy as np
import pytest

from emfc_ros.core.ident import (fit_motor_coefficient, fit_polynomial, IdentificationError,
                                 IllConditionedFitWarning, plateau_means)
from emfc_ros.core.signals import staircase

AMP = np.array([7.552e-6, 1.0e-2, -6.964e-6])          # paper Table 1, ascending powers
MOTOR = np.array([-5.273e-3, 0.012, 21.692])            # a, b, c with y in mm


def test_plateau_means_of_a_staircase():
    fs = 1000.0
    steps = staircase(-10.0, 2.0, 11, 0.5, fs)
    k = np.arange(int(11 * 0.5 * fs))
    u = steps.samples(k)
    # First-order settling (tau 20 ms) of the current to I(U), plus noise.
    target = np.polynomial.polynomial.polyval(u, AMP)
    current = target.copy()
    alpha = np.exp(-1.0 / (fs * 0.02))
    for i in range(1, k.size):
        current[i] = alpha * current[i - 1] + (1 - alpha) * target[i]
    rng = np.random.default_rng(1)
    current += 1e-6 * rng.standard_normal(k.size)
    plat = plateau_means({'U': u, 'I': current}, fs, steps.times_s, settle_s=0.2)
    np.testing.assert_allclose(plat.mean['U'], steps.levels_V, atol=1e-12)
    np.testing.assert_allclose(plat.mean['I'], np.polynomial.polynomial.polyval(
        steps.levels_V, AMP), atol=5 * 1e-6 / np.sqrt(300))
    assert np.all(plat.count == 300)
    np.testing.assert_allclose(plat.standard_error('I'), 1e-6 / np.sqrt(300), rtol=0.25)
    # Without the settle time the transient biases the first samples of every level.
    raw = plateau_means({'I': current}, fs, steps.times_s)
    assert np.max(np.abs(raw.mean['I'] - plat.mean['I'])) > 1e-5
    with pytest.raises(IdentificationError, match='plateau 0'):
        plateau_means({'I': current}, fs, steps.times_s, settle_s=0.5)


def test_polynomial_recovers_paper_amplifier_and_prints_it():
    u = np.linspace(-10.0, 10.0, 41)
    fit = fit_polynomial(u, np.polynomial.polynomial.polyval(u, AMP), 2, x_name='U',
                         y_name='I', x_unit='V', y_unit='A')
    np.testing.assert_allclose(fit.coefficients, AMP, rtol=1e-9)
    assert fit.formula() == 'I(U) = -6.964e-06 A/V^2 * U^2 + 1.000e-02 A/V * U + 7.552e-06 A'
    np.testing.assert_allclose(fit(u), np.polynomial.polynomial.polyval(u, AMP), atol=1e-15)
    assert fit.r_squared == pytest.approx(1.0)


def test_polynomial_standard_errors_cover_the_truth():
    rng = np.random.default_rng(2)
    u = np.linspace(-10.0, 10.0, 25)
    truth = np.polynomial.polynomial.polyval(u, AMP)
    inside, z = [], []
    for _ in range(300):
        fit = fit_polynomial(u, truth + 2e-6 * rng.standard_normal(u.size), 2)
        inside.append(np.abs(fit.coefficients - AMP) < 2.0 * fit.standard_errors)
        z.append((fit.coefficients - AMP) / fit.standard_errors)
    coverage = np.mean(inside, axis=0)
    # Student t with 22 dof: P(|t| < 2) = 0.94.
    assert np.all((coverage > 0.89) & (coverage < 0.98)), coverage
    np.testing.assert_allclose(np.std(z, axis=0), 1.0, rtol=0.15)


def test_polynomial_far_from_zero_is_well_conditioned():
    # Data around an offset: the raw Vandermonde in x is badly conditioned, the scaled one
    # is not, and the raw coefficients still come out right.
    x = np.linspace(1000.0, 1010.0, 30)
    y = 0.5 + 2.0 * (x - 1005.0) + 0.1 * (x - 1005.0) ** 2
    fit = fit_polynomial(x, y, 2)
    raw = np.array([0.5 - 2.0 * 1005.0 + 0.1 * 1005.0 ** 2, 2.0 - 0.2 * 1005.0, 0.1])
    np.testing.assert_allclose(fit.coefficients, raw, rtol=1e-7)
    np.testing.assert_allclose(fit(x), y, atol=1e-7)
    assert fit.condition_number < 10.0
    assert np.linalg.cond(np.vander(x, 3)) > 1e9


def test_ill_conditioned_design_warns():
    x = np.array([0.0, 0.0, 1.0, 1.0, 2.0, 2.0 + 1e-9, 2.0])
    with pytest.warns(IllConditionedFitWarning, match='condition number'):
        fit_polynomial(x, x ** 3, 3)
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        fit_polynomial(np.linspace(0.0, 2.0, 7), np.linspace(0.0, 2.0, 7) ** 3, 3)
    assert issubclass(IllConditionedFitWarning, UserWarning)


def test_motor_coefficient_fit():
    rng = np.random.default_rng(3)
    current = np.repeat(np.linspace(-0.1, 0.1, 9), 9)
    pos_mm = np.tile(np.linspace(-0.1, 0.1, 9), 9)
    force = (MOTOR[0] * pos_mm ** 2 + MOTOR[1] * pos_mm + MOTOR[2]) * current
    exact = fit_motor_coefficient(current, pos_mm, force)
    np.testing.assert_allclose(exact.coefficients, MOTOR, rtol=1e-7)
    assert exact.formula() == ('F(I, y) = (-5.273e-03 N/(A mm^2) * y^2 + 1.200e-02 N/(A mm) '
                               '* y + 2.169e+01 N/A) * I')
    # With noise the estimates sit within their standard errors (coverage over repeats).
    hits = []
    for _ in range(200):
        fit = fit_motor_coefficient(current, pos_mm, force + 1e-6 * rng.standard_normal(
            force.size))
        hits.append(np.abs(fit.coefficients - MOTOR) < 2.0 * fit.standard_errors)
    coverage = np.mean(hits, axis=0)
    assert np.all((coverage > 0.89) & (coverage < 0.99)), coverage
    # A constant position cannot separate a, b and c.
    with pytest.warns(IllConditionedFitWarning):
        fit_motor_coefficient(current, np.full(current.size, 0.05), force)


def test_fit_errors():
    with pytest.raises(IdentificationError, match='more samples'):
        fit_polynomial([0.0, 1.0, 2.0], [0.0, 1.0, 4.0], 2)
    with pytest.raises(IdentificationError, match='degree'):
        fit_polynomial([0.0, 1.0, 2.0], [0.0, 1.0, 4.0], -1)
    with pytest.raises(IdentificationError, match='equal length'):
        fit_motor_coefficient([1.0, 2.0], [1.0], [1.0, 2.0])


def test_a_std_floor_scales_the_covariance_of_a_too_good_fit():
    from emfc_ros.core.ident.static_fit import with_std_floor
    rng = np.random.default_rng(7)
    x = np.linspace(-1.0, 1.0, 9)
    y = 1e-5 + 0.01 * x + rng.normal(0.0, 1e-8, x.size)
    fit = fit_polynomial(x, y, 1)
    floored = with_std_floor(fit, 1e-6)
    ratio = 1e-6 / fit.residual_std
    np.testing.assert_allclose(floored.standard_errors, fit.standard_errors * ratio, rtol=1e-12)
    np.testing.assert_allclose(floored.coefficients, fit.coefficients)
    assert floored.residual_std == fit.residual_std
    # a fit whose scatter is already above the floor is left alone
    assert with_std_floor(fit, 0.5 * fit.residual_std) is fit
    assert with_std_floor(fit, 0.0) is fit


def test_quantised_plateau_means_get_an_uncertainty_that_covers_their_rounding():
    # plateau means rounded to a step of 3e-6 (no dither): the residuals of 9 plateaus may
    # scatter less than step / sqrt(12); the floor keeps the offset's interval honest
    from emfc_ros.core.ident.static_fit import with_std_floor
    step = 3.05e-6
    rng = np.random.default_rng(2024)
    inside_raw = inside_floor = 0
    trials = 400
    x = np.linspace(-1.0, 1.0, 9)
    for _ in range(trials):
        c0 = rng.uniform(-1e-5, 1e-5)
        c1 = 0.01 * rng.uniform(0.95, 1.05)
        y = np.round((c0 + c1 * x) / step) * step
        fit = fit_polynomial(x, y, 1)
        floored = with_std_floor(fit, step / np.sqrt(12.0))
        k = 2.36   # Student t, 7 degrees of freedom
        inside_raw += abs(fit.coefficients[0] - c0) <= k * fit.standard_errors[0]
        inside_floor += abs(floored.coefficients[0] - c0) <= k * floored.standard_errors[0]
    assert inside_floor / trials >= 0.93
    assert inside_floor >= inside_raw
