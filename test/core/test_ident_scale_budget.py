"""
Systematic (type B) part of the FRFs, transfer-function gains and static fits.

Analytic ground truth for the budgets (independent stated inputs in quadrature, a power of x
multiplying the x scale's error), then the case a real unit brings: a sensor whose gain is
off by 3 % scales every FRF magnitude by 3 % while the statistical uncertainty is a fraction
of that; the reported combined uncertainty covers it, and the modes do not move.
"""

from dataclasses import replace
import math

import numpy as np
import pytest

from emfc_ros.core.ident.offnominal import (draw_balance, record_draw, TEST_SEEDS,
                                            unit_experiment, with_position_gain)
from emfc_ros.core.ident.pipeline import identify
from emfc_ros.core.ident.scale_budget import frf_budget, ScaleBudget, static_budget
from emfc_ros.core.model.uncertainties import StatedUncertainties

SENSOR_ERROR = 0.03         # 1.5 stated standard uncertainties (the default 2 %)
MONITOR_ERROR = 0.003       # 1.5 stated standard uncertainties (the default 0.2 %)


def test_an_frf_carries_the_sensor_the_current_monitor_and_the_force_constant():
    stated = StatedUncertainties()
    coil = frf_budget(stated, 'coil')
    assert coil.relative == pytest.approx(math.sqrt(0.02 ** 2 + 5e-4 ** 2 + 0.01 ** 2
                                                    + 0.002 ** 2))
    assert coil.dominant == 'sensor_gain_relative'
    assert list(coil.as_dict()) == ['sensor_gain_relative', 'motor_coefficient_relative',
                                    'current_monitor_gain_relative', 'adc_gain_relative']
    pan = frf_budget(stated, 'pan')
    assert pan.relative == pytest.approx(math.sqrt(0.02 ** 2 + 5e-4 ** 2 + 0.02 ** 2
                                                   + 0.002 ** 2))
    # an input stated as exact drops out; a calibrated unit has a smaller budget
    exact = StatedUncertainties(sensor_gain_relative=0.0, motor_coefficient_relative=0.0)
    assert frf_budget(exact, 'coil').relative == pytest.approx(math.hypot(5e-4, 0.002))
    assert 'sensor_gain_relative' not in frf_budget(exact, 'coil').as_dict()
    with pytest.raises(KeyError):
        frf_budget(stated, 'both')
    # a recorded force (the simulator's channel) leaves the position's part only
    recorded = frf_budget(stated, 'pan', force_recorded=True)
    assert recorded.relative == pytest.approx(math.hypot(0.02, 5e-4))


def test_a_static_coefficient_carries_its_power_of_the_x_scale():
    stated = StatedUncertainties(current_monitor_gain_relative=0.002, coil_dac_gain_relative=0.01)
    # I = c0 + c1 U + c2 U^2: with U read (1 + e) too large, c_k is (1 + e)^-k too small
    rel = [static_budget(stated, 'coil_amplifier', k).relative for k in range(3)]
    np.testing.assert_allclose(rel, [0.002, math.hypot(0.002, 0.01), math.hypot(0.002, 0.02)])
    # F = c0 + c1 I: the force is the reference (exact), the current its monitor's
    lc = [static_budget(stated, 'load_changer', k) for k in range(3)]
    assert lc[0] == ScaleBudget() and lc[0].relative == 0.0 and lc[0].dominant == ''
    np.testing.assert_allclose([b.relative for b in lc[1:]], [0.002, 0.004])


@pytest.fixture(scope='module')
def simulated():
    seed = TEST_SEEDS[2]
    return record_draw(draw_balance(seed), seed, draw_seed=seed, experiment=unit_experiment())


@pytest.fixture(scope='module')
def record(simulated):
    # as a device records it: no force channels (the FRFs take the forces from the currents)
    channels = {k: v for k, v in simulated.recording.channels.items()
                if k not in ('coil_force_N', 'load_changer_force_N')}
    return replace(simulated, recording=replace(simulated.recording, channels=channels))


def _identify(rec):
    return identify(rec.recording, rec.section_table,
                    dict(rec.options(), greybox={'enabled': False}))


@pytest.fixture(scope='module')
def pair(record):
    return _identify(record), _identify(with_position_gain(record, 1.0 + SENSOR_ERROR))


