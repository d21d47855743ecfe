"""Exports a MATLAB or Python user loads (FRFs, models) and the report's plots."""

import dataclasses

import numpy as np
import pytest
from scipy import io as sio
from test_pipeline_balance import short_experiment, START, TRUTH
from test_pipeline_steps import staircase_recording
import yaml

from emfc_ros.core.ident.balance_experiment import section_table, simulate_experiment
from emfc_ros.core.ident.pipeline import identify
from emfc_ros.core.model.parameters import MechanicalParameters
from emfc_ros.core.report import read_frf_csv, read_frf_npz, residual_analysis, write_report
from emfc_ros.core.report.exports import ExportError, FRF_COLUMNS, frf_columns


@pytest.fixture(scope='module')
def report(tmp_path_factory):
    """A real identification of the simulated balance (FRFs, TF fits, grey-box) written."""
    recording = simulate_experiment(TRUTH, short_experiment(), seed=3)
    cfg = {'load_mass_kg': recording.load_mass_kg, 'load_changer_coupled': True,
           'balance': START.to_mapping()}
    result = identify(recording, section_table(recording), cfg)
    out = tmp_path_factory.mktemp('report')
    written = write_report(result, out)
    results = yaml.safe_load((out / 'results.yaml').read_text())
    return result, out, written, results


def _text(value) -> str:
    return str(np.asarray(value).squeeze())


def _response(num, den, frequency_Hz):
    s = 2j * np.pi * np.asarray(frequency_Hz)
    return np.polyval(num, s) / np.polyval(den, s)


def _ss_response(a, b, c, d, frequency_Hz):
    out = []
    for f in frequency_Hz:
        x = np.linalg.solve(2j * np.pi * f * np.eye(a.shape[0]) - a, b)
        out.append(c @ x + d)
    return np.array(out)


def test_frf_mat_matches_results_yaml(report):
    result, out, _, results = report
    assert len(results['frequency_responses']) == len(result.frfs) >= 4
    for r in results['frequency_responses']:
        m = sio.loadmat(out / f'frf_{r["name"]}.mat')
        n = r['n_frequencies']
        f = m['Frequency']
        assert f.shape == (n, 1)
        assert m['ResponseData'].shape == (1, 1, n)
        assert np.iscomplexobj(m['ResponseData'])
        assert m['CovarianceData'].shape == (1, 1, n, 2, 2)
        assert f.min() == pytest.approx(r['frequency_min_Hz'], rel=1e-12)
        assert f.max() == pytest.approx(r['frequency_max_Hz'], rel=1e-12)
        assert np.nanmedian(m['Coherence']) == pytest.approx(r['median_coherence'], rel=1e-12)
        # units as results.yaml states them
        assert _text(m['FrequencyUnit']) == 'Hz'
        assert _text(m['ResponseUnit']) == r['unit'] == 'm/N'
        assert r['input'] == f'{_text(m["InputName"])} [{_text(m["InputUnit"])}]'
        assert r['output'] == f'{_text(m["OutputName"])} [{_text(m["OutputUnit"])}]'
        units = m['Units'][0, 0]
        assert _text(units['Frequency']) == 'Hz' and _text(units['ResponseData']) == 'm/N'
        assert _text(units['CovarianceData']) == '(m/N)^2'
        assert _text(m['Estimator']) == r['estimator']
        assert _text(m['HoldCompensation']) == r['hold_compensation']
        assert _text(m['Name']) == r['name']
        # hold removed: a continuous-time FRF (Ts = 0)
        assert m['Ts'].item() == (0.0 if r['hold_compensation'] != 'none'
                                  else 1.0 / results['sample_rate_Hz'])
        # circular errors: covariance diag(std^2 / 2, std^2 / 2)
        std = m['ResponseStd'].ravel()
        cov = m['CovarianceData'][0, 0]
        np.testing.assert_allclose(cov[:, 0, 0], std ** 2 / 2, rtol=1e-12)
        np.testing.assert_allclose(cov[:, 1, 1], std ** 2 / 2, rtol=1e-12)
        assert not np.any(cov[:, 0, 1])
        # the TF fit's response is results.yaml's polynomials evaluated on the grid
        tf = r.get('transfer_function')
        fit = m['TfFitResponseData'].ravel()
        if tf is None:
            assert np.all(np.isnan(fit))
        else:
            expected = _response(tf['numerator_s_rad_per_s'], tf['denominator_s_rad_per_s'],
                                 f.ravel())
            np.testing.assert_allclose(fit, expected, rtol=1e-6)
        # the measured response is the pipeline's, bit for bit
        frf = result.frf(r['section'], r['name'].split('.')[-1])
        np.testing.assert_array_equal(m['ResponseData'].ravel(), frf.frd.response)


