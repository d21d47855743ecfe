"""Tests that need DDS carry the ``ros`` marker, so that ``-m 'not ros'`` runs the rest."""

from pathlib import Path
import subprocess
import sys

import ros_harness

REPO = Path(__file__).resolve().parents[1]


def _collected(*args: str) -> list:
    out = subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider',
                          '--collect-only', *args], capture_output=True, text=True,
                         cwd=REPO, timeout=ros_harness.scaled(120.0))
    return [line for line in out.stdout.splitlines() if '::' in line]


def test_node_tests_are_marked_ros_and_core_tests_are_not():
    files = ('test/nodes/test_daq_bridge_node.py', 'test/core/test_bridge_session.py')
    without = _collected('-m', 'not ros', *files)
    only = _collected('-m', 'ros', *files)
    assert without and all(line.startswith('test/core/') for line in without), without
    assert only and all(line.startswith('test/nodes/') for line in only), only
