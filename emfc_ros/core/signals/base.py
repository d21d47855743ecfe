"""
The signal protocol and the small helpers every signal shares.

A signal maps local sample indices ``k >= 0`` to setpoint voltages. Sample ``k`` is a pure
function of ``k``: generating in blocks of any size gives the whole-array result bit for bit.
"""

from __future__ import annotations

import math
from typing import Protocol, runtime_checkable

import numpy as np

from emfc_ros.core.errors import SignalError


@runtime_checkable
class Signal(Protocol):
    """
    Anything that turns local sample indices into float64 samples.

    Attributes
    ----------
    sample_rate_Hz : float
        The sample rate the signal was designed for.
    """

    sample_rate_Hz: float

    def samples(self, k: np.ndarray) -> np.ndarray:
        """
        Evaluate the signal.

        Parameters
        ----------
        k : numpy.ndarray
            int64 sample indices, all >= 0.

        Returns
        -------
        numpy.ndarray
            float64 samples of the same shape as ``k``.
        """
        ...  # pragma: no cover


def as_index(k: np.ndarray) -> np.ndarray:
    """
    Check and convert sample indices.

    Parameters
    ----------
    k : array_like of int
        Sample indices, all >= 0.

    Returns
    -------
    numpy.ndarray
        The indices as int64 (no copy when already int64).

    Raises
    ------
    SignalError
        If the indices are not integers or some are negative.
    """
    k = np.asarray(k)
    if k.dtype != np.int64:
        if k.dtype.kind not in 'iu':
            raise SignalError(f'sample indices must be integers, got dtype {k.dtype}')
        k = k.astype(np.int64)
    if k.size and k.min() < 0:
        raise SignalError(f'sample indices must be >= 0, got {int(k.min())}')
    return k


def check_rate(sample_rate_Hz: float) -> float:
    """
    Check a sample rate.

    Parameters
    ----------
    sample_rate_Hz : float
        The sample rate.

    Returns
    -------
    float
        The sample rate as float.

    Raises
    ------
    SignalError
        If it is not a finite positive number.
    """
    value = float(sample_rate_Hz)
    if not math.isfinite(value) or value <= 0.0:
        raise SignalError(f'sample_rate_Hz must be finite and > 0, got {sample_rate_Hz!r}')
    return value


def check_finite(name: str, value: float) -> float:
    """
    Check that a parameter is a finite number.

    Parameters
    ----------
    name : str
        Parameter name for the message.
    value : float
        The value.

    Returns
    -------
    float
        The value as float.

    Raises
    ------
    SignalError
        If it is not finite.
    """
    value = float(value)
    if not math.isfinite(value):
        raise SignalError(f'{name} must be finite, got {value!r}')
    return value


def check_frequency(name: str, frequency_Hz: float, sample_rate_Hz: float, *,
                    positive: bool = False) -> float:
    """
    Check that a frequency lies in [0, fs/2] (or (0, fs/2] when ``positive``).

    Parameters
    ----------
    name : str
        Parameter name for the message.
    frequency_Hz : float
        The frequency.
    sample_rate_Hz : float
        The sample rate.
    positive : bool
        Refuse zero.

    Returns
    -------
    float
        The frequency as float.

    Raises
    ------
    SignalError
        If it is out of range.
    """
    value = check_finite(name, frequency_Hz)
    nyquist_Hz = 0.5 * sample_rate_Hz
    if value < 0.0 or (positive and value == 0.0) or value > nyquist_Hz:
        low = '(0' if positive else '[0'
        raise SignalError(f'{name} must be in {low}, {nyquist_Hz!r}] Hz (Nyquist), '
                          f'got {value!r}')
    return value
