"""
What every launch file of the package shares: the common arguments and the argument check.

Imported by ``launch/*.launch.py`` only (it needs ROS 2's ``launch`` and ``launch_ros``,
which ``ros2 launch`` has; nothing else in the package imports this module).

- :func:`common_arguments`: ``namespace`` (default ``emfc``; one experiment graph per
  namespace) and ``discovery_range`` (the nodes' ``ROS_AUTOMATIC_DISCOVERY_RANGE``, default
  ``LOCALHOST``); :func:`gate_arguments` and :func:`generator_gate_parameters`: the start
  gate and pacing of a generator that feeds a plant simulator or a daq_bridge.
- :func:`refuse_undeclared`: an action that ends the launch with an error naming an
  argument the file does not declare (``ros2 launch`` itself sets any ``name:=value`` as a
  launch configuration and ignores it silently: ``use_sim_time:=false`` would do nothing).
  It checks the arguments of the command line when this file is the one ``ros2 launch``
  was given; a file included by another launch file gets its arguments from the including
  file, which ``launch`` does not tell apart from that file's own configurations, so there
  it checks nothing.
"""

from __future__ import annotations

import os
import sys
from typing import Iterable, List, Optional, Sequence

from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.parameter_descriptions import ParameterValue

#: Values of ROS_AUTOMATIC_DISCOVERY_RANGE (rcl).
DISCOVERY_RANGES = ['LOCALHOST', 'SUBNET', 'OFF', 'SYSTEM_DEFAULT']
#: Suffixes of launch files on a ``ros2 launch`` command line.
LAUNCH_SUFFIXES = ('.launch.py', '.launch.xml', '.launch.yaml', '.py', '.xml', '.yaml')


def common_arguments() -> List[DeclareLaunchArgument]:
    """
    ``namespace`` and ``discovery_range``, declared the same way in every file.

    Returns
    -------
    list of DeclareLaunchArgument
        The two declarations.
    """
    return [
        DeclareLaunchArgument(
            'namespace', default_value='emfc',
            description='namespace of every node of this launch (one experiment per '
                        'namespace; a PushROSNamespace of an including file is prepended)'),
        DeclareLaunchArgument(
            'discovery_range', default_value='LOCALHOST', choices=DISCOVERY_RANGES,
            description='ROS_AUTOMATIC_DISCOVERY_RANGE of the nodes: LOCALHOST keeps '
                        'discovery on this computer (ROS_STATIC_PEERS in the environment '
                        'adds named computers: docs/two_computers.md); SUBNET multicasts '
                        'it on every network this computer is on'),
    ]


#: The generator's start gates (signal_generator parameter ``start_gate``).
START_GATES = ['applier', 'subscribers', 'none']


def gate_arguments(applier: str, starts: str, paced_by: str) -> List[DeclareLaunchArgument]:
    """
    The start-gate and pacing arguments of a file whose generator feeds an applier.

    Parameters
    ----------
    applier : str
        What applies the excitation, for the descriptions (``'the plant'``).
    starts : str
        What the applier does once its listeners matched (``'subscribes to the excitation'``).
    paced_by : str
        What consumer pacing follows (``"the plant's acknowledgements"``).

    Returns
    -------
    list of DeclareLaunchArgument
        ``min_subscribers`` (1), ``excitation_subscribers`` (2), ``start_gate`` (applier),
        ``pacing`` (consumer) and ``window_blocks`` (8).
    """
    return [
        DeclareLaunchArgument(
            'min_subscribers', default_value='1',
            description=f'{applier} {starts} (and is ready) once this many subscriptions to '
                        'measurements (a recorder) matched [count]; 0: at once'),
        DeclareLaunchArgument(
            'excitation_subscribers', default_value='2',
            description=f'sample 0 also waits for this many subscriptions to the excitation '
                        f'[count], that of {applier} included: 2 = {applier} and a recorder '
                        'of the excitation; 1 when nothing records the excitation'),
        DeclareLaunchArgument(
            'start_gate', default_value='applier', choices=START_GATES,
            description=f'what sample 0 waits for: applier = {applier} ready on '
                        'excitation/ready (and excitation_subscribers); subscribers = the '
                        'count alone; none = nothing'),
        DeclareLaunchArgument(
            'pacing', default_value='consumer', choices=['consumer', 'wall'],
            description=f"consumer = {paced_by}; wall = this computer's clock"),
        DeclareLaunchArgument(
            'window_blocks', default_value='8',
            description=f'consumer pacing: excitation blocks in flight ahead of {paced_by} '
                        '[blocks]'),
    ]


