"""
Write an identification report folder: ``results.yaml``, exports, PNG plots, ``summary.md``.

The folder is what a person opens after an identification run (design brief section 5).
"""

from __future__ import annotations

from pathlib import Path
import re
from typing import Any, Dict, List, Union

import yaml

from emfc_ros.core.report.exports import write_exports
from emfc_ros.core.report.plots import (matplotlib_available, plot_bode, plot_coherence,
                                        plot_pole_zero, plot_residuals, plot_static_fit,
                                        plot_time_series, residual_analysis)
from emfc_ros.core.report.summary import summary_markdown


def _file_name(text: str) -> str:
    return re.sub(r'[^A-Za-z0-9_.-]+', '_', text)


def write_report(result: Any, out_dir: Union[str, Path], plots: bool = True
                 ) -> Dict[str, List[Path]]:
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
    results = out / 'results.yaml'
    with open(results, 'w', encoding='utf-8') as stream:
        yaml.safe_dump(result.to_dict(), stream, sort_keys=False, default_flow_style=None,
                       width=100)
    written['results'].append(results)
    written['exports'] = write_exports(result, out)
    notes = []
    if plots and not matplotlib_available():
        notes.append('matplotlib is not installed: plots were skipped')
    elif plots:
        written['plots'] = _plots(result, out)
    else:
        notes.append('plots were not requested')
    summary = out / 'summary.md'
    summary.write_text(summary_markdown(result, [p.name for p in written['plots']], notes,
                                        [p.name for p in written['exports']]),
                       encoding='utf-8')
    written['summary'].append(summary)
    return written


def _plots(result: Any, out: Path) -> List[Path]:
    drawn = []
    for frf in result.frfs:
        stem = _file_name(frf.name)
        drawn.append(plot_bode(frf, out / f'bode_{stem}.png'))
        drawn.append(plot_coherence(frf, out / f'coherence_{stem}.png'))
    if result.greybox is not None:
        for name in result.greybox.time_s:
            stem = _file_name(name)
            drawn.append(plot_time_series(result.greybox, name, out / f'time_{stem}.png'))
            analysis = residual_analysis(result.greybox, name)
            if analysis is not None:
                drawn.append(plot_residuals(analysis, out / f'resid_{stem}.png'))
    if result.static is not None:
        for key, fit in result.static.fits.items():
            points = getattr(result.static, 'points', {}).get(key)
            if points is not None:
                drawn.append(plot_static_fit(key, fit, points[0], points[1],
                                             out / f'static_{_file_name(key)}.png'))
    pz = plot_pole_zero(result, out / 'pole_zero.png')
    if pz is not None:
        drawn.append(pz)
    return drawn
