"""
A unit's own amplifier curves in the grey-box (issue 28 item 2, first part).

A unit whose amplifiers differ by a few percent from the file's curves was refused (right,
but no use to its owner). The static step identifies the curves from the staircases; the
grey-box now takes them (``greybox.amplifiers_from_static``, default on), and the report says
for each characteristic where it came from and how far the file's is from it.
"""

import dataclasses
import math

import pytest
import yaml

from emfc_ros.core.ident.offnominal import draw_balance, record_draw, TEST_SEEDS, \
    truth_values
from emfc_ros.core.ident.pipeline import identify
from emfc_ros.core.ident.pipeline_config import IdentificationConfig
from emfc_ros.core.model.peripherals import Amplifier
from emfc_ros.core.paths import config_file
from emfc_ros.core.run_plan import merge_experiments
from emfc_ros.core.signals import experiment_from_config, find_experiment_mapping

MECHANICS = ('c1_Nm_per_rad', 'c2_Nm_per_rad', 'd1_Nms_per_rad', 'd2_Nms_per_rad')


def trajectory_with_staircases():
    """The shipped trajectory followed by the static staircases, as the main job plays them."""
    files = ('identification_trajectory.yaml', 'static_characteristics.yaml')
    maps = [find_experiment_mapping(yaml.safe_load(config_file(f).read_text()))
            for f in files]
    return experiment_from_config({'experiment': merge_experiments(maps, list(files))})


@pytest.fixture(scope='module')
def unit():
    """A drawn balance whose coil amplifier is 3 % strong and load changer's 2 % weak."""
    seed = TEST_SEEDS[0]
    p = draw_balance(seed)
    p = dataclasses.replace(
        p, coil_amplifier=Amplifier(tuple(1.03 * c for c in p.coil_amplifier.coeffs_A_per_V_pow)),
        load_changer_amplifier=Amplifier(tuple(
            0.98 * c for c in p.load_changer_amplifier.coeffs_A_per_V_pow)))
    return record_draw(p, seed, experiment=trajectory_with_staircases(), draw_seed=seed)


def test_the_option_is_on_by_default_and_can_be_switched_off():
    assert IdentificationConfig.from_mapping({}).greybox.amplifiers_from_static is True
    off = IdentificationConfig.from_mapping({'greybox': {'amplifiers_from_static': False}})
    assert off.greybox.amplifiers_from_static is False


@pytest.mark.slow
def test_a_unit_with_its_own_amplifiers_is_identified(unit):
    truth = truth_values(unit.truth)
    res = identify(unit.recording, unit.section_table, unit.options())
    assert res.success, (res.failures, res.warnings)
    got = res.greybox.fit.parameters
    for name in MECHANICS:
        limit = 0.02 if name.startswith('c') else 0.10
        assert abs(got[name] / truth[name] - 1.0) <= limit, name
    # the curves the fit used are the unit's, and the report says so, with the comparison
    used = res.greybox.balance
    assert used.coil_amplifier.coeffs_A_per_V_pow[1] == pytest.approx(0.0103, rel=2e-3)
    assert used.load_changer_amplifier.coeffs_A_per_V_pow[1] == pytest.approx(0.0098, rel=2e-3)
    rows = {r['name']: r for r in res.to_dict()['model_parameters']}
    coil = rows['coil_amplifier.coeffs_A_per_V_pow']
    assert coil['status'] == 'identified (static)'
    assert coil['source'].startswith('identified (static staircase')
    assert "the file's gain 0.01 A/V is -2.9" in coil['source']
    assert rows['motor.coeffs_N_per_A_per_mm_pow']['status'] == 'fixed'
    # the amplifier's stated gain is replaced by the staircase's own uncertainty
    inputs = {i['name'] for i in res.to_dict()['greybox']['systematic']['inputs']}
    assert 'coil_amplifier_from_staircase' in inputs
    assert 'coil_amplifier_gain_relative' not in inputs
    assert 'coil_dac_gain_relative' not in inputs


