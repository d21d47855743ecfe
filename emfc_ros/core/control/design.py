"""
Loop-shaping design of the discrete position controller from a plant frequency response.

The controller is ``C(z) = K * PID(z) * Lead(z) [* Notch(z)]`` at the sample rate ``fs``:
the PID (integral corner, derivative time and a first-order derivative filter) and the lead
are continuous prototypes discretised with the bilinear transform
(:func:`scipy.signal.bilinear`), the notch is :func:`scipy.signal.iirnotch`. The loop is
closed with negative feedback, ``u = -C y``; the open loop is

``L(f) = C(exp(j 2 pi f / fs)) * ZOH(f) * exp(-j 2 pi f d / fs) * P(f)``

with ``P`` the continuous coil-force-to-position response [m/N], ``d`` the computation and
transport delay [samples] and ``ZOH(f) = sinc(f / fs) exp(-j pi f / fs)`` the zero-order hold
(the sampled-data loop approximated by its fundamental; aliasing is neglected).

:func:`design_controller` fixes the PID shape relative to the crossover, solves the lead's
phase so that the phase of ``L`` at the crossover is ``-180 + phase_margin_deg`` and sets the
gain so that ``|L| = 1`` there; the margins are then evaluated on a dense grid.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Callable, Optional, Tuple

import numpy as np
from scipy import optimize, signal

#: ``f_Hz -> complex response [m/N]`` (vectorised over a 1-D array of frequencies).
PlantResponse = Callable[[np.ndarray], np.ndarray]

_MAX_LEAD_RAD = math.radians(80.0)
_MIN_LEAD_RAD = math.radians(-60.0)


@dataclass(frozen=True)
class DiscreteController:
    """
    A discrete controller as a gain times a cascade of stages in z.

    Attributes
    ----------
    sample_rate_Hz : float
        Sample rate [Hz].
    gain : float
        Overall gain ``K`` [N/m].
    stages : tuple of (ndarray, ndarray)
        ``(b, a)`` coefficients in descending powers of z of each stage (PID, lead, notch...).
    stage_names : tuple of str
        Name of each stage.
    """

    sample_rate_Hz: float
    gain: float
    stages: Tuple[Tuple[np.ndarray, np.ndarray], ...]
    stage_names: Tuple[str, ...]

    @property
    def numerator(self) -> np.ndarray:
        """Numerator of ``C(z)`` in descending powers of z (gain included)."""
        b = np.array([self.gain])
        for sb, _ in self.stages:
            b = np.polymul(b, sb)
        return b

    @property
    def denominator(self) -> np.ndarray:
        """Denominator of ``C(z)`` in descending powers of z (monic)."""
        a = np.array([1.0])
        for _, sa in self.stages:
            a = np.polymul(a, sa)
        return a / a[0]

    def to_dlti(self) -> signal.dlti:
        """
        The controller as a :class:`scipy.signal.dlti`.

        Returns
        -------
        scipy.signal.dlti
            Transfer function with ``dt = 1 / sample_rate_Hz``.
        """
        a = np.array([1.0])
        b = np.array([self.gain])
        for sb, sa in self.stages:
            b = np.polymul(b, sb)
            a = np.polymul(a, sa)
        return signal.dlti(b / a[0], a / a[0], dt=1.0 / self.sample_rate_Hz)

    def frequency_response(self, frequency_Hz: np.ndarray) -> np.ndarray:
        """
        Frequency response ``C(exp(j 2 pi f / fs))``.

        Evaluated stage by stage (better conditioned than the product polynomials).

        Parameters
        ----------
        frequency_Hz : array_like
            Frequencies [Hz].

        Returns
        -------
        ndarray of complex
            Response [N/m], same shape as ``frequency_Hz`` (at least 1-D).
        """
        f = np.atleast_1d(np.asarray(frequency_Hz, dtype=float))
        h = np.full(f.shape, complex(self.gain))
        for b, a in self.stages:
            _, hs = signal.freqz(b, a, worN=f, fs=self.sample_rate_Hz)
            h = h * hs
        return h

    def stage_response(self, name: str, frequency_Hz: np.ndarray) -> np.ndarray:
        """
        Frequency response of one named stage (without the gain).

        Parameters
        ----------
        name : str
            One of :attr:`stage_names`.
        frequency_Hz : array_like
            Frequencies [Hz].

        Returns
        -------
        ndarray of complex
            Response of that stage.
        """
        if name not in self.stage_names:
            raise ValueError(f'name: no stage {name!r}; stages are {self.stage_names}')
        b, a = self.stages[self.stage_names.index(name)]
        f = np.atleast_1d(np.asarray(frequency_Hz, dtype=float))
        return signal.freqz(b, a, worN=f, fs=self.sample_rate_Hz)[1]


@dataclass(frozen=True)
class ControllerDesign:
    """
    A designed controller and the margins of its loop.

    Attributes
    ----------
    controller : DiscreteController
        The controller.
    delay_samples : float
        Loop delay used [samples] (the zero-order hold comes on top).
    requested_crossover_Hz : float
        Crossover asked for [Hz].
    requested_phase_margin_deg : float
        Phase margin asked for [deg].
    crossover_Hz : float
        Lowest gain crossover ``|L| = 1`` found on the grid [Hz]: the loop's bandwidth (a
        phase-stabilised mode above it adds crossovers of its own).
    gain_crossovers_Hz : tuple of float
        All gain crossovers [Hz], ascending.
    phase_margin_deg : float
        The phase margin closest to 0 over all gain crossovers [deg], in (-180, 180]: its
        magnitude is the smallest angular distance of ``L`` from -1 where ``|L| = 1`` (a
        phase-stabilised mode has ``L`` near +1 there, a margin near +/-180 deg).
    phase_margins_deg : tuple of float
        The phase margin at each gain crossover [deg], in the order of
        ``gain_crossovers_Hz``.
    lower_gain_margin : float or None
        Largest gain factor below 1 at which the loop loses stability (conditional
        stability); None if no such crossing of the negative real axis.
    upper_gain_margin : float or None
        Smallest gain factor above 1 at which the loop loses stability; None if none.
    phase_crossovers_Hz : tuple of float
        Frequencies where ``L`` crosses the negative real axis [Hz].
    bandwidth_Hz : float or None
        Lowest frequency where the closed loop ``|L / (1 + L)|`` falls below -3 dB [Hz].
    sensitivity_peak : float
        ``Ms = max |1 / (1 + L)|`` on the grid.
    sensitivity_peak_Hz : float
        Where that peak is [Hz].
    lead_phase_deg : float
        Phase of the lead stage at its centre (the crossover) [deg].
    """

    controller: DiscreteController
    delay_samples: float
    requested_crossover_Hz: float
    requested_phase_margin_deg: float
    crossover_Hz: float
    gain_crossovers_Hz: Tuple[float, ...]
    phase_margin_deg: float
    phase_margins_deg: Tuple[float, ...]
    lower_gain_margin: Optional[float]
    upper_gain_margin: Optional[float]
    phase_crossovers_Hz: Tuple[float, ...]
    bandwidth_Hz: Optional[float]
    sensitivity_peak: float
    sensitivity_peak_Hz: float
    lead_phase_deg: float

    @property
    def lower_gain_margin_dB(self) -> Optional[float]:
        """Lower gain margin [dB] (negative), None if none."""
        g = self.lower_gain_margin
        return None if g is None else 20.0 * math.log10(g)

    @property
    def upper_gain_margin_dB(self) -> Optional[float]:
        """Upper gain margin [dB] (positive), None if none."""
        g = self.upper_gain_margin
        return None if g is None else 20.0 * math.log10(g)


def delay_and_hold_response(frequency_Hz: np.ndarray, sample_rate_Hz: float,
                            delay_samples: float) -> np.ndarray:
    """
    Response of the zero-order hold times a pure delay.

    Parameters
    ----------
    frequency_Hz : array_like
        Frequencies [Hz].
    sample_rate_Hz : float
        Sample rate [Hz].
    delay_samples : float
        Delay on top of the hold [samples].

    Returns
    -------
    ndarray of complex
        ``sinc(f / fs) exp(-j 2 pi f (delay + 1/2) / fs)``.
    """
    f = np.atleast_1d(np.asarray(frequency_Hz, dtype=float))
    x = f / sample_rate_Hz
    return np.sinc(x) * np.exp(-2j * np.pi * x * (delay_samples + 0.5))


def open_loop_response(controller: DiscreteController, plant_frequency_response: PlantResponse,
                       frequency_Hz: np.ndarray, delay_samples: float) -> np.ndarray:
    """
    Open loop ``L = C * ZOH * delay * P``.

    Parameters
    ----------
    controller : DiscreteController
        The controller.
    plant_frequency_response : callable
        ``f_Hz -> complex [m/N]``.
    frequency_Hz : array_like
        Frequencies [Hz].
    delay_samples : float
        Loop delay [samples].

    Returns
    -------
    ndarray of complex
        ``L`` at the frequencies.
    """
    f = np.atleast_1d(np.asarray(frequency_Hz, dtype=float))
    p = np.asarray(plant_frequency_response(f), dtype=complex).reshape(f.shape)
    return (controller.frequency_response(f) * p
            * delay_and_hold_response(f, controller.sample_rate_Hz, delay_samples))


def pid_stage(sample_rate_Hz: float, integral_Hz: float, derivative_time_s: float,
              derivative_filter_Hz: float) -> Tuple[np.ndarray, np.ndarray]:
    """
    Unit-gain PID ``1 + wi / s + Td s / (1 + s / wf)`` discretised with the bilinear transform.

    Parameters
    ----------
    sample_rate_Hz : float
        Sample rate [Hz].
    integral_Hz : float
        Integral corner ``wi / 2 pi`` [Hz].
    derivative_time_s : float
        Derivative time ``Td`` [s].
    derivative_filter_Hz : float
        Derivative filter corner ``wf / 2 pi`` [Hz].

    Returns
    -------
    (ndarray, ndarray)
        ``(b, a)`` in z.
    """
    wi = 2.0 * math.pi * integral_Hz
    wf = 2.0 * math.pi * derivative_filter_Hz
    b = [1.0 / wf + derivative_time_s, 1.0 + wi / wf, wi]
    a = [1.0 / wf, 1.0, 0.0]
    return signal.bilinear(b, a, fs=sample_rate_Hz)


def lead_stage(sample_rate_Hz: float, centre_Hz: float,
               phase_rad: float) -> Tuple[np.ndarray, np.ndarray]:
    """
    Lead ``(1 + s / wz) / (1 + s / wp)`` with its maximum phase at ``centre_Hz``.

    ``alpha = (1 - sin phi) / (1 + sin phi)``, ``wz = wc sqrt(alpha)``, ``wp = wc / sqrt(alpha)``;
    a negative ``phi`` gives a lag. Discretised with the bilinear transform.

    Parameters
    ----------
    sample_rate_Hz : float
        Sample rate [Hz].
    centre_Hz : float
        Frequency of the extreme phase [Hz].
    phase_rad : float
        Extreme phase of the continuous prototype [rad], in (-pi/2, pi/2).

    Returns
    -------
    (ndarray, ndarray)
        ``(b, a)`` in z (unit gain at DC).
    """
    alpha = (1.0 - math.sin(phase_rad)) / (1.0 + math.sin(phase_rad))
    wc = 2.0 * math.pi * centre_Hz
    wz = wc * math.sqrt(alpha)
    wp = wc / math.sqrt(alpha)
    return signal.bilinear([1.0 / wz, 1.0], [1.0 / wp, 1.0], fs=sample_rate_Hz)


def design_controller(plant_frequency_response: PlantResponse, sample_rate_Hz: float = 10.0e3,
                      crossover_Hz: float = 50.0, phase_margin_deg: float = 40.0,
                      delay_samples: float = 1.5, notch_Hz: Optional[float] = None,
                      notch_quality: float = 5.0, integral_ratio: float = 5.0,
                      derivative_ratio: float = 0.25,
                      derivative_filter_ratio: float = 20.0,
                      grid_min_Hz: float = 0.01,
                      grid_points: int = 20000) -> ControllerDesign:
    """
    Design PID plus lead (plus optional notch) for a crossover and a phase margin.

    The PID's shape is fixed relative to the crossover ``fc``: integral corner
    ``fc / integral_ratio``, derivative time ``derivative_ratio / (2 pi fc)`` and derivative
    filter corner ``min(derivative_filter_ratio * fc, 0.4 fs)``. The lead, centred on ``fc``,
    supplies the remaining phase (solved with :func:`scipy.optimize.brentq` on the discrete
    loop, so the discretisation, the notch, the hold and the delay are all accounted for); the
    gain then makes ``|L(fc)| = 1``. The plant is assumed to have a positive static gain and
    phase near -180 deg at the crossover (the balance above its pivot resonance), so the loop
    ``u = -C y`` has a positive gain.

    Parameters
    ----------
    plant_frequency_response : callable
        ``f_Hz (1-D array) -> complex response [m/N]`` of coil force to position, e.g.
        :func:`plant_from_model`.
    sample_rate_Hz : float
        Controller sample rate [Hz].
    crossover_Hz : float
        Requested gain crossover [Hz], in (0, fs / 2).
    phase_margin_deg : float
        Requested phase margin [deg], in (0, 90).
    delay_samples : float
        Computation and transport delay [samples], >= 0 (the hold adds half a sample).
    notch_Hz : float, optional
        Centre of a notch (e.g. the 400 Hz resonance) [Hz], in (0, fs / 2).
    notch_quality : float
        Quality factor of the notch (centre over -3 dB width).
    integral_ratio : float
        Crossover over integral corner, > 0.
    derivative_ratio : float
        Derivative time times the crossover angular frequency, >= 0.
    derivative_filter_ratio : float
        Derivative filter corner over crossover, > 1.
    grid_min_Hz : float
        Lowest frequency of the evaluation grid [Hz].
    grid_points : int
        Points of the log-spaced evaluation grid (up to 0.999 fs / 2).

    Returns
    -------
    ControllerDesign
        The controller and its margins.

    Raises
    ------
    ValueError
        An argument out of range (the message names it), or the phase margin is not reachable
        with the lead's range of -60 to 80 deg.
    """
    fs = _positive('sample_rate_Hz', sample_rate_Hz)
    nyquist_Hz = fs / 2.0
    fc = _positive('crossover_Hz', crossover_Hz)
    if fc >= nyquist_Hz:
        raise ValueError(f'crossover_Hz: {fc} must be below the Nyquist frequency {nyquist_Hz}')
    pm = float(phase_margin_deg)
    if not 0.0 < pm < 90.0:
        raise ValueError(f'phase_margin_deg: {phase_margin_deg} must be in (0, 90)')
    delay = float(delay_samples)
    if not (math.isfinite(delay) and delay >= 0.0):
        raise ValueError(f'delay_samples: {delay_samples} must be finite and >= 0')
    if notch_Hz is not None:
        if not 0.0 < float(notch_Hz) < nyquist_Hz:
            raise ValueError(f'notch_Hz: {notch_Hz} must be in (0, {nyquist_Hz})')
        _positive('notch_quality', notch_quality)
    _positive('integral_ratio', integral_ratio)
    if not (math.isfinite(derivative_ratio) and derivative_ratio >= 0.0):
        raise ValueError(f'derivative_ratio: {derivative_ratio} must be finite and >= 0')
    if not (math.isfinite(derivative_filter_ratio) and derivative_filter_ratio > 1.0):
        raise ValueError(f'derivative_filter_ratio: {derivative_filter_ratio} must be > 1')
    _positive('grid_min_Hz', grid_min_Hz)
    if grid_min_Hz >= fc or int(grid_points) < 100:
        raise ValueError('grid_min_Hz, grid_points: need grid_min_Hz < crossover_Hz and '
                         '>= 100 points')

    pid = pid_stage(fs, fc / integral_ratio, derivative_ratio / (2.0 * math.pi * fc),
                    min(derivative_filter_ratio * fc, 0.4 * fs))
    fixed = [pid]
    names = ['pid', 'lead']
    if notch_Hz is not None:
        fixed.append(signal.iirnotch(float(notch_Hz), float(notch_quality), fs=fs))
        names.append('notch')
    p_c = complex(np.asarray(plant_frequency_response(np.array([fc])), dtype=complex)[0])
    if not np.isfinite(p_c) or p_c == 0:
        raise ValueError(f'plant_frequency_response: {p_c} at the crossover is not usable')
    target = np.exp(1j * math.radians(pm - 180.0))

    def build(phase_rad: float, gain: float = 1.0) -> DiscreteController:
        stages = [fixed[0], lead_stage(fs, fc, phase_rad)] + fixed[1:]
        return DiscreteController(fs, gain, tuple((np.asarray(b, dtype=float),
                                                   np.asarray(a, dtype=float))
                                                  for b, a in stages), tuple(names))

    def phase_error(phase_rad: float) -> float:
        l_c = build(phase_rad).frequency_response(fc)[0] * p_c * delay_and_hold_response(
            fc, fs, delay)[0]
        return float(np.angle(l_c / target))

    lo, hi = phase_error(_MIN_LEAD_RAD), phase_error(_MAX_LEAD_RAD)
    if not lo < 0.0 < hi:
        raise ValueError(f'phase_margin_deg: {pm} deg at {fc} Hz is not reachable with a lead '
                         'of -60 to 80 deg')
    phi = optimize.brentq(phase_error, _MIN_LEAD_RAD, _MAX_LEAD_RAD, xtol=1.0e-12)
    unit = build(phi)
    l_unit = open_loop_response(unit, plant_frequency_response, np.array([fc]), delay)[0]
    controller = build(phi, float(1.0 / abs(l_unit)))
    return analyse_loop(controller, plant_frequency_response, delay, fc, pm,
                        math.degrees(phi), grid_min_Hz, int(grid_points))


def analyse_loop(controller: DiscreteController, plant_frequency_response: PlantResponse,
                 delay_samples: float, requested_crossover_Hz: float = float('nan'),
                 requested_phase_margin_deg: float = float('nan'),
                 lead_phase_deg: float = float('nan'), grid_min_Hz: float = 0.01,
                 grid_points: int = 20000) -> ControllerDesign:
    """
    Margins, bandwidth and sensitivity peak of a loop on a dense log grid.

    Crossings found on the grid are refined with :func:`scipy.optimize.brentq` on the loop
    response itself.

    Parameters
    ----------
    controller : DiscreteController
        The controller.
    plant_frequency_response : callable
        ``f_Hz -> complex [m/N]``.
    delay_samples : float
        Loop delay [samples].
    requested_crossover_Hz, requested_phase_margin_deg, lead_phase_deg : float
        Copied into the result.
    grid_min_Hz : float
        Lowest grid frequency [Hz].
    grid_points : int
        Number of log-spaced points up to 0.999 of the Nyquist frequency.

    Returns
    -------
    ControllerDesign
        The analysis.
    """
    fs = controller.sample_rate_Hz
    f = np.logspace(math.log10(grid_min_Hz), math.log10(0.999 * fs / 2.0), grid_points)

    def loop(x: float) -> complex:
        return complex(open_loop_response(controller, plant_frequency_response,
                                          np.array([x]), delay_samples)[0])

    L = open_loop_response(controller, plant_frequency_response, f, delay_samples)
    log_mag = np.log(np.abs(L))
    gain_x = [optimize.brentq(lambda x: math.log(abs(loop(x))), f[i], f[i + 1], xtol=1e-12)
              for i in np.nonzero(np.sign(log_mag[:-1]) != np.sign(log_mag[1:]))[0]]
    margins = [180.0 + math.degrees(np.angle(loop(x))) for x in gain_x]
    margins = [(m + 180.0) % 360.0 - 180.0 for m in margins]
    im = L.imag
    phase_x = []
    factors = []
    for i in np.nonzero(np.sign(im[:-1]) != np.sign(im[1:]))[0]:
        if L.real[i] >= 0.0 and L.real[i + 1] >= 0.0:
            continue
        x = optimize.brentq(lambda v: loop(v).imag, f[i], f[i + 1], xtol=1e-12)
        lx = loop(x)
        if lx.real < 0.0:
            phase_x.append(x)
            factors.append(1.0 / abs(lx))
    lower = [k for k in factors if k < 1.0]
    upper = [k for k in factors if k > 1.0]
    T = L / (1.0 + L)
    S = 1.0 / (1.0 + L)
    below = np.nonzero(np.abs(T) < 1.0 / math.sqrt(2.0))[0]
    bandwidth = None
    if below.size and below[0] > 0:
        i = below[0]
        bandwidth = optimize.brentq(
            lambda x: abs(loop(x) / (1.0 + loop(x))) - 1.0 / math.sqrt(2.0), f[i - 1], f[i],
            xtol=1e-12)
    k = int(np.argmax(np.abs(S)))
    return ControllerDesign(
        controller=controller, delay_samples=float(delay_samples),
        requested_crossover_Hz=float(requested_crossover_Hz),
        requested_phase_margin_deg=float(requested_phase_margin_deg),
        crossover_Hz=float(min(gain_x)) if gain_x else float('nan'),
        gain_crossovers_Hz=tuple(float(x) for x in gain_x),
        phase_margin_deg=float(min(margins, key=abs)) if margins else float('inf'),
        phase_margins_deg=tuple(float(m) for m in margins),
        lower_gain_margin=float(max(lower)) if lower else None,
        upper_gain_margin=float(min(upper)) if upper else None,
        phase_crossovers_Hz=tuple(float(x) for x in phase_x),
        bandwidth_Hz=None if bandwidth is None else float(bandwidth),
        sensitivity_peak=float(np.abs(S[k])), sensitivity_peak_Hz=float(f[k]),
        lead_phase_deg=float(lead_phase_deg))


def plant_from_model(model: object, input: str = 'coil') -> PlantResponse:
    """
    Wrap a :class:`~emfc_ros.core.model.linear.LinearModel` as a plant response callable.

    Parameters
    ----------
    model : LinearModel
        Anything with ``frequency_response(frequency_Hz, input)`` returning an object with
        ``response_m_per_N``.
    input : str
        Input name, ``'coil'`` by default.

    Returns
    -------
    callable
        ``f_Hz -> complex [m/N]``.
    """
    def response(frequency_Hz: np.ndarray) -> np.ndarray:
        return model.frequency_response(frequency_Hz, input).response_m_per_N

    return response


def _positive(name: str, value: float) -> float:
    v = float(value)
    if not (math.isfinite(v) and v > 0.0):
        raise ValueError(f'{name}: {value} must be finite and > 0')
    return v
