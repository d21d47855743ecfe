"""
Arbitrary waveforms loaded from CSV or NPY files.

CSV files have a header line of column names, each ending in a unit suffix (``coil_V``,
``time_s``, ``force_mN``; ``sample_index`` is also accepted), then one row per sample, comma
separated; lines starting with ``#`` are comments. The chosen column must be a setpoint
voltage (suffix ``_V``). An optional ``time_s`` column must be uniformly spaced by
``1 / sample_rate_Hz`` within 1e-6 relative. NPY files hold a 1-D array, or a 2-D array
(samples x columns) with a column index; their sample rate is given by the caller and must
equal the experiment's.
Every failure raises :class:`~emfc_ros.core.errors.WaveformFileError` naming the file and,
where it applies, the column and data row (1-based, header excluded).
"""

from __future__ import annotations

import csv
from pathlib import Path
import re
from typing import Optional, Union

import numpy as np

from emfc_ros.core.errors import SignalError, WaveformFileError
from emfc_ros.core.signals.base import as_index, check_rate

END_MODES = ('zero', 'hold', 'repeat')
UNIT_SUFFIXES = ('V', 'A', 's', 'Hz', 'rad', 'm', 'N', 'g', 'W', 'Ohm', 'K', 'Pa', '1')
#: Optional SI prefixes of a unit suffix (``coil_mV`` has a unit, just not volts).
UNIT_PREFIXES = 'munpkMG'
DIMENSIONLESS = ('sample_index',)
TIME_COLUMN = 'time_s'
RATE_TOLERANCE = 1e-6
_NAME = re.compile(r'[A-Za-z][A-Za-z0-9_]*_[' + UNIT_PREFIXES + r']?('
                   + '|'.join(UNIT_SUFFIXES) + r')')


class Waveform:
    """
    Samples from an array; what comes after its end is configurable.

    Parameters
    ----------
    data_V : numpy.ndarray
        1-D finite samples (copied, read-only).
    sample_rate_Hz : float
        Sample rate.
    end : {'zero', 'hold', 'repeat'}
        After the last sample: 0 V, hold the last value, or start over.
    source : str
        Where the data came from, for messages.
    """

    def __init__(self, data_V: np.ndarray, sample_rate_Hz: float, end: str = 'zero',
                 source: str = '') -> None:
        self.sample_rate_Hz = check_rate(sample_rate_Hz)
        data = np.array(data_V, dtype=np.float64)
        if data.ndim != 1 or data.size == 0:
            raise SignalError(f'waveform data must be a non-empty 1-D array, got shape '
                              f'{data.shape}')
        if not np.isfinite(data).all():
            raise SignalError('waveform data must be finite')
        if end not in END_MODES:
            raise SignalError(f'end must be one of {list(END_MODES)}, got {end!r}')
        self.end = end
        self.source = source
        data.flags.writeable = False
        self.data_V = data
        self._padded = np.append(data, 0.0)

    def __len__(self) -> int:
        return self.data_V.size

    def samples(self, k: np.ndarray) -> np.ndarray:
        """
        Evaluate at local sample indices.

        Parameters
        ----------
        k : numpy.ndarray
            int64 sample indices >= 0.

        Returns
        -------
        numpy.ndarray
            float64 samples, same shape as ``k``.
        """
        k = as_index(k)
        n = self.data_V.size
        if self.end == 'repeat':
            return self.data_V[k % n]
        if self.end == 'hold':
            return self.data_V[np.minimum(k, n - 1)]
        return self._padded[np.minimum(k, n)]

    def __repr__(self) -> str:
        return (f'Waveform({len(self)} samples from {self.source or "array"!r}, '
                f'end={self.end!r})')


