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

Sparse excitation (issue 28): a multisine that excites only some lines (odd lines, a line
every few DFT lines of the section) leaves windows in which the input carries nothing, where
the polynomial ``G_i`` is undetermined. Such an input is detected from its spectrum
(:func:`excited_lines`: at least :data:`SPARSE_POWER_FRACTION` of its power on lines that stand
:data:`SPARSE_CONTRAST` times above the median of their window) and then handled as the LPM for
periodic excitations does: its response is evaluated at its excited lines only, constant over
the window (degree 0: only the centre line carries it), and the window's other lines estimate
the transient and the noise.

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
#: A line is excited (sparse excitation) when its input amplitude exceeds the median of its
#: window by this factor (a broadband input's amplitudes vary within a window by a few).
SPARSE_CONTRAST = 10.0
#: An input is sparse when at least this fraction of its power lies on such lines.
SPARSE_POWER_FRACTION = 0.9
#: Excited lines carry at least this fraction of the largest line's amplitude (quantisation
#: leaves lines of 1e-4 between those of a multisine, themselves far above their neighbours).
SPARSE_FLOOR = 1.0e-2


def excited_lines(spectrum: np.ndarray, half_width: int) -> Optional[np.ndarray]:
    """
    The excited lines of a sparse input, None for a broadband one.

    Parameters
    ----------
    spectrum : ndarray
        The input's DFT (one-sided, DC first).
    half_width : int
        Half width of the window the median is taken over [lines].

    Returns
    -------
    ndarray of int or None
        Indices of the lines standing :data:`SPARSE_CONTRAST` above their window's median
        (and above :data:`SPARSE_FLOOR` of the largest) when they carry
        :data:`SPARSE_POWER_FRACTION` of the power (DC excluded), else None.
    """
    from scipy.ndimage import median_filter

    a = np.abs(np.asarray(spectrum))
    a[0] = 0.0
    power = float(np.sum(a ** 2))
    if not power > 0.0:
        return None
    local = median_filter(a, size=2 * max(int(half_width), 1) + 1, mode='nearest')
    hits = np.flatnonzero((a > SPARSE_CONTRAST * local) & (a > SPARSE_FLOOR * np.max(a)))
    if float(np.sum(a[hits] ** 2)) < SPARSE_POWER_FRACTION * power:
        return None
    return hits


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


def detect_excitation(inputs: Sequence[np.ndarray], *, degree: int = 2,
                      half_width: Optional[int] = None) -> List[Optional[np.ndarray]]:
    """
    Each input's excited lines (sparse) or None (broadband), for ``excitation``.

    Parameters
    ----------
    inputs : sequence of ndarray
        The input records.
    degree, half_width
        As for :func:`local_polynomial_frf`.

    Returns
    -------
    list of (ndarray or None)
        :func:`excited_lines` of each input's DFT.
    """
    n = auto_half_width(len(inputs), degree) if half_width is None else int(half_width)
    return [excited_lines(np.fft.rfft(np.asarray(u, dtype=float).ravel()), n)
            for u in inputs]


