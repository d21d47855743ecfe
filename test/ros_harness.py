"""
Test harness for real rclpy nodes over real DDS, kept on this machine.

Every ROS process started here gets ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and the
session's distinct ``ROS_DOMAIN_ID``. Waits are bounded by timeouts and never fixed sleeps;
processes are ended by the id we started them with.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import time
from typing import Any, Callable, Dict, List, Optional, Sequence

#: The one scale of every test timeout: ``EMFC_TEST_TIMEOUT_SCALE`` (default 1), a positive
#: finite factor for slow or loaded machines. Timeouts only bound waits; no test asserts an
#: upper bound on wall-clock time (such figures are measured in ``bench/``).
TIMEOUT_SCALE_VARIABLE = 'EMFC_TEST_TIMEOUT_SCALE'


def _timeout_scale(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float('nan')
    if not math.isfinite(value) or value <= 0.0:
        raise ValueError(f'{TIMEOUT_SCALE_VARIABLE} must be a positive finite number (the '
                         f'factor of every test timeout), got {text!r}')
    return value


TIMEOUT_SCALE = _timeout_scale(os.environ.get(TIMEOUT_SCALE_VARIABLE, '1'))


def scaled(seconds: float) -> float:
    """
    A test timeout on this machine: its scale-1 value times ``EMFC_TEST_TIMEOUT_SCALE``.

    Parameters
    ----------
    seconds : float
        The timeout at scale 1 [s].

    Returns
    -------
    float
        The timeout to wait at most [s].
    """
    return float(seconds) * TIMEOUT_SCALE


DISCOVERY_TIMEOUT_S = scaled(10.0)


def session_domain_id() -> int:
    """
    The ROS domain id of this test session.

    Returns
    -------
    int
        ``ROS_DOMAIN_ID`` when set by the test command, else 100 + pid % 100.
    """
    value = os.environ.get('ROS_DOMAIN_ID', '')
    return int(value) if value.isdigit() else 100 + os.getpid() % 100


#: ``unshare(2)``'s flag for a new network namespace.
CLONE_NEWNET = 0x40000000


def worker_network_namespace() -> Optional[str]:
    """
    Give a pytest-xdist worker a loopback of its own (its own network namespace).

    ``tools/test.sh`` runs the suite in parallel workers inside one private network
    namespace (root only). Each worker then moves itself into a namespace of its own, before
    any thread of DDS starts, with its own domain id, so that the workers' nodes never see
    each other and the documented fixed ports (the device emulators' 5555 and 50051) are free
    in each. Outside a worker, or without that namespace, nothing changes.

    Returns
    -------
    str or None
        What was done (for the report header), None when nothing was.
    """
    worker = os.environ.get('PYTEST_XDIST_WORKER', '')
    if not worker.startswith('gw') or os.environ.get('EMFC_IN_NETNS') != '1' or \
            os.environ.get('EMFC_WORKER_NETNS') == worker:
        return None
    import ctypes
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.unshare(CLONE_NEWNET) != 0:
        raise OSError(ctypes.get_errno(), f'xdist worker {worker}: unshare of the network '
                                          f'namespace failed (tools/test.sh runs as root)')
    subprocess.run(['ip', 'link', 'set', 'lo', 'up'], check=True, timeout=30)
    index = int(worker[2:])
    base = session_domain_id()
    os.environ['ROS_DOMAIN_ID'] = str((base + 1 + index) % 230)
    os.environ['EMFC_WORKER_NETNS'] = worker
    return f'{worker}: own network namespace, ROS_DOMAIN_ID={os.environ["ROS_DOMAIN_ID"]}'


def isolate_environment() -> None:
    """Force loopback-only discovery and the session's domain id for this process."""
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ['ROS_DOMAIN_ID'] = str(session_domain_id())
    os.environ.pop('ROS_STATIC_PEERS', None)


def child_environment(extra: Optional[Dict[str, str]] = None) -> Dict[str, str]:
    """
    The environment for a child ROS process.

    Parameters
    ----------
    extra : dict, optional
        Variables to add or override (discovery settings cannot be overridden).

    Returns
    -------
    dict
        A copy of this process's environment, isolated.
    """
    env = dict(os.environ)
    env.update(extra or {})
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['ROS_DOMAIN_ID'] = str(session_domain_id())
    env.pop('ROS_STATIC_PEERS', None)
    env['PYTHONUNBUFFERED'] = '1'
    # Node wrappers run `python3` from PATH, as in an activated virtual environment.
    env['PATH'] = os.pathsep.join([str(Path(sys.executable).parent), env.get('PATH', '')])
    return env


def wait_until(predicate: Callable[[], bool], timeout_s: float,
               step: Optional[Callable[[], None]] = None, poll_s: float = 0.01) -> bool:
    """
    Call ``step`` (for example an executor's ``spin_once``) until ``predicate`` holds.

    Parameters
    ----------
    predicate : callable
        The condition.
    timeout_s : float
        Upper bound on the wait [s].
    step : callable, optional
        Called between checks; a short sleep when absent.
    poll_s : float
        Sleep between checks when there is no ``step`` [s].

    Returns
    -------
    bool
        Whether the condition held before the timeout.
    """
    deadline = time.monotonic() + timeout_s
    while True:
        if predicate():
            return True
        if time.monotonic() >= deadline:
            return False
        if step is not None:
            step()
        else:
            time.sleep(poll_s)


def spin_until(executor, predicate: Callable[[], bool], timeout_s: float) -> bool:
    """
    Spin an executor until ``predicate`` holds or the timeout passes.

    Parameters
    ----------
    executor : rclpy.executors.Executor
        The executor with the test's nodes.
    predicate : callable
        The condition.
    timeout_s : float
        Upper bound [s].

    Returns
    -------
    bool
        Whether the condition held in time.
    """
    return wait_until(predicate, timeout_s, lambda: executor.spin_once(timeout_sec=0.02))


def call_until_answered(executor, send: Callable[[], Any], timeout_s: float,
                        attempt_s: float = 3.0) -> Optional[Any]:
    """
    Send an idempotent service request again until it is answered or the timeout passes.

    Right after a client sees a server, the server may not yet have matched the client's
    response reader, and the response to a first request is then lost (the future never
    completes: a clean-clone CI run waited 20 s for a parameter client's first answer).

    Parameters
    ----------
    executor : rclpy.executors.Executor
        The executor with the client's node.
    send : callable
        Sends the request, returns its future (e.g. ``client.set_parameters(...)``).
    timeout_s : float
        Upper bound for all attempts [s].
    attempt_s : float
        Wait for one answer before sending again [s].

    Returns
    -------
    rclpy.task.Future or None
        The answered future; None if none was answered in time.
    """
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        future = send()
        if spin_until(executor, future.done, min(attempt_s, deadline - time.monotonic())):
            return future
    return None


class NodeProcess:
    """
    A node (or any command) in a child process, stopped by its own process id.

    Parameters
    ----------
    argv : sequence of str
        The command.
    log_dir : pathlib.Path
        Where stdout and stderr are written.
    env : dict, optional
        Extra environment variables.
    cwd : pathlib.Path, optional
        Working directory.
    new_session : bool
        Start it in a process group of its own (a terminal's job).
    """

    def __init__(self, argv: Sequence[str], log_dir: Path,
                 env: Optional[Dict[str, str]] = None, cwd: Optional[Path] = None,
                 new_session: bool = False) -> None:
        log_dir.mkdir(parents=True, exist_ok=True)
        name = Path(argv[0]).name
        self.stdout_path = log_dir / f'{name}.{time.monotonic_ns()}.out'
        self.stdout = open(self.stdout_path, 'wb')
        self.argv = list(argv)
        self.proc = subprocess.Popen(self.argv, stdout=self.stdout, stderr=subprocess.STDOUT,
                                     env=child_environment(env), cwd=cwd,
                                     start_new_session=new_session)
        self.pid = self.proc.pid
        self.killed = False

    def output(self) -> str:
        """
        What the process has printed so far.

        Returns
        -------
        str
            Its stdout and stderr.
        """
        if not self.stdout.closed:
            self.stdout.flush()
        return self.stdout_path.read_text(errors='replace')

    def alive(self) -> bool:
        """
        Whether the process is still running.

        Returns
        -------
        bool
            True while it runs.
        """
        return self.proc.poll() is None

    def stop(self, timeout_s: float = scaled(10.0)) -> int:
        """
        Interrupt the process (SIGINT), then kill it if it does not end in time.

        Parameters
        ----------
        timeout_s : float
            How long to wait after SIGINT [s].

        Returns
        -------
        int
            Its exit code.
        """
        if self.proc.poll() is None:
            os.kill(self.pid, signal.SIGINT)
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                os.kill(self.pid, signal.SIGKILL)
                self.proc.wait(timeout=timeout_s)
                self.killed = True
        self.stdout.close()
        if self.killed or self.proc.returncode not in (0, -signal.SIGINT):
            clean_shared_memory()
        return self.proc.returncode

    def kill(self) -> None:
        """Kill the process at once (SIGKILL) and clean its shared-memory leftovers."""
        if self.proc.poll() is None:
            os.kill(self.pid, signal.SIGKILL)
            self.proc.wait(timeout=scaled(10))
            self.killed = True
        self.stdout.close()
        clean_shared_memory()


def clean_shared_memory() -> None:
    """Remove Fast DDS shared-memory segments and ports left by dead processes."""
    fastdds = shutil.which('fastdds') or str(Path(sys.executable).parent / 'fastdds')
    if Path(fastdds).exists():
        subprocess.run([fastdds, 'shm', 'clean'], stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL, timeout=scaled(30), check=False)


def node_executable(name: str) -> List[str]:
    """
    The command that runs a node the way ``ros2 run emfc_ros <name>`` does.

    Parameters
    ----------
    name : str
        Executable name, for example ``'signal_generator'``.

    Returns
    -------
    list of str
        ``[<prefix>/lib/emfc_ros/<name>]`` resolved through ``AMENT_PREFIX_PATH``.
    """
    return [str(resolve_ros2run('emfc_ros', name))]


def resolve_ros2run(package: str, executable: str,
                    ament_prefix_path: Optional[str] = None) -> Path:
    """
    Find an executable as ``ros2 run`` does.

    The first prefix in ``AMENT_PREFIX_PATH`` with the marker
    ``share/ament_index/resource_index/packages/<package>`` is the package prefix; the
    executable must be a file with the executable bit in ``<prefix>/lib/<package>``.

    Parameters
    ----------
    package : str
        Package name.
    executable : str
        Executable name.
    ament_prefix_path : str, optional
        The search path; ``AMENT_PREFIX_PATH`` (or the interpreter prefix) when absent.

    Returns
    -------
    pathlib.Path
        The executable.

    Raises
    ------
    LookupError
        If the package or the executable is not found.
    """
    search = ament_prefix_path
    if search is None:
        search = os.environ.get('AMENT_PREFIX_PATH') or sys.prefix
    for prefix in search.split(os.pathsep):
        if not prefix:
            continue
        marker = Path(prefix, 'share', 'ament_index', 'resource_index', 'packages', package)
        if marker.is_file():
            path = Path(prefix, 'lib', package, executable)
            if path.is_file() and os.access(path, os.X_OK):
                return path
            raise LookupError(f'{package} found in {prefix} but {path} is not an '
                              'executable file')
    raise LookupError(f'package {package} not found in AMENT_PREFIX_PATH={search!r}')
