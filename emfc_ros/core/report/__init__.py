"""
Identification reports: ``results.yaml``, exports, PNG plots, ``summary.md`` (no ROS).

:func:`write_report` writes what :func:`emfc_ros.core.ident.pipeline.identify` found into a
folder a person can open. Plots need matplotlib (Agg backend); without it they are skipped and
the summary says so.
"""

from emfc_ros.core.report.exports import (models_dict, read_frf_csv, read_frf_npz,
                                          write_exports)
from emfc_ros.core.report.plots import (matplotlib_available, plot_bode, plot_coherence,
                                        plot_pole_zero, plot_residuals, plot_static_fit,
                                        plot_time_series, residual_analysis)
from emfc_ros.core.report.summary import summary_markdown
from emfc_ros.core.report.writer import write_report

__all__ = ['matplotlib_available', 'models_dict', 'plot_bode', 'plot_coherence',
           'plot_pole_zero', 'plot_residuals', 'plot_static_fit', 'plot_time_series',
           'read_frf_csv', 'read_frf_npz', 'residual_analysis', 'summary_markdown',
           'write_exports', 'write_report']
