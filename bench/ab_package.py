"""
A/B speed of ``Simulator.step_block``: the working tree's package against another checkout.

Where ``bench/ab_chain.py`` swaps only the compiled ``chain_block`` (so both versions need the
same signature), this loads the whole ``emfc_ros`` package of another checkout under the name
``emfc_ros_old`` (a copy with the imports renamed, in a temporary directory) and times both
simulators alternately on the same blocks, the order swapped every block, so that a slow spell
of the shared VM hits both alike::

    git worktree add /tmp/old <commit>
    .venv/bin/python bench/ab_package.py /tmp/old [--block 1000] [--samples 200000] \
        [--rounds 3] [--hold zoh]

It prints both rates, their ratio and the largest difference of the outputs (0 for a
bit-identical change). A run of the working tree against itself gives a ratio within about
1 % of 1.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import re
import shutil
import sys
import tempfile
from typing import List

from ab_timing import add_timing_arguments, alternate, excitation, FS_HZ

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))   # the working tree, not an installed copy

from emfc_ros.core.model import BalanceParameters  # noqa: E402
from emfc_ros.core.sim import numba_available, Simulator  # noqa: E402


def import_other(checkout: Path, workdir: Path):
    """Import the ``emfc_ros`` package of ``checkout`` as ``emfc_ros_old``; return the module."""
    target = workdir / 'emfc_ros_old'
    shutil.copytree(checkout / 'emfc_ros', target,
                    ignore=shutil.ignore_patterns('__pycache__'))
    for path in target.rglob('*.py'):
        path.write_text(re.sub(r'\bemfc_ros\b', 'emfc_ros_old', path.read_text()))
    sys.path.insert(0, str(workdir))
    import emfc_ros_old.core.model
    import emfc_ros_old.core.sim
    return emfc_ros_old


def main(argv: List[str] = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('other', type=Path, help='another checkout of the repository')
    add_timing_arguments(parser)
    parser.add_argument('--hold', choices=('zoh', 'foh'), default='zoh')
    args = parser.parse_args(argv)
    if not numba_available():
        print('numba is not installed: nothing to compare', file=sys.stderr)
        return 2
    if not (args.other / 'emfc_ros').is_dir():
        print(f'{args.other}: no emfc_ros package there', file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as workdir:
        old = import_other(args.other, Path(workdir))
        this = Simulator(BalanceParameters(), FS_HZ, seed=1, hold=args.hold)
        other = old.core.sim.Simulator(old.core.model.BalanceParameters(), FS_HZ, seed=1,
                                       hold=args.hold)
        print(alternate(this, other, excitation(this.hold_setpoints_V, args.samples),
                        args.block, args.rounds), args.hold)
    return 0


if __name__ == '__main__':
    sys.exit(main())
