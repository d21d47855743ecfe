"""
The daq_bridge's settings: its parameter values checked and turned into core objects.

:func:`bridge_settings` takes the node's parameters as a flat mapping (name to value, the
names of ``docs/daq_bridge.md``) and returns what a
:class:`~emfc_ros.core.device.bridge_session.BridgeSession` runs with: the back-end (through
the registry), the device configuration, the function-generator specs, the run-time values,
what the measurement description declares. Every refusal is a
:class:`~emfc_ros.core.errors.ConfigError` naming the parameter.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Dict, List, Mapping, Optional, Tuple

from emfc_ros.core.device import registry
from emfc_ros.core.device.backend import (check_generator_range, DEVICE_CONFIG_KEYS,
                                          DeviceBackend, DeviceConfig)
from emfc_ros.core.device.errors import DeviceConfigError
from emfc_ros.core.device.function_generator import GeneratorSpec, make_signal
from emfc_ros.core.errors import ConfigError, EmfcError
from emfc_ros.core.model.balance_file import load_balance
from emfc_ros.core.pan_load import declared_pan_load

#: ``excitation_mode``: the host streams the excitation, or the device's generator makes it.
EXCITATION_MODES = ('stream', 'function_generator')
#: Parameters settable while running, with their bounds: (low, high, low included). The
#: upper bound of ``state_rate_Hz`` is the sample rate.
RUNTIME_LIMITS = {'watchdog_timeout_s': (0.0, 3600.0, False),
                  'command_timeout_s': (0.0, 60.0, False),
                  'state_rate_Hz': (0.0, math.inf, True),
                  'excitation_lead_s': (0.0, 10.0, True)}
RUNTIME = tuple(RUNTIME_LIMITS)
#: Function-generator fields (``funcgen.<output>.<field>``): default and description.
FUNCGEN_FIELDS = {
    'waveform': ('off', "'off' (follow the excitation stream), 'sine', 'chirp', 'prbs', "
                        "'constant'"),
    'amplitude_V': (0.0, 'peak amplitude [V] (PRBS: +/- levels)'),
    'frequency_Hz': (0.0, 'sine frequency, chirp start frequency [Hz]'),
    'f_stop_Hz': (0.0, 'chirp stop frequency [Hz]'),
    'sweep_time_s': (1.0, 'chirp sweep duration [s]'),
    'method': ('logarithmic', "chirp law: 'linear' or 'logarithmic'"),
    'phase_rad': (0.0, 'phase at sample 0 [rad]'),
    'prbs_order': (10, 'PRBS register length, 2 to 31'),
    'prbs_hold_samples': (1, 'samples per PRBS bit [samples]'),
    'gain': (1.0, 'signal matching gain [1]'),
    'offset_V': (0.0, 'signal matching offset [V]'),
}


def funcgen_key(output: str) -> str:
    """
    The parameter group of an output's generator: its name without the ``_V`` suffix.

    Parameters
    ----------
    output : str
        The output's name (``coil_V``).

    Returns
    -------
    str
        The key (``coil``): parameters ``funcgen.coil.*``.
    """
    return output[:-2] if output.endswith('_V') and len(output) > 2 else output


@dataclasses.dataclass
class BridgeSettings:
    """
    Everything a bridge session runs with.

    Attributes
    ----------
    backend : DeviceBackend
        The back-end (not yet configured).
    device : DeviceConfig
        Its configuration (a recording's own for a replay).
    balance : BalanceParameters
        The balance (effort commands to coil setpoints, positions from ``sensor_V``).
    mode : str
        One of :data:`EXCITATION_MODES`.
    specs : list of GeneratorSpec
        One per output (``'off'``: the output follows the stream).
    runtime : dict
        The run-time settable values, :data:`RUNTIME` [s, Hz].
    pan : dict
        The declared pan load (``extra`` of the description).
    resolution : dict
        Per input: code ``step`` and ``noise_rms`` [unit] (``extra.resolution``).
    """

    backend: DeviceBackend
    device: DeviceConfig
    balance: Any
    mode: str
    specs: List[GeneratorSpec]
    runtime: Dict[str, float]
    pan: Dict[str, Any]
    resolution: Dict[str, Dict[str, float]]


def runtime_problem(name: str, value: Any, sample_rate_Hz: float) -> Optional[str]:
    """
    What is wrong with a run-time value (``must be ...``), or None.

    Parameters
    ----------
    name : str
        One of :data:`RUNTIME`.
    value : int or float
        The value.
    sample_rate_Hz : float
        The device's sample rate (the top of ``state_rate_Hz``) [Hz].

    Returns
    -------
    str or None
        The problem with its range, without the name (the caller names it).
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return f'must be a number, got {value!r}'
    low, high, closed = RUNTIME_LIMITS[name]
    high = min(high, sample_rate_Hz)
    v = float(value)
    if not math.isfinite(v) or not (low <= v if closed else low < v) or not v <= high:
        return f'must be in {"[" if closed else "("}{low}, {high}], got {value!r}'
    return None


def generator_specs(config: DeviceConfig, values: Mapping[str, Any]) -> List[GeneratorSpec]:
    """
    The function-generator specs of every output from ``funcgen.<output>.<field>`` values.

    Parameters
    ----------
    config : DeviceConfig
        The device configuration (outputs, limits, rate).
    values : Mapping
        Parameter name to value; missing fields take :data:`FUNCGEN_FIELDS`' defaults.

    Returns
    -------
    list of GeneratorSpec
        One per output, each checked like the device checks it.

    Raises
    ------
    ConfigError
        Naming ``funcgen.<output>`` and the problem.
    """
    specs = []
    for out in config.outputs:
        key = funcgen_key(out.name)
        fields = {}
        for field, (default, _) in FUNCGEN_FIELDS.items():
            value = values.get(f'funcgen.{key}.{field}', default)
            if value is None:
                value = default
            if isinstance(default, float) and isinstance(value, int) and \
                    not isinstance(value, bool):
                value = float(value)
            fields[field] = value
        try:
            spec = GeneratorSpec(**fields)
            make_signal(spec, config.sample_rate_Hz)
            check_generator_range([spec], DeviceConfig(
                config.sample_rate_Hz, config.block_size, config.inputs, (out,),
                config.watchdog_timeout_s))
        except (DeviceConfigError, TypeError) as exc:
            raise ConfigError(f'funcgen.{key}', str(exc)) from None
        specs.append(spec)
    return specs


def _device_mapping(params: Mapping[str, Any]) -> Dict[str, Any]:
    """The registry's mapping: the device keys, the back-end and each back-end's options."""
    cfg: Dict[str, Any] = {'backend': str(params.get('backend', 'sim'))}
    for key in DEVICE_CONFIG_KEYS:
        name = 'device_watchdog_timeout_s' if key == 'watchdog_timeout_s' else key
        value = params.get(name)
        if value is None:
            continue
        cfg[key] = value
    for entry in registry.BACKENDS.values():
        cfg[entry.name] = {o.key: params[f'{entry.name}.{o.key}'] for o in entry.options
                           if params.get(f'{entry.name}.{o.key}') is not None}
    return cfg


def _resolution(config: DeviceConfig, backend: DeviceBackend,
                noise: Optional[List[float]]) -> Dict[str, Dict[str, float]]:
    if backend.recorded_resolution is not None:
        # the recorded values are not codes: what the recording said, or nothing
        return backend.recorded_resolution
    noise = [0.0] * len(config.inputs) if noise is None else [float(v) for v in noise]
    if len(noise) != len(config.inputs) or not all(math.isfinite(v) and v >= 0.0
                                                   for v in noise):
        raise ConfigError('input_noise_rms', f'need {len(config.inputs)} values >= 0 (one '
                                             f'per input), got {noise}')
    return {c.name: {'step': abs(float(c.scale)), 'noise_rms': v}
            for c, v in zip(config.inputs, noise)}


def bridge_settings(params: Mapping[str, Any]) -> BridgeSettings:
    """
    The settings from the bridge's parameter values; builds the back-end.

    Parameters
    ----------
    params : Mapping
        Parameter name to value (``docs/daq_bridge.md``); an unset one may be None.

    Returns
    -------
    BridgeSettings
        The settings.

    Raises
    ------
    ConfigError
        Naming the parameter and what is allowed (no back-end is left open then).
    """
    try:
        return _settings(params)
    except EmfcError:
        raise
    except (TypeError, ValueError, OSError) as exc:    # a value of the wrong kind
        raise ConfigError('parameters', str(exc)) from exc


def _settings(params: Mapping[str, Any]) -> BridgeSettings:
    mode = str(params.get('excitation_mode', 'stream'))
    if mode not in EXCITATION_MODES:
        raise ConfigError('excitation_mode', f'must be one of {list(EXCITATION_MODES)}, got '
                                             f'{mode!r}')
    runtime = {}
    for name in RUNTIME:
        problem = runtime_problem(name, params.get(name), math.inf)
        if problem is not None:
            raise ConfigError(name, problem)
        runtime[name] = float(params[name])
    try:
        balance = load_balance(str(params.get('balance_file') or '') or None)
    except (OSError, ValueError) as exc:
        raise ConfigError('balance_file', str(exc)) from None
    backend, config = registry.backend_from_mapping(_device_mapping(params), balance=balance)
    try:
        pan = declared_pan_load(float(params.get('pan.load_mass_kg', -1.0)),
                                str(params.get('pan.load_changer_coupled', '')))
        problem = runtime_problem('state_rate_Hz', runtime['state_rate_Hz'],
                                  config.sample_rate_Hz)       # its top: the device's rate
        if problem is not None:
            raise ConfigError('state_rate_Hz', problem)
        specs = generator_specs(config, params) if mode == 'function_generator' else \
            [GeneratorSpec()] * len(config.outputs)
        resolution = _resolution(config, backend, params.get('input_noise_rms'))
    except (ConfigError, ValueError):
        backend.close()
        raise
    return BridgeSettings(backend, config, balance, mode, specs, runtime, pan, resolution)


def parameter_mapping(names: Tuple[str, ...], get: Any) -> Dict[str, Any]:
    """
    A flat mapping of parameter values through a getter (a node's ``get_parameter``).

    Parameters
    ----------
    names : tuple of str
        The parameter names.
    get : callable
        ``get(name) -> value`` (None when unset).

    Returns
    -------
    dict
        Name to value, lists for arrays.
    """
    out = {}
    for name in names:
        value = get(name)
        out[name] = value if value is None or isinstance(value, (str, bool, int, float)) \
            else list(value)
    return out
