"""
Stand-in for ``ros2 launch <package> <file> [name:=value ...]`` (``ros2launch.api``).

Finds the launch file in the package's share directory, loads it as
``PythonLaunchDescriptionSource`` does, parses the arguments (``parse_launch_arguments``:
``name:=value``; malformed ones are an error; the last one wins; names the file does not
declare are set as launch configurations and simply unused), checks that every argument
without a default was given (``IncludeLaunchDescription``), then executes the entities in
order and returns the processes the real tool would start instead of starting them.
"""

from __future__ import annotations

from dataclasses import dataclass
import importlib.util
import os
from pathlib import Path
import shlex
import sys
from typing import Dict, List, Sequence, Tuple

from ament_index_python.packages import get_package_share_directory
from launch import LaunchContext, LaunchDescription
from launch_ros.actions import Node as NodeAction, NodeProcess


@dataclass
class Launched:
    """
    The result of a launch.

    Attributes
    ----------
    processes : list of NodeProcess
        The node processes, in launch order.
    context : LaunchContext
        Launch configurations, warnings and the configurations used.
    description : LaunchDescription
        The launch file's description.
    """

    processes: List[NodeProcess]
    context: LaunchContext
    description: LaunchDescription


def find_launch_file(package: str, file_name: str) -> Path:
    """
    The launch file in the package's share directory (``get_share_file_path_from_package``).

    Parameters
    ----------
    package : str
        The package.
    file_name : str
        The launch file's name.

    Returns
    -------
    pathlib.Path
        Its path.

    Raises
    ------
    FileNotFoundError
        If it is not there, or there more than once.
    """
    share = get_package_share_directory(package)
    found = [Path(root, name) for root, _, files in os.walk(share) for name in files
             if name == file_name]
    if len(found) != 1:
        raise FileNotFoundError(f"file '{file_name}' was found {len(found)} times in the "
                                f"share directory of package '{package}' which is at '{share}'")
    return found[0]


def parse_launch_arguments(arguments: Sequence[str]) -> List[Tuple[str, str]]:
    """
    Parse ``name:=value`` arguments as ``ros2launch.api.parse_launch_arguments`` does.

    Parameters
    ----------
    arguments : sequence of str
        The command-line arguments after the launch file.

    Returns
    -------
    list of (str, str)
        Name and value; the last of a repeated name wins.

    Raises
    ------
    RuntimeError
        For a malformed argument.
    """
    parsed: Dict[str, str] = {}
    for argument in arguments:
        count = argument.count(':=')
        if count == 0 or argument.startswith(':=') or (count == 1 and argument.endswith(':=')):
            raise RuntimeError(f"malformed launch argument '{argument}', expected format "
                               "'<name>:=<value>'")
        name, value = argument.split(':=', maxsplit=1)
        parsed[name] = value
    return list(parsed.items())


def split_ros2_launch(line: str) -> Tuple[str, str, List[str]]:
    """
    Split a shell line ``ros2 launch <package> <file> [args] [# comment]``.

    Parameters
    ----------
    line : str
        The line (as in the README).

    Returns
    -------
    tuple
        Package, launch file name, launch arguments.
    """
    words = shlex.split(line, comments=True)
    start = words.index('launch')
    if start == 0 or words[start - 1] != 'ros2':
        raise ValueError(f'not a ros2 launch line: {line!r}')
    words = words[start + 1:]
    return words[0], words[1], words[2:]


def load_launch_description(path: Path) -> LaunchDescription:
    """
    Import a Python launch file and call its ``generate_launch_description()``.

    Parameters
    ----------
    path : pathlib.Path
        The ``.launch.py`` file.

    Returns
    -------
    LaunchDescription
        What it returns.
    """
    spec = importlib.util.spec_from_file_location(path.name.replace('.', '_'), str(path))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    if not isinstance(description, LaunchDescription):
        raise TypeError(f'{path}: generate_launch_description() returned {description!r}')
    return description


def launch(path: Path, arguments: Sequence[str], params_dir: Path) -> Launched:
    """
    Evaluate a launch file with command-line arguments as ``ros2 launch`` does.

    Parameters
    ----------
    path : pathlib.Path
        The launch file.
    arguments : sequence of str
        ``name:=value`` arguments.
    params_dir : pathlib.Path
        Where params files of dict parameters go.

    Returns
    -------
    Launched
        The processes to start.

    Raises
    ------
    RuntimeError
        For a malformed or a missing required argument (the message names it).
    """
    parsed = parse_launch_arguments(arguments)
    description = load_launch_description(path)
    given = [name for name, _ in parsed]
    for argument in description.get_launch_arguments():
        if argument.default_value is None and argument.name not in given:
            raise RuntimeError('Included launch description missing required argument '
                               f"'{argument.name}' (description: '{argument.description}'), "
                               f"given: [{', '.join(given)}]")
    context = LaunchContext(argv=list(arguments))
    context.locals.current_launch_file_path = str(path)
    context.launch_configurations.update(parsed)
    processes = []
    # What ``ros2 launch <package> <file> ...`` has in sys.argv (a file checks whether it is
    # the one on the command line, emfc_ros.launch_support).
    argv, sys.argv = sys.argv, ['ros2', 'launch', 'emfc_ros', path.name, *arguments]
    try:
        for entity in description.entities:
            if isinstance(entity, NodeAction):
                processes.append(entity.execute(context, params_dir))
            else:
                entity.execute(context)
    finally:
        sys.argv = argv
    return Launched(processes, context, description)
