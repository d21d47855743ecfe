"""
Shared fixtures: an isolated ROS context, executors, node processes and cleanup.

Importing this file forces loopback-only discovery and the session's domain id before
any test imports rclpy.
"""

from pathlib import Path
from typing import Dict

import pytest

import ros_harness

WORKER = ros_harness.worker_network_namespace()
ros_harness.isolate_environment()

#: Folders whose tests start real nodes over real DDS (or ROS command-line tools).
ROS_FOLDERS = ('nodes', 'install')
#: Fixtures that bring up ROS.
ROS_FIXTURES = {'ros_context', 'executor', 'processes'}


def pytest_collection_modifyitems(config, items):
    """
    Mark every test that needs DDS ``ros`` (``-m 'not ros'`` runs the rest, no DDS).

    Then order the files by the time their ``slow`` tests take, longest first (a ``slow``
    test counts its marker's ``seconds``, 5 when not given; stable: the tests of a file keep
    their order, files of equal weight theirs), so that the parallel workers of
    ``tools/test.sh`` (a file each at a time) start the long files first and do not end on
    one of them.
    """
    root = Path(__file__).resolve().parent
    weight: Dict[str, int] = {}
    for item in items:
        try:
            folder = Path(str(item.fspath)).resolve().relative_to(root).parts[0]
        except ValueError:
            folder = ''
        if folder in ROS_FOLDERS or ROS_FIXTURES & set(getattr(item, 'fixturenames', ())):
            item.add_marker(pytest.mark.ros)
        slow = item.get_closest_marker('slow')
        seconds = 0 if slow is None else int(slow.kwargs.get('seconds', 5))
        weight[str(item.fspath)] = weight.get(str(item.fspath), 0) + seconds
    items.sort(key=lambda item: -weight[str(item.fspath)])


@pytest.fixture
def ros_context():
    """An initialised rclpy context of its own, shut down after the test."""
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(context=context, domain_id=ros_harness.session_domain_id())
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


@pytest.fixture
def executor(ros_context):
    """A single-threaded executor on the test's context; its nodes are destroyed after."""
    from rclpy.executors import SingleThreadedExecutor

    ex = SingleThreadedExecutor(context=ros_context)
    yield ex
    for node in list(ex.get_nodes()):
        ex.remove_node(node)
        node.destroy_node()
    ex.shutdown(timeout_sec=1.0)


@pytest.fixture
def processes(tmp_path):
    """Start node processes with ``processes.start(argv)``; all are stopped after the test."""
    started = []

    class Starter:
        def start(self, argv, env=None, cwd=None):
            proc = ros_harness.NodeProcess(argv, Path(tmp_path) / 'logs', env=env, cwd=cwd)
            started.append(proc)
            return proc

    yield Starter()
    for proc in started:
        proc.stop()


def pytest_sessionfinish(session, exitstatus):
    """Clean Fast DDS shared-memory leftovers of any process that died."""
    ros_harness.clean_shared_memory()
