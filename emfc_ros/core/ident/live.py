"""
Identification of live data: measurement blocks accumulated by the identifier node.

The node hands over the accumulated channels, the section table of the excitation's
description, the measurement description's ``extra`` and its own settings.
:func:`live_recording` cuts the channels to the experiment on the excitation's clock and
refuses data the device did not excite as commanded, as ``emfc-identify`` does for a bag
(:mod:`emfc_ros.core.ident.alignment`: a daq_bridge measures on the device's clock, from an
offset it publishes, and publishes its device faults); :func:`identify_accumulated` resolves
what was on the pan exactly as for a bag (:mod:`emfc_ros.core.ident.plant`), never with a
default, and runs the pipeline.
"""

from __future__ import annotations

from typing import Any, Callable, Dict, Iterable, Mapping, Optional, Sequence, Tuple

import numpy as np

from emfc_ros.core.ident import alignment
from emfc_ros.core.ident.plant import plant_entries, resolve_plant

Progress = Callable[[str, float, str], None]

#: How a user of the identifier node gives the pan load and the coupling.
NODE_HOW_TO_GIVE = {
    'load_mass_kg': "the identifier's parameter `pan.load_mass_kg` [kg] (or `load_mass_kg` in "
                    'its options_file); a daq_bridge publishes it when told '
                    '`pan.load_mass_kg`',
    'load_changer_coupled': "the identifier's parameter `pan.load_changer_coupled` "
                            "('true' or 'false'; or `load_changer_coupled` in its "
                            'options_file)'}


def resolve_live_plant(options: Optional[Mapping[str, Any]],
                       declared: Optional[Mapping[str, Any]],
                       description_extra: Optional[Mapping[str, Any]],
                       description_source: str = '') -> Tuple[Dict[str, Any], str]:
    """
    The pan load and coupling of live data, and where they come from.

    In order: the options (file), the node's declared ``pan.*`` parameters, the measurement
    description's ``extra``.

    Parameters
    ----------
    options : Mapping or None
        The identification options.
    declared : Mapping or None
        The node's declared pan load (:func:`~emfc_ros.core.pan_load.declared_pan_load`).
    description_extra : Mapping or None
        The measurement description's ``extra``.
    description_source : str
        Who published the description, for the report.

    Returns
    -------
    settings : dict
        ``load_mass_kg`` [kg] and ``load_changer_coupled``.
    source : str
        Where each came from.

    Raises
    ------
    PlantConfigurationError
        Naming the parameter or option to give.
    """
    stream = 'measurement description (extra)'
    if description_source:
        stream += f' of {description_source}'
    return resolve_plant([('options file', plant_entries(options)),
                          ('identifier parameters pan.*', plant_entries(declared)),
                          (stream, plant_entries(description_extra))], NODE_HOW_TO_GIVE)


def identify_accumulated(recording: Mapping[str, Any], sections: Sequence[Any],
                         sample_rate_Hz: float, options: Optional[Mapping[str, Any]] = None,
                         description_extra: Optional[Mapping[str, Any]] = None,
                         declared: Optional[Mapping[str, Any]] = None,
                         description_source: str = '',
                         progress: Optional[Progress] = None) -> Any:
    """
    Identify accumulated live data; the pan load from the options, the node or the stream.

    Parameters
    ----------
    recording : Mapping
        Channel name to a 1-D array, sample 0 the experiment's first sample.
    sections : sequence
        The excitation description's section table.
    sample_rate_Hz : float
        Sample rate of the measurements [Hz].
    options : Mapping, optional
        The identification options (the node's options file); its ``load_mass_kg`` and
        ``load_changer_coupled`` win.
    description_extra : Mapping, optional
        The measurement description's ``extra`` (the plant simulator publishes the pan load
        there, a daq_bridge when told ``pan.load_mass_kg``).
    declared : Mapping, optional
        The node's parameters ``pan.load_mass_kg``/``pan.load_changer_coupled`` as
        :func:`~emfc_ros.core.pan_load.declared_pan_load` returns them.
    description_source : str
        Who published the description (its ``source``), for the report.
    progress : callable, optional
        ``progress(step, fraction, message)``.

    Returns
    -------
    IdentificationResult
        The pipeline's result, its ``plant_source`` saying where the pan load came from.

    Raises
    ------
    PlantConfigurationError
        When no source gives the pan load or the coupling (naming the parameter to set).
    IdentificationError, ConfigError
        As :func:`~emfc_ros.core.ident.pipeline.identify`.
    """
    from emfc_ros.core.ident import pipeline

    given = dict(options or {})
    settings, source = resolve_live_plant(given, declared, description_extra,
                                          description_source)
    given.update(settings)
    result = pipeline.identify(recording, sections, given, sample_rate_Hz=sample_rate_Hz,
                               progress=progress)
    result.plant_source = source
    return result


def live_recording(channels: Mapping[str, np.ndarray], first_index: int,
                   sections: Sequence[Mapping[str, Any]], sample_rate_Hz: float,
                   description_extras: Iterable[Mapping[str, Any]],
                   excitation_epoch: Optional[int] = None,
                   namespace: str = '') -> Dict[str, np.ndarray]:
    """
    Accumulated measurements cut to the experiment, on the excitation's sample clock.

    Parameters
    ----------
    channels : mapping of str to ndarray
        Channel name to the accumulated 1-D record, element 0 measurement sample
        ``first_index``.
    first_index : int
        Measurement sample index of the first accumulated sample.
    sections : sequence of mapping
        The excitation description's section table.
    sample_rate_Hz : float
        Sample rate of the measurements [Hz].
    description_extras : iterable of mapping
        The ``extra`` of every measurement description received while accumulating, the
        newest last: its ``excitation_offset_samples`` places the experiment; the faults of
        all of them count (a fault acknowledged with the daq_bridge's ``~/reset`` leaves its
        later descriptions, not the data).
    excitation_epoch : int, optional
        Epoch of the excitation description whose section table is used.
    namespace : str
        For messages.

    Returns
    -------
    dict of str to ndarray
        Channel name to the record whose index ``k`` is excitation sample ``k``: the
        experiment's samples where the measurements have an offset (a daq_bridge), all the
        accumulated samples from the first on otherwise (the plant simulator).

    Raises
    ------
    IdentificationError
        If the offset is unknown or of another excitation, or the accumulated samples do not
        cover the experiment.
    DeviceFaultError
        If the device reported that the excitation was not applied as commanded during the
        experiment (or a fault record is malformed).
    """
    from emfc_ros.core.device.faults import faults_from_extra

    extras = list(description_extras) or [{}]
    offset = alignment.excitation_offset(extras[-1], excitation_epoch, namespace,
                                         'the identifier was accumulating')
    total = alignment.experiment_samples(sections)
    faults = []
    for extra in extras:
        try:
            faults.extend(faults_from_extra(extra))
        except ValueError as exc:
            raise alignment.DeviceFaultError(f"the measurement description's fault record is "
                                             f'unreadable ({exc}): the data cannot be '
                                             'trusted') from None
    alignment.refuse_faults(faults, offset, total, sample_rate_Hz)
    return alignment.align(channels, first_index, offset, total if offset else None, namespace)
