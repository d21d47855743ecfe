"""
The report's figures as the plot workers draw them, against the figures of the result.

Reused axes (issue 14): a plot worker keeps one figure per kind and layout
(``plots.REUSE_FIGURES``) and wipes it for the next figure of that kind. Whatever a figure
leaves behind (limits, scales, locators, texts, legends) must not show in the next: every
figure of a full grey-box report, drawn in an order that mixes kinds and data, is compared
with the same figure drawn in fresh axes.

Figures drawn early: the model's figures (Bode diagrams with the model, the pole-zero map)
are queued once the time-domain fit has converged, before it checks its derivatives
(``on_step('greybox_model', ...)``); they must be the result's figures (same file, same key,
so the pool does not draw them again, and the same picture).
"""

from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import matplotlib.image as mimage
import numpy as np
import pytest
import yaml

from emfc_ros.core.ident.balance_experiment import (section_table, simulate_experiment,
                                                    time_scaled_mapping)
from emfc_ros.core.ident.pipeline import identify
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.report import background, plots
from emfc_ros.core.signals import experiment_from_config, find_experiment_mapping
from ros_harness import scaled

TRAJECTORY = Path(__file__).resolve().parents[2] / 'config' / 'identification_trajectory.yaml'


@pytest.fixture(scope='module')
def report(tmp_path_factory):
    """A grey-box report of an off-nominal balance (0.2x trajectory): result, figures, steps."""
    nominal = BalanceParameters()
    truth = nominal.with_mechanics(c1_Nm_per_rad=1.04 * nominal.mechanics.c1_Nm_per_rad,
                                   d2_Nms_per_rad=0.95 * nominal.mechanics.d2_Nms_per_rad)
    doc = yaml.safe_load(TRAJECTORY.read_text())
    exp = experiment_from_config(time_scaled_mapping(find_experiment_mapping(doc), 0.2))
    recording = simulate_experiment(truth, exp, seed=61307)
    out = tmp_path_factory.mktemp('figures')
    steps = []

    def on_step(step, partial):
        steps.append((step, background.step_jobs(step, partial, out)))

    result = identify(recording, section_table(recording),
                      {'load_mass_kg': recording.load_mass_kg, 'load_changer_coupled': True},
                      on_step=on_step)
    assert result.greybox is not None
    found = background.report_jobs(result, out)
    # every kind drawn into reused axes (the static figures are always drawn fresh)
    assert {job.kind for job in found} >= {'bode', 'coherence', 'time', 'resid', 'pole_zero'}
    return SimpleNamespace(result=result, jobs=found, steps=steps)


@pytest.fixture(scope='module')
def jobs(report):
    return report.jobs


def _draw_all(jobs, folder, reuse, monkeypatch):
    """Draw the figures; also the exact limits of every axes as saved (a stricter check)."""
    limits = []
    save = plots._save

    def observed(fig, path, **margins):
        written = save(fig, path, **margins)
        limits.append([(ax.get_xlim(), ax.get_ylim(), tuple(ax.dataLim.bounds),
                        ax.get_xscale(), ax.get_yscale()) for ax in fig.axes])
        return written

    monkeypatch.setattr(plots, '_save', observed)
    monkeypatch.setattr(plots, 'REUSE_FIGURES', reuse)
    plots._KEPT.clear()
    try:
        folder.mkdir()
        return [background.draw(replace(job, path=folder / job.path.name))
                for job in jobs], limits
    finally:
        plots._KEPT.clear()


@pytest.mark.parametrize('order', ['report', 'reversed', 'shuffled'])
def test_reused_axes_draw_the_fresh_figure(jobs, tmp_path, order, monkeypatch):
    sequence = list(jobs)
    if order == 'reversed':
        sequence.reverse()
    elif order == 'shuffled':
        np.random.default_rng(4242).shuffle(sequence)
    # each figure twice in a row as well: a figure after one of its own kind and data
    sequence = sequence + sequence[:3]
    fresh, fresh_limits = _draw_all(sequence, tmp_path / 'fresh', False, monkeypatch)
    reused, reused_limits = _draw_all(sequence, tmp_path / 'reused', True, monkeypatch)
    assert len(fresh) == len(reused) and all(p is not None for p in fresh)
    # the same limits to the last digit (a limit off in its last digit once moved a grid line
    # onto a spine), the same scales
    for path, a, b in zip(fresh, fresh_limits, reused_limits):
        assert a == b, path.name
    for a, b in zip(fresh, reused):
        pa, pb = mimage.imread(a), mimage.imread(b)
        assert pa.shape == pb.shape, a.name
        different = int(np.count_nonzero(np.any(pa != pb, axis=-1)))
        assert different == 0, f'{a.name}: {different} pixels differ'


def test_two_threads_never_share_a_figure(jobs, tmp_path):
    import threading
    bode = next(job for job in jobs if job.kind == 'bode')
    plots._KEPT.clear()
    together = threading.Barrier(2, timeout=scaled(60))

    def draw(k):
        together.wait()                 # both threads alive while either draws
        background.draw(replace(bode, path=tmp_path / f'{k}.png'))
        together.wait()

    threads = [threading.Thread(target=draw, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(120)
    assert len([key for key in plots._KEPT if key[0] == 'bode']) == 2
    plots._KEPT.clear()


def test_figures_of_one_layout_share_one_figure(jobs, tmp_path):
    bode = [job for job in jobs if job.kind == 'bode']
    assert len(bode) >= 2
    plots._KEPT.clear()
    for job in bode:
        background.draw(replace(job, path=tmp_path / job.path.name))
    kept = [key for key in plots._KEPT if key[0] == 'bode']
    assert len(kept) == 1
    plots._KEPT.clear()


def test_the_models_figures_are_queued_early_and_are_the_results(report, tmp_path):
    names = [step for step, _ in report.steps]
    assert names.index('greybox_model') < names.index('greybox_fit') < names.index('greybox')
    early = dict(report.steps)['greybox_model']
    assert sorted(job.kind for job in early) == ['bode'] * len(report.result.frfs) + [
        'pole_zero']
    final = {job.path: job for job in report.jobs}
    for job in early:
        # the same file and key: the pool does not draw it again at 'greybox_fit'
        assert (job.path, job.kind, job.key) == (final[job.path].path, final[job.path].kind,
                                                 final[job.path].key)
        a = background.draw(replace(job, path=tmp_path / ('early_' + job.path.name)))
        b = background.draw(replace(final[job.path], path=tmp_path / job.path.name))
        assert np.array_equal(mimage.imread(a), mimage.imread(b)), job.path.name
