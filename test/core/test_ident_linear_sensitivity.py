"""
The grey-box's Jacobian from the linearised model against the simulation it stands in for.

``BalanceGreyboxModel.output_derivatives`` (``linear_sensitivity.py``) on the 10-second
trajectory of a balance drawn off the defaults (a test seed): every column within 0.1 % of the
central difference of the nonlinear simulation, the RK4 map equal to the simulator's step on a
linear system, and the interpreted fallback's time estimate proportional to the samples.
"""

import numpy as np
import pytest

from emfc_ros.core.ident.balance_experiment import balancing_mass_kg, simulate_experiment
from emfc_ros.core.ident.balance_fit import expected_simulations, interpreted_estimate_s
from emfc_ros.core.ident.balance_greybox import (BalanceGreyboxModel, mass_matrix_entries,
                                                 REST_POSITION)
from emfc_ros.core.ident.linear_sensitivity import rk4_map
from emfc_ros.core.ident.offnominal import draw_balance, TEST_SEEDS
from emfc_ros.core.paths import config_file
from emfc_ros.core.signals import load_experiment_file

NAMES = ('c1_Nm_per_rad', 'd1_Nms_per_rad', 'c2_Nm_per_rad', 'd2_Nms_per_rad', 'M11_kgm2',
         'M12_kgm2', 'M22_kgm2', REST_POSITION)


@pytest.fixture(scope='module')
def model():
    balance = draw_balance(TEST_SEEDS[1])
    load = balancing_mass_kg(balance, True)
    rec = simulate_experiment(balance, load_experiment_file(config_file(
        'quick_trajectory.yaml')), seed=3, load_mass_kg=load, load_changer_coupled=True)
    u = np.column_stack([rec.channels['coil_setpoint_V'],
                         rec.channels['load_changer_setpoint_V']])
    m = BalanceGreyboxModel(balance, rec.sample_rate_Hz, u, load, True)
    mech = balance.mechanics
    entries = mass_matrix_entries(mech, load, True)
    values = {n: float(getattr(mech, n)) for n in NAMES[:4]}
    values.update(zip(NAMES[4:7], (float(e) for e in entries)))
    values[REST_POSITION] = 2.0e-6
    return m, values


def test_columns_match_the_simulations_central_differences(model):
    m, values = model
    d = m.output_derivatives(values, NAMES, m.setpoints_V)
    assert d.shape == (m.setpoints_V.shape[0], len(NAMES))
    for k, name in enumerate(NAMES):
        h = 1e-5 * (abs(values[name]) or 1.0) if name != REST_POSITION else 1e-9
        up = m.simulate_record(dict(values, **{name: values[name] + h}))
        down = m.simulate_record(dict(values, **{name: values[name] - h}))
        exact = (up - down) / (2.0 * h)
        difference = np.linalg.norm(d[:, k] - exact) / np.linalg.norm(exact)
        assert difference < 1e-3, (name, difference)


def test_sections_are_slices_and_other_inputs_are_refused(model):
    m, values = model
    whole = m.output_derivatives(values, NAMES[:2], m.setpoints_V)
    part = m.output_derivatives(values, NAMES[:2], m.setpoints_V[1000:3000])
    np.testing.assert_array_equal(part, whole[1000:3000])
    assert m.output_derivatives(values, NAMES[:2], m.setpoints_V[:10].copy()) is None


def test_rk4_map_is_one_rk4_step_of_a_linear_system():
    rng = np.random.default_rng(5)
    a = rng.standard_normal((4, 4)) * 50.0
    b = rng.standard_normal((4, 2))
    x, w, h = rng.standard_normal(4), rng.standard_normal(2), 1e-3

    def f(x):
        return a @ x + b @ w

    k1 = f(x)
    k2 = f(x + h / 2 * k1)
    k3 = f(x + h / 2 * k2)
    k4 = f(x + h * k3)
    step = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    phi, gamma = rk4_map(a, b, h)
    np.testing.assert_allclose(phi @ x + gamma @ w, step, rtol=1e-12, atol=1e-12)
    phi2, gamma2 = rk4_map(a, b, 2 * h, substeps=2)
    np.testing.assert_allclose(phi2 @ x + gamma2 @ w, phi @ (phi @ x + gamma @ w) + gamma @ w,
                               rtol=1e-12, atol=1e-12)


def test_interpreted_estimate_is_measured_on_a_short_block(model):
    m, values = model
    slow = BalanceGreyboxModel(m.params, m.sample_rate_Hz, m.setpoints_V, m.load_mass_kg,
                               True, backend='numpy')
    before = slow.n_simulations
    one = interpreted_estimate_s(slow, values, 1, probe_samples=500)
    assert np.isfinite(one) and one > 0.0
    assert slow.n_simulations == before         # a probe, not a record simulation
    assert expected_simulations('least_squares', 8) > expected_simulations('gauss_newton', 8)


def test_without_numba_the_fit_says_how_long_first(model, monkeypatch):
    """The interpreted fallback: the estimate is reported before the first simulation."""
    from emfc_ros.core.ident import balance_fit
    from emfc_ros.core.ident.offnominal import record_draw
    from emfc_ros.core.ident.pipeline import identify

    rec = record_draw(draw_balance(TEST_SEEDS[1]), 3, experiment=load_experiment_file(
        config_file('quick_trajectory.yaml')))
    monkeypatch.setattr(balance_fit, 'resolved_backend', lambda backend: 'numpy')
    monkeypatch.setattr(balance_fit, 'interpreted_estimate_s',
                        lambda model, values, count, probe_samples=2000: 600.0 * count / 12)
    messages = []
    options = rec.options(('coil_chirp', 'load_changer_chirp'))
    options.update({'static': {'enabled': False}, 'frf': {'two_input_sections': []}})
    res = identify(rec.recording, rec.section_table, options,
                   progress=lambda step, fraction, text: messages.append(text))
    said = [i for i, text in enumerate(messages) if 'runs interpreted' in text]
    simulated = [i for i, text in enumerate(messages) if text.endswith('simulations')]
    assert said, messages
    assert 'about 10 min' in messages[said[0]] and 'pip install numba' in messages[said[0]]
    assert not simulated or said[0] < simulated[0]
    assert any('runs interpreted' in w for w in res.warnings)
