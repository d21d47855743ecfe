"""
Check sample records taken on one clock: one-dimensional, finite, of equal length.

Shared by the identification, the dynamic weigher and the simulator kernels, each raising its
own error class (all subclasses of :class:`ValueError`).
"""

from __future__ import annotations

from typing import Sequence, Tuple, Type

import numpy as np


def _joined(items: Sequence[object]) -> str:
    words = [str(i) for i in items]
    return words[0] if len(words) == 1 else ', '.join(words[:-1]) + ' and ' + words[-1]


def same_clock_records(names: Sequence[str], arrays: Sequence[object],
                       error: Type[ValueError] = ValueError,
                       allow_empty: bool = False,
                       check_finite: bool = True) -> Tuple[np.ndarray, ...]:
    """
    Return records as contiguous float64 arrays after checking them.

    Parameters
    ----------
    names : sequence of str
        Argument names, for the messages.
    arrays : sequence of array_like
        The records, one per name.
    error : type
        Exception class raised (a subclass of ValueError).
    allow_empty : bool
        Accept records of no samples.
    check_finite : bool
        Check every sample for NaN and infinity (a caller whose result shows any non-finite
        sample may skip this pass and call again with it when the result is not finite).

    Returns
    -------
    tuple of ndarray
        The records, in order (views where no conversion was needed).

    Raises
    ------
    ValueError
        Of class ``error``, naming the record: not one-dimensional, empty (unless allowed),
        holding non-finite samples, or of unequal lengths.
    """
    records = tuple(np.ascontiguousarray(a, dtype=float) for a in arrays)
    for name, arr in zip(names, records):
        if arr.ndim != 1 or (arr.size == 0 and not allow_empty):
            raise error(f'{name} must be a {"" if allow_empty else "non-empty "}1-D array, '
                        f'got shape {arr.shape}')
        if check_finite and not np.isfinite(arr).all():
            raise error(f'{name} holds non-finite samples (NaN or infinite)')
    sizes = [arr.size for arr in records]
    if len(set(sizes)) > 1:
        raise error(f'{_joined(names)} must have equal length, got {_joined(sizes)}')
    return records
