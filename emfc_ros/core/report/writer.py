"""
Write an identification report folder: ``results.yaml``, PNG plots, ``summary.md``.

The folder is what a person opens after an identification run (design brief section 5).
"""

from __future__ import annotations

from pathlib import Path
import re
from typing import Any, Dict, List, Union

import yaml

from emfc_ros.core.report.plots import matplotlib_available, plot_bode, plot_time_series
from emfc_ros.core.report.summary import summary_markdown


def _file_name(text: str) -> str:
    return re.sub(r'[^A-Za-z0-9_.-]+', '_', text)


def write_report(result: Any, out_dir: Union[str, Path], plots: bool = True
                 ) -> Dict[str, List[Path]]:
    """
    Write the results, plots and summary of an identification into a folder.

    Files: ``results.yaml`` (:meth:`IdentificationResult.to_dict`), ``bode_<frf>.png`` per
    FRF (measured with confidence band, TF fit, grey-box linearisation),
    ``time_<section>.png`` per grey-box section (measured and simulated position) and
    ``summary.md``. Without matplotlib the plots are skipped and the summary says so.

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
        ``{'results': [...], 'plots': [...], 'summary': [...]}`` paths written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written: Dict[str, List[Path]] = {'results': [], 'plots': [], 'summary': []}
    results = out / 'results.yaml'
    with open(results, 'w', encoding='utf-8') as stream:
        yaml.safe_dump(result.to_dict(), stream, sort_keys=False, default_flow_style=None,
                       width=100)
    written['results'].append(results)
    notes = []
    if plots and not matplotlib_available():
        notes.append('matplotlib is not installed: plots were skipped')
    elif plots:
        for frf in result.frfs:
            written['plots'].append(plot_bode(frf, out / f'bode_{_file_name(frf.name)}.png'))
        if result.greybox is not None:
            for name in result.greybox.time_s:
                written['plots'].append(plot_time_series(
                    result.greybox, name, out / f'time_{_file_name(name)}.png'))
    else:
        notes.append('plots were not requested')
    summary = out / 'summary.md'
    summary.write_text(summary_markdown(result, [p.name for p in written['plots']], notes),
                       encoding='utf-8')
    written['summary'].append(summary)
    return written
