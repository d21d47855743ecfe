"""
Identification of off-nominal balances: accuracy, coverage and honesty (issue 12 item 6).

Balances are drawn with every stiffness, damping, mass and inertia uniform within +/-10 % of
the defaults (``emfc_ros.core.ident.offnominal.draw_balance``, seeds ``BENCH_SEEDS``, never
used by the tests). Each plays the shipped trajectory (``config/identification_trajectory.yaml``)
through the simulator with noise and quantisation, the pan loaded with its balancing mass and
the load changer coupled, and is identified knowing only the pan load and the coupling
(grey-box on the four dynamic sections). Reported against the targets:

* per parameter (c1, c2, d1, d2 and any mass or inertia the fit frees): median and worst
  relative error (targets 2 % stiffness, 10 % damping);
* the two resonances and the coil anti-resonance of the fitted model's linearisation
  (target 0.5 %); worst section fit (>= 95 %); failure flags raised; identification wall
  time (< 10 s);
* a same-run baseline: each draw also identified with the grey-box started from the true
  parameters (``greybox.initial`` = truth, ``initialise_from_frf: false``), and the ratio of
  the errors, so the effect of the start is visible;
* coverage: ``--reps`` noise repetitions of one draw (``BENCH_SEEDS[0]``, noise seeds
  ``BENCH_NOISE_SEEDS``): fraction whose 95 % interval (estimate +/- 1.96 standard
  uncertainty) holds the truth, for c1, c2, d1, d2 and the modal frequencies (target 90-98 %);
* the broken inputs (pan load told 20 % wrong, position scaled by 1.1, noise-only position):
  each must raise the failure flag or report a large uncertainty.

Units and user experiments (``--units [VARIANT ...]``, issue 28): each draw is a unit of the
balance type (``offnominal.draw_unit``, benchmark seeds): the mechanics within +/-10 %, each
amplifier's gain within +/-3 % and its offset within +/-20 uA, the sensor's gain normal with
the stated 2 %. It plays the shipped trajectory followed by the staircases, as the main job
does, and is identified with the default options and only the pan load and the coupling given,
the balance file holding the type's characteristics. Variants, each on the same draws:

- ``amplifiers_true_sensor``: the sensor as its characteristic says (the accuracy target:
  the characteristics the data determine are identified);
- ``amplifiers``: as above with a sensor-gain error drawn from its stated uncertainty (the
  coverage target);
- ``force_constants``: the motor's and the load changer's force constants drawn within
  +/-3 % too, identified with the default free set (their ratio fitted:
  ``load_changer_force_scale``);
- ``force_constants_file_ratio``: ``force_constants`` with the file's load-changer
  characteristic as it is (``greybox.free`` without ``load_changer_force_scale``);
- ``user_prbs``: ``amplifiers``, with the first section a user's PRBS starting at +2.5 mV;
- ``user_multisine``: ``user_prbs`` with the second section an odd random-phase multisine on
  the load changer (``offnominal.MULTISINE_SECTION``, one DFT line in twenty excited);
- ``user_noise``: ``user_multisine`` with the coil's PRBS replaced by Gaussian noise around
  +1 mV (``offnominal.RANDOM_SECTION``).

Per variant: how often the failure flag was raised, the worst relative errors of c1, c2, d1,
d2 and of the two modes, and the coverage of the 95 % intervals ``+/-1.96 u_c`` (``u_c``
combines the statistical and the systematic uncertainty; targets 90-98 %, the flag on none
of the intact draws, c1..d2 within 2 %/10 %, modes within 0.5 %). Results go to
``bench/results/ident_units.json`` (a run of some variants keeps the others' results).

    .venv/bin/python bench/bench_ident_offnominal.py --json bench/results/ident_offnominal.json
    .venv/bin/python bench/bench_ident_offnominal.py --quick --jobs 1      # 3 draws, 5 reps

    .venv/bin/python bench/bench_ident_offnominal.py --units --draws 20   # every variant
    .venv/bin/python bench/bench_ident_offnominal.py --units amplifiers force_constants \
        --draws 40

``--jobs 0`` runs every task in the main process (for a debugger or a profiler).
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import os
from pathlib import Path
import platform
import sys
import time
from typing import Any, Dict, List, Optional, Sequence, Tuple

for _var in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')   # one core per worker process

import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # the working tree, not an installed copy

from emfc_ros.core.ident.balance_names import DEFAULT_FREE, PAN_FORCE_SCALE  # noqa: E402
from emfc_ros.core.ident.offnominal import (BENCH_NOISE_SEEDS, BENCH_SEEDS,  # noqa: E402
                                            BROKEN_INPUTS, default_experiment, draw_balance,
                                            draw_unit, modal_truth, MULTISINE_SECTION,
                                            PRBS_SECTION, RANDOM_SECTION, record_draw,
                                            truth_values, unit_experiment, with_position_gain)
from emfc_ros.core.ident.pipeline import identify  # noqa: E402

#: Targets printed next to the figures.
TARGETS = {'stiffness': 0.02, 'damping': 0.10, 'mode': 0.005, 'section_fit_percent': 95.0,
           'coverage': (0.90, 0.98), 'time_s': 10.0}
#: Margins of the unit tests: an intact draw outside them is a bad result.
MARGINS = {'stiffness': 0.05, 'damping': 0.25, 'mode': 0.01, 'section_fit_percent': 90.0}
#: A relative standard uncertainty above this counts as 'large' for a broken input.
LARGE_UNCERTAINTY = 0.10
STIFFNESSES = ('c1_Nm_per_rad', 'c2_Nm_per_rad')
DAMPINGS = ('d1_Nms_per_rad', 'd2_Nms_per_rad')
CORE = STIFFNESSES + DAMPINGS
MODES = ('low_mode_Hz', 'high_mode_Hz', 'anti_resonance_Hz')
Z95 = 1.96

_EXPERIMENT = None


def experiment() -> Any:
    """Return the shipped trajectory, loaded once per process."""
    global _EXPERIMENT
    if _EXPERIMENT is None:
        _EXPERIMENT = default_experiment()
    return _EXPERIMENT


def target_of(name: str) -> Optional[float]:
    """Return the relative-error target of a parameter (None for masses and inertias)."""
    if name in STIFFNESSES:
        return TARGETS['stiffness']
    if name in DAMPINGS:
        return TARGETS['damping']
    return None


#: Where the grey-box result reports each mode (``to_dict()['greybox']['derived']``).
DERIVED_MODES = {'low_mode_Hz': 'low_mode_frequency_Hz', 'high_mode_Hz': 'high_mode_frequency_Hz',
                 'anti_resonance_Hz': 'coil_anti_resonance_frequency_Hz',
                 'low_damping_ratio': 'low_mode_damping_ratio',
                 'high_damping_ratio': 'high_mode_damping_ratio',
                 'anti_resonance_damping_ratio': 'coil_anti_resonance_damping_ratio'}
#: Their names in the modal truth (``offnominal.ModalTruth``).
MODE_DAMPINGS = ('low_damping_ratio', 'high_damping_ratio', 'anti_resonance_damping_ratio')


def reported_modes(greybox: Optional[Dict[str, Any]]) -> Optional[Dict[str, Tuple[float, float]]]:
    """
    Return the grey-box modes with their standard uncertainties, when the result reports them.

    Reads ``result.to_dict()['greybox']['derived']`` (``value`` and ``standard_uncertainty``
    of ``low_mode_frequency_Hz``, ``high_mode_frequency_Hz`` and
    ``coil_anti_resonance_frequency_Hz``).

    Parameters
    ----------
    greybox : dict or None
        The ``greybox`` part of :meth:`IdentificationResult.to_dict`.

    Returns
    -------
    dict or None
        ``{'low_mode_Hz': (value, std), ...}`` or None when not reported.
    """
    derived = (greybox or {}).get('derived') or {}
    out = {}
    for key, name in DERIVED_MODES.items():
        entry = derived.get(name)
        if entry and entry.get('value') is not None and \
                entry.get('standard_uncertainty') is not None:
            out[key] = (float(entry['value']), float(entry['standard_uncertainty']))
    return out or None


def assess(rec: Any, options: Dict[str, Any]) -> Dict[str, Any]:
    """
    Identify one record and compare with its truth.

    Parameters
    ----------
    rec : OffNominalRecord
        The record.
    options : dict
        Identification options.

    Returns
    -------
    dict
        Time, status, parameter estimates and errors, modal errors, section fits.
    """
    start = time.perf_counter()
    res = identify(rec.recording, rec.section_table, options)
    out: Dict[str, Any] = {'time_s': time.perf_counter() - start, 'success': res.success,
                           'failures': list(res.failures), 'n_warnings': len(res.warnings),
                           'steps_s': dict(res.timings_s)}
    if res.greybox is None:
        out['greybox'] = None
        return out
    fit = res.greybox.fit
    truth = truth_values(rec.truth)
    params = {}
    for name in fit.free_names:
        est, se = float(fit.parameters[name]), float(fit.standard_errors[name])
        tv = truth.get(name, 0.0)
        row = {'estimate': est, 'standard_error': se, 'truth': tv,
               'inside_95': bool(abs(est - tv) <= Z95 * se) if math.isfinite(se) else False}
        if tv != 0.0:
            row['error'] = est / tv - 1.0
            row['relative_standard_error'] = se / abs(tv)
        else:
            row['absolute_error'] = est - tv
        params[name] = row
    out['parameters'] = params
    out['optimiser_success'] = bool(fit.success)
    out['exit_reason'] = str(fit.exit_reason)
    out['section_fit_percent'] = {s.name: float(np.min(s.fit_percent)) for s in fit.sections}
    out['worst_section_fit_percent'] = min(out['section_fit_percent'].values())
    truth_modes = {k: getattr(rec.modal, k) for k in MODES}
    try:
        fitted = modal_truth(res.greybox.linear_model)
        out['modes'] = {k: {'estimate': getattr(fitted, k), 'truth': truth_modes[k],
                            'error': getattr(fitted, k) / truth_modes[k] - 1.0}
                        for k in MODES}
    except ValueError as exc:
        out['modes'] = None
        out['modes_problem'] = str(exc)
    try:
        reported = reported_modes(res.to_dict().get('greybox'))
    except Exception as exc:   # noqa: B902 (a serialisation bug must not stop the benchmark)
        reported = None
        out['to_dict_problem'] = repr(exc)
    truths = dict(truth_modes, **{k: getattr(rec.modal, k) for k in MODE_DAMPINGS})
    out['reported_modes'] = None if reported is None else {
        k: {'estimate': v, 'standard_uncertainty': s, 'truth': truths[k],
            'inside_95': bool(abs(v - truths[k]) <= Z95 * s)}
        for k, (v, s) in reported.items()}
    # modes of the transfer-function fit of the coil FRF, which do carry a std
    try:
        chosen = res.frf('coil_chirp', 'coil').fit.chosen

        def nearest(roots: Any, key: str) -> Any:
            # a higher order may add a near-cancelling pole-zero pair far above: match by
            # frequency, not by position in the list
            return min(roots, key=lambda m: abs(m.frequency_Hz - truth_modes[key]))

        pairs = [(k, nearest(chosen.modes, k)) for k in ('low_mode_Hz', 'high_mode_Hz')]
        if chosen.anti_resonances:
            pairs.append(('anti_resonance_Hz',
                          nearest(chosen.anti_resonances, 'anti_resonance_Hz')))
        out['coil_frf_modes'] = {
            k: {'estimate': m.frequency_Hz, 'standard_uncertainty_Hz': m.frequency_std_Hz,
                'truth': truth_modes[k],
                'error': m.frequency_Hz / truth_modes[k] - 1.0,
                'inside_95': bool(abs(m.frequency_Hz - truth_modes[k])
                                  <= Z95 * m.frequency_std_Hz)}
            for k, m in pairs}
        for (k, m), d in zip(pairs, MODE_DAMPINGS):
            zeta = getattr(rec.modal, d)
            out['coil_frf_modes'][d] = {
                'estimate': m.damping_ratio, 'standard_uncertainty': m.damping_std,
                'truth': zeta, 'error': m.damping_ratio / zeta - 1.0,
                'inside_95': bool(abs(m.damping_ratio - zeta) <= Z95 * m.damping_std)}
    except (KeyError, AttributeError, IndexError):
        out['coil_frf_modes'] = None
    return out


def run_draw(seed: int, spread: float) -> Dict[str, Any]:
    """Draw, record (noise seed = draw seed) and identify, from the FRF start and the truth."""
    params = draw_balance(seed, spread)
    start = time.perf_counter()
    rec = record_draw(params, seed, experiment=experiment(), draw_seed=seed)
    row = {'kind': 'draw', 'draw_seed': seed, 'noise_seed': seed,
           'simulation_s': time.perf_counter() - start,
           'load_mass_kg': rec.known_load_mass_kg, 'peak_position_m': rec.peak_position_m,
           'truth_parameters': truth_values(params),
           'truth_modes': {k: getattr(rec.modal, k) for k in MODES}}
    row['estimate'] = assess(rec, rec.options())
    row['truth_start'] = assess(rec, rec.truth_start_options())
    return row


def run_rep(draw_seed: int, noise_seed: int, spread: float) -> Dict[str, Any]:
    """One noise repetition of the coverage draw."""
    rec = record_draw(draw_balance(draw_seed, spread), noise_seed, experiment=experiment(),
                      draw_seed=draw_seed)
    return {'kind': 'rep', 'draw_seed': draw_seed, 'noise_seed': noise_seed,
            'estimate': assess(rec, rec.options())}


def run_broken(draw_seed: int, name: str, spread: float) -> Dict[str, Any]:
    """Identify a broken record of one draw (noise seed = draw seed)."""
    rec = record_draw(draw_balance(draw_seed, spread), draw_seed, experiment=experiment(),
                      draw_seed=draw_seed)
    broken = BROKEN_INPUTS[name](rec)
    out = assess(broken, broken.options())
    rel = [p.get('relative_standard_error', 0.0) for n, p in out.get('parameters', {}).items()
           if n in CORE]
    largest = max(rel) if rel else float('nan')
    params = out.get('parameters', {})
    right = all(abs(params[n].get('error', float('inf'))) <= target_of(n)
                for n in CORE if n in params) and bool(params) and \
        all(abs(m['error']) <= TARGETS['mode'] for m in (out.get('modes') or {}).values())
    if not out['success']:
        verdict = 'failure flag'
    elif largest > LARGE_UNCERTAINTY:
        verdict = 'large uncertainty'
    elif right:
        verdict = ('not needed: c, d and the modes are right within the targets (the broken '
                   'input does not enter them)')
    else:
        verdict = 'MISSED (a confident wrong answer)'
    return {'kind': 'broken', 'name': name, 'description': broken.broken,
            'draw_seed': draw_seed, 'largest_relative_standard_error': largest,
            'verdict': verdict, 'estimate': out}


#: Variants of ``--units`` (module docstring), in the order they run.
UNIT_VARIANTS = ('amplifiers_true_sensor', 'amplifiers', 'force_constants',
                 'force_constants_file_ratio', 'user_prbs', 'user_multisine', 'user_noise')
_UNIT_EXPERIMENTS: Optional[Dict[str, Any]] = None


def unit_experiments() -> Dict[str, Any]:
    """Return the shipped trajectory with staircases and the users' plans, once per process."""
    global _UNIT_EXPERIMENTS
    if _UNIT_EXPERIMENTS is None:
        _UNIT_EXPERIMENTS = {
            'shipped': unit_experiment(), 'user_prbs': unit_experiment(PRBS_SECTION),
            'user_multisine': unit_experiment(PRBS_SECTION, MULTISINE_SECTION),
            'user_noise': unit_experiment(RANDOM_SECTION, MULTISINE_SECTION)}
    return _UNIT_EXPERIMENTS