def generator_gate_parameters() -> dict:
    """
    The generator's parameters from the arguments of :func:`gate_arguments`.

    Returns
    -------
    dict
        ``pacing``, ``start_gate``, ``min_subscribers`` and ``window_blocks``.
    """
    return {
        'pacing': ParameterValue(LaunchConfiguration('pacing'), value_type=str),
        'start_gate': ParameterValue(LaunchConfiguration('start_gate'), value_type=str),
        'min_subscribers': ParameterValue(LaunchConfiguration('excitation_subscribers'),
                                          value_type=int),
        'window_blocks': ParameterValue(LaunchConfiguration('window_blocks'),
                                        value_type=int),
    }


def node_environment() -> dict:
    """
    The environment every node of a launch gets.

    Returns
    -------
    dict
        ``ROS_AUTOMATIC_DISCOVERY_RANGE`` from the ``discovery_range`` argument.
    """
    return {'ROS_AUTOMATIC_DISCOVERY_RANGE': LaunchConfiguration('discovery_range')}


def command_line_launch_file(argv: Sequence[str]) -> Optional[str]:
    """
    The launch file a ``ros2 launch`` command line names, if ``argv`` is one.

    Parameters
    ----------
    argv : sequence of str
        The process's arguments (``sys.argv``).

    Returns
    -------
    str or None
        The file's name or path as typed (``ros2 launch emfc_ros sim_experiment.launch.py``
        gives ``sim_experiment.launch.py``), or None when ``argv`` is not ``ros2 launch``.
    """
    words = list(argv)
    if len(words) < 3 or os.path.basename(words[0]) != 'ros2' or 'launch' not in words[1:]:
        return None
    for word in words[words.index('launch', 1) + 1:]:
        if ':=' in word:
            return None
        if not word.startswith('-') and word.endswith(LAUNCH_SUFFIXES):
            return word
    return None


def undeclared(arguments: Iterable[str], declared: Iterable[str]) -> List[str]:
    """
    The names of ``name:=value`` arguments that are not declared.

    Parameters
    ----------
    arguments : iterable of str
        Launch arguments as on the command line.
    declared : iterable of str
        The names the file declares.

    Returns
    -------
    list of str
        Undeclared names, in order, each once.
    """
    known = set(declared)
    out: List[str] = []
    for argument in arguments:
        if ':=' not in argument:
            continue
        name = argument.split(':=', 1)[0]
        if name not in known and name not in out:
            out.append(name)
    return out


def _check(context, declared: Sequence[str]) -> list:
    here = getattr(context.locals, 'current_launch_file_path', None)
    typed = command_line_launch_file(sys.argv)
    if here is None or typed is None or os.path.basename(typed) != os.path.basename(here):
        return []       # included by another file (or not run by ros2 launch): not ours
    if os.sep in typed and os.path.realpath(typed) != os.path.realpath(here):
        return []
    unknown = undeclared(context.argv or [], declared)
    if unknown:
        raise RuntimeError(
            f'{os.path.basename(here)} does not take the argument(s) '
            f'{", ".join(unknown)} (a misspelt or unsupported argument would be ignored); '
            f'it takes: {", ".join(sorted(declared))} (ros2 launch emfc_ros '
            f'{os.path.basename(here)} --show-args)')
    return []


def refuse_undeclared(declared: Sequence[str]) -> OpaqueFunction:
    """
    An action that fails the launch on a command-line argument the file does not declare.

    Parameters
    ----------
    declared : sequence of str
        Every argument the file declares.

    Returns
    -------
    OpaqueFunction
        Put it first in the description, so that no node starts.
    """
    names = list(declared)
    return OpaqueFunction(function=_check, args=[names])


def declared_names(entities: Iterable[object]) -> List[str]:
    """
    Names of the ``DeclareLaunchArgument`` entities of a list.

    Parameters
    ----------
    entities : iterable
        Launch entities.

    Returns
    -------
    list of str
        The argument names.
    """
    return [e.name for e in entities if isinstance(e, DeclareLaunchArgument)]
