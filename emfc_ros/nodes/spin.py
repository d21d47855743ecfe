"""The one ``main()`` body every node shares: init, spin, clean shutdown (Jazzy idioms)."""

from __future__ import annotations

import faulthandler
import signal
import sys
import time
from typing import Callable, List, Optional

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.logging import get_logger
from rclpy.node import Node

from emfc_ros.nodes.params import help_text, node_table, startup_line

#: Arguments that ask for the node's help (before any ``--ros-args``).
HELP_FLAGS = ('-h', '--help')
#: Node attribute set once :func:`run_node` has left the spin (see :func:`node_logger`).
SHUTTING_DOWN_ATTRIBUTE = '_emfc_shutting_down'


def run_node(factory: Callable[[], Node], args: Optional[List[str]] = None,
             warm_up: Optional[Callable[[], object]] = None) -> int:
    """
    Create a node, spin it until Ctrl-C or shutdown, then destroy it and shut down.

    Ctrl-C is honoured at any time, also while numba compiles a kernel (a first start after
    an install compiles for several seconds): numba's LLVM callbacks swallow the
    ``KeyboardInterrupt`` that Python raises there, so the request is also recorded by a
    handler of our own (during ``warm_up``) or read from the rclpy context, which rclpy's
    handler shuts down (during construction), and the process then ends with code 0.

    Parameters
    ----------
    factory : callable
        Builds the node (called after ``rclpy.init``).
    args : list of str, optional
        Command-line arguments (``--ros-args ...``).
    warm_up : callable, optional
        Called before ``rclpy.init`` (the node is not visible yet): compile the numerical
        kernels here, so that the node appears once it can serve.

    Returns
    -------
    int
        Process exit code (0).
    """
    if warm_up is not None and not _warm_up(warm_up):
        return 0
    rclpy.init(args=args)
    node = None
    why = 'error'
    try:
        node = factory()
        if rclpy.ok():
            node.get_logger().info(startup_line(node, sys.modules.get(factory.__module__)))
            rclpy.spin(node)
        why = 'shutdown requested'
    except (KeyboardInterrupt, ExternalShutdownException):
        why = 'interrupted (Ctrl-C or shutdown request)'
    except Exception:
        # Ctrl-C during construction: rclpy shut the context down under the constructor,
        # whose next call into rcl fails. Ctrl-C during the spin can race the same way: the
        # executor takes a message while rclpy's signal handler shuts the context down, and
        # the take fails with a RuntimeError a moment before rclpy.ok() turns False (seen
        # under load; ros/joint_state_publisher#117 reports the same). Anything else is a
        # genuine error.
        if _context_still_ok(SHUTDOWN_RACE_S):
            raise
        why = 'interrupted (Ctrl-C or shutdown request)' if node is not None else \
            'interrupted during start-up'
    finally:
        # A second Ctrl-C must not cut the cleanup short (the recorder closes its bag here):
        # from now on SIGINT is ignored; the cleanup is short and bounded.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        # rclpy's destroy_node can spin for ever at full CPU, holding the GIL, when Ctrl-C
        # interrupted a callback while it had borrowed a handle (seen once: a generator
        # after a double Ctrl-C, not even SIGTERM ended it). faulthandler's watchdog runs
        # without the GIL: it prints where the process hung and exits with code 1.
        faulthandler.dump_traceback_later(SHUTDOWN_LIMIT_S, exit=True)
        try:
            if node is not None:
                setattr(node, SHUTTING_DOWN_ATTRIBUTE, True)
                node_logger(node).info(f'shutting down: {why}')
                node.destroy_node()
            rclpy.try_shutdown()
        finally:
            faulthandler.cancel_dump_traceback_later()
    return 0


#: Longest shutdown (the recorder closing its bag included) before the process is ended [s].
SHUTDOWN_LIMIT_S = 60.0
#: How long an exception may precede the shutdown that caused it [s] (see run_node).
SHUTDOWN_RACE_S = 0.5


def _context_still_ok(within_s: float) -> bool:
    """Whether the default context is still up ``within_s`` [s] from now (polled)."""
    deadline = time.monotonic() + within_s
    while rclpy.ok():
        if time.monotonic() >= deadline:
            return True
        time.sleep(0.01)
    return False


def node_main(factory: Callable[[], Node], name: str,
              warm_up: Optional[Callable[[], object]] = None,
              note: str = '') -> Callable[[Optional[List[str]]], int]:
    """
    Build a node module's ``main(args=None) -> int`` (its console-script entry point).

    Parameters
    ----------
    factory : callable
        Builds the node (see :func:`run_node`).
    name : str
        Node name, for the docstring.
    warm_up : callable, optional
        See :func:`run_node`.
    note : str, optional
        A sentence added to the docstring.

    Returns
    -------
    callable
        ``main(args)``: run the node until shutdown, return the process exit code.
    """
    def main(args: Optional[List[str]] = None) -> int:
        argv = sys.argv[1:] if args is None else list(args)
        if wants_help(argv):
            tables = node_table(sys.modules.get(factory.__module__))
            sys.stdout.write(help_text(name, tables.doc, tables.table, tables.limits,
                                       tables.read_only, tables.extra, tables.groups))
            return 0
        return run_node(factory, args, warm_up=warm_up)

    main.__doc__ = (f'Run the {name} node until shutdown.{" " + note if note else ""}\n\n'
                    '``args``: command-line arguments (``--ros-args ...``; ``--help``: print '
                    'the parameters and topics, exit 0); returns the process exit code.')
    return main


def node_logger(node: Node):
    """
    The node's logger, or once it shuts down a console-only logger ``<node logger>.shutdown``.

    Once the context is shut down (Ctrl-C), a line through the node's own logger cannot reach
    ``/rosout`` and rcl prints "Failed to publish log message to rosout" for it; the child
    name is not registered with ``/rosout``, so its lines reach the console cleanly. rclpy
    shuts the context down from its signal handler, possibly just after the spin has
    ended: every line from the end of the spin on goes to the console.

    Parameters
    ----------
    node : rclpy.node.Node
        The node.

    Returns
    -------
    rclpy.impl.rcutils_logger.RcutilsLogger
        The logger to use.
    """
    if node.context.ok() and not getattr(node, SHUTTING_DOWN_ATTRIBUTE, False):
        return node.get_logger()
    return get_logger(f'{node.get_logger().name}.shutdown')


def wants_help(argv: List[str]) -> bool:
    """
    Whether the command line asks for the node's help (``-h`` or ``--help`` before ROS's).

    Parameters
    ----------
    argv : list of str
        Command-line arguments without the program name.

    Returns
    -------
    bool
        True for ``-h``/``--help`` before any ``--ros-args`` (``--ros-args --help`` is ROS's).
    """
    ros = argv.index('--ros-args') if '--ros-args' in argv else len(argv)
    return any(a in HELP_FLAGS for a in argv[:ros])


def _warm_up(warm_up: Callable[[], object]) -> bool:
    """Run ``warm_up`` with a SIGINT handler that records the request; False if interrupted."""
    requests = []

    def record(signum, frame):
        requests.append(signum)
        raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, record)
    try:
        warm_up()
    except KeyboardInterrupt:
        return False
    except Exception:
        # An interrupt inside numba's LLVM callback can break the compilation after it (the
        # cache save fails): that is the interrupt, not an error of the warm-up.
        if not requests:
            raise
    finally:
        signal.signal(signal.SIGINT, previous)
    return not requests
