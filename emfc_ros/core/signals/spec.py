"""
Building experiments from configuration (plain YAML or un-flattened ROS parameters).

Format
------
All keys are refused unless listed here, so typos are caught; every error is a
:class:`~emfc_ros.core.errors.ConfigError` naming the full dotted key (for example
``experiment.section.coil_chirp.coil.signals.sweep.f_stop_Hz``) and the allowed range.
Integers are accepted where floats are expected. ::

    experiment:
      sample_rate_Hz: 10000.0            # required, > 0
      channels: [coil, load_changer]     # optional, this is the default
      limits:                            # optional, per channel, default -10..10 V
        coil: {min_V: -10.0, max_V: 10.0}
      sections: [first, second]          # required: the order of the sections
      section:                           # one entry per name in `sections`, no others
        first:
          duration_s: 10.0               # required, > 0; round(duration_s * fs) samples
          coil:                          # a channel absent from a section outputs 0 V
            gain: 1.0                    # dimensionless, default 1
            offset_V: 0.0                # default 0
            signals:                     # name -> signal, summed in sorted-name order
              sweep: {type: chirp, amplitude_V: 0.01, f_start_Hz: 5.0,
                      f_stop_Hz: 2000.0, method: logarithmic}

Each channel outputs ``gain * sum(signals) + offset_V`` clamped to its limits; every signal
sees the sample index counted from the start of its section. Past the end of the experiment
every channel outputs 0 V clamped to its limits.

Signal types and their keys (``*`` = required; frequencies must lie in [0, fs/2]):

``sine``
    ``amplitude_V*``, ``frequency_Hz*``, ``phase_rad`` (0).
``chirp``
    ``amplitude_V*``, ``f_start_Hz*``, ``f_stop_Hz*`` (both > 0), ``sweep_time_s`` (the
    section duration), ``method`` (``linear`` | ``logarithmic``, default ``logarithmic``),
    ``after_sweep`` (``repeat`` with continuous phase | ``zero``; default ``repeat``),
    ``phase_rad`` (0).
``multisine``
    ``rms_V*``, ``period_samples*`` (>= 3; lines are harmonics of fs / period_samples), either
    ``lines`` (list of harmonic numbers) or ``f_min_Hz`` / ``f_max_Hz`` with ``odd_only``
    (false); ``phases`` (``schroeder`` | ``random``, default ``schroeder``), ``seed`` (0).
``prbs``
    ``order*`` (2..31, scipy's max_len_seq taps), ``low_V*``, ``high_V*``,
    ``hold_samples`` (samples per bit, 1); period ``(2^order - 1) hold_samples``.
``uniform_noise``
    ``low_V*``, ``high_V*``, ``seed`` (0).
``gaussian_noise``
    ``std_V*``, ``mean_V`` (0), ``seed`` (0).
``steps``
    ``times_s*`` (increasing, from the section start), ``levels_V*`` (same length); 0 V
    before the first time.
``staircase``
    ``start_V*``, ``step_V*``, ``count*``, ``dwell_s*``, ``start_time_s`` (0),
    ``up_and_down`` (false: also walk back down).
``constant``
    ``value_V*``.
``waveform``
    ``path*`` (CSV or NPY, relative to the config file's folder), ``column`` (CSV: name
    ending in ``_V``, default the only such column; NPY 2-D: index), ``file_sample_rate_Hz``
    (required for NPY, must equal ``sample_rate_Hz``), ``end`` (``zero`` | ``hold`` |
    ``repeat``, default ``zero``).

:func:`load_experiment_file` reads either a plain YAML with a top-level ``experiment:``
mapping, or a ROS 2 parameters file ``<node name or /**>: {ros__parameters: {experiment:
...}}`` (nested or dotted keys).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, Mapping, Optional, Union

import yaml

from emfc_ros.core.config import (get_bool, get_float, get_float_list, get_int, get_mapping,
                                  get_str, get_str_list, join, reject_unknown, unflatten)
from emfc_ros.core.errors import ConfigError, SignalError, WaveformFileError
from emfc_ros.core.safe_yaml import load_yaml_file, one_line
from emfc_ros.core.signals.base import Signal
from emfc_ros.core.signals.chirp import AFTER_SWEEP, Chirp, METHODS
from emfc_ros.core.signals.experiment import (ChannelLimits, ChannelPlan, DEFAULT_CHANNELS,
                                              Experiment, Section)
from emfc_ros.core.signals.multisine import Multisine, PHASES
from emfc_ros.core.signals.noise import GaussianNoise, UniformNoise
from emfc_ros.core.signals.prbs import MAX_ORDER, MIN_ORDER, Prbs
from emfc_ros.core.signals.sine import Sine
from emfc_ros.core.signals.steps import Constant, staircase, Steps
from emfc_ros.core.signals.waveform import END_MODES, load_waveform

EXPERIMENT_KEYS = ('sample_rate_Hz', 'channels', 'limits', 'sections', 'section')
CHANNEL_KEYS = ('gain', 'offset_V', 'signals')
LIMIT_KEYS = ('min_V', 'max_V')
MAX_SAMPLE_RATE_Hz = 1e7
MAX_SEED = 2 ** 63 - 1


class _Context:
    """What a signal builder needs besides its own mapping."""

    def __init__(self, sample_rate_Hz: float, duration_s: float,
                 base_dir: Optional[Path]) -> None:
        self.fs = sample_rate_Hz
        self.nyquist_Hz = 0.5 * sample_rate_Hz
        self.duration_s = duration_s
        self.base_dir = base_dir


def _freq(cfg: Mapping, key: str, path: str, ctx: _Context, positive: bool = True,
          **kw: Any) -> float:
    return get_float(cfg, key, path, minimum=0.0, min_exclusive=positive,
                     maximum=ctx.nyquist_Hz, **kw)


def _seed(cfg: Mapping, path: str) -> int:
    return get_int(cfg, 'seed', path, default=0, minimum=0, maximum=MAX_SEED)


def _sine(cfg: Mapping, path: str, ctx: _Context) -> Signal:
    return Sine(get_float(cfg, 'amplitude_V', path), _freq(cfg, 'frequency_Hz', path, ctx,
                                                           positive=False),
                get_float(cfg, 'phase_rad', path, default=0.0), ctx.fs)


def _chirp(cfg: Mapping, path: str, ctx: _Context) -> Signal:
    return Chirp(get_float(cfg, 'amplitude_V', path), _freq(cfg, 'f_start_Hz', path, ctx),
                 _freq(cfg, 'f_stop_Hz', path, ctx),
                 get_float(cfg, 'sweep_time_s', path, default=ctx.duration_s, minimum=0.0,
                           min_exclusive=True),
                 ctx.fs, method=get_str(cfg, 'method', path, default='logarithmic',
                                        choices=METHODS),
                 after_sweep=get_str(cfg, 'after_sweep', path, default='repeat',
                                     choices=AFTER_SWEEP),
                 phase_rad=get_float(cfg, 'phase_rad', path, default=0.0))


def _multisine(cfg: Mapping, path: str, ctx: _Context) -> Signal:
    period = get_int(cfg, 'period_samples', path, minimum=3)
    lines = None
    if 'lines' in cfg:
        for key in ('f_min_Hz', 'f_max_Hz', 'odd_only'):
            if key in cfg:
                raise ConfigError(join(path, key), 'give either lines or '
                                  'f_min_Hz/f_max_Hz/odd_only, not both')
        lines = _get_int_list(cfg, 'lines', path, minimum=1, maximum=(period + 1) // 2 - 1)
    f_min = _freq(cfg, 'f_min_Hz', path, ctx, positive=False, default=None) \
        if 'f_min_Hz' in cfg else None
    f_max = _freq(cfg, 'f_max_Hz', path, ctx, positive=False, default=None) \
        if 'f_max_Hz' in cfg else None
    return Multisine(get_float(cfg, 'rms_V', path, minimum=0.0, min_exclusive=True), period,
                     ctx.fs, lines=lines, f_min_Hz=f_min, f_max_Hz=f_max,
                     odd_only=get_bool(cfg, 'odd_only', path, default=False),
                     phases=get_str(cfg, 'phases', path, default='schroeder', choices=PHASES),
                     seed=_seed(cfg, path))


def _prbs(cfg: Mapping, path: str, ctx: _Context) -> Signal:
    return Prbs(get_int(cfg, 'order', path, minimum=MIN_ORDER, maximum=MAX_ORDER),
                get_int(cfg, 'hold_samples', path, default=1, minimum=1),
                get_float(cfg, 'low_V', path), get_float(cfg, 'high_V', path), ctx.fs)


def _uniform(cfg: Mapping, path: str, ctx: _Context) -> Signal:
    low = get_float(cfg, 'low_V', path)
    return UniformNoise(low, get_float(cfg, 'high_V', path, minimum=low), _seed(cfg, path),
                        ctx.fs)


def _gaussian(cfg: Mapping, path: str, ctx: _Context) -> Signal:
    return GaussianNoise(get_float(cfg, 'mean_V', path, default=0.0),
                         get_float(cfg, 'std_V', path, minimum=0.0), _seed(cfg, path), ctx.fs)


def _steps(cfg: Mapping, path: str, ctx: _Context) -> Signal:
    times = get_float_list(cfg, 'times_s', path, min_length=1, minimum=0.0)
    levels = get_float_list(cfg, 'levels_V', path, min_length=1)
    if len(levels) != len(times):
        raise ConfigError(join(path, 'levels_V'), f'needs one level per time: {len(times)} '
                          f'times_s, {len(levels)} levels_V')
    return Steps(times, levels, ctx.fs)


def _staircase(cfg: Mapping, path: str, ctx: _Context) -> Signal:
    return staircase(get_float(cfg, 'start_V', path), get_float(cfg, 'step_V', path),
                     get_int(cfg, 'count', path, minimum=1),
                     get_float(cfg, 'dwell_s', path, minimum=0.0, min_exclusive=True), ctx.fs,
                     start_time_s=get_float(cfg, 'start_time_s', path, default=0.0,
                                            minimum=0.0),
                     up_and_down=get_bool(cfg, 'up_and_down', path, default=False))


def _constant(cfg: Mapping, path: str, ctx: _Context) -> Signal:
    return Constant(get_float(cfg, 'value_V', path), ctx.fs)


def _waveform(cfg: Mapping, path: str, ctx: _Context) -> Signal:
    file_path = Path(get_str(cfg, 'path', path))
    if not file_path.is_absolute() and ctx.base_dir is not None:
        file_path = Path(ctx.base_dir) / file_path
    column = cfg.get('column')
    if column is not None and (isinstance(column, bool) or
                               not isinstance(column, (str, int))):
        raise ConfigError(join(path, 'column'), f'expected a column name or index, got '
                          f'{column!r}')
    rate = get_float(cfg, 'file_sample_rate_Hz', path, minimum=0.0, min_exclusive=True) \
        if 'file_sample_rate_Hz' in cfg else None
    end = get_str(cfg, 'end', path, default='zero', choices=END_MODES)
    try:
        return load_waveform(file_path, ctx.fs, column=column, file_sample_rate_Hz=rate,
                             end=end)
    except WaveformFileError as exc:
        raise WaveformFileError(f'{path}: {exc}') from exc


#: type -> (recognised keys besides ``type``, builder)
SIGNAL_TYPES: Dict[str, tuple] = {
    'sine': (('amplitude_V', 'frequency_Hz', 'phase_rad'), _sine),
    'multisine': (('rms_V', 'period_samples', 'lines', 'f_min_Hz', 'f_max_Hz', 'odd_only',
                   'phases', 'seed'), _multisine),
    'chirp': (('amplitude_V', 'f_start_Hz', 'f_stop_Hz', 'sweep_time_s', 'method',
               'after_sweep', 'phase_rad'), _chirp),
    'prbs': (('order', 'hold_samples', 'low_V', 'high_V'), _prbs),
    'uniform_noise': (('low_V', 'high_V', 'seed'), _uniform),
    'gaussian_noise': (('mean_V', 'std_V', 'seed'), _gaussian),
    'steps': (('times_s', 'levels_V'), _steps),
    'staircase': (('start_V', 'step_V', 'count', 'dwell_s', 'start_time_s', 'up_and_down'),
                  _staircase),
    'constant': (('value_V',), _constant),
    'waveform': (('path', 'column', 'file_sample_rate_Hz', 'end'), _waveform),
}


def signal_from_config(cfg: Mapping[str, Any], path: str, sample_rate_Hz: float, *,
                       section_duration_s: float = 0.0,
                       base_dir: Optional[Path] = None) -> Signal:
    """
    Build one signal from its mapping.

    Parameters
    ----------
    cfg : Mapping
        The signal's mapping, with a ``type`` key.
    path : str
        Its dotted path, for messages.
    sample_rate_Hz : float
        The experiment's sample rate.
    section_duration_s : float
        Duration of the enclosing section (default sweep time of chirps).
    base_dir : pathlib.Path, optional
        Folder that relative waveform paths start from.

    Returns
    -------
    Signal
        The signal.

    Raises
    ------
    ConfigError
        On any bad key or value.
    WaveformFileError
        If a waveform file fails validation (the message starts with the dotted key).
    """
    if not isinstance(cfg, Mapping):
        raise ConfigError(path, f'expected a mapping with a type key, got {cfg!r}')
    kind = get_str(cfg, 'type', path, choices=sorted(SIGNAL_TYPES))
    keys, builder = SIGNAL_TYPES[kind]
    reject_unknown(cfg, ('type',) + keys, path)
    try:
        return builder(cfg, path, _Context(sample_rate_Hz, section_duration_s, base_dir))
    except SignalError as exc:
        raise ConfigError(path, str(exc)) from exc


def experiment_from_config(cfg: Mapping[str, Any], base_dir: Optional[Path] = None, *,
                           path: str = 'experiment') -> Experiment:
    """
    Build an experiment from its nested mapping (see the module docstring for the format).

    Parameters
    ----------
    cfg : Mapping
        The content of the ``experiment`` mapping; a mapping whose only key is
        ``experiment`` is unwrapped.
    base_dir : pathlib.Path, optional
        Folder that relative waveform paths start from (default: the working directory).
    path : str
        Dotted path of ``cfg``, for messages.

    Returns
    -------
    Experiment
        The experiment.

    Raises
    ------
    ConfigError
        On any bad key or value, naming the dotted key.
    WaveformFileError
        If a waveform file fails validation.
    """
    if isinstance(cfg, Mapping) and list(cfg) == ['experiment']:
        cfg = get_mapping(cfg, 'experiment', '')
    if not isinstance(cfg, Mapping):
        raise ConfigError(path, f'expected a mapping, got {cfg!r}')
    reject_unknown(cfg, EXPERIMENT_KEYS, path)
    fs = get_float(cfg, 'sample_rate_Hz', path, minimum=0.0, min_exclusive=True,
                   maximum=MAX_SAMPLE_RATE_Hz)
    channels = get_str_list(cfg, 'channels', path, default=list(DEFAULT_CHANNELS),
                            min_length=1)
    if len(set(channels)) != len(channels):
        raise ConfigError(join(path, 'channels'), f'channel names must be distinct, got '
                          f'{channels}')
    for name in channels:
        if name in ('duration_s',) or not name.isidentifier():
            raise ConfigError(join(path, 'channels'), f'{name!r} is not a valid channel name')
    limits = _limits(get_mapping(cfg, 'limits', path, default={}), join(path, 'limits'),
                     channels)
    order = get_str_list(cfg, 'sections', path, min_length=1)
    defined = get_mapping(cfg, 'section', path)
    sections_path = join(path, 'section')
    seen = set()
    for i, name in enumerate(order):
        if name in seen:
            raise ConfigError(f'{join(path, "sections")}[{i}]', f'section {name!r} is listed '
                              f'twice; give each section its own name')
        seen.add(name)
        if name not in defined:
            raise ConfigError(join(sections_path, name), f'section listed in '
                              f'{join(path, "sections")} is not defined; defined: '
                              f'{sorted(defined)}')
    for name in defined:
        if name not in seen:
            raise ConfigError(join(sections_path, str(name)), f'section is not listed in '
                              f'{join(path, "sections")} {order}')
    sections = [_section(name, get_mapping(defined, name, sections_path),
                         join(sections_path, name), fs, channels, base_dir)
                for name in order]
    try:
        return Experiment(sections, fs, channels, limits)
    except SignalError as exc:
        raise ConfigError(path, str(exc)) from exc


def _limits(cfg: Mapping, path: str, channels: list) -> Dict[str, ChannelLimits]:
    reject_unknown(cfg, channels, path)
    out = {}
    for name in cfg:
        sub = get_mapping(cfg, name, path)
        sub_path = join(path, name)
        reject_unknown(sub, LIMIT_KEYS, sub_path)
        low = get_float(sub, 'min_V', sub_path, default=-10.0)
        out[name] = ChannelLimits(low, get_float(sub, 'max_V', sub_path, default=10.0,
                                                 minimum=low))
    return out


def _section(name: str, cfg: Mapping, path: str, fs: float, channels: list,
             base_dir: Optional[Path]) -> Section:
    reject_unknown(cfg, ['duration_s'] + list(channels), path)
    duration_s = get_float(cfg, 'duration_s', path, minimum=0.5 / fs, min_exclusive=True)
    plans = {}
    for channel in channels:
        if channel not in cfg:
            continue
        sub_path = join(path, channel)
        sub = get_mapping(cfg, channel, path)
        reject_unknown(sub, CHANNEL_KEYS, sub_path)
        signals_cfg = get_mapping(sub, 'signals', sub_path, default={})
        signals_path = join(sub_path, 'signals')
        signals = {str(sig): signal_from_config(get_mapping(signals_cfg, sig, signals_path),
                                                join(signals_path, str(sig)), fs,
                                                section_duration_s=duration_s,
                                                base_dir=base_dir)
                   for sig in signals_cfg}
        plans[channel] = ChannelPlan(signals, get_float(sub, 'gain', sub_path, default=1.0),
                                     get_float(sub, 'offset_V', sub_path, default=0.0))
    return Section.from_duration(name, duration_s, fs, plans)


def _get_int_list(cfg: Mapping, key: str, path: str, *, minimum: int, maximum: int) -> list:
    name = join(path, key)
    value = cfg.get(key)
    if isinstance(value, (str, bytes)) or not isinstance(value, (list, tuple)) or not value:
        raise ConfigError(name, f'expected a non-empty list of integers, got {value!r}')
    out = []
    for i, item in enumerate(value):
        if isinstance(item, float) and item.is_integer():
            item = int(item)
        if isinstance(item, bool) or not isinstance(item, int):
            raise ConfigError(f'{name}[{i}]', f'expected an integer, got {item!r}')
        if not minimum <= item <= maximum:
            raise ConfigError(f'{name}[{i}]', f'{item!r} must be in [{minimum}, {maximum}]')
        out.append(item)
    if len(set(out)) != len(out):
        raise ConfigError(name, f'lines must not repeat, got {out}')
    return out


def find_experiment_mapping(doc: Any, source: str = '<config>') -> Mapping[str, Any]:
    """
    Find the ``experiment`` mapping in a plain YAML document or a ROS parameters file.

    Parameters
    ----------
    doc : Any
        The parsed YAML document.
    source : str
        Name of the document, for messages.

    Returns
    -------
    Mapping
        The content of ``experiment``.

    Raises
    ------
    ConfigError
        If there is none, or several ROS nodes carry one and none is ``/**``.
    """
    if not isinstance(doc, Mapping):
        raise ConfigError(source, 'expected a YAML mapping at the top level')
    if 'experiment' in doc:
        return get_mapping(doc, 'experiment', '')
    found: Dict[str, Mapping] = {}
    _collect_ros_parameters(doc, '', found)
    found = {node: params for node, params in found.items() if 'experiment' in params}
    if not found:
        raise ConfigError(f'{source}: experiment', 'required key is missing (neither at the '
                          'top level nor under <node>.ros__parameters)')
    node = '/**' if '/**' in found else (next(iter(found)) if len(found) == 1 else None)
    if node is None:
        raise ConfigError(f'{source}: experiment', f'several nodes define one: {sorted(found)}'
                          f'; keep one or use /**')
    return get_mapping(found[node], 'experiment', f'{node}.ros__parameters')


def _collect_ros_parameters(doc: Mapping, prefix: str, found: Dict[str, Mapping]) -> None:
    for key, value in doc.items():
        if not isinstance(value, Mapping):
            continue
        name = f'{prefix}/{key}'.replace('//', '/') if prefix else str(key)
        if key == 'ros__parameters':
            found[prefix or '/'] = unflatten(_flatten(value))
        else:
            _collect_ros_parameters(value, name, found)


def _flatten(cfg: Mapping, prefix: str = '') -> dict:
    out: dict = {}
    for key, value in cfg.items():
        name = f'{prefix}.{key}' if prefix else str(key)
        if isinstance(value, Mapping) and value:
            out.update(_flatten(value, name))
        else:
            out[name] = value
    return out


def load_experiment_file(path: Union[str, Path]) -> Experiment:
    """
    Load an experiment from a YAML file (plain or ROS parameters file).

    Relative waveform paths start from the file's folder.

    Parameters
    ----------
    path : str or pathlib.Path
        The YAML file.

    Returns
    -------
    Experiment
        The experiment.

    Raises
    ------
    ConfigError
        If the file cannot be read or parsed, or the configuration is invalid.
    WaveformFileError
        If a waveform file fails validation.
    """
    path = Path(path)
    try:
        doc = load_yaml_file(path)
    except OSError as exc:
        raise ConfigError(str(path), f'cannot read file: {exc}') from exc
    except yaml.YAMLError as exc:
        raise ConfigError(str(path), f'invalid YAML: {one_line(exc)}') from exc
    return experiment_from_config(find_experiment_mapping(doc, str(path)), path.parent)


__all__ = ['SIGNAL_TYPES', 'experiment_from_config', 'find_experiment_mapping',
           'load_experiment_file', 'signal_from_config']
