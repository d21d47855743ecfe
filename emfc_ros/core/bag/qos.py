"""
Offered QoS profiles in the form rosbag2 (metadata version 9) stores them.

rosbag2 keeps, per topic, the list of QoS profiles its publishers offered: in
``metadata.yaml`` as a YAML list under ``offered_qos_profiles``, and in each MCAP channel's
metadata as the same list serialised to YAML text. Durations are ``{sec, nsec}``; an
infinite duration is ``2**63 - 1`` ns, that is ``{sec: 9223372036, nsec: 854775807}``.
"""

from __future__ import annotations

import dataclasses
from typing import Dict, List, Sequence

import yaml

HISTORY = ('system_default', 'keep_last', 'keep_all', 'unknown')
RELIABILITY = ('system_default', 'reliable', 'best_effort', 'unknown', 'best_available')
DURABILITY = ('system_default', 'transient_local', 'volatile', 'unknown', 'best_available')
LIVELINESS = ('system_default', 'automatic', 'manual_by_node', 'manual_by_topic', 'unknown',
              'best_available')
INFINITE_NS = 2 ** 63 - 1


@dataclasses.dataclass(frozen=True)
class OfferedQos:
    """
    One publisher's offered QoS, with rosbag2's lower-case policy names.

    Attributes
    ----------
    history : str
        One of :data:`HISTORY`.
    depth : int
        History depth [messages].
    reliability : str
        One of :data:`RELIABILITY`.
    durability : str
        One of :data:`DURABILITY`.
    deadline_ns : int
        Deadline [ns]; 0 or ``INFINITE_NS`` when unset.
    lifespan_ns : int
        Lifespan [ns].
    liveliness : str
        One of :data:`LIVELINESS`.
    liveliness_lease_duration_ns : int
        Liveliness lease duration [ns].
    avoid_ros_namespace_conventions : bool
        As in ``rmw_qos_profile_t``.
    """

    history: str = 'keep_last'
    depth: int = 10
    reliability: str = 'reliable'
    durability: str = 'volatile'
    deadline_ns: int = INFINITE_NS
    lifespan_ns: int = INFINITE_NS
    liveliness: str = 'automatic'
    liveliness_lease_duration_ns: int = INFINITE_NS
    avoid_ros_namespace_conventions: bool = False

    def to_dict(self) -> Dict[str, object]:
        """
        The profile as rosbag2 writes it in metadata version 9.

        Returns
        -------
        dict
            Policy names and ``{sec, nsec}`` durations.
        """
        return {
            'history': self.history,
            'depth': int(self.depth),
            'reliability': self.reliability,
            'durability': self.durability,
            'deadline': _duration(self.deadline_ns),
            'lifespan': _duration(self.lifespan_ns),
            'liveliness': self.liveliness,
            'liveliness_lease_duration': _duration(self.liveliness_lease_duration_ns),
            'avoid_ros_namespace_conventions': bool(self.avoid_ros_namespace_conventions),
        }


def policy_name(names: Sequence[str], value: int) -> str:
    """
    The rosbag2 name of a policy given as its rmw enum value.

    Parameters
    ----------
    names : sequence of str
        :data:`HISTORY`, :data:`RELIABILITY`, :data:`DURABILITY` or :data:`LIVELINESS`.
    value : int
        The enum value (``rmw_qos_*_policy_t``).

    Returns
    -------
    str
        The name, ``'unknown'`` for values out of range.
    """
    value = int(value)
    return names[value] if 0 <= value < len(names) else 'unknown'


def qos_list(profiles: Sequence[OfferedQos]) -> List[Dict[str, object]]:
    """
    The ``offered_qos_profiles`` value of ``metadata.yaml`` (version 9).

    Parameters
    ----------
    profiles : sequence of OfferedQos
        One per publisher.

    Returns
    -------
    list of dict
        The profiles.
    """
    return [p.to_dict() for p in profiles]


def qos_yaml(profiles: Sequence[OfferedQos]) -> str:
    """
    The ``offered_qos_profiles`` text of an MCAP channel's metadata.

    Parameters
    ----------
    profiles : sequence of OfferedQos
        One per publisher.

    Returns
    -------
    str
        The YAML list as text (``'[]'`` when empty).
    """
    if not profiles:
        return '[]'
    return yaml.safe_dump(qos_list(profiles), default_flow_style=False, sort_keys=False).strip()


def _duration(ns: int) -> Dict[str, int]:
    ns = int(min(max(ns, 0), INFINITE_NS))
    sec, nsec = divmod(ns, 1_000_000_000)
    return {'sec': sec, 'nsec': nsec}
