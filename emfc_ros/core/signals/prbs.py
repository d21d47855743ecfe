"""
Pseudo-random binary sequences from maximum-length linear feedback shift registers.

The register and its taps are those of :func:`scipy.signal.max_len_seq`: with the initial
state ``a[0..n-1]`` the sequence obeys ``a[i + n] = a[i] XOR a[i + t1] XOR ...`` for the taps
``t1, ...`` of order ``n``, so the bits equal scipy's for the same order and state.

Sample ``k`` is a pure function of ``k`` even for order 31: the register state at any bit
index is reached by a jump-ahead (powers ``M^(2^j)`` of the GF(2) companion matrix), and bits
are generated forward vectorised, using that a sequence annihilated by ``p(x)`` is also
annihilated by ``p(x)^(2^m) = p(x^(2^m))`` over GF(2), which lets one numpy step produce
``(n - t_max) 2^m`` new bits. Periods up to 2^20 bits are cached whole; longer ones in
cached chunks of 2^16 bits, so sequential blocks cost one gather.
"""

from __future__ import annotations

from collections import OrderedDict
import threading
from typing import Optional, Sequence

import numpy as np

from emfc_ros.core.errors import SignalError
from emfc_ros.core.signals.base import as_index, check_finite, check_rate

#: Feedback taps per order, identical to ``scipy.signal._max_len_seq._mls_taps``.
MLS_TAPS = {
    2: (1,), 3: (2,), 4: (3,), 5: (3,), 6: (5,), 7: (6,), 8: (7, 6, 1), 9: (5,), 10: (7,),
    11: (9,), 12: (11, 10, 4), 13: (12, 11, 8), 14: (13, 12, 2), 15: (14,), 16: (15, 13, 4),
    17: (14,), 18: (11,), 19: (18, 17, 14), 20: (17,), 21: (19,), 22: (21,), 23: (18,),
    24: (23, 22, 17), 25: (22,), 26: (25, 24, 20), 27: (26, 25, 22), 28: (25,), 29: (27,),
    30: (29, 28, 7), 31: (28,),
}
MIN_ORDER = 2
MAX_ORDER = 31
TABLE_MAX_BITS = 1 << 20
CHUNK_BITS = 1 << 16
CACHED_CHUNKS = 4


