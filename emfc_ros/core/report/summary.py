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


def _value_text(value: Any) -> str:
    if isinstance(value, bool) or value is None:
        return {True: 'true', False: 'false', None: 'not given'}[value]
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(f'{v:.6g}' for v in value) + ']'
    return f'{value:.6g}'


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
    conf = d['configuration']
    source = conf.get('source')
    load = conf.get('load_mass_kg')
    coupled = conf.get('load_changer_coupled')
    lines = ['# Identification of the EMFC balance', '', headline, '',
             f'Recording: {d["n_samples"]} samples at {d["sample_rate_Hz"]:g} Hz '
             f'({d["duration_s"]:.3g} s), {len(d["sections"])} sections; load on the pan '
             + ('not given' if load is None else f'{load:.6g} kg') + ', load changer '
             + {True: 'coupled', False: 'not coupled', None: 'coupling not given'}[coupled]
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
        lines += frf_systematic_lines(frfs)
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
                         f'{fit["n_plateaus"]} plateaus)' + _static_systematic_text(fit))
        lines.append('')
    g = d.get('greybox')
    if g:
        lines += ['## Grey-box model (two-beam mechanics, simulation error)', '',
                  f'Optimiser {g["method"]}: {g["exit_reason"]} after '
                  f'{g["optimizer_evaluations"]} evaluations in {g["time_s"]:.2f} s.', '',
                  '| parameter | estimate | standard error | systematic | combined (k = 1) | '
                  'start | unit |',
                  '|---|---|---|---|---|---|---|']
        for name, p in g['parameters'].items():
            se, start = p['standard_error'], p['initial']
            sy, uc = p.get('systematic_standard_uncertainty'), p.get(
                'combined_standard_uncertainty')
            lines.append(f'| {name} | {p["value"]:.6g} | '
                         f'{"n/a" if se is None else f"{se:.2g}"} | '
                         f'{"n/a" if sy is None else f"{sy:.2g}"} | '
                         f'{"n/a" if uc is None else f"{uc:.2g}"} | '
                         f'{"derived" if start is None else f"{start:.6g}"} | {p["unit"]} |')
        lines += systematic_lines(g)
        lines += ['', '| section | fit [%] | rms error [nm] | residual white [% of lags] | '
                  'residual-input uncorrelated [% of lags] | p white | p uncorrelated | '
                  'most coherent with an input (p) |', '|---|---|---|---|---|---|---|---|']
        for s in g['sections']:
            white = s['whiteness_fraction']
            cross = s['input_correlation_fraction']
            pw, pc = s.get('whiteness_p_value'), s.get('input_correlation_p_value')
            coh = s.get('coherence')
            lines.append(f'| {s["name"]} | {s["fit_percent"]:.2f} | '
                         f'{1e9 * s["rms_error_m"]:.3g} | '
                         f'{"n/a" if white is None else f"{100 * white:.0f} %"} | '
                         f'{"n/a" if cross is None else f"{100 * cross:.0f} %"} | '
                         f'{"n/a" if pw is None else f"{pw:.2g}"} | '
                         f'{"n/a" if pc is None else f"{pc:.2g}"} | '
                         + ('n/a' if not coh else
                            f'{coh["input"]} at {coh["frequency_Hz"]:.4g} Hz, '
                            f'{coh["squared_coherence"]:.2f} ({coh["p_value"]:.2g})') + ' |')
        lines += [''] + residual_test_note(g['sections'])
        lin = g['linearised_model']
        poles = ', '.join(f'{p["frequency_Hz"]:.5g} Hz (zeta {p["damping_ratio"]:.4g})'
                          for p in lin['poles'][::2])
        zeros = ', '.join(f'{z["signed_frequency_Hz"]:.5g} Hz' for z in lin['zeros_coil'][::2])
        lines += ['', f'Linearised fitted model: poles {poles}; coil zeros {zeros}.', '']
    if g:
        lines += identifiability_lines(g)
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


def frf_systematic_lines(frfs: Sequence[Mapping[str, Any]]) -> list:
    """
    The systematic (type B) part of the FRF magnitudes and transfer-function gains.

    Parameters
    ----------
    frfs : sequence of mapping
        ``frequency_responses`` of ``results.yaml``.

    Returns
    -------
    list of str
        Markdown lines, one per input (empty without a stated budget).
    """
    seen: dict = {}
    for r in frfs:
        rel = r.get('magnitude_systematic_relative_standard_uncertainty')
        if rel is not None:
            seen.setdefault(r['input'], (rel, r.get('systematic_inputs') or {}))
    if not seen:
        return []
    lines = ['Systematic (type B) part of every magnitude and transfer-function gain, from the '
             "balance file's stated uncertainties (phases, resonance and anti-resonance "
             'frequencies and damping ratios have none: a scale moves no pole or zero):', '']
    for name, (rel, parts) in seen.items():
        top = ', '.join(f'{k} {100.0 * v:.2g} %' for k, v in list(parts.items())[:2])
        lines.append(f'- the FRFs per {name}: {100.0 * rel:.2g} % (k = 1; largest: {top})')
    return lines + ['']


def _static_systematic_text(fit: Mapping[str, Any]) -> str:
    """'; systematic a %, b % per coefficient' for a static fit's line, or ''."""
    coefs = fit.get('coefficients_ascending') or []
    rel = [abs(c['systematic_standard_uncertainty'] / c['value']) if c.get('value') else 0.0
           for c in coefs if 'systematic_standard_uncertainty' in c]
    if not rel:
        return ''
    return ('; systematic (type B, k = 1) per coefficient in ascending powers: '
            + ', '.join(f'{100.0 * r:.2g} %' for r in rel))


