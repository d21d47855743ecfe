"""The collector settings of a command's own process (emfc_ros.core.heap)."""

import gc
import subprocess
import sys

from emfc_ros.core.heap import CommandHeap
from ros_harness import scaled


def _python(code):
    """Run code in a fresh interpreter (the collector settings are the whole process's)."""
    return subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=scaled(120))


def test_settled_does_nothing_before_start():
    heap = CommandHeap()
    frozen = gc.get_freeze_count()
    heap.settled()
    assert gc.isenabled()
    assert gc.get_freeze_count() == frozen


def test_the_collector_is_off_for_the_imports_and_the_imports_are_frozen():
    code = (
        'import gc\n'
        'from emfc_ros.core.heap import CommandHeap\n'
        'heap = CommandHeap()\n'
        'heap.start()\n'
        'assert not gc.isenabled()\n'
        'import json, xml.dom.minidom\n'
        'before = gc.get_freeze_count()\n'
        'heap.settled()\n'
        'assert gc.isenabled()\n'
        'assert gc.get_freeze_count() > before > -1\n'
        'assert gc.get_count()[0] < 50\n'
        'print("ok", gc.get_freeze_count())\n')
    out = _python(code)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith('ok ')
    assert int(out.stdout.split()[1]) > 10000


def test_the_command_turns_it_off_and_the_library_call_does_not():
    # console_main starts the heap; main() called as a function leaves the collector alone
    code = (
        'import gc, sys\n'
        'import emfc_ros.cli.experiment as ex\n'
        'sys.argv = ["emfc-experiment", "/nonexistent/plan.yaml"]\n'
        'assert ex.main() == 2 and gc.isenabled() and not ex.COMMAND_HEAP.active\n'
        'ex.console_main()\n')
    out = _python(code)
    assert out.returncode == 2, (out.stdout, out.stderr)
