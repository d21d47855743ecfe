"""
The hold point: the setpoints that keep the balance at rest with the lever end at zero.

The simulator starts there by default, and "zero excitation" means holding these setpoints.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from emfc_ros.core.model.operating_point import equilibrium, OperatingPoint
from emfc_ros.core.model.parameters import BalanceParameters


@dataclass(frozen=True)
class HoldPoint:
    """
    A state of rest and the amplifier setpoints that hold it.

    Attributes
    ----------
    operating_point : OperatingPoint
        Rest state (``y = 0``) with its loaded mechanics and forces.
    setpoints_V : ndarray, shape (2,)
        Coil and load-changer setpoints [V] (unquantised).
    currents_A : ndarray, shape (2,)
        Coil and load-changer currents [A].
    """

    operating_point: OperatingPoint
    setpoints_V: np.ndarray
    currents_A: np.ndarray

    @property
    def x(self) -> np.ndarray:
        """State ``[q1, q2, 0, 0]`` [rad, rad/s]."""
        return self.operating_point.x


def hold_point(params: BalanceParameters, load_mass_kg: float = 0.0,
               load_changer_coupled: bool = False, load_changer_V: float = 0.0) -> HoldPoint:
    """
    Find the coil setpoint that holds the lever end at ``y = 0`` for a load-changer setpoint.

    Parameters
    ----------
    params : BalanceParameters
        The parameters.
    load_mass_kg : float
        Mass on the pan [kg].
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan.
    load_changer_V : float
        Load-changer setpoint [V] (its force on the pan enters the balance).

    Returns
    -------
    HoldPoint
        State and setpoints.

    Raises
    ------
    ValueError
        If the needed coil current exceeds the amplifier's limit.
    """
    conv = params.converters
    i_lc = float(np.clip(params.load_changer_amplifier.current_A(float(load_changer_V)),
                         -conv.load_changer_current_limit_A,
                         conv.load_changer_current_limit_A))
    f_p = float(params.load_changer.force_N(i_lc))
    op = equilibrium(params.mechanics, load_mass_kg, load_changer_coupled, F_p_N=f_p)
    i_coil = float(params.motor.current_A(op.F_c_N, 0.0))
    if abs(i_coil) > conv.coil_current_limit_A:
        raise ValueError(f'load_mass_kg: holding {load_mass_kg!r} kg needs a coil current of '
                         f'{i_coil:.4g} A, beyond the limit of {conv.coil_current_limit_A} A')
    u_coil = float(params.coil_amplifier.voltage_V(i_coil))
    return HoldPoint(op, np.array([u_coil, float(load_changer_V)]), np.array([i_coil, i_lc]))
