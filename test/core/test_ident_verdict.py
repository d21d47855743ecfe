"""
The mass check of the grey-box verdict against drawn balances and scaled sensors.

No identification runs here: the identified mass matrix is the drawn balance's own (as a
perfect fit would give it) seen through a sensor of a given gain, which scales every
mass-matrix entry by ``1 / gain``.
"""

from dataclasses import replace

import numpy as np
import pytest

from emfc_ros.core.ident.balance_result import Derived, MASS_KEYS, Setting, Verdict
from emfc_ros.core.ident.balance_verdict import check_masses
from emfc_ros.core.ident.offnominal import draw_balance, TEST_SEEDS
from emfc_ros.core.ident.systematic import Component, SystematicBudget
from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.mechanics import mass_matrix
from emfc_ros.core.model.parameters import BalanceParameters

LOAD_KG = 0.1274


def identified(params: BalanceParameters, gain: float) -> dict:
    m = mass_matrix(np.zeros(2), loaded(params.mechanics, LOAD_KG, True)) / gain
    entries = (m[0, 0], m[0, 1], m[1, 1])
    return {k: Derived(float(v), 1e-4 * abs(float(v)), u) for (k, u), v in zip(MASS_KEYS, entries)}


def sensor_budget(derived: dict, relative: float = 0.02) -> SystematicBudget:
    # the sensor's stated uncertainty: every mass-matrix entry scales with the sensor's gain
    part = Component('sensor_gain_relative', 'sensor_gain_relative', 'position_scale',
                     relative, relative, '1')
    budget = SystematicBudget((part,))
    for k, _ in MASS_KEYS:
        budget.add(k, {part.name: -relative * derived[k].value})
    return budget


def verdict_for(truth: BalanceParameters, gain: float, relative_uncertainty: float = 0.05,
                configured: BalanceParameters = BalanceParameters(),
                stated_sensor: float = 0.0) -> Verdict:
    verdict = Verdict()
    setting = Setting(configured, LOAD_KG, True, 10000.0)
    derived = identified(truth, gain)
    budget = sensor_budget(derived, stated_sensor) if stated_sensor > 0.0 else None
    check_masses(derived, setting, relative_uncertainty, verdict, budget)
    return verdict


# seeds the benchmark never uses (TEST_SEEDS and a range of their own)
SEEDS = TEST_SEEDS + tuple(range(300, 340))


@pytest.mark.parametrize('seed', SEEDS)
def test_a_balance_within_10_percent_passes_the_check(seed):
    assert verdict_for(draw_balance(seed), 1.0).failures == []


@pytest.mark.parametrize('seed', SEEDS)
@pytest.mark.parametrize('gain', [0.9, 1.1])
def test_a_sensor_gain_10_percent_off_is_named(seed, gain):
    failures = verdict_for(draw_balance(seed), gain).failures
    assert len(failures) == 1
    assert 'scaled by' in failures[0] and 'gain' in failures[0]
    # the reported scale is the gain's, within the draws' own spread of the masses
    shown = float(failures[0].split('scaled by ')[1].split(' %')[0])
    assert shown == pytest.approx(100.0 * (1.0 / gain - 1.0), abs=4.0)


@pytest.mark.parametrize('seed', SEEDS)
def test_a_sensor_within_its_stated_uncertainty_passes_and_one_far_outside_is_named(seed):
    # 2 % stated: 4 % off (2 sigma) is no failure (a warning where the masses alone would
    # have failed it), 25 % off (12 sigma) still fails with the scale named
    within = verdict_for(draw_balance(seed), 1.04, stated_sensor=0.02)
    assert within.failures == []
    if verdict_for(draw_balance(seed), 1.04).failures:
        assert len(within.warnings) == 1 and 'masses alone' in within.warnings[0]
    far = verdict_for(draw_balance(seed), 1.25, stated_sensor=0.02).failures
    assert len(far) == 1 and 'scaled by' in far[0] and 'stated uncertainties' in far[0]
    # 10 % off (5 sigma): refused, or, where the drawn masses partly cancel it, named
    blunder = verdict_for(draw_balance(seed), 1.1, stated_sensor=0.02)
    assert blunder.failures or 'masses alone' in blunder.warnings[0]


def test_the_stated_sensor_uncertainty_turns_a_mass_only_failure_into_a_warning():
    truth = draw_balance(SEEDS[0])
    assert verdict_for(truth, 1.08).failures                  # the masses alone: refused
    verdict = verdict_for(truth, 1.08, stated_sensor=0.05)
    assert verdict.failures == [] and 'masses alone' in verdict.warnings[0]