UNIT_NUMBERS = ('c1_Nm_per_rad', 'c2_Nm_per_rad', 'd1_Nms_per_rad', 'd2_Nms_per_rad')
UNIT_MODES = (('low_mode_frequency_Hz', 'low_mode_Hz'), ('high_mode_frequency_Hz', 'high_mode_Hz'))


def run_unit(seed: int, variant: str) -> Dict[str, Any]:
    """Identify one drawn unit in one variant (``--units``) and compare with its truth."""
    experiments = unit_experiments()
    t0 = time.perf_counter()
    unit = draw_unit(seed, force_constants=variant.startswith('force_constants'),
                     sensor_gain_relative=0.0 if variant == 'amplifiers_true_sensor' else 0.02)
    user = variant.startswith('user_')
    exp = experiments[variant if user else 'shipped']
    rec = with_position_gain(record_draw(unit.params, seed, experiment=exp, draw_seed=seed),
                             unit.sensor_gain)
    sections = tuple(s.name for s in exp.sections if 'staircase' not in s.name)
    options = rec.options(sections=sections)
    if variant == 'force_constants_file_ratio':
        options['greybox']['free'] = [n for n in DEFAULT_FREE if n != PAN_FORCE_SCALE]
    if user:
        options['frf'] = {'coil_sections': [sections[0]], 'pan_sections': [sections[1]],
                          'two_input_sections': list(sections[2:])}
    res = identify(rec.recording, rec.section_table, options)
    row = {'seed': seed, 'variant': variant, 'success': res.success,
           'time_s': time.perf_counter() - t0,
           'failures': res.failures[:3], 'factors': unit.factors}
    g = res.greybox
    if g is None:
        return row
    truth = truth_values(rec.truth)
    for n in UNIT_NUMBERS:
        v, se = g.fit.parameters[n], g.fit.standard_errors[n]
        u_c = math.hypot(se, g.systematic_uncertainty(n) if math.isfinite(
            g.systematic_uncertainty(n)) else 0.0)
        row[n] = {'relative_error': v / truth[n] - 1.0, 'z_combined': (v - truth[n]) / u_c,
                  'z_statistical': (v - truth[n]) / se}
    for key, attr in UNIT_MODES:
        d = g.derived.get(key)
        if d is None:
            continue
        t = getattr(rec.modal, attr)
        row[key] = {'relative_error': d.value / t - 1.0,
                    'z_combined': (d.value - t) / d.combined_uncertainty,
                    'z_statistical': (d.value - t) / d.standard_uncertainty}
    return row


