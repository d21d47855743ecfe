"""
Two simultaneous inputs, one output: ``Y = H1 U1 + H2 U2`` solved per frequency.

From the Welch spectral matrix (:func:`~emfc_ros.core.ident.frf.cross_spectra`) with the input
matrix ``S_uu[i, j] = E[conj(U_i) U_j]`` and ``S_uy[i] = E[conj(U_i) Y]``, the H1-type estimate
is ``H = S_uu^-1 S_uy`` (Bendat & Piersol, ch. 7). The multiple coherence is
``gamma^2_y:u = S_uy^H S_uu^-1 S_uy / S_yy``. Treating the ``n_d`` segment spectra as a complex
regression, the complex variance of ``H_i`` is
``S_yy (1 - gamma^2_y:u) [S_uu^-1]_ii / (n_d - 2)``.

Fully or nearly correlated inputs make ``S_uu`` singular: the condition number is checked per
frequency.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence, Tuple, Union
import warnings

import numpy as np

from emfc_ros.core.ident.errors import IdentificationError
from emfc_ros.core.ident.frf import (as_records, cross_spectra, FrequencyResponseData,
                                     WindowSpec)

#: Default largest acceptable condition number of the 2 x 2 input spectral matrix.
MAX_CONDITION = 1.0e6


@dataclass(frozen=True)
class TwoInputResponse:
    """
    Frequency responses of two simultaneous inputs to one output.

    Attributes
    ----------
    responses : tuple of FrequencyResponseData
        One per input (estimator ``'two_input_H1'``); their ``coherence`` is the multiple
        coherence.
    multiple_coherence : ndarray
        ``gamma^2_y:u`` per frequency.
    condition_number : ndarray
        Condition number of ``S_uu`` per frequency (responses are NaN where it exceeds the
        limit).
    input_correlation : ndarray
        Coherence between the two inputs per frequency (0: uncorrelated, 1: fully).
    """

    responses: Tuple[FrequencyResponseData, FrequencyResponseData]
    multiple_coherence: np.ndarray
    condition_number: np.ndarray
    input_correlation: np.ndarray


def estimate_two_input_frf(inputs: Sequence[np.ndarray], output: np.ndarray,
                           sample_rate_Hz: float, *, nperseg: Optional[int] = None,
                           noverlap: Optional[int] = None, window: WindowSpec = 'hann',
                           detrend: Union[str, bool] = 'constant',
                           max_condition: float = MAX_CONDITION,
                           input_units: Sequence[str] = ('', ''),
                           output_unit: str = '') -> TwoInputResponse:
    """
    Estimate ``H1`` and ``H2`` of ``Y = H1 U1 + H2 U2`` from simultaneous excitation.

    Parameters
    ----------
    inputs : sequence of two ndarray
        The two input records.
    output : ndarray
        The output record, same length.
    sample_rate_Hz : float
        Sample rate [Hz].
    nperseg, noverlap, window, detrend
        Welch settings as in :func:`~emfc_ros.core.ident.frf.cross_spectra`.
    max_condition : float
        Frequencies where ``cond(S_uu)`` exceeds this get NaN responses (and a
        ``RuntimeWarning``); if that is more than half of them, the inputs are too correlated
        and an error is raised.
    input_units : sequence of two str
        Units of the inputs.
    output_unit : str
        Unit of the output.

    Returns
    -------
    TwoInputResponse
        Both responses above 0 Hz with multiple coherence and condition numbers.

    Raises
    ------
    IdentificationError
        If there are not two inputs, lengths differ, fewer than three segments are averaged,
        or the inputs are (nearly) fully correlated.
    """
    if len(inputs) != 2:
        raise IdentificationError(f'inputs must hold exactly two records, got {len(inputs)}')
    if len(input_units) != 2:
        raise IdentificationError('input_units must hold two strings')
    u1, u2, y = as_records(('inputs[0]', 'inputs[1]', 'output'), (inputs[0], inputs[1], output))
    spec = cross_spectra((u1, u2, y), sample_rate_Hz, nperseg=nperseg,
                         noverlap=noverlap, window=window, detrend=detrend)
    if spec.n_effective <= 2.0:
        raise IdentificationError(f'two inputs need more than 2 independent averages, got '
                                  f'{spec.n_effective:.2f}; use a shorter nperseg')
    m = spec.matrix[1:]
    suu, suy, syy = m[:, :2, :2], m[:, :2, 2], m[:, 2, 2].real
    cond = np.linalg.cond(suu)
    cond = np.where(np.isfinite(cond), cond, np.inf)
    bad = cond > max_condition
    if np.count_nonzero(bad) > 0.5 * bad.size:
        raise IdentificationError(
            f'the two inputs are (nearly) fully correlated: cond(S_uu) exceeds {max_condition:g} '
            f'at {np.count_nonzero(bad)} of {bad.size} frequencies (median '
            f'{np.median(cond):.3g}); excite them with uncorrelated signals')
    if bad.any():
        warnings.warn(f'cond(S_uu) exceeds {max_condition:g} at {np.count_nonzero(bad)} '
                      f'frequencies; their responses are NaN', RuntimeWarning, stacklevel=2)
    good = ~bad
    h = np.full((m.shape[0], 2), np.nan, dtype=complex)
    inv = np.full((m.shape[0], 2, 2), np.nan, dtype=complex)
    inv[good] = np.linalg.inv(suu[good])
    h[good] = np.einsum('fij,fj->fi', inv[good], suy[good])
    with np.errstate(divide='ignore', invalid='ignore'):
        gamma2 = np.real(np.einsum('fi,fi->f', np.conj(suy), h)) / syy
        gamma2 = np.clip(gamma2, 0.0, 1.0)
        corr = np.abs(suu[:, 0, 1]) ** 2 / (suu[:, 0, 0].real * suu[:, 1, 1].real)
    noise = syy * (1.0 - gamma2)
    n_d = spec.n_effective
    freq = spec.frequency_Hz[1:]
    details = {'n_segments': spec.n_segments, 'nperseg': spec.nperseg,
               'noverlap': spec.noverlap}
    responses = []
    for i in range(2):
        var = noise * np.real(inv[:, i, i]) / (n_d - 2.0)
        responses.append(FrequencyResponseData(
            freq, h[:, i], gamma2, np.sqrt(np.maximum(var, 0.0)), n_d, 'two_input_H1',
            input_units[i], output_unit, dict(details)))
    return TwoInputResponse((responses[0], responses[1]), gamma2, cond, corr)
