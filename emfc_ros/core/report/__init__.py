"""
Identification reports: ``results.yaml``, exports, PNG plots, ``summary.md`` (no ROS).

:func:`write_report` writes what :func:`emfc_ros.core.ident.pipeline.identify` found into a
folder a person can open. Plots need matplotlib (Agg backend); without it they are skipped and
the summary says so.
"""

from emfc_ros.core.lazy_names import lazy_getattr

#: Public names and the submodule that holds each: imported on first use (PEP 562), so that
#: the experiment runner can start its plot workers (:mod:`~emfc_ros.core.report.background`)
#: without importing scipy and the identification modules first.
_LAZY = {'models_dict': 'exports', 'read_frf_csv': 'exports', 'read_frf_npz': 'exports',
         'write_exports': 'exports', 'matplotlib_available': 'plots', 'plot_bode': 'plots',
         'plot_coherence': 'plots', 'plot_pole_zero': 'plots', 'plot_residuals': 'plots',
         'plot_static_fit': 'plots', 'plot_time_series': 'plots',
         'residual_analysis': 'plots', 'summary_markdown': 'summary',
         'write_report': 'writer'}


__getattr__ = lazy_getattr(__name__, _LAZY, globals())


__all__ = ['matplotlib_available', 'models_dict', 'plot_bode', 'plot_coherence',
           'plot_pole_zero', 'plot_residuals', 'plot_static_fit', 'plot_time_series',
           'read_frf_csv', 'read_frf_npz', 'residual_analysis', 'summary_markdown',
           'write_exports', 'write_report']
