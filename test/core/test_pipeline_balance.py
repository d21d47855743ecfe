"""Accuracy of the identification pipeline on the simulated balance (shortened trajectory)."""

from pathlib import Path

import numpy as np
import pytest
import yaml

from emfc_ros.core.ident.balance_experiment import (DEFAULT_TRAJECTORY_GAINS, scaled_experiment,
                                                    section_table, simulate_experiment,
                                                    time_scaled_mapping)
from emfc_ros.core.ident.pipeline import identify
from emfc_ros.core.model.linear import linearise
from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.signals import experiment_from_config, find_experiment_mapping

TRAJECTORY = Path(__file__).resolve().parents[2] / 'config' / 'identification_trajectory.yaml'
TRUTH = BalanceParameters()
#: The model's start values are off the truth (the grey-box must find its way back).
START = TRUTH.with_mechanics(c1_Nm_per_rad=0.12, d1_Nms_per_rad=3.5e-4, c2_Nm_per_rad=19.0,
                             d2_Nms_per_rad=2.8e-4, F_off_N=1.0e-4)
FREE = ('c1_Nm_per_rad', 'd1_Nms_per_rad', 'c2_Nm_per_rad', 'd2_Nms_per_rad')


def short_experiment():
    doc = yaml.safe_load(TRAJECTORY.read_text())
    # 3 s per section at 10 kHz, same chirp band and step pattern as the shipped 10 s
    exp = experiment_from_config(time_scaled_mapping(find_experiment_mapping(doc), 0.3))
    return scaled_experiment(exp, DEFAULT_TRAJECTORY_GAINS)


@pytest.fixture(scope='module')
def recording():
    return simulate_experiment(TRUTH, short_experiment(), seed=3)


@pytest.fixture(scope='module')
def result(recording):
    progress = []
    cfg = {'load_mass_kg': recording.load_mass_kg, 'load_changer_coupled': True,
           'balance': START.to_mapping()}
    res = identify(recording, section_table(recording), cfg,
                   progress=lambda *args: progress.append(args))
    res.progress_calls = progress
    return res


@pytest.fixture(scope='module')
def truth_model(recording):
    return linearise(loaded(TRUTH.mechanics, recording.load_mass_kg, True))


def test_scaled_trajectory_stays_in_sensor_range(recording):
    y = recording.channels['position_true_m']
    assert np.abs(y).max() < 90e-6
    assert np.abs(recording.channels['coil_setpoint_V']).max() == pytest.approx(0.0025, rel=0.05)


def test_resonance_anti_resonance_and_damping(result, truth_model):
    poles = [p for p in truth_model.poles() if p.s_rad_per_s.imag > 0]
    zeros = [z for z in truth_model.zeros('coil') if z.s_rad_per_s.imag > 0]
    for name in ('coil_chirp.coil', 'load_changer_chirp.pan'):
        fit = next(r for r in result.frfs if r.name == name).fit.chosen
        assert (fit.numerator_order, fit.denominator_order) == (2, 4)
        high = fit.modes[-1]
        np.testing.assert_allclose(high.frequency_Hz, poles[-1].frequency_Hz, rtol=0.005)
        np.testing.assert_allclose(high.damping_ratio, poles[-1].damping_ratio, rtol=0.1)
        low = fit.modes[0]
        np.testing.assert_allclose(low.frequency_Hz, poles[0].frequency_Hz, rtol=0.05)
        np.testing.assert_allclose(low.damping_ratio, poles[0].damping_ratio, rtol=0.2)
    coil = result.frf('coil_chirp', 'coil').fit.chosen
    assert len(coil.anti_resonances) == 1
    np.testing.assert_allclose(coil.anti_resonances[0].frequency_Hz, zeros[0].frequency_Hz,
                               rtol=0.01)


def test_frf_matches_model_within_its_uncertainty(result, truth_model):
    r = result.frf('coil_chirp', 'coil')
    band = (r.frd.frequency_Hz > 20.0) & (r.frd.frequency_Hz < 600.0)
    truth = truth_model.frequency_response(r.frd.frequency_Hz[band], 'coil').response_m_per_N
    z = np.abs(r.frd.response[band] - truth) / r.frd.std[band]
    assert np.median(z) < 2.0
    assert np.mean(z < 3.0) > 0.9


def test_two_input_solve_recovers_coil_response(result, truth_model):
    r = result.frf('coil_chirp_load_changer_steps', 'coil')
    assert r.two_input
    band = (r.frd.frequency_Hz > 20.0) & (r.frd.frequency_Hz < 250.0)
    truth = truth_model.frequency_response(r.frd.frequency_Hz[band], 'coil').response_m_per_N
    np.testing.assert_allclose(np.median(np.abs(r.frd.response[band] / truth)), 1.0, atol=0.02)


