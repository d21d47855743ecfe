"""
Nonlinear two-beam mechanics: energy, virtual work, equilibria and load-dependent mass.

Energy and power are computed here from the point positions of the geometry, independently of
the mass matrix and Coriolis terms of the implementation.
"""

from dataclasses import replace

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from emfc_ros.core.model import (equilibrium, hold_at, lever_position_m, linearise, loaded,
                                 MechanicalParameters, pan_mass_kg, rest_position,
                                 state_derivative)
from emfc_ros.core.model.mechanics import coriolis_matrix, mass_matrix

MECH = MechanicalParameters()
ASYM = replace(MECH, h1_m=0.004, h2_m=-0.003, F_off_N=0.02)


def _rot(q, v):
    c, s = np.cos(q), np.sin(q)
    return np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def _points(q, p):
    """Return positions of the mass points and centres of mass (x, z) [m]."""
    joint = _rot(q[0], (p.l2_m, 0.0))
    return {
        'cm1': _rot(q[0], (p.r1_m, p.h1_m)),
        'pan': _rot(q[0], (-p.l1_m, 0.0)),
        'cm2': joint + _rot(q[1], (p.r2_m, p.h2_m)),
        'coil': joint + _rot(q[1], (p.l3_m, 0.0)),
    }


def _energy(x, p):
    q, qd = x[:2], x[2:]
    h = 1.0e-6
    pts = _points(q, p)
    plus, minus = _points(q + h * qd, p), _points(q - h * qd, p)
    vel = {k: (plus[k] - minus[k]) / (2 * h) for k in pts}
    masses = {'cm1': p.m1_kg, 'pan': p.mp_kg, 'cm2': p.m2_kg, 'coil': p.m3_kg}
    kinetic = 0.5 * (p.J1c_kgm2 * qd[0] ** 2 + p.J2c_kgm2 * qd[1] ** 2)
    kinetic += sum(0.5 * masses[k] * vel[k] @ vel[k] for k in pts)
    potential = p.g_m_per_s2 * sum(masses[k] * pts[k][1] for k in pts)
    potential += 0.5 * p.c1_Nm_per_rad * q[0] ** 2 + 0.5 * p.c2_Nm_per_rad * (q[1] - q[0]) ** 2
    return kinetic + potential


def test_energy_is_conserved_without_damping_and_forces():
    p = replace(ASYM, d1_Nms_per_rad=0.0, d2_Nms_per_rad=0.0, F_off_N=0.0, c2_Nm_per_rad=0.5)
    x0 = np.array([0.3, -0.5, 4.0, -6.0])
    t = np.linspace(0.0, 0.5, 11)
    sol = solve_ivp(lambda t, x: state_derivative(x, 0.0, 0.0, p), (0.0, 0.5), x0,
                    method='DOP853', rtol=1e-12, atol=1e-13, t_eval=t)
    energies = np.array([_energy(x, p) for x in sol.y.T])
    kinetic = np.array([_energy(x, replace(p, g_m_per_s2=0.0, c1_Nm_per_rad=0.0,
                                           c2_Nm_per_rad=0.0)) for x in sol.y.T])
    # the motion trades a sizeable share of the energy, which a wrong Coriolis term would break
    assert np.ptp(kinetic) > 0.1 * kinetic.max()
    assert np.abs(energies - energies[0]).max() < 1e-6 * kinetic.max()


def test_mass_matrix_from_kinetic_energy_and_skew_property():
    q = np.array([0.2, -0.4])
    qd = np.array([1.5, -2.5])
    mass = mass_matrix(q, ASYM)
    p0 = replace(ASYM, g_m_per_s2=0.0, c1_Nm_per_rad=0.0, c2_Nm_per_rad=0.0)
    x = np.concatenate([q, qd])
    assert 0.5 * qd @ mass @ qd == pytest.approx(_energy(x, p0), rel=1e-9)
    assert np.all(np.linalg.eigvalsh(mass) > 0.0)
    h = 1.0e-7
    mdot = (mass_matrix(q + h * qd, ASYM) - mass_matrix(q - h * qd, ASYM)) / (2 * h)
    skew = mdot - 2.0 * coriolis_matrix(q, qd, ASYM)
    np.testing.assert_allclose(skew + skew.T, 0.0, atol=1e-9 * np.abs(mdot).max())


