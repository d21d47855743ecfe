"""
Linear model of the balance: the notes' poles, zeros and gains, and analytic vs numeric Jacobians.

The notes' figures are rounded to the digits they print, so each is compared within 0.1 % or
half a unit of its last printed digit, whichever is larger (see :func:`assert_printed`).
"""

from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from emfc_ros.core.model import (equilibrium, finite_difference_jacobians, hold_at,
                                 jacobians, linearise, loaded, MechanicalParameters)
from emfc_ros.core.model.summary import format_summaries, main, notes_summaries, summarize


def assert_printed(actual, printed):
    """Compare with a figure printed as ``printed`` (0.1 % or half its last digit)."""
    digits = len(printed.split('.')[1]) if '.' in printed else 0
    expected = float(printed)
    tol = max(1.0e-3 * abs(expected), 0.5 * 10.0 ** -digits)
    assert abs(actual - expected) <= tol, f'{actual} vs printed {printed} (tol {tol})'


def modes(roots):
    """Return (frequency_Hz, damping) of the roots with non-negative imaginary part."""
    return [(r.frequency_Hz, r.damping_ratio) for r in roots if r.s_rad_per_s.imag >= 0.0]


MECH = MechanicalParameters()


@pytest.mark.parametrize('load_kg, coupled, low, high, zero', [
    (0.0, False, '3.78', '410.0', '353.8'),
    (0.0, True, '3.74', '395.6', '338.0'),
    (0.1, False, '3.64', '362.5', '301.0'),
])
def test_poles_and_coil_zeros_match_notes(load_kg, coupled, low, high, zero):
    model = linearise(loaded(MECH, load_kg, coupled))
    poles = modes(model.poles())
    assert len(poles) == 2 and len(model.poles()) == 4
    assert_printed(poles[0][0], low)
    assert_printed(poles[1][0], high)
    coil = model.zeros('coil')
    assert len(coil) == 2 and not coil[0].is_real
    assert coil[0].s_rad_per_s == pytest.approx(np.conj(coil[1].s_rad_per_s))
    assert_printed(coil[0].frequency_Hz, zero)
    assert 0.0 < coil[0].damping_ratio < poles[1][1]  # notch just below the peak
    # pan input: real pair, unchanged by the pan mass
    pan = sorted(r.signed_frequency_Hz for r in model.zeros('pan'))
    assert all(r.is_real for r in model.zeros('pan'))
    assert_printed(pan[0], '-1100')
    assert_printed(pan[1], '1191')


def test_empty_pan_damping_ratios():
    poles = modes(linearise(MECH).poles())
    assert_printed(poles[0][1], '0.050')
    assert_printed(poles[1][1], '0.016')


def test_coil_magnitude_and_static_gains_match_notes():
    model = linearise(MECH)
    mag = model.frequency_response([0.1, 1.0, 10.0, 100.0, 1000.0], 'coil').magnitude_dB
    for value, printed in zip(mag, ['-21.8', '-21.2', '-37.4', '-78.9', '-115.7']):
        assert_printed(value, printed)
    assert_printed(20.0 * np.log10(model.static_gain_m_per_N('pan')), '-39.3')
    # about 12 N/m at the coil; 1 g on the pan moves the lever end about 100 um
    assert 1.0 / model.static_gain_m_per_N('coil') == pytest.approx(12.3, abs=0.1)
    assert model.static_gain_m_per_N('pan') * 1.0e-3 * MECH.g_m_per_s2 == pytest.approx(
        1.06e-4, rel=0.01)


def test_static_force_ratio_differs_from_lever_ratio():
    s = summarize(MECH)
    assert_printed(s.static_force_ratio, '0.13326')
    assert MECH.l1_m / (MECH.l2_m + MECH.l3_m) == pytest.approx(0.13333, abs=5e-6)


def test_static_force_ratio_from_nonlinear_equilibria():
    """The compensation force per pan weight of the full model reproduces 0.13326."""
    w = 1.0e-3 * MECH.g_m_per_s2
    f0 = equilibrium(MECH).F_c_N
    f1 = equilibrium(MECH, load_mass_kg=1.0e-3).F_c_N
    # coil force is positive upward, the load pulls the lever end up: compensation is negative
    assert_printed(-(f1 - f0) / w, '0.13326')


@pytest.mark.filterwarnings('ignore::scipy.signal.BadCoefficients')
def test_frequency_response_agrees_with_scipy_signal():
    # scipy goes through transfer-function polynomials (and warns about their conditioning)
    model = linearise(MECH)
    f = np.array([0.5, 3.78, 50.0, 353.8, 410.0, 2000.0])
    for j, name in enumerate(('coil', 'pan')):
        ss = signal.StateSpace(model.A, model.B[:, [j]], model.C, model.D[:, [j]])
        _, ref = signal.freqresp(ss, 2.0 * np.pi * f)
        ours = model.frequency_response(f, name).response_m_per_N
        np.testing.assert_allclose(ours, ref, rtol=1e-6)