def test_two_input_section_as_one_idfrd(report):
    _, out, written, results = report
    sections = sorted({r['section'] for r in results['frequency_responses'] if r['two_input']})
    assert len(sections) == 2
    for section in sections:
        path = out / f'frf_{section}.mat'
        assert path in written['exports']
        m = sio.loadmat(path, simplify_cells=True)
        coil = sio.loadmat(out / f'frf_{section}.coil.mat', simplify_cells=True)
        pan = sio.loadmat(out / f'frf_{section}.pan.mat', simplify_cells=True)
        n = coil['Frequency'].size
        assert m['ResponseData'].shape == (2, n) or m['ResponseData'].shape == (1, 2, n)
        h = np.reshape(m['ResponseData'], (1, 2, n))
        np.testing.assert_array_equal(h[0, 0], coil['ResponseData'])
        np.testing.assert_array_equal(h[0, 1], pan['ResponseData'])
        cov = np.reshape(m['CovarianceData'], (1, 2, n, 2, 2))
        np.testing.assert_array_equal(cov[0, 1], pan['CovarianceData'])
        assert list(m['InputName']) == ['coil force', 'pan force']
        assert list(m['InputUnit']) == ['N', 'N'] and m['OutputUnit'] == 'm'
        np.testing.assert_array_equal(m['Coherence'][:, 1], pan['Coherence'])
    raw = sio.loadmat(out / f'frf_{sections[0]}.mat')
    assert raw['ResponseData'].shape == (1, 2, raw['Frequency'].size)


def test_models_mat_matches_results_yaml(report):
    _, out, _, results = report
    m = sio.loadmat(out / 'models.mat', simplify_cells=True)
    fits = [r for r in results['frequency_responses'] if r.get('transfer_function')]
    assert len(fits) >= 2
    assert set(m['ModelNames']) == ({'tf_' + r['name'].replace('.', '_') for r in fits}
                                    | {'greybox_linearised'})
    f = np.geomspace(1.0, 2000.0, 40)
    for r in fits:
        tf = r['transfer_function']
        s = m['tf_' + r['name'].replace('.', '_')]
        np.testing.assert_array_equal(s['Numerator'], tf['numerator_s_rad_per_s'])
        np.testing.assert_array_equal(s['Denominator'], tf['denominator_s_rad_per_s'])
        assert s['InputName'] == r['input'] and s['OutputName'] == r['output']
        assert s['Units']['Poles'] == 'rad/s'
        # resonances of results.yaml are the complex poles of the exported model
        poles = np.atleast_1d(s['Poles'])
        upper = sorted(abs(p) / (2 * np.pi) for p in poles if p.imag > 0)
        np.testing.assert_allclose(upper, sorted(x['frequency_Hz'] for x in tf['resonances']),
                                   rtol=1e-9)
        # the state-space form is the same model
        h_ss = _ss_response(np.atleast_2d(s['A']), np.atleast_2d(s['B']).reshape(-1, 1),
                            np.atleast_2d(s['C']), np.atleast_2d(s['D']), f).ravel()
        np.testing.assert_allclose(h_ss, _response(s['Numerator'], s['Denominator'], f),
                                   rtol=1e-6)
    g = m['greybox_linearised']
    lin = results['greybox']['linearised_model']
    a, b, c, d = g['A'], g['B'], g['C'].reshape(1, -1), g['D'].reshape(1, -1)
    assert a.shape == (4, 4) and b.shape == (4, 2)
    assert list(g['InputName']) == ['coil force', 'pan force']
    assert list(g['InputUnit']) == ['N', 'N'] and g['OutputUnit'] == 'm'
    poles = np.atleast_1d(g['Poles'])
    got = sorted((p.real, abs(p.imag)) for p in poles)
    want = sorted((p['real_rad_per_s'], p['imag_rad_per_s']) for p in lin['poles'])
    np.testing.assert_allclose(got, want, rtol=1e-9)
    for j, name in enumerate(('coil', 'pan')):
        gain = float(-(c @ np.linalg.solve(a, b[:, j]))[0] + d[0, j])
        assert gain == pytest.approx(lin[f'static_gain_{name}_m_per_N'], rel=1e-9)
        assert g[f'StaticGain{name.capitalize()}_m_per_N'] == pytest.approx(gain, rel=1e-12)
        # the transfer-function coefficients are the state-space model
        np.testing.assert_allclose(_response(g['Numerator'][j], g['Denominator'], f),
                                   _ss_response(a, b[:, [j]], c, d[:, [j]], f).ravel(),
                                   rtol=1e-6)
    # the mechanics of the fitted model (the table also lists the pan load and the
    # characteristics, which the exported model does not hold)
    mechanics = set(MechanicalParameters.__dataclass_fields__)
    rows = {p['name']: p['value'] for p in results['model_parameters']
            if p['name'] in mechanics}
    assert set(rows) == mechanics
    assert all(g['Parameters'][k] == pytest.approx(v, rel=1e-12) for k, v in rows.items())
    # models.yaml holds the same numbers
    doc = yaml.safe_load((out / 'models.yaml').read_text())
    np.testing.assert_array_equal(doc['greybox_linearised']['state_space']['A'], a)
    assert [t['name'] for t in doc['transfer_function_fits']] == [r['name'] for r in fits]
    assert 'rad/s' in doc['greybox_linearised']['state_space']['units']
    assert all('m/N' in t['state_space']['units'] for t in doc['transfer_function_fits'])
    for t in doc['transfer_function_fits']:
        s = m['tf_' + t['name'].replace('.', '_')]
        np.testing.assert_array_equal(np.atleast_2d(s['A']), t['state_space']['A'])


