"""
Local polynomial method (LPM): FRF of transient (non-periodic) records with a noise estimate.

For a chirp, steps or any record that does not repeat, the DFT ratio ``Y(k) / U(k)`` is exact
only when the response has died out by the end of the record, and Welch averaging has a
deterministic leakage error at sharp resonances. The LPM (Pintelon, Schoukens, Vandersteen
and Barbe, "Estimation of nonparametric noise and FRF models for multivariable systems",
Mech. Syst. Signal Process. 24, 2010; Pintelon & Schoukens, *System Identification*, 2nd ed.,
sec. 7.2.2) models the DFT lines of a small window around each line ``k`` as

``Y(k + r) = sum_i G_i(k + r) U_i(k + r) + T(k + r) + V(k + r)``,  ``r = -n .. n``,

with ``G_i`` and the transient term ``T`` (leakage, initial and final conditions) polynomials of
degree ``R`` in ``r``. A complex linear least-squares solve per line gives ``G_i(k)`` (the value
at ``r = 0``), the residual gives the noise variance of ``V``, and the covariance of ``G_i(k)``
follows as ``sigma^2 [(K^H K)^-1]_ii``. Windows that overlap give correlated estimates, so by
default only every ``2n + 1``-th line is evaluated (independent windows).

"Coherence" here is the LPM analogue of the Welch coherence: the fraction of the output power in
the window explained by the inputs, ``P_model / (P_model + sigma^2)``.
"""

from __future__ import annotations

from typing import List, Optional, Sequence

import numpy as np

from emfc_ros.core.blas_threads import with_single_blas_thread
from emfc_ros.core.ident.errors import IdentificationError
from emfc_ros.core.ident.frf import FrequencyResponseData

#: Degrees of freedom left for the noise estimate when the half width is chosen automatically.
DEFAULT_DOF = 6


def auto_half_width(n_inputs: int, degree: int, dof: int = DEFAULT_DOF) -> int:
    """
    Smallest half width ``n`` that leaves ``dof`` degrees of freedom for the noise estimate.

    Parameters
    ----------
    n_inputs : int
        Number of inputs.
    degree : int
        Polynomial degree ``R``.
    dof : int
        Wanted ``2 n + 1 - (R + 1) (n_inputs + 1)``.

    Returns
    -------
    int
        The half width in lines.
    """
    unknowns = (degree + 1) * (n_inputs + 1)
    return int(np.ceil((unknowns + dof - 1) / 2.0))


