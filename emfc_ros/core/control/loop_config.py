"""
Configuration of the in-loop position controller and the precise current channel.

Parsed from a mapping (a ``control:`` section of a YAML file or the flattened ``control.*``
parameters of a node) with every error naming the dotted key.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Mapping, Optional, Tuple

from emfc_ros.core.config import get_bool, get_float, get_int, reject_unknown
from emfc_ros.core.errors import ConfigError

CONTROL_KEYS = ('enabled', 'rate_Hz', 'crossover_Hz', 'phase_margin_deg', 'delay_samples',
                'notch_Hz', 'notch_quality', 'position_setpoint_m', 'design_load_mass_kg',
                'max_load_kg')
CHANNEL_KEYS = ('shunt_ohm', 'adc_bits', 'adc_range_V', 'noise_V_rms')


@dataclasses.dataclass(frozen=True)
class LoopConfig:
    """
    The in-loop controller: where it runs and what it is designed for.

    Attributes
    ----------
    rate_Hz : float
        Controller sample rate [Hz]; the simulator's rate must be an integer multiple.
    crossover_Hz : float
        Design crossover [Hz] (130 Hz: a step of any load up to 200 g settles within 0.1 mg
        in 100 ms and keeps the lever within 40 um, ``docs/closed_loop.md``).
    phase_margin_deg : float
        Design phase margin [deg].
    delay_samples : float
        Computation and transport delay [controller samples]; times the simulator samples per
        controller sample it must be a whole number >= 1. Default 1: the controller reads
        the ADC at one sample and writes the DAC at the next, as on the device's FPGA; with
        the hold's half sample, which the design adds, the loop has the 1.5 samples of delay
        of the model notes (``docs/closed_loop.md``), and it fits any simulator rate that is
        a multiple of the controller's, the equal default rates of 10 kHz included.
    notch_Hz : float or None
        Notch centre [Hz], None for none (the default: the lever's mode moves from 410 Hz
        empty to 333 Hz with 200 g, and at 10 kHz the loop keeps it phase-stabilised at every
        load without a notch).
    notch_quality : float
        Notch quality factor.
    position_setpoint_m : float
        Lever-end position the loop holds [m].
    design_load_mass_kg : float
        Mass on the pan of the model the controller is designed on [kg].
    max_load_kg : float
        Top of the weighing range [kg]: the design is checked at loads from 0 to here
        (:func:`emfc_ros.core.control.robust.check_load_range`) and refused if it fails.
    """

    rate_Hz: float = 10000.0
    crossover_Hz: float = 130.0
    phase_margin_deg: float = 40.0
    delay_samples: float = 1.0
    notch_Hz: Optional[float] = None
    notch_quality: float = 5.0
    position_setpoint_m: float = 0.0
    design_load_mass_kg: float = 0.0
    max_load_kg: float = 0.2


@dataclasses.dataclass(frozen=True)
class CurrentChannelConfig:
    """
    The precise coil-current measurement: a shunt resistor into a high-resolution ADC.

    Real weighing cells measure the compensation current this way (a precision resistor and
    an integrating or sigma-delta converter), not through the 16-bit monitor.

    Attributes
    ----------
    shunt_ohm : float
        Shunt resistance [ohm].
    adc_bits : int
        Converter resolution [bit].
    adc_range_V : float
        Converter full scale, +/- [V].
    noise_V_rms : float
        Converter input noise per sample [V rms].
    """

    shunt_ohm: float = 20.0
    adc_bits: int = 24
    adc_range_V: float = 2.5
    noise_V_rms: float = 1.0e-6


def loop_config(cfg: Mapping[str, Any], path: str = 'control') -> Optional[LoopConfig]:
    """
    Read a ``control`` mapping; None when it is absent or ``enabled`` is false.

    Parameters
    ----------
    cfg : Mapping
        The mapping (keys of :data:`CONTROL_KEYS`).
    path : str
        Its dotted path, for error messages.

    Returns
    -------
    LoopConfig or None
        The configuration, or None for open loop.

    Raises
    ------
    ConfigError
        A key that is unknown, of the wrong type or out of range (named in the message).
    """
    if not cfg:
        return None
    reject_unknown(cfg, CONTROL_KEYS, path)
    if not get_bool(cfg, 'enabled', path, default=True):
        return None
    d = LoopConfig()
    notch = cfg.get('notch_Hz', None)
    if notch is not None and notch != 0 and notch != 0.0:
        notch = get_float(cfg, 'notch_Hz', path, minimum=0.0, min_exclusive=True)
    else:
        notch = None
    return LoopConfig(
        rate_Hz=get_float(cfg, 'rate_Hz', path, default=d.rate_Hz, minimum=0.0,
                          min_exclusive=True),
        crossover_Hz=get_float(cfg, 'crossover_Hz', path, default=d.crossover_Hz, minimum=0.0,
                               min_exclusive=True),
        phase_margin_deg=get_float(cfg, 'phase_margin_deg', path, default=d.phase_margin_deg,
                                   minimum=0.0, maximum=89.0, min_exclusive=True),
        delay_samples=get_float(cfg, 'delay_samples', path, default=d.delay_samples,
                                minimum=0.0),
        notch_Hz=notch,
        notch_quality=get_float(cfg, 'notch_quality', path, default=d.notch_quality,
                                minimum=0.0, min_exclusive=True),
        position_setpoint_m=get_float(cfg, 'position_setpoint_m', path,
                                      default=d.position_setpoint_m, minimum=-1.0e-4,
                                      maximum=1.0e-4),
        design_load_mass_kg=get_float(cfg, 'design_load_mass_kg', path,
                                      default=d.design_load_mass_kg, minimum=0.0,
                                      maximum=2.0),
        max_load_kg=get_float(cfg, 'max_load_kg', path, default=d.max_load_kg, minimum=0.0,
                              maximum=2.0))


def loop_timing(config: LoopConfig, sample_rate_Hz: float,
                path: str = 'control') -> Tuple[int, int]:
    """
    Check that a loop fits a simulator's (or a device's) sample clock.

    The simulator's rate must be a whole multiple ``M`` of the controller's, and the delay a
    whole number of simulator samples, at least one: ``delay_samples * M``.

    Parameters
    ----------
    config : LoopConfig
        The loop.
    sample_rate_Hz : float
        The simulator's sample rate [Hz] (the node's ``sample_rate_Hz``).
    path : str
        Dotted path of the loop's keys, for messages.

    Returns
    -------
    ratio : int
        Simulator samples per controller sample, ``M``.
    delay_sim_samples : int
        The delay [simulator samples].

    Raises
    ------
    ConfigError
        Naming ``<path>.rate_Hz`` or ``<path>.delay_samples``, the rates involved and values
        that fit.
    """
    fs = float(sample_rate_Hz)
    ratio = fs / config.rate_Hz
    if ratio < 1.0 - 1e-9 or abs(ratio - round(ratio)) > 1e-9:
        raise ConfigError(f'{path}.rate_Hz', f'{config.rate_Hz:g} Hz must divide the simulator '
                          f'rate sample_rate_Hz = {fs:g} Hz (a whole number of simulator '
                          f'samples per controller sample)')
    m = int(round(ratio))
    delay = config.delay_samples * m
    if delay < 1.0 - 1e-9 or abs(delay - round(delay)) > 1e-9:
        fits = sorted({max(1, math.floor(delay)) / m, max(1, math.ceil(delay)) / m})
        k = next((k for k in range(1, 101) if abs(config.delay_samples * k - round(
            config.delay_samples * k)) < 1e-9 and config.delay_samples * k >= 1.0), None)
        rate_hint = (f', or sample_rate_Hz = {k * config.rate_Hz:g} Hz' if k is not None
                     else '')
        raise ConfigError(f'{path}.delay_samples', f'{config.delay_samples:g} controller samples '
                          f'at {path}.rate_Hz = {config.rate_Hz:g} Hz is {delay:g} samples of '
                          f'the simulator at sample_rate_Hz = {fs:g} Hz; it must be a whole '
                          f'number >= 1: use {path}.delay_samples = '
                          f'{" or ".join(f"{v:g}" for v in fits)}{rate_hint}')
    return m, int(round(delay))


def current_channel_config(cfg: Mapping[str, Any],
                           path: str = 'current_channel') -> CurrentChannelConfig:
    """
    Read a ``current_channel`` mapping (absent keys take the defaults).

    Parameters
    ----------
    cfg : Mapping
        The mapping (keys of :data:`CHANNEL_KEYS`).
    path : str
        Its dotted path, for error messages.

    Returns
    -------
    CurrentChannelConfig
        The configuration.

    Raises
    ------
    ConfigError
        A key that is unknown, of the wrong type or out of range.
    """
    cfg = cfg or {}
    reject_unknown(cfg, CHANNEL_KEYS, path)
    d = CurrentChannelConfig()
    return CurrentChannelConfig(
        shunt_ohm=get_float(cfg, 'shunt_ohm', path, default=d.shunt_ohm, minimum=0.0,
                            min_exclusive=True),
        adc_bits=get_int(cfg, 'adc_bits', path, default=d.adc_bits, minimum=8, maximum=32),
        adc_range_V=get_float(cfg, 'adc_range_V', path, default=d.adc_range_V, minimum=0.0,
                              min_exclusive=True),
        noise_V_rms=get_float(cfg, 'noise_V_rms', path, default=d.noise_V_rms, minimum=0.0))
