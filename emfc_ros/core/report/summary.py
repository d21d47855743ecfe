"""
The Markdown summary of an identification result.

What was identified, the key numbers with their uncertainty, fit % per section and warnings.
"""

from __future__ import annotations

from typing import Any, Mapping, Optional, Sequence

import numpy as np


def _pm(value: Optional[float], std: Optional[float], digits: int = 5) -> str:
    if value is None:
        return 'n/a'
    if std is None or not np.isfinite(std):
        return f'{value:.{digits}g}'
    return f'{value:.{digits}g} +/- {std:.2g}'


def _modes_text(modes: Sequence[Mapping[str, Any]]) -> str:
    return '; '.join(f'{_pm(m["frequency_Hz"], m["frequency_std_Hz"])} '
                     f'({_pm(m["damping_ratio"], m["damping_ratio_std"], 4)})'
                     + (' extrapolated' if m.get('extrapolated') else '') for m in modes)


def summary_markdown(result: Any, plots: Sequence[str] = (),
                     notes: Sequence[str] = (), exports: Sequence[str] = ()) -> str:
    """
    Describe what was identified, the key numbers with uncertainty, fits and warnings.

    Parameters
    ----------
    result : IdentificationResult
        The pipeline's result.
    plots : sequence of str
        File names of the plots written next to the summary (linked).
    notes : sequence of str
        Extra lines for the warnings section (e.g. plots skipped).
    exports : sequence of str
        File names of the exported FRFs and models written next to the summary (listed).

    Returns
    -------
    str
        The Markdown text.
    """
    d: Mapping = result.to_dict()
    status = d.get('status') or {'success': True, 'failures': []}
    headline = ('**Identification succeeded**: no failure found (the warnings below still '
                'apply).' if status['success'] else
                '**Identification FAILED**: ' + '; '.join(status['failures'])
                + '. The numbers below are what the fit reached, not a usable model.')
    source = d['configuration'].get('source')
    lines = ['# Identification of the EMFC balance', '', headline, '',
             f'Recording: {d["n_samples"]} samples at {d["sample_rate_Hz"]:g} Hz '
             f'({d["duration_s"]:.3g} s), {len(d["sections"])} sections; load on the pan '
             f'{d["configuration"]["load_mass_kg"]:.6g} kg, load changer '
             f'{"coupled" if d["configuration"]["load_changer_coupled"] else "not coupled"}'
             + (f' ({source})' if source else '') + '.',
             '', 'Steps run: ' + (', '.join(f'{k} ({v:.2f} s)' for k, v in
                                            d['timings_s'].items()) or 'none') + '.', '']
    frfs = d['frequency_responses']
    if frfs:
        lines += ['## Frequency responses (lever-end position per force)', '',
                  '| FRF | estimator | band [Hz] | median coherence | fit | resonances '
                  '[Hz] (damping ratio) | anti-resonances [Hz] (damping ratio) |',
                  '|---|---|---|---|---|---|---|']
        for r in frfs:
            tf = r.get('transfer_function')
            band = (f'{r["frequency_min_Hz"]:.3g} - {r["frequency_max_Hz"]:.4g}'
                    if r['frequency_min_Hz'] is not None else '')
            coh = f'{r["median_coherence"]:.3f}' if r['median_coherence'] is not None else ''
            if tf:
                order = f'{tf["numerator_order"]}/{tf["denominator_order"]}'
                res = _modes_text(tf['resonances'])
                anti = _modes_text(tf['anti_resonances']) or 'none'
            else:
                order, res, anti = 'not fitted', '', ''
            lines.append(f'| {r["name"]} | {r["estimator"]} | {band} | {coh} | {order} | '
                         f'{res} | {anti} |')
        lines.append('')
        for r in frfs:
            sel = r.get('selected_frequencies')
            if not sel:
                continue
            lines += [f'Response of {r["name"]} at selected frequencies (LPM at the '
                      f'nearest line):', '', '| frequency [Hz] | magnitude [dB re 1 m/N] | '
                      'phase [deg] |', '|---|---|---|']
            for s in sel:
                mag = s['magnitude_dB_re_1m_per_N']
                mag_s = f'{mag:.2f}' if mag is not None else 'n/a'
                lines.append(f'| {s["frequency_Hz"]:g} | {mag_s} | {s["phase_deg"]:.1f} |')
            lines.append('')
    static = d.get('static_characteristics')
    if static:
        lines += ['## Static characteristics', '']
        for key, fit in static.items():
            lines.append(f'- {key}: `{fit["formula"]}` (R^2 {fit["r_squared"]:.6f}, '
                         f'{fit["n_plateaus"]} plateaus)')
        lines.append('')
    g = d.get('greybox')
    if g:
        lines += ['## Grey-box model (two-beam mechanics, simulation error)', '',
                  f'Optimiser {g["method"]}: {g["exit_reason"]} after '
                  f'{g["optimizer_evaluations"]} evaluations in {g["time_s"]:.2f} s.', '',
                  '| parameter | estimate | standard error | start | unit |',
                  '|---|---|---|---|---|']
        for name, p in g['parameters'].items():
            se, start = p['standard_error'], p['initial']
            lines.append(f'| {name} | {p["value"]:.6g} | '
                         f'{"n/a" if se is None else f"{se:.2g}"} | '
                         f'{"derived" if start is None else f"{start:.6g}"} | {p["unit"]} |')
        lines += ['', '| section | fit [%] | rms error [nm] | residual whiteness | '
                  'residual-input uncorrelated |', '|---|---|---|---|---|']
        for s in g['sections']:
            white = s['whiteness_fraction']
            cross = s['input_correlation_fraction']
            lines.append(f'| {s["name"]} | {s["fit_percent"]:.2f} | '
                         f'{1e9 * s["rms_error_m"]:.3g} | '
                         f'{"n/a" if white is None else f"{100 * white:.0f} %"} | '
                         f'{"n/a" if cross is None else f"{100 * cross:.0f} %"} |')
        lin = g['linearised_model']
        poles = ', '.join(f'{p["frequency_Hz"]:.5g} Hz (zeta {p["damping_ratio"]:.4g})'
                          for p in lin['poles'][::2])
        zeros = ', '.join(f'{z["signed_frequency_Hz"]:.5g} Hz' for z in lin['zeros_coil'][::2])
        lines += ['', f'Linearised fitted model: poles {poles}; coil zeros {zeros}.', '']
    lines += model_parameter_lines(d.get('model_parameters'))
    if plots:
        lines += ['## Plots', ''] + [f'- [{p}]({p})' for p in plots] + ['']
    if exports:
        lines += ['## Files to load in MATLAB or Python', '',
                  'Full-resolution FRFs (`frf_*.csv`, `frf_*.npz`, `frf_*.mat` with the '
                  '`idfrd` variables `Frequency`, `ResponseData`, `CovarianceData`) and the '
                  'fitted models (`models.yaml`, `models.mat`); fields and units in '
                  '`docs/identification_results.md`.', '']
        lines += [f'- [{e}]({e})' for e in exports] + ['']
    warn = list(d['warnings']) + list(notes)
    lines += ['## Warnings', ''] + ([f'- {w}' for w in warn] if warn else ['- none']) + ['']
    lines += ['All numbers with units and uncertainties are in `results.yaml`.', '']
    return '\n'.join(lines)


def model_parameter_lines(rows: Optional[Sequence[Mapping[str, Any]]]) -> list:
    """
    The table of every model parameter: identified or fixed, value, uncertainty, source.

    Parameters
    ----------
    rows : sequence of mapping or None
        ``results.yaml``'s ``model_parameters`` (``name, value, unit, status, source,
        standard_uncertainty`` and an optional ``note``).

    Returns
    -------
    list of str
        Markdown lines (none without rows).
    """
    if not rows:
        return []
    lines = ['## Every model parameter', '',
             '| parameter | value | standard uncertainty | unit | status | source |',
             '|---|---|---|---|---|---|']
    notes = []
    for r in rows:
        se = r.get('standard_uncertainty')
        mark = ''
        if r.get('note'):
            notes.append(f'{r["name"]}: {r["note"]}.')
            mark = f' [{len(notes)}]'
        lines.append(f'| {r["name"]}{mark} | {r["value"]:.6g} | '
                     f'{"" if se is None else f"{se:.2g}"} | {r["unit"]} | {r["status"]} | '
                     f'{r["source"]} |')
    lines.append('')
    lines += [f'[{i}] {n}' for i, n in enumerate(notes, 1)]
    return lines + ([''] if notes else [])
