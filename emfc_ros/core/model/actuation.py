"""
An effort command as an actuator setpoint: the balance's motor and amplifier inverted.

Used by every node that takes effort commands (the daq_bridge on hardware, the plant
simulator), so that both turn a force into the same coil setpoint.
"""

from __future__ import annotations

from emfc_ros.core.model.parameters import BalanceParameters


def coil_setpoint_for_force_V(params: BalanceParameters, force_N: float,
                              position_m: float) -> float:
    """
    Coil amplifier setpoint that produces a coil force at a lever position.

    Inverts the position-dependent motor coefficient, then the amplifier characteristic.

    Parameters
    ----------
    params : BalanceParameters
        The balance.
    force_N : float
        Wanted coil force at the lever end [N], positive upward.
    position_m : float
        Lever-end position [m].

    Returns
    -------
    float
        Setpoint voltage [V], clamped to the DAC range.
    """
    current_A = float(params.motor.current_A(force_N, position_m))
    limit_A = params.converters.coil_current_limit_A
    current_A = min(max(current_A, -limit_A), limit_A)
    setpoint_V = float(params.coil_amplifier.voltage_V(current_A))
    span = params.converters.dac_range_V
    return min(max(setpoint_V, -span), span)