class Prbs:
    """
    A maximum-length sequence held for ``hold_samples`` samples per bit.

    Bit 1 outputs ``high_V``, bit 0 ``low_V``. The period is ``(2^order - 1) hold_samples``.

    Parameters
    ----------
    order : int
        Register length n, 2..31.
    hold_samples : int
        Samples per bit, >= 1.
    low_V, high_V : float
        Output levels for bits 0 and 1.
    sample_rate_Hz : float
        Sample rate.
    state : sequence of int, optional
        Initial register state (n values 0/1, not all 0); all ones by default, like scipy.
    """

    def __init__(self, order: int, hold_samples: int = 1, low_V: float = -1.0,
                 high_V: float = 1.0, sample_rate_Hz: float = 10000.0,
                 state: Optional[Sequence[int]] = None) -> None:
        self.sample_rate_Hz = check_rate(sample_rate_Hz)
        if isinstance(order, bool) or int(order) != order or not (
                MIN_ORDER <= order <= MAX_ORDER):
            raise SignalError(f'order must be an integer in [{MIN_ORDER}, {MAX_ORDER}], '
                              f'got {order!r}')
        if isinstance(hold_samples, bool) or int(hold_samples) != hold_samples or \
                hold_samples < 1:
            raise SignalError(f'hold_samples must be an integer >= 1, got {hold_samples!r}')
        self.order = int(order)
        self.hold_samples = int(hold_samples)
        self.low_V = check_finite('low_V', low_V)
        self.high_V = check_finite('high_V', high_V)
        self.period_bits = (1 << self.order) - 1
        self.period_samples = self.period_bits * self.hold_samples
        self.taps = MLS_TAPS[self.order]
        if state is None:
            state0 = np.ones(self.order, dtype=np.int8)
        else:
            state0 = np.asarray(state)
            if state0.shape != (self.order,) or not np.isin(state0, (0, 1)).all():
                raise SignalError(f'state must be {self.order} values of 0 or 1')
            if not state0.any():
                raise SignalError('state must not be all zeros')
            state0 = state0.astype(np.int8)
        self.initial_state = state0
        self._levels = np.array([self.low_V, self.high_V], dtype=np.float64)
        self._jumps = _jump_matrices(self.order, self.taps)
        self._bit_table: Optional[np.ndarray] = None
        self._table: Optional[np.ndarray] = None
        self._chunks: OrderedDict = OrderedDict()
        self._lock = threading.Lock()
        if self.period_bits <= TABLE_MAX_BITS:
            self._bit_table = extend(state0, self.taps, self.period_bits)
            self._table = self._levels[self._bit_table]

    def state_at(self, bit_index: int) -> np.ndarray:
        """
        Register state ``a[b], ..., a[b + n - 1]`` at a bit index (jump-ahead).

        Parameters
        ----------
        bit_index : int
            Bit index b >= 0 (taken modulo the period).

        Returns
        -------
        numpy.ndarray
            int8 array of the n state bits (scipy's ``state`` convention).
        """
        b = int(bit_index) % self.period_bits
        s = self.initial_state.astype(np.int64)
        j = 0
        while b:
            if b & 1:
                s = (self._jumps[j] @ s) & 1
            b >>= 1
            j += 1
        return s.astype(np.int8)

    def bits(self, bit_index: np.ndarray) -> np.ndarray:
        """
        Sequence bits at bit indices.

        Parameters
        ----------
        bit_index : numpy.ndarray
            int64 bit indices >= 0 (taken modulo the period).

        Returns
        -------
        numpy.ndarray
            int8 bits 0/1, same shape.
        """
        b = as_index(bit_index) % self.period_bits
        if self._bit_table is not None:
            return self._bit_table[b]
        return self._chunk_gather(b)

    def samples(self, k: np.ndarray) -> np.ndarray:
        """
        Evaluate the PRBS at local sample indices.

        Parameters
        ----------
        k : numpy.ndarray
            int64 sample indices >= 0.

        Returns
        -------
        numpy.ndarray
            float64 samples (``low_V`` or ``high_V``), same shape as ``k``.
        """
        k = as_index(k)
        b = k // self.hold_samples if self.hold_samples != 1 else k
        b = b % self.period_bits
        if self._table is not None:
            return self._table[b]
        return self._levels[self._chunk_gather(b)]

    def _chunk_gather(self, b: np.ndarray) -> np.ndarray:
        if b.size == 0:
            return np.zeros(b.shape, dtype=np.int8)
        c = b // CHUNK_BITS
        c_min, c_max = int(c.min()), int(c.max())
        if c_min == c_max:
            return self._chunk(c_min)[b - c_min * CHUNK_BITS]
        first = c_min * CHUNK_BITS
        span = min((c_max - c_min + 1) * CHUNK_BITS, self.period_bits - first)
        if span <= 4 * b.size + 2 * CHUNK_BITS:
            # a large, mostly contiguous request: one uncached run covers it
            return extend(self.state_at(first), self.taps, span)[b - first]
        out = np.empty(b.shape, dtype=np.int8)
        for ci in np.unique(c):
            sel = c == ci
            out[sel] = self._chunk(int(ci))[b[sel] - int(ci) * CHUNK_BITS]
        return out

    def _chunk(self, c: int) -> np.ndarray:
        with self._lock:
            data = self._chunks.get(c)
            if data is not None:
                self._chunks.move_to_end(c)
                return data
        first = c * CHUNK_BITS
        length = min(CHUNK_BITS, self.period_bits - first)
        data = extend(self.state_at(first), self.taps, length)
        with self._lock:
            self._chunks[c] = data
            while len(self._chunks) > CACHED_CHUNKS:
                self._chunks.popitem(last=False)
        return data

    def __repr__(self) -> str:
        return (f'Prbs(order={self.order!r}, hold_samples={self.hold_samples!r}, '
                f'low_V={self.low_V!r}, high_V={self.high_V!r}, '
                f'sample_rate_Hz={self.sample_rate_Hz!r})')


def extend(state: np.ndarray, taps: Sequence[int], length: int) -> np.ndarray:
    """
    Generate ``length`` bits forward from a register state, vectorised.

    Parameters
    ----------
    state : numpy.ndarray
        The n state bits ``a[0..n-1]``.
    taps : sequence of int
        Feedback taps (each < n).
    length : int
        Number of bits to produce.

    Returns
    -------
    numpy.ndarray
        int8 bits ``a[0..length-1]``.
    """
    n = len(state)
    t_max = max(taps)
    out = np.empty(max(length, n), dtype=np.int8)
    out[:n] = state
    filled = n
    while filled < length:
        spread = 1 << ((filled // n).bit_length() - 1)   # largest 2^m with n 2^m <= filled
        base = filled - n * spread
        count = min((n - t_max) * spread, length - filled)
        new = out[base:base + count].copy()
        for t in taps:
            new ^= out[base + t * spread:base + t * spread + count]
        out[filled:filled + count] = new
        filled += count
    return out[:length]


def _jump_matrices(order: int, taps: Sequence[int]) -> list:
    # Companion matrix M with state(i + 1) = M state(i) over GF(2), and M^(2^j) for all j.
    m = np.zeros((order, order), dtype=np.int64)
    for j in range(order - 1):
        m[j, j + 1] = 1
    m[order - 1, 0] = 1
    for t in taps:
        m[order - 1, t] ^= 1
    powers = [m]
    for _ in range(order):
        powers.append((powers[-1] @ powers[-1]) & 1)
    return powers
