"""
Checks of a whole run plan before anything runs: experiment files, signals, identification.

The experiment runner (``emfc-experiment``) refuses a bad plan before it starts a node or
creates its output folder, so that a typo never costs an experiment (on a device, the
recording is the expensive part). :func:`emfc_ros.core.run_plan.load_plan` calls these checks;
every refusal is a :class:`~emfc_ros.core.errors.ConfigError` naming the dotted key, with the
experiment file in front of keys that live in an experiment file. Pure: no ROS imports.
"""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any, Dict, Mapping, Sequence

from emfc_ros.core.config import get_bool, join, reject_unknown
from emfc_ros.core.errors import ConfigError

#: Topics the runner and the identification need in the bag (relative to the namespace).
REQUIRED_TOPICS = ('excitation', 'excitation/description', 'measurements',
                   'measurements/description')
#: Identification keys that name sections of the experiment: (step, key).
SECTION_KEYS = (('frf', 'coil_sections'), ('frf', 'pan_sections'),
                ('frf', 'two_input_sections'), ('static', 'sections'), ('greybox', 'sections'))
#: Identification keys the plan sets itself (the pan load of the run), with the plan key.
PLAN_OWN_KEYS = ('load_mass_kg', 'load_changer_coupled')


def resolve_waveform_paths(experiment: Mapping[str, Any], base_dir: Path) -> Dict[str, Any]:
    """
    Make the relative ``path`` of every ``waveform`` signal absolute.

    A waveform path is relative to its experiment file's folder; the runner plays the merged
    experiment from its output folder, so the paths are resolved where the file is read.

    Parameters
    ----------
    experiment : Mapping
        The content of one file's ``experiment`` mapping (nested).
    base_dir : pathlib.Path
        The experiment file's folder.

    Returns
    -------
    dict
        A copy with absolute waveform paths (everything else unchanged).
    """
    out = copy.deepcopy(dict(experiment))
    sections = out.get('section')
    if not isinstance(sections, dict):
        return out
    for section in sections.values():
        if not isinstance(section, dict):
            continue
        for channel in section.values():
            signals = channel.get('signals') if isinstance(channel, dict) else None
            if not isinstance(signals, dict):
                continue
            for signal in signals.values():
                if isinstance(signal, dict) and signal.get('type') == 'waveform' and \
                        isinstance(signal.get('path'), str) and \
                        not Path(signal['path']).is_absolute():
                    signal['path'] = str((Path(base_dir) / signal['path']).resolve())
    return out


def check_experiment(experiment: Mapping[str, Any], where: str) -> float:
    """
    Build an experiment once, as the signal generator will, to check every section and signal.

    Parameters
    ----------
    experiment : Mapping
        The content of an ``experiment`` mapping (waveform paths absolute).
    where : str
        Prefix of the key in messages, for example ``'run.experiment_files[1] (a.yaml)'``.

    Returns
    -------
    float
        Duration of the experiment [s].

    Raises
    ------
    ConfigError
        ``<where>: experiment.<dotted key>`` and the problem (also for an unreadable or
        invalid waveform file).
    """
    from emfc_ros.core.signals import experiment_from_config

    try:
        built = experiment_from_config(experiment, path='experiment')
    except ConfigError as exc:
        raise ConfigError(f'{where}: {exc.key}', exc.problem) from None
    except ValueError as exc:           # a waveform file or a signal that cannot be built
        raise ConfigError(f'{where}: experiment', str(exc)) from None
    return built.total_samples / built.sample_rate_Hz


def check_identification(cfg: Mapping[str, Any], sections: Sequence[str],
                         path: str = 'run.identification') -> Any:
    """
    Check the identification options of a plan as the pipeline will read them.

    Parameters
    ----------
    cfg : Mapping
        The ``identification`` mapping of the plan: ``enabled`` plus the pipeline's options
        (:class:`~emfc_ros.core.ident.pipeline_config.IdentificationConfig`).
    sections : sequence of str
        The sections of the merged experiment: section names the options give must be among
        them.
    path : str
        Dotted path of ``cfg``, for messages.

    Returns
    -------
    IdentificationConfig
        The configuration the pipeline will use (pan load aside: the run sets it).

    Raises
    ------
    ConfigError
        An unknown key (``run.identification.greybox.tolerence: unknown key; ...``), a value of
        the wrong type or out of range, a section name the experiment does not have, or a key
        the plan sets itself (the pan load).
    """
    from emfc_ros.core.ident.pipeline_config import IdentificationConfig

    if not isinstance(cfg, Mapping):
        raise ConfigError(path, f'expected a mapping, got {cfg!r}')
    for key in PLAN_OWN_KEYS:
        if key in cfg:
            raise ConfigError(join(path, key), 'set by the run: the pan load of the experiment '
                              'is run.simulator.load_mass_kg / load_changer_coupled (or '
                              'run.bridge.*), stored in the bag with the recording')
    reject_unknown(cfg, ['enabled'] + [k for k in IdentificationConfig.__dataclass_fields__
                                       if k not in PLAN_OWN_KEYS], path)
    get_bool(cfg, 'enabled', path, default=True)
    options = {k: v for k, v in cfg.items() if k != 'enabled'}
    config = IdentificationConfig.from_mapping(options, path)
    known = list(sections)
    for step, key in SECTION_KEYS:
        given = options.get(step, {}).get(key) if isinstance(options.get(step), Mapping) \
            else None
        for i, name in enumerate(given or []):
            if name not in known:
                raise ConfigError(f'{join(join(path, step), key)}[{i}]',
                                  f'{name!r} is not a section of the experiment; its sections '
                                  f'are {known}')
    return config


def check_recording_topics(topics: Sequence[str], namespace: str,
                           path: str = 'run.recording.topics') -> None:
    """
    Refuse a recording that lacks the streams the runner waits for and identifies from.

    Parameters
    ----------
    topics : sequence of str
        The plan's topics (relative to the run's namespace unless absolute).
    namespace : str
        The run's namespace.
    path : str
        Dotted path, for messages.

    Raises
    ------
    ConfigError
        Naming the missing topics.
    """
    ns = '/' + namespace.strip('/') if namespace.strip('/') else ''
    missing = [t for t in REQUIRED_TOPICS if t not in topics and f'{ns}/{t}' not in topics]
    if missing:
        raise ConfigError(path, f'lacks {missing}: the runner waits until the recorder '
                          'records the excitation and the measurements, and identifies from '
                          'them and their descriptions')


def check_balance_file(path: Path, key: str) -> None:
    """
    Read a balance parameters file once, as the nodes and the identification will.

    Parameters
    ----------
    path : pathlib.Path
        The file.
    key : str
        The plan key that names it, for messages.

    Raises
    ------
    ConfigError
        If the file cannot be read or holds invalid parameters.
    """
    from emfc_ros.core.model.parameters import BalanceParameters

    try:
        BalanceParameters.load_yaml(Path(path))
    except ConfigError as exc:
        raise ConfigError(key, f'{path}: {exc}') from None
    except (OSError, ValueError) as exc:
        raise ConfigError(key, f'cannot read {path}: {exc}') from None
