"""
Generation throughput of the excitation signals, against scipy baselines in the same run.

For each signal type: samples per second through ``samples(k)`` in 1000-sample blocks (as
the signal_generator node produces them) and as one big array, best of a few repeats. In
the same run the baselines ``scipy.signal.chirp`` (same lengths, block-wise on time slices)
and ``scipy.signal.max_len_seq`` (block-wise by carrying the register state), and the
throughput of ``Experiment.block`` for the shipped identification trajectory (2 channels).

    .venv/bin/python bench/bench_signals.py --seconds 60 --json bench/results/signals.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import platform
import sys
import time
from typing import Callable, Dict

import numpy as np
import scipy
from scipy import signal as sps

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # the working tree, not an installed copy

from emfc_ros.core import signals as sig  # noqa: E402

FS = 10000.0
BLOCK = 1000


def best_rate(run: Callable[[], int], repeats: int) -> float:
    """Best samples per second of ``run`` (returns the number of samples) over repeats."""
    best = 0.0
    for _ in range(repeats):
        start = time.perf_counter()
        n = run()
        elapsed = time.perf_counter() - start
        best = max(best, n / elapsed)
    return best


def ours_blocks(signal, n: int) -> Callable[[], int]:
    def run() -> int:
        for first in range(0, n, BLOCK):
            signal.samples(np.arange(first, first + BLOCK, dtype=np.int64))
        return n - n % BLOCK if n % BLOCK else n
    return run


def ours_whole(signal, n: int) -> Callable[[], int]:
    def run() -> int:
        signal.samples(np.arange(n, dtype=np.int64))
        return n
    return run


def scipy_chirp_blocks(n: int, seconds: float) -> Callable[[], int]:
    def run() -> int:
        for first in range(0, n, BLOCK):
            t = np.arange(first, first + BLOCK) / FS
            sps.chirp(t, 5.0, seconds, 2000.0, method='logarithmic', phi=-90.0)
        return n
    return run


def scipy_chirp_whole(n: int, seconds: float) -> Callable[[], int]:
    def run() -> int:
        sps.chirp(np.arange(n) / FS, 5.0, seconds, 2000.0, method='logarithmic', phi=-90.0)
        return n
    return run


def scipy_mls_blocks(order: int, n: int) -> Callable[[], int]:
    def run() -> int:
        state = None
        for _ in range(0, n, BLOCK):
            _, state = sps.max_len_seq(order, state=state, length=BLOCK)
        return n
    return run


def scipy_mls_whole(order: int, n: int) -> Callable[[], int]:
    def run() -> int:
        sps.max_len_seq(order, length=n)
        return n
    return run


def experiment_blocks(exp: sig.Experiment) -> Callable[[], int]:
    def run() -> int:
        for first in range(0, exp.total_samples, BLOCK):
            exp.block(first, BLOCK)
        return exp.total_samples
    return run


def signals_under_test(seconds: float) -> Dict[str, object]:
    return {
        'sine': sig.Sine(0.01, 123.4, 0.0, FS),
        'chirp_log': sig.Chirp(0.01, 5.0, 2000.0, seconds, FS, 'logarithmic'),
        'chirp_linear': sig.Chirp(0.01, 5.0, 2000.0, seconds, FS, 'linear'),
        'multisine': sig.Multisine(0.01, 10000, FS, f_min_Hz=5.0, f_max_Hz=2000.0),
        'prbs_15': sig.Prbs(15, 1, -0.1, 0.1, FS),
        'prbs_31': sig.Prbs(31, 1, -0.1, 0.1, FS),
        'uniform_noise': sig.UniformNoise(-0.1, 0.1, 1, FS),
        'gaussian_noise': sig.GaussianNoise(0.0, 0.1, 1, FS),
        'steps': sig.Steps([0.0, 2.5, 5.0, 7.5], [0.0, 0.2, -0.2, 0.0], FS),
        'constant': sig.Constant(0.1, FS),
        'waveform': sig.Waveform(np.sin(np.arange(100000) * 0.01), FS, 'repeat'),
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=60.0,
                        help='signal length at 10 kHz (default 60 s = 600 000 samples)')
    parser.add_argument('--repeats', type=int, default=3, help='best of this many runs')
    parser.add_argument('--json', type=Path, default=ROOT / 'bench' / 'results' / 'signals.json',
                        help='output JSON (default bench/results/signals.json)')
    args = parser.parse_args(argv)
    n = int(round(args.seconds * FS))
    n -= n % BLOCK
    rows = []
    for name, signal in signals_under_test(args.seconds).items():
        rows.append({'name': name, 'kind': 'emfc_ros',
                     'block_Sps': best_rate(ours_blocks(signal, n), args.repeats),
                     'whole_Sps': best_rate(ours_whole(signal, n), args.repeats)})
    rows.append({'name': 'scipy.signal.chirp (log)', 'kind': 'baseline',
                 'block_Sps': best_rate(scipy_chirp_blocks(n, args.seconds), args.repeats),
                 'whole_Sps': best_rate(scipy_chirp_whole(n, args.seconds), args.repeats)})
    for order in (15, 31):
        rows.append({'name': f'scipy.signal.max_len_seq({order})', 'kind': 'baseline',
                     'block_Sps': best_rate(scipy_mls_blocks(order, n), args.repeats),
                     'whole_Sps': best_rate(scipy_mls_whole(order, n), args.repeats)})
    exp = sig.load_experiment_file(ROOT / 'config' / 'identification_trajectory.yaml')
    exp_rate = best_rate(experiment_blocks(exp), args.repeats)
    rows.append({'name': 'Experiment.block (shipped, 2 ch)', 'kind': 'experiment',
                 'block_Sps': exp_rate, 'whole_Sps': None,
                 'note': 'samples per channel per second; x2 channel samples'})

    print(f'{n} samples at {FS:g} Hz, blocks of {BLOCK}, best of {args.repeats}; MS/s')
    print(f'{"signal":36s} {"1000-blocks":>12s} {"whole array":>12s}')
    for row in rows:
        whole = f'{row["whole_Sps"] / 1e6:12.1f}' if row['whole_Sps'] else f'{"-":>12s}'
        print(f'{row["name"]:36s} {row["block_Sps"] / 1e6:12.1f} {whole}')
    doc = {'samples': n, 'sample_rate_Hz': FS, 'block_samples': BLOCK,
           'repeats': args.repeats, 'python': platform.python_version(),
           'numpy': np.__version__, 'scipy': scipy.__version__,
           'machine': platform.machine(), 'rows': rows}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(doc, indent=2) + '\n')
    print(f'wrote {args.json}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
