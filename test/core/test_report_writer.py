"""The report folder: results.yaml, plots and summary."""

import builtins

import numpy as np
import pytest
from scipy import signal
import yaml

from emfc_ros.core.ident.pipeline import identify
from emfc_ros.core.report import plots as plots_module
from emfc_ros.core.report import write_report


def small_result():
    fs = 2000.0
    rng = np.random.default_rng(5)
    n = 8000
    force = 1e-3 * rng.standard_normal(n)
    w = 2 * np.pi * 100.0
    sysd = signal.cont2discrete(([1.0], [1e-3, 2 * 0.02 * 1e-3 * w, 1e-3 * w ** 2]), 1 / fs,
                                'zoh')
    y = signal.lfilter(sysd[0].ravel(), sysd[1], force) + 1e-9 * rng.standard_normal(n)
    rec = {'sample_rate_Hz': fs, 'coil_setpoint_V': np.zeros(n),
           'load_changer_setpoint_V': np.zeros(n), 'coil_current_A': np.zeros(n),
           'load_changer_current_A': np.zeros(n), 'position_m': y, 'coil_force_N': force,
           'load_changer_force_N': np.zeros(n)}
    cfg = {'greybox': {'enabled': False}, 'frf': {'pan_sections': [], 'two_input_sections': [],
                                                  'frequency_max_Hz': 800.0},
           'tf_fit': {'numerator_orders': [0], 'denominator_orders': [2]}}
    return identify(rec, [('coil_chirp', 0, n)], cfg)


def test_report_files(tmp_path):
    res = small_result()
    mode = res.frfs[0].fit.chosen.modes[0]
    np.testing.assert_allclose(mode.frequency_Hz, 100.0, rtol=0.01)
    written = write_report(res, tmp_path / 'out')
    data = yaml.safe_load((tmp_path / 'out' / 'results.yaml').read_text())
    tf = data['frequency_responses'][0]['transfer_function']
    np.testing.assert_allclose(tf['resonances'][0]['frequency_Hz'], mode.frequency_Hz)
    assert [p.name for p in written['plots']] == ['bode_coil_chirp.coil.png',
                                                  'coherence_coil_chirp.coil.png',
                                                  'pole_zero.png']
    assert all(p.read_bytes()[:4] == b'\x89PNG' for p in written['plots'])
    assert [p.name for p in written['exports']] == [
        'frf_coil_chirp.coil.csv', 'frf_coil_chirp.coil.npz', 'frf_coil_chirp.coil.mat',
        'models.yaml', 'models.mat']
    text = (tmp_path / 'out' / 'summary.md').read_text()
    assert 'coil_chirp.coil' in text and 'bode_coil_chirp.coil.png' in text


def test_report_without_matplotlib(tmp_path, monkeypatch):
    res = small_result()
    real_import = builtins.__import__

    def fake_import(name, *args, **kwargs):
        if name.startswith('matplotlib'):
            raise ImportError('no matplotlib')
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, '__import__', fake_import)
    assert not plots_module.matplotlib_available()
    written = write_report(res, tmp_path)
    assert written['plots'] == []
    assert 'matplotlib is not installed' in (tmp_path / 'summary.md').read_text()
    # the exports need no matplotlib
    assert (tmp_path / 'frf_coil_chirp.coil.mat').stat().st_size > 0
    assert (tmp_path / 'results.yaml').exists()


@pytest.mark.parametrize('plots', [False])
def test_report_plots_off(tmp_path, plots):
    written = write_report(small_result(), tmp_path, plots=plots)
    assert written['plots'] == [] and written['summary'][0].exists()
