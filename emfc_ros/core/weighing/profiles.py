"""
Load profiles for mass-on-pan and load-changer experiments, and their load-changer setpoints.

Profiles are mass [kg] per sample, sample ``i`` at ``t_i = i / sample_rate_Hz``, with linear
ramps evaluated exactly at the sample instants. :func:`load_changer_setpoints_V` turns a mass
profile into the load-changer amplifier setpoints that put the force ``m g`` on the pan.
"""

from __future__ import annotations

import math
from typing import Tuple

import numpy as np

from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.weighing.errors import WeighingError


def _positive(name: str, value: float) -> float:
    out = float(value)
    if not (math.isfinite(out) and out > 0.0):
        raise WeighingError(f'{name}: must be finite and > 0, got {value!r}')
    return out


def _non_negative(name: str, value: float) -> float:
    out = float(value)
    if not (math.isfinite(out) and out >= 0.0):
        raise WeighingError(f'{name}: must be finite and >= 0, got {value!r}')
    return out


def _finite(name: str, value: float) -> float:
    out = float(value)
    if not math.isfinite(out):
        raise WeighingError(f'{name}: must be finite, got {value!r}')
    return out


def _indices(sample_rate_Hz: float, duration_s: float) -> np.ndarray:
    fs = _positive('sample_rate_Hz', sample_rate_Hz)
    n = int(round(_positive('duration_s', duration_s) * fs))
    if n < 1:
        raise WeighingError(f'duration_s: {duration_s!r} s is less than one sample at {fs} Hz')
    return np.arange(n, dtype=float)


def _samples(duration_s: float, sample_rate_Hz: float) -> float:
    # a duration in samples, snapped to a whole number within 1e-6 samples (float sums of
    # decimal seconds such as 0.1 + 0.2 must not move a breakpoint off the sample grid)
    x = duration_s * float(sample_rate_Hz)
    return float(round(x)) if abs(x - round(x)) < 1.0e-6 else x


def _ramp(i: np.ndarray, start: float, length: float) -> np.ndarray:
    # in samples, so that breakpoints on the sample grid are hit exactly
    if length > 0.0:
        return np.clip((i - start) / length, 0.0, 1.0)
    return (i >= start).astype(float)


def step(sample_rate_Hz: float, duration_s: float, step_time_s: float, mass_kg: float,
         initial_mass_kg: float = 0.0) -> np.ndarray:
    """
    A mass step.

    Parameters
    ----------
    sample_rate_Hz : float
        Sample rate [Hz].
    duration_s : float
        Profile length [s] (``round(duration_s * fs)`` samples).
    step_time_s : float
        Time of the step [s], >= 0: samples with ``t_i >= step_time_s`` carry ``mass_kg``.
    mass_kg : float
        Mass after the step [kg].
    initial_mass_kg : float
        Mass before the step [kg].

    Returns
    -------
    ndarray
        Mass per sample [kg].
    """
    i = _indices(sample_rate_Hz, duration_s)
    t_step = _non_negative('step_time_s', step_time_s)
    before = _finite('initial_mass_kg', initial_mass_kg)
    after = _finite('mass_kg', mass_kg)
    return np.where(_ramp(i, _samples(t_step, sample_rate_Hz), 0.0) > 0.0, after, before)


def trapezoid(sample_rate_Hz: float, mass_kg: float, rise_s: float, hold_s: float,
              fall_s: float, start_s: float = 0.0, end_s: float = 0.0,
              base_mass_kg: float = 0.0) -> np.ndarray:
    """
    A trapezoidal load: ramp up, hold, ramp down.

    Parameters
    ----------
    sample_rate_Hz : float
        Sample rate [Hz].
    mass_kg : float
        Mass added at the top of the trapezoid [kg].
    rise_s, hold_s, fall_s : float
        Ramp-up, hold and ramp-down times [s], >= 0 (0: a step).
    start_s : float
        Time at ``base_mass_kg`` before the rise [s].
    end_s : float
        Time at ``base_mass_kg`` after the fall [s].
    base_mass_kg : float
        Mass outside the trapezoid [kg].

    Returns
    -------
    ndarray
        Mass per sample [kg]; ``round((start + rise + hold + fall + end) fs)`` samples.
    """
    rise = _non_negative('rise_s', rise_s)
    hold = _non_negative('hold_s', hold_s)
    fall = _non_negative('fall_s', fall_s)
    start = _non_negative('start_s', start_s)
    end = _non_negative('end_s', end_s)
    base = _finite('base_mass_kg', base_mass_kg)
    top = _finite('mass_kg', mass_kg)
    i = _indices(sample_rate_Hz, start + rise + hold + fall + end)
    n_start, n_rise, n_hold, n_fall = (_samples(d, sample_rate_Hz)
                                       for d in (start, rise, hold, fall))
    shape = (_ramp(i, n_start, n_rise) - _ramp(i, n_start + n_rise + n_hold, n_fall))
    return base + top * shape


