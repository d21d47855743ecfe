"""Tests of the compensation force and the weighing calibration against hand computations."""

import math

import numpy as np
import pytest

from emfc_ros.core.model.operating_point import equilibrium
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.model.peripherals import MotorCoefficient
from emfc_ros.core.sim.hold_point import hold_point
from emfc_ros.core.weighing import (compensation_force_N, WeighingCalibration, WeighingError)

MOTOR = (21.692, 0.012, -5.273e-3)
S_NOMINAL = -(0.060 + 0.030) / (0.012 * 9.81)


@pytest.fixture(scope='module')
def params():
    return BalanceParameters()


def test_compensation_force_matches_the_motor_characteristic():
    rng = np.random.default_rng(1)
    current = rng.uniform(-0.1, 0.1, 200)
    position = rng.uniform(-100e-6, 100e-6, 200)
    expected = MotorCoefficient(MOTOR).force_N(current, position)
    np.testing.assert_allclose(compensation_force_N(current, position, MOTOR), expected,
                               rtol=1e-15, atol=0.0)


def test_compensation_force_by_hand_and_broadcasting():
    # y = 50 um = 0.05 mm: k = 21.692 + 0.012 * 0.05 - 5.273e-3 * 0.05**2
    k = 21.692 + 0.012 * 0.05 - 5.273e-3 * 0.0025
    np.testing.assert_allclose(compensation_force_N(0.03, 50e-6, MOTOR), k * 0.03, rtol=1e-15)
    out = compensation_force_N(np.array([0.01, 0.02]), 0.0, MOTOR)
    np.testing.assert_allclose(out, [0.21692, 0.43384], rtol=1e-15)
    with pytest.raises(WeighingError, match='motor_coeffs'):
        compensation_force_N(0.01, 0.0, [])


def test_nominal_sensitivity_from_geometry(params):
    cal = WeighingCalibration.nominal(params.mechanics)
    assert cal.sensitivity_kg_per_N == pytest.approx(S_NOMINAL, rel=1e-15)
    assert cal.sensitivity_kg_per_N == pytest.approx(-0.764525993883792, rel=1e-12)
    assert cal.zero_force_N == 0.0 and cal.tare_kg == 0.0


def test_sign_against_the_hold_point(params):
    # The coil setpoint that holds y = 0 falls when mass is added: 0.768 V -> 0.165 V.
    u0 = hold_point(params, 0.0).setpoints_V[0]
    u1 = hold_point(params, 0.1).setpoints_V[0]
    assert u0 == pytest.approx(0.768, abs=1e-3) and u1 == pytest.approx(0.165, abs=1e-3)
    f0 = equilibrium(params.mechanics, 0.0).F_c_N
    f1 = equilibrium(params.mechanics, 0.1).F_c_N
    cal = WeighingCalibration.nominal(params.mechanics).zeroed(f0)
    # nominal span: positive reading, 0.054 % low (y = 0 held, not q = 0)
    assert cal.mass_kg(f1) == pytest.approx(0.1 * 0.13326 / (0.012 / 0.090), rel=2e-5)
    adjusted = cal.adjusted(f1, 0.1)
    assert adjusted.mass_kg(f1) == pytest.approx(0.1, rel=1e-14)
    f_half = equilibrium(params.mechanics, 0.05).F_c_N
    assert adjusted.mass_kg(f_half) == pytest.approx(0.05, rel=1e-6)


