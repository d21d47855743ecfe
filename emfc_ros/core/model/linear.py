"""
Linearisation of the nonlinear mechanics, poles, zeros and frequency responses.

State ``x = [q1, q2, q1', q2']`` [rad, rad/s], inputs ``u = [F_c, F_p]`` [N] (coil force at the
lever end, up; external pan force, down), output ``y`` [m] (lever-end position). The analytic
Jacobians hold at any state and input (not only at rest); :func:`finite_difference_jacobians`
differentiates :func:`~emfc_ros.core.model.mechanics.state_derivative` numerically to check
them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence, Tuple

import numpy as np

from emfc_ros.core.model.mechanics import (_coupling, accelerations, damping_matrix,
                                           input_matrix, lever_position_m, mass_matrix,
                                           state_derivative, tangent_stiffness)
from emfc_ros.core.model.operating_point import hold_at, OperatingPoint
from emfc_ros.core.model.parameters import MechanicalParameters

#: Input names in the column order of B.
INPUTS = ('coil', 'pan')
STATES = ('q1_rad', 'q2_rad', 'q1dot_rad_per_s', 'q2dot_rad_per_s')


@dataclass(frozen=True)
class Root:
    """
    A pole or zero of a continuous-time model.

    Attributes
    ----------
    s_rad_per_s : complex
        The root in the s-plane [rad/s].
    """

    s_rad_per_s: complex

    @property
    def frequency_Hz(self) -> float:
        """Natural frequency ``|s| / 2 pi`` [Hz]."""
        return float(abs(self.s_rad_per_s) / (2.0 * np.pi))

    @property
    def damping_ratio(self) -> float:
        """Damping ratio ``-Re(s) / |s|`` (1 or -1 for a real root, negative: right half)."""
        mag = abs(self.s_rad_per_s)
        return float(-self.s_rad_per_s.real / mag) if mag > 0.0 else 1.0

    @property
    def is_real(self) -> bool:
        """Whether the root is real (imaginary part below 1e-9 of its magnitude)."""
        return abs(self.s_rad_per_s.imag) <= 1.0e-9 * abs(self.s_rad_per_s)

    @property
    def signed_frequency_Hz(self) -> float:
        """For a real root ``s / 2 pi`` [Hz] (negative: left half plane); else the frequency."""
        if self.is_real:
            return float(self.s_rad_per_s.real / (2.0 * np.pi))
        return self.frequency_Hz


@dataclass(frozen=True)
class FrequencyResponse:
    """
    Frequency response of one input of a linear model to the lever-end position.

    Attributes
    ----------
    input : str
        ``'coil'`` or ``'pan'``.
    frequency_Hz : ndarray
        Frequencies [Hz].
    response_m_per_N : ndarray
        Complex response [m/N].
    """

    input: str
    frequency_Hz: np.ndarray
    response_m_per_N: np.ndarray

    @property
    def magnitude_dB(self) -> np.ndarray:
        """Magnitude [dB re 1 m/N]."""
        return 20.0 * np.log10(np.abs(self.response_m_per_N))

    @property
    def phase_deg(self) -> np.ndarray:
        """Unwrapped phase [deg]."""
        return np.degrees(np.unwrap(np.angle(self.response_m_per_N)))


@dataclass(frozen=True)
class LinearModel:
    """
    Continuous-time linear model ``x' = A x + B u``, ``y = C x + D u`` about an operating point.

    Attributes
    ----------
    A : ndarray, shape (4, 4)
        State matrix [1/s, 1/s^2].
    B : ndarray, shape (4, 2)
        Input matrix, columns coil and pan force [rad/(s^2 N)] (zero upper rows).
    C : ndarray, shape (1, 4)
        Output matrix [m/rad].
    D : ndarray, shape (1, 2)
        Feedthrough [m/N] (zero).
    operating_point : OperatingPoint
        The point of linearisation (state, inputs, loaded mechanics).
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    operating_point: OperatingPoint

    def poles(self) -> Tuple[Root, ...]:
        """
        Eigenvalues of A, the poles for both inputs.

        Returns
        -------
        tuple of Root
            Sorted by frequency, then imaginary part.
        """
        from scipy import linalg
        return _sorted_roots(linalg.eigvals(self.A))

    def zeros(self, input: str = 'coil') -> Tuple[Root, ...]:
        """
        Invariant zeros of one input to the lever-end position.

        Computed as the finite generalised eigenvalues of the Rosenbrock pencil
        ``([[A, b], [C, d]], diag(I, 0))`` with ``scipy.linalg.eig`` (QZ), which avoids the
        ill-conditioned transfer-function polynomials.

        Parameters
        ----------
        input : str
            ``'coil'`` or ``'pan'``.

        Returns
        -------
        tuple of Root
            Sorted by frequency, then imaginary part.
        """
        from scipy import linalg
        j = _input_index(input)
        n = self.A.shape[0]
        pencil = np.block([[self.A, self.B[:, [j]]], [self.C, self.D[:, [j]]]])
        ident = np.zeros((n + 1, n + 1))
        ident[:n, :n] = np.eye(n)
        alpha, beta = linalg.eig(pencil, ident, right=False, homogeneous_eigvals=True)
        scale = np.max(np.abs(linalg.eigvals(self.A))) + 1.0
        keep = np.abs(beta) * 1.0e8 * scale > np.abs(alpha)
        return _sorted_roots(alpha[keep] / beta[keep])

    def static_gain_m_per_N(self, input: str = 'coil') -> float:
        """
        Compute the static gain ``-C A^-1 b + d`` of one input to the lever-end position.

        Parameters
        ----------
        input : str
            ``'coil'`` or ``'pan'``.

        Returns
        -------
        float
            Gain [m/N].
        """
        j = _input_index(input)
        return float(-(self.C @ np.linalg.solve(self.A, self.B[:, j]))[0] + self.D[0, j])

    def frequency_response(self, frequency_Hz: Sequence[float],
                           input: str = 'coil') -> FrequencyResponse:
        """
        Frequency response ``C (j w I - A)^-1 b + d`` of one input.

        Evaluated by a linear solve per frequency (better conditioned than going through
        transfer-function polynomials, as ``scipy.signal.freqresp`` does for state space).
        For the mechanics' second-order form (``A = [[0, I], [A21, A22]]``, ``B = [[0], [B2]]``,
        which :func:`linearise` gives) the solve is the 2 x 2 system
        ``(s^2 I - s A22 - A21) q = b2``, ``y = (Cq + s Cv) q + d``, by Cramer's rule for all
        frequencies at once (about 20 times faster than a 4 x 4 solve per line; the two agree
        to rounding).

        Parameters
        ----------
        frequency_Hz : sequence of float
            Frequencies [Hz].
        input : str
            ``'coil'`` or ``'pan'``.

        Returns
        -------
        FrequencyResponse
            The response [m/N].
        """
        j = _input_index(input)
        f = np.atleast_1d(np.asarray(frequency_Hz, dtype=float))
        s = 2j * np.pi * f
        n = self.A.shape[0]
        if _second_order(self.A, self.B):
            a21, a22, b2 = self.A[2:, :2], self.A[2:, 2:], self.B[2:, j]
            s2 = s * s
            p00 = s2 - s * a22[0, 0] - a21[0, 0]
            p01 = -s * a22[0, 1] - a21[0, 1]
            p10 = -s * a22[1, 0] - a21[1, 0]
            p11 = s2 - s * a22[1, 1] - a21[1, 1]
            det = p00 * p11 - p01 * p10
            q0 = (p11 * b2[0] - p01 * b2[1]) / det
            q1 = (p00 * b2[1] - p10 * b2[0]) / det
            c = self.C[0]
            resp = (c[0] + s * c[2]) * q0 + (c[1] + s * c[3]) * q1 + self.D[0, j]
            return FrequencyResponse(input, f, np.asarray(resp))
        lhs = s[:, None, None] * np.eye(n)[None] - self.A[None]
        rhs = np.broadcast_to(self.B[:, j].astype(complex), (f.size, n))[..., None]
        resp = (self.C[0] @ np.linalg.solve(lhs, rhs)[..., 0].T) + self.D[0, j]
        return FrequencyResponse(input, f, np.asarray(resp))