def summarise_units(rows: Sequence[Dict[str, Any]],
                    variants: Sequence[str]) -> Dict[str, Any]:
    """Per variant: draws, share flagged, worst errors and coverages (``--units``)."""
    summary = {}
    for variant in variants:
        mine = [r for r in rows if r['variant'] == variant]
        entry: Dict[str, Any] = {'draws': len(mine),
                                 'flagged': float(np.mean([not r['success'] for r in mine])),
                                 'flagged_seeds': [r['seed'] for r in mine if not r['success']]}
        for n in UNIT_NUMBERS + tuple(k for k, _ in UNIT_MODES):
            got = [r[n] for r in mine if n in r]
            if not got:
                continue
            entry[n] = {
                'worst_relative_error': float(max(abs(x['relative_error']) for x in got)),
                'coverage_95_combined': float(np.mean([abs(x['z_combined']) <= Z95
                                                       for x in got])),
                'coverage_95_statistical': float(np.mean([abs(x['z_statistical']) <= Z95
                                                          for x in got])),
                'std_of_z_combined': float(np.std([x['z_combined'] for x in got]))}
        summary[variant] = entry
    return summary


def write_units(summary: Dict[str, Any], rows: List[Dict[str, Any]], variants: Sequence[str],
                path: Path) -> None:
    """Write ``--units`` results, keeping those of variants this run did not repeat."""
    if path.is_file():
        old = json.loads(path.read_text())
        summary = dict(old.get('summary', {}), **summary)
        rows = [r for r in old.get('rows', []) if r.get('variant') not in variants] + rows
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({'command': ' '.join(sys.argv), 'summary': summary,
                                'rows': rows}, indent=1, default=_plain))
    print(f'wrote {path}')


