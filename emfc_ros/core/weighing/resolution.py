"""
What a quantised channel can still be wrong by after averaging: the resolution budget.

A converter with step ``q`` maps its input ``x`` to ``q round(x / q)``. Averaging many samples
removes the quantisation error only if noise at the converter's input (independent from
sample to sample) dithers it: for Gaussian input noise of standard deviation ``sigma`` the
mean error of one sample, whatever the signal, is the Fourier series

``E[e | x] = sum_k (-1)^k (q / (pi k)) exp(-2 pi^2 k^2 sigma^2 / q^2) sin(2 pi k x / q)``

so its magnitude is at most :func:`quantisation_bias_bound` (never more than ``q / 2``, the
error of an undithered converter). The loop's own motion is no dither: a current toggling
between two DAC codes meets the ADC at two fixed points, each with its fixed error. The bound
holds for any signal and survives averaging; it enters the budget as a rectangular
distribution, ``u = bound / sqrt(3)`` (:func:`quantisation_u`).

Examples (default balance): the precise current channel (24 bit over +/-2.5 V into 20 ohm,
14.9 nA per code, 112 nA rms of amplifier and converter noise: 7.5 codes) has a bound below
1e-300 codes, nothing; the 16-bit current monitor (3.05 uA per code, 0.1 uA rms) one of half a
code, 1.5 uA, which is 25 mg at the pan: a reading from it is honest only with that in its
uncertainty; the position (6.1 nm per code, 2 nm rms) 0.04 codes.

The stream descriptions carry what is needed in ``extra.resolution``:
``{channel: {"step": q, "noise_rms": sigma}}`` in the channel's unit (``noise_rms`` 0 or
absent: unknown, no dither assumed).
"""

from __future__ import annotations

import math
from typing import Mapping, Optional, Tuple

from emfc_ros.core.weighing.errors import WeighingError

#: Terms of the series summed (the next ones are below 1e-300 for sigma >= q / 4).
TERMS = 64


def quantisation_bias_bound(step: float, noise_rms: float = 0.0) -> float:
    """
    Largest mean error of a quantised sample, for any signal, given the input noise.

    Parameters
    ----------
    step : float
        Quantisation step ``q`` (any unit), >= 0 (0: not quantised).
    noise_rms : float
        Standard deviation of independent Gaussian noise at the converter's input (same
        unit), >= 0 (0: unknown or none: no dither).

    Returns
    -------
    float
        ``min(q / 2, sum_k q / (pi k) exp(-2 pi^2 k^2 sigma^2 / q^2))`` (same unit).

    Raises
    ------
    WeighingError
        For a negative or non-finite argument.
    """
    q = _non_negative('step', step)
    sigma = _non_negative('noise_rms', noise_rms)
    if q == 0.0:
        return 0.0
    if sigma == 0.0:
        return 0.5 * q
    a = 2.0 * math.pi ** 2 * (sigma / q) ** 2
    total = 0.0
    for k in range(1, TERMS + 1):
        term = math.exp(-a * k * k) / k
        total += term
        if term < 1e-300:
            break
    return min(0.5 * q, q / math.pi * total)


def quantisation_u(step: float, noise_rms: float = 0.0) -> float:
    """
    Standard uncertainty of an averaged quantised channel: the bias bound over sqrt(3).

    Parameters
    ----------
    step, noise_rms : float
        As :func:`quantisation_bias_bound`.

    Returns
    -------
    float
        Standard uncertainty (same unit).
    """
    return quantisation_bias_bound(step, noise_rms) / math.sqrt(3.0)


def channel_resolution(extra: Mapping, channel: str) -> Optional[Tuple[float, float]]:
    """
    A channel's quantisation step and input noise from a stream description's ``extra``.

    Parameters
    ----------
    extra : Mapping
        The description's ``extra``.
    channel : str
        Channel name.

    Returns
    -------
    (float, float) or None
        ``(step, noise_rms)`` in the channel's unit, or None when the description does not
        say (``extra.resolution.<channel>.step`` absent).

    Raises
    ------
    WeighingError
        If the entry is there but malformed (not a mapping, negative or non-finite values).
    """
    table = extra.get('resolution') if isinstance(extra, Mapping) else None
    if not isinstance(table, Mapping) or channel not in table:
        return None
    entry = table[channel]
    if not isinstance(entry, Mapping) or 'step' not in entry:
        raise WeighingError(f'extra.resolution.{channel}: need a mapping with "step" (and '
                            f'optionally "noise_rms"), got {entry!r}')
    try:
        return (_non_negative(f'extra.resolution.{channel}.step', entry['step']),
                _non_negative(f'extra.resolution.{channel}.noise_rms',
                              entry.get('noise_rms', 0.0)))
    except (TypeError, ValueError) as exc:
        raise WeighingError(str(exc)) from None


def _non_negative(name: str, value: float) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise WeighingError(f'{name}: need a finite number >= 0, got {value!r}') from None
    if not (math.isfinite(out) and out >= 0.0):
        raise WeighingError(f'{name}: need a finite number >= 0, got {value!r}')
    return out