def test_greybox_parameters_and_fit(result):
    g = result.greybox
    assert g.fit.success and result.success, result.failures
    for name in FREE:
        np.testing.assert_allclose(g.fit.parameters[name], getattr(TRUTH.mechanics, name),
                                   rtol=0.02)
        # the reported uncertainty covers the error (generously: 4 standard uncertainties)
        error = g.fit.parameters[name] - getattr(TRUTH.mechanics, name)
        assert abs(error) < 4.0 * g.fit.standard_errors[name], name
    # F_off is tied to the fitted coil mass's weight: it must be 0 within its uncertainty
    assert abs(g.parameters['F_off_N']) < 4.0 * g.derived['F_off_N'].standard_uncertainty
    assert g.derived['F_off_N'].standard_uncertainty < 2e-3
    for sec in g.fit.sections:
        assert np.min(sec.fit_percent) > 95.0
    poles = [p for p in g.linear_model.poles() if p.s_rad_per_s.imag > 0]
    np.testing.assert_allclose(poles[-1].frequency_Hz, 353.067, rtol=0.005)


def test_progress_and_serialisation(result):
    steps = [c[0] for c in result.progress_calls]
    assert steps[0] == 'frf' and steps[-1] == 'done'
    assert {'frf', 'tf_fit', 'greybox'} <= set(steps)
    assert all(0.0 <= c[1] <= 1.0 for c in result.progress_calls)
    d = result.to_dict()
    text = yaml.safe_dump(d)
    back = yaml.safe_load(text)
    assert back['greybox']['parameters']['c2_Nm_per_rad']['unit'] == 'N m/rad'
    assert back['frequency_responses'][0]['unit'] == 'm/N'
    # an LPM std is a standard uncertainty with few degrees of freedom (7 complex residuals
    # for one input: 14 real): the 95 % factor is Student's, t(0.975, 14) = 2.145
    assert back['frequency_responses'][0]['std_degrees_of_freedom'] == 14
    np.testing.assert_allclose(back['frequency_responses'][0]['coverage_factor_95'], 2.145,
                               atol=1e-3)
    assert len(back['greybox']['sections']) == 4


def test_pattern_search_option(recording):
    start = TRUTH.with_mechanics(c2_Nm_per_rad=19.0, d2_Nms_per_rad=2.8e-4)
    cfg = {'load_mass_kg': recording.load_mass_kg, 'load_changer_coupled': True,
           'balance': start.to_mapping(), 'tf_fit': {'numerator_orders': [2],
                                                     'denominator_orders': [4]},
           'greybox': {'method': 'pattern_search', 'free': ['c2_Nm_per_rad', 'd2_Nms_per_rad'],
                       'max_evaluations': 60}}
    res = identify(recording, section_table(recording), cfg)
    fit = res.greybox.fit
    assert fit.method == 'pattern_search'
    assert fit.optimizer_evaluations <= 60
    for name in ('c2_Nm_per_rad', 'd2_Nms_per_rad'):
        np.testing.assert_allclose(fit.parameters[name], getattr(TRUTH.mechanics, name),
                                   rtol=0.02)


def test_welch_option_and_disabled_steps(recording, truth_model):
    cfg = {'frf': {'method': 'welch', 'two_input_sections': [], 'pan_sections': []},
           'tf_fit': {'numerator_orders': [2], 'denominator_orders': [4]},
           'greybox': {'enabled': False}, 'load_mass_kg': recording.load_mass_kg}
    res = identify(recording, section_table(recording), cfg)
    assert res.greybox is None and 'greybox' not in res.timings_s
    poles = [p for p in truth_model.poles() if p.s_rad_per_s.imag > 0]
    high = res.frf('coil_chirp', 'coil').fit.chosen.modes[-1]
    assert res.frf('coil_chirp', 'coil').frd.estimator == 'H1'
    np.testing.assert_allclose(high.frequency_Hz, poles[-1].frequency_Hz, rtol=0.01)


def test_modes_outside_the_fitted_band_are_flagged(result):
    d = result.to_dict()
    coil = next(r for r in d['frequency_responses'] if r['name'] == 'coil_chirp.coil')
    tf = coil['transfer_function']
    low, high = tf['resonances'][0], tf['resonances'][-1]
    # the 3.6 Hz mode lies below the 5 Hz start of the band, the 353 Hz mode inside it
    assert low['frequency_Hz'] < coil['frequency_min_Hz'] and low['extrapolated'] is True
    assert high['extrapolated'] is False
    assert any('extrapolated' in w and 'coil_chirp.coil' in w for w in result.warnings)
