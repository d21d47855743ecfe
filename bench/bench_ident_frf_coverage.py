"""
Whether the FRF points' and the transfer-function modes' uncertainties match their errors.

Noise repetitions of one off-nominal draw (``emfc_ros.core.ident.offnominal``, benchmark seeds
only) through the shipped trajectory; the grey-box step is off. For every LPM line between
10 Hz and 1 kHz, ``|e|^2 / std^2`` against the drawn balance's linear model (exponential with
mean 1 when the std is right, below -ln 0.05 = 3.0 in 95 % of the lines), and for the coil
and pan transfer-function fits the modes' ``z = error / std`` (standard deviation 1 and 95 %
inside +/-1.96 when right). The same-run reference is the ideal: mean 1, coverage 95 %.

    .venv/bin/python bench/bench_ident_frf_coverage.py --reps 15 \
        --json bench/results/frf_coverage.json
    .venv/bin/python bench/bench_ident_frf_coverage.py --reps 100 --draw-index 0 \
        --first-noise 0    # the off-nominal benchmark's coverage draw and noise seeds
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys
import time
from typing import Dict, List

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # the working tree, not an installed copy

from scipy import stats  # noqa: E402

from emfc_ros.core.ident.balance_experiment import section_table  # noqa: E402
from emfc_ros.core.ident.offnominal import (BENCH_NOISE_SEEDS, BENCH_SEEDS,  # noqa: E402
                                            draw_balance, record_draw)
from emfc_ros.core.ident.pipeline import identify  # noqa: E402
from emfc_ros.core.model.linear import linearise  # noqa: E402
from emfc_ros.core.model.load import loaded  # noqa: E402

#: Noise seeds used here (disjoint from bench_ident_offnominal's repetitions, which start at
#: BENCH_NOISE_SEEDS[0]).
FIRST_NOISE = 300


def nearest(roots, frequency_Hz: float):
    """Return the root nearest a frequency [Hz]."""
    return min(roots, key=lambda m: abs(m.frequency_Hz - frequency_Hz))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--reps', type=int, default=15, help='noise repetitions')
    parser.add_argument('--draw-index', type=int, default=1, help='which of BENCH_SEEDS')
    parser.add_argument('--first-noise', type=int, default=FIRST_NOISE,
                        help='index of the first noise seed in BENCH_NOISE_SEEDS')
    parser.add_argument('--json', default=None, help='write the figures to this file')
    args = parser.parse_args()
    draw = draw_balance(BENCH_SEEDS[args.draw_index])
    lines: Dict[str, List[np.ndarray]] = {}
    dofs: Dict[str, int] = {}
    z: Dict[str, List[float]] = {}
    t0 = time.perf_counter()
    for seed in BENCH_NOISE_SEEDS[args.first_noise:args.first_noise + args.reps]:
        rec = record_draw(draw, seed)
        options = dict(rec.options(), greybox={'enabled': False})
        res = identify(rec.recording, section_table(rec.recording), options)
        lin = linearise(loaded(draw.mechanics, options['load_mass_kg'],
                               options['load_changer_coupled']))
        for r in res.frfs:
            band = (r.frd.frequency_Hz >= 10.0) & (r.frd.frequency_Hz <= 1000.0)
            f = r.frd.frequency_Hz[band]
            h = lin.frequency_response(f, r.input).response_m_per_N
            lines.setdefault(r.name, []).append(
                np.abs(r.frd.response[band] - h) ** 2 / r.frd.std[band] ** 2)
            dofs[r.name] = int(r.frd.details.get('dof', 0))
            if r.fit is None:
                continue
            c = r.fit.chosen
            truth = rec.modal
            # matched by frequency: a higher order may add a near-cancelling pair far above
            pairs = [('low mode', nearest(c.modes, truth.low_mode_Hz), truth.low_mode_Hz),
                     ('high mode', nearest(c.modes, truth.high_mode_Hz), truth.high_mode_Hz)]
            if r.input == 'coil' and c.anti_resonances:
                pairs.append(('anti-resonance', nearest(c.anti_resonances,
                                                        truth.anti_resonance_Hz),
                              truth.anti_resonance_Hz))
            for label, mode, true in pairs:
                z.setdefault(f'{r.name} {label}', []).append(
                    (mode.frequency_Hz - true) / mode.frequency_std_Hz)
    out = {'reps': args.reps, 'draw_seed': BENCH_SEEDS[args.draw_index],
           'noise_seeds': [BENCH_NOISE_SEEDS[args.first_noise],
                           BENCH_NOISE_SEEDS[args.first_noise + args.reps - 1]],
           'wall_time_s': time.perf_counter() - t0, 'frf_points': {}, 'modes': {}}
    print(f'{args.reps} noise repetitions of draw {BENCH_SEEDS[args.draw_index]}, noise seeds '
          f'{out["noise_seeds"][0]}-{out["noise_seeds"][1]}')
    print('| FRF points 10 Hz - 1 kHz | lines | mean |e|^2/std^2 (known std: 1; '
          'F(2, 2 dof): 1 + 2/(2 dof - 2)) | coverage, known-std 95 % region | coverage, '
          'F(2, 2 dof) 95 % region (ideal 95 %) |')
    for name, parts in lines.items():
        e2 = np.concatenate(parts)
        nu = 2 * dofs[name]
        row = {'lines': int(e2.size), 'mean_ratio': float(e2.mean()),
               'expected_mean_ratio': nu / (nu - 2.0) if nu > 2 else None,
               'coverage_95_known_std': float(np.mean(e2 < -np.log(0.05))),
               'coverage_95_f': float(np.mean(e2 < stats.f.ppf(0.95, 2, nu))) if nu else None}
        out['frf_points'][name] = row
        print(f'| {name} | {row["lines"]} | {row["mean_ratio"]:.2f} '
              f'({row["expected_mean_ratio"]:.2f}) | '
              f'{100 * row["coverage_95_known_std"]:.1f} % | {100 * row["coverage_95_f"]:.1f} % |')
    print('| TF-fit mode | n | mean of z (ideal 0) | std of z (ideal 1) | 95 % coverage '
          '(ideal 95 %) |')
    for name, values in z.items():
        v = np.array(values)
        row = {'n': int(v.size), 'mean_z': float(np.mean(v)), 'std_z': float(np.std(v)),
               'coverage_95': float(np.mean(np.abs(v) < 1.96))}
        out['modes'][name] = row
        print(f'| {name} | {row["n"]} | {row["mean_z"]:+.2f} | {row["std_z"]:.2f} | '
              f'{100 * row["coverage_95"]:.0f} % |')
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(out, indent=2))
        print(f'wrote {args.json}')


if __name__ == '__main__':
    main()
