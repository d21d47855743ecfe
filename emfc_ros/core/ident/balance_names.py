"""
Names of the grey-box model's parameters (light: no scipy, no simulator).

The run plan's check (:mod:`emfc_ros.core.plan_check`) validates ``greybox.free`` and
``greybox.initial`` with these before anything runs; importing them must not pull in the
identification's numerical modules (``docs/benchmarks.md``, main job: those are imported while
the experiment runs).
"""

from __future__ import annotations

from dataclasses import fields
from typing import Tuple

from emfc_ros.core.model.parameters import MechanicalParameters

#: Free-parameter name of the load changer's force scale: a factor on the balance file's
#: load-changer characteristic, fitted with the mechanics so that the ratio of the two
#: actuators' force constants comes from the data (issue 28 item 2; dimensionless).
PAN_FORCE_SCALE = 'load_changer_force_scale'

#: Default free parameters (fields of MechanicalParameters): stiffnesses, dampings, the
#: lever and coil-carrier inertias and the coil mass (together they set the three entries of
#: the mass matrix, which is what the data determine), the offset force, and the load
#: changer's force scale (fixed at 1 when no fitted section moves the load changer).
DEFAULT_FREE = ('c1_Nm_per_rad', 'd1_Nms_per_rad', 'c2_Nm_per_rad', 'd2_Nms_per_rad',
                'J1c_kgm2', 'm3_kg', 'J2c_kgm2', 'F_off_N', PAN_FORCE_SCALE)


def mechanical_names() -> Tuple[str, ...]:
    """
    Names of the parameters the grey-box model accepts (all mechanical parameters).

    Returns
    -------
    tuple of str
        Field names of :class:`MechanicalParameters`, units in the names.
    """
    return tuple(f.name for f in fields(MechanicalParameters))


def free_names() -> Tuple[str, ...]:
    """
    Names ``greybox.free`` accepts: the mechanical parameters and :data:`PAN_FORCE_SCALE`.

    Returns
    -------
    tuple of str
        In that order.
    """
    return mechanical_names() + (PAN_FORCE_SCALE,)
