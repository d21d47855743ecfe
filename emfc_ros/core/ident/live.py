"""
Identification of live data: measurement blocks accumulated by the identifier node.

The node hands over the accumulated channels, the section table of the excitation's
description, the measurement description's ``extra`` and its own settings;
:func:`identify_accumulated` resolves what was on the pan exactly as ``emfc-identify`` does for
a bag (:mod:`emfc_ros.core.ident.plant`), never with a default, and runs the pipeline.
"""

from __future__ import annotations

from typing import Any, Callable, Dict, Mapping, Optional, Sequence, Tuple

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
