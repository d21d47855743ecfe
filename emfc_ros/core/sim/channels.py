"""
Names and units of the simulator's output channels (the measurement stream of the ROS node).

Each name ends in its unit; the order is the row order of :meth:`Simulator.step_block`'s result.
"""

from __future__ import annotations

from typing import Tuple

#: Measured channels: name, unit, meaning.
MEASURED = (
    ('coil_setpoint_V', 'V', 'coil amplifier setpoint as applied (after the DAC)'),
    ('load_changer_setpoint_V', 'V', 'load-changer amplifier setpoint as applied (after the DAC)'),
    ('coil_current_A', 'A', 'coil current from the current monitor through the ADC'),
    ('load_changer_current_A', 'A', 'load-changer current from its monitor through the ADC'),
    ('sensor_V', 'V', 'position sensor voltage through the ADC'),
    ('position_m', 'm', 'lever-end position from sensor_V through the inverse characteristic'),
    ('coil_force_N', 'N', 'coil force k(position_m) * coil_current_A, positive upward'),
    ('load_changer_force_N', 'N', 'load-changer force F(load_changer_current_A) on the pan, '
                                  'positive downward'),
)

#: Reference channels (extra instruments of the paper; true values, no noise or converters).
REFERENCE = (
    ('position_true_m', 'm', 'true lever-end position (interferometer)'),
    ('pan_force_N', 'N', 'true load-changer force on the pan, positive downward'),
    ('coil_force_true_N', 'N', 'true coil force at the lever end, positive upward'),
)


def channel_names(reference: bool = True) -> Tuple[str, ...]:
    """
    Names of the output channels.

    Parameters
    ----------
    reference : bool
        Include the reference channels.

    Returns
    -------
    tuple of str
        Names, in row order.
    """
    return tuple(c[0] for c in MEASURED + (REFERENCE if reference else ()))


def channel_units(reference: bool = True) -> Tuple[str, ...]:
    """
    Units of the output channels.

    Parameters
    ----------
    reference : bool
        Include the reference channels.

    Returns
    -------
    tuple of str
        SI units, in row order.
    """
    return tuple(c[1] for c in MEASURED + (REFERENCE if reference else ()))