def residual_test_note(sections: Sequence[Mapping[str, Any]]) -> list:
    """
    What the two residual columns mean.

    Parameters
    ----------
    sections : sequence of mapping
        ``results.yaml``'s ``greybox.sections``.

    Returns
    -------
    list of str
        Markdown lines.
    """
    tested = {s.get('residual_tested', 'raw') for s in sections}
    if all(t.startswith('noise-weighted') for t in tested):
        return ['The residual columns test the **pre-whitened** residual: the output error '
                'divided by a smooth noise model estimated from the final residual (the '
                'physical shapes |H_coil|^2, |H_pan|^2 and a white floor, corrected over +/-25 '
                '% of the frequency; the transient at the section ends projected out), which '
                'is what the noise-weighted fit treats as white. Each column is the share of '
                'the lags (autocorrelation 1..25, cross-correlation with each input -25..25) '
                'inside the 99 % band 2.576/sqrt(N) (right only for a white input: a step '
                "input's plateaus put a right model's lags outside it). The verdict uses the "
                'p-values: Ljung-Box for the whiteness, and for the cross-correlation the '
                'chi-square statistic with the null covariance of the lags for the actual '
                "input (Bartlett) and the fitted parameters' estimation error; and the "
                'squared coherence with each input per frequency (Hann segments, Bonferroni '
                'over the frequencies), which names the frequency of a dynamic the model '
                'lacks. A section warns below 0.01 divided by the number of sections. The raw '
                'output error is process noise ringing at the low mode, never white, and is '
                'not tested.', '']
    return ['The residual columns test the raw output error y - y_hat (the fit was not '
            'noise-weighted): the share of the lags (autocorrelation 1..25, cross-correlation '
            'with each input -25..25) inside the 99 % band 2.576/sqrt(N). On the balance the '
            'output error is dominated by process noise ringing at the low mode, so a low '
            'whiteness share is expected and says little about the model; the parameter '
            'uncertainties come from the sandwich covariance, which does not assume white '
            'residuals.', '']


def identifiability_lines(g: Mapping[str, Any]) -> list:
    """
    What the fitted sections determine: rank, condition, inseparable combinations, fixed.

    Parameters
    ----------
    g : mapping
        ``results.yaml``'s ``greybox``.

    Returns
    -------
    list of str
        Markdown lines (none without an analysis).
    """
    ident = g.get('identifiability')
    td = g.get('time_domain_identifiability')
    if not ident and not td:
        return []
    names = ', '.join(s['name'] for s in g.get('sections', []))
    lines = ['## Identifiability (what the fitted sections determine)', '',
             f'Fisher information of the grey-box model on the sections it fits ({names}), '
             'in relative variables: a direction (a combination of relative parameter '
             'changes) counts as determined when its relative standard uncertainty is below '
             'the threshold given.', '']

    def summary(label: str, a: Mapping[str, Any]) -> None:
        lines.append(f'- {label}: {", ".join(a["names"])}: rank {a["rank"]} of '
                     f'{len(a["names"])} (threshold '
                     f'{100 * a.get("rank_threshold_relative_uncertainty", 0.3):.3g} %), '
                     f'condition number {a["condition_number"]:.3g}.')
        for u in a.get('not_determined', []):
            rel = u['relative_uncertainty']
            shown = f'{100 * rel:.3g} %' if rel is not None else 'not at all'
            lines.append(f'  - not determined: `{u["combination"]}` (to {shown})')

    if ident:
        summary('requested, frequency domain at the start', ident['requested'])
        if ident['fixed']:
            summary('left free', ident['free'])
            lines.append('- fixed on purpose at the configured values:')
            lines += [f'  - {n}: {why}' for n, why in ident['fixed'].items()]
        else:
            lines.append('- nothing fixed: the data determine every requested parameter '
                         'the analysis may fix (masses and inertias; stiffnesses and '
                         'dampings always stay free, their uncertainty says how well they '
                         'are known).')
    if td:
        summary('time-domain fit (its sandwich covariance)', td)
    return lines + ['']


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
        lines.append(f'| {r["name"]}{mark} | {_value_text(r["value"])} | '
                     f'{"" if se is None else f"{se:.2g}"} | {r["unit"]} | {r["status"]} | '
                     f'{r["source"]} |')
    lines.append('')
    lines += [f'[{i}] {n}' for i, n in enumerate(notes, 1)]
    return lines + ([''] if notes else [])


def systematic_lines(g: dict) -> list:
    """
    What the systematic part of the grey-box uncertainties is made of.

    Parameters
    ----------
    g : dict
        ``results.yaml``'s ``greybox``.

    Returns
    -------
    list of str
        Markdown lines (empty without a systematic budget).
    """
    budget = g.get('systematic')
    if not budget or not budget.get('numbers'):
        return []
    out = ['', 'Systematic part: the stated standard uncertainties of the inputs the fit takes '
           "as known (the balance file's `uncertainties`) propagated; the inputs that make "
           'up most of it:', '']
    for name, row in budget['numbers'].items():
        if name not in g['parameters'] and not name.endswith('_Hz'):
            continue
        top = ', '.join(f'{d["input"]} {100 * d["variance_share"]:.0f} %'
                        for d in row['dominant_inputs'][:3])
        if top:
            out.append(f'- {name}: {top}')
    return out
