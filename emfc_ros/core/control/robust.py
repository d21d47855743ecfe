"""
The loop over the whole weighing range: margins and exact stability at every load.

A load on the pan adds inertia: the lever's 410 Hz mode falls to 333 Hz with 200 g (the
antiresonance of the coil input from 354 to 266 Hz) and the gain near the crossover drops.
A notch fixed at the empty pan's mode then sits beside the loaded mode and the loop rings
(issue 15). The default in-loop design therefore has no notch: at 10 kHz with one sample of
delay the mode stays phase-stabilised (its loop gain stays near 0 deg, far from -1) at every
load, and the design is *checked* over the range instead of trusted at one load:

* :func:`closed_loop_poles`: the exact sampled-data closed loop (zero-order hold at the
  controller rate, a delay of any whole or fractional number of samples, the controller's
  state space), whose largest pole radius decides stability without any grid;
* :func:`check_load_range`: for loads from 0 to ``max_load_kg`` the margins of
  :func:`~emfc_ros.core.control.design.analyse_loop` on the loaded model and the exact poles,
  compared with :class:`RobustnessLimits`.

No ROS imports.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Optional, Tuple

import numpy as np
from scipy import linalg, signal

from emfc_ros.core.control.design import analyse_loop, DiscreteController, plant_from_model
from emfc_ros.core.model.linear import linearise, LinearModel
from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.parameters import MechanicalParameters


@dataclass(frozen=True)
class RobustnessLimits:
    """
    What every load of the range must meet.

    Attributes
    ----------
    max_sensitivity_peak : float
        Largest ``Ms = max |1 / (1 + L)|`` (2.0: the textbook limit, which alone guarantees
        6 dB of gain margin and 29 deg of phase margin).
    min_gain_margin_dB : float
        Smallest distance of both gain margins from 0 dB [dB].
    max_pole_radius : float
        Largest radius of the exact closed-loop poles (below 1: stable).
    """

    max_sensitivity_peak: float = 2.0
    min_gain_margin_dB: float = 6.0
    max_pole_radius: float = 0.9999


@dataclass(frozen=True)
class LoadMargins:
    """
    The loop at one load.

    Attributes
    ----------
    load_mass_kg : float
        Mass on the pan [kg].
    crossover_Hz : float
        Lowest gain crossover [Hz] (the loop's bandwidth; higher ones belong to the
        phase-stabilised mode).
    sensitivity_peak : float
        ``Ms``.
    lower_gain_margin_dB, upper_gain_margin_dB : float or None
        Gain margins [dB]; None when the loop never crosses the negative real axis there.
    pole_radius : float
        Largest radius of the exact sampled-data closed-loop poles.
    mode_Hz : float
        Frequency of the lever's mode at this load (the highest open-loop pole) [Hz].
    """

    load_mass_kg: float
    crossover_Hz: float
    sensitivity_peak: float
    lower_gain_margin_dB: Optional[float]
    upper_gain_margin_dB: Optional[float]
    pole_radius: float
    mode_Hz: float

    def problems(self, limits: RobustnessLimits) -> Tuple[str, ...]:
        """
        What this load violates (empty when it meets every limit).

        Parameters
        ----------
        limits : RobustnessLimits
            The limits.

        Returns
        -------
        tuple of str
            One sentence per violated limit.
        """
        out = []
        at = f'at {self.load_mass_kg * 1e3:g} g'
        if not self.pole_radius < limits.max_pole_radius:
            out.append(f'{at} the closed loop is unstable (pole radius {self.pole_radius:.6f}, '
                       f'mode at {self.mode_Hz:.0f} Hz)')
        if not self.sensitivity_peak <= limits.max_sensitivity_peak:
            out.append(f'{at} the sensitivity peak is {self.sensitivity_peak:.2f} (limit '
                       f'{limits.max_sensitivity_peak:g})')
        for name, value in (('lower', self.lower_gain_margin_dB),
                            ('upper', self.upper_gain_margin_dB)):
            if value is not None and abs(value) < limits.min_gain_margin_dB:
                out.append(f'{at} the {name} gain margin is {value:.1f} dB (limit '
                           f'{limits.min_gain_margin_dB:g} dB)')
        return tuple(out)


def closed_loop_poles(model: LinearModel, controller: DiscreteController,
                      delay_samples: float) -> np.ndarray:
    """
    Poles of the exact sampled-data loop ``u = -C(z) y`` around the coil input.

    The plant is held by a zero-order hold at the controller's rate; a delay of
    ``d = a + f`` samples (``a`` whole, ``0 <= f < 1``) makes the plant see ``u[k - a - 1]``
    over the first fraction ``f`` of the interval ``[kT, (k + 1) T)`` and ``u[k - a]`` over the
    rest (so ``d = 1`` is one whole sample: the output computed at ``kT`` acts over
    ``[(k + 1) T, (k + 2) T)``).

    Parameters
    ----------
    model : LinearModel
        Continuous model (``A``, ``B`` with the coil force as input 0, ``C``).
    controller : DiscreteController
        The controller at its sample rate.
    delay_samples : float
        Delay [controller samples], >= 0.

    Returns
    -------
    ndarray of complex
        The closed-loop poles in z.
    """
    d = float(delay_samples)
    if not (math.isfinite(d) and d >= 0.0):
        raise ValueError(f'delay_samples: {delay_samples!r} must be finite and >= 0')
    a_whole = int(math.floor(d + 1e-12))
    frac = d - a_whole
    if frac < 1e-12:
        frac = 0.0
    period = 1.0 / controller.sample_rate_Hz
    A = np.asarray(model.A, dtype=float)
    b = np.asarray(model.B, dtype=float)[:, [0]]
    C = np.asarray(model.C, dtype=float)[[0], :]
    n = A.shape[0]

    def phi_gamma(tau: float):
        m = np.zeros((n + 1, n + 1))
        m[:n, :n] = A
        m[:n, n:] = b
        e = linalg.expm(m * tau)
        return e[:n, :n], e[:n, n:]

    phi_f, gam_f = phi_gamma(frac * period)          # over [kT, kT + fT): u[k - a - 1]
    phi_r, gam_r = phi_gamma((1.0 - frac) * period)  # over the rest: u[k - a]
    phi = phi_r @ phi_f
    gam_old = phi_r @ gam_f
    gam_new = gam_r
    Ac, Bc, Cc, Dc = signal.tf2ss(controller.numerator, controller.denominator)
    nc = Ac.shape[0]
    # state: plant x (n), the controller outputs u[k-1] .. u[k-a-1] (a + 1), controller (nc)
    nu = a_whole + 1
    size = n + nu + nc
    M = np.zeros((size, size))
    iu = n                  # index of u[k - 1]; u[k - j] at iu + j - 1
    ic = n + nu
    M[:n, :n] = phi
    # x[k+1] = phi x[k] + gam_new u[k - a] + gam_old u[k - a - 1]
    if a_whole == 0:
        # u[k] = -Dc C x[k] + Cc xc[k] (computed this sample)
        M[:n, :n] += gam_new @ (-(Dc @ C))
        M[:n, ic:] += gam_new @ Cc
    else:
        M[:n, [iu + a_whole - 1]] += gam_new
    M[:n, [iu + a_whole]] += gam_old
    # shift register: u[k] into slot 0, slot j-1 into slot j
    M[iu, :n] = -(Dc @ C)[0]
    M[iu, ic:] = Cc[0]
    for j in range(1, nu):
        M[iu + j, iu + j - 1] = 1.0
    M[ic:, :n] = -Bc @ C
    M[ic:, ic:] = Ac
    return linalg.eigvals(M)


def load_margins(mechanics: MechanicalParameters, controller: DiscreteController,
                 delay_samples: float, load_mass_kg: float,
                 load_changer_coupled: bool = False, grid_points: int = 4000) -> LoadMargins:
    """
    Margins and exact stability of a loop at one load.

    Parameters
    ----------
    mechanics : MechanicalParameters
        The empty balance.
    controller : DiscreteController
        The controller.
    delay_samples : float
        Loop delay [controller samples] (the hold adds half a sample in the margins).
    load_mass_kg : float
        Mass on the pan [kg].
    load_changer_coupled : bool
        Whether the load changer rides on the pan.
    grid_points : int
        Frequency grid of the margin analysis.

    Returns
    -------
    LoadMargins
        The loop at that load.
    """
    model = linearise(loaded(mechanics, load_mass_kg, load_changer_coupled))
    analysis = analyse_loop(controller, plant_from_model(model), delay_samples,
                            grid_points=grid_points)
    poles = closed_loop_poles(model, controller, delay_samples)
    modes = [r.frequency_Hz for r in model.poles()]
    return LoadMargins(
        load_mass_kg=float(load_mass_kg),
        crossover_Hz=float(min(analysis.gain_crossovers_Hz)) if analysis.gain_crossovers_Hz
        else float('nan'),
        sensitivity_peak=analysis.sensitivity_peak,
        lower_gain_margin_dB=analysis.lower_gain_margin_dB,
        upper_gain_margin_dB=analysis.upper_gain_margin_dB,
        pole_radius=float(np.max(np.abs(poles))), mode_Hz=float(max(modes)))


def check_load_range(mechanics: MechanicalParameters, controller: DiscreteController,
                     delay_samples: float, max_load_kg: float,
                     load_changer_coupled: bool = False, n_loads: int = 11,
                     limits: RobustnessLimits = RobustnessLimits(),
                     grid_points: int = 4000) -> Tuple[LoadMargins, ...]:
    """
    Check a loop at loads evenly spread from 0 to ``max_load_kg``.

    Parameters
    ----------
    mechanics : MechanicalParameters
        The empty balance.
    controller : DiscreteController
        The controller.
    delay_samples : float
        Loop delay [controller samples].
    max_load_kg : float
        Top of the weighing range [kg], >= 0.
    load_changer_coupled : bool
        Whether the load changer rides on the pan.
    n_loads : int
        Loads checked (0 and ``max_load_kg`` included), >= 2.
    limits : RobustnessLimits
        What each load must meet.
    grid_points : int
        Frequency grid of each margin analysis.

    Returns
    -------
    tuple of LoadMargins
        The loop at each load.

    Raises
    ------
    ValueError
        Naming every load that violates a limit and how.
    """
    top = float(max_load_kg)
    if not (math.isfinite(top) and top >= 0.0):
        raise ValueError(f'max_load_kg: {max_load_kg!r} must be finite and >= 0')
    if int(n_loads) < 2:
        raise ValueError(f'n_loads: {n_loads!r} must be >= 2')
    results = tuple(load_margins(mechanics, controller, delay_samples, m,
                                 load_changer_coupled, grid_points)
                    for m in np.linspace(0.0, top, int(n_loads)))
    problems = [p for r in results for p in r.problems(limits)]
    if problems:
        more = f' (and {len(problems) - 4} more)' if len(problems) > 4 else ''
        raise ValueError('the loop does not hold over the weighing range 0 to '
                         f'{top * 1e3:g} g: ' + '; '.join(problems[:4]) + more)
    return results
