"""
Response at selected frequencies, as the paper reports it.

The paper gives "the amplitude as well as the phase response at selected frequencies". Two
methods, both evaluated over the whole record:

* ``'sine_fit'`` (default): one joint linear least-squares fit of
  ``x(t) = c + sum_k (a_k cos(w_k t) + b_k sin(w_k t))`` to input and output at all the
  requested frequencies (:func:`scipy.linalg.lstsq`). The complex amplitude is
  ``X_k = a_k - j b_k`` and ``H_k = Y_k / U_k``. The residual variance ``s^2`` and
  ``(A^T A)^-1`` give ``Var(X_k) = Var(a_k) + Var(b_k)``, propagated to
  ``std(H)^2 = |H|^2 (Var(Y)/|Y|^2 + Var(U)/|U|^2)``. Exact for sines and multisines at these
  frequencies in steady state (they need not be on a DFT line); the std assumes white
  residuals.
* ``'dft'``: the ratio of single-frequency DFTs ``Y(f) / U(f)`` with
  ``X(f) = sum_n x[n] exp(-j 2 pi f n / fs)`` (an ETFE at arbitrary frequencies). Right for
  transient records, e.g. a chirp whose response has died out by the end. No std.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy import linalg

from emfc_ros.core.ident.errors import IdentificationError
from emfc_ros.core.ident.frf import as_records, check_rate, FrequencyResponseData

METHODS = ('sine_fit', 'dft')


def response_at(input: np.ndarray, output: np.ndarray, sample_rate_Hz: float,
                frequencies_Hz: Sequence[float], *, method: str = 'sine_fit',
                input_unit: str = '', output_unit: str = '') -> FrequencyResponseData:
    """
    Complex response at the given frequencies.

    Parameters
    ----------
    input, output : ndarray
        Records on the same sample clock, equal length.
    sample_rate_Hz : float
        Sample rate [Hz].
    frequencies_Hz : sequence of float
        Distinct frequencies in (0, fs/2) [Hz].
    method : {'sine_fit', 'dft'}
        See the module docstring.
    input_unit, output_unit : str
        Units carried into the result.

    Returns
    -------
    FrequencyResponseData
        Estimator ``method``; ``coherence`` NaN; ``std`` NaN for ``'dft'``; ``details`` holds
        the complex amplitudes ``input_amplitude`` and ``output_amplitude``.

    Raises
    ------
    IdentificationError
        If the frequencies are out of range or repeat, the records differ in length, or the
        input has no component at some frequency.
    """
    if method not in METHODS:
        raise IdentificationError(f'method must be one of {METHODS}, got {method!r}')
    fs = check_rate(sample_rate_Hz)
    u, y = as_records(('input', 'output'), (input, output))
    f = np.atleast_1d(np.asarray(frequencies_Hz, dtype=float))
    if f.ndim != 1 or f.size == 0 or not np.isfinite(f).all() or f.min() <= 0.0 or \
            f.max() >= 0.5 * fs:
        raise IdentificationError(f'frequencies_Hz must be finite and in (0, {0.5 * fs}) Hz '
                                  f'(Nyquist), got {frequencies_Hz!r}')
    if np.unique(f).size != f.size:
        raise IdentificationError('frequencies_Hz must not repeat')
    t = np.arange(u.size) / fs
    if method == 'dft':
        kernel = np.exp(-2j * np.pi * np.outer(f, t))
        U = kernel @ u * (2.0 / u.size)
        Y = kernel @ y * (2.0 / u.size)
        var_u = var_y = np.full(f.shape, np.nan)
    else:
        phase = 2.0 * np.pi * np.outer(t, f)
        design = np.hstack((np.ones((t.size, 1)), np.cos(phase), np.sin(phase)))
        if design.shape[0] <= design.shape[1]:
            raise IdentificationError(f'{f.size} frequencies need more than '
                                      f'{design.shape[1]} samples, got {t.size}')
        U, var_u = _sine_amplitudes(design, u, f.size)
        Y, var_y = _sine_amplitudes(design, y, f.size)
    if np.any(np.abs(U) <= 1e-12 * np.max(np.abs(U))) or np.max(np.abs(U)) == 0.0:
        raise IdentificationError('the input has no component at some requested frequency')
    h = Y / U
    std = np.abs(h) * np.sqrt(var_y / np.abs(Y) ** 2 + var_u / np.abs(U) ** 2)
    nan = np.full(f.shape, np.nan)
    return FrequencyResponseData(f, h, nan, std, 1.0, method, input_unit, output_unit,
                                 {'input_amplitude': U, 'output_amplitude': Y})


def _sine_amplitudes(design: np.ndarray, x: np.ndarray, count: int):
    """Complex amplitudes ``a - j b`` and their variances from a least-squares sine fit."""
    coef, _, rank, sv = linalg.lstsq(design, x)
    if rank < design.shape[1]:
        raise IdentificationError('the frequencies cannot be separated over this record '
                                  '(rank-deficient sine fit); use a longer record')
    resid = x - design @ coef
    dof = design.shape[0] - design.shape[1]
    s2 = float(resid @ resid) / dof
    cov_diag = s2 * np.diag(linalg.pinvh(design.T @ design))
    a, b = coef[1:1 + count], coef[1 + count:]
    var = cov_diag[1:1 + count] + cov_diag[1 + count:]
    return a - 1j * b, var
