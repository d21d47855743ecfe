"""
What was on the pan: never a silent default, for bags and for live data alike.

The pan load and the load-changer coupling are resolved from ordered sources
(:mod:`emfc_ros.core.ident.plant`); without them the identification stops with an error
naming the option (``emfc-identify``) or the parameter (the identifier node) to give.
"""

import numpy as np
import pytest

from emfc_ros.core.errors import ConfigError
from emfc_ros.core.ident.from_bag import CLI_HOW_TO_GIVE
from emfc_ros.core.ident.live import identify_accumulated, resolve_live_plant
from emfc_ros.core.ident.pipeline import identify
from emfc_ros.core.ident.pipeline_config import IdentificationConfig
from emfc_ros.core.ident.plant import PlantConfigurationError, resolve_plant
from emfc_ros.core.pan_load import declared_pan_load, plant_entries
from emfc_ros.core.report.summary import summary_markdown

FAST = {'greybox': {'enabled': False}, 'static': {'enabled': False},
        'tf_fit': {'enabled': False}, 'frf': {'pan_sections': [], 'two_input_sections': []}}


def small_recording(n=4000):
    rng = np.random.default_rng(0)
    u = 1e-3 * rng.standard_normal(n)
    return {'coil_setpoint_V': u, 'load_changer_setpoint_V': np.zeros(n),
            'coil_current_A': 1e-2 * u, 'load_changer_current_A': np.zeros(n),
            'position_m': 1e-6 * np.convolve(u, np.ones(5) / 5, 'same')
            + 1e-9 * rng.standard_normal(n)}


def test_each_setting_from_the_first_source_that_has_it():
    settings, source = resolve_plant(
        [('options', {}), ('stream', {'load_mass_kg': 0.1}),
         ('parameters', {'load_mass_kg': 0.2, 'load_changer_coupled': False})],
        CLI_HOW_TO_GIVE)
    assert settings == {'load_mass_kg': 0.1, 'load_changer_coupled': False}
    assert source == 'load_mass_kg from stream; load_changer_coupled from parameters'


def test_an_unknown_pan_load_names_what_to_give():
    with pytest.raises(PlantConfigurationError) as err:
        resolve_plant([('options', {}), ('measurement description (extra)',
                                         plant_entries({'time_mode': 'sim'}))],
                      CLI_HOW_TO_GIVE)
    text = str(err.value)
    assert '--load-mass-kg' in text and 'load_mass_kg' in text
    assert 'options, measurement description (extra)' in text
    with pytest.raises(PlantConfigurationError, match='--load-changer-coupled'):
        resolve_plant([('options', {'load_mass_kg': 0.1})], CLI_HOW_TO_GIVE)
    assert isinstance(err.value, ValueError)        # callers catching ValueError see it


def test_live_data_order_options_parameters_stream():
    extra = {'load_mass_kg': 0.1024, 'load_changer_coupled': True, 'time_mode': 'sim'}
    settings, source = resolve_live_plant({}, {}, extra, '/plant_simulator')
    assert settings == {'load_mass_kg': 0.1024, 'load_changer_coupled': True}
    assert source == ('load_mass_kg from measurement description (extra) of /plant_simulator; '
                      'load_changer_coupled from measurement description (extra) of '
                      '/plant_simulator')
    settings, source = resolve_live_plant({'load_mass_kg': 0.3}, declared_pan_load(0.2, 'false'),
                                          extra)
    assert settings == {'load_mass_kg': 0.3, 'load_changer_coupled': False}
    assert source == ('load_mass_kg from options file; load_changer_coupled from identifier '
                      'parameters pan.*')
    with pytest.raises(PlantConfigurationError) as err:
        resolve_live_plant({}, declared_pan_load(-1.0, ''), {'time_mode': 'sim'})
    assert '`pan.load_mass_kg`' in str(err.value) and 'options_file' in str(err.value)


def test_declared_pan_load():
    assert declared_pan_load(-1.0, '') == {}
    assert declared_pan_load(0.0, 'true') == {'load_mass_kg': 0.0,
                                              'load_changer_coupled': True}
    with pytest.raises(ConfigError, match='pan.load_mass_kg'):
        declared_pan_load(float('nan'), '')
    with pytest.raises(ConfigError, match='pan.load_changer_coupled'):
        declared_pan_load(0.1, 'yes')


def test_no_default_pan_load_in_the_options():
    cfg = IdentificationConfig.from_mapping({})
    assert cfg.load_mass_kg is None and cfg.load_changer_coupled is None
    cfg = IdentificationConfig.from_mapping({'load_mass_kg': None, 'load_changer_coupled': False})
    assert cfg.load_mass_kg is None and cfg.load_changer_coupled is False
    with pytest.raises(ConfigError, match='identification.load_mass_kg'):
        IdentificationConfig.from_mapping({'load_mass_kg': -0.1})


def test_the_greybox_step_refuses_an_unknown_pan_load():
    rec = small_recording()
    with pytest.raises(PlantConfigurationError) as err:
        identify(rec, [('coil_chirp', 0, 4000)], {'load_changer_coupled': True},
                 sample_rate_Hz=1e4)
    assert 'load_mass_kg' in str(err.value) and 'guessed' in str(err.value)


def test_without_the_greybox_the_pan_load_is_reported_as_not_given():
    res = identify(small_recording(), [('coil_chirp', 0, 4000)], FAST, sample_rate_Hz=1e4)
    conf = res.to_dict()['configuration']
    assert conf['load_mass_kg'] is None and conf['load_changer_coupled'] is None
    assert conf['source'].startswith('not given (not needed')
    assert 'load on the pan not given' in summary_markdown(res)


def test_live_identification_takes_the_pan_load_from_the_stream_or_refuses():
    rec = small_recording()
    res = identify_accumulated(rec, [('coil_chirp', 0, 4000)], 1e4, FAST,
                               {'load_mass_kg': 0.05, 'load_changer_coupled': False}, {},
                               '/daq_bridge')
    assert res.config.load_mass_kg == 0.05 and res.config.load_changer_coupled is False
    assert 'measurement description (extra) of /daq_bridge' in res.plant_source
    with pytest.raises(PlantConfigurationError, match='pan.load_mass_kg'):
        identify_accumulated(rec, [('coil_chirp', 0, 4000)], 1e4, FAST, {'time_mode': 'x'})