def _call(task: Tuple[str, tuple]) -> Dict[str, Any]:
    kind, args = task
    return {'draw': run_draw, 'rep': run_rep, 'broken': run_broken,
            'unit': run_unit}[kind](*args)


# ---------------------------------------------------------------- summaries


def _errors(rows: Sequence[Dict], case: str, name: str) -> List[float]:
    out = []
    for r in rows:
        p = (r[case].get('parameters') or {}).get(name)
        if p is not None and 'error' in p:
            out.append(p['error'])
    return out


def _mode_errors(rows: Sequence[Dict], case: str, name: str) -> List[float]:
    return [r[case]['modes'][name]['error'] for r in rows if r[case].get('modes')]


def _stats(errors: Sequence[float]) -> Dict[str, Any]:
    if not errors:
        return {'n': 0, 'median_abs': None, 'worst': None}
    e = np.asarray(errors, dtype=float)
    worst = float(e[np.argmax(np.abs(e))])
    return {'n': int(e.size), 'median_abs': float(np.median(np.abs(e))), 'worst': worst}


def _pct(value: Optional[float], digits: int = 2, sign: bool = False) -> str:
    if value is None or not math.isfinite(value):
        return '-'
    return f'{100 * value:+.{digits}f} %' if sign else f'{100 * value:.{digits}f} %'


