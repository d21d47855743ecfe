"""
A user's own experiment (issue 28 item 3): a plan that starts at a non-zero setpoint.

The shipped trajectory starts each section at 0 V, where the balance rested; a PRBS starts at
one of its levels, so the balance steps at sample 0 and rings at its low mode for seconds.
The grey-box simulation started at rest under the first setpoints: the right model fitted
such a section to 22 % and the identification failed. It now starts at rest under
``greybox.initial_setpoints_V`` (0 V) and estimates what is left of the initial state
(``emfc_ros.core.ident.initial_state``). A drawn off-nominal balance (a test seed),
identified knowing only the pan load and the coupling.
"""

import copy

import numpy as np
import pytest
import yaml

from emfc_ros.core.ident.initial_state import correct_record, free_response_basis
from emfc_ros.core.ident.offnominal import (draw_balance, MULTISINE_SECTION, PRBS_SECTION,
                                            RANDOM_SECTION, record_draw, relative_error,
                                            TEST_SEEDS, truth_values, unit_experiment)
from emfc_ros.core.ident.pipeline import identify
from emfc_ros.core.model.linear import linearise
from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.paths import config_file
from emfc_ros.core.signals import experiment_from_config, find_experiment_mapping


def prbs_first_plan():
    """
    The shipped trajectory with its first section a user's PRBS on the coil.

    +/-2.5 mV (the chirp's amplitude), bits of 0.5 ms: it starts at +2.5 mV, where the
    balance, resting at 0 V, steps.
    """
    doc = yaml.safe_load(config_file('identification_trajectory.yaml').read_text())
    plan = copy.deepcopy(find_experiment_mapping(doc))
    plan['sections'][0] = 'coil_prbs'
    del plan['section']['coil_chirp']
    plan['section']['coil_prbs'] = {'duration_s': 10.0, 'coil': {'signals': {'p': {
        'type': 'prbs', 'order': 14, 'hold_samples': 5, 'low_V': -0.0025,
        'high_V': 0.0025}}}}
    return plan


def assert_mechanics_within_targets(res, rec):
    """c1, c2 within 2 % and d1, d2 within 10 % of the drawn truth (issue 12's targets)."""
    got = res.greybox.fit.parameters
    truth = truth_values(rec.truth)
    errors = {n: relative_error(got[n], truth[n]) for n in
              ('c1_Nm_per_rad', 'c2_Nm_per_rad', 'd1_Nms_per_rad', 'd2_Nms_per_rad')}
    assert all(abs(errors[n]) <= 0.02 for n in ('c1_Nm_per_rad', 'c2_Nm_per_rad')), errors
    assert all(abs(errors[n]) <= 0.10 for n in ('d1_Nms_per_rad', 'd2_Nms_per_rad')), errors


def test_the_free_response_basis_is_the_linear_models_own():
    lin = linearise(loaded(BalanceParameters().mechanics, 0.1274, False))
    fs = 10000.0
    basis = free_response_basis(lin.A, lin.C[0], fs, 50000)
    # one step of the discretised model, by hand
    from scipy.linalg import expm
    a_d = expm(lin.A / fs)
    dx = np.array([1e-5, -2e-5, 3e-4, 1e-4])
    x, y = dx.copy(), []
    for _ in range(200):
        y.append(lin.C[0] @ x)
        x = a_d @ x
    np.testing.assert_allclose(basis[:200] @ dx, y, rtol=1e-9, atol=1e-18)
    # a record with a known initial deviation added: estimated back, the error removed
    rng = np.random.default_rng(3)
    sim = 1e-6 * rng.standard_normal(80000)
    measured = sim.copy()
    measured[:basis.shape[0]] += basis @ dx
    measured += 1e-9 * rng.standard_normal(measured.size)
    spans = [(0, 30000), (30000, 50000)]
    out, state = correct_record(lin.A, lin.C[0], fs, measured, sim, spans)
    # the free response it gives is the one added (the fast mode's rate is barely seen in a
    # position sampled at 10 kHz: the state itself is not the point)
    np.testing.assert_allclose(basis @ state.deviation, basis @ dx, atol=2e-9)
    assert state.position_m == pytest.approx(basis[0] @ dx, abs=2e-9)
    assert state.rms_after_m < 1e-8 < state.rms_before_m
    np.testing.assert_allclose(out - measured, 0.0, atol=1e-8)


