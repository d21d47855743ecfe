"""
Physical model of the EMFC balance: parameters, peripherals, two-beam mechanics, linearisation.

No ROS imports. See ``docs/model.md`` for the equations and conventions.
"""

from emfc_ros.core.model.linear import (finite_difference_jacobians, FrequencyResponse,
                                        jacobians, linearise, LinearModel, Root)
from emfc_ros.core.model.load import loaded, pan_mass_kg
from emfc_ros.core.model.mechanics import lever_position_m, state_derivative
from emfc_ros.core.model.operating_point import (equilibrium, hold_at, OperatingPoint,
                                                 rest_position)
from emfc_ros.core.model.parameters import (BalanceParameters, ConverterParameters,
                                            MechanicalParameters)
from emfc_ros.core.model.peripherals import (Amplifier, LoadChanger, MotorCoefficient,
                                             PositionSensor)

__all__ = [
    'Amplifier', 'BalanceParameters', 'ConverterParameters', 'equilibrium',
    'finite_difference_jacobians', 'FrequencyResponse', 'hold_at', 'jacobians',
    'lever_position_m', 'linearise', 'LinearModel', 'LoadChanger', 'loaded',
    'MechanicalParameters', 'MotorCoefficient',
    'OperatingPoint', 'pan_mass_kg', 'PositionSensor', 'rest_position', 'Root',
    'state_derivative',
]
