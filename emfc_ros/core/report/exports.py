"""
Files a MATLAB or Python user loads: full-resolution FRFs and the fitted models (no ROS).

Per FRF ``<section>.<input>`` of :class:`~emfc_ros.core.ident.pipeline.IdentificationResult`:

* ``frf_<name>.csv``: one row per frequency line, one header row, the unit in every column
  name (:data:`FRF_COLUMNS`);
* ``frf_<name>.npz``: the same columns as arrays under the same keys, plus text keys
  (:data:`FRF_TEXT_KEYS`);
* ``frf_<name>.mat``: MATLAB variables named as ``idfrd`` has its properties
  (``Frequency``, ``ResponseData``, ``CovarianceData``, ``Ts``, ``FrequencyUnit``,
  ``InputName``, ``InputUnit``, ``OutputName``, ``OutputUnit``) plus ``Coherence``,
  ``ResponseStd``, the models' responses and a ``Units`` struct, so that
  ``idfrd(ResponseData, Frequency, Ts, 'FrequencyUnit', FrequencyUnit)`` rebuilds it;
* per two-input section also ``frf_<section>.mat``: both FRFs of the joint solve as one
  ``1 x 2`` ``idfrd`` (inputs coil and pan force).

The fitted models (every transfer-function fit chosen by order selection and the grey-box
model's linearisation) go to ``models.mat`` and ``models.yaml`` as transfer-function
coefficients and state-space matrices, with poles and zeros. The files are described in
``docs/identification_results.md``.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
import re
from typing import Any, Dict, List, Optional, Tuple, Union

import numpy as np
from scipy import io as sio
import yaml

from emfc_ros.core.errors import EmfcError
from emfc_ros.core.model.linear import INPUTS, STATES

#: Columns of the FRF CSV and numeric arrays of the FRF NPZ, in order, with their meaning.
FRF_COLUMNS = (
    ('frequency_Hz', 'frequency of the DFT line [Hz]'),
    ('response_real_m_per_N', 'real part of the measured response [m/N]'),
    ('response_imag_m_per_N', 'imaginary part of the measured response [m/N]'),
    ('magnitude_m_per_N', 'magnitude of the measured response [m/N]'),
    ('magnitude_dB_re_1m_per_N', 'magnitude [dB re 1 m/N]'),
    ('phase_deg', 'phase of the measured response, in (-180, 180] [deg]'),
    ('coherence', 'ordinary (multiple for two-input sections) coherence, 0 to 1 '
                  '[dimensionless]; NaN where the estimator gives none'),
    ('response_std_m_per_N', 'complex standard deviation sqrt(E|H_hat - H|^2) [m/N]; NaN '
                             'where unknown'),
    ('magnitude_std_m_per_N', 'standard deviation of the magnitude, std / sqrt(2) [m/N]'),
    ('phase_std_deg', 'standard deviation of the phase, std / (sqrt(2) |H|) [deg]'),
    ('tf_fit_real_m_per_N', 'real part of the chosen transfer-function fit [m/N]; NaN '
                            'without a fit'),
    ('tf_fit_imag_m_per_N', 'imaginary part of the chosen transfer-function fit [m/N]'),
    ('greybox_real_m_per_N', 'real part of the grey-box model linearisation [m/N]; NaN '
                             'without the grey-box step'),
    ('greybox_imag_m_per_N', 'imaginary part of the grey-box model linearisation [m/N]'),
)

#: Text entries of the FRF NPZ.
FRF_TEXT_KEYS = ('name', 'section', 'input', 'output', 'unit', 'estimator', 'hold_compensation')

#: Units of the MATLAB variables of ``frf_<name>.mat``.
FRF_MAT_UNITS = {
    'Frequency': 'Hz', 'ResponseData': 'm/N', 'CovarianceData': '(m/N)^2',
    'Coherence': '1 (dimensionless, 0 to 1)', 'ResponseStd': 'm/N',
    'TfFitResponseData': 'm/N', 'GreyboxResponseData': 'm/N', 'Ts': 's',
}

INPUT_TEXT = {'coil': 'coil force', 'pan': 'pan force'}
INPUT_SETPOINT = {'coil': 'coil setpoint', 'pan': 'load-changer setpoint'}
OUTPUT_TEXT = 'lever-end position'


class ExportError(EmfcError, ValueError):
    """A file to export or to read back does not have the expected content."""


def file_stem(text: str) -> str:
    """
    Turn a name into a file-name part (letters, digits, ``_``, ``.``, ``-``).

    Parameters
    ----------
    text : str
        A name such as ``coil_chirp.coil``.

    Returns
    -------
    str
        The name with every other character run replaced by ``_``.
    """
    return re.sub(r'[^A-Za-z0-9_.-]+', '_', text)


def matlab_name(text: str) -> str:
    """
    Turn a name into a valid MATLAB identifier (``coil_chirp.coil`` -> ``coil_chirp_coil``).

    Parameters
    ----------
    text : str
        A name.

    Returns
    -------
    str
        Letters, digits and underscores, starting with a letter, at most 63 characters.
    """
    name = re.sub(r'[^A-Za-z0-9_]+', '_', text).strip('_') or 'x'
    if not name[0].isalpha():
        name = 'x_' + name
    return name[:63]


# ---------------------------------------------------------------- FRFs


def frf_columns(frf: Any) -> Dict[str, np.ndarray]:
    """
    The full-resolution FRF of one section and input as named columns.

    Parameters
    ----------
    frf : FrfResult
        One entry of ``IdentificationResult.frfs``.

    Returns
    -------
    dict of str to ndarray
        The columns of :data:`FRF_COLUMNS`, all of the length of the frequency grid.
    """
    frd = frf.frd
    f = np.asarray(frd.frequency_Hz, dtype=float)
    h = np.asarray(frd.response, dtype=complex)
    std = np.asarray(frd.std, dtype=float)
    nan = np.full(f.size, np.nan)
    with np.errstate(divide='ignore', invalid='ignore'):
        mag = np.abs(h)
        cols = {
            'frequency_Hz': f, 'response_real_m_per_N': h.real,
            'response_imag_m_per_N': h.imag, 'magnitude_m_per_N': mag,
            'magnitude_dB_re_1m_per_N': np.where(mag > 0.0, 20.0 * np.log10(mag), np.nan),
            'phase_deg': np.degrees(np.angle(h)),
            'coherence': np.asarray(frd.coherence, dtype=float),
            'response_std_m_per_N': std, 'magnitude_std_m_per_N': std / math.sqrt(2.0),
            'phase_std_deg': np.degrees(np.where(mag > 0.0, std / (math.sqrt(2.0) * mag),
                                                 np.nan)),
        }
    fit = frf.fit.chosen.response(f) if frf.fit is not None else nan + 0j
    model = (np.asarray(frf.model_response, dtype=complex) if frf.model_response is not None
             else nan + 0j)
    cols.update({'tf_fit_real_m_per_N': fit.real, 'tf_fit_imag_m_per_N': fit.imag,
                 'greybox_real_m_per_N': model.real, 'greybox_imag_m_per_N': model.imag})
    return {k: np.asarray(cols[k], dtype=float) for k, _ in FRF_COLUMNS}


def _frf_text(frf: Any) -> Dict[str, str]:
    return {'name': frf.name, 'section': frf.section,
            'input': f'{INPUT_TEXT[frf.input]} [N]', 'output': f'{OUTPUT_TEXT} [m]',
            'unit': 'm/N', 'estimator': str(frf.frd.estimator),
            'hold_compensation': str(frf.frd.details.get('hold_compensation', 'none'))}


def write_frf_csv(frf: Any, path: Union[str, Path]) -> Path:
    """
    Write one FRF as CSV: a header row of :data:`FRF_COLUMNS` names, one row per line.

    Numbers are written with 17 significant digits (they read back bit for bit); NaN is
    written as ``nan``.

    Parameters
    ----------
    frf : FrfResult
        The FRF.
    path : str or Path
        File to write.

    Returns
    -------
    Path
        The file written.
    """
    cols = frf_columns(frf)
    path = Path(path)
    with open(path, 'w', encoding='utf-8', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(list(cols))
        # Python floats column by column (tolist), not numpy scalars one by one: the same
        # repr text, several times faster
        writer.writerows([repr(v) for v in row] for row in zip(
            *(np.asarray(c, dtype=float).tolist() for c in cols.values())))
    return path


def read_frf_csv(path: Union[str, Path]) -> Dict[str, np.ndarray]:
    """
    Read an FRF CSV written by :func:`write_frf_csv`.

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    dict of str to ndarray
        The columns by name.

    Raises
    ------
    ExportError
        If the header is not the expected one or a row is malformed.
    """
    path = Path(path)
    with open(path, encoding='utf-8', newline='') as stream:
        rows = list(csv.reader(stream))
    expected = [k for k, _ in FRF_COLUMNS]
    if not rows or rows[0] != expected:
        raise ExportError(f'{path}: header must be {expected}, got '
                          f'{rows[0] if rows else "an empty file"}')
    try:
        data = np.array([[float(v) for v in row] for row in rows[1:]], dtype=float)
    except ValueError as exc:
        raise ExportError(f'{path}: a value is not a number ({exc})') from None
    if data.size and data.shape[1] != len(expected):
        raise ExportError(f'{path}: rows must have {len(expected)} values')
    data = data.reshape(-1, len(expected))
    return {k: data[:, i] for i, k in enumerate(expected)}


def write_frf_npz(frf: Any, path: Union[str, Path]) -> Path:
    """
    Write one FRF as NumPy ``.npz``: the CSV's columns and the text keys (no pickles).

    Parameters
    ----------
    frf : FrfResult
        The FRF.
    path : str or Path
        File to write.

    Returns
    -------
    Path
        The file written.
    """
    path = Path(path)
    arrays: Dict[str, np.ndarray] = dict(frf_columns(frf))
    arrays.update({k: np.array(v) for k, v in _frf_text(frf).items()})
    with open(path, 'wb') as stream:
        np.savez(stream, **arrays)
    return path


def read_frf_npz(path: Union[str, Path]) -> Dict[str, Any]:
    """
    Read an FRF ``.npz`` written by :func:`write_frf_npz`.

    Parameters
    ----------
    path : str or Path
        The file.

    Returns
    -------
    dict
        Numeric columns as arrays, text keys as str.

    Raises
    ------
    ExportError
        If a column or text key is missing.
    """
    with np.load(Path(path), allow_pickle=False) as data:
        missing = [k for k, _ in FRF_COLUMNS if k not in data.files]
        missing += [k for k in FRF_TEXT_KEYS if k not in data.files]
        if missing:
            raise ExportError(f'{path}: lacks {missing}')
        out: Dict[str, Any] = {k: np.asarray(data[k], dtype=float) for k, _ in FRF_COLUMNS}
        out.update({k: str(data[k]) for k in FRF_TEXT_KEYS})
    return out


def frf_mat_variables(frf: Any, sample_rate_Hz: float) -> Dict[str, Any]:
    """
    The MATLAB variables of one FRF, named as ``idfrd``'s properties.

    ``ResponseData`` is ``1 x 1 x Nf`` (outputs x inputs x frequencies), ``CovarianceData``
    ``1 x 1 x Nf x 2 x 2`` (covariance of real and imaginary part; the errors are taken as
    circular, so it is ``diag(std^2 / 2, std^2 / 2)``). ``Ts`` is 0 (continuous time) when
    the DAC hold was removed from the FRF, else the sample time.

    Parameters
    ----------
    frf : FrfResult
        The FRF.
    sample_rate_Hz : float
        Sample rate of the recording [Hz].

    Returns
    -------
    dict
        Variable name to value, ready for :func:`scipy.io.savemat`.
    """
    cols = frf_columns(frf)
    text = _frf_text(frf)
    nf = cols['frequency_Hz'].size
    resp = cols['response_real_m_per_N'] + 1j * cols['response_imag_m_per_N']
    var = cols['response_std_m_per_N'] ** 2 / 2.0
    cov = np.zeros((1, 1, nf, 2, 2))
    cov[0, 0, :, 0, 0] = var
    cov[0, 0, :, 1, 1] = var
    hold = text['hold_compensation']
    ts = 0.0 if hold not in ('', 'none') else 1.0 / float(sample_rate_Hz)
    out = {
        'Frequency': cols['frequency_Hz'].reshape(nf, 1),
        'ResponseData': resp.reshape(1, 1, nf),
        'CovarianceData': cov,
        'Ts': ts, 'TimeUnit': 'seconds', 'FrequencyUnit': 'Hz',
        'InputName': INPUT_TEXT[frf.input], 'InputUnit': 'N',
        'OutputName': OUTPUT_TEXT, 'OutputUnit': 'm', 'ResponseUnit': 'm/N',
        'Coherence': cols['coherence'].reshape(nf, 1),
        'ResponseStd': cols['response_std_m_per_N'].reshape(nf, 1),
        'TfFitResponseData': (cols['tf_fit_real_m_per_N']
                              + 1j * cols['tf_fit_imag_m_per_N']).reshape(1, 1, nf),
        'GreyboxResponseData': (cols['greybox_real_m_per_N']
                                + 1j * cols['greybox_imag_m_per_N']).reshape(1, 1, nf),
        'Name': text['name'], 'Section': text['section'], 'Estimator': text['estimator'],
        'HoldCompensation': hold, 'TwoInput': bool(frf.two_input),
        'SampleRate_Hz': float(sample_rate_Hz),
        'Units': dict(FRF_MAT_UNITS),
        'Notes': ('Measured FRF of the lever-end position per force, hold removed as '
                  'HoldCompensation says. CovarianceData(1,1,k,:,:) is the covariance of real '
                  'and imaginary part [(m/N)^2]. Coherence is NaN where the estimator gives '
                  'none; TfFitResponseData and GreyboxResponseData are NaN without the fit.'),
    }
    return out


def write_frf_mat(frf: Any, path: Union[str, Path], sample_rate_Hz: float) -> Path:
    """
    Write one FRF as a MATLAB ``.mat`` (version 5) file of :func:`frf_mat_variables`.

    Parameters
    ----------
    frf : FrfResult
        The FRF.
    path : str or Path
        File to write.
    sample_rate_Hz : float
        Sample rate of the recording [Hz].

    Returns
    -------
    Path
        The file written.
    """
    path = Path(path)
    sio.savemat(path, frf_mat_variables(frf, sample_rate_Hz), oned_as='column',
                do_compression=True)
    return path


def two_input_mat_variables(coil: Any, pan: Any, sample_rate_Hz: float) -> Dict[str, Any]:
    """
    The MATLAB variables of a two-input section: one ``idfrd`` with inputs coil and pan force.

    ``ResponseData`` is ``1 x 2 x Nf`` and ``CovarianceData`` ``1 x 2 x Nf x 2 x 2`` (each
    entry's own real/imaginary covariance; the covariance between the two entries is not
    estimated). ``Coherence``, ``ResponseStd`` and the model responses get one column (or
    second index) per input.

    Parameters
    ----------
    coil, pan : FrfResult
        The section's two FRFs from the joint solve (same frequency lines).
    sample_rate_Hz : float
        Sample rate of the recording [Hz].

    Returns
    -------
    dict
        Variable name to value, ready for :func:`scipy.io.savemat`.

    Raises
    ------
    ExportError
        If the two FRFs are not of one section on the same lines.
    """
    if (coil.section != pan.section or coil.input != 'coil' or pan.input != 'pan'
            or not np.array_equal(coil.frd.frequency_Hz, pan.frd.frequency_Hz)):
        raise ExportError(f'{coil.name} and {pan.name} are not the coil and pan FRFs of one '
                          f'section on the same frequency lines')
    a = frf_mat_variables(coil, sample_rate_Hz)
    b = frf_mat_variables(pan, sample_rate_Hz)
    out = dict(a)
    for key in ('ResponseData', 'CovarianceData', 'TfFitResponseData', 'GreyboxResponseData'):
        out[key] = np.concatenate((a[key], b[key]), axis=1)
    for key in ('Coherence', 'ResponseStd'):
        out[key] = np.hstack((a[key], b[key]))
    out.update({'InputName': _cell([INPUT_TEXT['coil'], INPUT_TEXT['pan']]),
                'InputUnit': _cell(['N', 'N']), 'Name': coil.section,
                'Notes': a['Notes'] + ' Two inputs (coil force, pan force) from the joint '
                                      'solve: ResponseData(1,j,k) is input j at line k; '
                                      'Coherence and ResponseStd have one column per input.'})
    return out


def write_two_input_mat(coil: Any, pan: Any, path: Union[str, Path],
                        sample_rate_Hz: float) -> Path:
    """
    Write a two-input section as one MATLAB ``.mat`` of :func:`two_input_mat_variables`.

    Parameters
    ----------
    coil, pan : FrfResult
        The section's coil and pan FRFs.
    path : str or Path
        File to write.
    sample_rate_Hz : float
        Sample rate of the recording [Hz].

    Returns
    -------
    Path
        The file written.
    """
    path = Path(path)
    sio.savemat(path, two_input_mat_variables(coil, pan, sample_rate_Hz), oned_as='column',
                do_compression=True)
    return path


# ---------------------------------------------------------------- models


def _roots_plain(values: np.ndarray) -> List[Dict[str, float]]:
    return [{'real_rad_per_s': float(v.real), 'imag_rad_per_s': float(v.imag)}
            for v in np.asarray(values, dtype=complex)]


def _matrix(a: np.ndarray) -> List[List[float]]:
    return [[float(v) for v in row] for row in np.atleast_2d(np.asarray(a, dtype=float))]


def tf_to_ss(num: np.ndarray, den: np.ndarray
             ) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """
    Controllable canonical state space of a proper SISO transfer function.

    What ``scipy.signal.tf2ss`` returns for it, with numpy alone (scipy.signal takes about a
    second to import, more than the whole report takes to write).

    Parameters
    ----------
    num, den : ndarray
        Coefficients in descending powers of s, ``len(num) <= len(den)``, ``den[0] != 0``.

    Returns
    -------
    A, B, C, D : ndarray
        Shapes (n, n), (n, 1), (1, n), (1, 1), n = ``len(den) - 1``.
    """
    den = np.trim_zeros(np.atleast_1d(np.asarray(den, dtype=float)), 'f')
    num = np.atleast_1d(np.asarray(num, dtype=float)) / den[0]
    den = den / den[0]
    k = den.size
    if num.size > k:
        raise ValueError('improper transfer function: the numerator has a higher order')
    num = np.concatenate((np.zeros(k - num.size), num))
    d = np.array([[num[0]]])
    if k == 1:
        return np.zeros((1, 1)), np.zeros((1, 1)), np.zeros((1, 1)), d
    a = np.vstack((-den[1:][None, :], np.eye(k - 2, k - 1)))
    b = np.eye(k - 1, 1)
    c = (num[1:] - num[0] * den[1:])[None, :]
    return a, b, c, d


def ss_to_tf(a: np.ndarray, b: np.ndarray, c: np.ndarray, d: np.ndarray, input: int = 0
             ) -> Tuple[np.ndarray, np.ndarray]:
    """
    Transfer function of one input of a state-space model.

    What ``scipy.signal.ss2tf(a, b, c, d, input=input)`` returns, with numpy alone.

    Parameters
    ----------
    a, b, c, d : ndarray
        State-space matrices, shapes (n, n), (n, m), (p, n), (p, m).
    input : int
        The input's column.

    Returns
    -------
    num : ndarray, shape (p, n + 1)
        Numerators in descending powers of s, one row per output.
    den : ndarray, shape (n + 1,)
        The characteristic polynomial of ``a``.
    """
    a, b = np.atleast_2d(np.asarray(a, dtype=float)), np.atleast_2d(np.asarray(b, dtype=float))
    c, d = np.atleast_2d(np.asarray(c, dtype=float)), np.atleast_2d(np.asarray(d, dtype=float))
    bj = b[:, input:input + 1]
    den = np.poly(a)
    num = np.zeros((c.shape[0], den.size))
    for k in range(c.shape[0]):
        num[k] = np.poly(a - bj @ c[k:k + 1, :]) + (d[k, input] - 1.0) * den
    return num, den


def _tf_model(frf: Any) -> Dict[str, Any]:
    c = frf.fit.chosen
    num = np.asarray(c.numerator, dtype=float)
    den = np.asarray(c.denominator, dtype=float)
    a, b, cc, d = tf_to_ss(num, den)
    return {
        'name': frf.name, 'section': frf.section, 'input': f'{INPUT_TEXT[frf.input]} [N]',
        'output': f'{OUTPUT_TEXT} [m]', 'unit': 'm/N', 'variable': 's [rad/s]',
        'numerator_order': int(c.numerator_order),
        'denominator_order': int(c.denominator_order),
        'numerator_s_rad_per_s': [float(v) for v in num],
        'denominator_s_rad_per_s': [float(v) for v in den],
        'poles_rad_per_s': _roots_plain([p.s_rad_per_s for p in c.poles]),
        'zeros_rad_per_s': _roots_plain([z.s_rad_per_s for z in c.zeros]),
        'stable': bool(c.is_stable),
        'state_space': {
            'form': 'controllable canonical (scipy.signal.tf2ss)',
            'units': 'the states of this form have no physical unit; input force N, output '
                     'lever-end position m, time in s: the map from input to output is the '
                     'transfer function in m/N',
            'A': _matrix(a), 'B': _matrix(b), 'C': _matrix(cc), 'D': _matrix(d)},
    }


def _greybox_model(g: Any) -> Dict[str, Any]:
    lin = g.linear_model
    a, b = np.asarray(lin.A, dtype=float), np.asarray(lin.B, dtype=float)
    c, d = np.asarray(lin.C, dtype=float), np.asarray(lin.D, dtype=float)
    nums, den = [], None
    for j, name in enumerate(INPUTS):
        num, den = ss_to_tf(a, b, c, d, input=j)
        nums.append({'input': f'{INPUT_TEXT[name]} [N]',
                     'numerator_s_rad_per_s': [float(v) for v in np.ravel(num)]})
    return {
        'description': 'linearisation of the fitted two-beam grey-box model about its rest '
                       'position in the experiment configuration',
        'states': list(STATES), 'inputs': [f'{INPUT_TEXT[n]} [N]' for n in INPUTS],
        'output': f'{OUTPUT_TEXT} [m]', 'variable': 's [rad/s]',
        'state_space': {
            'units': 'x = [q1 rad, q2 rad, q1dot rad/s, q2dot rad/s], u = [F_coil N, F_pan N], '
                     'y = lever-end position m; A [1/s, 1/s^2], B [rad/(s^2 N)], C [m/rad], '
                     'D [m/N]',
            'A': _matrix(a), 'B': _matrix(b), 'C': _matrix(c), 'D': _matrix(d)},
        'transfer_functions': {'denominator_s_rad_per_s': [float(v) for v in np.ravel(den)],
                               'numerators': nums, 'unit': 'm/N'},
        'poles_rad_per_s': _roots_plain([p.s_rad_per_s for p in lin.poles()]),
        'zeros_coil_rad_per_s': _roots_plain([z.s_rad_per_s for z in lin.zeros('coil')]),
        'zeros_pan_rad_per_s': _roots_plain([z.s_rad_per_s for z in lin.zeros('pan')]),
        'static_gain_coil_m_per_N': float(lin.static_gain_m_per_N('coil')),
        'static_gain_pan_m_per_N': float(lin.static_gain_m_per_N('pan')),
        'parameters': {k: float(v) for k, v in g.parameters.items()},
    }


def models_dict(result: Any) -> Dict[str, Any]:
    """
    The fitted models as plain data (the content of ``models.yaml``).

    Parameters
    ----------
    result : IdentificationResult
        The pipeline's result.

    Returns
    -------
    dict
        ``transfer_function_fits`` (one per FRF with a fit) and ``greybox_linearised``
        (None without the grey-box step); every key names its unit.
    """
    return {
        'transfer_function_fits': [_tf_model(r) for r in result.frfs if r.fit is not None],
        'greybox_linearised': (_greybox_model(result.greybox) if result.greybox is not None
                               else None),
    }


def _complex(roots: List[Dict[str, float]]) -> np.ndarray:
    return np.array([r['real_rad_per_s'] + 1j * r['imag_rad_per_s'] for r in roots],
                    dtype=complex).reshape(-1, 1)


def _cell(items: List[str]) -> np.ndarray:
    out = np.empty((1, len(items)), dtype=object)
    for i, item in enumerate(items):
        out[0, i] = item
    return out


def models_mat_variables(result: Any) -> Dict[str, Any]:
    """
    The fitted models as MATLAB variables (the content of ``models.mat``).

    One struct ``tf_<section>_<input>`` per transfer-function fit (``Numerator``,
    ``Denominator`` for ``tf(Numerator, Denominator)``, ``A, B, C, D``, ``Poles``, ``Zeros``)
    and ``greybox_linearised`` (``A, B, C, D`` for ``ss(A, B, C, D)``, ``Numerator`` one row
    per input, ``Denominator``, poles, zeros, static gains, parameters); each struct carries
    a ``Units`` struct. ``ModelNames`` lists the struct names.

    Parameters
    ----------
    result : IdentificationResult
        The pipeline's result.

    Returns
    -------
    dict
        Variable name to value, ready for :func:`scipy.io.savemat`.
    """
    models = models_dict(result)
    out: Dict[str, Any] = {}
    names = []
    for tf in models['transfer_function_fits']:
        ss = tf['state_space']
        key = 'tf_' + matlab_name(tf['name'])
        names.append(key)
        out[key] = {
            'Name': tf['name'], 'Section': tf['section'], 'InputName': tf['input'],
            'InputUnit': 'N', 'OutputName': tf['output'], 'OutputUnit': 'm',
            'Numerator': np.array(tf['numerator_s_rad_per_s'], dtype=float).reshape(1, -1),
            'Denominator': np.array(tf['denominator_s_rad_per_s'], dtype=float).reshape(1, -1),
            'Poles': _complex(tf['poles_rad_per_s']), 'Zeros': _complex(tf['zeros_rad_per_s']),
            'A': np.array(ss['A']), 'B': np.array(ss['B']),
            'C': np.array(ss['C']), 'D': np.array(ss['D']),
            'Stable': tf['stable'],
            'Units': {'Numerator': 'm/N with s in rad/s, highest power first',
                      'Denominator': 'monic, s in rad/s, highest power first',
                      'Poles': 'rad/s', 'Zeros': 'rad/s',
                      'StateSpace': ss['form'] + '; ' + ss['units']},
        }
    g = models['greybox_linearised']
    if g is not None:
        ss = g['state_space']
        tfs = g['transfer_functions']
        names.append('greybox_linearised')
        out['greybox_linearised'] = {
            'Description': g['description'],
            'A': np.array(ss['A']), 'B': np.array(ss['B']), 'C': np.array(ss['C']),
            'D': np.array(ss['D']),
            'StateName': _cell(list(STATES)),
            'InputName': _cell([INPUT_TEXT[n] for n in INPUTS]),
            'InputUnit': _cell(['N', 'N']), 'OutputName': OUTPUT_TEXT, 'OutputUnit': 'm',
            'Numerator': np.array([n['numerator_s_rad_per_s'] for n in tfs['numerators']],
                                  dtype=float),
            'Denominator': np.array(tfs['denominator_s_rad_per_s'], dtype=float).reshape(1, -1),
            'Poles': _complex(g['poles_rad_per_s']),
            'ZerosCoil': _complex(g['zeros_coil_rad_per_s']),
            'ZerosPan': _complex(g['zeros_pan_rad_per_s']),
            'StaticGainCoil_m_per_N': g['static_gain_coil_m_per_N'],
            'StaticGainPan_m_per_N': g['static_gain_pan_m_per_N'],
            'Parameters': {matlab_name(k): v for k, v in g['parameters'].items()},
            'Units': {'StateSpace': ss['units'],
                      'Numerator': 'm/N, one row per input (coil, pan), s in rad/s, highest '
                                   'power first',
                      'Denominator': 's in rad/s, highest power first',
                      'Poles': 'rad/s', 'ZerosCoil': 'rad/s', 'ZerosPan': 'rad/s',
                      'Parameters': 'SI, the unit is the suffix of each name'},
        }
    out['ModelNames'] = _cell(names)
    return out


def write_models(result: Any, out_dir: Union[str, Path]) -> List[Path]:
    """
    Write ``models.yaml`` and ``models.mat`` (nothing when no model was fitted).

    Parameters
    ----------
    result : IdentificationResult
        The pipeline's result.
    out_dir : str or Path
        Folder.

    Returns
    -------
    list of Path
        The files written.
    """
    models = models_dict(result)
    if not models['transfer_function_fits'] and models['greybox_linearised'] is None:
        return []
    out = Path(out_dir)
    yaml_path = out / 'models.yaml'
    with open(yaml_path, 'w', encoding='utf-8') as stream:
        yaml.safe_dump(models, stream, sort_keys=False, default_flow_style=None, width=100)
    mat_path = out / 'models.mat'
    sio.savemat(mat_path, models_mat_variables(result), oned_as='column',
                do_compression=True)
    return [yaml_path, mat_path]


def write_exports(result: Any, out_dir: Union[str, Path],
                  sample_rate_Hz: Optional[float] = None) -> List[Path]:
    """
    Write every FRF as CSV, NPZ and MAT, and the models as YAML and MAT.

    Parameters
    ----------
    result : IdentificationResult
        The pipeline's result.
    out_dir : str or Path
        Folder (created if needed).
    sample_rate_Hz : float, optional
        Sample rate [Hz]; default the result's.

    Returns
    -------
    list of Path
        The files written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    fs = float(sample_rate_Hz if sample_rate_Hz is not None else result.sample_rate_Hz)
    written = []
    for frf in result.frfs:
        stem = 'frf_' + file_stem(frf.name)
        written.append(write_frf_csv(frf, out / f'{stem}.csv'))
        written.append(write_frf_npz(frf, out / f'{stem}.npz'))
        written.append(write_frf_mat(frf, out / f'{stem}.mat', fs))
    pairs: Dict[str, Dict[str, Any]] = {}
    for frf in result.frfs:
        if frf.two_input:
            pairs.setdefault(frf.section, {})[frf.input] = frf
    for section, pair in pairs.items():
        same_lines = set(pair) == {'coil', 'pan'} and np.array_equal(
            pair['coil'].frd.frequency_Hz, pair['pan'].frd.frequency_Hz)
        if same_lines:
            written.append(write_two_input_mat(pair['coil'], pair['pan'],
                                               out / f'frf_{file_stem(section)}.mat', fs))
    written += write_models(result, out)
    return written
