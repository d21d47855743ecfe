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


def test_plots_by_the_worker_pool_are_the_report_s_plots(tmp_path):
    """The pool draws every figure the in-process report draws, queued early or late."""
    from emfc_ros.core.ident.offnominal import draw_balance, record_draw, TEST_SEEDS
    from emfc_ros.core.paths import config_file
    from emfc_ros.core.report.background import PlotPool
    from emfc_ros.core.signals import load_experiment_file

    rec = record_draw(draw_balance(TEST_SEEDS[2]), 4, experiment=load_experiment_file(
        config_file('quick_trajectory.yaml')))
    options = rec.options(('coil_chirp', 'load_changer_chirp'))
    options.update({'static': {'enabled': False}, 'frf': {'two_input_sections': []}})
    steps = []

    def step_done(step, partial):
        steps.append(step)
        pool.submit_step(step, partial, tmp_path / 'pool')

    with PlotPool() as pool:
        res = identify(rec.recording, rec.section_table, options, on_step=step_done)
        by_pool = write_report(res, tmp_path / 'pool', pool=pool)
        assert pool.errors == []
    # the model's figures were queued when the time-domain fit converged, the grey-box's
    # others when it ended
    assert steps == ['frf', 'tf_fit', 'greybox_model', 'greybox_fit', 'greybox']
    in_process = write_report(res, tmp_path / 'here')
    names = [p.name for p in in_process['plots']]
    assert [p.name for p in by_pool['plots']] == names
    # and they are the final result's figures, pixel for pixel
    for path in by_pool['plots']:
        assert path.read_bytes() == (tmp_path / 'here' / path.name).read_bytes(), path.name
    assert {'bode_coil_chirp.coil.png', 'coherence_load_changer_chirp.pan.png',
            'time_coil_chirp.png', 'resid_load_changer_chirp.png', 'pole_zero.png'} <= set(names)
    for path in by_pool['plots']:
        assert path.read_bytes()[:4] == b'\x89PNG' and path.stat().st_size > 10000
    assert (tmp_path / 'pool' / 'summary.md').read_text().count('.png') == \
        (tmp_path / 'here' / 'summary.md').read_text().count('.png')


def test_a_figure_queued_again_with_another_key_is_drawn_again(tmp_path):
    """Same path and key: drawn once; another key: redrawn after the first, and it stays."""
    import dataclasses

    from emfc_ros.core.report.background import draw, PlotJob, PlotPool

    frf = small_result().frfs[0]
    other = dataclasses.replace(frf, model_response=2.0 * frf.frd.response)
    path = tmp_path / 'pool' / 'bode.png'
    with PlotPool() as pool:
        pool.wait([])                   # the workers have started
        pool.submit([PlotJob(path, 'bode', (frf,), '')])
        pool.submit([PlotJob(path, 'bode', (frf,), '')])        # the same: not queued again
        first = pool._futures[path]
        pool.submit([PlotJob(path, 'bode', (other,), 'model 2')])
        assert pool._futures[path] is not first
        assert pool.wait([path]) == [path]
        assert first.done() and pool.errors == []
    draw(PlotJob(tmp_path / 'first.png', 'bode', (frf,)))
    draw(PlotJob(tmp_path / 'second.png', 'bode', (other,)))
    assert (tmp_path / 'first.png').read_bytes() != (tmp_path / 'second.png').read_bytes()
    assert path.read_bytes() == (tmp_path / 'second.png').read_bytes()


def test_envelope_keeps_each_column_s_extremes_in_order():
    rng = np.random.default_rng(8)
    x = np.arange(100003) / 1e4
    y = np.cumsum(rng.standard_normal(x.size))
    xe, ye = plots_module.envelope(x, y, 900)
    assert xe.size <= 2 * 900 + 4 and np.all(np.diff(xe) > 0)
    assert (xe[0], xe[-1]) == (x[0], x[-1])
    assert ye.min() == y.min() and ye.max() == y.max()
    # every column's extremes survive: the drawn band is the full trace's
    k = -(-y.size // 900)
    for start in range(0, y.size, k * 97):
        block = slice(start, min(start + k, y.size))
        assert y[block].max() in ye and y[block].min() in ye
    short_x, short_y = plots_module.envelope(x[:50], y[:50], 900)
    np.testing.assert_array_equal(short_y, y[:50])
