"""Pipeline steps on small synthetic records: config, LPM, static fits, errors."""

import numpy as np
import pytest
from scipy import signal

from emfc_ros.core.errors import ConfigError
from emfc_ros.core.ident.balance_greybox import BalanceGreyboxModel
from emfc_ros.core.ident.errors import IdentificationError
from emfc_ros.core.ident.local_polynomial import local_polynomial_frf
from emfc_ros.core.ident.pipeline import find_plateaus, hold_factor, identify
from emfc_ros.core.ident.pipeline_config import IdentificationConfig
from emfc_ros.core.model.parameters import BalanceParameters

FS = 1000.0


def second_order(n, seed, noise=0.0):
    rng = np.random.default_rng(seed)
    u = rng.standard_normal(n)
    wn, z = 2 * np.pi * 50.0, 0.02
    sysd = signal.cont2discrete(([wn ** 2], [1, 2 * z * wn, wn ** 2]), 1 / FS, 'zoh')
    y = signal.lfilter(sysd[0].ravel(), sysd[1], u) + noise * rng.standard_normal(n)
    return u, y, sysd


def test_lpm_exact_on_transient_and_std_calibrated():
    u, y, sysd = second_order(20000, 1)
    frd, = local_polynomial_frf([u], y, FS, frequency_min_Hz=5, frequency_max_Hz=400)
    _, truth = signal.freqz(sysd[0].ravel(), sysd[1], worN=frd.frequency_Hz, fs=FS)
    # noise free: only the (small) polynomial approximation error of G and T remains
    np.testing.assert_allclose(frd.response, truth, rtol=5e-3, atol=1e-4)
    errs = []
    for seed in range(8):
        u, y, _ = second_order(20000, 10 + seed, noise=0.05)
        frd, = local_polynomial_frf([u], y, FS, frequency_min_Hz=5, frequency_max_Hz=400)
        errs.append(np.abs(frd.response - truth) ** 2 / frd.std ** 2)
    ratio = np.mean(errs)
    assert 0.6 < ratio < 1.6


def test_lpm_two_inputs():
    rng = np.random.default_rng(2)
    u1, u2 = rng.standard_normal((2, 16000))
    y = signal.lfilter([0.5, 0.2], [1.0, -0.3], u1) + signal.lfilter([-1.0], [1.0, 0.5], u2)
    a, b = local_polynomial_frf([u1, u2], y, FS, frequency_min_Hz=1)
    w = np.exp(-2j * np.pi * a.frequency_Hz / FS)
    np.testing.assert_allclose(a.response, (0.5 + 0.2 * w) / (1 - 0.3 * w), rtol=1e-6)
    np.testing.assert_allclose(b.response, -1.0 / (1 + 0.5 * w), rtol=1e-6)


def test_lpm_refuses_bad_input():
    with pytest.raises(IdentificationError):
        local_polynomial_frf([np.ones(10)], np.ones(11), FS)
    with pytest.raises(IdentificationError):
        local_polynomial_frf([np.ones(10)], np.ones(10), FS, half_width=1)


def test_hold_factor():
    np.testing.assert_allclose(hold_factor([0.0], 1e4, 'zoh'), [1.0])
    np.testing.assert_allclose(np.angle(hold_factor([1000.0], 1e4, 'zoh')), [-np.pi * 0.1])
    np.testing.assert_allclose(np.abs(hold_factor([1000.0], 1e4, 'foh')),
                               [np.sinc(0.1) ** 2])


def test_config_defaults_and_errors():
    cfg = IdentificationConfig.from_mapping({'greybox': {'method': 'pattern_search'}})
    assert cfg.greybox.method == 'pattern_search'
    assert cfg.greybox.free[-2:] == ('F_off_N', 'load_changer_force_scale')
    assert cfg.to_dict()['frf']['frequency_min_Hz'] == 5.0
    with pytest.raises(ConfigError, match='greybox.free'):
        IdentificationConfig.from_mapping({'greybox': {'free': ['c9']}})
    with pytest.raises(ConfigError, match='frf.method'):
        IdentificationConfig.from_mapping({'frf': {'method': 'magic'}})
    with pytest.raises(ConfigError, match='identification.frf'):
        IdentificationConfig.from_mapping({'frf': {'typo_Hz': 1}})


