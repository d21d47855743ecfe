"""
Stated standard uncertainties of what the identification takes as known (GUM type B).

The identification fits the mechanics through the characteristics of the balance's file: the
sensor characteristic converts volts to metres, the amplifier curves, the DAC and the motor
and load-changer constants convert setpoints to forces, the lever lengths and the load
changer's mass are fixed, the pan load is told. None of these is exact for a real unit; an
error in any of them moves the identified numbers without making the fit worse (a sensor 3 %
off scales every stiffness, damping and inertia by 3 %). :class:`StatedUncertainties` holds
their standard uncertainties (the balance file's optional ``uncertainties`` section);
:mod:`emfc_ros.core.ident.systematic` propagates them to every identified number.

The defaults are the project's assumptions for a unit of the paper's balance type whose file
holds the type's characteristics, not a calibration of the unit (the paper states no
tolerances): replace them with the values of the unit's calibration certificates. Each
default, its reasoning and where to find the unit's own value is in ``docs/identification.md``
("Systematic uncertainties").
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any, Dict, Tuple


def _u(default: float, maximum: float) -> Any:
    return field(default=default, metadata={'min': 0.0, 'max': maximum, 'exclusive': False,
                                            'optional': True})


@dataclass(frozen=True)
class StatedUncertainties:
    """
    Standard uncertainties (k = 1) of the inputs the identification takes as known.

    Relative ones (``*_relative``) are fractions of the value (0.02 = 2 %); the others in the
    unit their name ends with. 0 takes an input as exact.

    Attributes
    ----------
    sensor_gain_relative : float
        Gain (sensitivity) of the position sensor characteristic (0.02: a unit's sensor
        differs from the type's characteristic by a few percent).
    adc_gain_relative : float
        Gain of the ADC channel reading the sensor (5e-4: a 16-bit converter's gain error).
    motor_coefficient_relative : float
        Force constant of the balance coil (0.01).
    coil_amplifier_gain_relative : float
        Gain of the coil amplifier's curve (0.005).
    coil_dac_gain_relative : float
        Gain of the DAC channel driving the coil amplifier (5e-4).
    load_changer_force_relative : float
        Force constant of the load changer (0.02).
    load_changer_amplifier_gain_relative : float
        Gain of the load changer amplifier's curve (0.005).
    load_changer_dac_gain_relative : float
        Gain of the DAC channel driving the load changer amplifier (5e-4).
    lever_length_m : float
        Each of the lever lengths ``l1_m``, ``l2_m``, ``l3_m`` [m] (1e-4 m: a drawing's
        tolerance; independent).
    load_changer_mass_relative : float
        Moving mass of the load changer (0.05, as ``greybox.mass_relative_uncertainty``).
    load_mass_relative : float
        The pan load the identification is told (1e-4: mass pieces of a weighing set, far
        better in practice; a wrong load is a blunder the mass check is there for).
    current_monitor_gain_relative : float
        Scale of an amplifier's current monitor with its ADC channel (0.002: a monitor shunt
        and a 16-bit converter). Used instead of the amplifier's and its DAC's gain when the
        amplifier curve is identified from a staircase.
    """

    sensor_gain_relative: float = _u(0.02, 1.0)
    adc_gain_relative: float = _u(5.0e-4, 1.0)
    motor_coefficient_relative: float = _u(0.01, 1.0)
    coil_amplifier_gain_relative: float = _u(0.005, 1.0)
    coil_dac_gain_relative: float = _u(5.0e-4, 1.0)
    load_changer_force_relative: float = _u(0.02, 1.0)
    load_changer_amplifier_gain_relative: float = _u(0.005, 1.0)
    load_changer_dac_gain_relative: float = _u(5.0e-4, 1.0)
    lever_length_m: float = _u(1.0e-4, 0.1)
    load_changer_mass_relative: float = _u(0.05, 1.0)
    load_mass_relative: float = _u(1.0e-4, 1.0)
    current_monitor_gain_relative: float = _u(0.002, 1.0)


#: What each stated uncertainty acts on, for the propagation: the effect it shares with others
#: (they are independent inputs, each adding its own variance) and the unit its value is in.
#: Effects: ``position_scale`` (the measured position scales), ``coil_force_scale`` and
#: ``pan_force_scale`` (an input force scales), a mechanical parameter by name, or
#: ``load_mass`` (the told pan load).
EFFECTS: Dict[str, Tuple[Tuple[str, ...], str]] = {
    'sensor_gain_relative': (('position_scale',), '1'),
    'adc_gain_relative': (('position_scale',), '1'),
    'motor_coefficient_relative': (('coil_force_scale',), '1'),
    'coil_amplifier_gain_relative': (('coil_force_scale',), '1'),
    'coil_dac_gain_relative': (('coil_force_scale',), '1'),
    'load_changer_force_relative': (('pan_force_scale',), '1'),
    'load_changer_amplifier_gain_relative': (('pan_force_scale',), '1'),
    'load_changer_dac_gain_relative': (('pan_force_scale',), '1'),
    'lever_length_m': (('l1_m', 'l2_m', 'l3_m'), 'm'),
    'load_changer_mass_relative': (('load_changer_mass_kg',), '1'),
    'load_mass_relative': (('load_mass',), '1'),
    'current_monitor_gain_relative': ((), '1'),      # identified amplifiers only
}


def uncertainty_names() -> Tuple[str, ...]:
    """
    The keys of the ``uncertainties`` section.

    Returns
    -------
    tuple of str
        Field names of :class:`StatedUncertainties`.
    """
    return tuple(f.name for f in fields(StatedUncertainties))