def test_a_sensor_gain_off_is_covered_by_the_frf_s_combined_uncertainty(pair):
    intact, broken = pair
    good = {r.name: r for r in intact.frfs}
    assert good and {r.name for r in broken.frfs} == set(good)
    for r in broken.frfs:
        ref = good[r.name]
        band = (ref.frd.coherence > 0.99) & (ref.frd.frequency_Hz > 5.0)
        assert band.sum() > 20, r.name
        ratio = np.abs(r.frd.response[band] / ref.frd.response[band])
        assert float(np.median(ratio)) - 1.0 == pytest.approx(SENSOR_ERROR, abs=5e-3)
        # the band's magnitude scale against the FRF measured with the true sensor, as a fit
        # of the band estimates it (lines weighted by their statistical variance), and the
        # statistical uncertainty of that: alone it calls a 3 % error many sigmas, the
        # confident wrong answer; the combined one covers it at k = 2
        line = r.frd.std[band] / np.abs(r.frd.response[band])
        weights = 1.0 / line ** 2
        error = float(np.sum(weights * ratio) / np.sum(weights)) - 1.0
        statistical = float(1.0 / np.sqrt(np.sum(weights)))
        systematic = r.systematic.relative
        if not r.two_input:                 # the precise ones (a chirp on the input)
            assert error > 5.0 * statistical, (r.name, statistical)
        assert error < 2.0 * math.hypot(statistical, systematic), r.name
        assert r.systematic.dominant == 'sensor_gain_relative'
    # what a scale does not move: the transfer-function fits' resonances
    for r in broken.frfs:
        ref = good[r.name]
        if r.fit is None or ref.fit is None:
            continue
        f_off = sorted(m.frequency_Hz for m in r.fit.chosen.modes)
        f_ref = sorted(m.frequency_Hz for m in ref.fit.chosen.modes)
        if len(f_off) == len(f_ref):
            np.testing.assert_allclose(f_off, f_ref, rtol=2e-3)


def test_results_and_summary_state_the_systematic_part(pair):
    from emfc_ros.core.report.summary import summary_markdown
    _, broken = pair
    d = broken.to_dict()
    frfs = d['frequency_responses']
    assert frfs
    for r in frfs:
        rel = r['magnitude_systematic_relative_standard_uncertainty']
        assert rel == pytest.approx(frf_budget(StatedUncertainties(),
                                               r['name'].rsplit('.', 1)[1]).relative)
        assert set(r['systematic_inputs']) >= {'sensor_gain_relative', 'adc_gain_relative'}
        for s in r.get('selected_frequencies') or []:
            assert s['magnitude_systematic_std_m_per_N'] == pytest.approx(
                s['magnitude_m_per_N'] * rel)
            assert s['magnitude_combined_std_m_per_N'] >= s['magnitude_systematic_std_m_per_N']
        if r.get('transfer_function'):
            assert r['transfer_function']['gain_systematic_relative_standard_uncertainty'] == rel
    text = summary_markdown(broken)
    assert 'Systematic (type B) part of every magnitude' in text
    static = d.get('static_characteristics') or {}
    for key, fit in static.items():
        for c in fit['coefficients_ascending']:
            assert c['combined_standard_uncertainty'] >= c['standard_error']
            assert c['combined_standard_uncertainty'] >= c['systematic_standard_uncertainty']
    if static:
        assert 'systematic (type B, k = 1) per coefficient' in text


def test_a_current_monitor_off_is_covered_by_the_static_combined_uncertainty(record, pair):
    intact, _ = pair
    channels = dict(record.recording.channels)
    channels['coil_current_A'] = channels['coil_current_A'] * (1.0 + MONITOR_ERROR)
    off = _identify(replace(record, recording=replace(record.recording, channels=channels)))
    good, bad = intact.static.fits['coil_amplifier'], off.static.fits['coil_amplifier']
    budgets = off.static.systematic['coil_amplifier']
    assert len(budgets) == bad.degree + 1
    for k in range(bad.degree + 1):
        # every coefficient of I(U) scales with the monitor (an offset too)
        if abs(good.coefficients[k]) < 10.0 * good.standard_errors[k]:
            continue                    # a coefficient the data barely determine
        error = bad.coefficients[k] / good.coefficients[k] - 1.0
        assert error == pytest.approx(MONITOR_ERROR, rel=0.05), k
        rel_se = bad.standard_errors[k] / abs(bad.coefficients[k])
        assert abs(error) < 2.0 * math.hypot(rel_se, budgets[k].relative), k
        assert budgets[k].dominant in ('current_monitor_gain_relative', 'coil_dac_gain_relative')
    # the slope: statistically a fraction of a per mille, so 0.3 % alone was many sigmas
    assert bad.standard_errors[1] / abs(bad.coefficients[1]) < MONITOR_ERROR / 5.0


def test_a_recorded_force_leaves_the_position_s_part(simulated):
    res = _identify(simulated)
    assert res.frfs
    for r in res.frfs:
        assert set(r.systematic.as_dict()) == {'sensor_gain_relative', 'adc_gain_relative'}