def test_find_plateaus():
    x = np.repeat([0.0, 1.0, 2.0, 2.0], [100, 50, 200, 100])
    np.testing.assert_array_equal(find_plateaus(x, 1000.0, 0.01, 0.05), [(10, 100), (160, 450)])


def staircase_recording(count=9):
    params = BalanceParameters()
    fs = 1000.0
    levels = np.linspace(-8.0, 8.0, count)
    u = np.repeat(levels, 200)
    i_c = params.coil_amplifier.current_A(u) + 1e-6 * np.random.default_rng(0).standard_normal(
        u.size)
    i_lc = params.load_changer_amplifier.current_A(-u)
    rec = {'sample_rate_Hz': fs, 'coil_setpoint_V': u, 'load_changer_setpoint_V': -u,
           'coil_current_A': i_c, 'load_changer_current_A': i_lc,
           'position_m': np.zeros(u.size),
           'load_changer_force_N': params.load_changer.force_N(i_lc)}
    return params, rec, [('amplifier_staircase', 0, u.size)]


def test_static_fits_recover_table_1():
    params, rec, sections = staircase_recording()
    cfg = {'frf': {'enabled': False}, 'greybox': {'enabled': False}}
    res = identify(rec, sections, cfg)
    fits = res.static.fits
    np.testing.assert_allclose(fits['coil_amplifier'].coefficients,
                               params.coil_amplifier.coeffs_A_per_V_pow, rtol=2e-3, atol=2e-6)
    np.testing.assert_allclose(fits['load_changer_amplifier'].coefficients,
                               params.load_changer_amplifier.coeffs_A_per_V_pow, rtol=1e-9,
                               atol=1e-12)
    np.testing.assert_allclose(fits['load_changer'].coefficients,
                               params.load_changer.coeffs_N_per_A_pow, rtol=1e-9)
    d = res.to_dict()['static_characteristics']
    assert d['coil_amplifier']['coefficients_ascending'][1]['unit'] == 'A/V'
    assert 'U^2' in d['coil_amplifier']['formula']


@pytest.mark.parametrize('count', [1, 2, 3, 4])
def test_a_short_staircase_is_a_warning_not_a_crash(count):
    """Three levels for a quadratic amplifier curve crashed the static step (issue 28)."""
    params, rec, sections = staircase_recording(count)
    res = identify(rec, sections, {'frf': {'enabled': False}, 'greybox': {'enabled': False}})
    assert res.failures == []
    degree = len(params.coil_amplifier.coeffs_A_per_V_pow) - 1
    fitted = 'coil_amplifier' in res.static.fits
    assert fitted == (count >= degree + 2), (count, degree)
    if not fitted:
        assert any(f'static: coil_amplifier: {count} distinct setpoint levels for a '
                   f'degree-{degree} curve' in w and f'at least {degree + 2} needed' in w
                   for w in res.warnings), res.warnings
    res.to_dict()                                   # the report can be written


def test_missing_channel_and_bad_sections():
    _, rec, sections = staircase_recording()
    bad = dict(rec)
    del bad['position_m']
    with pytest.raises(IdentificationError, match='position_m'):
        identify(bad, sections)
    with pytest.raises(IdentificationError, match='does not fit'):
        identify(rec, [('x', 0, 10 ** 6)])
    res = identify(rec, sections, {'greybox': {'enabled': False}})
    assert any('coil_chirp' in w for w in res.warnings)


def test_greybox_model_slices_match_full_simulation():
    params = BalanceParameters()
    u = np.zeros((3000, 2))
    u[:, 0] = 1e-3 * np.sin(np.arange(3000) * 0.05)
    model = BalanceGreyboxModel(params, 1e4, u, 0.1274, False)
    full = model.simulate_record({})
    part = model.simulate({}, model.setpoints_V[1000:2000])
    np.testing.assert_array_equal(part, full[1000:2000])
    assert model.n_simulations == 1
    alone = model.simulate({}, u[:100].copy())
    np.testing.assert_allclose(alone, full[:100], rtol=0, atol=1e-15)