def check_weigher_pulse(sample_rate_Hz: float, mass_kg: float, duration_s: float,
                        ramp_s: float, lead_s: float = 0.1, tail_s: float = 0.1) -> np.ndarray:
    """
    A load passing over the pan of a check weigher.

    The load enters over ``ramp_s`` (its length over the belt speed), is fully on the pan,
    and leaves over ``ramp_s``; ``duration_s`` is the whole time any part of it is on the pan
    (pan plus load length over the belt speed), so the full load is on for
    ``duration_s - 2 ramp_s``.

    Parameters
    ----------
    sample_rate_Hz : float
        Sample rate [Hz].
    mass_kg : float
        Mass of the load [kg].
    duration_s : float
        Time from first contact to departure [s], >= ``2 ramp_s``.
    ramp_s : float
        Ramp-in and ramp-out time [s], >= 0.
    lead_s, tail_s : float
        Empty-pan time before and after [s].

    Returns
    -------
    ndarray
        Mass per sample [kg].

    Raises
    ------
    WeighingError
        If ``duration_s < 2 ramp_s`` or an argument is invalid.
    """
    ramp = _non_negative('ramp_s', ramp_s)
    total = _positive('duration_s', duration_s)
    if total < 2.0 * ramp:
        raise WeighingError(f'duration_s: {duration_s!r} s is shorter than the two ramps '
                            f'(2 x {ramp_s!r} s)')
    return trapezoid(sample_rate_Hz, mass_kg, ramp, total - 2.0 * ramp, ramp, lead_s, tail_s)


def load_changer_setpoints_V(mass_kg, params: BalanceParameters) -> np.ndarray:
    """
    Load-changer amplifier setpoints that put the force ``m g`` on the pan.

    Inverts the load changer ``F(I)`` (force on the pan, positive down; default
    ``3.982e-4 N - 0.904 N/A I``, so the current is negative for a positive force and a
    setpoint of 0 V is NOT zero force) and then the load-changer amplifier ``I(U)``, both with
    the Newton inverses of :mod:`emfc_ros.core.model.peripherals`. A mass of 0 kg gives the
    setpoint that cancels the load changer's offset force.

    Parameters
    ----------
    mass_kg : float or array_like
        Mass equivalent of the pan force per sample [kg].
    params : BalanceParameters
        Gravity, load changer, its amplifier and converter limits.

    Returns
    -------
    ndarray
        Setpoint voltages [V], same shape as ``mass_kg``.

    Raises
    ------
    WeighingError
        If a mass is not finite, or needs a current beyond the load changer's current limit
        or a setpoint beyond the DAC range (the message gives the reachable masses).
    """
    m = np.asarray(mass_kg, dtype=float)
    if not np.all(np.isfinite(m)):
        raise WeighingError('mass_kg: contains non-finite values')
    g = params.mechanics.g_m_per_s2
    conv = params.converters
    lc = params.load_changer
    current = np.asarray(lc.current_A(m * g), dtype=float)
    limit = conv.load_changer_current_limit_A
    if np.any(np.abs(current) > limit):
        reach = sorted(float(lc.force_N(s * limit)) / g for s in (-1.0, 1.0))
        raise WeighingError(f'mass_kg: the load changer reaches {reach[0]:.6g} to '
                            f'{reach[1]:.6g} kg within +/-{limit} A; got '
                            f'{float(m.min()):.6g} to {float(m.max()):.6g} kg')
    volts = np.asarray(params.load_changer_amplifier.voltage_V(current), dtype=float)
    if np.any(np.abs(volts) > conv.dac_range_V):
        raise WeighingError(f'mass_kg: setpoints up to {float(np.abs(volts).max()):.6g} V '
                            f'exceed the DAC range of +/-{conv.dac_range_V} V')
    return volts


def parse_load_schedule(text: str, max_mass_kg: float = 2.0) -> Tuple[Tuple[float, float], ...]:
    """
    Parse a load schedule ``'t:kg,t:kg,...'`` (simulated seconds : mass on the pan).

    ``'0:0,2:0.0734829,5:0'``: empty pan from 0 s, 73.4829 g from 2 s, empty again from 5 s.
    An empty text is no schedule.

    Parameters
    ----------
    text : str
        The schedule: comma-separated ``time_s:mass_kg`` pairs, times strictly increasing.
    max_mass_kg : float
        Largest mass accepted [kg].

    Returns
    -------
    tuple of (float, float)
        ``(time_s, mass_kg)`` pairs in order.

    Raises
    ------
    WeighingError
        Naming the entry that is malformed, negative, out of order or too heavy.
    """
    out = []
    text = str(text).strip()
    if not text:
        return ()
    for k, item in enumerate(text.split(',')):
        parts = item.strip().split(':')
        if len(parts) != 2:
            raise WeighingError(f'load schedule entry {k + 1} {item.strip()!r}: need '
                                'time_s:mass_kg (for example 2:0.0734829)')
        try:
            t, m = float(parts[0]), float(parts[1])
        except ValueError:
            raise WeighingError(f'load schedule entry {k + 1} {item.strip()!r}: time and mass '
                                'must be numbers') from None
        if not (math.isfinite(t) and t >= 0.0):
            raise WeighingError(f'load schedule entry {k + 1} {item.strip()!r}: time must be '
                                '>= 0 s')
        if not (math.isfinite(m) and 0.0 <= m <= max_mass_kg):
            raise WeighingError(f'load schedule entry {k + 1} {item.strip()!r}: mass must be '
                                f'from 0 to {max_mass_kg:g} kg')
        if out and t <= out[-1][0]:
            raise WeighingError(f'load schedule entry {k + 1} {item.strip()!r}: times must '
                                'increase')
        out.append((t, m))
    return tuple(out)