def _bad_intact(r: Dict) -> List[str]:
    # reasons an intact draw is outside the unit tests' margins
    e = r['estimate']
    why = []
    for name in CORE:
        p = (e.get('parameters') or {}).get(name)
        limit = MARGINS['stiffness'] if name in STIFFNESSES else MARGINS['damping']
        if p is None or abs(p.get('error', 0.0)) > limit:
            why.append(name)
    if not e.get('modes') or any(abs(m['error']) > MARGINS['mode']
                                 for m in e['modes'].values()):
        why.append('modes')
    if e.get('worst_section_fit_percent', -math.inf) < MARGINS['section_fit_percent']:
        why.append('section fit')
    return why


def summarise(draws: List[Dict], reps: List[Dict], broken: List[Dict]) -> Dict[str, Any]:
    """Aggregate the rows into the figures the table prints."""
    names = []
    for r in draws:
        for n in (r['estimate'].get('parameters') or {}):
            if n not in names and n != 'F_off_N':
                names.append(n)
    params = {}
    for n in names:
        est, base = _stats(_errors(draws, 'estimate', n)), _stats(_errors(draws, 'truth_start', n))
        ratio = est['median_abs'] / base['median_abs'] \
            if est['n'] and base['n'] and base['median_abs'] > 0 else None
        params[n] = {'estimate': est, 'truth_start': base, 'median_error_ratio': ratio,
                     'target': target_of(n)}
    modes = {}
    for n in MODES:
        est, base = _stats(_mode_errors(draws, 'estimate', n)), \
            _stats(_mode_errors(draws, 'truth_start', n))
        ratio = est['median_abs'] / base['median_abs'] \
            if est['n'] and base['n'] and base['median_abs'] > 0 else None
        modes[n] = {'estimate': est, 'truth_start': base, 'median_error_ratio': ratio,
                    'target': TARGETS['mode']}
    frf_modes = {n: _stats([r['estimate']['coil_frf_modes'][n]['error'] for r in draws
                            if n in (r['estimate'].get('coil_frf_modes') or {})])
                 for n in MODES}
    fits = {case: [r[case].get('worst_section_fit_percent', -math.inf) for r in draws]
            for case in ('estimate', 'truth_start')}
    times = {case: [r[case]['time_s'] for r in draws] for case in ('estimate', 'truth_start')}
    flagged = [r['draw_seed'] for r in draws if not r['estimate']['success']]
    bad = {r['draw_seed']: _bad_intact(r) for r in draws}
    silent = [s for s, why in bad.items() if why and s not in flagged]
    failures = sorted({f for r in draws for f in r['estimate']['failures']})
    coverage: Dict[str, Any] = {'n_repetitions': len(reps)}
    for n in CORE:
        inside = [r['estimate']['parameters'][n]['inside_95'] for r in reps
                  if n in (r['estimate'].get('parameters') or {})]
        ests = [r['estimate']['parameters'][n]['estimate'] for r in reps
                if n in (r['estimate'].get('parameters') or {})]
        ses = [r['estimate']['parameters'][n]['standard_error'] for r in reps
               if n in (r['estimate'].get('parameters') or {})]
        coverage[n] = {'n': len(inside), 'fraction': float(np.mean(inside)) if inside else None,
                       'spread_over_reported': float(np.std(ests, ddof=1) / np.median(ses))
                       if len(ests) > 1 and np.median(ses) > 0 else None}
    for source in ('reported_modes', 'coil_frf_modes'):
        for n in ('low_mode_Hz', 'high_mode_Hz', 'anti_resonance_Hz') + MODE_DAMPINGS:
            got = [r['estimate'][source][n]['inside_95'] for r in reps
                   if r['estimate'].get(source) and n in r['estimate'][source]]
            coverage[f'{source}.{n}'] = {'n': len(got), 'fraction':
                                         float(np.mean(got)) if got else None}
    return {'parameters': params, 'modes': modes, 'coil_frf_fit_modes': frf_modes,
            'worst_section_fit_percent': {c: (min(v) if v else None) for c, v in fits.items()},
            'median_worst_section_fit_percent': {c: (float(np.median(v)) if v else None)
                                                 for c, v in fits.items()},
            'time_s': {c: {'median': float(np.median(v)) if v else None,
                           'max': float(np.max(v)) if v else None} for c, v in times.items()},
            'flagged_draws': flagged, 'outside_margins': {str(k): v for k, v in bad.items()},
            'silent_bad_draws': silent, 'failure_messages': failures,
            'coverage': coverage,
            'broken': [{k: b[k] for k in ('name', 'description', 'verdict',
                                          'largest_relative_standard_error')} |
                       {'success': b['estimate']['success'],
                        'failures': b['estimate']['failures'],
                        'worst_section_fit_percent':
                            b['estimate'].get('worst_section_fit_percent')}
                       for b in broken]}


