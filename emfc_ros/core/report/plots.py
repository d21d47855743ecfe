"""
Plots of an identification result: Bode diagrams and time series (matplotlib, Agg backend).

Matplotlib is imported lazily; :func:`matplotlib_available` tells whether it can be used.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Optional, Union

import numpy as np

#: Confidence level of the FRF bands.
CONFIDENCE = 0.95


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
    plt = _pyplot()
    frd = frf.frd
    f = frd.frequency_Hz
    mag = np.abs(frd.response)
    ok = np.isfinite(frd.response)
    fig, (ax_m, ax_p) = plt.subplots(2, 1, sharex=True, figsize=(8.0, 6.5))
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
    ax_m.grid(True, which='both', alpha=0.3)
    ax_p.grid(True, which='both', alpha=0.3)
    ax_m.legend(loc='lower left', fontsize=8)
    kind = 'pan force' if frf.input == 'pan' else 'coil force'
    ax_m.set_title(title or f'{frf.section}: position per {kind}')
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


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
        Longer records are decimated (every k-th sample) for drawing.

    Returns
    -------
    Path
        The file written.
    """
    plt = _pyplot()
    t = greybox.time_s[section]
    y = greybox.measured_m[section]
    yh = greybox.simulated_m[section]
    step = max(1, t.size // max_points)
    fit = next((s for s in greybox.fit.sections if s.name == section), None)
    fig, (ax, ax_e) = plt.subplots(2, 1, sharex=True, figsize=(9.0, 5.5),
                                   gridspec_kw={'height_ratios': [3, 1]})
    ax.plot(t[::step], 1e6 * y[::step], lw=0.6, color='C0', label='measured')
    ax.plot(t[::step], 1e6 * yh[::step], lw=0.6, color='C1', label='simulated (grey-box)')
    ax_e.plot(t[::step], 1e9 * (y - yh)[::step], lw=0.5, color='C3')
    ax.set_ylabel('position [um]')
    ax_e.set_ylabel('error [nm]')
    ax_e.set_xlabel('time from section start [s]')
    label = f' (fit {float(np.min(fit.fit_percent)):.2f} %)' if fit is not None else ''
    ax.set_title(f'{section}: lever-end position{label}')
    ax.legend(loc='upper right', fontsize=8)
    ax.grid(True, alpha=0.3)
    ax_e.grid(True, alpha=0.3)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
