"""
The plant_simulator's configuration: parameter values to a checked :class:`PlantConfig`.

Pure functions of plain values (the node reads its parameters and passes them here): the
start-up checks with the reasons the node reports, the balance and the simulator built from
them, and the checks of a run-time parameter change.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from pathlib import Path
from typing import Any, Callable, List, Mapping, Optional, Tuple

from emfc_ros.core.config import unflatten
from emfc_ros.core.control.loop_config import loop_config, loop_timing
from emfc_ros.core.errors import ConfigError
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.paths import config_file
from emfc_ros.core.sim.load_schedule import LoadEntry
from emfc_ros.core.sim.plant_parameters import (
    CONTROL_PREFIX, DEFAULT_BALANCE, LOCKSTEP_MATCH, PARAMETERS, READ_ONLY, TIME_MODES)
from emfc_ros.core.sim.simulator import Simulator
from emfc_ros.core.weighing.errors import WeighingError
from emfc_ros.core.weighing.profiles import parse_load_schedule


@dataclass
class PlantConfig:
    """
    The checked start-up configuration of a plant session (parameter names as the node's).

    ``lockstep_period`` is ``sample_rate_Hz / state_rate_Hz`` in lockstep mode (0 otherwise,
    or when it is refused); ``errors`` the reasons the configuration is refused, in the order
    the checks ran (the last one is the session's error).
    """

    sample_rate_Hz: float = 10000.0
    block_size: int = 1000
    time_mode: str = 'owner'
    state_rate_Hz: float = 1000.0
    command_timeout_s: float = 0.1
    command_delay_periods: int = 1
    lockstep_match: str = 'stamp'
    publish_groups: bool = True
    max_state_wall_rate_Hz: float = 500.0
    min_subscribers: int = 0
    load_mass_kg: float = 0.0
    load_changer_coupled: bool = False
    load_schedule: List[LoadEntry] = field(default_factory=list)
    lockstep_period: int = 0
    control: dict = field(default_factory=dict)
    errors: List[str] = field(default_factory=list)


def plant_config(value: Callable[[str], Any]) -> PlantConfig:
    """
    Check the start-up parameters.

    Parameters
    ----------
    value : callable
        Parameter name (a key of ``PARAMETERS``) to its value.

    Returns
    -------
    PlantConfig
        The configuration; refused values are replaced by their defaults and the reasons
        listed in ``errors``.
    """
    rate = float(value('sample_rate_Hz'))
    cfg = PlantConfig(
        sample_rate_Hz=rate, block_size=int(value('block_size')),
        time_mode=str(value('time_mode')), state_rate_Hz=float(value('state_rate_Hz')),
        command_timeout_s=float(value('command_timeout_s')),
        publish_groups=bool(value('publish_groups')),
        load_mass_kg=float(value('load_mass_kg')),
        load_changer_coupled=bool(value('load_changer_coupled')),
        control={n[len(CONTROL_PREFIX):]: value(n) for n in PARAMETERS
                 if n.startswith(CONTROL_PREFIX)})
    err = cfg.errors.append
    control = control_error(cfg.control, rate, cfg.time_mode)
    if control:
        err(control)
    wall_rate = value('max_state_wall_rate_Hz')
    if _number(wall_rate) and math.isfinite(wall_rate) and wall_rate >= 0.0:
        cfg.max_state_wall_rate_Hz = float(wall_rate)
    else:
        err(f'max_state_wall_rate_Hz must be a number >= 0 [Hz], got {wall_rate!r}; '
            'using 500 Hz until the node is restarted with a valid value')
    try:
        cfg.load_schedule = [(int(round(t * rate)), float(m), None)
                             for t, m in parse_load_schedule(str(value('load_schedule')))]
    except WeighingError as exc:
        err(f'load_schedule refused: {exc}; restart the node with a valid schedule')
    if cfg.time_mode not in TIME_MODES:
        err(f'time_mode must be one of {list(TIME_MODES)}, got {cfg.time_mode!r}')
    elif cfg.time_mode == 'lockstep':
        _check_lockstep(cfg, value('command_delay_periods'), value('lockstep_match'), err)
    subscribers = value('min_subscribers')
    if _number(subscribers) and isinstance(subscribers, int) and 0 <= subscribers <= 100:
        cfg.min_subscribers = subscribers
    else:
        err(f'min_subscribers must be a whole number from 0 to 100, got {subscribers!r}; '
            'using 0 until the node is restarted with a valid value')
    return cfg


def _check_lockstep(cfg: PlantConfig, delay: Any, match: Any, err: Callable) -> None:
    """The lockstep parameters: a whole number of samples per controller period."""
    rate, state = cfg.sample_rate_Hz, cfg.state_rate_Hz
    ratio = rate / state if state > 0.0 else 0.0
    n = int(round(ratio))
    if state <= 0.0 or n < 1 or abs(ratio - n) > 1e-9 * ratio:
        err(f'time_mode lockstep needs state_rate_Hz > 0 dividing sample_rate_Hz into a whole '
            f'number of samples per period; got {rate} Hz / {state} Hz = {ratio:g} samples')
    elif isinstance(delay, bool) or delay not in (0, 1):
        err(f'command_delay_periods must be 0 or 1, got {delay!r}')
    elif match not in LOCKSTEP_MATCH:
        err(f'lockstep_match must be one of {list(LOCKSTEP_MATCH)}, got {match!r}')
    else:
        cfg.lockstep_period, cfg.command_delay_periods = n, int(delay)
        cfg.lockstep_match = str(match)


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def control_error(control: Mapping[str, Any], sample_rate_Hz: float, time_mode: str) -> str:
    """
    The reason the ``control.*`` parameters do not fit the plant, or ''.

    Parameters
    ----------
    control : mapping
        The ``control.*`` parameters without their prefix.
    sample_rate_Hz : float
        The simulator's sample rate [Hz].
    time_mode : str
        The plant's time mode.

    Returns
    -------
    str
        Empty, or the reason.
    """
    try:
        loop = loop_config(dict(control))
        if loop is not None:
            loop_timing(loop, sample_rate_Hz)
    except ConfigError as exc:
        return (f'control configuration refused: {exc} (control.* and sample_rate_Hz are '
                'fixed at start-up: restart the node with values that fit; '
                'docs/closed_loop.md)')
    if loop is not None and time_mode == 'lockstep':
        return ('control configuration refused: control.enabled: the in-loop controller '
                'and the lockstep mode (an external controller) exclude each other')
    return ''


def load_balance(path: str, flat: Mapping[str, Any],
                 overrides: Optional[Mapping[str, Any]] = None) -> BalanceParameters:
    """
    The balance: from ``path``, else from the flattened ``balance.*`` values, else the default.

    Parameters
    ----------
    path : str
        ``balance_file`` (empty: none).
    flat : mapping
        The ``balance.*`` parameters without their prefix.
    overrides : mapping, optional
        Parameters about to be set (``balance_file``, ``balance.*``; others are ignored).

    Returns
    -------
    BalanceParameters
        The balance.

    Raises
    ------
    ValueError, OSError
        If the file or the values are refused.
    """
    flat = dict(flat)
    for name, value in (overrides or {}).items():
        if name == 'balance_file':
            path = value
        elif name.startswith('balance.'):
            flat[name[len('balance.'):]] = value
    if path:
        return BalanceParameters.load_yaml(Path(path))
    if not flat:
        return BalanceParameters.load_yaml(config_file(DEFAULT_BALANCE))
    flat = {k: (list(v) if not isinstance(v, (str, bytes, bool, int, float)) else v)
            for k, v in flat.items()}
    tree = unflatten(flat)
    return BalanceParameters.from_mapping(tree['balance'] if 'balance' in tree else tree)


def make_simulator(balance: BalanceParameters, value: Callable[[str], Any],
                   load_mass_kg: float, coupled: bool) -> Tuple[object, str]:
    """
    The simulator of the parameters, closed-loop when ``control.enabled``.

    Parameters
    ----------
    balance : BalanceParameters
        The balance.
    value : callable
        Parameter name to value (``sample_rate_Hz``, ``seed``, ``noise``, ``quantisation``,
        ``substeps``, ``hold``, ``time_mode``, ``control.*``).
    load_mass_kg : float
        Mass on the pan [kg].
    coupled : bool
        Load changer's moving mass coupled to the pan.

    Returns
    -------
    tuple
        The simulator (``Simulator`` or ``ClosedLoopSimulator``) and a line for the log
        (empty without the controller).

    Raises
    ------
    ValueError
        If the ``control.*`` parameters are refused.
    """
    substeps = int(value('substeps'))
    sim = Simulator(balance, float(value('sample_rate_Hz')), seed=int(value('seed')),
                    noise=bool(value('noise')), quantisation=bool(value('quantisation')),
                    substeps=substeps or None, hold=str(value('hold')),
                    load_mass_kg=float(load_mass_kg), load_changer_coupled=bool(coupled))
    try:
        loop = loop_config({n[len(CONTROL_PREFIX):]: value(n) for n in PARAMETERS
                            if n.startswith(CONTROL_PREFIX)})
    except ConfigError as exc:
        raise ValueError(str(exc)) from exc
    if loop is None:
        return sim, ''
    if value('time_mode') == 'lockstep':
        raise ValueError('control.enabled: the in-loop controller and the lockstep mode '
                         '(an external controller) exclude each other')
    # Imported here: the controller design needs scipy.signal (a second of start-up).
    from emfc_ros.core.sim.closed_loop import ClosedLoopSimulator
    looped = ClosedLoopSimulator(sim, loop)
    d = looped.design
    return looped, (
        f'in-loop controller at {loop.rate_Hz:g} Hz: crossover {d.crossover_Hz:.1f} Hz, '
        f'phase margin {d.phase_margin_deg:.1f} deg, gain margins '
        f'{d.lower_gain_margin_dB} / '
        f'{d.upper_gain_margin_dB} dB, sensitivity peak {d.sensitivity_peak:.2f}')


def runtime_refusal(name: str, value: Any, sample_rate_Hz: float, time_mode: str) -> str:
    """
    Why a run-time change of one parameter is refused, or ''.

    Parameters
    ----------
    name : str
        The parameter.
    value : any
        Its new value.
    sample_rate_Hz : float
        The simulator's sample rate [Hz] (the top of ``state_rate_Hz``).
    time_mode : str
        The plant's time mode (``state_rate_Hz`` is fixed in lockstep mode).

    Returns
    -------
    str
        Empty, or the reason.
    """
    if name in READ_ONLY or (time_mode == 'lockstep' and name == 'state_rate_Hz'):
        return f'{name} is fixed at start-up; restart the node with the new value'
    if name == 'load_mass_kg' and not (_number(value) and 0.0 <= float(value) <= 2.0):
        return f'load_mass_kg must be a number from 0 to 2 kg, got {value!r}'
    if name == 'load_changer_coupled' and not isinstance(value, bool):
        return 'load_changer_coupled must be true or false'
    if name == 'state_rate_Hz' and not (_number(value) and
                                        0.0 <= float(value) <= sample_rate_Hz):
        return f'state_rate_Hz must be from 0 to {sample_rate_Hz} Hz, got {value!r}'
    if name == 'command_timeout_s' and not (_number(value) and 0.0 < float(value) <= 60.0):
        return f'command_timeout_s must be in (0, 60] s, got {value!r}'
    return ''
