"""
Identification reports: ``results.yaml``, PNG plots and ``summary.md`` (no ROS imports).

:func:`write_report` writes what :func:`emfc_ros.core.ident.pipeline.identify` found into a
folder a person can open. Plots need matplotlib (Agg backend); without it they are skipped and
the summary says so.
"""

from emfc_ros.core.report.plots import matplotlib_available, plot_bode, plot_time_series
from emfc_ros.core.report.summary import summary_markdown
from emfc_ros.core.report.writer import write_report

__all__ = ['matplotlib_available', 'plot_bode', 'plot_time_series', 'summary_markdown',
           'write_report']
