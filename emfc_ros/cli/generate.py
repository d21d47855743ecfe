"""
emfc-generate: write an experiment's excitation to a CSV or NPY file, offline.

``emfc-generate CONFIG.yaml -o OUT.csv [--first-sample N] [--samples N]`` loads CONFIG (a
plain YAML with ``experiment:`` or a ROS parameters file), generates the samples exactly as
the signal_generator node would, and writes them:

* CSV: header ``sample_index,time_s,<channel>_V,...``, one row per sample;
* NPY: a float64 array of shape (n_channels, n_samples), channel-major like
  ``Experiment.block``; a note on its layout is printed.

It prints one summary line per section. Errors go to stderr with exit code 2.
"""

from __future__ import annotations

import argparse
from pathlib import Path
import sys
from typing import List, Optional

import numpy as np

from emfc_ros.core.signals import Experiment, load_experiment_file

TIME_FORMAT = '%.12f'
VALUE_FORMAT = '%.17g'


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='emfc-generate',
        description='Write the excitation of an experiment configuration to CSV or NPY.')
    parser.add_argument('config', type=Path, help='experiment YAML (plain or ROS params file)')
    parser.add_argument('-o', '--output', type=Path, required=True,
                        help='output file, .csv or .npy')
    parser.add_argument('--first-sample', type=int, default=0,
                        help='index of the first sample to write (default 0)')
    parser.add_argument('--samples', type=int, default=None,
                        help='number of samples (default: to the end of the experiment)')
    return parser


def section_lines(experiment: Experiment, first: int, stop: int,
                  data: np.ndarray) -> List[str]:
    """
    Describe the sections that overlap the written range, one line each.

    Parameters
    ----------
    experiment : Experiment
        The experiment.
    first, stop : int
        Written sample range [first, stop).
    data : numpy.ndarray
        The written samples, shape (n_channels, stop - first).

    Returns
    -------
    list of str
        The lines.
    """
    lines = []
    fs = experiment.sample_rate_Hz
    count = len(experiment.sections)
    for i, section in enumerate(experiment.sections):
        a = int(experiment.boundaries[i])
        b = int(experiment.boundaries[i + 1])
        lo, hi = max(a, first), min(b, stop)
        if lo >= hi:
            continue
        parts = []
        for row, channel in enumerate(experiment.channels):
            plan = section.channels.get(channel)
            x = data[row, lo - first:hi - first]
            what = ('+'.join(f'{name}({type(sig).__name__})'
                             for name, sig in sorted(plan.signals.items())) or 'no signals'
                    if plan is not None else 'not driven')
            parts.append(f'{channel}: {what} in [{x.min():.6g}, {x.max():.6g}] V')
        lines.append(f'section {i + 1}/{count} {section.name}: samples [{a}, {b}) '
                     f'{(b - a) / fs:.3f} s, written [{lo}, {hi}); ' + '; '.join(parts))
    if stop > experiment.total_samples:
        lines.append(f'past the end: samples [{max(first, experiment.total_samples)}, {stop}) '
                     f'hold the safe values {experiment.safe_V.tolist()} V')
    return lines


def write_csv(path: Path, experiment: Experiment, first: int, data: np.ndarray) -> None:
    """
    Write samples as CSV with header ``sample_index,time_s,<channel>_V,...``.

    Parameters
    ----------
    path : pathlib.Path
        Output file.
    experiment : Experiment
        The experiment (channel names, sample rate).
    first : int
        Index of the first sample.
    data : numpy.ndarray
        Samples, shape (n_channels, n).
    """
    index = np.arange(first, first + data.shape[1], dtype=np.int64)
    header = ','.join(['sample_index', 'time_s'] + [f'{c}_V' for c in experiment.channels])
    with open(path, 'w', encoding='utf-8', newline='\n') as stream:
        stream.write(header + '\n')
        table = np.column_stack([index, index / experiment.sample_rate_Hz, data.T])
        np.savetxt(stream, table, delimiter=',',
                   fmt=['%d', TIME_FORMAT] + [VALUE_FORMAT] * data.shape[0])


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
        suffix = args.output.suffix.lower()
        if suffix not in ('.csv', '.npy'):
            raise ValueError(f'output must end in .csv or .npy, got {args.output}')
        if args.first_sample < 0:
            raise ValueError(f'--first-sample must be >= 0, got {args.first_sample}')
        experiment = load_experiment_file(args.config)
        first = args.first_sample
        n = max(experiment.total_samples - first, 0) if args.samples is None else args.samples
        if n < 0:
            raise ValueError(f'--samples must be >= 0, got {n}')
        data = experiment.block(first, n)
        if suffix == '.csv':
            write_csv(args.output, experiment, first, data)
        else:
            np.save(args.output, data)
    except (ValueError, OSError) as exc:
        print(f'emfc-generate: error: {exc}', file=sys.stderr)
        return 2
    print(f'{args.config}: {len(experiment.sections)} sections, {experiment.total_samples} '
          f'samples ({experiment.duration_s:g} s) at {experiment.sample_rate_Hz:g} Hz, '
          f'channels {list(experiment.channels)}')
    for line in section_lines(experiment, first, first + n, data):
        print(line)
    if suffix == '.npy':
        print(f'{args.output}: float64 array of shape {data.shape} = (channels, samples), '
              f'rows {[f"{c}_V" for c in experiment.channels]}, column j = sample index '
              f'{first} + j at {experiment.sample_rate_Hz:g} Hz')
    else:
        print(f'{args.output}: {n} rows, columns sample_index, time_s, '
              + ', '.join(f'{c}_V' for c in experiment.channels))
    return 0


if __name__ == '__main__':
    sys.exit(main())
