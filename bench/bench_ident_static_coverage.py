"""
Whether the static characteristics' standard errors match their errors.

Repetitions of the shipped staircases (``config/static_characteristics.yaml``) on balances
drawn for the benchmark (``emfc_ros.core.ident.offnominal``, ``BENCH_SEEDS`` in turn), each
with its amplifiers and load changer drawn too (offset within +/-10 uA, gain +/-5 %,
curvature +/-50 %, load-changer coefficients +/-5 %) and new noise (``BENCH_NOISE_SEEDS``).
Drawing the characteristics matters: the current noise (0.1 uA rms) is far below the ADC step
(3.05 uA), so the plateau means are rounded without dither and the same balance gives the same
error for every noise seed. Per coefficient ``z = (estimate - truth) / standard error``, its
mean and spread, and the coverage of ``+/- k`` standard errors with ``k`` the
``coverage_factor_95`` that ``results.yaml`` reports (ideal: mean 0, spread 1, 95 %).

    .venv/bin/python bench/bench_ident_static_coverage.py --reps 100 --first-noise 100
"""

from __future__ import annotations

import argparse
from dataclasses import replace
import json
from pathlib import Path
import sys
import time
from typing import Dict, List

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # the working tree, not an installed copy

from emfc_ros.core.ident.balance_experiment import section_table  # noqa: E402
from emfc_ros.core.ident.offnominal import (BENCH_NOISE_SEEDS, BENCH_SEEDS,  # noqa: E402
                                            draw_balance, record_draw)
from emfc_ros.core.ident.pipeline import identify  # noqa: E402
from emfc_ros.core.model.parameters import BalanceParameters  # noqa: E402
from emfc_ros.core.signals import load_experiment_file  # noqa: E402

KEYS = {'coil_amplifier': ('coil_amplifier', 'coeffs_A_per_V_pow'),
        'load_changer_amplifier': ('load_changer_amplifier', 'coeffs_A_per_V_pow'),
        'load_changer': ('load_changer', 'coeffs_N_per_A_pow')}


def draw_characteristics(base: BalanceParameters, rng: np.random.Generator) -> BalanceParameters:
    """Draw the amplifiers' and the load changer's characteristics around the base's."""
    def amplifier(a):
        c = np.array(a.coeffs_A_per_V_pow, dtype=float)
        c[1:] *= np.concatenate((rng.uniform(0.95, 1.05, 1), rng.uniform(0.5, 1.5, c.size - 2)))
        c[0] = rng.uniform(-1e-5, 1e-5)
        return replace(a, coeffs_A_per_V_pow=tuple(c))
    lc = np.array(base.load_changer.coeffs_N_per_A_pow, dtype=float) * rng.uniform(0.95, 1.05, 2)
    return replace(base, coil_amplifier=amplifier(base.coil_amplifier),
                   load_changer_amplifier=amplifier(base.load_changer_amplifier),
                   load_changer=replace(base.load_changer, coeffs_N_per_A_pow=tuple(lc)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--reps', type=int, default=100, help='repetitions')
    parser.add_argument('--first-noise', type=int, default=100,
                        help='index of the first noise seed in BENCH_NOISE_SEEDS')
    parser.add_argument('--json', default=None, help='write the figures to this file')
    args = parser.parse_args()
    experiment = load_experiment_file(ROOT / 'config' / 'static_characteristics.yaml')
    z: Dict[str, List[np.ndarray]] = {}
    k: Dict[str, float] = {}
    t0 = time.perf_counter()
    seeds = BENCH_NOISE_SEEDS[args.first_noise:args.first_noise + args.reps]
    for i, seed in enumerate(seeds):
        rng = np.random.default_rng(seed)
        balance = draw_characteristics(draw_balance(BENCH_SEEDS[i % len(BENCH_SEEDS)]), rng)
        rec = record_draw(balance, seed, experiment=experiment)
        options = dict(rec.options(), greybox={'enabled': False})
        res = identify(rec.recording, section_table(rec.recording), options)
        reported = res.to_dict()['static_characteristics'] or {}
        for key, (part, field) in KEYS.items():
            fit = res.static.fits.get(key) if res.static else None
            if fit is None:
                continue
            truth = np.zeros(len(fit.coefficients))
            given = np.asarray(getattr(getattr(balance, part), field), dtype=float)
            truth[:min(truth.size, given.size)] = given[:truth.size]
            z.setdefault(key, []).append((fit.coefficients - truth) / fit.standard_errors)
            k[key] = float(reported[key].get('coverage_factor_95') or 1.96)
    out = {'reps': args.reps, 'noise_seeds': [seeds[0], seeds[-1]],
           'wall_time_s': time.perf_counter() - t0, 'fits': {}}
    print(f'{args.reps} repetitions, noise seeds {seeds[0]}-{seeds[-1]}')
    print('| fit | coefficient (power) | mean of z | std of z | coverage +/- k (k) |')
    for key, rows in z.items():
        v = np.array(rows)
        out['fits'][key] = {'mean_z': v.mean(axis=0).tolist(), 'std_z': v.std(axis=0).tolist(),
                            'coverage_95': (np.abs(v) < k[key]).mean(axis=0).tolist(),
                            'coverage_factor_95': k[key]}
        for p in range(v.shape[1]):
            print(f'| {key} | {p} | {v[:, p].mean():+.2f} | {v[:, p].std():.2f} | '
                  f'{100 * np.mean(np.abs(v[:, p]) < k[key]):.0f} % ({k[key]:.2f}) |')
    print(f'wall time {out["wall_time_s"]:.0f} s')
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=2))
        print(f'wrote {args.json}')


if __name__ == '__main__':
    main()
