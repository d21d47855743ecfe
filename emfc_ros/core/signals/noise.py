"""
Seeded uniform and Gaussian noise that is a pure function of the sample index.

Samples are drawn in fixed chunks of :data:`CHUNK_SAMPLES`; chunk ``c`` comes from
``numpy.random.default_rng(numpy.random.SeedSequence([seed, c]))``, so any sample can be
regenerated without the ones before it. The last few chunks are cached.
"""

from __future__ import annotations

from collections import OrderedDict
import threading

import numpy as np

from emfc_ros.core.errors import SignalError
from emfc_ros.core.signals.base import as_index, check_finite, check_rate

CHUNK_SAMPLES = 4096
CACHED_CHUNKS = 8


class _ChunkedNoise:
    """Common chunk machinery; subclasses implement ``_draw(rng, n)``."""

    def __init__(self, seed: int, sample_rate_Hz: float) -> None:
        self.sample_rate_Hz = check_rate(sample_rate_Hz)
        if isinstance(seed, bool) or int(seed) != seed or seed < 0:
            raise SignalError(f'seed must be an integer >= 0, got {seed!r}')
        self.seed = int(seed)
        self._cache: OrderedDict = OrderedDict()
        self._lock = threading.Lock()

    def _draw(self, rng: np.random.Generator, n: int) -> np.ndarray:
        raise NotImplementedError

    def chunk(self, c: int) -> np.ndarray:
        """
        Return the samples of chunk ``c`` (indices ``c * CHUNK_SAMPLES`` onwards).

        Parameters
        ----------
        c : int
            Chunk number >= 0.

        Returns
        -------
        numpy.ndarray
            Read-only float64 array of ``CHUNK_SAMPLES`` samples.
        """
        with self._lock:
            data = self._cache.get(c)
            if data is not None:
                self._cache.move_to_end(c)
                return data
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, c]))
        data = self._draw(rng, CHUNK_SAMPLES)
        data.flags.writeable = False
        with self._lock:
            self._cache[c] = data
            while len(self._cache) > CACHED_CHUNKS:
                self._cache.popitem(last=False)
        return data

    def samples(self, k: np.ndarray) -> np.ndarray:
        """
        Evaluate the noise at local sample indices.

        Parameters
        ----------
        k : numpy.ndarray
            int64 sample indices >= 0.

        Returns
        -------
        numpy.ndarray
            float64 samples, same shape as ``k``.
        """
        k = as_index(k)
        if k.size == 0:
            return np.zeros(k.shape)
        c = k // CHUNK_SAMPLES
        c_min, c_max = int(c.min()), int(c.max())
        if c_min == c_max:
            return self.chunk(c_min)[k - c_min * CHUNK_SAMPLES]
        if (c_max - c_min + 1) <= 2 * (k.size // CHUNK_SAMPLES + 1):
            # mostly contiguous: gather from the concatenated chunks
            get = self.chunk if c_max - c_min < CACHED_CHUNKS // 2 else self._fresh
            data = np.concatenate([get(ci) for ci in range(c_min, c_max + 1)])
            return data[k - c_min * CHUNK_SAMPLES]
        out = np.empty(k.shape)
        for ci in np.unique(c):
            sel = c == ci
            out[sel] = self.chunk(int(ci))[k[sel] - int(ci) * CHUNK_SAMPLES]
        return out

    def _fresh(self, c: int) -> np.ndarray:
        with self._lock:
            data = self._cache.get(c)
        if data is not None:
            return data
        return self._draw(np.random.default_rng(np.random.SeedSequence([self.seed, c])),
                          CHUNK_SAMPLES)


class UniformNoise(_ChunkedNoise):
    """
    Uniform noise in [low_V, high_V).

    Parameters
    ----------
    low_V, high_V : float
        Bounds, ``low_V <= high_V``.
    seed : int
        Seed (>= 0).
    sample_rate_Hz : float
        Sample rate.
    """

    def __init__(self, low_V: float, high_V: float, seed: int = 0,
                 sample_rate_Hz: float = 10000.0) -> None:
        super().__init__(seed, sample_rate_Hz)
        self.low_V = check_finite('low_V', low_V)
        self.high_V = check_finite('high_V', high_V)
        if self.high_V < self.low_V:
            raise SignalError(f'high_V ({high_V!r}) must be >= low_V ({low_V!r})')

    def _draw(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return rng.uniform(self.low_V, self.high_V, n)

    def __repr__(self) -> str:
        return (f'UniformNoise(low_V={self.low_V!r}, high_V={self.high_V!r}, '
                f'seed={self.seed!r})')


class GaussianNoise(_ChunkedNoise):
    """
    Gaussian white noise.

    Parameters
    ----------
    mean_V : float
        Mean.
    std_V : float
        Standard deviation (>= 0).
    seed : int
        Seed (>= 0).
    sample_rate_Hz : float
        Sample rate.
    """

    def __init__(self, mean_V: float, std_V: float, seed: int = 0,
                 sample_rate_Hz: float = 10000.0) -> None:
        super().__init__(seed, sample_rate_Hz)
        self.mean_V = check_finite('mean_V', mean_V)
        self.std_V = check_finite('std_V', std_V)
        if self.std_V < 0.0:
            raise SignalError(f'std_V must be >= 0, got {std_V!r}')

    def _draw(self, rng: np.random.Generator, n: int) -> np.ndarray:
        return rng.normal(self.mean_V, self.std_V, n)

    def __repr__(self) -> str:
        return (f'GaussianNoise(mean_V={self.mean_V!r}, std_V={self.std_V!r}, '
                f'seed={self.seed!r})')