def test_generalised_forces_do_the_virtual_work_of_vertical_forces():
    """
    Check the power of Q against the vertical forces.

    ``Q q'`` must equal ``(F_c + F_off)`` times the lever end's upward speed plus ``F_p`` times
    the pan's downward speed.
    """
    p = ASYM
    q = np.array([0.1, -0.3])
    qd = np.array([0.7, 1.9])
    f_c, f_p = 0.37, -0.21
    x = np.concatenate([q, qd])
    # isolate Q: difference of the accelerations with and without the forces
    qdd_f = state_derivative(x, f_c, f_p, p)[2:]
    qdd_0 = state_derivative(x, -p.F_off_N, 0.0, p)[2:]
    power_q = qd @ (mass_matrix(q, p) @ (qdd_f - qdd_0))
    h = 1.0e-7
    up, down = _points(q + h * qd, p), _points(q - h * qd, p)
    coil_up = (up['coil'][1] - down['coil'][1]) / (2 * h)
    pan_down = -(up['pan'][1] - down['pan'][1]) / (2 * h)
    assert power_q == pytest.approx((f_c + p.F_off_N) * coil_up + f_p * pan_down, rel=1e-7)


def test_output_is_lever_end_height():
    q = np.array([0.01, -0.02])
    assert lever_position_m(q, ASYM) == pytest.approx(_points(q, ASYM)['coil'][1], rel=1e-14)
    assert lever_position_m(np.concatenate([q, [5.0, 6.0]]), ASYM) == lever_position_m(q, ASYM)


@pytest.mark.parametrize('load_kg, coupled, f_off, f_p', [
    (0.0, False, None, 0.0), (0.0, True, None, 0.0), (0.1, False, None, 0.0),
    (0.5, False, 0.05, 0.0), (0.02, True, -0.1, 0.03),
])
def test_equilibrium_is_at_rest_at_y0(load_kg, coupled, f_off, f_p):
    op = equilibrium(MECH, load_mass_kg=load_kg, load_changer_coupled=coupled, F_off_N=f_off,
                     F_p_N=f_p)
    assert op.mechanics.mp_kg == pytest.approx(pan_mass_kg(MECH, load_kg, coupled))
    assert abs(op.y_m) < 1e-18
    xdot = state_derivative(op.x, op.F_c_N, op.F_p_N, op.mechanics)
    # scale: the acceleration gravity alone would cause
    scale = np.abs(np.linalg.solve(mass_matrix(np.zeros(2), op.mechanics),
                                   [op.mechanics.g_m_per_s2 * op.mechanics.m3_kg
                                    * op.mechanics.l3_m] * 2)).max()
    assert np.abs(xdot).max() < 1e-12 * scale


def test_equilibrium_at_nonzero_position_and_rest_position_agree():
    op = equilibrium(MECH, load_mass_kg=0.05, y_m=20e-6)
    assert op.y_m == pytest.approx(20e-6, rel=1e-12)
    back = rest_position(MECH, op.F_c_N, load_mass_kg=0.05)
    np.testing.assert_allclose(back.q_rad, op.q_rad, rtol=1e-9)
    xdot = state_derivative(back.x, back.F_c_N, back.F_p_N, back.mechanics)
    assert np.abs(xdot).max() < 1e-9


def test_rest_position_follows_static_gain_for_small_forces():
    op = equilibrium(MECH)
    gain = linearise(MECH).static_gain_m_per_N('coil')
    df = 1.0e-5  # about 0.8 um of travel
    moved = rest_position(MECH, op.F_c_N + df)
    assert moved.y_m / df == pytest.approx(gain, rel=1e-3)


def test_hold_at_zero_balances_gravity():
    op = hold_at(MECH)
    xdot = state_derivative(op.x, op.F_c_N, op.F_p_N, op.mechanics)
    assert np.abs(xdot).max() < 1e-10


def test_load_adds_to_pan_mass_and_refuses_negative_load():
    assert loaded(MECH, 0.1, True).mp_kg == pytest.approx(0.060 + 0.1 + 0.025)
    assert loaded(MECH).mp_kg == MECH.mp_kg
    with pytest.raises(ValueError, match='load_mass_kg'):
        loaded(MECH, -0.001)
