"""
Nonlinear two-beam equations of motion of the weighing cell (Lagrange, see ``docs/model.md``).

Generalised coordinates ``q = [q1, q2]`` [rad] are absolute beam angles, counter-clockwise
positive; the state is ``x = [q1, q2, q1', q2']`` (rad, rad/s). Geometry: pivot O at the origin,
pan point at ``-l1 (cos q1, sin q1)``, joint J at ``l2 (cos q1, sin q1)``, lever end (coil) at
``J + l3 (cos q2, sin q2)``; gravity along -z.

Force directions (the notes' ``Bq = [[l2, l1], [l3, 0]]``): all external forces are vertical.
The coil force ``F_c`` and the offset force ``F_off`` act at the lever end, positive upward
(+z, increasing ``y``); the pan force ``F_p`` acts at the pan point, positive downward (-z,
like a weight), so both positive inputs raise the lever end. ``F_p`` is the external force in
addition to the weight of the pan masses (for example the load-changer force); the weight of
every mass of the model, including a load and the coupled load changer on the pan (both part
of ``mp_kg``), is in the gravity vector.

The equations are ``M(q) q'' + C(q, q') q' + G(q) + K q + D q' = Q(q, F_c, F_p)``.
"""

from __future__ import annotations

from typing import Tuple

import numpy as np

from emfc_ros.core.model.parameters import MechanicalParameters


def _coupling(q: np.ndarray, p: MechanicalParameters) -> Tuple[float, float]:
    # M12(phi) with phi = q2 - q1 and its derivative dM12/dphi.
    phi = q[1] - q[0]
    a = p.m3_kg * p.l3_m + p.m2_kg * p.r2_m
    b = p.m2_kg * p.h2_m
    c, s = np.cos(phi), np.sin(phi)
    return p.l2_m * (a * c - b * s), -p.l2_m * (a * s + b * c)


def mass_matrix(q: np.ndarray, p: MechanicalParameters) -> np.ndarray:
    """
    Mass matrix M(q).

    Parameters
    ----------
    q : ndarray, shape (2,)
        Beam angles [rad].
    p : MechanicalParameters
        The mechanics.

    Returns
    -------
    ndarray, shape (2, 2)
        Symmetric positive definite mass matrix [kg m^2].
    """
    m12, _ = _coupling(q, p)
    m11 = p.J1_kgm2 + p.mp_kg * p.l1_m ** 2 + (p.m2_kg + p.m3_kg) * p.l2_m ** 2
    m22 = p.J2_kgm2 + p.m3_kg * p.l3_m ** 2
    return np.array([[m11, m12], [m12, m22]])


def coriolis_matrix(q: np.ndarray, qd: np.ndarray, p: MechanicalParameters) -> np.ndarray:
    """
    Coriolis and centrifugal matrix C(q, q'), such that ``C q'`` is the velocity term.

    Parameters
    ----------
    q : ndarray, shape (2,)
        Beam angles [rad].
    qd : ndarray, shape (2,)
        Angular velocities [rad/s].
    p : MechanicalParameters
        The mechanics.

    Returns
    -------
    ndarray, shape (2, 2)
        ``[[0, M12' q2'], [-M12' q1', 0]]`` [kg m^2/s] with ``M12' = dM12/d(q2 - q1)``;
        ``dM/dt - 2 C`` is skew-symmetric.
    """
    _, dm12 = _coupling(q, p)
    return np.array([[0.0, dm12 * qd[1]], [-dm12 * qd[0], 0.0]])


def gravity_vector(q: np.ndarray, p: MechanicalParameters) -> np.ndarray:
    """
    Gravity torques G(q) = dV_g/dq.

    Parameters
    ----------
    q : ndarray, shape (2,)
        Beam angles [rad].
    p : MechanicalParameters
        The mechanics.

    Returns
    -------
    ndarray, shape (2,)
        Generalised gravity forces [N m].
    """
    g = p.g_m_per_s2
    c1, s1 = np.cos(q[0]), np.sin(q[0])
    c2, s2 = np.cos(q[1]), np.sin(q[1])
    arm1 = (p.m2_kg + p.m3_kg) * p.l2_m - p.mp_kg * p.l1_m
    g1 = g * (p.m1_kg * (p.r1_m * c1 - p.h1_m * s1) + arm1 * c1)
    g2 = g * (p.m2_kg * (p.r2_m * c2 - p.h2_m * s2) + p.m3_kg * p.l3_m * c2)
    return np.array([g1, g2])


def stiffness_matrix(p: MechanicalParameters) -> np.ndarray:
    """
    Flexure stiffness matrix K (pivot on ``q1``, joint J on ``q2 - q1``).

    Parameters
    ----------
    p : MechanicalParameters
        The mechanics.

    Returns
    -------
    ndarray, shape (2, 2)
        ``[[c1 + c2, -c2], [-c2, c2]]`` [N m/rad].
    """
    c1, c2 = p.c1_Nm_per_rad, p.c2_Nm_per_rad
    return np.array([[c1 + c2, -c2], [-c2, c2]])


