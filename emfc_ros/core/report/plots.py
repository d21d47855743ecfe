"""
Plots of an identification result (matplotlib, Agg backend).

Bode diagrams, coherence, measured and simulated time series, residual analysis (MATLAB
``resid``), static characteristics with residuals and the pole-zero map.

Matplotlib is imported lazily; :func:`matplotlib_available` tells whether it can be used.

Drawing cost (issue 14): each figure is a bare ``matplotlib.figure.Figure`` on the Agg canvas
(no pyplot figure manager) with fixed margins (``tight_layout`` measured and re-measured every
tick label: a third of the time), logarithmic axes labelled with plain numbers (no mathtext),
PNGs written with zlib level 1, and time series reduced to their minimum and maximum per pixel
column (:func:`envelope`), which draws the same picture from about 2 000 points instead of
100 000. :mod:`~emfc_ros.core.report.background` draws them in worker processes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
import threading
from typing import Any, Dict, Optional, Sequence, Tuple, Union

import numpy as np

from emfc_ros.core.ident.errors import IdentificationError
from emfc_ros.core.ident.metrics import (CorrelationTest, input_correlation_test,
                                         whiteness_test)

#: Confidence level of the FRF bands.
CONFIDENCE = 0.95
#: Resolution of the PNGs [dots per inch].
DPI = 110
#: zlib level of the PNGs (1: fastest; the default 6 took longer than drawing a figure).
PNG_COMPRESSION = 1
#: Whether a figure of the same kind and layout as one drawn before in this process reuses
#: that figure, its axes and their ticks (:func:`_axes`). Creating the tick objects (a line,
#: a label and a grid line each, styled from the rc parameters) was about a fifth of a
#: figure's time; the picture is the same, pixel for pixel (``test_report_plots.py``).
REUSE_FIGURES = True
#: The figures kept for reuse, by thread, kind and layout (a figure is never shared by two
#: threads drawing at once, e.g. two reports of a node's service callbacks).
#: Most figures kept (beyond, the cache starts again empty).
MAX_KEPT = 32
_KEPT: Dict[Tuple[Any, ...], Tuple[Any, np.ndarray]] = {}


def matplotlib_available() -> bool:
    """
    Tell whether matplotlib can be imported (with the Agg backend).

    Returns
    -------
    bool
        True when plots can be drawn.
    """
    try:
        _pyplot()
    except ImportError:
        return False
    return True


def _pyplot() -> Any:
    import matplotlib
    matplotlib.use('Agg', force=True)
    import matplotlib.pyplot as plt
    return plt


def _figure(**kwargs: Any) -> Any:
    """A figure on the Agg canvas, outside pyplot's figure manager."""
    _pyplot()
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(**kwargs)
    FigureCanvasAgg(fig)
    return fig


def _axes(kind: str, figsize: Tuple[float, float], rows: int, sharex: bool = False,
          height_ratios: Optional[Sequence[float]] = None) -> Tuple[Any, np.ndarray]:
    """
    A figure with a column of axes: the one kept from the last figure of this layout, wiped.

    Parameters
    ----------
    kind : str
        The kind of figure (figures of different kinds never share one).
    figsize : (float, float)
        Size [inch].
    rows : int
        Axes, one above the other.
    sharex : bool
        Whether they share the x axis.
    height_ratios : sequence of float, optional
        Relative heights of the rows.

    Returns
    -------
    fig : Figure
        The figure.
    axes : ndarray of Axes, shape (rows, 1)
        Its axes, empty.
    """
    key = (kind, tuple(figsize), rows, sharex, tuple(height_ratios or ()),
           threading.get_ident())
    kept = _KEPT.get(key) if REUSE_FIGURES else None
    if kept is not None:
        for ax in kept[1].flat:
            _wipe(ax)
        return kept
    fig = _figure(figsize=figsize)
    extra = {'gridspec_kw': {'height_ratios': list(height_ratios)}} if height_ratios else {}
    axes = fig.subplots(rows, 1, sharex=sharex, squeeze=False, **extra)
    if REUSE_FIGURES:
        if len(_KEPT) >= MAX_KEPT:      # threads come and go in a long-lived node
            _KEPT.clear()
        _KEPT[key] = (fig, axes)
    return fig, axes