@with_single_blas_thread
def local_polynomial_frf(inputs: Sequence[np.ndarray], output: np.ndarray,
                         sample_rate_Hz: float, *, degree: int = 2,
                         half_width: Optional[int] = None, stride: Optional[int] = None,
                         frequency_min_Hz: float = 0.0,
                         frequency_max_Hz: Optional[float] = None,
                         input_units: Sequence[str] = (),
                         output_unit: str = '') -> List[FrequencyResponseData]:
    """
    Estimate the FRF of each input to the output with the local polynomial method.

    Parameters
    ----------
    inputs : sequence of ndarray
        One or more input records (same length as the output).
    output : ndarray
        The output record.
    sample_rate_Hz : float
        Sample rate [Hz].
    degree : int
        Polynomial degree ``R`` of the local models (>= 0).
    half_width : int, optional
        Window half width ``n`` in DFT lines; default :func:`auto_half_width`.
    stride : int, optional
        Evaluate every ``stride``-th line; default ``2 n + 1`` (independent estimates).
    frequency_min_Hz, frequency_max_Hz : float
        Band of the evaluated lines [Hz] (default DC excluded up to Nyquist).
    input_units : sequence of str
        Units of the inputs (for the results' units).
    output_unit : str
        Unit of the output.

    Returns
    -------
    list of FrequencyResponseData
        One per input, estimator ``'LPM'``, with std (complex standard deviation),
        coherence (explained power fraction), ``n_averages`` the noise degrees of freedom and
        ``details`` holding ``degree``, ``half_width_lines``, ``stride_lines``, ``dof``,
        ``resolution_Hz`` and ``noise_std`` (of the output DFT, per line).

    Raises
    ------
    IdentificationError
        If the records are inconsistent or too short for the window.
    """
    us = [np.asarray(u, dtype=float).ravel() for u in inputs]
    y = np.asarray(output, dtype=float).ravel()
    if not us or any(u.size != y.size for u in us):
        raise IdentificationError('LPM: need at least one input, each as long as the output')
    if not (np.all(np.isfinite(y)) and all(np.all(np.isfinite(u)) for u in us)):
        raise IdentificationError('LPM: records hold NaN or infinite samples')
    fs = float(sample_rate_Hz)
    if not fs > 0.0:
        raise IdentificationError(f'LPM: sample_rate_Hz must be > 0, got {sample_rate_Hz!r}')
    if degree < 0:
        raise IdentificationError(f'LPM: degree must be >= 0, got {degree}')
    n_in = len(us)
    n = auto_half_width(n_in, degree) if half_width is None else int(half_width)
    width = 2 * n + 1
    n_par = (degree + 1) * (n_in + 1)
    dof = width - n_par
    if dof < 1:
        raise IdentificationError(f'LPM: half width {n} leaves no degree of freedom for '
                                  f'{n_in} input(s) at degree {degree}')
    step = width if stride is None else int(stride)
    if step < 1:
        raise IdentificationError(f'LPM: stride must be >= 1, got {stride}')
    N = y.size
    scale = 1.0 / np.sqrt(N)
    Y = np.fft.rfft(y) * scale
    U = np.array([np.fft.rfft(u) * scale for u in us])
    n_lines = Y.size
    if n_lines < width + 1:
        raise IdentificationError(f'LPM: {N} samples give {n_lines} lines, fewer than the '
                                  f'window of {width} lines')
    resolution = fs / N
    f_max = fs / 2.0 if frequency_max_Hz is None else float(frequency_max_Hz)
    k_lo = max(1, int(np.ceil(float(frequency_min_Hz) / resolution)))
    k_hi = min(n_lines - 1, int(np.floor(f_max / resolution)))
    lines = np.arange(k_lo, k_hi + 1, step)
    if lines.size == 0:
        raise IdentificationError(f'LPM: no line in [{frequency_min_Hz}, {f_max}] Hz')
    # window start: centred where possible, shifted at the edges (DC and Nyquist)
    start = np.clip(lines - n, 1, n_lines - width)
    idx = start[:, None] + np.arange(width)[None, :]
    r = (idx - lines[:, None]).astype(float)
    r_scaled = r / max(n, 1)
    powers = np.stack([r_scaled ** s for s in range(degree + 1)], axis=-1)   # (K, W, R+1)
    cols = [U[i][idx][..., None] * powers for i in range(n_in)] + [powers.astype(complex)]
    K = np.concatenate(cols, axis=-1)                                       # (K, W, P)
    rhs = Y[idx]
    norms = np.sqrt(np.sum(np.abs(K) ** 2, axis=1))
    norms[norms == 0.0] = 1.0
    Ks = K / norms[:, None, :]
    KH = np.conj(np.swapaxes(Ks, 1, 2))
    gram = KH @ Ks
    try:
        gram_inv = np.linalg.inv(gram)
    except np.linalg.LinAlgError:
        gram_inv = np.linalg.pinv(gram)
    theta = (gram_inv @ (KH @ rhs[..., None]))[..., 0]
    resid = rhs - (Ks @ theta[..., None])[..., 0]
    sigma2 = np.sum(np.abs(resid) ** 2, axis=1) / dof
    theta = theta / norms
    cov_diag = np.real(np.diagonal(gram_inv, axis1=1, axis2=2)) / norms ** 2
    model = np.zeros(idx.shape, dtype=complex)
    for i in range(n_in):
        g_local = powers @ theta[:, i * (degree + 1):(i + 1) * (degree + 1), None]
        model += g_local[..., 0] * U[i][idx]
    p_model = np.mean(np.abs(model) ** 2, axis=1)
    with np.errstate(divide='ignore', invalid='ignore'):
        coherence = np.where(p_model + sigma2 > 0.0, p_model / (p_model + sigma2), 0.0)
    freq = lines * resolution
    units = list(input_units) + [''] * (n_in - len(input_units))
    out = []
    for i in range(n_in):
        j = i * (degree + 1)
        g = theta[:, j]
        std = np.sqrt(np.maximum(sigma2 * cov_diag[:, j], 0.0))
        details = {'degree': int(degree), 'half_width_lines': int(n), 'stride_lines': int(step),
                   'dof': int(dof), 'resolution_Hz': float(resolution),
                   'noise_std': np.sqrt(sigma2),
                   'input_amplitude': np.abs(U[i][lines])}
        out.append(FrequencyResponseData(freq, g, coherence.copy(), std, float(dof), 'LPM',
                                         units[i], output_unit, details))
    return out
