"""
Periodic excitation: period averaging with a nonparametric noise estimate, and the ETFE.

With a periodic excitation of ``period_samples`` samples (an integer) and ``P`` steady-state
periods, the DFT of each period ``U_p(k)``, ``Y_p(k)`` at line ``k`` (frequency
``k fs / period_samples``) is computed with a rectangular window: no leakage. The response is
the ratio of the period means ``H = Y_bar / U_bar``. The period-to-period scatter gives the
sample (co)variances ``s_U^2``, ``s_Y^2``, ``s_YU`` (divisor ``P - 1``); the means have
``s^2 / P``; first-order propagation of ``H = Y / U`` gives the complex standard deviation

``std(H)^2 = |H|^2 (s_Y^2 / |Y|^2 + s_U^2 / |U|^2 - 2 Re(s_YU / (Y conj(U)))) / P``

(Pintelon & Schoukens, *System Identification: A Frequency Domain Approach*, 2nd ed., sec.
2.5). No noise model is assumed: the noise may be coloured and may sit on input and output.
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from emfc_ros.core.ident.errors import IdentificationError
from emfc_ros.core.ident.frf import as_record, as_records, check_rate, FrequencyResponseData

#: Lines whose mean input amplitude is below this fraction of the largest count as not excited.
EXCITED_FRACTION = 1.0e-3


def period_spectra(record: np.ndarray, period_samples: int,
                   transient_periods: int = 1) -> np.ndarray:
    """
    DFT of each steady-state period.

    Parameters
    ----------
    record : ndarray
        Samples; a trailing incomplete period is ignored.
    period_samples : int
        Samples per period (integer).
    transient_periods : int
        Leading periods to discard.

    Returns
    -------
    ndarray, shape (P, period_samples // 2 + 1)
        ``rfft`` of each kept period, scaled by ``2 / period_samples`` (peak amplitude of a
        sine on a line, phase of a cosine).

    Raises
    ------
    IdentificationError
        If fewer than two periods remain.
    """
    x = as_record('record', record)
    if isinstance(period_samples, bool) or int(period_samples) != period_samples or \
            period_samples < 2:
        raise IdentificationError(f'period_samples must be an integer >= 2, got '
                                  f'{period_samples!r}')
    n_per = int(period_samples)
    if isinstance(transient_periods, bool) or int(transient_periods) != transient_periods or \
            transient_periods < 0:
        raise IdentificationError(f'transient_periods must be an integer >= 0, got '
                                  f'{transient_periods!r}')
    total = x.size // n_per
    kept = total - int(transient_periods)
    if kept < 2:
        raise IdentificationError(
            f'need at least 2 periods after discarding {transient_periods} transient ones; '
            f'the record holds {total} whole periods of {n_per} samples')
    periods = x[int(transient_periods) * n_per:total * n_per].reshape(kept, n_per)
    return np.fft.rfft(periods, axis=1) * (2.0 / n_per)


def average_periods(input: np.ndarray, output: np.ndarray, sample_rate_Hz: float,
                    period_samples: int, *, transient_periods: int = 1,
                    lines: Optional[Sequence[int]] = None, input_unit: str = '',
                    output_unit: str = '') -> FrequencyResponseData:
    """
    FRF of a periodic experiment by averaging over periods, with its noise-based std.

    Parameters
    ----------
    input, output : ndarray
        Records on the same sample clock, equal length, starting at a period boundary.
    sample_rate_Hz : float
        Sample rate [Hz].
    period_samples : int
        Samples per period of the excitation.
    transient_periods : int
        Leading periods discarded (transient of the system).
    lines : sequence of int, optional
        Excited harmonic numbers (e.g. ``Multisine.lines``); by default every line above DC
        whose mean input amplitude exceeds ``EXCITED_FRACTION`` of the largest.
    input_unit, output_unit : str
        Units carried into the result.

    Returns
    -------
    FrequencyResponseData
        Estimator ``'periodic'``; ``n_averages`` = number of periods used; ``coherence`` from
        the period spectra; ``details`` holds ``lines``, ``input_amplitude``,
        ``output_amplitude`` (complex means), ``input_std``, ``output_std`` (std of the
        means) and ``n_periods``.

    Raises
    ------
    IdentificationError
        If the records differ in length, hold fewer than two periods after the transient,
        or a requested line is out of range or not excited.
    """
    fs = check_rate(sample_rate_Hz)
    u, y = as_records(('input', 'output'), (input, output))
    U = period_spectra(u, period_samples, transient_periods)
    Y = period_spectra(y, period_samples, transient_periods)
    n_p = U.shape[0]
    u_mean, y_mean = U.mean(axis=0), Y.mean(axis=0)
    if lines is None:
        amp = np.abs(u_mean)
        amp[0] = 0.0
        if amp.max() == 0.0:
            raise IdentificationError('the input holds no periodic excitation above DC')
        sel = np.flatnonzero(amp >= EXCITED_FRACTION * amp.max())
    else:
        sel = np.asarray(lines, dtype=np.int64)
        top = U.shape[1] - 1
        if sel.ndim != 1 or sel.size == 0 or sel.min() < 1 or sel.max() > top:
            raise IdentificationError(f'lines must be harmonic numbers in [1, {top}], got '
                                      f'{lines!r}')
        if np.any(u_mean[sel] == 0.0):
            raise IdentificationError('some requested lines carry no input (zero DFT)')
    Us, Ys = U[:, sel], Y[:, sel]
    um, ym = u_mean[sel], y_mean[sel]
    du, dy = Us - um, Ys - ym
    var_u = np.sum(np.abs(du) ** 2, axis=0) / (n_p - 1) / n_p
    var_y = np.sum(np.abs(dy) ** 2, axis=0) / (n_p - 1) / n_p
    cov_yu = np.sum(dy * np.conj(du), axis=0) / (n_p - 1) / n_p
    h = ym / um
    rel = (var_y / np.abs(ym) ** 2 + var_u / np.abs(um) ** 2
           - 2.0 * np.real(cov_yu / (ym * np.conj(um))))
    std = np.abs(h) * np.sqrt(np.maximum(rel, 0.0))
    sxy = np.sum(np.conj(Us) * Ys, axis=0)
    coherence = np.abs(sxy) ** 2 / (np.sum(np.abs(Us) ** 2, axis=0)
                                    * np.sum(np.abs(Ys) ** 2, axis=0))
    freq = sel * (fs / int(period_samples))
    details = {'lines': sel, 'input_amplitude': um, 'output_amplitude': ym,
               'input_std': np.sqrt(var_u), 'output_std': np.sqrt(var_y), 'n_periods': n_p}
    return FrequencyResponseData(freq, h, np.clip(coherence, 0.0, 1.0), std, float(n_p),
                                 'periodic', input_unit, output_unit, details)


def etfe(input: np.ndarray, output: np.ndarray, sample_rate_Hz: float, *,
         min_relative_input: float = EXCITED_FRACTION, input_unit: str = '',
         output_unit: str = '') -> FrequencyResponseData:
    """
    Empirical transfer-function estimate ``Y(k) / U(k)`` of the whole record (Ljung).

    Exact on the excited lines for a periodic input over an integer number of periods in
    steady state, and for a transient record (input and response both back to zero at the
    end). No smoothing and no uncertainty (``std`` and ``coherence`` are NaN).

    Parameters
    ----------
    input, output : ndarray
        Records on the same sample clock, equal length.
    sample_rate_Hz : float
        Sample rate [Hz].
    min_relative_input : float
        Lines whose input DFT magnitude is below this fraction of the largest are dropped.
    input_unit, output_unit : str
        Units carried into the result.

    Returns
    -------
    FrequencyResponseData
        Estimator ``'etfe'`` at the kept DFT lines above DC.

    Raises
    ------
    IdentificationError
        If the records differ in length or the input is zero.
    """
    fs = check_rate(sample_rate_Hz)
    u, y = as_records(('input', 'output'), (input, output))
    U = np.fft.rfft(u)[1:]
    Y = np.fft.rfft(y)[1:]
    amp = np.abs(U)
    if amp.size == 0 or amp.max() == 0.0:
        raise IdentificationError('the input has no spectral content above DC')
    keep = amp >= min_relative_input * amp.max()
    freq = np.fft.rfftfreq(u.size, 1.0 / fs)[1:][keep]
    nan = np.full(freq.shape, np.nan)
    return FrequencyResponseData(freq, Y[keep] / U[keep], nan, nan.copy(), 1.0, 'etfe',
                                 input_unit, output_unit, {})