def _wipe(ax: Any) -> None:
    """
    Bring reused axes back to the state of new ones, their ticks kept.

    Removes what a figure drew (artists, legend, title and labels) and restores the linear
    scales, the unit view and an empty data range: the data limits of an artist drawn partly
    in axes coordinates (``axhspan``, ``fill_between`` before ``semilogx``) are computed
    through the current view and scale, so anything else left from the last figure moved a
    limit in its last digit and, once, a grid line onto the spine.
    """
    from matplotlib.transforms import Bbox
    for artist in [*ax.lines, *ax.collections, *ax.patches, *ax.texts, *ax.images]:
        artist.remove()
    legend = ax.get_legend()
    if legend is not None:
        legend.remove()
    ax.containers.clear()
    ax.set_title('')
    ax.set_xlabel('')
    ax.set_ylabel('')
    if ax.get_xscale() != 'linear':
        ax.set_xscale('linear')
    if ax.get_yscale() != 'linear':
        ax.set_yscale('linear')
    ax.viewLim.set_points(Bbox.unit().get_points())
    ax.relim()
    ax.set_autoscale_on(True)
    ax.set_prop_cycle(None)


def _save(fig: Any, path: Union[str, Path], **margins: float) -> Path:
    """Fixed margins (fractions of the figure), then the PNG."""
    fig.subplots_adjust(**margins)
    path = Path(path)
    fig.savefig(path, dpi=DPI, pil_kwargs={'compress_level': PNG_COMPRESSION})
    return path


def _plain_log(axis: Any) -> None:
    """Label a logarithmic axis with plain numbers (10, 100, 1000), minor ticks unlabelled."""
    from matplotlib.ticker import FuncFormatter, NullFormatter
    axis.set_major_formatter(FuncFormatter(lambda value, _: f'{value:g}'))
    axis.set_minor_formatter(NullFormatter())


def _log_frequency_grid(axes: Any, frequency_Hz: np.ndarray) -> None:
    """
    Decade ticks with plain labels and the 2..9 lines as one collection per axes.

    Matplotlib's minor ticks on a logarithmic axis are a tick object each (line, label,
    grid line): they took half of a Bode plot's drawing time.
    """
    from matplotlib.ticker import NullLocator
    f = np.asarray(frequency_Hz, dtype=float)
    f = f[np.isfinite(f) & (f > 0.0)]
    for ax in axes:
        ax.xaxis.set_minor_locator(NullLocator())
        _plain_log(ax.xaxis)
        ax.grid(True, which='major', alpha=0.3)
    if f.size == 0:
        return
    decades = np.arange(np.floor(np.log10(f.min())), np.ceil(np.log10(f.max())) + 1)
    lines = (np.arange(2.0, 10.0)[None, :] * 10.0 ** decades[:, None]).ravel()
    lines = lines[(lines > f.min()) & (lines < f.max())]
    for ax in axes:
        ax.vlines(lines, 0.0, 1.0, transform=ax.get_xaxis_transform(), colors='0.5',
                  linewidths=0.5, alpha=0.25, zorder=0.5)


