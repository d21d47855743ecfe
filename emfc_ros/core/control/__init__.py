"""
Closed-loop control of the EMFC balance: controller design from a plant frequency response.

No ROS imports. The public names are imported on first use (PEP 562), so that a node that
only reads the loop configuration (:mod:`~emfc_ros.core.control.loop_config`) does not import
scipy.signal behind the design.
"""

from emfc_ros.core.lazy_names import lazy_getattr

_LAZY = {name: 'design' for name in (
    'analyse_loop', 'ControllerDesign', 'delay_and_hold_response', 'design_controller',
    'DiscreteController', 'lead_stage', 'open_loop_response', 'pid_stage', 'plant_from_model')}

__getattr__ = lazy_getattr(__name__, _LAZY, globals())

__all__ = [
    'analyse_loop', 'ControllerDesign', 'delay_and_hold_response', 'design_controller',
    'DiscreteController', 'lead_stage', 'open_loop_response', 'pid_stage', 'plant_from_model',
]
