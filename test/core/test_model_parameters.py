"""Balance parameters: defaults, the shipped YAML, both file forms and validation messages."""

import copy
from pathlib import Path

import pytest
import yaml

from emfc_ros.core.errors import ConfigError
from emfc_ros.core.model import BalanceParameters, MechanicalParameters

YAML = Path(__file__).resolve().parents[2] / 'config' / 'balance_default.yaml'


def _defaults():
    return BalanceParameters().to_mapping()


def test_defaults_are_the_notes_table():
    m = MechanicalParameters()
    assert (m.l1_m, m.l2_m, m.l3_m, m.mp_kg) == (0.012, 0.060, 0.030, 0.060)
    assert (m.m1_kg, m.r1_m, m.h1_m, m.J1c_kgm2) == (0.030, 0.020, 0.0, 1.225e-5)
    assert (m.m2_kg, m.r2_m, m.h2_m, m.J2c_kgm2) == (0.004, 0.015, 0.0, 3.0e-7)
    assert (m.m3_kg, m.c1_Nm_per_rad, m.d1_Nms_per_rad) == (0.015, 0.10, 4.21e-4)
    assert (m.c2_Nm_per_rad, m.d2_Nms_per_rad, m.F_off_N) == (20.69, 2.28e-4, 0.0)
    assert (m.g_m_per_s2, m.load_changer_mass_kg) == (9.81, 0.025)


def test_shipped_yaml_loads_and_equals_defaults():
    assert BalanceParameters.load_yaml(str(YAML)) == BalanceParameters()
    doc = yaml.safe_load(YAML.read_text())
    assert set(doc) == {'/**'}
    assert BalanceParameters.from_document(doc) == BalanceParameters()


def test_plain_yaml_form_and_round_trip(tmp_path):
    path = tmp_path / 'plain.yaml'
    path.write_text(yaml.safe_dump({'balance': _defaults()}))
    assert BalanceParameters.load_yaml(str(path)) == BalanceParameters()
    node_form = {'plant_simulator': {'ros__parameters': {'balance': _defaults()}}}
    assert BalanceParameters.from_document(node_form) == BalanceParameters()


def test_partial_override_with_base():
    params = BalanceParameters.from_mapping({'mechanics': {'mp_kg': 0.1}},
                                            base=BalanceParameters())
    assert params.mechanics.mp_kg == 0.1
    assert params == BalanceParameters().with_mechanics(mp_kg=0.1)


def _error(mutate):
    cfg = copy.deepcopy(_defaults())
    mutate(cfg)
    with pytest.raises(ConfigError) as info:
        BalanceParameters.from_mapping(cfg)
    return info.value


def test_negative_mass_names_key_and_range():
    err = _error(lambda c: c['mechanics'].update(m3_kg=-0.01))
    assert err.key == 'balance.mechanics.m3_kg'
    assert 'at least 0.0' in str(err) and 'allowed range [0.0, 100.0]' in str(err)


def test_missing_key_names_key_and_range():
    err = _error(lambda c: c['mechanics'].pop('c2_Nm_per_rad'))
    assert err.key == 'balance.mechanics.c2_Nm_per_rad'
    assert 'missing' in str(err) and 'allowed range (0.0, 1000000.0]' in str(err)


def test_missing_section_names_it():
    err = _error(lambda c: c.pop('sensor'))
    assert err.key == 'balance.sensor'


def test_unknown_key_names_key_and_recognised_keys():
    err = _error(lambda c: c['converters'].update(adc_bitz=16))
    assert err.key == 'balance.converters.adc_bitz'
    assert 'unknown key' in str(err) and 'adc_bits' in str(err)


def test_non_number_names_key_and_range():
    err = _error(lambda c: c['mechanics'].update(l1_m='twelve mm'))
    assert err.key == 'balance.mechanics.l1_m'
    assert 'expected a number' in str(err) and 'allowed range (0.0, 1.0]' in str(err)


def test_bad_coefficient_list_names_element():
    err = _error(lambda c: c['sensor'].update(coeffs_V_per_m_pow=[0.0, 'x']))
    assert err.key == 'balance.sensor.coeffs_V_per_m_pow[1]'
    assert 'ascending powers' in str(err)


def test_non_monotonic_characteristic_is_refused():
    # a quadratic amplifier term that folds the characteristic back inside +/-10 V
    err = _error(lambda c: c['coil_amplifier'].update(coeffs_A_per_V_pow=[0.0, 0.01, 0.001]))
    assert err.key == 'balance.coil_amplifier.coeffs_A_per_V_pow'
    assert 'monotonic' in str(err) and '-10.0' in str(err)


def test_integer_converter_field_and_ros_path_in_errors(tmp_path):
    err = _error(lambda c: c['converters'].update(adc_bits=16.5))
    assert err.key == 'balance.converters.adc_bits' and 'allowed range [1, 32]' in str(err)
    cfg = _defaults()
    cfg['mechanics']['mp_kg'] = -1.0
    path = tmp_path / 'ros.yaml'
    path.write_text(yaml.safe_dump({'/**': {'ros__parameters': {'balance': cfg}}}))
    with pytest.raises(ConfigError) as info:
        BalanceParameters.load_yaml(str(path))
    assert info.value.key == '/**.ros__parameters.balance.mechanics.mp_kg'


def test_unreadable_or_wrong_document():
    with pytest.raises(ConfigError, match='cannot read'):
        BalanceParameters.load_yaml('/nonexistent/balance.yaml')
    with pytest.raises(ConfigError, match='no top-level balance'):
        BalanceParameters.from_document({'other': 1})
