"""
Identification straight from a recorded bag.

The offline command, the identifier node and the experiment runner all call
:func:`identify_bag`.

The bag must hold a measurement block stream (``<ns>/measurements``) and the excitation's
stream description (``<ns>/excitation/description``, which carries the section table).

Options: the identification options stored in the bag's custom data
(``emfc_ros.identification_options``, written by the experiment runner from its plan), merged
key by key with the options given (which win), so that ``emfc-identify BAG`` reproduces the
run's identification.

Pan load and load-changer coupling, never a silent default, from the first that has them:
the options given, the bag's ``emfc_ros.plant_configuration`` (the runner: the plan's mass
pieces), the measurement description's ``extra`` (a daq_bridge told the pan load), the
recorded node parameters (a plant simulator). Without any,
:class:`~emfc_ros.core.ident.plant.PlantConfigurationError` names the option to give (the
resolution is shared with the identifier node's live path: :mod:`emfc_ros.core.ident.plant`).

Measurements recorded through the daq_bridge are on the device's sample clock: excitation
sample ``k`` was applied at device sample ``k + offset``, the offset published in the
measurement description (``extra.excitation_offset_samples``). The measured channels are cut
to the experiment on the excitation's clock before the section table is applied.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Dict, Mapping, Optional, Tuple

import yaml

from emfc_ros.core.bag import custom_data, read_messages, read_streams
from emfc_ros.core.blocks import StreamDescription
from emfc_ros.core.ident import alignment, plant
# DeviceFaultError: raised here and imported from here by the callers
from emfc_ros.core.ident.alignment import DeviceFaultError, experiment_samples  # noqa: F401
from emfc_ros.core.ident.errors import IdentificationError
# PlantConfigurationError: raised here and imported from here by the callers
from emfc_ros.core.ident.plant import (plant_entries, PLANT_KEYS,  # noqa: F401
                                       PlantConfigurationError)
from emfc_ros.core.safe_yaml import load_yaml_text, YamlRefused

Progress = Callable[[str, float, str], None]
OPTIONS_KEY = 'emfc_ros.identification_options'
PLANT_KEY = 'emfc_ros.plant_configuration'


def _yaml_mapping(text: str) -> Dict[str, Any]:
    try:
        doc = load_yaml_text(text or '', 'bag custom_data') or {}
    except (yaml.YAMLError, YamlRefused):
        return {}
    return doc if isinstance(doc, dict) else {}


def stored_options(bag_path: Path) -> Dict[str, Any]:
    """
    The identification options stored in a bag (empty when none).

    Parameters
    ----------
    bag_path : pathlib.Path
        The bag folder.

    Returns
    -------
    dict
        The mapping the experiment runner used.
    """
    return _yaml_mapping(custom_data(bag_path).get(OPTIONS_KEY, ''))


def merged_options(base: Mapping[str, Any], override: Mapping[str, Any]) -> Dict[str, Any]:
    """
    Merge option mappings key by key (nested mappings too); ``override`` wins.

    Parameters
    ----------
    base, override : Mapping
        The stored and the given options.

    Returns
    -------
    dict
        The merged options.
    """
    out = dict(base)
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            out[key] = merged_options(out[key], value)
        else:
            out[key] = value
    return out


#: How a user of ``emfc-identify`` gives the pan load and the coupling.
CLI_HOW_TO_GIVE = {
    'load_mass_kg': '`emfc-identify --load-mass-kg KG` (or `load_mass_kg` in the --options '
                    'file)',
    'load_changer_coupled': '`emfc-identify --load-changer-coupled true|false` (or '
                            '`load_changer_coupled` in the --options file)'}


def resolve_plant(bag_path: Path, options: Mapping[str, Any], measurements: Any = None
                  ) -> Tuple[Dict[str, Any], str]:
    """
    Pan load and load-changer coupling of a recording, and where they come from.

    The sources in order (:func:`emfc_ros.core.ident.plant.resolve_plant` takes each setting
    from the first that has it): the options given, the bag's custom data
    ``emfc_ros.plant_configuration``, the measurement description's ``extra``, the recorded
    node parameters.

    Parameters
    ----------
    bag_path : pathlib.Path
        The bag folder.
    options : Mapping
        The options given (their ``load_mass_kg``/``load_changer_coupled`` win).
    measurements : Stream, optional
        The measurement stream (its description's ``extra``).

    Returns
    -------
    settings : dict
        ``load_mass_kg`` and ``load_changer_coupled``.
    source : str
        Where they were found.

    Raises
    ------
    PlantConfigurationError
        When no source gives the pan load or the coupling.
    """
    description = getattr(measurements, 'description', None)
    extra = description.extra if description is not None else {}
    stored = _yaml_mapping(custom_data(bag_path).get(PLANT_KEY, ''))
    sources = [('options', plant_entries(options)),
               (f'bag custom data {PLANT_KEY}'
                + (f' ({stored["source"]})' if stored.get('source') else ''),
                plant_entries(stored)),
               ('measurement description (extra)', plant_entries(extra)),
               ('recorded node parameters', plant_settings(bag_path))]
    return plant.resolve_plant(sources, CLI_HOW_TO_GIVE)


def find_namespace(topics: Mapping[str, Any], namespace: Optional[str] = None) -> str:
    """
    The namespace whose ``measurements`` stream to identify.

    Parameters
    ----------
    topics : Mapping
        Streams by topic name (as :func:`read_streams` returns them).
    namespace : str, optional
        The wanted namespace; found automatically when there is exactly one.

    Returns
    -------
    str
        The namespace ('' for the root).

    Raises
    ------
    IdentificationError
        If there is no measurement stream, or several and no namespace was given.
    """
    found = sorted(name[:-len('/measurements')] for name in topics
                   if name.endswith('/measurements'))
    if namespace is not None:
        namespace = namespace.rstrip('/')
        if namespace not in found:
            raise IdentificationError(f'no {namespace}/measurements stream in the bag; it has '
                                      f'{[f + "/measurements" for f in found]}')
        return namespace
    if len(found) != 1:
        raise IdentificationError(f'expected one */measurements stream in the bag, found '
                                  f'{[f + "/measurements" for f in found]}; name the namespace')
    return found[0]


def plant_settings(bag_path: Path) -> Dict[str, Any]:
    """
    Pan load and load-changer coupling from the recorded node parameters, if any.

    Parameters
    ----------
    bag_path : pathlib.Path
        The bag folder.

    Returns
    -------
    dict
        ``load_mass_kg`` and ``load_changer_coupled`` when a recorded node had them.
    """
    try:
        params = load_yaml_text(custom_data(bag_path).get('emfc_ros.node_parameters', '')
                                or '{}', 'bag custom_data emfc_ros.node_parameters') or {}
    except (yaml.YAMLError, YamlRefused):
        return {}
    for node in params.values():
        values = (node or {}).get('ros__parameters', {}) if isinstance(node, dict) else {}
        if all(key in values for key in PLANT_KEYS):
            return {key: values[key] for key in PLANT_KEYS}
    return {}


def identify_bag(bag_path: Path, options: Optional[Mapping[str, Any]] = None,
                 namespace: Optional[str] = None, progress: Optional[Progress] = None,
                 streams: Optional[Mapping[str, Any]] = None,
                 on_step: Optional[Callable[[str, Any], None]] = None,
                 executor: Optional[Any] = None) -> Tuple[Any, Dict[str, Any]]:
    """
    Read a bag back and identify the balance from it.

    Parameters
    ----------
    bag_path : pathlib.Path
        The bag folder.
    options : Mapping, optional
        Identification options (the pipeline's configuration mapping), merged over the ones
        stored in the bag.
    namespace : str, optional
        Which namespace's streams to use when the bag holds several.
    progress : callable, optional
        ``progress(step, fraction, message)``.
    streams : Mapping, optional
        The bag's streams if the caller has read them already (:func:`read_streams`).
    on_step, executor : optional
        Passed to :func:`~emfc_ros.core.ident.pipeline.identify`.

    Returns
    -------
    result : IdentificationResult
        The pipeline's result.
    info : dict
        What was read: namespace, samples, sample rate, sections, plant settings used and
        their source.

    Raises
    ------
    PlantConfigurationError
        If the pan load is not known (give ``load_mass_kg`` in the options).
    IdentificationError
        If the streams needed are missing or have gaps.
    """
    from emfc_ros.core.ident import pipeline

    bag_path = Path(bag_path)
    report = progress or (lambda step, fraction, message: None)
    report('read bag', 0.0, str(bag_path))
    if streams is None:
        streams = read_streams(bag_path)
    ns = find_namespace(streams, namespace)
    measurements = streams[f'{ns}/measurements']
    excitation = streams.get(f'{ns}/excitation')
    sections = experiment_sections(bag_path, streams, ns)
    offset = excitation_offset_samples(measurements, excitation, ns)
    n_excitation = experiment_samples(
        sections, excitation.first_sample_index + excitation.n_samples
        if excitation is not None else 0)
    refuse_faults(bag_path, measurements, ns, offset, n_excitation)
    recording = aligned_channels(measurements, offset, n_excitation if offset else None, ns)
    given = dict(options or {})
    options = merged_options(stored_options(bag_path), given)
    settings, source = resolve_plant(bag_path, given, measurements)
    options.update(settings)
    n = len(next(iter(recording.values()))) if recording else 0
    report('read bag', 1.0, f'{n} samples of {ns}/measurements'
           + (f' from device sample {offset}' if offset else ''))
    result = pipeline.identify(recording, sections, options,
                               sample_rate_Hz=measurements.sample_rate_Hz, progress=progress,
                               on_step=on_step, executor=executor)
    info = {'namespace': ns, 'samples': n,
            'sample_rate_Hz': measurements.sample_rate_Hz, 'sections': sections,
            'excitation_offset_samples': offset,
            'plant_settings': settings, 'plant_settings_source': source}
    result.plant_source = source
    return result, info


def experiment_sections(bag_path: Path, streams: Mapping[str, Any], ns: str) -> list:
    """
    The experiment's section table, from the excitation's recorded description.

    Parameters
    ----------
    bag_path : pathlib.Path
        The bag folder.
    streams : mapping
        Its block streams (:func:`~emfc_ros.core.bag.read_streams`).
    ns : str
        The experiment's namespace.

    Returns
    -------
    list of dict
        ``name``, ``first_sample_index``, ``n_samples`` per section.

    Raises
    ------
    IdentificationError
        If the description was not recorded or holds no section table.
    """
    excitation = streams.get(f'{ns}/excitation')
    description = excitation.description if excitation is not None else None
    if description is None:
        # The excitation's blocks were not recorded (they are not needed: the measurements
        # hold the setpoints); its latched description, which carries the sections, may be.
        description = recorded_description(bag_path, f'{ns}/excitation')
    sections = description.extra.get('sections', []) if description is not None else []
    if not sections:
        what = ('has no section table (extra.sections)' if description is not None else
                'was not recorded')
        raise IdentificationError(f'{ns}/excitation/description {what}: it carries the '
                                  "experiment's sections; record it with the measurements "
                                  '(the signal generator publishes it, latched)')
    return list(sections)


def recorded_description(bag_path: Path, topic: str) -> Optional[StreamDescription]:
    """
    The last stream description of ``topic`` recorded in a bag, read without its blocks.

    Parameters
    ----------
    bag_path : pathlib.Path
        The bag folder.
    topic : str
        The block topic (its ``/description`` is read).

    Returns
    -------
    StreamDescription or None
        None when the bag has no such description or it does not parse.
    """
    last = None
    try:
        for _, msg in read_messages(bag_path, topic + '/description'):
            last = msg
    except KeyError:
        return None
    if last is None:
        return None
    try:
        return StreamDescription.from_json(last.data)
    except ValueError:
        return None


def refuse_faults(bag_path: Path, measurements: Any, namespace: str, offset: int,
                  n_samples: int) -> None:
    """
    Refuse a bag whose device reported that the excitation was not applied as commanded.

    The faults come from the measurement description (``extra.faults``, the daq_bridge's
    latched faults) and from the bag's custom data ``emfc_ros.faults`` (the recorder keeps
    every fault a description reported, also after a ``~/reset`` cleared it).

    Parameters
    ----------
    bag_path : pathlib.Path
        The bag folder.
    measurements : Stream
        The measurement stream, with its description.
    namespace : str
        The streams' namespace.
    offset : int
        Device index of experiment sample 0.
    n_samples : int
        Samples of the experiment.

    Raises
    ------
    DeviceFaultError
        If a fault touches the experiment's samples or its position is unknown.
    """
    from emfc_ros.core.device.faults import Fault, faults_from_extra
    description = getattr(measurements, 'description', None)
    faults = []
    try:
        if description is not None:
            faults.extend(faults_from_extra(description.extra))
        topic = f'{namespace}/measurements/description'
        text = custom_data(bag_path).get('emfc_ros.faults', '')
        for doc in load_yaml_text(text, f'{bag_path} custom data emfc_ros.faults') or []:
            if isinstance(doc, dict) and doc.get('topic', topic) == topic:
                faults.append(Fault.from_dict(doc))
    except (ValueError, yaml.YAMLError) as exc:      # YamlRefused is a ValueError
        raise DeviceFaultError(f"the bag's fault record is unreadable ({exc}): the data "
                               'cannot be trusted') from None
    alignment.refuse_faults(faults, offset, n_samples, measurements.sample_rate_Hz)


def excitation_offset_samples(measurements: Any, excitation: Any = None,
                              namespace: str = '') -> int:
    """
    Device sample index at which excitation sample 0 was applied.

    The plant simulator measures on the excitation's own sample clock (offset 0, no
    ``excitation_offset_samples`` in its description); the daq_bridge measures on the
    device's clock and publishes the offset in the measurement description's ``extra``.

    Parameters
    ----------
    measurements : Stream
        The measurement stream (:func:`read_streams`), with its description.
    excitation : Stream, optional
        The excitation stream, to check that the offset belongs to its epoch.
    namespace : str
        For messages.

    Returns
    -------
    int
        The offset [samples]: measurement ``k + offset`` responds to excitation ``k``.

    Raises
    ------
    IdentificationError
        If the description says there is an offset but it is unknown (the bridge never took
        excitation while recording) or it belongs to another excitation epoch.
    """
    description = getattr(measurements, 'description', None)
    return alignment.excitation_offset(
        description.extra if description is not None else {},
        excitation.epoch if excitation is not None else None, namespace)


def aligned_channels(measurements: Any, offset: int, n_samples: Optional[int] = None,
                     namespace: str = '') -> Dict[str, Any]:
    """
    The measured channels on the excitation's sample clock.

    Parameters
    ----------
    measurements : Stream
        The measurement stream (:func:`read_streams`).
    offset : int
        Device sample of excitation sample 0 (:func:`excitation_offset_samples`).
    n_samples : int, optional
        Samples wanted from there (the experiment's length); None: to the end of the
        recording.
    namespace : str
        For messages.

    Returns
    -------
    dict
        Channel name to a 1-D array whose index ``k`` is excitation sample ``k``.

    Raises
    ------
    IdentificationError
        If the recording does not cover the experiment.
    """
    return alignment.align({name: measurements.channel(name)
                            for name in measurements.channel_names},
                           measurements.first_sample_index, offset, n_samples, namespace)
