"""
The device contract of both device nodes: effort commands in, joint states and groups out.

The daq_bridge (hardware) and the plant_simulator (the simulated balance) are drop-ins for
each other, so that a controller, a recorder or an experiment runs on either unchanged. What
they share is decided here, once:

- **effort commands** on ``joint_commands`` (``sensor_msgs/JointState``, joint ``lever``) or
  ``commands`` (``std_msgs/Float64MultiArray``, one value): the coil force [N], checked by
  :func:`joint_command_effort` and :func:`array_command_effort` and held by
  :class:`EffortCommand`, whose watchdog returns it to 0 N after ``command_timeout_s``;
- **measurement groups**: ``measurements/position``, ``current`` and ``force`` hold the
  channels of unit m, A and N, position also ``sensor_V`` (:func:`measurement_groups`);
- **joint states** at ``state_rate_Hz``: the samples on the grid of the device's sample
  index (:func:`state_sample_offsets`), stamped from the epoch's start.
"""

from __future__ import annotations

import math
from typing import Dict, Sequence, Tuple

import numpy as np

from emfc_ros.core.errors import EmfcError

#: The joint of the balance's lever in ``joint_states`` and ``joint_commands``.
JOINT = 'lever'
#: The grouped measurement streams and the units of their channels.
GROUP_UNITS = {'position': ('m',), 'current': ('A',), 'force': ('N',)}
#: Channels a group holds besides those of its units.
GROUP_EXTRA = {'position': ('sensor_V',)}


class CommandError(EmfcError, ValueError):
    """An effort command is malformed (the message names what is wrong)."""


def joint_command_effort(names: Sequence[str], efforts: Sequence[float],
                         joint: str = JOINT) -> float:
    """
    The effort a ``JointState`` command gives the lever.

    Parameters
    ----------
    names : sequence of str
        The message's joint names.
    efforts : sequence of float
        Its efforts, one per name [N].
    joint : str
        The joint to read.

    Returns
    -------
    float
        The effort [N], finite.

    Raises
    ------
    CommandError
        Without an effort for the joint, or a non-finite one.
    """
    names = list(names)
    if joint not in names or len(efforts) != len(names):
        raise CommandError(f'joint_commands needs an effort for joint {joint!r}; got names '
                           f'{names} with {len(efforts)} efforts')
    return _finite(float(efforts[names.index(joint)]))


def array_command_effort(data: Sequence[float]) -> float:
    """
    The effort a ``Float64MultiArray`` command gives the lever.

    Parameters
    ----------
    data : sequence of float
        The message's data: exactly one value [N].

    Returns
    -------
    float
        The effort [N], finite.

    Raises
    ------
    CommandError
        Unless it holds exactly one finite value.
    """
    if len(data) != 1:
        raise CommandError(f'commands needs exactly 1 value (effort [N]), got {len(data)}')
    return _finite(float(data[0]))


def _finite(effort_N: float) -> float:
    if not math.isfinite(effort_N):
        raise CommandError(f'effort command {effort_N!r} N is not finite')
    return effort_N


class EffortCommand:
    """
    The effort command held between messages, with its watchdog.

    Attributes
    ----------
    effort_N : float
        The command now [N] (0 before the first and after a watchdog trip).
    watchdog_trips : int
        Commands returned to 0 N because none came for ``timeout_s``.
    """

    def __init__(self) -> None:
        self.effort_N = 0.0
        self.watchdog_trips = 0
        self._time_s = -math.inf

    def set(self, effort_N: float, now_s: float) -> None:
        """
        A new command.

        Parameters
        ----------
        effort_N : float
            The effort [N] (checked by the parsers above).
        now_s : float
            When it arrived (monotonic) [s].
        """
        self.effort_N = float(effort_N)
        self._time_s = float(now_s)

    def clear(self) -> None:
        """Back to 0 N now (a safe-output hold), not counted as a watchdog trip."""
        self.effort_N = 0.0

    def value(self, now_s: float, timeout_s: float) -> float:
        """
        The command in force at ``now_s``: 0 N once ``timeout_s`` passed without a new one.

        Parameters
        ----------
        now_s : float
            Now (monotonic) [s].
        timeout_s : float
            The command watchdog [s].

        Returns
        -------
        float
            The effort [N].
        """
        if self.effort_N != 0.0 and now_s - self._time_s > timeout_s:
            self.effort_N = 0.0
            self.watchdog_trips += 1
        return self.effort_N


def measurement_groups(names: Sequence[str], units: Sequence[str]) -> Dict[str, Tuple[int, ...]]:
    """
    The rows of each grouped measurement stream (groups without a channel are left out).

    Parameters
    ----------
    names, units : sequence of str
        The channels of the measurement stream, in row order.

    Returns
    -------
    dict
        Group name (``position``, ``current``, ``force``) to its rows, in stream order.
    """
    groups = {}
    for group, wanted in GROUP_UNITS.items():
        rows = tuple(i for i, (n, u) in enumerate(zip(names, units))
                     if u in wanted or n in GROUP_EXTRA.get(group, ()))
        if rows:
            groups[group] = rows
    return groups


def state_sample_offsets(first_sample_index: int, n_samples: int, sample_rate_Hz: float,
                         state_rate_Hz: float) -> np.ndarray:
    """
    The samples of a block that are joint states, on the grid of the device's sample index.

    Every ``sample_rate / state_rate``-th device sample (counted from the epoch's sample 0,
    not from the block's first).

    Parameters
    ----------
    first_sample_index : int
        The block's first device sample index.
    n_samples : int
        Its length.
    sample_rate_Hz, state_rate_Hz : float
        The sample rate and the joint-state rate [Hz] (<= 0: none).

    Returns
    -------
    numpy.ndarray
        Offsets into the block, ascending.
    """
    if state_rate_Hz <= 0.0:
        return np.zeros(0, dtype=np.int64)
    step = max(1, int(round(sample_rate_Hz / state_rate_Hz)))
    return np.arange((-int(first_sample_index)) % step, int(n_samples), step, dtype=np.int64)
