"""
Launch files and ``ros2`` command lines as users run them: the real tools when installed.

``tools/setup_env.sh`` installs the real ROS 2 Jazzy command line (``ros2 launch``, ``ros2
run``, ``ros2 service``, ``ros2 topic``...) from ``../shared/ros2-jazzy-cli`` when that folder
exists (CI has it). Then :func:`start_launch` runs ``ros2 launch <package> <file> ARGS`` as a
process, and :func:`as_started` runs a ``ros2 ...`` line as typed. Without it (a clone
without ``../shared``) the launch file is evaluated by the test stand-in ``test/launch_stub``
and its nodes are started as ``ros2 launch`` would start them, ``ros2 run`` lines run the
executable ``ros2 run`` would run, and :func:`which_tools` says so in the test output.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
import signal
import subprocess
import sys
from typing import Dict, List, Optional, Sequence

import ros_harness
from ros_harness import scaled

REPO = Path(__file__).resolve().parents[1]
CLI_SOURCE = REPO.parent / 'shared' / 'ros2-jazzy-cli'


def installed_cli() -> bool:
    """
    Whether this environment has the real ``ros2`` command line and launch packages.

    Returns
    -------
    bool
        True when ``<venv>/bin/ros2`` and the ``ros2launch`` package are installed.
    """
    return Path(sys.prefix, 'bin', 'ros2').exists() and \
        importlib.util.find_spec('ros2launch') is not None


def real_cli() -> bool:
    """
    Whether the launch tests use the real tools.

    Returns
    -------
    bool
        :func:`installed_cli`, unless ``EMFC_LAUNCH_TOOL=stand-in`` asks for the stand-in
        (to run the tests as a clone without ``../shared`` does).
    """
    return installed_cli() and os.environ.get('EMFC_LAUNCH_TOOL', '') != 'stand-in'


def which_tools() -> str:
    """
    The line the tests print about the tools they ran.

    Returns
    -------
    str
        Which ``ros2 launch`` (and ``ros2`` verbs) the launch tests use.
    """
    if real_cli():
        return ('launch tests: the real ros2 launch / ros2 run / ros2 service / ros2 topic '
                '(ROS 2 Jazzy ros2cli 0.32.2, launch 3.4.3, launch_ros 0.26.6, installed from '
                f'{CLI_SOURCE})')
    why = ('EMFC_LAUNCH_TOOL=stand-in' if installed_cli() else
           f'the real ROS 2 command line is not installed: {CLI_SOURCE} is absent')
    return (f'launch tests: the test stand-in test/launch_stub ({why}); ros2 run lines run '
            'the executable ros2 run resolves, ros2 service call and topic echo are done '
            'with rclpy')


def as_started(argv: Sequence[str]) -> List[str]:
    """
    The process a typed command line starts.

    Parameters
    ----------
    argv : sequence of str
        The line's words.

    Returns
    -------
    list of str
        With the real command line: the line as typed. Without it, ``ros2 run PKG EXE ARGS``
        becomes ``<prefix>/lib/PKG/EXE ARGS`` (what ``ros2 run`` executes); other ``ros2``
        verbs are refused (the caller does them with rclpy).
    """
    argv = list(argv)
    if real_cli() or argv[:1] != ['ros2']:
        return argv
    if argv[:2] == ['ros2', 'run']:
        return [str(ros_harness.resolve_ros2run(argv[2], argv[3]))] + argv[4:]
    raise AssertionError(f'no stand-in for {argv}: the real ros2 command line is not here')


class TypedProcess(ros_harness.NodeProcess):
    """
    A command started as a shell starts it, and interrupted like Ctrl-C in its terminal.

    The command runs in a process group of its own (a terminal's foreground job); Ctrl-C is
    SIGINT to that group, so ``ros2 run``'s child (the node) gets it as in a terminal
    (``ros2 run`` itself only waits for its child). If the job has not ended in time the
    group, started here, is killed.

    Parameters
    ----------
    argv : sequence of str
        The command.
    log_dir : pathlib.Path
        Where its output goes.
    env : dict, optional
        Extra environment variables.
    cwd : pathlib.Path, optional
        Working directory.
    """

    def __init__(self, argv: Sequence[str], log_dir: Path,
                 env: Optional[Dict[str, str]] = None, cwd: Optional[Path] = None) -> None:
        super().__init__(argv, log_dir, env=env, cwd=cwd, new_session=True)

    def wait(self, timeout_s: float) -> Optional[int]:
        """
        Wait for the job to end by itself.

        Parameters
        ----------
        timeout_s : float
            Upper bound [s].

        Returns
        -------
        int or None
            Its exit code, None if it still runs.
        """
        try:
            return self.proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            return None

    def stop(self, timeout_s: float = scaled(30.0)) -> int:
        """
        Ctrl-C (SIGINT to the job's group), then SIGKILL to the group if it does not end.

        Parameters
        ----------
        timeout_s : float
            Wait after SIGINT [s].

        Returns
        -------
        int
            The exit code of the job's first process.
        """
        if self.stdout.closed:                          # stopped before
            return self.proc.returncode
        if self.proc.poll() is None:
            _signal_group(self.pid, signal.SIGINT)
            if self.wait(timeout_s) is None:
                _signal_group(self.pid, signal.SIGKILL)
                self.proc.wait(timeout=scaled(10))
                ros_harness.clean_shared_memory()
        else:
            # ended by itself: end what it may have left in its group (still ours: the
            # group's id stays taken while any member lives)
            _signal_group(self.pid, signal.SIGKILL)
        self.stdout.close()
        return self.proc.returncode


def _signal_group(pgid: int, sig: int) -> None:
    """Signal the process group we started (gone already: nothing to do)."""
    try:
        os.killpg(pgid, sig)
    except ProcessLookupError:
        pass


class LaunchProcess(TypedProcess):
    """
    ``ros2 launch ARGS`` as a terminal job, interrupted like Ctrl-C.

    Parameters
    ----------
    args : sequence of str
        What follows ``ros2 launch`` (package, file, ``name:=value`` ...).
    log_dir : pathlib.Path
        Where its output goes.
    env : dict, optional
        Extra environment variables.
    cwd : pathlib.Path, optional
        Working directory.
    """

    def __init__(self, args: Sequence[str], log_dir: Path,
                 env: Optional[Dict[str, str]] = None, cwd: Optional[Path] = None) -> None:
        super().__init__(['ros2', 'launch', *args], log_dir, env=env, cwd=cwd)


class StubLaunch:
    """
    The stand-in's launch: the file evaluated, each node started as ``ros2 launch`` would.

    Parameters
    ----------
    stub : module
        ``ros2launch_stub``.
    path : pathlib.Path
        The installed launch file.
    args : sequence of str
        ``name:=value`` arguments.
    log_dir : pathlib.Path
        Where the node processes' output goes.
    """

    def __init__(self, stub, path: Path, args: Sequence[str], log_dir: Path) -> None:
        self.launched = stub.launch(path, list(args), log_dir / 'launch_params')
        self.nodes = [ros_harness.NodeProcess(p.cmd, log_dir, env=p.additional_env)
                      for p in self.launched.processes]

    def output(self) -> str:
        """What the node processes printed so far."""
        return '\n'.join(f'--- {p.argv[0]}\n{p.output()}' for p in self.nodes)

    def alive(self) -> bool:
        """Whether every node process still runs."""
        return all(p.alive() for p in self.nodes)

    def stop(self, timeout_s: float = scaled(30.0)) -> int:
        """
        Ctrl-C to every node; 0 when each ended with 0, else the first other exit code.

        Parameters
        ----------
        timeout_s : float
            Wait per node [s].

        Returns
        -------
        int
            The combined exit code.
        """
        codes = [p.stop(timeout_s) for p in self.nodes]
        return next((c for c in codes if c != 0), 0)


def start_launch(stub, package: str, file_name: str, args: Sequence[str], log_dir: Path,
                 cwd: Optional[Path] = None):
    """
    Start a launch file as ``ros2 launch PACKAGE FILE ARGS`` does.

    Parameters
    ----------
    stub : module
        ``ros2launch_stub`` (used when the real tool is not installed).
    package, file_name : str
        As typed.
    args : sequence of str
        ``name:=value`` arguments.
    log_dir : pathlib.Path
        For the output.
    cwd : pathlib.Path, optional
        Working directory (the real tool).

    Returns
    -------
    LaunchProcess or StubLaunch
        With ``output()``, ``alive()`` and ``stop()``.
    """
    if real_cli():
        return LaunchProcess([package, file_name, *args], log_dir, cwd=cwd)
    return StubLaunch(stub, stub.find_launch_file(package, file_name), args, log_dir)


def stop_ros2_daemon() -> None:
    """Stop the ``ros2`` daemon that ``ros2 topic`` verbs start (it would outlive the tests)."""
    if real_cli():
        subprocess.run(['ros2', 'daemon', 'stop'], capture_output=True, timeout=scaled(60),
                       env=ros_harness.child_environment(), check=False)