def load_waveform(path: Union[str, Path], sample_rate_Hz: float, *,
                  column: Union[str, int, None] = None,
                  file_sample_rate_Hz: Optional[float] = None, end: str = 'zero',
                  min_samples: int = 2) -> Waveform:
    """
    Load and validate a waveform file.

    Parameters
    ----------
    path : str or pathlib.Path
        A ``.csv`` or ``.npy`` file.
    sample_rate_Hz : float
        The experiment's sample rate; the file must have this rate.
    column : str or int, optional
        CSV: column name (default: the only ``_V`` column). NPY: column index of a 2-D array.
    file_sample_rate_Hz : float, optional
        The file's sample rate; required for NPY, checked against ``time_s`` for CSV.
    end : {'zero', 'hold', 'repeat'}
        Behaviour past the end.
    min_samples : int
        Minimum number of samples.

    Returns
    -------
    Waveform
        The waveform.

    Raises
    ------
    WaveformFileError
        If the file is unreadable or fails validation.
    """
    path = Path(path)
    sample_rate_Hz = check_rate(sample_rate_Hz)
    if file_sample_rate_Hz is not None and not _same_rate(file_sample_rate_Hz, sample_rate_Hz):
        raise WaveformFileError(f'{path}: file sample rate {file_sample_rate_Hz!r} Hz differs '
                                f'from the experiment sample rate {sample_rate_Hz!r} Hz '
                                f'(no resampling is done)')
    suffix = path.suffix.lower()
    if suffix == '.csv':
        data, name = _load_csv(path, column, sample_rate_Hz)
    elif suffix == '.npy':
        if file_sample_rate_Hz is None:
            raise WaveformFileError(f'{path}: an NPY file carries no sample rate; give '
                                    f'file_sample_rate_Hz')
        data, name = _load_npy(path, column)
    else:
        raise WaveformFileError(f'{path}: unknown waveform file type {suffix!r}; '
                                f'expected .csv or .npy')
    if data.size < min_samples:
        raise WaveformFileError(f'{path}: column {name!r} has {data.size} samples, at least '
                                f'{min_samples} are needed')
    bad = np.flatnonzero(~np.isfinite(data))
    if bad.size:
        raise WaveformFileError(f'{path}: column {name!r} row {bad[0] + 1}: value '
                                f'{data[bad[0]]!r} is not finite')
    return Waveform(data, sample_rate_Hz, end=end, source=f'{path}:{name}')


def _same_rate(a_Hz: float, b_Hz: float) -> bool:
    return abs(float(a_Hz) - float(b_Hz)) <= 1e-9 * abs(float(b_Hz))


def _read_text(path: Path) -> str:
    try:
        return path.read_text(encoding='utf-8')
    except (OSError, UnicodeDecodeError) as exc:
        raise WaveformFileError(f'{path}: cannot read file: {exc}') from exc


def _load_csv(path: Path, column: Union[str, int, None], sample_rate_Hz: float) -> tuple:
    lines = [(i + 1, line) for i, line in enumerate(_read_text(path).splitlines())
             if line.strip() and not line.lstrip().startswith('#')]
    if not lines:
        raise WaveformFileError(f'{path}: empty file (no header line)')
    header = [name.strip() for name in next(csv.reader([lines[0][1]]))]
    for name in header:
        if name not in DIMENSIONLESS and not _NAME.fullmatch(name):
            raise WaveformFileError(f'{path}: column {name!r} has no unit suffix; name '
                                    f'columns like coil_V or time_s')
    if len(set(header)) != len(header):
        raise WaveformFileError(f'{path}: repeated column names in header {header}')
    name = _pick_csv_column(path, header, column)
    rows = lines[1:]
    if not rows:
        raise WaveformFileError(f'{path}: no data rows after the header')
    try:        # fast path; on any failure the loop below finds and names the bad cell
        table = np.loadtxt([text for _, text in rows], delimiter=',', ndmin=2,
                           dtype=np.float64)
        if table.shape != (len(rows), len(header)):
            raise ValueError('shape')
    except ValueError:
        table = _parse_rows(path, header, rows)
    if TIME_COLUMN in header:
        _check_time(path, table[:, header.index(TIME_COLUMN)], sample_rate_Hz)
    return table[:, header.index(name)], name


