"""
The experiment runner's plan: what to excite, on which target, what to record and identify.

Parsed from YAML (``run:`` mapping; see ``config/experiment_default.yaml``) with every error
naming the dotted key and the allowed range. Pure: the runner command turns a plan into
nodes.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Tuple

import yaml

from emfc_ros.core.config import (flatten, get_bool, get_float, get_int, get_mapping, get_str,
                                  get_str_list, reject_unknown, unflatten)
from emfc_ros.core.errors import ConfigError
from emfc_ros.core.signals.experiment import DEFAULT_CHANNELS
from emfc_ros.core.signals.spec import find_experiment_mapping

TARGETS = ('simulator', 'bridge')
RUN_KEYS = ('name', 'target', 'namespace', 'experiment_files', 'block_size', 'simulator',
            'recording', 'identification', 'timeout_s')
SIMULATOR_KEYS = ('balance_file', 'load_mass_kg', 'load_changer_coupled', 'seed', 'noise',
                  'quantisation', 'state_rate_Hz')
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
    """

    balance_file: Optional[Path] = None
    load_mass_kg: Optional[float] = None
    load_changer_coupled: bool = True
    seed: int = 0
    noise: bool = True
    quantisation: bool = True
    state_rate_Hz: float = 10.0


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
    if target == 'bridge':
        raise ConfigError('run.target', "'bridge' needs the daq_bridge node, which this version "
                          "does not have yet; use 'simulator'")
    files = get_str_list(cfg, 'experiment_files', path, min_length=1)
    mappings, names = [], []
    for i, name in enumerate(files):
        file_path = Path(name) if Path(name).is_absolute() else base_dir / name
        try:
            doc = yaml.safe_load(file_path.read_text())
        except (OSError, yaml.YAMLError) as exc:
            raise ConfigError(f'run.experiment_files[{i}]', f'cannot read {file_path}: '
                              f'{exc}') from exc
        try:
            mappings.append(unflatten(flatten(find_experiment_mapping(doc, str(file_path)))))
        except ValueError as exc:
            raise ConfigError(f'run.experiment_files[{i}]', f'{file_path}: {exc}') from exc
        names.append(str(file_path))
    experiment = merge_experiments(mappings, names)

    sim_cfg = get_mapping(cfg, 'simulator', path, default={})
    sim_path = f'{path}.simulator'
    reject_unknown(sim_cfg, SIMULATOR_KEYS, sim_path)
    balance = get_str(sim_cfg, 'balance_file', sim_path, default='')
    load = sim_cfg.get('load_mass_kg', 'balance')
    if load == 'balance':
        load_kg = None
    else:
        load_kg = get_float(sim_cfg, 'load_mass_kg', sim_path, minimum=0.0, maximum=2.0)
    simulator = SimulatorPlan(
        balance_file=(Path(balance) if Path(balance).is_absolute() else base_dir / balance)
        if balance else None,
        load_mass_kg=load_kg,
        load_changer_coupled=get_bool(sim_cfg, 'load_changer_coupled', sim_path, default=True),
        seed=get_int(sim_cfg, 'seed', sim_path, default=0, minimum=0),
        noise=get_bool(sim_cfg, 'noise', sim_path, default=True),
        quantisation=get_bool(sim_cfg, 'quantisation', sim_path, default=True),
        state_rate_Hz=get_float(sim_cfg, 'state_rate_Hz', sim_path, default=10.0,
                                minimum=0.0))

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
    identification = dict(get_mapping(cfg, 'identification', path, default={}))
    return RunPlan(
        name=get_str(cfg, 'name', path, default='experiment'),
        target=target,
        namespace=get_str(cfg, 'namespace', path, default='/emfc'),
        experiment=experiment,
        block_size=get_int(cfg, 'block_size', path, default=1000, minimum=1,
                           maximum=1_000_000),
        simulator=simulator, recording=recording, identification=identification,
        timeout_s=get_float(cfg, 'timeout_s', path, default=600.0, minimum=1.0),
        source=source)


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
        doc = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ConfigError(str(path), f'cannot read the run plan: {exc}') from exc
    if not isinstance(doc, Mapping) or not isinstance(doc.get('run'), Mapping):
        raise ConfigError(f'{path}: run', 'a run plan needs a top-level run: mapping')
    return plan_from_mapping(doc['run'], Path(path).resolve().parent, Path(path))