def test_zero_at_q0_matches_notes_matrices():
    """The analytic model at q = 0 equals the notes' closed-form A and B."""
    p = MECH
    g = p.g_m_per_s2
    m12 = p.l2_m * (p.m3_kg * p.l3_m + p.m2_kg * p.r2_m)
    mass = np.array([[p.J1_kgm2 + p.mp_kg * p.l1_m ** 2 + (p.m2_kg + p.m3_kg) * p.l2_m ** 2,
                      m12], [m12, p.J2_kgm2 + p.m3_kg * p.l3_m ** 2]])
    damp = np.array([[p.d1_Nms_per_rad + p.d2_Nms_per_rad, -p.d2_Nms_per_rad],
                     [-p.d2_Nms_per_rad, p.d2_Nms_per_rad]])
    stiff = np.array([[p.c1_Nm_per_rad + p.c2_Nm_per_rad - g * p.m1_kg * p.h1_m,
                       -p.c2_Nm_per_rad],
                      [-p.c2_Nm_per_rad, p.c2_Nm_per_rad - g * p.m2_kg * p.h2_m]])
    bq = np.array([[p.l2_m, p.l1_m], [p.l3_m, 0.0]])
    a = np.block([[np.zeros((2, 2)), np.eye(2)],
                  [-np.linalg.solve(mass, stiff), -np.linalg.solve(mass, damp)]])
    b = np.vstack([np.zeros((2, 2)), np.linalg.solve(mass, bq)])
    model = linearise(p)
    np.testing.assert_allclose(model.A, a, rtol=1e-12, atol=1e-12 * np.abs(a).max())
    np.testing.assert_allclose(model.B, b, rtol=1e-12)
    np.testing.assert_allclose(model.C, [[p.l2_m, p.l3_m, 0.0, 0.0]])


def _assert_jacobians_match(mech, x, u):
    analytic = jacobians(mech, x, u)
    numeric = finite_difference_jacobians(mech, x, u)
    for name, a, f in zip('ABCD', analytic, numeric):
        scale = np.abs(a).max()
        np.testing.assert_allclose(f, a, rtol=1e-6, atol=1e-9 * scale + 1e-300,
                                   err_msg=f'matrix {name}')


def test_analytic_jacobians_match_finite_differences_at_q0():
    op = hold_at(MECH, (0.0, 0.0))
    _assert_jacobians_match(op.mechanics, op.x, op.u)


@pytest.mark.parametrize('load_kg, coupled, f_off', [(0.1, False, 0.0), (0.0, True, -0.05),
                                                     (0.3, False, 0.2)])
def test_analytic_jacobians_match_finite_differences_at_equilibrium(load_kg, coupled, f_off):
    op = equilibrium(MECH, load_mass_kg=load_kg, load_changer_coupled=coupled, F_off_N=f_off)
    assert np.abs(op.q_rad).max() > 1.0e-5  # a genuinely non-zero operating point
    _assert_jacobians_match(op.mechanics, op.x, op.u)


def test_analytic_jacobians_match_finite_differences_off_equilibrium():
    """Large angles, velocities and unbalanced forces: every term of the Jacobian matters."""
    mech = loaded(MECH.__class__(h1_m=0.003, h2_m=-0.002, F_off_N=0.01), 0.05, True)
    x = np.array([0.05, -0.2, 3.0, -7.0])
    _assert_jacobians_match(mech, x, np.array([0.3, -0.4]))


def test_linearise_at_equilibrium_keeps_notes_poles():
    """Linearising at the true y = 0 equilibrium hardly moves the poles (tiny geometry)."""
    op = equilibrium(MECH, load_mass_kg=0.1)
    at_op = modes(linearise(op.mechanics, op).poles())
    at_zero = modes(linearise(op.mechanics).poles())
    np.testing.assert_allclose(np.array(at_op), np.array(at_zero), rtol=1e-5)


def test_summary_table_prints_three_configurations():
    text = format_summaries(notes_summaries())
    assert text.count('\n| ') == 3  # one row per configuration below the header
    assert '410.00 Hz' in text and '353.85 Hz' in text and '-1100.2 Hz (real)' in text


def test_summary_command_reads_the_shipped_yaml(capsys):
    yaml_path = Path(__file__).resolve().parents[2] / 'config' / 'balance_default.yaml'
    assert main(['--config', str(yaml_path)]) == 0
    out = capsys.readouterr().out
    assert '3.78 Hz (zeta 0.0500), 410.00 Hz (zeta 0.0159)' in out
    assert '-21.8 / -21.2 / -37.4 / -78.9 / -115.7 dB' in out