def _second_order(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether ``A = [[0, I], [A21, A22]]`` and ``B = [[0], [B2]]`` (4 states)."""
    return (a.shape == (4, 4) and b.shape[0] == 4 and not np.any(a[:2, :2])
            and np.array_equal(a[:2, 2:], np.eye(2)) and not np.any(b[:2]))


def _input_index(name: str) -> int:
    if name not in INPUTS:
        raise ValueError(f'input must be one of {INPUTS}, got {name!r}')
    return INPUTS.index(name)


def _sorted_roots(values: np.ndarray) -> Tuple[Root, ...]:
    roots = [Root(complex(v)) for v in values]
    return tuple(sorted(roots, key=lambda r: (abs(r.s_rad_per_s), r.s_rad_per_s.imag,
                                              r.s_rad_per_s.real)))


def jacobians(p: MechanicalParameters, x: np.ndarray,
              u: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """
    Analytic Jacobians of the nonlinear model at any state and input.

    Parameters
    ----------
    p : MechanicalParameters
        The (loaded) mechanics.
    x : ndarray, shape (4,)
        State ``[q1, q2, q1', q2']`` [rad, rad/s].
    u : ndarray, shape (2,)
        Inputs ``[F_c, F_p]`` [N].

    Returns
    -------
    A, B, C, D : ndarray
        ``df/dx`` (4, 4), ``df/du`` (4, 2), ``dy/dx`` (1, 4), ``dy/du`` (1, 2).
    """
    x = np.asarray(x, dtype=float)
    q, qd = x[:2], x[2:4]
    F_c, F_p = float(u[0]), float(u[1])
    mass = mass_matrix(q, p)
    m12, dm12 = _coupling(q, p)
    qdd = accelerations(x, F_c, F_p, p)
    # d(C(q, q') q')/dq and d/dq' for C q' = [M12' q2'^2, -M12' q1'^2], dM12'/dphi = -M12.
    dh_dq = np.array([[m12 * qd[1] ** 2, -m12 * qd[1] ** 2],
                      [-m12 * qd[0] ** 2, m12 * qd[0] ** 2]])
    dh_dqd = np.array([[0.0, 2.0 * dm12 * qd[1]], [-2.0 * dm12 * qd[0], 0.0]])
    # dM/dq_i q'' with dM12/dq1 = -M12', dM12/dq2 = M12'.
    dm_qdd = np.column_stack([-dm12 * qdd[::-1], dm12 * qdd[::-1]])
    dr_dq = -tangent_stiffness(q, F_c, F_p, p) - dh_dq - dm_qdd
    dr_dqd = -dh_dqd - damping_matrix(p)
    a = np.zeros((4, 4))
    a[:2, 2:] = np.eye(2)
    a[2:, :2] = np.linalg.solve(mass, dr_dq)
    a[2:, 2:] = np.linalg.solve(mass, dr_dqd)
    b = np.zeros((4, 2))
    b[2:, :] = np.linalg.solve(mass, input_matrix(q, p))
    c = np.array([[p.l2_m * np.cos(q[0]), p.l3_m * np.cos(q[1]), 0.0, 0.0]])
    return a, b, c, np.zeros((1, 2))


def finite_difference_jacobians(
        p: MechanicalParameters, x: np.ndarray, u: np.ndarray,
        step_x: Sequence[float] = (1.0e-7, 1.0e-7, 1.0e-5, 1.0e-5),
        step_u_N: float = 1.0e-5) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """
    Central finite-difference Jacobians of the nonlinear model (checks :func:`jacobians`).

    Parameters
    ----------
    p : MechanicalParameters
        The (loaded) mechanics.
    x : ndarray, shape (4,)
        State [rad, rad/s].
    u : ndarray, shape (2,)
        Inputs [N].
    step_x : sequence of float
        Steps for the four states [rad, rad, rad/s, rad/s].
    step_u_N : float
        Step for the forces [N].

    Returns
    -------
    A, B, C, D : ndarray
        As :func:`jacobians`.
    """
    x = np.asarray(x, dtype=float)
    u = np.asarray(u, dtype=float)

    def f(xx: np.ndarray, uu: np.ndarray) -> np.ndarray:
        return state_derivative(xx, uu[0], uu[1], p)

    def h(xx: np.ndarray, uu: np.ndarray) -> np.ndarray:
        return np.array([lever_position_m(xx, p)])

    a, b = np.zeros((4, 4)), np.zeros((4, 2))
    c, d = np.zeros((1, 4)), np.zeros((1, 2))
    for i, step in enumerate(step_x):
        e = np.zeros(4)
        e[i] = step
        a[:, i] = (f(x + e, u) - f(x - e, u)) / (2.0 * step)
        c[:, i] = (h(x + e, u) - h(x - e, u)) / (2.0 * step)
    for j in range(2):
        e = np.zeros(2)
        e[j] = step_u_N
        b[:, j] = (f(x, u + e) - f(x, u - e)) / (2.0 * step_u_N)
        d[:, j] = (h(x, u + e) - h(x, u - e)) / (2.0 * step_u_N)
    return a, b, c, d


def linearise(p: MechanicalParameters,
              operating_point: Optional[OperatingPoint] = None) -> LinearModel:
    """
    Linear model about an operating point (analytic Jacobians).

    Parameters
    ----------
    p : MechanicalParameters
        The (loaded) mechanics; ignored when ``operating_point`` is given (its own
        ``mechanics`` are used).
    operating_point : OperatingPoint, optional
        The point; default: rest at ``q = 0`` held by the forces of
        :func:`~emfc_ros.core.model.operating_point.hold_at` (the notes' linear model).

    Returns
    -------
    LinearModel
        A, B, C, D and the operating point.
    """
    op = operating_point if operating_point is not None else hold_at(p, (0.0, 0.0))
    a, b, c, d = jacobians(op.mechanics, op.x, op.u)
    return LinearModel(a, b, c, d, op)
