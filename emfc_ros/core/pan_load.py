"""
The pan load and load-changer coupling as a user declares them (no numerics imported).

Shared by the daq_bridge (``pan.load_mass_kg``, ``pan.load_changer_coupled``, published in the
measurement description), the identifier node (the same parameters for its live path) and the
identification's resolution of what was on the pan (:mod:`emfc_ros.core.ident.plant`).
"""

from __future__ import annotations

import math
from typing import Any, Dict, Mapping

from emfc_ros.core.errors import ConfigError

#: The two settings, as keys of the options, the description's ``extra`` and node parameters.
PLANT_KEYS = ('load_mass_kg', 'load_changer_coupled')
#: Largest pan load accepted [kg] (the identification options' limit).
MAX_LOAD_MASS_KG = 100.0


def plant_entries(mapping: Any) -> Dict[str, Any]:
    """
    The pan load and coupling a mapping gives (keys absent or None left out).

    Parameters
    ----------
    mapping : Mapping or None
        Options, a description's ``extra``, node parameters.

    Returns
    -------
    dict
        The entries of :data:`PLANT_KEYS` it has.
    """
    if not isinstance(mapping, Mapping):
        return {}
    return {k: mapping[k] for k in PLANT_KEYS if mapping.get(k) is not None}


def declared_pan_load(load_mass_kg: float, coupled: str, prefix: str = 'pan.') -> Dict[str, Any]:
    """
    The pan load a user declared as node parameters (``pan.load_mass_kg``, ``pan.*coupled``).

    Parameters
    ----------
    load_mass_kg : float
        ``pan.load_mass_kg`` [kg]; negative: not declared.
    coupled : str
        ``pan.load_changer_coupled``: ``'true'``, ``'false'`` or ``''`` (not declared).
    prefix : str
        Prefix of the parameter names, for messages.

    Returns
    -------
    dict
        ``load_mass_kg`` and ``load_changer_coupled`` as declared (empty when not).

    Raises
    ------
    ConfigError
        For a non-finite or too large mass, or another coupling text.
    """
    out: Dict[str, Any] = {}
    if not math.isfinite(load_mass_kg) or load_mass_kg > MAX_LOAD_MASS_KG:
        raise ConfigError(f'{prefix}load_mass_kg', f'must be from 0 to {MAX_LOAD_MASS_KG:g} kg '
                                                   f'(negative: not declared), got '
                                                   f'{load_mass_kg}')
    if load_mass_kg >= 0.0:
        out['load_mass_kg'] = float(load_mass_kg)
    if coupled not in ('', 'true', 'false'):
        raise ConfigError(f'{prefix}load_changer_coupled', f"must be 'true', 'false' or '', "
                                                           f'got {coupled!r}')
    if coupled:
        out['load_changer_coupled'] = coupled == 'true'
    return out
