"""
Speed of the identification core, against scipy baselines measured in the same run.

* FRF (H1 with coherence and std, Welch, Hann, 50 % overlap, nperseg 4096) of 10^6 samples
  with :func:`emfc_ros.core.ident.estimate_frf`, against ``scipy.signal.csd`` alone (one
  cross-spectrum) and against the scipy way to the same result (``csd`` + two ``welch``).
* Transfer-function fit (2/4) of the default balance's coil FRF (400 points, 1 % noise), and
  an order selection over five candidates.
* Grey-box fit of a mass-spring-damper (stiffness, damping, gain free; mass fixed; two
  sections of 2000 samples) by least squares and by pattern search: evaluations, time, fit
  and largest relative parameter error, noise-free and with 5 % output noise.

    .venv/bin/python bench/bench_ident_core.py --json bench/results/ident_core.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import platform
import sys
import time
from typing import Callable, Dict, List

import numpy as np
import scipy
from scipy import linalg
from scipy import signal as sps

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # the working tree, not an installed copy

from emfc_ros.core.ident import (DataSection, estimate_frf, fit_greybox,  # noqa: E402
                                 fit_transfer_function, FrequencyResponseData, ParameterSpec,
                                 select_order)
from emfc_ros.core.model import linearise, MechanicalParameters  # noqa: E402

FS_HZ = 10000.0
NPERSEG = 4096


def best_time(run: Callable[[], object], repeats: int) -> float:
    """Best wall time of ``run`` over repeats [s]."""
    best = float('inf')
    for _ in range(repeats):
        start = time.perf_counter()
        run()
        best = min(best, time.perf_counter() - start)
    return best


def frf_rows(n: int, repeats: int) -> List[Dict]:
    rng = np.random.default_rng(0)
    u = rng.standard_normal(n)
    b, a = sps.butter(4, 0.1)
    y = sps.lfilter(b, a, u) + 0.01 * rng.standard_normal(n)

    def scipy_h1() -> None:
        _, pxy = sps.csd(u, y, FS_HZ, nperseg=NPERSEG)
        _, pxx = sps.welch(u, FS_HZ, nperseg=NPERSEG)
        _, pyy = sps.welch(y, FS_HZ, nperseg=NPERSEG)
        _ = pxy / pxx, np.abs(pxy) ** 2 / (pxx * pyy)

    rows = []
    for name, run in (
            ('FRF H1 ours (estimate_frf)', lambda: estimate_frf(u, y, FS_HZ, nperseg=NPERSEG)),
            ('baseline scipy csd only', lambda: sps.csd(u, y, FS_HZ, nperseg=NPERSEG)),
            ('baseline scipy csd + 2 welch', scipy_h1)):
        rows.append({'case': name, 'samples': n, 'time_s': best_time(run, repeats)})
    return rows


def tf_rows(repeats: int) -> List[Dict]:
    f = np.logspace(0.0, 3.0, 400)
    h = linearise(MechanicalParameters()).frequency_response(f, 'coil').response_m_per_N
    rng = np.random.default_rng(1)
    noisy = h * (1.0 + 0.01 * (rng.standard_normal(f.size) + 1j * rng.standard_normal(f.size)))
    frd = FrequencyResponseData(f, noisy, np.ones(f.size), 0.01 * np.sqrt(2.0) * np.abs(h),
                                1.0, 'bench', 'N', 'm')
    fit = fit_transfer_function(frd, 2, 4)
    rows = [{'case': 'TF fit 2/4, 400 points', 'time_s': best_time(
        lambda: fit_transfer_function(frd, 2, 4), repeats),
        'modes_Hz': [m.frequency_Hz for m in fit.modes],
        'anti_resonances_Hz': [m.frequency_Hz for m in fit.anti_resonances]}]
    cands = [(0, 2), (1, 3), (2, 4), (3, 5), (2, 6)]
    sel = select_order(frd, cands)
    rows.append({'case': 'order selection, 5 candidates', 'time_s': best_time(
        lambda: select_order(frd, cands), repeats),
        'chosen': [sel.chosen.numerator_order, sel.chosen.denominator_order]})
    return rows


TRUTH = {'mass': 1.0, 'stiffness': (2 * np.pi * 5.0) ** 2, 'damping': 2 * 0.1 * 2 * np.pi * 5.0,
         'gain': 1000.0}


def msd(p: Dict[str, float], u: np.ndarray) -> np.ndarray:
    """Exact zero-order-hold response of gain / (mass s^2 + damping s + stiffness) at 1 kHz."""
    a = np.zeros((3, 3))
    a[0, 1] = 1.0
    a[1] = [-p['stiffness'] / p['mass'], -p['damping'] / p['mass'], p['gain'] / p['mass']]
    e = linalg.expm(a / 1000.0)
    (a11, a12), (a21, a22) = e[:2, :2]
    b1, b2 = e[:2, 2]
    return sps.lfilter([0.0, b1, a12 * b2 - a22 * b1],
                       [1.0, -(a11 + a22), a11 * a22 - a12 * a21], u)


def greybox_rows() -> List[Dict]:
    rng = np.random.default_rng(0)
    inputs = [('prbs', np.repeat(rng.choice([-1.0, 1.0], 200), 10)),
              ('steps', np.repeat([0.0, 1.0, -0.5, 0.5], 500))]
    specs = [ParameterSpec('mass', 1.0, free=False),
             ParameterSpec('stiffness', 700.0, 100.0, 5000.0),
             ParameterSpec('damping', 10.0, 0.1, 100.0),
             ParameterSpec('gain', 600.0, 10.0, 1.0e4)]
    rows = []
    for noise in (0.0, 0.05):
        noise_rng = np.random.default_rng(2)
        sections = []
        for name, u in inputs:
            y = msd(TRUTH, u)
            sections.append(DataSection(name, u, y + noise * np.std(y)
                                        * noise_rng.standard_normal(y.size)))
        for method in ('least_squares', 'pattern_search'):
            res = fit_greybox(msd, sections, specs, method=method)
            err = max(abs(res.parameters[k] / TRUTH[k] - 1.0) for k in res.free_names)
            rows.append({'case': f'grey-box {method}, noise {100 * noise:.0f} %',
                         'evaluations': res.optimizer_evaluations, 'time_s': res.time_s,
                         'fit_percent': [float(s.fit_percent[0]) for s in res.sections],
                         'max_relative_error': err, 'exit_reason': res.exit_reason})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[1])
    parser.add_argument('--samples', type=int, default=10 ** 6)
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--json', type=Path, default=ROOT / 'bench' / 'results'
                        / 'ident_core.json')
    args = parser.parse_args()
    frf = frf_rows(args.samples, args.repeats)
    tf = tf_rows(args.repeats)
    gb = greybox_rows()
    print(f'{"case":44s} {"time [s]":>9s}  details')
    for row in frf:
        print(f'{row["case"]:44s} {row["time_s"]:9.3f}  {row["samples"]} samples')
    for row in tf:
        extra = {k: v for k, v in row.items() if k not in ('case', 'time_s')}
        print(f'{row["case"]:44s} {row["time_s"]:9.3f}  {extra}')
    for row in gb:
        fits = '/'.join(f'{v:.2f}' for v in row['fit_percent'])
        print(f'{row["case"]:44s} {row["time_s"]:9.3f}  {row["evaluations"]} evaluations, '
              f'fit {fits} %, max rel. error {row["max_relative_error"]:.1e}')
    result = {'python': platform.python_version(), 'numpy': np.__version__,
              'scipy': scipy.__version__, 'machine': platform.machine(),
              'frf': frf, 'tf_fit': tf, 'greybox': gb}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(result, indent=2, default=float) + '\n')
    print(f'wrote {args.json}')


if __name__ == '__main__':
    main()
