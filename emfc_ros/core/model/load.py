"""
Load-dependent mechanics.

A load on the pan and the coupled load changer add to the pan mass.
"""

from __future__ import annotations

from dataclasses import replace

from emfc_ros.core.model.parameters import MechanicalParameters


def pan_mass_kg(p: MechanicalParameters, load_mass_kg: float = 0.0,
                load_changer_coupled: bool = False) -> float:
    """
    Total mass moving with the pan point.

    Parameters
    ----------
    p : MechanicalParameters
        The mechanics (``mp_kg`` is the empty pan and load carrier).
    load_mass_kg : float
        Mass placed on the pan [kg], at least 0.
    load_changer_coupled : bool
        Whether the load changer's moving mass (``load_changer_mass_kg``) rides on the pan.

    Returns
    -------
    float
        Pan mass [kg].

    Raises
    ------
    ValueError
        If ``load_mass_kg`` is negative or not finite.
    """
    load = float(load_mass_kg)
    if not load >= 0.0 or load == float('inf'):
        raise ValueError(f'load_mass_kg must be a finite mass >= 0 kg, got {load_mass_kg!r}')
    return p.mp_kg + load + (p.load_changer_mass_kg if load_changer_coupled else 0.0)


def loaded(p: MechanicalParameters, load_mass_kg: float = 0.0,
           load_changer_coupled: bool = False) -> MechanicalParameters:
    """
    Mechanics for a given load on the pan and load-changer coupling.

    The added masses move with the pan point, so they enter the mass matrix and, through their
    weight, the gravity vector.

    Parameters
    ----------
    p : MechanicalParameters
        The mechanics of the empty, uncoupled balance.
    load_mass_kg : float
        Mass placed on the pan [kg].
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan.

    Returns
    -------
    MechanicalParameters
        A copy with ``mp_kg`` replaced by the total pan mass.
    """
    return replace(p, mp_kg=pan_mass_kg(p, load_mass_kg, load_changer_coupled))
