"""
emfc-identify: identify the balance from a recorded bag, offline (no ROS needed).

Reads the measurement stream and the experiment's section table from the bag, runs the
identification pipeline (frequency responses with coherence and uncertainty, transfer
function and modal fit, static characteristics, grey-box fit of the physical parameters)
and writes ``results.yaml``, plots and ``summary.md`` to the output folder.

The options stored in the bag by the run plan are used (``--options`` overrides them key by
key), and the pan load comes from the bag; a bag that does not say what was on the pan needs
``--load-mass-kg``. Exit codes: 0 identified, 1 the identification failed (the report says
why, and is written), 2 bad arguments, an unreadable bag or an unknown pan load.
"""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path
import sys
import time
from typing import Any, List, Optional

import yaml

from emfc_ros.core.safe_yaml import load_yaml_file, one_line, YamlRefused


def _progress(step: str, fraction: float, message: str) -> None:
    print(f'  {step:<12} {100 * fraction:5.1f} %  {message}', flush=True)


def _plot_pool() -> Any:
    """
    Worker processes for the report's figures, started now (None without matplotlib).

    They import matplotlib while this process reads the bag and identifies, draw the
    figures of each step while the next runs, and run the grey-box's probe for a second
    optimum beside its time-domain fit (:mod:`emfc_ros.core.report.background`), as in
    ``emfc-experiment``; the report is the same as drawn here.
    """
    if importlib.util.find_spec('matplotlib') is None:
        return None
    from emfc_ros.core.report.background import PlotPool
    return PlotPool()


def main(argv: Optional[List[str]] = None) -> int:
    """
    Entry point of ``emfc-identify``.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (``sys.argv[1:]`` when None).

    Returns
    -------
    int
        0 on success, 1 if the identification failed, 2 for bad arguments or files.
    """
    parser = argparse.ArgumentParser(prog='emfc-identify',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('bag', help='bag folder (with metadata.yaml)')
    parser.add_argument('-o', '--out', default=None,
                        help='output folder (default: <bag>_identification)')
    parser.add_argument('--options', default=None,
                        help='identification options YAML (a mapping; see '
                             'docs/identification_results.md)')
    parser.add_argument('--namespace', default=None,
                        help='namespace of the streams when the bag holds several')
    parser.add_argument('--load-mass-kg', type=float, default=None,
                        help='mass on the pan during the experiment [kg] (overrides the bag)')
    parser.add_argument('--load-changer-coupled', choices=('true', 'false'), default=None,
                        help="whether the load changer's moving mass rode on the pan "
                             '(overrides the bag)')
    args = parser.parse_args(argv)
    bag = Path(args.bag)
    if not (bag / 'metadata.yaml').is_file():
        print(f'emfc-identify: {bag} is not a bag folder (no metadata.yaml); a bag killed '
              'while recording needs `emfc-bag-repair` first', file=sys.stderr)
        return 2
    options = {}
    if args.options:
        try:
            options = load_yaml_file(args.options) or {}
        except YamlRefused as exc:
            print(f'emfc-identify: {exc}', file=sys.stderr)
            return 2
        except (OSError, yaml.YAMLError) as exc:
            print(f'emfc-identify: cannot read {args.options}: {one_line(exc)}',
                  file=sys.stderr)
            return 2
        if not isinstance(options, dict):
            print(f'emfc-identify: {args.options} must hold a mapping', file=sys.stderr)
            return 2
    if args.load_mass_kg is not None:
        if not (args.load_mass_kg >= 0.0 and args.load_mass_kg < 100.0):
            print(f'emfc-identify: --load-mass-kg must be from 0 to 100 kg, got '
                  f'{args.load_mass_kg}', file=sys.stderr)
            return 2
        options['load_mass_kg'] = args.load_mass_kg
    if args.load_changer_coupled is not None:
        options['load_changer_coupled'] = args.load_changer_coupled == 'true'
    out = Path(args.out) if args.out else bag.with_name(bag.name + '_identification')
    from emfc_ros.core.bag.errors import BagFormatError
    from emfc_ros.core.ident.from_bag import identify_bag, PlantConfigurationError
    from emfc_ros.core.report import write_report
    t0 = time.monotonic()
    pool = _plot_pool()
    try:
        def step_done(step: str, partial: Any) -> None:
            pool.submit_step(step, partial, out)    # drawn while the next step runs

        try:
            result, info = identify_bag(bag, options, args.namespace, progress=_progress,
                                        on_step=step_done if pool is not None else None,
                                        executor=pool.tasks if pool is not None else None)
        except (PlantConfigurationError, BagFormatError) as exc:
            _failure_report(out, exc, bag)
            return 2
        except (ValueError, OSError, KeyError) as exc:
            _failure_report(out, exc, bag)
            return 1
        try:
            write_report(result, out, pool=pool)
        except (ValueError, OSError) as exc:
            print(f'emfc-identify: cannot write the report to {out}: {exc}', file=sys.stderr)
            return 1
    finally:
        if pool is not None:
            pool.close()
    print(f'identified {info["samples"]} samples of {info["namespace"]}/measurements in '
          f'{time.monotonic() - t0:.1f} s; results in {out}/')
    print((out / 'summary.md').read_text())
    if not result.success:
        print('emfc-identify: the identification FAILED: ' + '; '.join(result.failures),
              file=sys.stderr)
        return 1
    return 0


def _failure_report(out: Path, exc: BaseException, bag: Path) -> None:
    """Say why nothing was identified, on stderr and in the report folder."""
    from emfc_ros.core.report.writer import write_failure_report
    reason = str(exc) if not isinstance(exc, KeyError) else f'missing {exc}'
    try:
        summary = write_failure_report(out, reason, str(bag))
    except OSError as err:
        print(f'emfc-identify: cannot write the report to {out}: {err}', file=sys.stderr)
        print(f'emfc-identify: {reason}', file=sys.stderr)
        return
    print(f'emfc-identify: {reason} (this reason is also in {summary})', file=sys.stderr)


if __name__ == '__main__':
    raise SystemExit(main())
