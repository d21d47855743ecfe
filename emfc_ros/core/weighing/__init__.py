"""
Weighing with the EMFC balance: compensation force, calibration, readings, dynamic estimate.

No ROS imports; everything works on plain numpy arrays. See ``docs/weighing.md``.
"""

from emfc_ros.core.weighing.calibration import (nominal_sensitivity_kg_per_N,
                                                WeighingCalibration)
from emfc_ros.core.weighing.compensation import compensation_force_N
from emfc_ros.core.weighing.dynamic import (DEFAULT_FORCE_RANDOM_WALK_N_PER_SQRT_S,
                                            DynamicEstimate, DynamicWeigher)
from emfc_ros.core.weighing.errors import WeighingError
from emfc_ros.core.weighing.profiles import (check_weigher_pulse, load_changer_setpoints_V,
                                             parse_load_schedule, step, trapezoid)
from emfc_ros.core.weighing.reading import (DEFAULT_STABILITY_THRESHOLD_KG, Reading,
                                            ReadingFilter, settled_reading, window_statistics)

__all__ = [
    'check_weigher_pulse', 'compensation_force_N', 'DEFAULT_FORCE_RANDOM_WALK_N_PER_SQRT_S',
    'DEFAULT_STABILITY_THRESHOLD_KG', 'DynamicEstimate', 'DynamicWeigher',
    'load_changer_setpoints_V', 'nominal_sensitivity_kg_per_N', 'parse_load_schedule',
    'Reading', 'ReadingFilter',
    'settled_reading', 'step', 'trapezoid', 'WeighingCalibration', 'WeighingError',
    'window_statistics',
]
