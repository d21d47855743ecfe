"""
emfc-compile-kernels: compile the numba kernels into numba's cache, ahead of the first run.

``pip install .`` installs numba but compiles nothing: without this, the first command that
simulates waits about 15 s for the simulator's kernel (``docs/simulator.md``). Run it once after
installing (``tools/setup_env.sh`` does); it prints, per kernel, whether numba compiled it or
loaded it from its cache, how long that took and where the cache is.
"""

from __future__ import annotations

import argparse
import sys
from typing import List, Optional


def main(argv: Optional[List[str]] = None) -> int:
    """
    Entry point of ``emfc-compile-kernels``.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (``sys.argv[1:]`` when None).

    Returns
    -------
    int
        0 when every kernel is ready, 1 without numba (the interpreted fallback runs, about
        500 times slower), 2 for an unknown kernel name.
    """
    from emfc_ros.core.kernels import KERNELS, prepare

    parser = argparse.ArgumentParser(prog='emfc-compile-kernels',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('kernels', nargs='*', metavar='KERNEL',
                        help=f'kernels to prepare (default all: {", ".join(KERNELS)})')
    args = parser.parse_args(argv)
    unknown = [k for k in args.kernels if k not in KERNELS]
    if unknown:
        print(f'emfc-compile-kernels: unknown kernel(s) {unknown}; known: {list(KERNELS)}',
              file=sys.stderr)
        return 2

    def report(status) -> None:
        how = (f'compiled {status.compiled} signature(s)' if status.compiled
               else f'loaded {status.loaded} signature(s) from the cache')
        print(f'{status.name}: {how} in {status.seconds:.1f} s ({status.cache_path})',
              flush=True)

    try:
        prepare(args.kernels or None, report)
    except ImportError:
        print('emfc-compile-kernels: numba is not installed: the kernels run interpreted, '
              'about 500 times slower (pip install numba)', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