def damping_matrix(p: MechanicalParameters) -> np.ndarray:
    """
    Flexure damping matrix D (pivot on ``q1'``, joint J on ``q2' - q1'``).

    Parameters
    ----------
    p : MechanicalParameters
        The mechanics.

    Returns
    -------
    ndarray, shape (2, 2)
        ``[[d1 + d2, -d2], [-d2, d2]]`` [N m s/rad].
    """
    d1, d2 = p.d1_Nms_per_rad, p.d2_Nms_per_rad
    return np.array([[d1 + d2, -d2], [-d2, d2]])


def input_matrix(q: np.ndarray, p: MechanicalParameters) -> np.ndarray:
    """
    Map of the vertical forces ``[F_c, F_p]`` to generalised forces, dQ/du.

    Parameters
    ----------
    q : ndarray, shape (2,)
        Beam angles [rad].
    p : MechanicalParameters
        The mechanics.

    Returns
    -------
    ndarray, shape (2, 2)
        ``[[l2 cos q1, l1 cos q1], [l3 cos q2, 0]]`` [m]; equals the notes' Bq at q = 0.
    """
    c1, c2 = np.cos(q[0]), np.cos(q[1])
    return np.array([[p.l2_m * c1, p.l1_m * c1], [p.l3_m * c2, 0.0]])


def generalised_forces(q: np.ndarray, F_c: float, F_p: float,
                       p: MechanicalParameters) -> np.ndarray:
    """
    Generalised forces of the coil, pan and offset forces.

    Parameters
    ----------
    q : ndarray, shape (2,)
        Beam angles [rad].
    F_c : float
        Coil force at the lever end [N], positive upward.
    F_p : float
        External pan force at the pan point [N], positive downward.
    p : MechanicalParameters
        The mechanics (``F_off_N`` is added to ``F_c``).

    Returns
    -------
    ndarray, shape (2,)
        Generalised forces [N m].
    """
    return input_matrix(q, p) @ np.array([F_c + p.F_off_N, F_p])


def lever_position_m(q: np.ndarray, p: MechanicalParameters) -> float:
    """
    Height of the lever end, the measured output ``y = l2 sin q1 + l3 sin q2``.

    Parameters
    ----------
    q : ndarray, shape (2,)
        Beam angles [rad] (or the state; only the first two entries are used).
    p : MechanicalParameters
        The mechanics.

    Returns
    -------
    float
        Lever-end position [m].
    """
    return float(p.l2_m * np.sin(q[0]) + p.l3_m * np.sin(q[1]))


def accelerations(x: np.ndarray, F_c: float, F_p: float,
                  p: MechanicalParameters) -> np.ndarray:
    """
    Angular accelerations ``q''`` solving the equations of motion.

    Parameters
    ----------
    x : ndarray, shape (4,)
        State ``[q1, q2, q1', q2']`` [rad, rad/s].
    F_c, F_p : float
        Coil force [N] (up) and external pan force [N] (down).
    p : MechanicalParameters
        The mechanics.

    Returns
    -------
    ndarray, shape (2,)
        ``q''`` [rad/s^2].
    """
    x = np.asarray(x, dtype=float)
    q, qd = x[:2], x[2:4]
    rhs = (generalised_forces(q, F_c, F_p, p) - coriolis_matrix(q, qd, p) @ qd
           - gravity_vector(q, p) - stiffness_matrix(p) @ q - damping_matrix(p) @ qd)
    return np.linalg.solve(mass_matrix(q, p), rhs)


def state_derivative(x: np.ndarray, F_c: float, F_p: float,
                     p: MechanicalParameters) -> np.ndarray:
    """
    Evaluate the right-hand side of the nonlinear state equation ``x' = f(x, u)``.

    Parameters
    ----------
    x : ndarray, shape (4,)
        State ``[q1, q2, q1', q2']`` [rad, rad/s].
    F_c : float
        Coil force at the lever end [N], positive upward.
    F_p : float
        External pan force at the pan point [N], positive downward.
    p : MechanicalParameters
        The mechanics.

    Returns
    -------
    ndarray, shape (4,)
        ``[q1', q2', q1'', q2'']``.
    """
    x = np.asarray(x, dtype=float)
    return np.concatenate([x[2:4], accelerations(x, F_c, F_p, p)])


def tangent_stiffness(q: np.ndarray, F_c: float, F_p: float,
                      p: MechanicalParameters) -> np.ndarray:
    """
    Compute the static tangent stiffness ``d(G + K q - Q)/dq`` at rest.

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
    ndarray, shape (2, 2)
        Stiffness [N m/rad]; at q = 0 the notes' ``K`` (gravity enters through ``h1``, ``h2``).
    """
    g = p.g_m_per_s2
    c1, s1 = np.cos(q[0]), np.sin(q[0])
    c2, s2 = np.cos(q[1]), np.sin(q[1])
    arm1 = (p.m2_kg + p.m3_kg) * p.l2_m - p.mp_kg * p.l1_m
    dg1 = -g * (p.m1_kg * (p.r1_m * s1 + p.h1_m * c1) + arm1 * s1)
    dg2 = -g * (p.m2_kg * (p.r2_m * s2 + p.h2_m * c2) + p.m3_kg * p.l3_m * s2)
    f_end = F_c + p.F_off_N
    dq1 = -s1 * (p.l2_m * f_end + p.l1_m * F_p)
    dq2 = -s2 * p.l3_m * f_end
    return stiffness_matrix(p) + np.diag([dg1 - dq1, dg2 - dq2])
