"""
emfc-simulate: run an excitation file through the plant simulator, offline.

``emfc-simulate EXCITATION.(csv|npy) -o OUT.(csv|npy) [--config FILE] [--sample-rate-Hz R]
[--seed S] [--no-noise] [--no-quantisation] [--load-mass-kg M] [--load-changer-coupled]
[--hold zoh|foh] [--substeps N] [--add-hold-setpoints]``

Input:

* CSV with a header naming the columns ``coil_V`` and ``load_changer_V`` (setpoints [V]);
  optional ``sample_index`` and ``time_s`` columns, as ``emfc-generate`` writes them, are used
  for the output's sample indices and, without ``--sample-rate-Hz``, for the sample rate;
* NPY: a float array of shape (n, 2), columns coil and load changer; an array of shape (2, n)
  with n != 2 (the channel-major layout ``emfc-generate`` writes) is accepted too.

The setpoints are absolute voltages; ``--add-hold-setpoints`` adds the setpoints that hold the
lever end at 0 (for zero-mean excitation). The simulator starts at that hold point.

Output:

* CSV: header ``sample_index,time_s,<channel>...`` (every channel name ends in its unit, see
  ``docs/simulator.md``), one row per sample;
* NPY: float64 array of shape (n, 2 + channels) with the same columns, plus a JSON sidecar
  (``OUT.json``) with the column names, units, sample rate and settings.

Errors go to stderr with exit code 2.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys
from typing import List, Optional, Tuple
import warnings

import numpy as np

from emfc_ros.core.errors import EmfcError
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.sim.simulator import HOLDS, Simulator

DEFAULT_SAMPLE_RATE_HZ = 10000.0
INPUT_COLUMNS = ('coil_V', 'load_changer_V')
TIME_FORMAT = '%.12f'
VALUE_FORMAT = '%.17g'


class ExcitationFileError(EmfcError, ValueError):
    """The excitation file is unreadable or malformed."""


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='emfc-simulate',
        description='Run setpoint voltages from a CSV or NPY file through the simulated '
                    'balance and write the measured channels.')
    parser.add_argument('excitation', type=Path,
                        help='CSV (columns coil_V, load_changer_V) or NPY (n, 2) setpoints [V]')
    parser.add_argument('-o', '--output', type=Path, required=True,
                        help='output file, .csv or .npy (with a .json sidecar)')
    parser.add_argument('--config', help='balance parameter YAML (default: built-in defaults)')
    parser.add_argument('--sample-rate-Hz', type=float, default=None,
                        help='sample rate [Hz] (default: from the time_s column, else '
                             f'{DEFAULT_SAMPLE_RATE_HZ:g})')
    parser.add_argument('--seed', type=int, default=0, help='noise seed (default 0)')
    parser.add_argument('--no-noise', action='store_true', help='no sensor or current noise')
    parser.add_argument('--no-quantisation', action='store_true',
                        help='no DAC/ADC quantisation (saturation stays)')
    parser.add_argument('--load-mass-kg', type=float, default=0.0,
                        help='mass on the pan [kg] (default 0)')
    parser.add_argument('--load-changer-coupled', action='store_true',
                        help="the load changer's moving mass rides on the pan")
    parser.add_argument('--hold', choices=HOLDS, default='zoh',
                        help='zero- or first-order hold of the setpoints (default zoh)')
    parser.add_argument('--substeps', type=int, default=None,
                        help='RK4 steps per sample (default: automatic)')
    parser.add_argument('--add-hold-setpoints', action='store_true',
                        help="add the setpoints that hold the lever end at 0 to the file's")
    return parser


def _rate_from_time(time_s: np.ndarray) -> Optional[float]:
    if time_s.size < 2:
        return None
    step = np.diff(time_s)
    if not np.all(step > 0.0):
        raise ExcitationFileError('time_s must increase from row to row')
    # time_s is printed with 12 decimals: keep 10 significant digits of the rate
    return float(f'{(time_s.size - 1) / (time_s[-1] - time_s[0]):.10g}')


def read_excitation(path: Path) -> Tuple[np.ndarray, Optional[np.ndarray], Optional[float]]:
    """
    Read setpoints from a CSV or NPY file.

    Parameters
    ----------
    path : pathlib.Path
        The file (``.csv`` or ``.npy``).

    Returns
    -------
    setpoints : ndarray, shape (2, n)
        Coil and load-changer setpoints [V].
    sample_index : ndarray of int64 or None
        The file's sample indices, if it has them.
    sample_rate_Hz : float or None
        The rate implied by a ``time_s`` column, if any.

    Raises
    ------
    ExcitationFileError
        If the file cannot be read or is malformed.
    """
    suffix = path.suffix.lower()
    index = None
    rate = None
    try:
        if suffix == '.npy':
            data = np.load(path, allow_pickle=False)
            if data.ndim != 2 or data.dtype.kind not in 'fiu':
                raise ExcitationFileError(f'{path}: expected a numeric array of shape (n, 2), '
                                          f'got {data.dtype} {data.shape}')
            if data.shape[1] == 2:
                u = data.T
            elif data.shape[0] == 2:
                u = data
            else:
                raise ExcitationFileError(f'{path}: expected shape (n, 2) (columns coil, '
                                          f'load_changer), got {data.shape}')
        elif suffix == '.csv':
            with open(path, 'r', encoding='utf-8') as stream:
                header = [h.strip() for h in stream.readline().strip().split(',')]
                missing = [c for c in INPUT_COLUMNS if c not in header]
                if missing:
                    raise ExcitationFileError(f'{path}: the header must name the columns '
                                              f'{list(INPUT_COLUMNS)}; missing {missing}, '
                                              f'found {header}')
                with warnings.catch_warnings():
                    warnings.simplefilter('ignore', UserWarning)   # no data: checked below
                    table = np.loadtxt(stream, delimiter=',', ndmin=2)
            if table.size and table.shape[1] != len(header):
                raise ExcitationFileError(f'{path}: {table.shape[1]} columns per row but '
                                          f'{len(header)} names in the header')
            table = table.reshape(-1, len(header))
            u = np.stack([table[:, header.index(c)] for c in INPUT_COLUMNS])
            if 'sample_index' in header:
                raw = table[:, header.index('sample_index')]
                index = raw.astype(np.int64)
                if not np.array_equal(index, raw) or (index.size and index.min() < 0):
                    raise ExcitationFileError(f'{path}: sample_index must hold integers >= 0')
            if 'time_s' in header:
                rate = _rate_from_time(table[:, header.index('time_s')])
        else:
            raise ExcitationFileError(f'{path}: the excitation must be a .csv or .npy file')
    except (OSError, ValueError) as exc:
        if isinstance(exc, ExcitationFileError):
            raise
        raise ExcitationFileError(f'{path}: cannot read the excitation: {exc}') from exc
    u = np.ascontiguousarray(u, dtype=float)
    if u.shape[1] == 0:
        raise ExcitationFileError(f'{path}: no samples')
    if not np.all(np.isfinite(u)):
        raise ExcitationFileError(f'{path}: the setpoints must be finite numbers')
    return u, index, rate


def write_output(path: Path, sim: Simulator, index: np.ndarray, out: np.ndarray,
                 settings: dict) -> None:
    """
    Write the simulated channels as CSV, or as NPY with a JSON sidecar.

    Parameters
    ----------
    path : pathlib.Path
        ``.csv`` or ``.npy`` file.
    sim : Simulator
        The simulator (names, units, sample rate).
    index : ndarray of int64
        Sample indices.
    out : ndarray, shape (channels, n)
        The channels.
    settings : dict
        Settings recorded in the sidecar.
    """
    names = ['sample_index', 'time_s'] + list(sim.channel_names)
    units = ['1', 's'] + list(sim.channel_units)
    time_s = index / sim.sample_rate_Hz
    if path.suffix.lower() == '.csv':
        with open(path, 'w', encoding='utf-8', newline='\n') as stream:
            stream.write(','.join(names) + '\n')
            np.savetxt(stream, np.column_stack([index, time_s, out.T]), delimiter=',',
                       fmt=['%d', TIME_FORMAT] + [VALUE_FORMAT] * out.shape[0])
        return
    np.save(path, np.column_stack([index.astype(float), time_s, out.T]))
    sidecar = {'file': path.name, 'layout': '(samples, columns) float64', 'columns': names,
               'units': units, 'sample_rate_Hz': sim.sample_rate_Hz, **settings}
    with open(path.with_suffix('.json'), 'w', encoding='utf-8') as stream:
        json.dump(sidecar, stream, indent=2)
        stream.write('\n')


def main(argv: Optional[List[str]] = None) -> int:
    """
    Run the command.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        0 on success, 2 on a usage, configuration or file error.
    """
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:          # argparse already printed the message
        return int(exc.code or 0)
    try:
        if args.output.suffix.lower() not in ('.csv', '.npy'):
            raise ValueError(f'output must end in .csv or .npy, got {args.output}')
        params = BalanceParameters.load_yaml(args.config) if args.config else BalanceParameters()
        u, index, file_rate = read_excitation(args.excitation)
        rate = args.sample_rate_Hz or file_rate or DEFAULT_SAMPLE_RATE_HZ
        sim = Simulator(params, rate, args.seed, substeps=args.substeps, hold=args.hold,
                        noise=not args.no_noise, quantisation=not args.no_quantisation,
                        load_mass_kg=args.load_mass_kg,
                        load_changer_coupled=args.load_changer_coupled)
        if args.add_hold_setpoints:
            u = u + sim.hold_setpoints_V[:, None]
        if index is None:
            index = np.arange(u.shape[1], dtype=np.int64)
        out = sim.step_block(u)
        settings = {'seed': sim.seed, 'noise': sim.noise, 'quantisation': sim.quantisation,
                    'hold': sim.hold, 'substeps': sim.substeps,
                    'load_mass_kg': sim.load_mass_kg,
                    'load_changer_coupled': sim.load_changer_coupled,
                    'config': args.config or 'built-in defaults',
                    'excitation': str(args.excitation),
                    'hold_setpoints_added': bool(args.add_hold_setpoints)}
        write_output(args.output, sim, index, out, settings)
    except (ValueError, OSError, RuntimeError) as exc:
        print(f'emfc-simulate: error: {exc}', file=sys.stderr)
        return 2
    saturated = np.abs(out[sim.channel_names.index('position_m')]) >= \
        params.converters.sensor_range_m * (1.0 - 1e-9)
    print(f'{args.excitation}: {u.shape[1]} samples at {rate:g} Hz '
          f'({u.shape[1] / rate:g} s), seed {sim.seed}, noise {"on" if sim.noise else "off"}, '
          f'quantisation {"on" if sim.quantisation else "off"}, hold {sim.hold}, '
          f'{sim.substeps} RK4 step(s) per sample')
    print(f'{args.output}: columns sample_index, time_s, ' + ', '.join(sim.channel_names)
          + (f' (+ {args.output.with_suffix(".json")})' if args.output.suffix == '.npy' else ''))
    if saturated.any():
        print(f'warning: the position sensor saturated in {int(saturated.sum())} samples '
              f'(open loop, the balance is soft: use small excitation or '
              f'--add-hold-setpoints)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