def print_report(s: Dict[str, Any], args: argparse.Namespace, n_draws: int) -> None:
    """Print the Markdown tables."""
    print(f'\n{n_draws} draws (BENCH_SEEDS[:{n_draws}], spread +/-{100 * args.spread:g} %), '
          f'{s["coverage"]["n_repetitions"]} noise repetitions of draw {BENCH_SEEDS[0]}')
    print('\n| parameter | median abs error | worst error | target | truth start: median | '
          'truth start: worst | ratio of medians |')
    print('|---|---|---|---|---|---|---|')
    for n, p in list(s['parameters'].items()) + list(s['modes'].items()):
        e, b = p['estimate'], p['truth_start']
        ratio = f'{p["median_error_ratio"]:.3g}' if p['median_error_ratio'] else '-'
        target = _pct(p['target'], 1) if p['target'] is not None else '(free, no target)'
        print(f'| {n} | {_pct(e["median_abs"], 3)} | {_pct(e["worst"], 3, True)} | {target} | '
              f'{_pct(b["median_abs"], 3)} | {_pct(b["worst"], 3, True)} | {ratio} |')
    for n, e in s['coil_frf_fit_modes'].items():
        print(f'| {n} of the coil FRF\'s TF fit (not the grey-box) | {_pct(e["median_abs"], 3)} '
              f'| {_pct(e["worst"], 3, True)} | {_pct(TARGETS["mode"], 1)} | | | |')
    w, m = s['worst_section_fit_percent'], s['median_worst_section_fit_percent']
    print(f'\nworst section fit: {w["estimate"]:.1f} % (median of draws {m["estimate"]:.1f} %; '
          f'truth start {w["truth_start"]:.1f} %, median {m["truth_start"]:.1f} %); '
          f'target >= {TARGETS["section_fit_percent"]:g} %')
    t = s['time_s']
    print(f'identification wall time: median {t["estimate"]["median"]:.1f} s, max '
          f'{t["estimate"]["max"]:.1f} s (truth start median {t["truth_start"]["median"]:.1f} s);'
          f' target < {TARGETS["time_s"]:g} s')
    print(f'failure flag raised on intact draws: {len(s["flagged_draws"])} of {n_draws} '
          f'{s["flagged_draws"] or ""}')
    print(f'intact draws outside the margins of the unit tests yet reported as success '
          f'(silent): '
          f'{len(s["silent_bad_draws"])} of {n_draws}')
    if s['failure_messages']:
        print('failure messages: ' + '; '.join(s['failure_messages'][:6]))
    c = s['coverage']
    lo, hi = TARGETS['coverage']
    print(f'\n| coverage of the 95 % interval ({c["n_repetitions"]} repetitions) | fraction | '
          f'spread of estimates / median reported std | target |')
    print('|---|---|---|---|')
    for key, v in c.items():
        if key == 'n_repetitions':
            continue
        frac = f'{100 * v["fraction"]:.0f} % (n={v["n"]})' if v['fraction'] is not None \
            else 'not reported'
        ratio = f'{v["spread_over_reported"]:.3g}' if v.get('spread_over_reported') else '-'
        print(f'| {key} | {frac} | {ratio} | {100 * lo:.0f}-{100 * hi:.0f} % |')
    print('\n| broken input | success | failures | largest rel. std (c, d) | worst fit | '
          'verdict |')
    print('|---|---|---|---|---|---|')
    for b in s['broken']:
        fit = b['worst_section_fit_percent']
        print(f'| {b["description"]} | {b["success"]} | {len(b["failures"])} | '
              f'{_pct(b["largest_relative_standard_error"], 3)} | '
              f'{"-" if fit is None else f"{fit:.1f} %"} | {b["verdict"]} |')


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--draws', type=int, default=None, help='draws (default 20)')
    parser.add_argument('--reps', type=int, default=None,
                        help='noise repetitions for coverage (default 100)')
    parser.add_argument('--jobs', type=int, default=2,
                        help='worker processes (default 2; 0: everything in this process)')
    parser.add_argument('--quick', action='store_true', help='3 draws, 5 repetitions')
    parser.add_argument('--spread', type=float, default=0.10)
    parser.add_argument('--json', default=None, help='write the results to this file')
    parser.add_argument('--units', nargs='*', default=None, metavar='VARIANT',
                        help='identify drawn units and user experiments instead (all '
                             f'variants when none is named: {", ".join(UNIT_VARIANTS)}); '
                             'writes bench/results/ident_units.json unless --json')
    args = parser.parse_args()
    if args.units is not None:
        return units_main(parser, args)
    n_draws = args.draws if args.draws is not None else (3 if args.quick else 20)
    n_reps = args.reps if args.reps is not None else (5 if args.quick else 100)
    if not 1 <= n_draws <= len(BENCH_SEEDS) or not 0 <= n_reps <= len(BENCH_NOISE_SEEDS):
        parser.error(f'--draws in [1, {len(BENCH_SEEDS)}], --reps in '
                     f'[0, {len(BENCH_NOISE_SEEDS)}]')

    tasks = [('draw', (seed, args.spread)) for seed in BENCH_SEEDS[:n_draws]]
    tasks += [('broken', (BENCH_SEEDS[0], name, args.spread)) for name in BROKEN_INPUTS]
    tasks += [('rep', (BENCH_SEEDS[0], noise, args.spread))
              for noise in BENCH_NOISE_SEEDS[:n_reps]]
    start = time.perf_counter()
    rows = []
    for count, row in enumerate(run_tasks(tasks, args.jobs), 1):
        rows.append(row)
        print(f'[{count}/{len(tasks)}] {row["kind"]} draw {row["draw_seed"]} '
              f'{row.get("name", row.get("noise_seed", ""))}: success '
              f'{row["estimate"]["success"]}, worst fit '
              f'{row["estimate"].get("worst_section_fit_percent", float("nan")):.1f} %, '
              f'{row["estimate"]["time_s"]:.1f} s', file=sys.stderr, flush=True)
    wall_s = time.perf_counter() - start
    draws = sorted((r for r in rows if r['kind'] == 'draw'), key=lambda r: r['draw_seed'])
    reps = sorted((r for r in rows if r['kind'] == 'rep'), key=lambda r: r['noise_seed'])
    broken = [r for name in BROKEN_INPUTS for r in rows
              if r['kind'] == 'broken' and r['name'] == name]
    summary = summarise(draws, reps, broken)
    print_report(summary, args, n_draws)
    print(f'\ntotal wall time {wall_s:.0f} s with {args.jobs} job(s)')
    if args.json:
        out = {'machine': {'python': platform.python_version(),
                           'platform': platform.platform(), 'cpus': os.cpu_count()},
               'command': ' '.join(sys.argv), 'spread': args.spread, 'targets': TARGETS,
               'margins': MARGINS, 'large_uncertainty': LARGE_UNCERTAINTY,
               'draw_seeds': [r['draw_seed'] for r in draws],
               'noise_seeds': [r['noise_seed'] for r in reps], 'wall_s': wall_s,
               'summary': summary, 'draws': draws, 'repetitions': reps, 'broken': broken}
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(out, indent=2, default=_plain))
        print(f'wrote {path}')
    return 0


