"""
What a plant session asks its front end to publish, as plain data, in the order to publish it.

The session (:class:`emfc_ros.core.sim.plant_session.PlantSession`) returns a list of these
from every call; the node turns each into its message. Nothing here knows ROS.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np


@dataclass(frozen=True)
class ClockTick:
    """Simulated time has reached ``stamp_ns`` [ns] (``/clock``)."""

    stamp_ns: int


@dataclass(frozen=True)
class MeasurementBlock:
    """
    Simulated samples, every channel (rows as the session's ``channel_names``).

    ``first_index`` is the sample index of column 0 on the stream's sample clock.
    """

    first_index: int
    samples: np.ndarray


@dataclass(frozen=True)
class JointStates:
    """Joint states of joint ``lever``: stamps [ns], position [m], velocity [m/s], effort [N]."""

    stamps_ns: np.ndarray
    position_m: np.ndarray
    velocity_m_per_s: np.ndarray
    effort_N: np.ndarray


@dataclass(frozen=True)
class Acknowledgement:
    """The excitation is consumed up to (not including) sample ``index``."""

    index: int


@dataclass(frozen=True)
class DescriptionChanged:
    """
    The stream descriptions changed (load, epoch, balance): publish them again.

    ``scheduled_load_kg``: the mass a load schedule entry put on the pan [kg] (the node's
    ``load_mass_kg`` parameter shows it), None for any other change.
    """

    scheduled_load_kg: Optional[float] = None


@dataclass(frozen=True)
class LogLine:
    """A line for the log: ``level`` is ``info``, ``warning`` or ``error``."""

    level: str
    text: str
