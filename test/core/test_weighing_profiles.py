"""Tests of the load profiles and the load-changer setpoints against hand computations."""

import math

import numpy as np
import pytest

from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.weighing import (check_weigher_pulse, load_changer_setpoints_V, step,
                                    trapezoid, WeighingError)

FS = 1000.0


def test_step():
    m = step(FS, 2.0, 0.5, 0.1, initial_mass_kg=0.02)
    assert m.size == 2000
    assert np.all(m[:500] == 0.02) and np.all(m[500:] == 0.1)
    with pytest.raises(WeighingError, match='step_time_s'):
        step(FS, 1.0, -0.1, 0.1)
    with pytest.raises(WeighingError, match='duration_s'):
        step(FS, 0.0, 0.1, 0.1)


def test_trapezoid_levels_and_durations():
    m = trapezoid(FS, 0.05, rise_s=0.2, hold_s=0.3, fall_s=0.1, start_s=0.1, end_s=0.4,
                  base_mass_kg=0.01)
    assert m.size == 1100
    t = np.arange(m.size) / FS
    assert np.all(m[t <= 0.1] == 0.01)
    np.testing.assert_allclose(m[200], 0.01 + 0.05 * 0.5, rtol=1e-14)   # mid-rise, t = 0.2 s
    np.testing.assert_allclose(m[(t >= 0.3) & (t <= 0.6)], 0.06, rtol=1e-14)
    np.testing.assert_allclose(m[650], 0.01 + 0.05 * 0.5, rtol=1e-14)   # mid-fall, t = 0.65 s
    assert np.all(m[t >= 0.7] == 0.01)
    # area above the base: mass times (hold + (rise + fall) / 2)
    np.testing.assert_allclose(np.sum(m - 0.01) / FS, 0.05 * (0.3 + 0.15), rtol=1e-12)
    stepped = trapezoid(FS, 0.1, 0.0, 0.2, 0.0, start_s=0.1, end_s=0.1)
    assert np.count_nonzero(stepped == 0.1) == 200 and stepped.size == 400


def test_check_weigher_pulse():
    m = check_weigher_pulse(FS, 0.2, duration_s=0.5, ramp_s=0.1, lead_s=0.2, tail_s=0.3)
    assert m.size == 1000
    t = np.arange(m.size) / FS
    full = m == 0.2
    # fully on from 0.3 s to 0.6 s inclusive
    np.testing.assert_allclose([t[full][0], t[full][-1]], [0.3, 0.6], atol=1e-12)
    on_pan = m > 0.0
    np.testing.assert_allclose([t[on_pan][0], t[on_pan][-1]], [0.201, 0.699], atol=1e-12)
    np.testing.assert_allclose(np.sum(m) / FS, 0.2 * (0.5 - 0.1), rtol=1e-12)
    with pytest.raises(WeighingError, match='shorter than the two ramps'):
        check_weigher_pulse(FS, 0.2, duration_s=0.1, ramp_s=0.06)


def test_load_changer_setpoints_map_back_to_m_g():
    params = BalanceParameters()
    masses = trapezoid(FS, 0.008, 0.1, 0.1, 0.1, 0.05, 0.05, base_mass_kg=-0.001)
    volts = load_changer_setpoints_V(masses, params)
    force = params.load_changer.force_N(params.load_changer_amplifier.current_A(volts))
    np.testing.assert_allclose(force, masses * 9.81, rtol=1e-9, atol=1e-15)


def test_load_changer_setpoint_by_hand():
    params = BalanceParameters()
    force = 0.005 * 9.81
    current = (force - 3.982e-4) / -0.904
    a, b, c = -6.964e-6, 0.010, 7.552e-6 - current
    volts = (-b + math.sqrt(b * b - 4 * a * c)) / (2 * a)
    np.testing.assert_allclose(load_changer_setpoints_V(0.005, params), volts, rtol=1e-12)
    assert volts < 0.0  # negative force coefficient: a positive force needs negative volts
    # zero mass is not zero volts: the setpoint cancels the 0.398 mN offset
    zero = float(load_changer_setpoints_V(0.0, params))
    assert zero == pytest.approx((3.982e-4 / 0.904 - 7.552e-6) / 0.010, rel=1e-4)


def test_load_changer_limits():
    params = BalanceParameters()
    with pytest.raises(WeighingError, match='reaches'):
        load_changer_setpoints_V(np.array([0.0, 0.01]), params)   # 0.108 A > 0.1 A
    with pytest.raises(WeighingError, match='non-finite'):
        load_changer_setpoints_V([np.nan], params)