@pytest.mark.slow
def test_with_the_files_curves_the_same_unit_is_refused_or_covered(unit):
    """
    The file's amplifier curves: the error is refused, or inside the combined uncertainty.

    With the force scale free (the default) the load changer's 2 % and the coil's 3 % become
    their ratio, which the fit finds, and a common 3 % scale, which the coil amplifier's
    stated uncertainty covers; with the file's load-changer characteristic as it is, the
    fit is refused or its combined uncertainties (the load changer's stated 2 % among the
    inputs of the mass check since issue 28) cover the errors.
    """
    from emfc_ros.core.ident.balance_names import DEFAULT_FREE, PAN_FORCE_SCALE
    truth = truth_values(unit.truth)
    res = identify(unit.recording, unit.section_table,
                   unit.options(amplifiers_from_static=False))
    g = res.greybox
    assert list(g.characteristics) == ['load_changer']      # no amplifier curve
    assert 'time-domain fit' in g.characteristics['load_changer']
    rows = {r['name']: r for r in res.to_dict()['model_parameters']}
    assert rows['coil_amplifier.coeffs_A_per_V_pow']['status'] == 'fixed'
    assert g.fit.parameters[PAN_FORCE_SCALE] == pytest.approx(0.98 / 1.03, rel=2e-3)
    for name in MECHANICS:
        error = g.fit.parameters[name] - truth[name]
        assert abs(error / truth[name]) > 0.02                   # the coil's 3 % is there
        combined = math.hypot(g.fit.standard_errors[name], g.systematic_uncertainty(name))
        assert res.success is False or abs(error) < 2.0 * combined, name
    fixed = [n for n in DEFAULT_FREE if n != PAN_FORCE_SCALE]
    refused = identify(unit.recording, unit.section_table,
                       unit.options(amplifiers_from_static=False, free=fixed))
    if refused.success:     # within the characteristics' stated uncertainties: covered
        g = refused.greybox
        for name in MECHANICS:
            error = g.fit.parameters[name] - truth[name]
            combined = math.hypot(g.fit.standard_errors[name], g.systematic_uncertainty(name))
            assert abs(error) < 2.0 * combined, name
        # the load changer's 2 % is there, and its stated 2 % dominates c2's budget
        assert abs(g.fit.parameters['c2_Nm_per_rad'] / truth['c2_Nm_per_rad'] - 1.0) > 0.03
        assert g.systematic.dominant('c2_Nm_per_rad')[0][0] == 'load_changer_force_relative'


def test_a_drawn_unit_keeps_the_drawn_mechanics_and_draws_its_characteristics():
    from emfc_ros.core.ident.offnominal import draw_unit
    from emfc_ros.core.model.parameters import BalanceParameters
    seed = TEST_SEEDS[1]
    unit = draw_unit(seed, force_constants=True)
    assert unit.params.mechanics == draw_balance(seed).mechanics
    assert unit == draw_unit(seed, force_constants=True)             # reproducible
    nominal = BalanceParameters()
    for key in ('coil_amplifier_gain', 'load_changer_amplifier_gain', 'motor_coefficient',
                'load_changer_force'):
        assert 0.97 <= unit.factors[key] <= 1.03 and unit.factors[key] != 1.0, key
    assert unit.params.motor.coeffs_N_per_A_per_mm_pow[0] == pytest.approx(
        nominal.motor.coeffs_N_per_A_per_mm_pow[0] * unit.factors['motor_coefficient'])
    assert abs(unit.factors['coil_amplifier_offset_A']) <= 2e-5
    assert unit.sensor_gain == unit.factors['sensor_gain'] != 1.0
    # without force constants they stay the file's
    assert draw_unit(seed).params.motor == nominal.motor


@pytest.mark.slow
def test_the_ratio_of_the_force_constants_is_identified_by_default():
    """``load_changer_force_scale`` in the default ``greybox.free``: the actuators' ratio."""
    from emfc_ros.core.ident.balance_names import DEFAULT_FREE, PAN_FORCE_SCALE
    from emfc_ros.core.ident.offnominal import draw_unit, unit_experiment
    assert PAN_FORCE_SCALE in DEFAULT_FREE
    seed = TEST_SEEDS[2]
    unit = draw_unit(seed, force_constants=True, sensor_gain_relative=0.0)
    rec = record_draw(unit.params, seed, experiment=unit_experiment(), draw_seed=seed)
    res = identify(rec.recording, rec.section_table, rec.options())
    assert res.success, (res.failures, res.warnings)
    g = res.greybox
    ratio = unit.factors['load_changer_force'] / unit.factors['motor_coefficient']
    assert g.fit.parameters[PAN_FORCE_SCALE] == pytest.approx(ratio, rel=1e-3)
    # what is left is the common scale of the coil's force constant (a stated input)
    truth = truth_values(rec.truth)
    common = 1.0 / unit.factors['motor_coefficient']
    for name in MECHANICS:
        assert got_ratio(g, truth, name) == pytest.approx(common, rel=0.01), name
    assert g.derived['low_mode_frequency_Hz'].value == pytest.approx(rec.modal.low_mode_Hz,
                                                                     rel=5e-4)
    rows = {r['name']: r for r in res.to_dict()['model_parameters']}
    assert rows['load_changer.coeffs_N_per_A_pow']['status'] == 'identified (time-domain fit)'
    inputs = {i['name'] for i in res.to_dict()['greybox']['systematic']['inputs']}
    assert 'load_changer_force_relative' not in inputs
    assert 'motor_coefficient_relative' in inputs


def got_ratio(g, truth, name):
    """Identified over true value of a parameter."""
    return g.fit.parameters[name] / truth[name]
