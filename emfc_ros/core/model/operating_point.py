"""
Static equilibria of the nonlinear mechanics.

The compensation force that holds the lever end at a position, the rest angles, and the
open-loop rest position for a given coil force.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Optional, Sequence

import numpy as np

from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.mechanics import (generalised_forces, gravity_vector, input_matrix,
                                           lever_position_m, stiffness_matrix,
                                           tangent_stiffness)
from emfc_ros.core.model.parameters import MechanicalParameters

_XTOL = 1.0e-15


@dataclass(frozen=True)
class OperatingPoint:
    """
    A state of rest of the balance and the inputs holding it there.

    Attributes
    ----------
    mechanics : MechanicalParameters
        The (loaded) mechanics this point belongs to; linearise with these.
    q_rad : tuple of float
        Beam angles ``(q1, q2)`` at rest [rad].
    F_c_N : float
        Coil force at the lever end [N], positive upward (``F_off_N`` acts in addition).
    F_p_N : float
        External pan force [N], positive downward (in addition to the pan masses' weight).
    """

    mechanics: MechanicalParameters
    q_rad: tuple
    F_c_N: float
    F_p_N: float

    @property
    def x(self) -> np.ndarray:
        """State ``[q1, q2, 0, 0]`` [rad, rad/s]."""
        return np.array([self.q_rad[0], self.q_rad[1], 0.0, 0.0])

    @property
    def u(self) -> np.ndarray:
        """Inputs ``[F_c, F_p]`` [N]."""
        return np.array([self.F_c_N, self.F_p_N])

    @property
    def y_m(self) -> float:
        """Lever-end position at rest [m]."""
        return lever_position_m(np.asarray(self.q_rad), self.mechanics)


def static_residual(q: np.ndarray, F_c: float, F_p: float,
                    p: MechanicalParameters) -> np.ndarray:
    """
    Compute the static torque balance ``Q(q, u) - G(q) - K q`` (zero at rest).

    Parameters
    ----------
    q : ndarray, shape (2,)
        Beam angles [rad].
    F_c, F_p : float
        Coil force [N] (up) and external pan force [N] (down).
    p : MechanicalParameters
        The mechanics.

    Returns
    -------
    ndarray, shape (2,)
        Residual generalised force [N m].
    """
    q = np.asarray(q, dtype=float)
    return generalised_forces(q, F_c, F_p, p) - gravity_vector(q, p) - stiffness_matrix(p) @ q


def _prepare(p: MechanicalParameters, load_mass_kg: float, load_changer_coupled: bool,
             F_off_N: Optional[float]) -> MechanicalParameters:
    mech = loaded(p, load_mass_kg, load_changer_coupled)
    if F_off_N is not None:
        mech = replace(mech, F_off_N=float(F_off_N))
    return mech


def _solve(fun, jac, x0: np.ndarray, what: str) -> np.ndarray:
    from scipy import optimize      # here: importing scipy.optimize takes about 0.5 s
    sol = optimize.root(fun, x0, jac=jac, method='hybr', options={'xtol': _XTOL})
    x = sol.x
    # One Newton polish step: hybr stops at its relative tolerance, Newton reaches round-off.
    x = x - np.linalg.solve(jac(x), fun(x))
    if not np.all(np.isfinite(x)) or np.max(np.abs(fun(x))) > 1.0e-9 * (
            1.0 + np.max(np.abs(fun(x0)))):
        raise RuntimeError(f'{what}: no static equilibrium found ({sol.message})')
    return x


def hold_at(p: MechanicalParameters, q_rad: Sequence[float] = (0.0, 0.0)) -> OperatingPoint:
    """
    Find the coil and pan forces that hold the beams at rest at given angles.

    With ``q = 0`` this is the operating point of the notes' linear model.

    Parameters
    ----------
    p : MechanicalParameters
        The (loaded) mechanics.
    q_rad : sequence of float
        Beam angles ``(q1, q2)`` [rad].

    Returns
    -------
    OperatingPoint
        The point with ``F_c_N`` and ``F_p_N`` (which may be negative, i.e. an upward pan force).
    """
    q = np.asarray(q_rad, dtype=float)
    need = gravity_vector(q, p) + stiffness_matrix(p) @ q
    f_end, f_pan = np.linalg.solve(input_matrix(q, p), need)
    return OperatingPoint(p, (float(q[0]), float(q[1])), float(f_end - p.F_off_N),
                          float(f_pan))


def equilibrium(p: MechanicalParameters, load_mass_kg: float = 0.0,
                load_changer_coupled: bool = False, F_off_N: Optional[float] = None,
                F_p_N: float = 0.0, y_m: float = 0.0) -> OperatingPoint:
    """
    Find the compensated state: coil force and rest angles that hold the lever end at ``y_m``.

    Parameters
    ----------
    p : MechanicalParameters
        The mechanics of the empty, uncoupled balance.
    load_mass_kg : float
        Mass on the pan [kg] (adds to the pan mass and its weight).
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan.
    F_off_N : float, optional
        Offset force at the lever end [N]; ``None`` keeps ``p.F_off_N``.
    F_p_N : float
        External pan force [N], positive downward (e.g. a load-changer force).
    y_m : float
        Lever-end position to hold [m] (0: the controller's set point).

    Returns
    -------
    OperatingPoint
        The point, with ``mechanics`` the loaded parameters.

    Raises
    ------
    RuntimeError
        If no equilibrium is found.
    """
    mech = _prepare(p, load_mass_kg, load_changer_coupled, F_off_N)
    F_p = float(F_p_N)

    def fun(z: np.ndarray) -> np.ndarray:
        q = z[:2]
        return np.concatenate([static_residual(q, z[2], F_p, mech),
                               [lever_position_m(q, mech) - y_m]])

    def jac(z: np.ndarray) -> np.ndarray:
        q = z[:2]
        out = np.zeros((3, 3))
        out[:2, :2] = -tangent_stiffness(q, z[2], F_p, mech)
        out[:2, 2] = input_matrix(q, mech)[:, 0]
        out[2, :2] = [mech.l2_m * np.cos(q[0]), mech.l3_m * np.cos(q[1])]
        return out

    start = hold_at(mech, (0.0, 0.0))
    z = _solve(fun, jac, np.array([0.0, 0.0, start.F_c_N]), 'equilibrium')
    return OperatingPoint(mech, (float(z[0]), float(z[1])), float(z[2]), F_p)


def rest_position(p: MechanicalParameters, F_c_N: float, load_mass_kg: float = 0.0,
                  load_changer_coupled: bool = False, F_off_N: Optional[float] = None,
                  F_p_N: float = 0.0) -> OperatingPoint:
    """
    Open-loop rest position for a given coil force (no mechanical stops).

    Parameters
    ----------
    p : MechanicalParameters
        The mechanics of the empty, uncoupled balance.
    F_c_N : float
        Coil force [N], positive upward.
    load_mass_kg : float
        Mass on the pan [kg].
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan.
    F_off_N : float, optional
        Offset force at the lever end [N]; ``None`` keeps ``p.F_off_N``.
    F_p_N : float
        External pan force [N], positive downward.

    Returns
    -------
    OperatingPoint
        The rest point; its ``y_m`` is the lever-end position.

    Raises
    ------
    RuntimeError
        If no equilibrium is found.
    """
    mech = _prepare(p, load_mass_kg, load_changer_coupled, F_off_N)
    F_c, F_p = float(F_c_N), float(F_p_N)

    def fun(q: np.ndarray) -> np.ndarray:
        return static_residual(q, F_c, F_p, mech)

    def jac(q: np.ndarray) -> np.ndarray:
        return -tangent_stiffness(q, F_c, F_p, mech)

    q0 = np.linalg.solve(tangent_stiffness(np.zeros(2), F_c, F_p, mech),
                         fun(np.zeros(2)))
    q = _solve(fun, jac, q0, 'rest position')
    return OperatingPoint(mech, (float(q[0]), float(q[1])), F_c, F_p)
