"""
The experiment runner's plan: what to excite, on which target, what to record and identify.

Parsed from YAML (``run:`` mapping; see ``config/experiment_default.yaml`` for the simulator
target and ``config/experiment_bridge_emulator.yaml`` for the bridge target) with every error
naming the dotted key and the allowed range. Pure: the runner command turns a plan into
nodes.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Tuple

import yaml

from emfc_ros.core.config import (flatten, get_bool, get_float, get_int, get_mapping, get_str,
                                  get_str_list, reject_unknown, unflatten)
from emfc_ros.core.errors import ConfigError
from emfc_ros.core.plan_check import (check_balance_file, check_experiment,
                                      check_identification, check_recording_topics,
                                      resolve_waveform_paths)
from emfc_ros.core.safe_yaml import load_yaml_file, one_line
from emfc_ros.core.signals.experiment import DEFAULT_CHANNELS
from emfc_ros.core.signals.spec import find_experiment_mapping

TARGETS = ('simulator', 'bridge')
RUN_KEYS = ('name', 'target', 'namespace', 'experiment_files', 'block_size', 'simulator',
            'bridge', 'recording', 'identification', 'timeout_s', 'executor')
#: The runner's executors (``run.executor``): rclpy's EventsExecutor (rclpy >= 7.1.4, Jazzy;
#: the default) or its wait-set SingleThreadedExecutor.
EXECUTORS = ('events', 'single_threaded')
#: Back-ends whose device the runner can emulate (``start_emulator``).
EMULATED_BACKENDS = ('udp', 'daqmx')
#: Analog inputs of the emulated NI-DAQmx device (``emfc-daqmx-emulator``: ai0:7).
DAQMX_EMULATOR_INPUTS = 8
BRIDGE_KEYS = ('backend', 'parameters_file', 'parameters', 'start_emulator', 'emulator',
               'balance_file', 'load_mass_kg', 'load_changer_coupled', 'pacing',
               'window_blocks', 'lead_blocks', 'settle_s')
EMULATOR_KEYS = ('host', 'port', 'channels', 'seed', 'noise', 'quantisation')
BRIDGE_PACINGS = ('consumer', 'wall')
#: daq_bridge parameters the plan has its own keys for.
BRIDGE_OWN_KEYS = {'balance_file': 'run.bridge.balance_file',
                   'sim.load_mass_kg': 'run.bridge.load_mass_kg',
                   'sim.load_changer_coupled': 'run.bridge.load_changer_coupled'}
#: daq_bridge defaults the runner uses unless the parameters say otherwise: joint states at
#: a monitoring rate and no per-unit group topics (the block stream is the record).
BRIDGE_RUNNER_DEFAULTS = {'state_rate_Hz': 10.0, 'publish_groups': False}
#: The daq_bridge node's own defaults that the plan checks depend on.
BRIDGE_NODE_DEFAULTS = {'watchdog_timeout_s': 1.0, 'excitation_lead_s': 0.1,
                        'excitation_mode': 'stream', 'udp.device_host': '127.0.0.1',
                        'block_size': 1000}
SIMULATOR_KEYS = ('balance_file', 'load_mass_kg', 'load_changer_coupled', 'seed', 'noise',
                  'quantisation', 'state_rate_Hz', 'max_state_wall_rate_Hz')
RECORDING_KEYS = ('topics', 'flush_period_s', 'max_bag_size_B', 'max_bag_duration_s')
DEFAULT_TOPICS = ('excitation', 'excitation/description', 'measurements',
                  'measurements/description', 'joint_states', '/diagnostics',
                  'signal_generator/status')


@dataclasses.dataclass(frozen=True)
class SimulatorPlan:
    """
    The simulated balance of a run.

    Attributes
    ----------
    balance_file : pathlib.Path or None
        Balance parameters (None: the shipped default).
    load_mass_kg : float or None
        Mass on the pan [kg]; None: the balancing mass (lever at 0 with 0 V on the coil).
    load_changer_coupled : bool
        Load changer's moving mass on the pan.
    seed : int
        Noise seed.
    noise, quantisation : bool
        Noise and converter quantisation on.
    state_rate_Hz : float
        Rate of ``joint_states`` [Hz] (0 disables).
    max_state_wall_rate_Hz : float or None
        The plant's wall-rate limit on ``joint_states`` [Hz] (0: none); None: automatic
        (:func:`runner_state_wall_rate_Hz`).
    """

    balance_file: Optional[Path] = None
    load_mass_kg: Optional[float] = None
    load_changer_coupled: bool = True
    seed: int = 0
    noise: bool = True
    quantisation: bool = True
    state_rate_Hz: float = 10.0
    max_state_wall_rate_Hz: Optional[float] = None


#: The plant simulator's own ``max_state_wall_rate_Hz`` default [Hz].
PLANT_STATE_WALL_RATE_HZ = 500.0


#: Joint states per block that the events executor keeps lossless without a wall-rate limit:
#: the plant's and the recorder's history depth for ``joint_states`` (1000 messages).
EVENTS_STATES_PER_BLOCK = 1000


def runner_state_wall_rate_Hz(simulator: SimulatorPlan, sample_rate_Hz: float,
                              block_size: int, executor: str = 'events') -> float:
    """
    The plant's wall-rate limit on ``joint_states`` in a run of the experiment runner.

    The runner's nodes share one thread of one executor. With the events executor
    (``run.executor: events``) callbacks run in arrival order and the generator keeps one
    block in flight: the recorder takes every joint state of a block before the plant
    simulates the next, so up to the subscriptions' history depth
    (:data:`EVENTS_STATES_PER_BLOCK` per block) need no limit (measured: 1 kHz states, 100 per
    block, 49 000 of 49 000 recorded at full speed). The wait-set executor lets the plant
    answer one block and the recorder take one message per topic per cycle: there at most one
    joint state per block keeps up at any speed (the default, 10 Hz at 1000-sample blocks of
    10 kHz), and more states per block are limited to the plant's default 500 Hz of wall
    time, the rate measured lossless with 1 kHz states (``docs/recording.md``, no silent loss).

    Parameters
    ----------
    simulator : SimulatorPlan
        The plan's simulator (its ``max_state_wall_rate_Hz`` wins when given).
    sample_rate_Hz : float
        The experiment's sample rate [Hz].
    block_size : int
        Samples per excitation block.
    executor : str
        The executor the runner uses (:data:`EXECUTORS`).

    Returns
    -------
    float
        The limit [Hz]; 0: none.
    """
    if simulator.max_state_wall_rate_Hz is not None:
        return float(simulator.max_state_wall_rate_Hz)
    per_block = simulator.state_rate_Hz * block_size / sample_rate_Hz
    limit = EVENTS_STATES_PER_BLOCK if executor == 'events' else 1.0
    return 0.0 if per_block <= limit else PLANT_STATE_WALL_RATE_HZ


@dataclasses.dataclass(frozen=True)
class RecordingPlan:
    """
    What the recorder records.

    Attributes
    ----------
    topics : tuple of str
        Topics, relative to the run's namespace unless absolute.
    flush_period_s : float
        Data reach the disk at least this often [s].
    max_bag_size_B : int
        Split size [B] (0: never).
    max_bag_duration_s : float
        Split duration [s] (0: never).
    """

    topics: Tuple[str, ...] = DEFAULT_TOPICS
    flush_period_s: float = 1.0
    max_bag_size_B: int = 0
    max_bag_duration_s: float = 0.0


@dataclasses.dataclass(frozen=True)
class EmulatorPlan:
    """
    The device emulator the runner starts for the bridge's udp back-end.

    Attributes
    ----------
    host : str
        Bind address (loopback only).
    port : int
        UDP port (0: any free one; the bridge is pointed at the bound port).
    channels : int
        Analog inputs of the emulated device (at least the bridge's inputs).
    seed : int
        Noise seed.
    noise, quantisation : bool
        Simulator noise and converter quantisation on.
    """

    host: str = '127.0.0.1'
    port: int = 0
    channels: int = 6
    seed: int = 0
    noise: bool = True
    quantisation: bool = True


@dataclasses.dataclass(frozen=True)
class BridgePlan:
    """
    The hardware side of a run: the daq_bridge node and its back-end.

    Attributes
    ----------
    backend : str
        ``'sim'``, ``'udp'``, ``'replay'`` or ``'daqmx'``.
    parameters : dict
        daq_bridge parameters by dotted name: the runner's defaults, then the parameters
        file, then the ``parameters`` mapping (the runner adds ``sample_rate_Hz``,
        ``autostart``, ``backend``, the balance and, with the emulator, the device address).
    parameters_file : pathlib.Path or None
        The ROS parameters file the parameters were read from.
    start_emulator : bool
        Start the device emulator (loopback only): for the udp back-end in the runner's
        process, for the daqmx back-end ``emfc-daqmx-emulator`` as a process of its own.
    emulator : EmulatorPlan
        The emulator's settings.
    balance_file : pathlib.Path or None
        Balance parameters (None: the shipped default): the simulated device's balance and
        the identification's model.
    load_mass_kg : float or None
        Mass on the pan [kg]; None: the balancing mass. Loads the simulated device (sim
        back-end, emulator) and tells the identification what was on the pan.
    load_changer_coupled : bool
        Load changer's moving mass on the pan.
    pacing : str
        Signal generator pacing: ``'consumer'`` (the bridge's ``excitation/consumed``, that
        is the device's sample clock) or ``'wall'``.
    window_blocks : int
        Consumer pacing: blocks in flight beyond the acknowledged index.
    lead_blocks : int
        Wall pacing: blocks sent ahead of the wall clock.
    settle_s : float
        Measured after the last excitation sample before the acquisition stops [s].
    """

    backend: str = 'sim'
    parameters: Dict[str, Any] = dataclasses.field(default_factory=dict)
    parameters_file: Optional[Path] = None
    start_emulator: bool = False
    emulator: EmulatorPlan = EmulatorPlan()
    balance_file: Optional[Path] = None
    load_mass_kg: Optional[float] = None
    load_changer_coupled: bool = True
    pacing: str = 'consumer'
    window_blocks: int = 4
    lead_blocks: int = 2
    settle_s: float = 0.2


@dataclasses.dataclass(frozen=True)
class RunPlan:
    """
    A whole run.

    Attributes
    ----------
    name : str
        Used in the output folder's name.
    target : str
        ``'simulator'`` or ``'bridge'``.
    namespace : str
        ROS namespace of the run's nodes.
    experiment : dict
        The excitation experiment (the ``experiment:`` mapping of the signal core), merged
        from ``experiment_files`` in order.
    block_size : int
        Samples per excitation block.
    simulator : SimulatorPlan
        The simulated balance.
    recording : RecordingPlan
        The recording.
    identification : dict
        Options for the identification step; ``enabled: false`` skips it.
    timeout_s : float
        Upper bound on the experiment phase [s].
    source : pathlib.Path or None
        The file the plan came from.
    bridge : BridgePlan or None
        The daq_bridge side (target ``'bridge'`` only).
    executor : str
        The runner's executor, one of :data:`EXECUTORS`.
    """

    name: str
    target: str
    namespace: str
    experiment: Dict[str, Any]
    block_size: int
    simulator: SimulatorPlan
    recording: RecordingPlan
    identification: Dict[str, Any]
    timeout_s: float
    source: Optional[Path] = None
    bridge: Optional[BridgePlan] = None
    executor: str = 'events'


def merge_experiments(mappings: List[Mapping[str, Any]], names: List[str]) -> Dict[str, Any]:
    """
    Append the sections of several experiment mappings into one experiment.

    Parameters
    ----------
    mappings : list of Mapping
        ``experiment:`` mappings of the signal core, in play order.
    names : list of str
        Where each came from, for error messages.

    Returns
    -------
    dict
        One experiment mapping.

    Raises
    ------
    ConfigError
        If sample rates, channels or limits differ, or a section name repeats.
    """
    defaults = {'channels': list(DEFAULT_CHANNELS), 'limits': {}}
    merged: Dict[str, Any] = {}
    for mapping, name in zip(mappings, names):
        mapping = dict(defaults, **mapping)
        mapping['channels'] = list(mapping['channels'])
        # Absent limits are the default -10..10 V: compare them filled in.
        mapping['limits'] = {ch: dict({'min_V': -10.0, 'max_V': 10.0},
                                      **dict(mapping['limits'].get(ch, {})))
                             for ch in mapping['channels']}
        if not merged:
            merged = {k: v for k, v in mapping.items() if k not in ('sections', 'section')}
            merged['sections'] = []
            merged['section'] = {}
        for key in ('sample_rate_Hz', 'channels', 'limits'):
            if mapping.get(key) != merged.get(key):
                raise ConfigError(f'{name}: experiment.{key}',
                                  f'{mapping.get(key)!r} differs from the first file, '
                                  f'{merged.get(key)!r}; experiments to append must agree')
        for section in mapping.get('sections', []):
            if section in merged['section']:
                raise ConfigError(f'{name}: experiment.sections',
                                  f'section {section!r} appears in two files')
            merged['sections'].append(section)
            merged['section'][section] = mapping.get('section', {}).get(section, {})
    return merged


def plan_from_mapping(cfg: Mapping[str, Any], base_dir: Path,
                      source: Optional[Path] = None) -> RunPlan:
    """
    Build and check a run plan.

    Parameters
    ----------
    cfg : Mapping
        The ``run:`` mapping.
    base_dir : pathlib.Path
        Folder that relative file names are relative to.
    source : pathlib.Path, optional
        The file it came from.

    Returns
    -------
    RunPlan
        The plan.

    Raises
    ------
    ConfigError
        Naming the key and the allowed values.
    """
    path = 'run'
    reject_unknown(cfg, RUN_KEYS, path)
    target = get_str(cfg, 'target', path, default='simulator', choices=TARGETS)
    if target == 'bridge' and 'simulator' in cfg:
        raise ConfigError('run.simulator', "not used with target 'bridge': the device, its "
                          'balance and pan load are under run.bridge')
    if target == 'simulator' and 'bridge' in cfg:
        raise ConfigError('run.bridge', "only used with target 'bridge'")
    files = get_str_list(cfg, 'experiment_files', path, min_length=1)
    mappings, names = [], []
    for i, name in enumerate(files):
        file_path = Path(name) if Path(name).is_absolute() else base_dir / name
        try:
            doc = load_yaml_file(file_path)
        except (OSError, yaml.YAMLError) as exc:
            raise ConfigError(f'run.experiment_files[{i}]', f'cannot read {file_path}: '
                              f'{one_line(exc)}') from exc
        try:
            mapping = unflatten(flatten(find_experiment_mapping(doc, str(file_path))))
        except ValueError as exc:
            raise ConfigError(f'run.experiment_files[{i}]', f'{file_path}: {exc}') from exc
        mapping = resolve_waveform_paths(mapping, file_path.parent)
        # Every section and signal of the file, checked on its own so that an error names
        # the file (the merged experiment is checked again below).
        check_experiment(mapping, f'run.experiment_files[{i}] ({file_path})')
        mappings.append(mapping)
        names.append(str(file_path))
    experiment = merge_experiments(mappings, names)
    duration_s = check_experiment(experiment, 'run.experiment_files (merged)')

    sim_cfg = get_mapping(cfg, 'simulator', path, default={})
    sim_path = f'{path}.simulator'
    reject_unknown(sim_cfg, SIMULATOR_KEYS, sim_path)
    balance = get_str(sim_cfg, 'balance_file', sim_path, default='')
    load = sim_cfg.get('load_mass_kg', 'balance')
    if load == 'balance':
        load_kg = None
    else:
        load_kg = get_float(sim_cfg, 'load_mass_kg', sim_path, minimum=0.0, maximum=2.0)
    if balance:
        check_balance_file(_resolve(balance, base_dir), f'{sim_path}.balance_file')
    simulator = SimulatorPlan(
        balance_file=_resolve(balance, base_dir) if balance else None,
        load_mass_kg=load_kg,
        load_changer_coupled=get_bool(sim_cfg, 'load_changer_coupled', sim_path, default=True),
        seed=get_int(sim_cfg, 'seed', sim_path, default=0, minimum=0),
        noise=get_bool(sim_cfg, 'noise', sim_path, default=True),
        quantisation=get_bool(sim_cfg, 'quantisation', sim_path, default=True),
        state_rate_Hz=get_float(sim_cfg, 'state_rate_Hz', sim_path, default=10.0,
                                minimum=0.0),
        max_state_wall_rate_Hz=None if sim_cfg.get('max_state_wall_rate_Hz') in (
            None, 'auto') else get_float(sim_cfg, 'max_state_wall_rate_Hz', sim_path,
                                         minimum=0.0, maximum=1.0e6))

    rec_cfg = get_mapping(cfg, 'recording', path, default={})
    rec_path = f'{path}.recording'
    reject_unknown(rec_cfg, RECORDING_KEYS, rec_path)
    recording = RecordingPlan(
        topics=tuple(get_str_list(rec_cfg, 'topics', rec_path, default=list(DEFAULT_TOPICS),
                                  min_length=1)),
        flush_period_s=get_float(rec_cfg, 'flush_period_s', rec_path, default=1.0,
                                 minimum=0.01, maximum=60.0),
        max_bag_size_B=get_int(rec_cfg, 'max_bag_size_B', rec_path, default=0, minimum=0),
        max_bag_duration_s=get_float(rec_cfg, 'max_bag_duration_s', rec_path, default=0.0,
                                     minimum=0.0))
    namespace = get_str(cfg, 'namespace', path, default='/emfc')
    check_recording_topics(recording.topics, namespace, f'{rec_path}.topics')
    identification = dict(get_mapping(cfg, 'identification', path, default={}))
    check_identification(identification, experiment['sections'], f'{path}.identification')
    block_size = get_int(cfg, 'block_size', path, default=1000, minimum=1, maximum=1_000_000)
    timeout_s = get_float(cfg, 'timeout_s', path, default=600.0, minimum=1.0)
    executor = get_str(cfg, 'executor', path, default='events', choices=EXECUTORS)
    bridge = None
    if target == 'bridge':
        bridge = bridge_plan_from_mapping(
            get_mapping(cfg, 'bridge', path), base_dir, experiment, block_size,
            identify=bool(identification.get('enabled', True)))
        if timeout_s <= duration_s + bridge.settle_s:
            raise ConfigError('run.timeout_s', f'{timeout_s} s is too short: on the device '
                              f'the experiment takes {duration_s:g} s of wall time plus '
                              f'{bridge.settle_s:g} s of settling')
    return RunPlan(
        name=get_str(cfg, 'name', path, default='experiment'),
        target=target,
        namespace=namespace,
        experiment=experiment,
        block_size=block_size,
        simulator=simulator, recording=recording, identification=identification,
        timeout_s=timeout_s, source=source, bridge=bridge, executor=executor)


def _resolve(name: str, base_dir: Path) -> Path:
    return Path(name) if Path(name).is_absolute() else base_dir / name


def read_parameters_file(path: Path, node: str = 'daq_bridge',
                         key: str = 'run.bridge.parameters_file') -> Dict[str, Any]:
    """
    Read a node's parameters from a ROS 2 parameters file, as dotted names.

    Parameters
    ----------
    path : pathlib.Path
        The file: ``<node or /**>: {ros__parameters: {...}}`` (nested mappings become dotted
        names), or a plain mapping of parameters.
    node : str
        The node whose entry is wanted when the file has several (``/**`` first, then a key
        ending in the node name).
    key : str
        The plan key, for error messages.

    Returns
    -------
    dict
        Parameter name to value.

    Raises
    ------
    ConfigError
        If the file cannot be read or holds no parameters for the node.
    """
    try:
        doc = load_yaml_file(path)
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(key, f'cannot read {path}: {one_line(exc)}') from exc
    if not isinstance(doc, Mapping):
        raise ConfigError(key, f'{path}: expected a YAML mapping at the top level')
    found: Dict[str, Mapping[str, Any]] = {}

    def collect(mapping: Mapping[str, Any], prefix: str) -> None:
        for name, value in mapping.items():
            if not isinstance(value, Mapping):
                continue
            if name == 'ros__parameters':
                found[prefix or '/'] = value
            else:
                collect(value, f'{prefix}/{name}'.replace('//', '/'))

    collect(doc, '')
    if not found:
        return flatten(doc)
    for name in ('/**', *sorted(n for n in found if n.rstrip('/').endswith(node))):
        if name in found:
            return flatten(found[name])
    if len(found) == 1:
        return flatten(next(iter(found.values())))
    raise ConfigError(key, f'{path}: several nodes have parameters ({sorted(found)}) and '
                           f'none is /** or {node}')


def bridge_plan_from_mapping(cfg: Mapping[str, Any], base_dir: Path,
                             experiment: Mapping[str, Any], block_size: int,
                             identify: bool = True) -> BridgePlan:
    """
    Build and check the ``run.bridge`` part of a plan.

    Parameters
    ----------
    cfg : Mapping
        The ``run.bridge`` mapping.
    base_dir : pathlib.Path
        Folder that relative file names are relative to.
    experiment : Mapping
        The merged experiment (its sample rate is the device's).
    block_size : int
        Samples per excitation block.
    identify : bool
        Whether the run identifies: then the bridge's inputs must hold the channels the
        identification needs.

    Returns
    -------
    BridgePlan
        The bridge side of the plan.

    Raises
    ------
    ConfigError
        Naming the dotted key (``run.bridge.<key>``, ``run.bridge.parameters.<name>``) and
        what is allowed.
    """
    from emfc_ros.core.device.backend import DEFAULT_INPUTS
    from emfc_ros.core.device import registry
    from emfc_ros.core.device.emulator import check_bind_host
    from emfc_ros.core.device.errors import DeviceConfigError

    path = 'run.bridge'
    reject_unknown(cfg, BRIDGE_KEYS, path)
    params: Dict[str, Any] = dict(BRIDGE_RUNNER_DEFAULTS)
    origin = {name: f'{path}.parameters.{name}' for name in params}
    file_name = get_str(cfg, 'parameters_file', path, default='')
    params_file = _resolve(file_name, base_dir) if file_name else None
    if params_file is not None:
        from_file = read_parameters_file(params_file, key=f'{path}.parameters_file')
        params.update(from_file)
        origin.update({name: f'{path}.parameters_file ({params_file}): {name}'
                       for name in from_file})
    overrides = flatten(get_mapping(cfg, 'parameters', path, default={}))
    params.update(overrides)
    origin.update({name: f'{path}.parameters.{name}' for name in overrides})
    for name, own in BRIDGE_OWN_KEYS.items():
        if name in params:
            raise ConfigError(origin[name], f'set by the plan: use {own}')
    params.pop('autostart', None)       # the runner starts the bridge once all is up
    default_backend = params.pop('backend', 'sim')
    backend = get_str(cfg, 'backend', path, default=default_backend,
                      choices=list(registry.names()))
    if 'backend' in cfg and default_backend != backend and 'backend' in origin:
        raise ConfigError(f'{path}.backend', f'{backend!r} differs from '
                          f'{origin["backend"]} = {default_backend!r}')
    if not registry.entry(backend).cls.applies_excitation:
        applying = [n for n, e in registry.BACKENDS.items() if e.cls.applies_excitation]
        raise ConfigError(f'{path}.backend', f'{backend!r} applies no excitation (it '
                          f're-publishes a recording): an experiment needs one of {applying}')

    rate = float(experiment.get('sample_rate_Hz', 0.0))
    if 'sample_rate_Hz' in params:
        value = params['sample_rate_Hz']
        if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                abs(float(value) - rate) > 1e-9 * rate:
            raise ConfigError(origin['sample_rate_Hz'], f'{value!r} differs from the '
                              f"experiment's sample rate {rate:g} Hz; the device samples at the "
                              "excitation rate (omit it to take the experiment's)")
    params['sample_rate_Hz'] = rate
    for name, (low, high) in (('watchdog_timeout_s', (0.0, 3600.0)),
                              ('excitation_lead_s', (0.0, 10.0))):
        value = params.get(name, BRIDGE_NODE_DEFAULTS[name])
        if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                not low <= float(value) <= high:
            raise ConfigError(origin.get(name, f'{path}.parameters.{name}'),
                              f'must be a number in [{low}, {high}], got {value!r}')
    mode = params.get('excitation_mode', 'stream')
    if mode != 'stream':
        raise ConfigError(origin['excitation_mode'], f"must be 'stream' for an experiment "
                          f'(the signal generator streams the excitation), got {mode!r}')
    inputs = params.get('inputs', list(DEFAULT_INPUTS))
    if isinstance(inputs, (str, bytes)) or not isinstance(inputs, (list, tuple)) or \
            not all(isinstance(i, str) for i in inputs) or not inputs:
        raise ConfigError(origin.get('inputs', f'{path}.parameters.inputs'),
                          f'expected a non-empty list of channel names, got {inputs!r}')
    if identify:
        from emfc_ros.core.ident.pipeline import REQUIRED_CHANNELS
        missing = [c for c in REQUIRED_CHANNELS if c not in inputs]
        if missing:
            raise ConfigError(origin.get('inputs', f'{path}.parameters.inputs'),
                              f'lacks {missing}, which the identification needs (it has '
                              f'{list(inputs)}); add them, or set '
                              'run.identification.enabled: false')

    pacing = get_str(cfg, 'pacing', path, default='consumer', choices=BRIDGE_PACINGS)
    window = get_int(cfg, 'window_blocks', path, default=4, minimum=1, maximum=1000)
    lead = get_int(cfg, 'lead_blocks', path, default=2, minimum=0, maximum=1000)
    ahead_s = ((window if pacing == 'consumer' else lead) + 1) * block_size / rate + \
        float(params.get('excitation_lead_s', BRIDGE_NODE_DEFAULTS['excitation_lead_s']))
    watchdog_s = float(params.get('watchdog_timeout_s',
                                  BRIDGE_NODE_DEFAULTS['watchdog_timeout_s']))
    if watchdog_s < ahead_s + 0.2:
        raise ConfigError(origin.get('watchdog_timeout_s',
                                     f'{path}.parameters.watchdog_timeout_s'),
                          f'{watchdog_s:g} s would trip before the last excitation block is '
                          f'applied: the generator runs up to {ahead_s:g} s ahead of the '
                          f'device; use at least {ahead_s + 0.2:g} s or fewer '
                          f'{"window" if pacing == "consumer" else "lead"}_blocks')
    if pacing == 'consumer':
        check_consumer_window(window, block_size, rate, params, origin, path)
    if backend == 'daqmx':
        check_daqmx_lead(params, origin, rate, path)

    start_emulator = get_bool(cfg, 'start_emulator', path, default=False)
    emu_cfg = get_mapping(cfg, 'emulator', path, default={})
    emu_path = f'{path}.emulator'
    reject_unknown(emu_cfg, EMULATOR_KEYS, emu_path)
    if emu_cfg and not start_emulator:
        raise ConfigError(emu_path, 'only used with start_emulator: true')
    if start_emulator and backend not in EMULATED_BACKENDS:
        raise ConfigError(f'{path}.start_emulator', 'starts a device emulator: needs backend '
                          f"'udp' (emfc-device-emulator) or 'daqmx' (emfc-daqmx-emulator), "
                          f'got {backend!r}')
    host = get_str(emu_cfg, 'host', emu_path, default='127.0.0.1')
    try:
        host = check_bind_host(host)
    except DeviceConfigError as exc:
        raise ConfigError(f'{emu_path}.host', f'{exc}; the runner starts the emulator on '
                          'loopback only') from None
    emulator = EmulatorPlan(
        host=host,
        port=get_int(emu_cfg, 'port', emu_path, default=0, minimum=0, maximum=65535),
        channels=get_int(emu_cfg, 'channels', emu_path, default=max(4, len(inputs)),
                         minimum=1, maximum=64),
        seed=get_int(emu_cfg, 'seed', emu_path, default=0, minimum=0),
        noise=get_bool(emu_cfg, 'noise', emu_path, default=True),
        quantisation=get_bool(emu_cfg, 'quantisation', emu_path, default=True))
    if start_emulator and backend == 'daqmx' and len(inputs) > DAQMX_EMULATOR_INPUTS:
        raise ConfigError(f'{path}.parameters.inputs', f'the emulated NI-DAQmx device has '
                          f'{DAQMX_EMULATOR_INPUTS} analog inputs, got {len(inputs)} inputs')
    if start_emulator and backend == 'udp' and emulator.channels < len(inputs):
        raise ConfigError(f'{emu_path}.channels', f'{emulator.channels} analog inputs cannot '
                          f'carry the {len(inputs)} inputs {list(inputs)}')

    balance = get_str(cfg, 'balance_file', path, default='')
    if balance:
        check_balance_file(_resolve(balance, base_dir), f'{path}.balance_file')
    load = cfg.get('load_mass_kg', 'balance')
    if load == 'balance' and backend in EMULATED_BACKENDS and not start_emulator:
        # On a real balance the model's balancing mass is a guess, and the identification
        # needs what is really on the pan (issue 12): the plan declares the mass pieces.
        raise ConfigError(f'{path}.load_mass_kg', 'on a real device give the mass on the pan '
                          "[kg] (the mass pieces); 'balance' is the configured model's "
                          'balancing mass, only meant for the emulator and the sim back-end')
    load_kg = None if load == 'balance' else get_float(cfg, 'load_mass_kg', path, minimum=0.0,
                                                       maximum=2.0)
    return BridgePlan(
        backend=backend, parameters=params, parameters_file=params_file,
        start_emulator=start_emulator, emulator=emulator,
        balance_file=_resolve(balance, base_dir) if balance else None,
        load_mass_kg=load_kg,
        load_changer_coupled=get_bool(cfg, 'load_changer_coupled', path, default=True),
        pacing=pacing, window_blocks=window, lead_blocks=lead,
        settle_s=get_float(cfg, 'settle_s', path, default=0.2, minimum=0.0, maximum=60.0))


def check_daqmx_lead(params: Mapping[str, Any], origin: Mapping[str, str], rate_Hz: float,
                     path: str = 'run.bridge') -> None:
    """
    Refuse an ``excitation_lead_s`` the daqmx back-end would turn into late setpoints.

    The back-end commits outputs ``daqmx.output_lead_s`` ahead of the device, and the bridge
    writes setpoints from the end of the last block it received (up to one device block and
    one read behind the device): its lead must cover all three, with 50 ms to spare.

    Parameters
    ----------
    params : Mapping
        The bridge parameters.
    origin : Mapping
        Where each parameter came from, for the message.
    rate_Hz : float
        The sample rate [Hz].
    path : str
        The plan's path, for messages.

    Raises
    ------
    ConfigError
        Naming ``excitation_lead_s`` and the smallest lead that works.
    """
    from emfc_ros.core.device.registry import entry
    defaults = {o.key: o.default for o in entry('daqmx').options}
    device_block = int(params.get('block_size', 1000))
    output_lead = float(params.get('daqmx.output_lead_s', defaults['output_lead_s']))
    read_period = float(params.get('daqmx.read_period_s', defaults['read_period_s']))
    need = device_block / rate_Hz + output_lead + read_period + 0.05
    lead = float(params.get('excitation_lead_s', BRIDGE_NODE_DEFAULTS['excitation_lead_s']))
    if lead < need - 1e-9:
        raise ConfigError(origin.get('excitation_lead_s', f'{path}.parameters.excitation_lead_s'),
                          f'{lead:g} s is too short for the daqmx back-end: it commits the '
                          f'outputs {output_lead:g} s ahead (daqmx.output_lead_s) and the bridge '
                          f'writes from the last block received ({device_block} samples, '
                          f'{device_block / rate_Hz:g} s, plus a read of {read_period:g} s): '
                          f'use at least {need:g} s')


def check_consumer_window(window_blocks: int, block_size: int, rate_Hz: float,
                          params: Mapping[str, Any], origin: Mapping[str, str],
                          path: str = 'run.bridge') -> None:
    """
    Refuse a consumer-paced generator whose window cannot feed the bridge's lead.

    The daq_bridge acknowledges excitation as the device measures it (one measurement block
    at a time) and writes setpoints ``excitation_lead_s`` ahead of the newest measured
    sample; a consumer-paced generator stays at most ``window_blocks`` blocks ahead of the
    acknowledged samples. Unless the lead plus one measurement block fits in the window, the
    bridge writes setpoints the generator was not yet allowed to send: the outputs are at
    their safe values there and the excitation arrives late (measured: with a 0.5 s lead and a
    0.4 s window 59 000 of 65 000 samples were not applied).

    Parameters
    ----------
    window_blocks : int
        The generator's window [blocks].
    block_size : int
        Samples per excitation block.
    rate_Hz : float
        Sample rate [Hz].
    params : mapping
        The daq_bridge parameters (``excitation_lead_s`` [s], ``block_size`` [samples]).
    origin : mapping
        Where each parameter was given, for the message.
    path : str
        The plan key of the bridge section.

    Raises
    ------
    ConfigError
        Naming ``excitation_lead_s`` and the window that would fit.
    """
    lead_s = float(params.get('excitation_lead_s', BRIDGE_NODE_DEFAULTS['excitation_lead_s']))
    try:
        measured = int(params.get('block_size', BRIDGE_NODE_DEFAULTS['block_size']))
    except (TypeError, ValueError):
        return                          # not a block size: the node refuses it, naming it
    window_s = window_blocks * block_size / rate_Hz
    need_s = lead_s + measured / rate_Hz
    if need_s > window_s * (1.0 + 1e-9):
        blocks = int(math.ceil(need_s * rate_Hz / block_size - 1e-9))
        raise ConfigError(origin.get('excitation_lead_s', f'{path}.parameters.excitation_lead_s'),
                          f'{lead_s:g} s plus one measurement block ({measured / rate_Hz:g} s) '
                          f"does not fit in the generator's window ({window_blocks} blocks, "
                          f'{window_s:g} s): a consumer-paced generator stays at most its '
                          'window ahead of what the device measured, so the bridge would run '
                          'out of excitation and output the safe values; use '
                          f'{path}.window_blocks >= {blocks} or a shorter excitation_lead_s')


def load_plan(path: Path) -> RunPlan:
    """
    Read a run plan file (a YAML with a top-level ``run:`` mapping).

    Parameters
    ----------
    path : pathlib.Path
        The file.

    Returns
    -------
    RunPlan
        The plan.

    Raises
    ------
    ConfigError
        If the file is unreadable or a key is wrong.
    """
    try:
        doc = load_yaml_file(path)
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(str(path), f'cannot read the run plan: {one_line(exc)}') from exc
    if not isinstance(doc, Mapping) or not isinstance(doc.get('run'), Mapping):
        raise ConfigError(f'{path}: run', 'a run plan needs a top-level run: mapping')
    return plan_from_mapping(doc['run'], Path(path).resolve().parent, Path(path))