def test_zero_tare_adjust_round_trip():
    cal = WeighingCalibration(S_NOMINAL)
    f0, f_ref, f_box = 0.1668, 0.1668 - 0.1308, 0.1668 - 0.0654
    zeroed = cal.zeroed(f0)
    assert zeroed.mass_kg(f0) == 0.0
    adjusted = zeroed.adjusted(f_ref, 0.1)
    np.testing.assert_allclose(adjusted.sensitivity_kg_per_N, 0.1 / (f_ref - f0), rtol=1e-15)
    np.testing.assert_allclose(adjusted.mass_kg(f_ref), 0.1, rtol=1e-15)
    assert adjusted.zero_force_N == f0
    tared = adjusted.tared(f_box)
    np.testing.assert_allclose(tared.mass_kg(f_box), 0.0, atol=1e-17)
    gross_box = 0.1 * (f_box - f0) / (f_ref - f0)
    np.testing.assert_allclose(tared.tare_kg, gross_box, rtol=1e-14)
    np.testing.assert_allclose(tared.gross_mass_kg(f_ref), 0.1, rtol=1e-15)
    np.testing.assert_allclose(tared.mass_kg(f_ref), 0.1 - gross_box, rtol=1e-14)
    # re-zeroing clears the tare and keeps the span
    rezeroed = tared.zeroed(f0 + 1e-4)
    assert rezeroed.tare_kg == 0.0
    assert rezeroed.sensitivity_kg_per_N == adjusted.sensitivity_kg_per_N
    # vectorised, and the originals are unchanged (immutable)
    np.testing.assert_allclose(adjusted.mass_kg(np.array([f0, f_ref])), [0.0, 0.1], atol=1e-16)
    assert cal.zero_force_N == 0.0
    with pytest.raises(Exception):
        cal.zero_force_N = 1.0


def test_calibration_uncertainty_propagation():
    f0, f_ref, m_ref = 0.2, 0.2 - 0.13, 0.1
    u0, u_ref_force, u_ref_mass = 3e-8, 4e-8, 5e-9
    cal = WeighingCalibration(S_NOMINAL).zeroed(f0, u0)
    cal = cal.adjusted(f_ref, m_ref, u_ref_force, u_ref_mass)
    s = m_ref / (f_ref - f0)
    u_rel = math.sqrt((u_ref_force ** 2 + u0 ** 2) / 0.13 ** 2 + (u_ref_mass / m_ref) ** 2)
    assert cal.sensitivity_u_relative == pytest.approx(u_rel, rel=1e-12)
    # at the zero only the zero mean contributes; at the reference both
    assert cal.standard_uncertainty_kg(f0) == pytest.approx(abs(s) * u0, rel=1e-12)
    assert cal.standard_uncertainty_kg(f_ref) == pytest.approx(
        math.hypot(abs(s) * u0, m_ref * u_rel), rel=1e-12)
    tared = cal.tared(0.15, 2e-8)
    assert tared.tare_u_kg == pytest.approx(abs(s) * 2e-8, rel=1e-12)
    assert tared.standard_uncertainty_kg(f0) == pytest.approx(
        math.hypot(abs(s) * u0, abs(s) * 2e-8), rel=1e-12)
    assert WeighingCalibration(S_NOMINAL).standard_uncertainty_kg(0.3) == 0.0


@pytest.mark.parametrize('call, match', [
    (lambda c: c.zeroed(float('nan')), 'mean_force_N: need a finite number'),
    (lambda c: c.tared(float('inf')), 'mean_force_N: need a finite number'),
    (lambda c: c.adjusted(0.1, 0.0), 'reference_mass_kg: the reference weight must be > 0'),
    (lambda c: c.adjusted(0.1, -0.1), 'reference_mass_kg'),
    (lambda c: c.adjusted(0.2, 0.1), 'equals the zero force'),
    (lambda c: c.adjusted(0.3, 0.1), 'wrong direction'),
    (lambda c: c.adjusted(0.1, float('nan')), 'reference_mass_kg: need a finite'),
    (lambda c: c.zeroed(0.1, -1e-9), 'force_u_N: a standard uncertainty must be >= 0'),
    (lambda c: c.adjusted(0.1, 0.1, reference_mass_u_kg=-1.0), 'reference_mass_u_kg'),
    (lambda c: WeighingCalibration(0.0), 'sensitivity_kg_per_N: must be non-zero'),
    (lambda c: WeighingCalibration(S_NOMINAL, zero_force_N='x'), 'zero_force_N'),
])
def test_calibration_errors(call, match):
    cal = WeighingCalibration(S_NOMINAL, zero_force_N=0.2)
    with pytest.raises(WeighingError, match=match) as info:
        call(cal)
    assert isinstance(info.value, ValueError)
