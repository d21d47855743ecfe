"""
Frequency-response data and the Welch-based H1, H2 and Hv estimators.

All estimators share one set of spectra: the record is cut into segments exactly as
:func:`scipy.signal.welch` / :func:`scipy.signal.csd` cut it (same window, overlap, detrend and
density scaling; see :func:`cross_spectra`), each channel is Fourier transformed once and every
auto- and cross-spectrum is averaged from those transforms. With the convention of
:func:`scipy.signal.csd`, ``S_xy = E[conj(X) Y]``:

* ``H1 = S_xy / S_xx``: unbiased with output noise, biased low with input noise;
* ``H2 = S_yy / S_yx = S_yy / conj(S_xy)``: unbiased with input noise, biased high with output
  noise;
* ``Hv`` (total least squares, equal noise weighting of input and output): the eigenvector of
  the smallest eigenvalue of ``[[S_xx, S_xy], [S_yx, S_yy]]``, i.e.
  ``Hv = (S_yy - S_xx + sqrt((S_xx - S_yy)^2 + 4 |S_xy|^2)) / (2 conj(S_xy))``, which lies
  between H1 and H2 (``|H1| <= |Hv| <= |H2|``).

Ordinary coherence ``gamma^2 = |S_xy|^2 / (S_xx S_yy)``. Random error (Bendat & Piersol,
*Random Data*, 4th ed., eq. 9.90 and 9.91) with ``n_d`` averages: normalised random error of
the magnitude ``eps = sqrt(1 - gamma^2) / (|gamma| sqrt(2 n_d))`` and standard deviation of the
phase ``eps`` [rad]. The ``std`` field holds the complex standard deviation
``sqrt(E|H_hat - H|^2) = sqrt(2) eps |H|``. For overlapped segments ``n_d`` is Welch's
equivalent number of independent averages (:func:`effective_averages`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Sequence, Tuple, Union

import numpy as np
from scipy import special

from emfc_ros.core.ident.errors import IdentificationError
from emfc_ros.core.ident.welch import welch_sums
from emfc_ros.core.records import same_clock_records

ESTIMATORS = ('H1', 'H2', 'Hv')
WindowSpec = Union[str, Tuple, np.ndarray]


@dataclass(frozen=True)
class FrequencyResponseData:
    """
    A measured (estimated) frequency response with its uncertainty.

    Modelled on python-control's ``FrequencyResponseData``.

    Attributes
    ----------
    frequency_Hz : ndarray
        Frequencies [Hz], ascending.
    response : ndarray
        Complex response in ``output_unit / input_unit``.
    coherence : ndarray
        Ordinary (or, for two inputs, multiple) coherence in [0, 1]; NaN where the method
        gives none.
    std : ndarray
        Complex standard deviation ``sqrt(E|H_hat - H|^2)`` of the response (same unit);
        NaN where unknown. Real and imaginary errors are taken as circular, so the magnitude
        standard deviation is ``std / sqrt(2)`` and the phase one ``std / (sqrt(2) |H|)``.
    n_averages : float
        Number of (equivalent independent) averages behind each estimate.
    estimator : str
        ``'H1'``, ``'H2'``, ``'Hv'``, ``'periodic'``, ``'etfe'``, ``'sine_fit'``, ``'dft'``,
        ``'two_input_H1'``.
    input_unit, output_unit : str
        Units of input and output (e.g. ``'N'``, ``'m'``).
    """

    frequency_Hz: np.ndarray
    response: np.ndarray
    coherence: np.ndarray
    std: np.ndarray
    n_averages: float
    estimator: str
    input_unit: str = ''
    output_unit: str = ''
    details: dict = field(default_factory=dict, compare=False)

    @property
    def unit(self) -> str:
        """Unit of the response, ``output_unit/input_unit``."""
        return f'{self.output_unit}/{self.input_unit}'

    @property
    def magnitude(self) -> np.ndarray:
        """Magnitude ``|H|`` [unit]."""
        return np.abs(self.response)

    @property
    def magnitude_dB(self) -> np.ndarray:
        """Magnitude [dB re 1 unit]."""
        return 20.0 * np.log10(np.abs(self.response))

    @property
    def phase_rad(self) -> np.ndarray:
        """Unwrapped phase [rad]."""
        return np.unwrap(np.angle(self.response))

    @property
    def phase_deg(self) -> np.ndarray:
        """Unwrapped phase [deg]."""
        return np.degrees(self.phase_rad)

    @property
    def magnitude_std(self) -> np.ndarray:
        """Standard deviation of the magnitude [unit] (``std / sqrt(2)``)."""
        return self.std / np.sqrt(2.0)

    @property
    def phase_std_rad(self) -> np.ndarray:
        """Standard deviation of the phase [rad] (``std / (sqrt(2) |H|)``)."""
        return self.std / (np.sqrt(2.0) * np.abs(self.response))

    def confidence_bounds(self, level: float = 0.95) -> Tuple[np.ndarray, np.ndarray,
                                                              np.ndarray, np.ndarray]:
        """
        Gaussian confidence bounds of magnitude and phase.

        Parameters
        ----------
        level : float
            Two-sided confidence level in (0, 1).

        Returns
        -------
        magnitude_low, magnitude_high, phase_low_rad, phase_high_rad : ndarray
            ``|H| -/+ z sigma_|H|`` (clipped at 0) and ``phase -/+ z sigma_phase``.
        """
        if not 0.0 < level < 1.0:
            raise IdentificationError(f'level must be in (0, 1), got {level!r}')
        z = float(special.ndtri(0.5 + 0.5 * level))
        mag, phase = self.magnitude, self.phase_rad
        return (np.maximum(mag - z * self.magnitude_std, 0.0), mag + z * self.magnitude_std,
                phase - z * self.phase_std_rad, phase + z * self.phase_std_rad)

    def select(self, mask: np.ndarray) -> 'FrequencyResponseData':
        """
        Keep the frequencies where ``mask`` is true (or the given indices).

        Parameters
        ----------
        mask : ndarray of bool or int
            Selection along the frequency axis.

        Returns
        -------
        FrequencyResponseData
            The subset (same estimator, units and averages).
        """
        return FrequencyResponseData(
            self.frequency_Hz[mask], self.response[mask], self.coherence[mask],
            self.std[mask], self.n_averages, self.estimator, self.input_unit,
            self.output_unit, dict(self.details))

    def band(self, f_min_Hz: float, f_max_Hz: float) -> 'FrequencyResponseData':
        """
        Keep the frequencies in [f_min_Hz, f_max_Hz].

        Parameters
        ----------
        f_min_Hz, f_max_Hz : float
            Band limits [Hz].

        Returns
        -------
        FrequencyResponseData
            The subset.
        """
        return self.select((self.frequency_Hz >= f_min_Hz) & (self.frequency_Hz <= f_max_Hz))


@dataclass(frozen=True)
class Spectra:
    """
    Averaged one-sided auto- and cross-spectral densities of several channels.

    Attributes
    ----------
    frequency_Hz : ndarray, shape (F,)
        Frequencies [Hz] from 0 to Nyquist.
    matrix : ndarray, shape (F, C, C)
        ``matrix[f, i, j] = S_ij = E[conj(X_i) X_j]`` scaled as :func:`scipy.signal.csd`
        (density, unit^2/Hz); ``matrix[:, i, j]`` equals ``csd(x_i, x_j)``.
    n_segments : int
        Number of segments averaged.
    n_effective : float
        Welch's equivalent number of independent averages (``<= n_segments``).
    nperseg, noverlap : int
        Segment length and overlap used [samples].
    """

    frequency_Hz: np.ndarray
    matrix: np.ndarray
    n_segments: int
    n_effective: float
    nperseg: int
    noverlap: int


def default_nperseg(n_samples: int) -> int:
    """
    Default segment length: the largest power of two not above ``n_samples / 4``.

    With 50 % overlap that gives at least 7 segments (MATLAB's ``tfestimate`` uses 8).

    Parameters
    ----------
    n_samples : int
        Record length.

    Returns
    -------
    int
        Segment length (at least 8 when the record allows, else ``n_samples``).
    """
    if n_samples < 32:
        return int(n_samples)
    return int(2 ** int(np.floor(np.log2(n_samples / 4.0))))


def effective_averages(window: np.ndarray, step: int, n_segments: int) -> float:
    """
    Welch's equivalent number of independent averages for overlapped segments.

    ``n_eff = K / (1 + 2 sum_{j=1}^{K-1} (1 - j / K) rho_j^2)`` with the window overlap
    correlation ``rho_j = sum_n w[n] w[n + j step] / sum_n w[n]^2`` (Welch 1967, eq. 10).

    Parameters
    ----------
    window : ndarray
        The window samples.
    step : int
        Segment step (``nperseg - noverlap``).
    n_segments : int
        Number of segments K.

    Returns
    -------
    float
        ``n_eff`` in [1, K].
    """
    w = np.asarray(window, dtype=float)
    power = float(np.sum(w * w))
    total = 0.0
    j = 1
    while j < n_segments and j * step < w.size:
        rho = float(np.sum(w[j * step:] * w[:w.size - j * step])) / power
        total += (1.0 - j / n_segments) * rho * rho
        j += 1
    return n_segments / (1.0 + 2.0 * total)


def as_record(name: str, values: np.ndarray) -> np.ndarray:
    """
    Check a one-dimensional finite float record.

    Parameters
    ----------
    name : str
        Argument name for the message.
    values : array_like
        The samples.

    Returns
    -------
    ndarray
        float64 copy-free view when possible.

    Raises
    ------
    IdentificationError
        If not one-dimensional, empty or not finite.
    """
    return same_clock_records((name,), (values,), IdentificationError)[0]


def as_records(names: Sequence[str], values: Sequence[np.ndarray]) -> Tuple[np.ndarray, ...]:
    """
    Check records on one sample clock: each as :func:`as_record`, all of equal length.

    Parameters
    ----------
    names : sequence of str
        Argument names for the messages.
    values : sequence of array_like
        The records.

    Returns
    -------
    tuple of ndarray
        The records as float64.

    Raises
    ------
    IdentificationError
        If one is not a finite non-empty 1-D record or the lengths differ.
    """
    return same_clock_records(names, values, IdentificationError)


def check_rate(sample_rate_Hz: float) -> float:
    """
    Check a sample rate.

    Parameters
    ----------
    sample_rate_Hz : float
        Sample rate [Hz].

    Returns
    -------
    float
        The rate.

    Raises
    ------
    IdentificationError
        If not finite and positive.
    """
    fs = float(sample_rate_Hz)
    if not np.isfinite(fs) or fs <= 0.0:
        raise IdentificationError(f'sample_rate_Hz must be finite and > 0, got '
                                  f'{sample_rate_Hz!r}')
    return fs


def _channel_records(channels: Union[np.ndarray, Sequence[np.ndarray]]) -> list:
    """Rows of a (C, N) array, or a sequence of equally long 1-D records, as float64."""
    if isinstance(channels, np.ndarray) and channels.ndim != 2:
        raise IdentificationError(f'channels must have shape (C, N), got {channels.shape}')
    records = [np.asarray(c, dtype=float) for c in channels]
    shapes = {r.shape for r in records}
    if not records or len(shapes) != 1 or records[0].ndim != 1 or records[0].size == 0:
        raise IdentificationError(f'channels must have shape (C, N) (C equally long '
                                  f'non-empty records), got shapes {sorted(shapes)}')
    return records


def window_samples(window: WindowSpec, nperseg: int) -> np.ndarray:
    """
    The window of a Welch segment, as ``scipy.signal.get_window(window, nperseg)`` gives it.

    The default ``'hann'`` (periodic, for spectral analysis) is computed here; any other
    window comes from scipy.signal, imported then (it takes about a second to import).

    Parameters
    ----------
    window : str or tuple
        A window name (with parameters as a tuple) scipy.signal.get_window accepts.
    nperseg : int
        Segment length [samples].

    Returns
    -------
    ndarray
        The window, ``nperseg`` values.
    """
    if isinstance(window, str) and window in ('hann', 'han', 'hanning'):
        if nperseg == 1:
            return np.ones(1)
        return 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(nperseg) / nperseg)
    from scipy import signal as sps
    return sps.get_window(window, nperseg)


def cross_spectra(channels: Union[np.ndarray, Sequence[np.ndarray]], sample_rate_Hz: float, *,
                  nperseg: Optional[int] = None, noverlap: Optional[int] = None,
                  window: WindowSpec = 'hann', detrend: Union[str, bool] = 'constant',
                  ) -> Spectra:
    """
    All auto- and cross-spectral densities of several channels from one FFT per segment.

    Segmenting, windowing, detrending and scaling follow :func:`scipy.signal.csd` with
    ``average='mean'`` and ``scaling='density'`` (one-sided), so ``matrix[:, i, j]`` equals
    ``scipy.signal.csd(x_i, x_j, ...)`` to rounding; but each channel is transformed once
    instead of once per pair. The segments are processed a cache-sized chunk at a time
    (:func:`~emfc_ros.core.ident.welch.welch_sums`), so no copy of the whole segmented record
    is made.

    Parameters
    ----------
    channels : ndarray, shape (C, N), or sequence of C ndarrays of shape (N,)
        Equally long records on one sample clock (a sequence avoids stacking them).
    sample_rate_Hz : float
        Sample rate [Hz].
    nperseg : int, optional
        Segment length (default :func:`default_nperseg`).
    noverlap : int, optional
        Overlap in samples (default ``nperseg // 2``).
    window : str, tuple or ndarray
        Window for :func:`scipy.signal.get_window`, or its samples.
    detrend : {'constant', 'linear', False}
        Per-segment detrending as in :func:`scipy.signal.welch`.

    Returns
    -------
    Spectra
        Frequencies, spectral matrix and number of averages.

    Raises
    ------
    IdentificationError
        If the settings do not fit the record.
    """
    fs = check_rate(sample_rate_Hz)
    records = _channel_records(channels)
    n = records[0].size
    if nperseg is None:
        nperseg = default_nperseg(n)
    nperseg = int(nperseg)
    if nperseg < 2 or nperseg > n:
        raise IdentificationError(f'nperseg must be in [2, {n}] (the record length), got '
                                  f'{nperseg}')
    if noverlap is None:
        noverlap = nperseg // 2
    noverlap = int(noverlap)
    if not 0 <= noverlap < nperseg:
        raise IdentificationError(f'noverlap must be in [0, {nperseg - 1}], got {noverlap}')
    if detrend not in ('constant', 'linear', False):
        raise IdentificationError(f"detrend must be 'constant', 'linear' or False, got "
                                  f'{detrend!r}')
    if isinstance(window, np.ndarray):
        win = np.asarray(window, dtype=float)
        if win.shape != (nperseg,):
            raise IdentificationError(f'window array must have nperseg = {nperseg} samples, '
                                      f'got shape {win.shape}')
    else:
        win = window_samples(window, nperseg)
    step = nperseg - noverlap
    n_seg = (n - noverlap) // step
    matrix = welch_sums(records, nperseg, step, n_seg, win, detrend)
    matrix *= 1.0 / (fs * float(np.sum(win * win)) * n_seg)
    if nperseg % 2:
        matrix[1:] *= 2.0
    else:
        matrix[1:-1] *= 2.0
    freq = np.fft.rfftfreq(nperseg, 1.0 / fs)
    return Spectra(freq, matrix, int(n_seg), effective_averages(win, step, n_seg), nperseg,
                   noverlap)


def random_error(coherence: np.ndarray, n_averages: float) -> np.ndarray:
    """
    Bendat & Piersol normalised random error of an FRF magnitude.

    ``eps = sqrt(1 - gamma^2) / (|gamma| sqrt(2 n_d))``; also the phase standard deviation
    in radians.

    Parameters
    ----------
    coherence : ndarray
        Ordinary coherence ``gamma^2``.
    n_averages : float
        Number of independent averages ``n_d``.

    Returns
    -------
    ndarray
        ``eps`` (inf where the coherence is 0).
    """
    g2 = np.clip(np.asarray(coherence, dtype=float), 0.0, 1.0)
    with np.errstate(divide='ignore', invalid='ignore'):
        return np.sqrt(1.0 - g2) / np.sqrt(2.0 * n_averages * g2)


def estimate_frf(input: np.ndarray, output: np.ndarray, sample_rate_Hz: float, *,
                 estimator: str = 'H1', nperseg: Optional[int] = None,
                 noverlap: Optional[int] = None, window: WindowSpec = 'hann',
                 detrend: Union[str, bool] = 'constant', input_unit: str = '',
                 output_unit: str = '') -> FrequencyResponseData:
    """
    Estimate a frequency response from one input and one output record (Welch averaging).

    Parameters
    ----------
    input, output : ndarray
        Records on the same sample clock, equal length.
    sample_rate_Hz : float
        Sample rate [Hz].
    estimator : {'H1', 'H2', 'Hv'}
        See the module docstring.
    nperseg, noverlap, window, detrend
        Welch settings as in :func:`cross_spectra`.
    input_unit, output_unit : str
        Units carried into the result.

    Returns
    -------
    FrequencyResponseData
        Response at the Welch frequencies above 0 Hz, with coherence, Bendat & Piersol
        standard deviation and the equivalent number of averages. ``details`` holds
        ``n_segments``, ``nperseg``, ``noverlap``, ``window``.

    Raises
    ------
    IdentificationError
        If the records differ in length, are not finite, or the settings are invalid.
    """
    if estimator not in ESTIMATORS:
        raise IdentificationError(f'estimator must be one of {ESTIMATORS}, got {estimator!r}')
    names = ('input', 'output')
    # The finiteness check rides on the spectra: a NaN or infinite sample in any segment makes
    # the sums non-finite; only the samples after the last segment are checked directly.
    u, y = same_clock_records(names, (input, output), IdentificationError, check_finite=False)
    with np.errstate(invalid='ignore', over='ignore'):     # checked just below
        spec = cross_spectra((u, y), sample_rate_Hz, nperseg=nperseg, noverlap=noverlap,
                             window=window, detrend=detrend)
    used = (spec.n_segments - 1) * (spec.nperseg - spec.noverlap) + spec.nperseg
    if not (np.isfinite(spec.matrix).all() and np.isfinite(u[used:]).all()
            and np.isfinite(y[used:]).all()):
        as_records(names, (u, y))     # raises, naming the record
        raise IdentificationError('the spectra are not finite: the records hold values too '
                                  'large to square (above about 1e150)')
    m = spec.matrix[1:]
    sxx, syy, sxy = m[:, 0, 0].real, m[:, 1, 1].real, m[:, 0, 1]
    with np.errstate(divide='ignore', invalid='ignore'):
        coherence = np.abs(sxy) ** 2 / (sxx * syy)
        if estimator == 'H1':
            h = sxy / sxx
        elif estimator == 'H2':
            h = syy / np.conj(sxy)
        else:
            h = (syy - sxx + np.sqrt((sxx - syy) ** 2 + 4.0 * np.abs(sxy) ** 2)) / (
                2.0 * np.conj(sxy))
    coherence = np.clip(coherence, 0.0, 1.0)
    std = np.sqrt(2.0) * random_error(coherence, spec.n_effective) * np.abs(h)
    details = {'n_segments': spec.n_segments, 'nperseg': spec.nperseg,
               'noverlap': spec.noverlap, 'window': _window_name(window)}
    return FrequencyResponseData(spec.frequency_Hz[1:], h, coherence, std, spec.n_effective,
                                 estimator, input_unit, output_unit, details)


def _window_name(window: WindowSpec) -> str:
    """Printable name of a window specification."""
    if isinstance(window, np.ndarray):
        return 'custom'
    return str(window)
