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
from typing import List

from ab_timing import add_timing_arguments, alternate, excitation, FS_HZ

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # the working tree, not an installed copy

from emfc_ros.core.model import BalanceParameters  # noqa: E402
from emfc_ros.core.sim import numba_available, Simulator  # noqa: E402


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
    add_timing_arguments(parser)
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
    print(alternate(this, other, excitation(this.hold_setpoints_V, args.samples), args.block,
                    args.rounds))
    return 0


if __name__ == '__main__':
    sys.exit(main())
