"""
The grey-box identification of the balance: start from the data, verdict, provenance.

A shortened trajectory (3 s per section) of a balance that is not the configured one (every
stiffness, damping, mass and inertia moved by a fixed pattern of up to 8 %), identified from
configured values that are 20 % off.
"""

from pathlib import Path

import numpy as np
import pytest
import yaml

from emfc_ros.core.ident import balance_frf
from emfc_ros.core.ident.balance_derived import modal_summary
from emfc_ros.core.ident.balance_experiment import (section_table, simulate_experiment,
                                                    time_scaled_mapping)
from emfc_ros.core.ident.balance_greybox import offset_force_N, rest_state
from emfc_ros.core.ident.pipeline import identify
from emfc_ros.core.model.linear import linearise
from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.mechanics import mass_matrix
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.signals import experiment_from_config, find_experiment_mapping

TRAJECTORY = Path(__file__).resolve().parents[2] / 'config' / 'identification_trajectory.yaml'
NOMINAL = BalanceParameters()
PATTERN = {'c1_Nm_per_rad': 1.06, 'd1_Nms_per_rad': 0.93, 'c2_Nm_per_rad': 0.95,
           'd2_Nms_per_rad': 1.08, 'mp_kg': 1.04, 'm1_kg': 0.96, 'J1c_kgm2': 1.07,
           'm2_kg': 1.05, 'J2c_kgm2': 0.92, 'm3_kg': 1.06, 'load_changer_mass_kg': 0.97}
TRUTH = NOMINAL.with_mechanics(**{k: getattr(NOMINAL.mechanics, k) * v
                                  for k, v in PATTERN.items()})
DYNAMIC = ['coil_chirp', 'load_changer_chirp', 'coil_chirp_load_changer_steps',
           'load_changer_chirp_coil_steps']


def configured(factor):
    """The balance a user configured: every parameter of PATTERN off the default by factor."""
    return NOMINAL.with_mechanics(**{k: getattr(NOMINAL.mechanics, k) * factor
                                     for k in PATTERN})


@pytest.fixture(scope='module')
def recording():
    doc = yaml.safe_load(TRAJECTORY.read_text())
    exp = experiment_from_config(time_scaled_mapping(find_experiment_mapping(doc), 0.3))
    return simulate_experiment(TRUTH, exp, seed=21)


def options(recording, factor=1.0, **extra):
    return dict({'load_mass_kg': recording.load_mass_kg, 'load_changer_coupled': True,
                 'balance': configured(factor).to_mapping()}, **extra)


@pytest.fixture(scope='module')
def results(recording):
    # masses configured 20 % off: the user says so (known to 30 %), else the mass check fails
    loose = {'greybox': {'mass_relative_uncertainty': 0.3}}
    return {f: identify(recording, section_table(recording), options(recording, f, **loose))
            for f in (0.8, 1.2)}


def test_masses_configured_20_percent_off_but_claimed_known_to_5_percent_fail(recording):
    res = identify(recording, section_table(recording), options(recording, 0.8))
    assert not res.success
    assert any('mass matrix' in f for f in res.failures)
    # the mechanics are still there to look at, with the failure beside them
    assert res.greybox is not None


def truth_numbers(recording):
    mech = loaded(TRUTH.mechanics, recording.load_mass_kg, True)
    return mass_matrix(np.zeros(2), mech), modal_summary(linearise(mech))


def test_offset_force_gives_the_wanted_rest_position():
    for y in (0.0, 4e-5, -6e-5):
        force = offset_force_N(NOMINAL, [0.002, 0.1], 0.1, True, y)
        x = rest_state(NOMINAL.with_mechanics(F_off_N=force), [0.002, 0.1], 0.1, True)
        m = NOMINAL.mechanics
        np.testing.assert_allclose(m.l2_m * np.sin(x[0]) + m.l3_m * np.sin(x[1]), y,
                                   atol=1e-12)


def test_unseen_balance_identified_from_a_start_20_percent_off(results, recording):
    m_true, modes_true = truth_numbers(recording)
    for factor, res in results.items():
        assert res.success, (factor, res.failures)
        g = res.greybox
        for name in ('c1_Nm_per_rad', 'c2_Nm_per_rad'):
            np.testing.assert_allclose(g.parameters[name], getattr(TRUTH.mechanics, name),
                                       rtol=0.02)
        for name in ('d1_Nms_per_rad', 'd2_Nms_per_rad'):
            np.testing.assert_allclose(g.parameters[name], getattr(TRUTH.mechanics, name),
                                       rtol=0.1)
        # masses and inertias are free: the mass matrix the data determine is right
        for key, (i, j) in (('mass_matrix_11_kgm2', (0, 0)), ('mass_matrix_12_kgm2', (0, 1)),
                            ('mass_matrix_22_kgm2', (1, 1))):
            np.testing.assert_allclose(g.derived[key].value, m_true[i, j], rtol=0.01)
        for key, k in (('low_mode_frequency_Hz', 0), ('high_mode_frequency_Hz', 2),
                       ('coil_anti_resonance_frequency_Hz', 4)):
            np.testing.assert_allclose(g.derived[key].value, modes_true[k], rtol=0.005)
        for sec in g.fit.sections:
            assert float(np.min(sec.fit_percent)) > 95.0


