"""
What was on the pan: the pan load and the load-changer coupling of a recording.

The grey-box model of the balance needs the mass on the pan and whether the load changer's
moving mass rode on it. Neither is ever guessed: every way into the identification (a bag,
live data accumulated by the identifier node) lists where they may come from, in order of
precedence, and :func:`resolve_plant` takes each from the first source that has it, or stops
with :class:`PlantConfigurationError` naming the option or parameter to give.

Sources, as the callers use them:

* ``emfc-identify BAG`` (:func:`emfc_ros.core.ident.from_bag.resolve_plant`): the options given,
  the bag's custom data ``emfc_ros.plant_configuration`` (the experiment runner: the plan's
  mass pieces), the measurement description's ``extra`` (a plant simulator, or a daq_bridge
  told ``pan.load_mass_kg``), the recorded node parameters;
* the identifier node's live path (:func:`emfc_ros.core.ident.live.identify_accumulated`):
  its options file, its parameters ``pan.load_mass_kg`` and ``pan.load_changer_coupled``, the
  measurement description's ``extra`` received with the stream.
"""

from __future__ import annotations

from typing import Any, Dict, Mapping, Sequence, Tuple

from emfc_ros.core.ident.errors import IdentificationError
# the light part (no numerics), shared with the daq_bridge, re-exported here
from emfc_ros.core.pan_load import (declared_pan_load, MAX_LOAD_MASS_KG,  # noqa: F401
                                    plant_entries, PLANT_KEYS)


class PlantConfigurationError(IdentificationError):
    """The pan load (or the load-changer coupling) of a recording is not known."""


def resolve_plant(sources: Sequence[Tuple[str, Mapping[str, Any]]],
                  how_to_give: Mapping[str, str]) -> Tuple[Dict[str, Any], str]:
    """
    Take the pan load and the coupling each from the first source that has it.

    Parameters
    ----------
    sources : sequence of (str, Mapping)
        ``(name, entries)`` in order of precedence; ``entries`` as :func:`plant_entries`
        returns them (the name says where in words, e.g. ``'measurement description
        (extra)'``).
    how_to_give : Mapping of str to str
        Per key of :data:`PLANT_KEYS`, how the user gives it (e.g. ``'`emfc-identify
        --load-mass-kg KG` (or `load_mass_kg` in the --options file)'``).

    Returns
    -------
    settings : dict
        ``load_mass_kg`` [kg] and ``load_changer_coupled``.
    source : str
        Where each came from, e.g. ``'load_mass_kg from options; load_changer_coupled from
        measurement description (extra)'``.

    Raises
    ------
    PlantConfigurationError
        When no source gives one of them, naming the sources looked at and what to give.
    """
    settings: Dict[str, Any] = {}
    where: Dict[str, str] = {}
    for name, found in sources:
        for key in PLANT_KEYS:
            if key not in settings and key in found:
                settings[key], where[key] = found[key], name
    looked = ', '.join(name for name, _ in sources)
    if 'load_mass_kg' not in settings:
        raise PlantConfigurationError(
            f'the pan load of this recording is unknown (no load_mass_kg in: {looked}): give '
            f'it with {how_to_give["load_mass_kg"]}; the grey-box model is not identified '
            'with a guessed load')
    if 'load_changer_coupled' not in settings:
        raise PlantConfigurationError(
            f"whether the load changer's moving mass rode on the pan is unknown for this "
            f'recording (no load_changer_coupled in: {looked}): give it with '
            f'{how_to_give["load_changer_coupled"]}')
    text = '; '.join(f'{k} from {v}' for k, v in where.items())
    return settings, text
