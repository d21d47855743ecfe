"""The one ``main()`` body every node shares: init, spin, clean shutdown (Jazzy idioms)."""

from __future__ import annotations

import signal
from typing import Callable, List, Optional

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node


def run_node(factory: Callable[[], Node], args: Optional[List[str]] = None) -> int:
    """
    Create a node, spin it until Ctrl-C or shutdown, then destroy it and shut down.

    Parameters
    ----------
    factory : callable
        Builds the node (called after ``rclpy.init``).
    args : list of str, optional
        Command-line arguments (``--ros-args ...``).

    Returns
    -------
    int
        Process exit code (0).
    """
    rclpy.init(args=args)
    node = None
    try:
        node = factory()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        # A second Ctrl-C must not cut the cleanup short (the recorder closes its bag here):
        # from now on SIGINT is ignored; the cleanup is short and bounded.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