def test_both_starts_reach_the_same_optimum(results):
    a, b = results[0.8].greybox, results[1.2].greybox
    for name in ('c1_Nm_per_rad', 'd1_Nms_per_rad', 'c2_Nm_per_rad', 'd2_Nms_per_rad'):
        se = a.fit.standard_errors[name]
        assert abs(a.parameters[name] - b.parameters[name]) < se, name


def test_uncertainties_cover_the_error(results, recording):
    m_true, modes_true = truth_numbers(recording)
    g = results[1.2].greybox
    for name in ('c1_Nm_per_rad', 'd1_Nms_per_rad', 'c2_Nm_per_rad', 'd2_Nms_per_rad'):
        error = g.parameters[name] - getattr(TRUTH.mechanics, name)
        assert abs(error) < 4.0 * g.fit.standard_errors[name], name
    for key, k in (('low_mode_frequency_Hz', 0), ('high_mode_frequency_Hz', 2)):
        d = g.derived[key]
        assert abs(d.value - modes_true[k]) < 4.0 * d.standard_uncertainty, key
    assert g.fit.covariance_method == 'sandwich'


def test_every_parameter_identified_or_fixed_with_its_source(results):
    rows = results[1.2].to_dict()['model_parameters']
    by_name = {r['name']: r for r in rows}
    assert set(by_name) == set(NOMINAL.mechanics.__dataclass_fields__)
    for name in ('c1_Nm_per_rad', 'J1c_kgm2', 'm3_kg', 'F_off_N'):
        assert by_name[name]['status'] == 'identified'
        assert by_name[name]['standard_uncertainty'] > 0.0
    assert by_name['J1c_kgm2']['note'].startswith('identified through M11')
    for name in ('l1_m', 'm1_kg', 'mp_kg'):
        assert by_name[name]['status'] == 'fixed'
        assert by_name[name]['source'].startswith('configuration')
        assert by_name[name]['standard_uncertainty'] is None


def test_identifiability_is_reported(results):
    d = results[1.2].to_dict()['greybox']['identifiability']
    assert d['free']['rank'] == len(d['free']['names'])
    assert d['free']['condition_number'] > 1.0


def test_data_of_pure_noise_fail(recording):
    rng = np.random.default_rng(4)
    channels = dict(recording.channels)
    channels['position_m'] = rng.normal(0.0, 3e-5, channels['position_m'].size)
    res = identify(dict(channels, sample_rate_Hz=recording.sample_rate_Hz),
                   section_table(recording), options(recording))
    assert not res.success
    assert any(f.startswith('greybox:') for f in res.failures)
    assert res.to_dict()['status']['success'] is False


def test_a_sensor_gain_off_by_15_percent_fails(recording):
    channels = dict(recording.channels)
    channels['position_m'] = channels['position_m'] * 1.15
    res = identify(dict(channels, sample_rate_Hz=recording.sample_rate_Hz),
                   section_table(recording),
                   dict(options(recording), balance=TRUTH.to_mapping()))
    assert not res.success
    # either the free mass matrix contradicts the configured masses, or (where the short
    # record does not determine the mass matrix to 5 % and it is fixed) the model cannot fit
    assert any('mass matrix' in f or 'fits only' in f for f in res.failures), res.failures


def test_frequency_domain_fit_alone_has_an_honest_chi_square(recording):
    jobs = [(name, first, n, inputs) for (name, first, n), inputs in
            zip(section_table(recording), (['coil'], ['pan'], ['coil', 'pan'], ['coil', 'pan']))]
    frfs = balance_frf.measure_frfs(recording.channels, recording.sample_rate_Hz, jobs,
                                    NOMINAL, frequency_min_Hz=5.0, frequency_max_Hz=1500.0)
    assert {m.name for m in frfs} >= {'coil_chirp.coil', 'load_changer_chirp.pan'}
    model = balance_frf.MechanicsFrfModel(TRUTH, recording.load_mass_kg, True)
    names = ['c1_Nm_per_rad', 'd1_Nms_per_rad', 'c2_Nm_per_rad', 'd2_Nms_per_rad']
    start = {n: getattr(TRUTH.mechanics, n) for n in names}
    fit = balance_frf.fit_frfs(model, frfs, start, names)
    assert 0.7 < fit.chi2_reduced < 1.5
    se = fit.standard_errors()
    for n in names:
        assert abs(fit.values[n] - start[n]) < 4.0 * se[n], n