@pytest.mark.slow
@pytest.mark.parametrize('initial', [[0.0, 0.0], None], ids=['rest_at_0V', 'rest_unknown'])
def test_a_plan_that_starts_at_a_non_zero_setpoint_identifies(initial):
    """
    Off-nominal balance, PRBS first: the parameters and every section's fit as with chirps.

    ``rest_at_0V``: the default ``greybox.initial_setpoints_V``, where the balance rested.
    ``rest_unknown``: ``null`` (at rest under the first setpoints, +2.5 mV, as before issue
    28): the estimated initial state makes up for it.
    """
    seed = TEST_SEEDS[2]
    plan = prbs_first_plan()
    experiment = experiment_from_config({'experiment': plan})
    assert experiment.block(0, 1)[0, 0] == pytest.approx(0.0025)       # a non-zero start
    rec = record_draw(draw_balance(seed), seed, experiment=experiment, draw_seed=seed)
    sections = tuple(plan['sections'])
    options = rec.options(sections=sections, initial_setpoints_V=initial)
    options['frf'] = {'coil_sections': ['coil_prbs'], 'pan_sections': ['load_changer_chirp'],
                      'two_input_sections': list(sections[2:])}
    res = identify(rec.recording, rec.section_table, options)
    assert res.success, (res.failures, res.warnings)
    fits = {s.name: float(np.min(s.fit_percent)) for s in res.greybox.fit.sections}
    assert min(fits.values()) > 99.0, fits
    state = res.greybox.initial_state
    if initial is None:
        # the model started 2.5 mV of coil force away from where the balance was: the
        # estimate removes most of the error (and its position is that of the rest shift)
        assert state.rms_after_m < 0.2 * state.rms_before_m, state
    else:
        assert abs(state.position_m) < 1e-6, state
    assert_mechanics_within_targets(res, rec)
    assert res.to_dict()['greybox']['initial_state']['rms_error_with_m'] == pytest.approx(
        state.rms_after_m)


@pytest.mark.slow
@pytest.mark.parametrize('first', ['prbs', 'noise'])
def test_a_multisine_on_the_load_changer_identifies(first):
    """
    The issue's user plan: a multisine on the load changer after a PRBS or noise on the coil.

    PRBS, or Gaussian noise around +1 mV, on the coil; an odd random-phase multisine on the
    load changer; the shipped two-input sections after them.

    The multisine excites one DFT line in twenty: the ordinary LPM's windows between its
    lines held no input and gave the feature start a low mode of 2.6 Hz instead of 3.3 Hz (c1
    64 % off at the start, 6 % after the fit, "fits only 70 %"); the noise plan also met two
    "optima" 1e-5 apart that the ambiguity probe called two answers.
    """
    seed = TEST_SEEDS[3]
    coil = PRBS_SECTION if first == 'prbs' else RANDOM_SECTION
    experiment = unit_experiment(coil, MULTISINE_SECTION)
    names = [s.name for s in experiment.sections if 'staircase' not in s.name]
    assert names[:2] == [coil['name'], 'load_changer_multisine']
    rec = record_draw(draw_balance(seed), seed, experiment=experiment, draw_seed=seed)
    options = rec.options(sections=tuple(names))
    options['frf'] = {'coil_sections': [names[0]], 'pan_sections': [names[1]],
                      'two_input_sections': names[2:]}
    res = identify(rec.recording, rec.section_table, options)
    assert res.success, (res.failures, res.warnings)
    pan = [r for r in res.frfs if r.section == 'load_changer_multisine']
    assert pan and pan[0].frd.details['sparse_excitation']
    assert_mechanics_within_targets(res, rec)
    for key, attr in (('low_mode_frequency_Hz', 'low_mode_Hz'),
                      ('high_mode_frequency_Hz', 'high_mode_Hz')):
        assert abs(relative_error(res.greybox.derived[key].value,
                                  getattr(rec.modal, attr))) <= 0.005
    # the paper-style table found an excited line next to each even frequency
    table = pan[0].selected
    assert table is not None and len(table.details['requested_frequency_Hz']) >= 8
    assert np.all(np.abs(table.frequency_Hz - table.details['requested_frequency_Hz']) <= 5.0)
