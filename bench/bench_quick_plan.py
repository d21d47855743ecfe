"""
The 10-second plan against the default plan: errors, uncertainties and time (issue 14 item 6).

Balances drawn with every stiffness, damping, mass and inertia within +/-10 % of the defaults
(``emfc_ros.core.ident.offnominal.draw_balance``, seeds ``BENCH_SEEDS``, never used by the tests)
play both plans through the simulator (noise, quantisation, the pan loaded with the balance's
balancing mass, the load changer coupled) and are identified knowing only the pan load and the
coupling, with the identification options of each plan's file (``config/experiment_quick.yaml``:
``quick_trajectory.yaml``, 10 s; the default: ``identification_trajectory.yaml``'s four dynamic
sections, 40 s, the options ``bench_ident_offnominal.py`` uses). Printed per quantity: the
largest error, the largest ``|error| / reported standard uncertainty`` and the fraction inside
the 95 % interval, for c1, d1, c2, d2, the mass-matrix entries and the grey-box modes, and the
identification's wall and CPU time; the default plan is the same-run baseline (ratios).

    .venv/bin/python bench/bench_quick_plan.py                 # 10 draws
    .venv/bin/python bench/bench_quick_plan.py --draws 3       # quicker
    .venv/bin/python bench/bench_quick_plan.py --json bench/results/quick_plan.json

Targets (the issue): every error within 1 %, the errors consistent with the reported standard
uncertainties (|z| small, about 95 % inside the 95 % interval), identification at most 5 s.
"""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path
import sys
import time
from typing import Any, Dict, List

for _var in ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS'):
    os.environ.setdefault(_var, '1')

import numpy as np  # noqa: E402
import yaml  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # the working tree, not an installed copy

from emfc_ros.core.ident.balance_greybox import mass_matrix_entries  # noqa: E402
from emfc_ros.core.ident.offnominal import (BENCH_SEEDS, default_experiment,  # noqa: E402
                                            draw_balance, record_draw)
from emfc_ros.core.ident.pipeline import identify  # noqa: E402
from emfc_ros.core.signals import load_experiment_file  # noqa: E402

QUICK_PLAN = ROOT / 'config' / 'experiment_quick.yaml'
QUICK_TRAJECTORY = ROOT / 'config' / 'quick_trajectory.yaml'
#: Noise seeds of the simulated recordings: the draw seed plus this (disjoint from the tests').
NOISE_OFFSET = 70000
PARAMETERS = ('c1_Nm_per_rad', 'd1_Nms_per_rad', 'c2_Nm_per_rad', 'd2_Nms_per_rad',
              'M11_kgm2', 'M12_kgm2', 'M22_kgm2')
#: Grey-box modes in ``to_dict()['greybox']['derived']`` and in ``offnominal.ModalTruth``.
MODES = {'low_mode_frequency_Hz': 'low_mode_Hz', 'high_mode_frequency_Hz': 'high_mode_Hz',
         'coil_anti_resonance_frequency_Hz': 'anti_resonance_Hz',
         'low_mode_damping_ratio': 'low_damping_ratio',
         'high_mode_damping_ratio': 'high_damping_ratio'}
TARGET_ERROR = 0.01
TARGET_TIME_S = 5.0
Z95 = 1.96


def quick_options() -> Dict[str, Any]:
    """The identification mapping of ``config/experiment_quick.yaml``."""
    plan = yaml.safe_load(QUICK_PLAN.read_text())
    options = dict(plan['run']['identification'])
    options.pop('enabled', None)
    return options


def assess(rec: Any, options: Dict[str, Any]) -> Dict[str, Any]:
    """Identify one recording; errors and z-scores of the parameters and modes."""
    wall, cpu = time.perf_counter(), time.process_time()
    res = identify(rec.recording, rec.section_table, options)
    out: Dict[str, Any] = {'time_s': time.perf_counter() - wall,
                           'cpu_s': time.process_time() - cpu, 'success': res.success,
                           'failures': list(res.failures), 'values': {}}
    if res.greybox is None:
        return out
    fit = res.greybox.fit
    mech = rec.truth.mechanics
    entries = mass_matrix_entries(mech, rec.known_load_mass_kg, rec.load_changer_coupled)
    truth = {n: float(getattr(mech, n)) for n in PARAMETERS[:4]}
    truth.update(zip(PARAMETERS[4:], (float(v) for v in entries)))
    for name in PARAMETERS:
        if name in fit.free_names:
            out['values'][name] = (float(fit.parameters[name]),
                                   float(fit.standard_errors[name]), truth[name])
    derived = res.to_dict()['greybox']['derived']
    for key, attr in MODES.items():
        entry = derived.get(key) or {}
        if entry.get('value') is not None and entry.get('standard_uncertainty') is not None:
            out['values'][key] = (float(entry['value']), float(entry['standard_uncertainty']),
                                  float(getattr(rec.modal, attr)))
    out['evaluations'] = int(fit.n_evaluations)
    out['jacobian'] = fit.jacobian_method
    return out