def test_masses_known_worse_widen_the_check():
    # the same 10 % sensor passes when the user says the masses are known to 30 % only
    assert verdict_for(draw_balance(SEEDS[0]), 1.1, relative_uncertainty=0.3).failures == []


def test_masses_that_contradict_without_a_common_scale_fail_the_consistency_test():
    truth = BalanceParameters()
    mech = truth.mechanics
    # coil mass up, pan-side inertia down: M22 rises while M11 falls, no common scale
    odd = replace(truth, mechanics=replace(mech, m3_kg=mech.m3_kg * 1.4,
                                           J1c_kgm2=mech.J1c_kgm2 * 0.5))
    failures = verdict_for(odd, 1.0).failures
    assert len(failures) == 1 and 'differs from the configured masses' in failures[0]


def test_zero_uncertainty_disables_the_check():
    assert verdict_for(draw_balance(SEEDS[0]), 1.3, relative_uncertainty=0.0).failures == []


def _fit(values, errors, sections=()):
    from emfc_ros.core.ident.greybox import GreyboxResult
    names = tuple(values)
    return GreyboxResult(dict(values), dict(errors), np.eye(len(names)), names, 1.0, 1, 1, 0.0,
                         'least_squares', True, 'ok', tuple(sections))


def test_poorly_determined_free_parameters_are_named():
    from emfc_ros.core.ident.balance_verdict import (check_uncertainties,
                                                     POOR_RELATIVE_UNCERTAINTY)
    fit = _fit({'c1_Nm_per_rad': 0.1, 'c2_Nm_per_rad': 20.0, 'M11_kgm2': 1e-4,
                'M22_kgm2': 1.5e-5, 'rest_position_m': 1e-9},
               {'c1_Nm_per_rad': 1e-4, 'c2_Nm_per_rad': 20.0 * 1.5 * POOR_RELATIVE_UNCERTAINTY,
                'M11_kgm2': 0.08e-4, 'M22_kgm2': 0.01 * 1.5e-5, 'rest_position_m': 1e-8})
    verdict = Verdict()
    check_uncertainties(fit, 0.05, verdict, skip=('rest_position_m',))
    text = ' '.join(verdict.warnings)
    assert len(verdict.warnings) == 2, verdict.warnings
    assert 'c2_Nm_per_rad is poorly determined' in text and '15 %' in text
    # a mass-matrix entry known worse (8 %) than the configured masses (5 %)
    assert 'M11_kgm2 is poorly determined' in text and 'configured masses (5 %)' in text
    assert 'c1_Nm_per_rad' not in text and 'rest_position_m' not in text
    assert verdict.failures == []           # the numbers are honest: a warning, not a failure


def test_residual_tests_of_a_prewhitened_residual_are_judged():
    """By their p-values against 0.01 over the tested sections; raw residuals not at all."""
    from emfc_ros.core.ident.balance_verdict import check
    from emfc_ros.core.ident.greybox import SectionFit
    from emfc_ros.core.ident.residual_coherence import CoherencePeak
    weighted = 'noise-weighted (noise model of the final residual)'
    quiet = CoherencePeak('coil', 120.0, 0.05, 0.6, 150, 97)
    good = SectionFit('a', np.array([99.9]), 1.0, 1.0, np.array([1e-9]), weighted,
                      0.5, 0.4, quiet)
    # 20 % of the lags inside the band, p 1e-4: dependent (level 0.01 / 3 sections)
    bad = SectionFit('b', np.array([99.9]), 0.96, 0.2, np.array([1e-9]), weighted,
                     0.5, 1e-4, quiet)
    # p 0.004 is not below 0.01 / 3 = 0.0033: no warning, whatever the share of lags
    edge = SectionFit('d', np.array([99.9]), 0.5, 0.5, np.array([1e-9]), weighted,
                      0.004, 0.004, CoherencePeak('load_changer', 333.0, 0.4, 1e-9, 150, 97))
    raw = SectionFit('c', np.array([99.9]), 0.0, 0.0, np.array([1e-9]), 'raw')
    fit = _fit({'c1_Nm_per_rad': 0.1}, {'c1_Nm_per_rad': 1e-5}, (good, bad, edge, raw))
    fit = replace(fit, initial={'c1_Nm_per_rad': 0.09})
    verdict = Verdict()
    check(fit, [], None, verdict)
    assert len(verdict.warnings) == 2, verdict.warnings
    assert "section 'b'" in verdict.warnings[0] and 'depends on the inputs' in \
        verdict.warnings[0] and '20 %' in verdict.warnings[0] and 'p = 0.0001' in \
        verdict.warnings[0]
    assert "section 'd'" in verdict.warnings[1] and 'load_changer input at 333 Hz' in \
        verdict.warnings[1] and 'unmodelled mode' in verdict.warnings[1]
