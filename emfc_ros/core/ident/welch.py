"""
Welch sums of auto- and cross-spectra of several records, computed chunk by chunk.

The segments are the ones :func:`scipy.signal.csd` cuts (``n_segments`` segments of
``nperseg`` samples, ``step`` apart). They are never copied as a whole: a chunk of a few
segments (:data:`CHUNK_BYTES` of samples for all channels, so that it stays in the core's
cache) is detrended and windowed in place in a preallocated buffer, Fourier transformed, and
its products are added to the running sums before the next chunk is read. Profiled at 10^6
samples (issue 14), the former whole-record version spent 40 % of its time in the windowed copy
of every segment and 15 % in a cumulative sum for the segment means, against 28 % in the FFT;
chunked, the FFT is about two thirds of the time and the products of the spectra most of the
rest (``docs/benchmarks.md``). The segment means come from block sums taken once over the
record (:func:`segment_means`) when the overlap lets whole blocks tile the segments.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence, Union

import numpy as np
from scipy import fft as spfft

# Samples of one chunk, all channels together [bytes]. On the project's 2-core machine (4 MiB
# L2 per core, shared with other work) 512 KiB and 1 MiB were within the run-to-run noise of
# each other (1 MiB halves the per-chunk Python calls); 128 KiB paid for those calls and 4 MiB
# lost the cache. The FFT runs on one thread: ``workers=2`` was no faster on that machine
# under load (``bench/bench_ident_core.py --sweep`` measures both; docs/benchmarks.md).
CHUNK_BYTES = 1 << 20
# Threads of each FFT call (scipy.fft ``workers``).
FFT_WORKERS = 1

_VECDOT = getattr(np, 'vecdot', None)   # numpy >= 2.0: sum(conj(a) * b) without a copy


def segment_views(records: Sequence[np.ndarray], nperseg: int, step: int,
                  n_segments: int) -> list:
    """
    Strided (copy-free) views of the segments of each record.

    Parameters
    ----------
    records : sequence of ndarray
        One-dimensional float64 records of equal length.
    nperseg, step, n_segments : int
        Segment length, distance between segment starts and number of segments [samples].

    Returns
    -------
    list of ndarray
        One read-only view of shape (n_segments, nperseg) per record.
    """
    return [np.lib.stride_tricks.sliding_window_view(r, nperseg)[::step][:n_segments]
            for r in records]


def segment_means(record: np.ndarray, nperseg: int, step: int, n_segments: int,
                  max_blocks: int = 8) -> Optional[np.ndarray]:
    """
    Means of all segments from sums of blocks that tile them, in one pass over the record.

    With ``g = gcd(step, nperseg)`` every segment is ``nperseg / g`` whole blocks of ``g``
    samples (two half-segments at 50 % overlap), so the block sums, taken once over the
    record, give every segment's sum with ``nperseg / g - 1`` additions.

    Parameters
    ----------
    record : ndarray
        One-dimensional float64 record.
    nperseg, step, n_segments : int
        Segment length, distance between segment starts and number of segments [samples].
    max_blocks : int
        Largest number of blocks per segment worth it (beyond, None is returned and the
        caller takes the means segment by segment).

    Returns
    -------
    ndarray or None
        Shape (n_segments,), or None when a segment would take more than ``max_blocks``
        blocks.
    """
    g = math.gcd(step, nperseg)
    per_segment, stride = nperseg // g, step // g
    if per_segment > max_blocks:
        return None
    used = (n_segments - 1) * step + nperseg
    blocks = record[:used].reshape(-1, g).sum(axis=-1)
    sums = blocks[0:(n_segments - 1) * stride + 1:stride].copy()
    for j in range(1, per_segment):
        sums += blocks[j:j + (n_segments - 1) * stride + 1:stride]
    return sums / nperseg


def welch_sums(records: Sequence[np.ndarray], nperseg: int, step: int, n_segments: int,
               window: np.ndarray, detrend: Union[str, bool]) -> np.ndarray:
    """
    Sum over segments of ``conj(X_i) X_j`` for every pair of records.

    ``X_i`` is the one-sided FFT of the detrended, windowed segment of record ``i``, as in
    :func:`scipy.signal.csd` before scaling and averaging.

    Parameters
    ----------
    records : sequence of ndarray
        C one-dimensional float64 records of equal length.
    nperseg, step, n_segments : int
        Segment length, distance between segment starts and number of segments [samples]
        (the caller checked them against the record length).
    window : ndarray, shape (nperseg,)
        Window samples.
    detrend : {'constant', 'linear', False}
        Per-segment detrending as in :func:`scipy.signal.welch`.

    Returns
    -------
    ndarray, shape (nperseg // 2 + 1, C, C)
        ``sums[f, i, j] = sum_k conj(X_ik[f]) X_jk[f]``; Hermitian in ``(i, j)``, with an
        exactly real diagonal.
    """
    n_ch = len(records)
    n_freq = nperseg // 2 + 1
    views = segment_views(records, nperseg, step, n_segments)
    chunk = int(min(n_segments, max(1, CHUNK_BYTES // (8 * nperseg * n_ch))))
    buf = np.empty((n_ch, chunk, nperseg))
    auto = np.zeros((n_ch, 2 * n_freq))          # sum of re^2 and im^2, interleaved
    cross = {(i, j): np.zeros(n_freq, dtype=complex)
             for i in range(n_ch) for j in range(i + 1, n_ch)}
    means = [segment_means(r, nperseg, step, n_segments) for r in records] \
        if detrend == 'constant' else [None] * n_ch
    for k0 in range(0, n_segments, chunk):
        k1 = min(n_segments, k0 + chunk)
        part = buf[:, :k1 - k0]
        for c, view in enumerate(views):
            seg = view[k0:k1]
            if detrend == 'constant':
                m = means[c]
                np.subtract(seg, seg.mean(axis=-1, keepdims=True) if m is None
                            else m[k0:k1, None], out=part[c])
                part[c] *= window
            elif detrend:
                from scipy import signal as sps     # linear detrend only
                np.multiply(sps.detrend(seg, axis=-1, type=detrend), window, out=part[c])
            else:
                np.multiply(seg, window, out=part[c])
        spec = spfft.rfft(part, axis=-1, workers=FFT_WORKERS)   # (C, k, F)
        as_real = spec.view(float)                # (C, k, 2F): re, im interleaved
        for i in range(n_ch):
            auto[i] += np.einsum('kf,kf->f', as_real[i], as_real[i])
        for (i, j), acc in cross.items():
            if _VECDOT is not None:
                acc += _VECDOT(spec[i], spec[j], axis=0)
            else:
                acc += np.einsum('kf,kf->f', np.conj(spec[i]), spec[j])
    sums = np.empty((n_freq, n_ch, n_ch), dtype=complex)
    for i in range(n_ch):
        sums[:, i, i] = auto[i, 0::2] + auto[i, 1::2]
    for (i, j), acc in cross.items():
        sums[:, i, j] = acc
        sums[:, j, i] = np.conj(acc)
    return sums
