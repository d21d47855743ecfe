"""Peripheral characteristics of Table 1: inverses and the notes' sanity figures."""

from hypothesis import given, settings, strategies as st
import numpy as np
import pytest

from emfc_ros.core.model import (Amplifier, BalanceParameters, LoadChanger, MotorCoefficient,
                                 PositionSensor)
from emfc_ros.core.model.peripherals import poly_inverse

RTOL = 1e-12


def _assert_round_trip(x, back, full_scale):
    np.testing.assert_allclose(back, x, rtol=RTOL, atol=RTOL * full_scale)


def test_amplifier_round_trip_and_full_scale():
    amp = Amplifier()
    u = np.linspace(-10.0, 10.0, 2001)
    current = amp.current_A(u)
    _assert_round_trip(u, amp.voltage_V(current), 10.0)
    _assert_round_trip(current, amp.current_A(amp.voltage_V(current)), 0.1)
    # +/-10 V gives about +/-100 mA, nonlinearity about 0.7 % of full scale
    assert amp.current_A(10.0) == pytest.approx(0.1, rel=0.01)
    assert amp.current_A(-10.0) == pytest.approx(-0.1, rel=0.01)
    nonlinearity = np.abs(current - (amp.coeffs_A_per_V_pow[0] + 0.010 * u)).max() / 0.1
    assert nonlinearity == pytest.approx(0.007, abs=0.0005)


def test_motor_coefficient_uses_millimetres_and_inverts():
    motor = MotorCoefficient()
    assert motor.coefficient_N_per_A(0.0) == pytest.approx(21.692)
    # y in mm: at 100 um the coefficient changes by about 0.012 * 0.1 N/A only
    assert motor.coefficient_N_per_A(100e-6) == pytest.approx(
        21.692 + 0.012 * 0.1 - 5.273e-3 * 0.01, rel=1e-14)
    y = np.linspace(-150e-6, 150e-6, 31)[:, None]
    current = np.linspace(-0.1, 0.1, 41)[None, :]
    force = motor.force_N(current, y)
    assert force.shape == (31, 41)
    _assert_round_trip(np.broadcast_to(current, force.shape), motor.current_A(force, y), 0.1)


def test_sensor_round_trip_and_linear_term_dominates():
    sensor = PositionSensor()
    assert sensor.coeffs_V_per_m_pow[1] == 5.0e4
    y = np.linspace(-100e-6, 100e-6, 4001)
    volts = sensor.voltage_V(y)
    _assert_round_trip(y, sensor.position_m(volts), 100e-6)
    _assert_round_trip(volts, sensor.voltage_V(sensor.position_m(volts)), 5.0)
    assert sensor.voltage_V(100e-6) == pytest.approx(5.0, rel=0.03)
    linear = 5.0e4 * 100e-6
    for k, c in enumerate(sensor.coeffs_V_per_m_pow[2:], start=2):
        assert abs(c) * 100e-6 ** k < 0.025 * linear, f'term y^{k} too large'
    assert np.all(np.diff(volts) > 0.0)
    assert isinstance(sensor.position_m(1.0), float)


def test_load_changer_round_trip_and_constant():
    lc = LoadChanger()
    current = np.linspace(-0.1, 0.1, 201)
    _assert_round_trip(current, lc.current_A(lc.force_N(current)), 0.1)
    assert lc.force_N(0.0) == pytest.approx(3.982e-4)
    assert lc.force_N(1.0) - lc.force_N(0.0) == pytest.approx(-0.904)


@settings(max_examples=200, deadline=None)
@given(st.floats(-10.0, 10.0), st.floats(-100e-6, 100e-6))
def test_inverses_property(u_v, y_m):
    params = BalanceParameters()
    amp, sensor = params.coil_amplifier, params.sensor
    assert amp.voltage_V(amp.current_A(u_v)) == pytest.approx(u_v, rel=RTOL, abs=RTOL * 10.0)
    assert sensor.position_m(sensor.voltage_V(y_m)) == pytest.approx(y_m, rel=RTOL,
                                                                     abs=RTOL * 100e-6)


def test_inverse_refuses_non_monotonic_region():
    # U = y + y^2 has its minimum -1/4 at y = -1/2: U = -1 has no real solution
    with pytest.raises(ValueError, match='converge'):
        poly_inverse([0.0, 1.0, 1.0], -1.0)
