"""
Identification straight from a recorded bag.

The offline command, the identifier node and the experiment runner all call
:func:`identify_bag`.

The bag must hold a measurement block stream (``<ns>/measurements``) and the excitation's
stream description (``<ns>/excitation/description``, which carries the section table); the
plant configuration (pan load, load-changer coupling) is taken from the recorded node
parameters when the options do not give it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Dict, Mapping, Optional, Tuple

import yaml

from emfc_ros.core.bag import custom_data, read_streams
from emfc_ros.core.ident.errors import IdentificationError

Progress = Callable[[str, float, str], None]
PLANT_KEYS = ('load_mass_kg', 'load_changer_coupled')


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
        params = yaml.safe_load(custom_data(bag_path).get('emfc_ros.node_parameters', '')
                                or '{}') or {}
    except yaml.YAMLError:
        return {}
    for node in params.values():
        values = (node or {}).get('ros__parameters', {}) if isinstance(node, dict) else {}
        if all(key in values for key in PLANT_KEYS):
            return {key: values[key] for key in PLANT_KEYS}
    return {}


def identify_bag(bag_path: Path, options: Optional[Mapping[str, Any]] = None,
                 namespace: Optional[str] = None, progress: Optional[Progress] = None,
                 streams: Optional[Mapping[str, Any]] = None) -> Tuple[Any, Dict[str, Any]]:
    """
    Read a bag back and identify the balance from it.

    Parameters
    ----------
    bag_path : pathlib.Path
        The bag folder.
    options : Mapping, optional
        Identification options (the pipeline's configuration mapping).
    namespace : str, optional
        Which namespace's streams to use when the bag holds several.
    progress : callable, optional
        ``progress(step, fraction, message)``.
    streams : Mapping, optional
        The bag's streams if the caller has read them already (:func:`read_streams`).

    Returns
    -------
    result : IdentificationResult
        The pipeline's result.
    info : dict
        What was read: namespace, samples, sample rate, sections, plant settings used.

    Raises
    ------
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
    description = excitation.description if excitation is not None else None
    sections = description.extra.get('sections', []) if description is not None else []
    if not sections:
        raise IdentificationError(f'the bag has no section table: record '
                                  f'{ns}/excitation/description with the experiment')
    if measurements.first_sample_index != 0:
        raise IdentificationError(f'{ns}/measurements starts at sample '
                                  f'{measurements.first_sample_index}, not 0: the start of '
                                  'the experiment was not recorded')
    options = dict(options or {})
    settings = plant_settings(bag_path)
    for key, value in settings.items():
        options.setdefault(key, value)
    recording = {name: measurements.channel(name) for name in measurements.channel_names}
    report('read bag', 1.0, f'{measurements.n_samples} samples of {ns}/measurements')
    result = pipeline.identify(recording, sections, options,
                               sample_rate_Hz=measurements.sample_rate_Hz, progress=progress)
    info = {'namespace': ns, 'samples': measurements.n_samples,
            'sample_rate_Hz': measurements.sample_rate_Hz, 'sections': sections,
            'plant_settings_from_bag': settings}
    return result, info
