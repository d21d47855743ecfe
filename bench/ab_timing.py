"""
The timing loop shared by the A/B benchmarks (``ab_chain.py``, ``ab_package.py``).

Two simulators step the same blocks alternately, the order swapped every block, so that a slow
spell of a shared VM hits both alike.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

FS_HZ = 20000.0


def add_timing_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options of :func:`alternate`: ``--block``, ``--samples``, ``--rounds``."""
    parser.add_argument('--block', type=int, default=1000, help='samples per block')
    parser.add_argument('--samples', type=int, default=200000, help='samples per round')
    parser.add_argument('--rounds', type=int, default=3)


def excitation(hold_V: np.ndarray, n: int) -> np.ndarray:
    """Hold setpoints [V] plus a 2 mV coil sine and a 0.1 V load-changer step, shape (2, n)."""
    u = np.tile(np.asarray(hold_V, dtype=float)[:, None], (1, n))
    u[0] += 0.002 * np.sin(np.arange(n) * 0.01)
    u[1, n // 2:] += 0.1
    return u


def alternate(this, other, u: np.ndarray, block: int, rounds: int) -> str:
    """
    Time ``this`` and ``other`` (objects with ``step_block`` and ``reset``) on ``u``.

    Returns
    -------
    str
        Both rates [samples/s], their ratio and the largest difference of the outputs.
    """
    for sim in (this, other):     # compile (or load) both before timing
        sim.step_block(u[:, :10])
    elapsed = [0.0, 0.0]
    diff = 0.0
    count = 0
    for _ in range(rounds):
        this.reset()
        other.reset()
        for k, start in enumerate(range(0, u.shape[1] - block + 1, block)):
            chunk = u[:, start:start + block]
            pair = [(this, 0), (other, 1)] if k % 2 else [(other, 1), (this, 0)]
            outs = [None, None]
            for sim, slot in pair:
                t0 = time.perf_counter()
                outs[slot] = sim.step_block(chunk)
                elapsed[slot] += time.perf_counter() - t0
            diff = max(diff, float(np.abs(outs[0] - outs[1]).max()))
            count += block
    return (f'working tree {count / elapsed[0] / 1e6:8.3f} M/s   other '
            f'{count / elapsed[1] / 1e6:8.3f} M/s   working tree / other '
            f'{elapsed[1] / elapsed[0]:6.3f}   largest output difference {diff:.3g}   '
            f'({count} samples each, blocks of {block})')
