"""
Static characteristics of the peripheral components (paper Table 1) and their inverses.

Every characteristic is a polynomial in ascending powers, ``f(x) = sum_k c[k] x**k``, with the
reading of units fixed in ``docs/model.md``:

* amplifier: setpoint voltage U [V] to coil current I [A], ``c[k]`` in A/V**k;
* motor coefficient: ``F = k(y) I`` with ``k(y) = sum_j k[j] (y / 1 mm)**j``, ``k[j]`` in N/A
  (the paper's polynomial takes the lever-end position in millimetres);
* position sensor: lever-end position y [m] to voltage U [V], ``c[k]`` in V/m**k;
* load changer: current I [A] to force on the pan F [N] (positive downward, like a weight),
  ``c[k]`` in N/A**k.

All functions accept scalars or numpy arrays and return the same shape. Inverses use a
vectorised Newton iteration started from the linear term, which converges in a few steps for
the monotonic characteristics that the parameter validation enforces.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence, Tuple

import numpy as np
from numpy.polynomial import polynomial as npoly

from emfc_ros.core.errors import ConfigError

_MM_PER_M = 1.0e3
_MAX_NEWTON_STEPS = 60


def _tuple(coeffs: Sequence[float]) -> Tuple[float, ...]:
    return tuple(float(c) for c in coeffs)


def poly_eval(coeffs: Sequence[float], x):
    """
    Evaluate a polynomial given in ascending powers.

    Parameters
    ----------
    coeffs : sequence of float
        ``c[0], c[1], ...`` of ``sum_k c[k] x**k``.
    x : float or ndarray
        Argument(s).

    Returns
    -------
    float or ndarray
        Value(s), same shape as ``x``.
    """
    return npoly.polyval(x, np.asarray(coeffs, dtype=float))


def poly_inverse(coeffs: Sequence[float], value):
    """
    Invert a monotonic polynomial by a vectorised Newton iteration.

    Parameters
    ----------
    coeffs : sequence of float
        Ascending-power coefficients; ``c[1]`` must be non-zero.
    value : float or ndarray
        Target value(s) ``f(x)``.

    Returns
    -------
    float or ndarray
        ``x`` with ``f(x) = value`` (to a few ulp), same shape as ``value``.

    Raises
    ------
    ValueError
        If the iteration does not converge (the polynomial is not monotonic there).
    """
    c = np.asarray(coeffs, dtype=float)
    dc = npoly.polyder(c)
    target = np.asarray(value, dtype=float)
    x = (target - c[0]) / c[1]
    if c.size <= 2:
        return x if x.ndim else float(x)
    eps = np.finfo(float).eps
    for _ in range(_MAX_NEWTON_STEPS):
        slope = npoly.polyval(x, dc)
        step = (npoly.polyval(x, c) - target) / slope
        x = x - step
        # converged when the step is at the rounding level of x or of evaluating f(x)
        noise = npoly.polyval(np.abs(x), np.abs(c)) / np.abs(slope)
        if np.all(np.abs(step) <= 8.0 * eps * (np.abs(x) + noise)):
            break
    else:
        raise ValueError('polynomial inverse did not converge; is the characteristic '
                         'monotonic over the requested values?')
    return x if x.ndim else float(x)


def check_monotonic(coeffs: Sequence[float], lower: float, upper: float, key: str) -> None:
    """
    Refuse a characteristic that is not strictly monotonic on ``[lower, upper]``.

    Parameters
    ----------
    coeffs : sequence of float
        Ascending-power coefficients.
    lower, upper : float
        The working range of the argument (in the polynomial's own unit).
    key : str
        Dotted configuration key for the error message.

    Raises
    ------
    ConfigError
        If the linear coefficient is zero or the derivative changes sign inside the range.
    """
    c = np.asarray(coeffs, dtype=float)
    if c.size < 2 or c[1] == 0.0:
        raise ConfigError(key, 'the linear coefficient (index 1) must be non-zero')
    dc = npoly.polyder(c)
    probe = np.linspace(lower, upper, 2001)
    slope = npoly.polyval(probe, dc)
    if not (np.all(slope > 0.0) or np.all(slope < 0.0)):
        raise ConfigError(key, f'the characteristic must be strictly monotonic over '
                               f'[{lower!r}, {upper!r}] (its working range)')


@dataclass(frozen=True)
class Amplifier:
    """
    Linear analog power amplifier: setpoint voltage to output current.

    Attributes
    ----------
    coeffs_A_per_V_pow : tuple of float
        ``I(U) = sum_k c[k] U**k`` with ``c[k]`` in A/V**k (paper: 7.552e-6 A, 0.010 A/V,
        -6.964e-6 A/V**2).
    """

    coeffs_A_per_V_pow: Tuple[float, ...] = (7.552e-6, 0.010, -6.964e-6)

    def __post_init__(self) -> None:
        object.__setattr__(self, 'coeffs_A_per_V_pow', _tuple(self.coeffs_A_per_V_pow))

    def current_A(self, U_V):
        """
        Output current for a setpoint voltage.

        Parameters
        ----------
        U_V : float or ndarray
            Setpoint voltage [V].

        Returns
        -------
        float or ndarray
            Coil current [A].
        """
        return poly_eval(self.coeffs_A_per_V_pow, U_V)

    def voltage_V(self, I_A):
        """
        Setpoint voltage that produces a current (inverse of :meth:`current_A`).

        Parameters
        ----------
        I_A : float or ndarray
            Current [A].

        Returns
        -------
        float or ndarray
            Setpoint voltage [V].
        """
        return poly_inverse(self.coeffs_A_per_V_pow, I_A)


@dataclass(frozen=True)
class MotorCoefficient:
    """
    Position-dependent motor coefficient of the balance's voice coil actuator.

    Attributes
    ----------
    coeffs_N_per_A_per_mm_pow : tuple of float
        ``k(y) = sum_j k[j] (y / mm)**j`` in N/A, so ``k[j]`` is in N/(A mm**j) (paper:
        21.692, 0.012, -5.273e-3). The force at the lever end is ``F = k(y) I`` in N, positive
        upward (increasing y).
    """

    coeffs_N_per_A_per_mm_pow: Tuple[float, ...] = (21.692, 0.012, -5.273e-3)

    def __post_init__(self) -> None:
        object.__setattr__(self, 'coeffs_N_per_A_per_mm_pow',
                           _tuple(self.coeffs_N_per_A_per_mm_pow))

    def coefficient_N_per_A(self, y_m):
        """
        Motor coefficient at a lever-end position.

        Parameters
        ----------
        y_m : float or ndarray
            Lever-end position [m] (converted to mm inside the polynomial).

        Returns
        -------
        float or ndarray
            Motor coefficient [N/A].
        """
        return poly_eval(self.coeffs_N_per_A_per_mm_pow, np.asarray(y_m) * _MM_PER_M)

    def force_N(self, I_A, y_m):
        """
        Coil force for a current at a position.

        Parameters
        ----------
        I_A : float or ndarray
            Coil current [A].
        y_m : float or ndarray
            Lever-end position [m].

        Returns
        -------
        float or ndarray
            Force at the lever end [N], positive upward.
        """
        return self.coefficient_N_per_A(y_m) * I_A

    def current_A(self, F_N, y_m):
        """
        Coil current needed for a force at a position (inverse of :meth:`force_N`).

        Parameters
        ----------
        F_N : float or ndarray
            Force at the lever end [N].
        y_m : float or ndarray
            Lever-end position [m].

        Returns
        -------
        float or ndarray
            Coil current [A].
        """
        return F_N / self.coefficient_N_per_A(y_m)


@dataclass(frozen=True)
class PositionSensor:
    """
    Lever-end position sensor: position to voltage.

    Attributes
    ----------
    coeffs_V_per_m_pow : tuple of float
        ``U(y) = sum_k c[k] y**k`` with ``c[k]`` in V/m**k. The linear term is 5e4 V/m (the
        printed 1.95e17 V/m is impossible, see ``docs/model.md``); the higher-order terms are
        the paper's (-1.39e6 V/m**2, -1.10e11 V/m**3, 6.84e13 V/m**4, 4.31e17 V/m**5), each at
        most about 2 % of the linear term inside +/-100 um.
    """

    coeffs_V_per_m_pow: Tuple[float, ...] = (0.0, 5.0e4, -1.39e6, -1.10e11, 6.84e13, 4.31e17)

    def __post_init__(self) -> None:
        object.__setattr__(self, 'coeffs_V_per_m_pow', _tuple(self.coeffs_V_per_m_pow))

    def voltage_V(self, y_m):
        """
        Sensor voltage at a lever-end position.

        Parameters
        ----------
        y_m : float or ndarray
            Lever-end position [m].

        Returns
        -------
        float or ndarray
            Sensor voltage [V].
        """
        return poly_eval(self.coeffs_V_per_m_pow, y_m)

    def position_m(self, U_V):
        """
        Lever-end position for a sensor voltage (inverse of :meth:`voltage_V`).

        Parameters
        ----------
        U_V : float or ndarray
            Sensor voltage [V].

        Returns
        -------
        float or ndarray
            Lever-end position [m].
        """
        return poly_inverse(self.coeffs_V_per_m_pow, U_V)


@dataclass(frozen=True)
class LoadChanger:
    """
    Load changer actuator: current to force on the pan.

    Attributes
    ----------
    coeffs_N_per_A_pow : tuple of float
        ``F(I) = sum_k c[k] I**k`` with ``c[k]`` in N/A**k (paper: 3.982e-4 N, -0.904 N/A).
        The force acts on the pan in the pan-force convention of the mechanics (positive
        downward, like a weight).
    """

    coeffs_N_per_A_pow: Tuple[float, ...] = (3.982e-4, -0.904)

    def __post_init__(self) -> None:
        object.__setattr__(self, 'coeffs_N_per_A_pow', _tuple(self.coeffs_N_per_A_pow))

    def force_N(self, I_A):
        """
        Force on the pan for a load-changer current.

        Parameters
        ----------
        I_A : float or ndarray
            Load-changer current [A].

        Returns
        -------
        float or ndarray
            Force on the pan [N], positive downward.
        """
        return poly_eval(self.coeffs_N_per_A_pow, I_A)

    def current_A(self, F_N):
        """
        Load-changer current for a force on the pan (inverse of :meth:`force_N`).

        Parameters
        ----------
        F_N : float or ndarray
            Force on the pan [N], positive downward.

        Returns
        -------
        float or ndarray
            Load-changer current [A].
        """
        return poly_inverse(self.coeffs_N_per_A_pow, F_N)
