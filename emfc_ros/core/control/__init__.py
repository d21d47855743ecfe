"""
Closed-loop control of the EMFC balance: controller design from a plant frequency response.

No ROS imports.
"""

from emfc_ros.core.control.design import (analyse_loop, ControllerDesign, delay_and_hold_response,
                                          design_controller, DiscreteController, lead_stage,
                                          open_loop_response, pid_stage, plant_from_model)

__all__ = [
    'analyse_loop', 'ControllerDesign', 'delay_and_hold_response', 'design_controller',
    'DiscreteController', 'lead_stage', 'open_loop_response', 'pid_stage', 'plant_from_model',
]
