"""
Write an identification report folder: ``results.yaml``, exports, PNG plots, ``summary.md``.

The folder is what a person opens after an identification run (design brief section 5).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, List, Optional, Union

import yaml

from emfc_ros.core.report.background import draw, PlotPool, report_jobs, slowest_first
from emfc_ros.core.report.exports import write_exports
from emfc_ros.core.report.plots import matplotlib_available
from emfc_ros.core.report.summary import summary_markdown

#: libyaml's emitter when PyYAML has it (same output, several times faster).
_DUMPER = getattr(yaml, 'CSafeDumper', yaml.SafeDumper)


def write_report(result: Any, out_dir: Union[str, Path], plots: bool = True,
                 pool: Optional[PlotPool] = None) -> Dict[str, List[Path]]:
    """
    Write the results, exports, plots and summary of an identification into a folder.

    Files (``docs/identification_results.md`` lists every field and unit):

    * ``results.yaml`` (:meth:`IdentificationResult.to_dict`) and ``summary.md``;
    * per FRF ``frf_<frf>.csv``, ``frf_<frf>.npz`` and ``frf_<frf>.mat`` (full resolution,
      coherence, uncertainty; the ``.mat`` named as MATLAB ``idfrd``), and ``models.yaml``,
      ``models.mat`` (transfer-function fits and the grey-box linearisation as coefficients
      and state space), see :mod:`emfc_ros.core.report.exports`;
    * plots: ``bode_<frf>.png`` and ``coherence_<frf>.png`` per FRF, ``time_<section>.png``
      and ``resid_<section>.png`` per grey-box section, ``static_<characteristic>.png`` per
      static fit and ``pole_zero.png``. Without matplotlib the plots are skipped and the
      summary says so.

    Parameters
    ----------
    result : IdentificationResult
        The pipeline's result.
    out_dir : str or Path
        Folder (created if needed).
    plots : bool
        Draw the plots.
    pool : PlotPool, optional
        Draw them in these worker processes while this one writes the other files
        (:mod:`~emfc_ros.core.report.background`); default in this process.

    Returns
    -------
    dict
        ``{'results': [...], 'exports': [...], 'plots': [...], 'summary': [...]}`` paths
        written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: Dict[str, List[Path]] = {'results': [], 'exports': [], 'plots': [],
                                      'summary': []}
    notes = []
    jobs = report_jobs(result, out) if plots else []
    if pool is not None and jobs:
        # drawn while the files below are written, the slowest first
        pool.submit(slowest_first(jobs))
    results = out / 'results.yaml'
    with open(results, 'w', encoding='utf-8') as stream:
        yaml.dump(result.to_dict(), stream, Dumper=_DUMPER, sort_keys=False,
                  default_flow_style=None, width=100)
    written['results'].append(results)
    written['exports'] = write_exports(result, out)
    if plots and pool is not None:
        written['plots'] = pool.wait([job.path for job in jobs])
        notes += [f'plot failed: {error}' for error in pool.errors]
    elif plots and not matplotlib_available():
        notes.append('matplotlib is not installed: plots were skipped')
    elif plots:
        written['plots'] = [p for p in (draw(job) for job in jobs) if p is not None]
    else:
        notes.append('plots were not requested')
    summary = out / 'summary.md'
    summary.write_text(summary_markdown(result, [p.name for p in written['plots']], notes,
                                        [p.name for p in written['exports']]),
                       encoding='utf-8')
    written['summary'].append(summary)
    return written


def write_failure_report(out_dir: Union[str, Path], reason: str, source: str) -> Path:
    """
    The report of an identification that could not run: the reason, in the usual files.

    ``results.yaml`` has ``status: {success: false, failures: [reason]}`` and the source,
    ``summary.md`` the headline ``Identification FAILED``, so that every exit of
    ``emfc-identify`` leaves a report that says what happened.

    Parameters
    ----------
    out_dir : str or Path
        Folder (created if needed).
    reason : str
        Why nothing was identified.
    source : str
        What was to be identified (the bag).

    Returns
    -------
    pathlib.Path
        The summary written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    with open(out / 'results.yaml', 'w', encoding='utf-8') as stream:
        yaml.dump({'status': {'success': False, 'failures': [reason]}, 'source': source},
                  stream, Dumper=_DUMPER, sort_keys=False, width=100)
    summary = out / 'summary.md'
    summary.write_text('# Identification of the EMFC balance\n\n'
                       f'**Identification FAILED**: {reason}\n\n'
                       f'Recording: `{source}`. Nothing was identified; `results.yaml` has '
                       'the same reason.\n', encoding='utf-8')
    return summary
