"""
A/B speed of the simulator's chain kernel: the working tree against another version of it.

Run-to-run spread on a shared VM is 10 to 15 %, larger than most kernel changes, so separate
benchmark runs cannot tell them apart. This compiles both versions of
``emfc_ros/core/sim/chain.py`` in one process and calls them alternately on the same blocks
(order swapped every block), so that a slow spell of the machine hits both alike::

    git worktree add /tmp/chain_old HEAD
    .venv/bin/python bench/ab_chain.py /tmp/chain_old/emfc_ros/core/sim/chain.py \
        [--block 1000] [--samples 200000] [--rounds 3] [--no-noise]

It prints both rates, their ratio and the largest difference of the outputs (0 for a
bit-identical change). Both versions need the working tree's ``chain_block`` signature; to
compare across a change of it, use ``bench/ab_package.py`` (whole packages).
"""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path
import sys
import time
from typing import List

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # the working tree, not an installed copy

from emfc_ros.core.model import BalanceParameters  # noqa: E402
from emfc_ros.core.sim import numba_available, Simulator  # noqa: E402

FS_HZ = 20000.0


def load_other(path: Path):
    """Compile ``chain_block`` of the chain module at ``path`` (imported under another name)."""
    import numba
    spec = importlib.util.spec_from_file_location('chain_other', path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return numba.njit(cache=False, **module.JIT_OPTIONS)(module.chain_block)


def main(argv: List[str] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('other', type=Path, help='the other version of chain.py')
    parser.add_argument('--block', type=int, default=1000, help='samples per block')
    parser.add_argument('--samples', type=int, default=200000, help='samples per round')
    parser.add_argument('--rounds', type=int, default=3)
    parser.add_argument('--no-noise', action='store_true',
                        help='without noise and quantisation')
    args = parser.parse_args(argv)
    if not numba_available():
        print('numba is not installed: nothing to compare', file=sys.stderr)
        return 2
    params = BalanceParameters()
    options = dict(noise=not args.no_noise, quantisation=not args.no_noise)
    this = Simulator(params, FS_HZ, seed=1, **options)
    other = Simulator(params, FS_HZ, seed=1, **options)
    other._run = load_other(args.other)
    n = args.samples
    u = np.tile(this.hold_setpoints_V[:, None], (1, n))
    u[0] += 0.002 * np.sin(np.arange(n) * 0.01)
    u[1, n // 2:] += 0.1
    for sim in (this, other):     # compile (or load) both before timing
        sim.step_block(u[:, :10])
        sim.reset()
    t_this = t_other = 0.0
    diff = 0.0
    count = 0
    for _ in range(args.rounds):
        for k, start in enumerate(range(0, n - args.block + 1, args.block)):
            block = u[:, start:start + args.block]
            pair = [(this, 0), (other, 1)] if k % 2 else [(other, 1), (this, 0)]
            outs = [None, None]
            for sim, slot in pair:
                t0 = time.perf_counter()
                outs[slot] = sim.step_block(block)
                elapsed = time.perf_counter() - t0
                if slot == 0:
                    t_this += elapsed
                else:
                    t_other += elapsed
            diff = max(diff, float(np.abs(outs[0] - outs[1]).max()))
            count += args.block
    print(f'working tree {count / t_this / 1e6:8.3f} M/s   other {count / t_other / 1e6:8.3f} '
          f'M/s   working tree / other {t_other / t_this:6.3f}   largest output difference '
          f'{diff:.3g}   ({count} samples each, blocks of {args.block})')
    return 0


if __name__ == '__main__':
    sys.exit(main())
