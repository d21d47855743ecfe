"""
Seeded, counter-based noise for the simulator: a pure function of the sample index and the seed.

The simulator's kernel draws its noise per chunk of samples inside the compiled loop
(:func:`emfc_ros.core.sim.chain.chain_block`); this module derives the key from the seed and
computes the same numbers vectorised in numpy (for tests, baselines and documentation).

Generator: SplitMix64 in counter form, inverted through the normal distribution. With
``key = noise_key(seed)``, sample ``i`` uses the 64-bit outputs
``z_j = mix(key + j * 0x9E3779B97F4A7C15 mod 2**64)`` at ``j = 3 i + 1, 3 i + 2, 3 i + 3``
(``mix`` is SplitMix64's finaliser) for the sensor, coil-current and load-changer-current
noise. Each ``z`` becomes ``p = ((z >> 11) + 0.5) / 2**53`` in (0, 1) and then a standard normal
value through Acklam's rational approximation of the inverse normal CDF (relative error below
1.2e-9; tails to 8.3 sigma). No state is carried between samples, so block-wise equals one-shot
bit for bit for any block sizes, on either backend. The compiled and the interpreted kernel agree
with :func:`standard_normals` to rounding.
"""

from __future__ import annotations

import numpy as np

#: Rows of a noise block.
ROWS = ('sensor_position', 'coil_current', 'load_changer_current')

_MASK = (1 << 64) - 1
_GOLDEN = 0x9E3779B97F4A7C15
_MIX1 = 0xBF58476D1CE4E5B9
_MIX2 = 0x94D049BB133111EB
#: Distinguishes the simulator's key from other uses of the same seed.
_DOMAIN = 0x656D66635F73696D   # 'emfc_sim'


def check_seed(seed: int) -> int:
    """
    Validate a noise seed.

    Parameters
    ----------
    seed : int
        An integer in [0, 2**64).

    Returns
    -------
    int
        The seed.

    Raises
    ------
    ValueError
        If the seed is not such an integer.
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or \
            not 0 <= int(seed) <= _MASK:
        raise ValueError(f'seed must be an integer in [0, 2**64), got {seed!r}')
    return int(seed)


def _mix(z: int) -> int:
    z = ((z ^ (z >> 30)) * _MIX1) & _MASK
    z = ((z ^ (z >> 27)) * _MIX2) & _MASK
    return z ^ (z >> 31)


def noise_key(seed: int) -> np.uint64:
    """
    Key of the noise streams for a seed (the seed hashed, so nearby seeds are unrelated).

    Parameters
    ----------
    seed : int
        Seed in [0, 2**64).

    Returns
    -------
    numpy.uint64
        The key.
    """
    return np.uint64(_mix(_mix(check_seed(seed) ^ _DOMAIN)))


def standard_normals(seed: int, first: int, n: int) -> np.ndarray:
    """
    The simulator's noise of samples ``[first, first + n)`` as standard normal values.

    Parameters
    ----------
    seed : int
        Seed in [0, 2**64).
    first : int
        Index of the first sample (>= 0).
    n : int
        Number of samples (>= 0).

    Returns
    -------
    ndarray, shape (3, n)
        Rows as ``ROWS``; multiply by the configured rms values.
    """
    if first < 0 or n < 0:
        raise ValueError(f'first and n must be >= 0, got {first!r} and {n!r}')
    key = noise_key(seed)
    counter = np.arange(first, first + n, dtype=np.uint64) * np.uint64(3)
    out = np.empty((len(ROWS), n))
    for row in range(len(ROWS)):
        z = key + (counter + np.uint64(row + 1)) * np.uint64(_GOLDEN)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(_MIX1)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(_MIX2)
        z = z ^ (z >> np.uint64(31))
        out[row] = inverse_normal_cdf(((z >> np.uint64(11)).astype(float) + 0.5) / 2.0 ** 53)
    return out


_A = (-3.969683028665376e+01, 2.209460984245205e+02, -2.759285104469687e+02,
      1.383577518672690e+02, -3.066479806614716e+01, 2.506628277459239e+00)
_B = (-5.447609879822406e+01, 1.615858368580409e+02, -1.556989798598866e+02,
      6.680131188771972e+01, -1.328068155288572e+01, 1.0)
_C = (-7.784894002430293e-03, -3.223964580411365e-01, -2.400758277161838e+00,
      -2.549732539343734e+00, 4.374664141464968e+00, 2.938163982698783e+00)
_D = (7.784695709041462e-03, 3.224671290700398e-01, 2.445134137142996e+00,
      3.754408661907416e+00, 1.0)
_P_LOW = 0.02425


def _horner_desc(coeffs, x):
    acc = np.zeros_like(x) + coeffs[0]
    for c in coeffs[1:]:
        acc = acc * x + c
    return acc


def inverse_normal_cdf(p: np.ndarray) -> np.ndarray:
    """
    Acklam's rational approximation of the standard normal quantile (relative error 1.2e-9).

    Parameters
    ----------
    p : ndarray
        Probabilities in (0, 1).

    Returns
    -------
    ndarray
        Quantiles.
    """
    p = np.asarray(p, dtype=float)
    q = p - 0.5
    r = q * q
    out = _horner_desc(_A, r) * q / _horner_desc(_B, r)
    tail = (p < _P_LOW) | (p > 1.0 - _P_LOW)
    if np.any(tail):
        pt = p[tail]
        qt = np.sqrt(-2.0 * np.log(np.minimum(pt, 1.0 - pt)))
        v = _horner_desc(_C, qt) / _horner_desc(_D, qt)
        out[tail] = np.where(pt < 0.5, v, -v)
    return out
