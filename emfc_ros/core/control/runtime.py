"""
The designed controller run sample by sample: PID with anti-windup, then lead and notch.

:func:`controller_step` is written in the subset of Python that numba compiles, so that the
simulator's closed-loop kernel (:mod:`emfc_ros.core.sim.closed_loop`) runs exactly the code
that :class:`RuntimeController` runs interpreted (the external controller node, tests).

Coefficients (``coef``, a flat float array) and state (``state``):

* ``coef = [gain, ki, kd_pole, kd_gain, lower_N, upper_N, n_biquads, b0, b1, b2, a1, a2, ...]``
* ``state = [integral, derivative, previous_error, z1, z2, ...]``

The PID stage of :func:`~emfc_ros.core.control.design.pid_stage` is split exactly into its
three parallel terms (the bilinear transform maps a sum to a sum)::

    PID(z) = 1 + ki (z + 1) / (z - 1) + kd_gain (z - 1) / (z - kd_pole)

so the integral is a state of its own: when the output would saturate and the integral's
increment pushes further into the limit, the increment is dropped (conditional integration,
the anti-windup). The other stages (lead, notch) are second-order sections in transposed
direct form II; the output is ``gain`` times the cascade, clamped to ``[lower_N, upper_N]``.
"""

from __future__ import annotations

import math
from typing import Tuple

import numpy as np

from emfc_ros.core.control.design import DiscreteController

try:    # callable from numba-compiled code (the closed-loop kernel), plain Python otherwise
    from numba.extending import register_jitable as _jitable
except ImportError:     # pragma: no cover - numba is optional
    def _jitable(function):
        return function

#: Indices into ``coef``.
GAIN, KI, KD_POLE, KD_GAIN, LOWER, UPPER, N_BIQUADS = range(7)
HEADER = 7
#: Indices into ``state``.
INTEGRAL, DERIVATIVE, PREVIOUS_ERROR = range(3)
STATE_HEADER = 3


@_jitable
def controller_step(coef, state, error):
    """
    Advance the controller by one sample.

    Parameters
    ----------
    coef : ndarray
        Coefficients (module docstring).
    state : ndarray
        State, updated in place.
    error : float
        Setpoint minus measurement [m].

    Returns
    -------
    float
        The clamped output [N].
    """
    ki = coef[KI]
    gain = coef[GAIN]
    e_prev = state[PREVIOUS_ERROR]
    integral_old = state[INTEGRAL]
    integral = integral_old + ki * (error + e_prev)
    derivative = coef[KD_POLE] * state[DERIVATIVE] + coef[KD_GAIN] * (error - e_prev)
    n_bq = int(coef[N_BIQUADS])
    u = gain * _cascade(coef, state, error + integral + derivative, n_bq, False)
    lower = coef[LOWER]
    upper = coef[UPPER]
    step = gain * (integral - integral_old)
    if (u > upper and step > 0.0) or (u < lower and step < 0.0):
        integral = integral_old
    u = gain * _cascade(coef, state, error + integral + derivative, n_bq, True)
    state[INTEGRAL] = integral
    state[DERIVATIVE] = derivative
    state[PREVIOUS_ERROR] = error
    return min(max(u, lower), upper)


@_jitable
def _cascade(coef, state, v, n_bq, commit):
    # the second-order sections in transposed direct form II; the state only when commit
    for i in range(n_bq):
        o = HEADER + 5 * i
        s = STATE_HEADER + 2 * i
        y = coef[o] * v + state[s]
        if commit:
            state[s] = coef[o + 1] * v - coef[o + 3] * y + state[s + 1]
            state[s + 1] = coef[o + 2] * v - coef[o + 4] * y
        v = y
    return v


def pid_terms(b: np.ndarray, a: np.ndarray) -> Tuple[float, float, float]:
    """
    Split a PID stage ``(b, a)`` into ``(ki, kd_pole, kd_gain)`` (module docstring).

    Parameters
    ----------
    b, a : ndarray
        Numerator and denominator in descending powers of z (``a`` with roots 1 and the
        derivative filter's pole).

    Returns
    -------
    (float, float, float)
        ``ki``, ``kd_pole``, ``kd_gain``.

    Raises
    ------
    ValueError
        If the stage is not of that form (checked by rebuilding it).
    """
    b = np.asarray(b, dtype=float) / a[0]
    a = np.asarray(a, dtype=float) / a[0]
    if b.shape != (3,) or a.shape != (3,) or abs(1.0 + a[1] + a[2]) > 1e-9:
        raise ValueError('pid stage: expected a second-order stage with an integrator (a pole '
                         'at z = 1)')
    pole = a[2]                     # (z - 1)(z - p) = z^2 - (1 + p) z + p
    ki = float(np.sum(b) / (2.0 * (1.0 - pole)))
    kd_gain = float((np.polyval(b, -1.0) / np.polyval(a, -1.0) - 1.0) * (1.0 + pole) / 2.0)
    rebuilt_b = (np.polymul([1.0, -1.0], [1.0, -pole]) + ki * np.polymul([1.0, 1.0],
                                                                         [1.0, -pole])
                 + kd_gain * np.polymul([1.0, -1.0], [1.0, -1.0]))
    if not np.allclose(rebuilt_b, b, rtol=1e-9, atol=1e-12 * np.max(np.abs(b))):
        raise ValueError('pid stage: not of the form 1 + integral + filtered derivative')
    return ki, float(pole), kd_gain