def _parse_rows(path: Path, header: list, rows: list) -> np.ndarray:
    table = np.empty((len(rows), len(header)))
    for r, (line_no, text) in enumerate(rows):
        cells = next(csv.reader([text]))
        if len(cells) != len(header):
            raise WaveformFileError(f'{path}: row {r + 1} (line {line_no}) has {len(cells)} '
                                    f'values, the header has {len(header)}')
        for c, cell in enumerate(cells):
            try:
                table[r, c] = float(cell)
            except ValueError:
                raise WaveformFileError(f'{path}: column {header[c]!r} row {r + 1} '
                                        f'(line {line_no}): {cell.strip()!r} is not a '
                                        f'number') from None
    return table


def _pick_csv_column(path: Path, header: list, column: Union[str, int, None]) -> str:
    volts = [name for name in header if name.endswith('_V')]
    if column is None:
        if len(volts) != 1:
            raise WaveformFileError(f'{path}: {len(volts)} voltage columns {volts}; choose '
                                    f'one with column')
        return volts[0]
    if not isinstance(column, str):
        raise WaveformFileError(f'{path}: a CSV column is chosen by name, got {column!r}')
    if column not in header:
        raise WaveformFileError(f'{path}: no column {column!r}; the header has {header}')
    if not column.endswith('_V'):
        raise WaveformFileError(f'{path}: column {column!r} is not a setpoint voltage; its '
                                f'name must end in the unit suffix _V')
    return column


def _check_time(path: Path, time_s: np.ndarray, sample_rate_Hz: float) -> None:
    bad = np.flatnonzero(~np.isfinite(time_s))
    if bad.size:
        raise WaveformFileError(f'{path}: column {TIME_COLUMN!r} row {bad[0] + 1}: value '
                                f'{time_s[bad[0]]!r} is not finite')
    if time_s.size < 2:
        return
    spacing = np.diff(time_s) * sample_rate_Hz
    wrong = np.flatnonzero(np.abs(spacing - 1.0) > RATE_TOLERANCE)
    if wrong.size:
        r = wrong[0]
        raise WaveformFileError(
            f'{path}: column {TIME_COLUMN!r} rows {r + 1}-{r + 2}: spacing '
            f'{time_s[r + 1] - time_s[r]!r} s does not match the sample rate '
            f'{sample_rate_Hz!r} Hz (expected {1.0 / sample_rate_Hz!r} s within '
            f'{RATE_TOLERANCE:g} relative)')


def _load_npy(path: Path, column: Union[str, int, None]) -> tuple:
    try:
        array = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as exc:
        raise WaveformFileError(f'{path}: cannot read NPY file: {exc}') from exc
    if not isinstance(array, np.ndarray) or array.dtype.kind not in 'iuf':
        raise WaveformFileError(f'{path}: expected a numeric array, got dtype '
                                f'{getattr(array, "dtype", type(array))}')
    if isinstance(column, bool) or (column is not None and not isinstance(column, int)):
        raise WaveformFileError(f'{path}: an NPY column is chosen by index, got {column!r}')
    if array.ndim == 1:
        if column not in (None, 0):
            raise WaveformFileError(f'{path}: 1-D array has no column {column!r}')
        return array.astype(np.float64), 0
    if array.ndim == 2:
        if column is None:
            if array.shape[1] != 1:
                raise WaveformFileError(f'{path}: 2-D array with {array.shape[1]} columns; '
                                        f'choose one with column')
            column = 0
        if not 0 <= column < array.shape[1]:
            raise WaveformFileError(f'{path}: column {column} out of range; the array has '
                                    f'{array.shape[1]} columns')
        return array[:, column].astype(np.float64), column
    raise WaveformFileError(f'{path}: expected a 1-D or 2-D array, got shape {array.shape}')
