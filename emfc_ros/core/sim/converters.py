"""
DAC and ADC model in numpy: nearest code, clamped to the converter's codes.

The simulator's kernel does the same per sample (:mod:`emfc_ros.core.sim.chain`); this module
serves baselines, tests and users who convert offline.
"""

from __future__ import annotations

import numpy as np


def lsb_V(bits: int, range_V: float) -> float:
    """
    Step of a bipolar converter.

    Parameters
    ----------
    bits : int
        Resolution [bit].
    range_V : float
        Full scale, +/- value [V].

    Returns
    -------
    float
        ``2 range / 2**bits`` [V] (305.2 uV for 16 bit over +/-10 V).
    """
    return 2.0 * float(range_V) / 2.0 ** int(bits)


def convert_V(v_V: np.ndarray, bits: int, range_V: float, quantise: bool = True) -> np.ndarray:
    """
    Convert voltages like the simulator's DAC and ADC.

    Parameters
    ----------
    v_V : ndarray
        Voltages [V].
    bits : int
        Resolution [bit].
    range_V : float
        Full scale, +/- value [V].
    quantise : bool
        Round to the nearest code ``c lsb`` with ``c`` in ``[-2**(bits-1), 2**(bits-1) - 1]``;
        if False only clamp to ``[-range_V, range_V]``.

    Returns
    -------
    ndarray
        Converted voltages [V].
    """
    v = np.asarray(v_V, dtype=float)
    if not quantise:
        return np.clip(v, -range_V, range_V)
    lsb = lsb_V(bits, range_V)
    lo, hi = -2.0 ** (bits - 1), 2.0 ** (bits - 1) - 1.0
    code = np.floor(np.clip(v / lsb, lo - 1.0, hi + 1.0) + 0.5)
    return np.clip(code, lo, hi) * lsb