@with_single_blas_thread
def local_polynomial_frf(inputs: Sequence[np.ndarray], output: np.ndarray,
                         sample_rate_Hz: float, *, degree: int = 2,
                         half_width: Optional[int] = None, stride: Optional[int] = None,
                         frequency_min_Hz: float = 0.0,
                         frequency_max_Hz: Optional[float] = None,
                         input_units: Sequence[str] = (),
                         output_unit: str = '',
                         excitation: Optional[Sequence[Optional[np.ndarray]]] = None
                         ) -> List[FrequencyResponseData]:
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
    excitation : sequence of (ndarray or None), optional
        Per input, its excited lines (sparse) or None (broadband), as
        :func:`detect_excitation` gives them for the same records; default: detected here (a
        caller estimating at many bands of one record detects once).

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
    N = y.size
    scale = 1.0 / np.sqrt(N)
    Y = np.fft.rfft(y) * scale
    U = np.array([np.fft.rfft(u) * scale for u in us])
    n0 = auto_half_width(n_in, degree) if half_width is None else int(half_width)
    if excitation is None:
        sparse = [excited_lines(U[i], n0) for i in range(n_in)]
    else:
        if len(excitation) != n_in:
            raise IdentificationError(f'LPM: excitation names {len(excitation)} inputs, '
                                      f'the records {n_in}')
        sparse = [None if e is None else np.asarray(e, dtype=int) for e in excitation]
    # A sparse input whose excited lines are close enough that a window holds degree + 1 of
    # them is served by the ordinary LPM (its G polynomial rests on them).
    spacing = [int(np.median(np.diff(e))) if e is not None and e.size > 1 else 0 for e in sparse]
    sparse = [e if e is not None and (degree + 1) * sp > 2 * n0 + 1 else None
              for e, sp in zip(sparse, spacing)]
    degrees = [0 if e is not None else int(degree) for e in sparse]
    n_par = sum(d + 1 for d in degrees) + degree + 1
    n = n0
    if half_width is None and any(e is not None for e in sparse):
        # one excited line per window: no wider than the closest spacing allows
        n = min(int(np.ceil((n_par + DEFAULT_DOF - 1) / 2.0)),
                min(sp for e, sp in zip(sparse, spacing) if e is not None) - 1)
    width = 2 * n + 1
    dof = width - n_par
    if dof < 1:
        raise IdentificationError(f'LPM: half width {n} leaves no degree of freedom for '
                                  f'{n_in} input(s) at degree {degree}')
    step = width if stride is None else int(stride)
    if step < 1:
        raise IdentificationError(f'LPM: stride must be >= 1, got {stride}')
    n_lines = Y.size
    if n_lines < width + 1:
        raise IdentificationError(f'LPM: {N} samples give {n_lines} lines, fewer than the '
                                  f'window of {width} lines')
    resolution = fs / N
    f_max = fs / 2.0 if frequency_max_Hz is None else float(frequency_max_Hz)
    k_lo = max(1, int(np.ceil(float(frequency_min_Hz) / resolution)))
    k_hi = min(n_lines - 1, int(np.floor(f_max / resolution)))
    dense = np.arange(k_lo, k_hi + 1, step)
    units = list(input_units) + [''] * (n_in - len(input_units))
    solved = {}
    out = []
    for i in range(n_in):
        if sparse[i] is None:
            lines = dense
        else:
            lines = sparse[i][(sparse[i] >= k_lo) & (sparse[i] <= k_hi)]
            if step > 1 and stride is not None:
                lines = lines[::step]
        key = 'dense' if sparse[i] is None else f'sparse{i}'
        if key not in solved:
            if lines.size == 0:
                raise IdentificationError(f'LPM: no line in [{frequency_min_Hz}, {f_max}] Hz')
            solved[key] = _solve(Y, U, lines, n, degrees, degree, dof)
        g_all, std_all, coherence = solved[key]
        details = {'degree': int(degrees[i]), 'half_width_lines': int(n),
                   'stride_lines': int(step), 'dof': int(dof),
                   'resolution_Hz': float(resolution),
                   'noise_std': std_all[-1],
                   'input_amplitude': np.abs(U[i][lines]),
                   'sparse_excitation': sparse[i] is not None}
        out.append(FrequencyResponseData(lines * resolution, g_all[i], coherence.copy(),
                                         std_all[i], float(dof), 'LPM', units[i],
                                         output_unit, details))
    return out


def _solve(Y: np.ndarray, U: np.ndarray, lines: np.ndarray, n: int, degrees: Sequence[int],
           degree: int, dof: int) -> tuple:
    # The local least-squares problems at ``lines``: per input a polynomial of its degree
    # times its spectrum, plus the transient polynomial of ``degree``.
    n_in = U.shape[0]
    width = 2 * n + 1
    n_lines = Y.size
    start = np.clip(lines - n, 1, n_lines - width)
    idx = start[:, None] + np.arange(width)[None, :]
    r = (idx - lines[:, None]).astype(float)
    r_scaled = r / max(n, 1)
    powers = [np.stack([r_scaled ** s for s in range(d + 1)], axis=-1) for d in degrees]
    transient = np.stack([r_scaled ** s for s in range(degree + 1)], axis=-1)
    cols = [U[i][idx][..., None] * powers[i] for i in range(n_in)] + \
        [transient.astype(complex)]
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
    offsets = np.cumsum([0] + [d + 1 for d in degrees])
    for i in range(n_in):
        g_local = powers[i] @ theta[:, offsets[i]:offsets[i + 1], None]
        model += g_local[..., 0] * U[i][idx]
    p_model = np.mean(np.abs(model) ** 2, axis=1)
    with np.errstate(divide='ignore', invalid='ignore'):
        coherence = np.where(p_model + sigma2 > 0.0, p_model / (p_model + sigma2), 0.0)
    gs = [theta[:, offsets[i]] for i in range(n_in)]
    stds = [np.sqrt(np.maximum(sigma2 * cov_diag[:, offsets[i]], 0.0)) for i in range(n_in)]
    return gs, stds + [np.sqrt(sigma2)], coherence