def test_frf_csv_and_npz_round_trip(report):
    result, out, written, _ = report
    names = {p.name for p in written['exports']}
    assert {'models.mat', 'models.yaml'} <= names
    for frf in result.frfs:
        cols = frf_columns(frf)
        assert list(cols) == [k for k, _ in FRF_COLUMNS]
        assert all(k.endswith(('_Hz', '_m_per_N', '_deg', '_dB_re_1m_per_N'))
                   or k == 'coherence' for k in cols)
        csv_path = out / f'frf_{frf.name}.csv'
        npz_path = out / f'frf_{frf.name}.npz'
        assert csv_path.name in names and npz_path.name in names
        back_csv = read_frf_csv(csv_path)
        back_npz = read_frf_npz(npz_path)
        for k, v in cols.items():
            np.testing.assert_array_equal(back_csv[k], v)
            np.testing.assert_array_equal(back_npz[k], v)
        assert back_npz['name'] == frf.name and back_npz['unit'] == 'm/N'
        assert back_npz['estimator'] == frf.frd.estimator
        # a generic reader sees the same numbers under the same names
        table = np.genfromtxt(csv_path, delimiter=',', names=True)
        np.testing.assert_array_equal(table['frequency_Hz'], frf.frd.frequency_Hz)
        np.testing.assert_array_equal(table['response_real_m_per_N'] + 1j
                                      * table['response_imag_m_per_N'], frf.frd.response)
        np.testing.assert_array_equal(table['coherence'], frf.frd.coherence)


def test_bad_csv_is_refused_with_the_reason(report, tmp_path):
    _, out, _, _ = report
    text = next(out.glob('frf_*.csv')).read_text().splitlines()
    bad = tmp_path / 'bad.csv'
    bad.write_text('\n'.join([text[0].replace('frequency_Hz', 'frequency')] + text[1:]))
    with pytest.raises(ExportError, match='header'):
        read_frf_csv(bad)
    bad.write_text('\n'.join([text[0], text[1].replace(',', ',x', 1)]))
    with pytest.raises(ExportError, match='not a number'):
        read_frf_csv(bad)


def test_plots_of_a_real_identification(report):
    result, out, written, _ = report
    names = [p.name for p in written['plots']]
    expected = {f'{kind}_{r.name}.png' for r in result.frfs for kind in ('bode', 'coherence')}
    expected |= {f'{kind}_{s}.png' for s in result.greybox.time_s for kind in ('time', 'resid')}
    expected.add('pole_zero.png')
    assert set(names) == expected and len(names) == len(expected)
    for p in written['plots']:
        data = p.read_bytes()
        assert data[:4] == b'\x89PNG' and len(data) > 10000
    summary = (out / 'summary.md').read_text()
    assert 'resid_coil_chirp.png' in summary and 'models.mat' in summary


def test_residual_analysis_bands(report):
    result, _, _, _ = report
    g = result.greybox
    a = residual_analysis(g, 'coil_chirp')
    n = g.time_s['coil_chirp'].size
    auto = a.autocorrelation
    assert auto.lags[0] == 0 and auto.values[0] == 1.0 and auto.lags[-1] == 25
    assert auto.bound == pytest.approx(1.959964 / np.sqrt(n), rel=1e-6)
    # only the varied input is correlated: the load changer rests in the coil chirp
    assert list(a.cross_correlations) == ['coil setpoint']
    assert list(a.cross_correlations['coil setpoint'].lags) == list(range(-25, 26))
    # a white residual stays inside the 95 % band at about 95 % of the lags
    noise = 1e-9 * np.random.default_rng(1).standard_normal(n)
    white = dataclasses.replace(g, simulated_m={'coil_chirp': g.measured_m['coil_chirp']
                                                - noise})
    w = residual_analysis(white, 'coil_chirp', max_lag=400)
    assert 0.92 <= w.autocorrelation.fraction_inside <= 0.98
    # (neighbouring lags of a cross-correlation with the slow chirp are correlated: wider)
    cross = w.cross_correlations['coil setpoint']
    assert cross.bound == w.autocorrelation.bound and cross.fraction_inside >= 0.85
    # the fitted model's residual at 10 kHz is coloured (slow model error): outside the band
    assert auto.fraction_inside < 0.5


def test_static_fit_plots(tmp_path):
    _, rec, sections = staircase_recording()
    res = identify(rec, sections, {'frf': {'enabled': False}, 'greybox': {'enabled': False}})
    written = write_report(res, tmp_path)
    names = sorted(p.name for p in written['plots'])
    assert names == ['static_coil_amplifier.png', 'static_load_changer.png',
                     'static_load_changer_amplifier.png']
    assert all(p.stat().st_size > 10000 for p in written['plots'])
    assert written['exports'] == []
    x, y = res.static.points['coil_amplifier']
    assert x.size == res.static.n_plateaus['coil_amplifier'] == 9
    np.testing.assert_allclose(res.static.fits['coil_amplifier'](x), y, atol=1e-6)