def envelope(x: np.ndarray, y: np.ndarray, columns: int) -> tuple:
    """
    Reduce a long trace to its minimum and maximum per column, in order.

    A line through the points of each column's extremes covers the same pixels as the line
    through every point when a column holds many samples (what the eye sees of a trace denser
    than the screen).

    Parameters
    ----------
    x, y : ndarray, shape (n,)
        The trace (``x`` increasing).
    columns : int
        Columns to reduce to (the plot's width in pixels).

    Returns
    -------
    (ndarray, ndarray)
        At most ``2 columns + 2`` points, the first and last sample among them; the input
        when it is not longer than that.
    """
    x = np.asarray(x)
    y = np.asarray(y)
    n = y.size
    if columns < 1 or n <= 2 * columns + 2:
        return x, y
    k = -(-n // columns)
    full = (n // k) * k
    blocks = y[:full].reshape(-1, k)
    base = np.arange(blocks.shape[0]) * k
    keep = [base + blocks.argmin(axis=1), base + blocks.argmax(axis=1)]
    if full < n:
        tail = y[full:]
        keep.append(np.array([full + int(tail.argmin()), full + int(tail.argmax())]))
    idx = np.unique(np.concatenate(keep + [np.array([0, n - 1])]))
    return x[idx], y[idx]


def _wrap_deg(rad: np.ndarray) -> np.ndarray:
    # phases in [-360, 0) deg: the balance's responses sit near -180 deg
    return np.mod(np.degrees(rad), 360.0) - 360.0


def plot_bode(frf: Any, path: Union[str, Path], title: Optional[str] = None) -> Path:
    """
    Bode magnitude and phase of a measured FRF with its confidence band and the models.

    Draws the measurement (points) with its 95 % band, the chosen transfer-function fit and,
    when present, the grey-box model's linearisation.

    Parameters
    ----------
    frf : FrfResult
        One FRF of :class:`~emfc_ros.core.ident.pipeline.IdentificationResult`.
    path : str or Path
        PNG file to write.
    title : str, optional
        Figure title (default the FRF's name).

    Returns
    -------
    Path
        The file written.
    """
    frd = frf.frd
    f = frd.frequency_Hz
    mag = np.abs(frd.response)
    ok = np.isfinite(frd.response)
    fig, axes = _axes('bode', (8.0, 6.5), 2, sharex=True)
    ax_m, ax_p = axes[:, 0]
    with np.errstate(divide='ignore', invalid='ignore'):
        lo, hi, ph_lo, ph_hi = frd.confidence_bounds(CONFIDENCE)
        lo = np.where(lo > 0.0, lo, np.nan)
        ax_m.fill_between(f, 20 * np.log10(lo), 20 * np.log10(hi), color='C0', alpha=0.25,
                          lw=0, label=f'{100 * CONFIDENCE:.0f} % confidence')
        ax_m.semilogx(f[ok], 20 * np.log10(mag[ok]), '.', ms=2, color='C0',
                      label=f'measured ({frd.estimator})')
        phase = _wrap_deg(np.angle(frd.response))
        offset = phase - np.degrees(np.angle(frd.response))
        ax_p.fill_between(f, np.degrees(ph_lo) + offset, np.degrees(ph_hi) + offset, color='C0',
                          alpha=0.25, lw=0)
        ax_p.semilogx(f[ok], phase[ok], '.', ms=2, color='C0')
        if frf.fit is not None:
            h = frf.fit.chosen.response(f)
            c = frf.fit.chosen
            ax_m.semilogx(f, 20 * np.log10(np.abs(h)), '-', color='C1',
                          label=f'TF fit {c.numerator_order}/{c.denominator_order}')
            ax_p.semilogx(f, _wrap_deg(np.angle(h)), '-', color='C1')
        if frf.model_response is not None:
            h = frf.model_response
            ax_m.semilogx(f, 20 * np.log10(np.abs(h)), '--', color='C2',
                          label='grey-box model (linearised)')
            ax_p.semilogx(f, _wrap_deg(np.angle(h)), '--', color='C2')
    ax_m.set_ylabel('magnitude [dB re 1 m/N]')
    ax_p.set_ylabel('phase [deg]')
    ax_p.set_xlabel('frequency [Hz]')
    ax_p.set_ylim(-370.0, 10.0)
    ax_p.set_yticks(np.arange(-360.0, 1.0, 90.0))
    ax_m.grid(True, axis='y', alpha=0.3)
    ax_p.grid(True, axis='y', alpha=0.3)
    _log_frequency_grid((ax_m, ax_p), f)
    ax_m.legend(loc='lower left', fontsize=8)
    kind = 'pan force' if frf.input == 'pan' else 'coil force'
    ax_m.set_title(title or f'{frf.section}: position per {kind}')
    return _save(fig, path, left=0.11, right=0.97, top=0.95, bottom=0.08, hspace=0.08)


def plot_time_series(greybox: Any, section: str, path: Union[str, Path],
                     max_points: int = 20000) -> Path:
    """
    Measured and simulated position of one section, and their difference.

    Parameters
    ----------
    greybox : BalanceGreyboxResult
        The grey-box result with the per-section signals.
    section : str
        Section name.
    path : str or Path
        PNG file to write.
    max_points : int
        Most points drawn per trace: a longer trace is drawn as its minimum and maximum per
        column (:func:`envelope`, at most one column per pixel of the figure).

    Returns
    -------
    Path
        The file written.
    """
    t = greybox.time_s[section]
    y = greybox.measured_m[section]
    yh = greybox.simulated_m[section]
    fit = next((s for s in greybox.fit.sections if s.name == section), None)
    width = (9.0, 5.5)
    columns = max(1, min(int(width[0] * DPI), max_points // 2))
    fig, axes = _axes('time', width, 2, sharex=True, height_ratios=(3, 1))
    ax, ax_e = axes[:, 0]
    # measured drawn wide and light underneath, simulated thin and dashed on top: both
    # stay visible where they coincide
    ax.plot(*envelope(t, 1e6 * y, columns), lw=2.4, color='C0', alpha=0.45, zorder=2,
            solid_capstyle='butt', label='measured')
    ax.plot(*envelope(t, 1e6 * yh, columns), lw=0.8, color='k', ls=(0, (4, 2)), zorder=3,
            label='simulated (grey-box)')
    ax_e.plot(*envelope(t, 1e9 * (y - yh), columns), lw=0.5, color='C3',
              label='measured - simulated')
    ax_e.legend(loc='upper right', fontsize=8)
    ax.set_ylabel('position [um]')
    ax_e.set_ylabel('error [nm]')
    ax_e.set_xlabel('time from section start [s]')
    label = f' (fit {float(np.min(fit.fit_percent)):.2f} %)' if fit is not None else ''
    ax.set_title(f'{section}: lever-end position{label}')
    ax.legend(loc='upper right', fontsize=8)
    ax.grid(True, alpha=0.3)
    ax_e.grid(True, alpha=0.3)
    return _save(fig, path, left=0.09, right=0.98, top=0.94, bottom=0.1, hspace=0.1)


def plot_coherence(frf: Any, path: Union[str, Path]) -> Path:
    """
    Coherence of a measured FRF over frequency.

    Parameters
    ----------
    frf : FrfResult
        One FRF of the result.
    path : str or Path
        PNG file to write.

    Returns
    -------
    Path
        The file written.
    """
    frd = frf.frd
    f = np.asarray(frd.frequency_Hz, dtype=float)
    coh = np.asarray(frd.coherence, dtype=float)
    ok = np.isfinite(coh)
    fig, axes = _axes('coherence', (8.0, 3.5), 1)
    ax = axes[0, 0]
    kind = 'multiple' if frf.two_input else 'ordinary'
    ax.semilogx(f[ok], coh[ok], '.-', ms=2, lw=0.5, color='C0',
                label=f'{kind} coherence ({frd.estimator})')
    if not np.any(ok):
        ax.text(0.5, 0.5, f'the {frd.estimator} estimator gives no coherence',
                transform=ax.transAxes, ha='center', va='center')
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel('frequency [Hz]')
    ax.set_ylabel('coherence [1]')
    ax.set_title(f'{frf.name}: coherence of position and force')
    ax.grid(True, axis='y', alpha=0.3)
    if np.any(ok):
        _log_frequency_grid((ax,), f[ok])
    ax.legend(loc='lower left', fontsize=8)
    return _save(fig, path, left=0.09, right=0.97, top=0.9, bottom=0.15)


@dataclass(frozen=True)
class ResidualAnalysis:
    """
    Residual correlations of one grey-box section, as MATLAB ``resid`` shows them.

    Attributes
    ----------
    section : str
        Section name.
    autocorrelation : CorrelationTest
        Normalised autocorrelation of ``measured - simulated`` position at lags
        ``0..max_lag`` [samples] (1 at lag 0) and the band ``z / sqrt(N)``.
    cross_correlations : dict of str to CorrelationTest
        Per varied model input (``'coil setpoint'``, ``'load-changer setpoint'``):
        normalised cross-correlation of residual and input at lags ``-max_lag..max_lag``.
    sample_period_s : float
        Duration of one lag [s].
    confidence : float
        Two-sided confidence level of the bands.
    """

    section: str
    autocorrelation: CorrelationTest
    cross_correlations: Dict[str, CorrelationTest]
    sample_period_s: float
    confidence: float


def residual_analysis(greybox: Any, section: str, max_lag: int = 25,
                      confidence: float = CONFIDENCE) -> Optional[ResidualAnalysis]:
    """
    Residual auto- and cross-correlation of one section with their confidence bands.

    Parameters
    ----------
    greybox : BalanceGreyboxResult
        The grey-box result (per-section measured, simulated position and inputs).
    section : str
        Section name.
    max_lag : int
        Largest lag [samples] (MATLAB ``resid``'s default 25).
    confidence : float
        Two-sided confidence level of the bands (0.95 by default; MATLAB ``resid`` uses 0.99).

    Returns
    -------
    ResidualAnalysis or None
        None when the residual is too short or identically zero.
    """
    e = np.asarray(greybox.measured_m[section], dtype=float) - np.asarray(
        greybox.simulated_m[section], dtype=float)
    try:
        white = whiteness_test(e, max_lag, confidence)
    except IdentificationError:
        return None
    auto = CorrelationTest(np.concatenate(([0], white.lags)),
                           np.concatenate(([1.0], white.values)), white.bound,
                           white.fraction_inside)
    cross = {}
    u = getattr(greybox, 'inputs_V', {}).get(section)
    if u is not None:
        u = np.asarray(u, dtype=float).reshape(e.size, -1)
        for j, name in enumerate(('coil setpoint', 'load-changer setpoint')[:u.shape[1]]):
            if np.ptp(u[:, j]) > 0.0:
                cross[name] = input_correlation_test(e, u[:, j], max_lag, confidence)
    t = np.asarray(greybox.time_s[section], dtype=float)
    dt = float(t[1] - t[0]) if t.size > 1 else float('nan')
    return ResidualAnalysis(section, auto, cross, dt, confidence)


def plot_residuals(analysis: ResidualAnalysis, path: Union[str, Path]) -> Path:
    """
    Residual autocorrelation and residual-input cross-correlations with their bands.

    Laid out as MATLAB ``resid``: the autocorrelation of the residual on top, below one
    panel per varied input with the cross-correlation (positive lags: the residual lags the
    input); the shaded region is the confidence band ``+/- z / sqrt(N)``.

    Parameters
    ----------
    analysis : ResidualAnalysis
        From :func:`residual_analysis`.
    path : str or Path
        PNG file to write.

    Returns
    -------
    Path
        The file written.
    """
    panels = [('residual autocorrelation, lags from 1', analysis.autocorrelation)]
    panels += [(f'residual x {name}', test) for name, test in
               analysis.cross_correlations.items()]
    height = 2.6 * len(panels) + 0.6
    fig, axes = _axes('resid', (8.0, height), len(panels))
    pct = f'{100 * analysis.confidence:.0f} %'
    for ax, (label, test) in zip(axes[:, 0], panels):
        lags = np.asarray(test.lags)
        ax.axhspan(-test.bound, test.bound, color='C0', alpha=0.2, lw=0,
                   label=f'{pct} confidence band')
        ax.vlines(lags, 0.0, test.values, color='C1', lw=1.2)
        ax.plot(lags, test.values, 'o', ms=3, color='C1',
                label=f'{label} ({100 * test.fraction_inside:.0f} % of lags inside)')
        ax.axhline(0.0, color='k', lw=0.5)
        ax.set_ylabel('normalised correlation [1]')
        ax.grid(True, alpha=0.3)
        ax.legend(loc='best', fontsize=8)
    axes[-1, 0].set_xlabel(f'lag [samples of {1e3 * analysis.sample_period_s:.4g} ms]')
    axes[0, 0].set_title(f'{analysis.section}: residual analysis (measured - simulated '
                         f'position)')
    return _save(fig, path, left=0.11, right=0.97, top=1.0 - 0.35 / height,
                 bottom=0.5 / height, hspace=0.3)


STATIC_TITLES = {'coil_amplifier': 'coil amplifier I(U)',
                 'load_changer_amplifier': 'load-changer amplifier I(U)',
                 'load_changer': 'load changer F(I)'}


def plot_static_fit(key: str, fit: Any, x: np.ndarray, y: np.ndarray,
                    path: Union[str, Path]) -> Path:
    """
    A static characteristic: plateau means, the fitted polynomial and the residuals.

    Parameters
    ----------
    key : str
        ``coil_amplifier``, ``load_changer_amplifier`` or ``load_changer``.
    fit : PolynomialFit
        The fitted polynomial.
    x, y : ndarray
        Plateau means in the fit's units (``fit.x_unit``, ``fit.y_unit``).
    path : str or Path
        PNG file to write.

    Returns
    -------
    Path
        The file written.
    """
    x = np.asarray(x, dtype=float)
    y = np.asarray(y, dtype=float)
    grid = np.linspace(float(x.min()), float(x.max()), 400)
    fig = _figure(figsize=(8.0, 5.5))
    ax, ax_r = fig.subplots(2, 1, sharex=True, gridspec_kw={'height_ratios': [3, 1.3]})
    ax.plot(x, y, 'o', ms=4, color='C0', label=f'plateau means ({x.size})')
    ax.plot(grid, fit(grid), '-', color='C1', lw=1.0,
            label=f'{fit.formula()} (R^2 {fit.r_squared:.6f})')
    res = y - fit(x)
    ax_r.axhspan(-2 * fit.residual_std, 2 * fit.residual_std, color='C1', alpha=0.15, lw=0,
                 label='+/- 2 residual std')
    ax_r.plot(x, res, 'o', ms=3, color='C3', label='plateau mean - fit')
    ax_r.axhline(0.0, color='k', lw=0.5)
    ax.set_ylabel(f'{fit.y_name} [{fit.y_unit}]')
    ax_r.set_ylabel(f'residual [{fit.y_unit}]')
    ax_r.set_xlabel(f'{fit.x_name} [{fit.x_unit}]')
    ax.set_title(f'static characteristic: {STATIC_TITLES.get(key, key)}')
    for a in (ax, ax_r):
        a.grid(True, alpha=0.3)
        a.legend(loc='best', fontsize=8)
    return _save(fig, path, left=0.12, right=0.97, top=0.94, bottom=0.1, hspace=0.08)


def plot_pole_zero(result: Any, path: Union[str, Path]) -> Optional[Path]:
    """
    Pole-zero map of every transfer-function fit and of the grey-box linearisation.

    Real and imaginary parts are shown divided by 2 pi, in Hz, on symmetric logarithmic axes
    (the balance's modes lie decades apart). Transfer-function fits: poles crosses, zeros
    circles; grey-box linearisation: poles plus signs, zeros squares.

    Parameters
    ----------
    result : IdentificationResult
        The pipeline's result.
    path : str or Path
        PNG file to write.

    Returns
    -------
    Path or None
        The file written; None when there is no model.
    """
    # (label, poles, zeros, pole marker, zero marker); the grey-box model's poles are shared
    # by both inputs and drawn once
    models = []
    for r in result.frfs:
        if r.fit is not None:
            c = r.fit.chosen
            models.append((f'TF fit {r.name} ({c.numerator_order}/{c.denominator_order})',
                           [p.s_rad_per_s for p in c.poles], [z.s_rad_per_s for z in c.zeros],
                           'x', 'o'))
    if result.greybox is not None:
        lin = result.greybox.linear_model
        models.append(('grey-box linearised', [p.s_rad_per_s for p in lin.poles()], [],
                       '+', 's'))
        for name in ('coil', 'pan'):
            models.append((f'grey-box linearised, {name}', [],
                           [z.s_rad_per_s for z in lin.zeros(name)], '+', 's'))
    if not models:
        return None
    fig = _figure(figsize=(8.0, 6.5))
    ax = fig.subplots()
    every = []
    for k, (label, poles, zeros, pmark, zmark) in enumerate(models):
        p = np.asarray(poles, dtype=complex) / (2 * np.pi)
        z = np.asarray(zeros, dtype=complex) / (2 * np.pi)
        every += list(p) + list(z)
        color = f'C{k % 10}'
        if p.size:
            ax.plot(p.real, p.imag, pmark, ms=12 if pmark == '+' else 8, mew=1.5, color=color,
                    label=f'{label}: poles')
        if z.size:
            ax.plot(z.real, z.imag, zmark, ms=11 if zmark == 's' else 7, mfc='none', mew=1.2,
                    color=color, label=f'{label}: zeros')
    vals = np.abs(np.concatenate([np.real(every), np.imag(every)]))
    # round-off parts (a real root's 1e-12 imaginary part) must not set the linear range
    vals = vals[vals > 1e-6 * vals.max()] if vals.size else vals
    thresh = float(10 ** np.floor(np.log10(vals.min()))) if vals.size else 1.0
    ax.set_xscale('symlog', linthresh=thresh)
    ax.set_yscale('symlog', linthresh=thresh)
    _plain_log(ax.xaxis)
    _plain_log(ax.yaxis)
    ax.axhline(0.0, color='k', lw=0.5)
    ax.axvline(0.0, color='k', lw=0.5)
    ax.set_xlabel('real part / 2 pi [Hz]')
    ax.set_ylabel('imaginary part / 2 pi [Hz]')
    ax.set_title('pole-zero map (continuous time, s / 2 pi)')
    ax.grid(True, which='both', alpha=0.3)
    ax.legend(loc='best', fontsize=7)
    return _save(fig, path, left=0.11, right=0.97, top=0.94, bottom=0.08)