def pack_controller(controller: DiscreteController,
                    output_limits_N: Tuple[float, float] = (-math.inf, math.inf)
                    ) -> np.ndarray:
    """
    Pack a designed controller into the ``coef`` array of :func:`controller_step`.

    Parameters
    ----------
    controller : DiscreteController
        The design's controller; its first stage must be named ``'pid'``.
    output_limits_N : (float, float)
        Output clamp ``(lower, upper)`` [N], lower < upper.

    Returns
    -------
    ndarray
        The coefficients.

    Raises
    ------
    ValueError
        If the first stage is not a PID, a stage is above second order, or the limits are
        not ordered.
    """
    lower, upper = (float(v) for v in output_limits_N)
    if not lower < upper:
        raise ValueError(f'output_limits_N: {output_limits_N!r} must be (lower, upper) with '
                         'lower < upper')
    if not controller.stage_names or controller.stage_names[0] != 'pid':
        raise ValueError('controller: the first stage must be the PID (named "pid")')
    ki, pole, kd_gain = pid_terms(*controller.stages[0])
    sections = []
    for name, (b, a) in zip(controller.stage_names[1:], controller.stages[1:]):
        b = np.asarray(b, dtype=float) / a[0]
        a = np.asarray(a, dtype=float) / a[0]
        if len(b) > 3 or len(a) > 3:
            raise ValueError(f'controller stage {name!r}: above second order')
        b = np.concatenate([b, np.zeros(3 - len(b))])
        a = np.concatenate([a, np.zeros(3 - len(a))])
        sections.extend([b[0], b[1], b[2], a[1], a[2]])
    head = [controller.gain, ki, pole, kd_gain, lower, upper, float(len(sections) // 5)]
    return np.array(head + sections, dtype=float)


def initial_state(coef: np.ndarray, output_N: float = 0.0) -> np.ndarray:
    """
    Controller state at rest with zero error and a given output (bumpless start).

    The integral holds ``output / gain`` and every section is at its steady state for that
    constant input (the lead and the notch have unit gain at DC).

    Parameters
    ----------
    coef : ndarray
        Coefficients of :func:`pack_controller`.
    output_N : float
        The output to start from [N], e.g. the force that holds the lever.

    Returns
    -------
    ndarray
        The state.
    """
    n_bq = int(coef[N_BIQUADS])
    state = np.zeros(STATE_HEADER + 2 * n_bq)
    v = float(output_N) / coef[GAIN]
    state[INTEGRAL] = v
    for i in range(n_bq):
        b0, b1, b2, a1, a2 = coef[HEADER + 5 * i:HEADER + 5 * i + 5]
        dc = (b0 + b1 + b2) / (1.0 + a1 + a2)
        y = dc * v
        state[STATE_HEADER + 2 * i + 1] = b2 * v - a2 * y
        state[STATE_HEADER + 2 * i] = y - b0 * v
        v = y
    return state


class RuntimeController:
    """
    A designed controller run one sample at a time (interpreted :func:`controller_step`).

    Parameters
    ----------
    controller : DiscreteController
        The design (e.g. ``design_controller(...).controller``).
    output_limits_N : (float, float)
        Output clamp [N].
    initial_output_N : float
        Output at the start, with zero error [N].

    Attributes
    ----------
    sample_rate_Hz : float
        The controller's sample rate [Hz].
    coefficients : ndarray
        Packed coefficients.
    state : ndarray
        Current state.
    saturated_samples : int
        Samples whose output was clamped.
    """

    def __init__(self, controller: DiscreteController,
                 output_limits_N: Tuple[float, float] = (-math.inf, math.inf),
                 initial_output_N: float = 0.0) -> None:
        self.sample_rate_Hz = controller.sample_rate_Hz
        self.coefficients = pack_controller(controller, output_limits_N)
        self.saturated_samples = 0
        self.reset(initial_output_N)

    def reset(self, initial_output_N: float = 0.0) -> None:
        """
        Return to rest with zero error and the given output [N].

        Parameters
        ----------
        initial_output_N : float
            Output [N].
        """
        if not math.isfinite(float(initial_output_N)):
            raise ValueError(f'initial_output_N: {initial_output_N!r} is not finite')
        self.state = initial_state(self.coefficients, initial_output_N)

    def update(self, error_m: float) -> float:
        """
        One sample: the output for the error ``setpoint - position``.

        Parameters
        ----------
        error_m : float
            Control error [m].

        Returns
        -------
        float
            The output force [N], clamped.

        Raises
        ------
        ValueError
            If the error is not finite (the state is left unchanged).
        """
        e = float(error_m)
        if not math.isfinite(e):
            raise ValueError(f'error_m: {error_m!r} is not finite')
        u = controller_step(self.coefficients, self.state, e)
        if u in (self.coefficients[LOWER], self.coefficients[UPPER]):
            self.saturated_samples += 1
        return u

    def update_block(self, error_m: np.ndarray) -> np.ndarray:
        """
        Run a sequence of errors [m]; returns the outputs [N].

        Parameters
        ----------
        error_m : array_like
            Errors [m].

        Returns
        -------
        ndarray
            Outputs [N].
        """
        return np.array([self.update(e) for e in np.asarray(error_m, dtype=float).ravel()])
