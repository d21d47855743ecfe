"""The one ``main()`` body every node shares: init, spin, clean shutdown (Jazzy idioms)."""

from __future__ import annotations

import signal
from typing import Callable, List, Optional

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node


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
    try:
        node = factory()
        if rclpy.ok():
            rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        # Ctrl-C during construction: rclpy shut the context down under the constructor,
        # whose next call into rcl fails. Anything else is a genuine error.
        if rclpy.ok():
            raise
    finally:
        # A second Ctrl-C must not cut the cleanup short (the recorder closes its bag here):
        # from now on SIGINT is ignored; the cleanup is short and bounded.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


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
        return run_node(factory, args, warm_up=warm_up)

    main.__doc__ = (f'Run the {name} node until shutdown.{" " + note if note else ""}\n\n'
                    '``args``: command-line arguments (``--ros-args ...``); returns the '
                    'process exit code.')
    return main


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