def run_tasks(tasks: Sequence[Tuple[str, tuple]], jobs: int) -> Any:
    """Yield the tasks' rows as they finish (``jobs`` worker processes, 0: in-process)."""
    if jobs <= 0:
        yield from map(_call, tasks)
        return
    pool = multiprocessing.get_context('spawn').Pool(jobs)
    try:
        yield from pool.imap_unordered(_call, tasks)
    finally:
        pool.close()
        pool.join()


def units_main(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    """Run ``--units``: every named variant on the first ``--draws`` benchmark seeds."""
    variants = list(args.units) or list(UNIT_VARIANTS)
    unknown = [v for v in variants if v not in UNIT_VARIANTS]
    n_draws = args.draws if args.draws is not None else (3 if args.quick else 20)
    if unknown or not 1 <= n_draws <= len(BENCH_SEEDS):
        parser.error(f'--units variants from {", ".join(UNIT_VARIANTS)}; --draws in '
                     f'[1, {len(BENCH_SEEDS)}]')
    tasks = [('unit', (seed, v)) for seed in BENCH_SEEDS[:n_draws] for v in variants]
    start = time.perf_counter()
    rows = []
    for count, row in enumerate(run_tasks(tasks, args.jobs), 1):
        rows.append(row)
        worst = {n: round(100 * row[n]['relative_error'], 3) for n in UNIT_NUMBERS if n in row}
        print(f'[{count}/{len(tasks)}] {row["seed"]} {row["variant"]:26s} success '
              f'{row["success"]} errors % {worst} {row["failures"][:1]}', file=sys.stderr,
              flush=True)
    rows.sort(key=lambda r: (variants.index(r['variant']), r['seed']))
    summary = summarise_units(rows, variants)
    print(json.dumps(summary, indent=1))
    print(f'\ntotal wall time {time.perf_counter() - start:.0f} s with {args.jobs} job(s)')
    write_units(summary, rows, variants,
                Path(args.json) if args.json else ROOT / 'bench' / 'results' / 'ident_units.json')
    return 0


def _plain(value: Any) -> Any:
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.bool_):
        return bool(value)
    return str(value)


if __name__ == '__main__':
    raise SystemExit(main())