def summarise(rows: List[Dict[str, Any]], name: str) -> Dict[str, float]:
    """Largest error, largest |z| and 95 % coverage of one quantity over the draws."""
    errors, zs = [], []
    for row in rows:
        if name in row['values']:
            est, se, truth = row['values'][name]
            errors.append(est / truth - 1.0)
            zs.append((est - truth) / se if se > 0.0 else math.inf)
    if not errors:
        return {'n': 0}
    return {'n': len(errors), 'worst_error': float(max(errors, key=abs)),
            'median_abs_error': float(np.median(np.abs(errors))),
            'worst_z': float(max(zs, key=abs)),
            'inside_95': float(np.mean(np.abs(zs) <= Z95)),
            'rms_z': float(np.sqrt(np.mean(np.square(zs))))}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--draws', type=int, default=10, help='balances drawn (default 10)')
    parser.add_argument('--json', default=None, help='write the results to this file')
    parser.add_argument('--no-default', action='store_true',
                        help='skip the default plan (no baseline)')
    args = parser.parse_args()
    quick_exp = load_experiment_file(QUICK_TRAJECTORY)
    quick_sections = tuple(s.name for s in quick_exp.sections)
    plans = {'quick (10 s)': (quick_exp, quick_sections, quick_options())}
    if not args.no_default:
        plans['default (40 s)'] = (default_experiment(), None, {})
    rows: Dict[str, List[Dict[str, Any]]] = {name: [] for name in plans}
    for seed in BENCH_SEEDS[:args.draws]:
        balance = draw_balance(seed)
        for name, (exp, sections, extra) in plans.items():
            rec = record_draw(balance, seed + NOISE_OFFSET, experiment=exp, draw_seed=seed)
            options = rec.options(sections) if sections else rec.options()
            options.update(extra)
            row = assess(rec, options)
            row['peak_position_m'] = rec.peak_position_m
            rows[name].append(row)
            print(f'draw {seed} {name}: success {row["success"]}, {row["time_s"]:.2f} s '
                  f'({row["cpu_s"]:.2f} s CPU), peak {1e6 * rec.peak_position_m:.0f} um',
                  file=sys.stderr, flush=True)
    names = list(PARAMETERS) + list(MODES)
    table = {plan: {n: summarise(r, n) for n in names} for plan, r in rows.items()}
    print(f'\n{args.draws} draws (+/-10 %), seeds {BENCH_SEEDS[0]}..'
          f'{BENCH_SEEDS[args.draws - 1]}; per plan: worst error, worst |z|, inside 95 %')
    header = f'{"quantity":<34}' + ''.join(f'{plan:>36}' for plan in plans)
    print(header)
    for n in names:
        cells = []
        for plan in plans:
            s = table[plan][n]
            cells.append(f'{"-":>36}' if not s['n'] else
                         f'{100 * s["worst_error"]:>+10.3f} % {s["worst_z"]:>+7.2f} '
                         f'{100 * s["inside_95"]:>7.0f} %     ')
        print(f'{n:<34}' + ''.join(cells))
    times = {plan: [r['time_s'] for r in rows[plan]] for plan in plans}
    cpus = {plan: [r['cpu_s'] for r in rows[plan]] for plan in plans}
    for plan in plans:
        ok = sum(r['success'] for r in rows[plan])
        print(f'{plan}: identified {ok} of {len(rows[plan])}; identification time median '
              f'{np.median(times[plan]):.2f} s, max {max(times[plan]):.2f} s (CPU median '
              f'{np.median(cpus[plan]):.2f} s); peak excursion max '
              f'{1e6 * max(r["peak_position_m"] for r in rows[plan]):.0f} um')
    quick = 'quick (10 s)'
    worst = max(abs(table[quick][n].get('worst_error', math.inf)) for n in names)
    met_error = worst <= TARGET_ERROR
    met_time = max(times[quick]) <= TARGET_TIME_S
    inside = min(table[quick][n].get('inside_95', 0.0) for n in names)
    print(f'target: every error within {100 * TARGET_ERROR:g} %: '
          f'{"met" if met_error else "NOT met"} (worst {100 * worst:.3f} %); identification '
          f'within {TARGET_TIME_S:g} s: {"met" if met_time else "NOT met"}; lowest 95 % '
          f'coverage over the quantities {100 * inside:.0f} %')
    if len(plans) > 1:
        base = 'default (40 s)'
        print(f'same-run ratio, quick / default: identification time '
              f'{np.median(times[quick]) / np.median(times[base]):.2f}, worst |error| per '
              'quantity: ' + ', '.join(
                  f'{n.split("_")[0]} {abs(table[quick][n]["worst_error"]) / max(abs(table[base][n]["worst_error"]), 1e-12):.2f}'  # noqa: E501
                  for n in PARAMETERS if table[quick][n]['n'] and table[base][n]['n']))
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps({'draws': args.draws, 'table': table,
                                               'rows': rows}, indent=2, default=str))
        print(f'wrote {args.json}')
    return 0 if met_error and met_time else 1


if __name__ == '__main__':
    raise SystemExit(main())
