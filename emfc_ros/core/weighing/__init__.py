"""
Weighing with the EMFC balance: compensation force, calibration, readings, dynamic estimate.

No ROS imports; everything works on plain numpy arrays. See ``docs/weighing.md``.
"""

from emfc_ros.core.lazy_names import lazy_getattr

#: Public names and the submodule that holds each: imported on first use (PEP 562), so that
#: a node that only parses a load schedule does not import scipy.signal behind the dynamic
#: weigher (a second of start-up).
_LAZY = {
    'nominal_sensitivity_kg_per_N': 'calibration', 'WeighingCalibration': 'calibration',
    'compensation_force_N': 'compensation',
    'DEFAULT_FORCE_RANDOM_WALK_N_PER_SQRT_S': 'dynamic', 'DynamicEstimate': 'dynamic',
    'DynamicWeigher': 'dynamic', 'WeighingError': 'errors',
    'check_weigher_pulse': 'profiles', 'load_changer_setpoints_V': 'profiles',
    'parse_load_schedule': 'profiles', 'step': 'profiles', 'trapezoid': 'profiles',
    'DEFAULT_STABILITY_THRESHOLD_KG': 'reading', 'Reading': 'reading',
    'ReadingFilter': 'reading', 'settled_reading': 'reading', 'window_statistics': 'reading',
}

__getattr__ = lazy_getattr(__name__, _LAZY, globals())

__all__ = [
    'check_weigher_pulse', 'compensation_force_N', 'DEFAULT_FORCE_RANDOM_WALK_N_PER_SQRT_S',
    'DEFAULT_STABILITY_THRESHOLD_KG', 'DynamicEstimate', 'DynamicWeigher',
    'load_changer_setpoints_V', 'nominal_sensitivity_kg_per_N', 'parse_load_schedule',
    'Reading', 'ReadingFilter',
    'settled_reading', 'step', 'trapezoid', 'WeighingCalibration', 'WeighingError',
    'window_statistics',
]
