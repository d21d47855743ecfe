"""
Ctrl-C ends a node at any moment of its start, with exit code 0.

numba compiles through LLVM callbacks that ctypes runs; a ``KeyboardInterrupt`` raised inside
one is printed as "Exception ignored" and lost. ``run_node`` must not lose the request: these
tests swallow an interrupt the same way (a real SIGINT delivered inside a real ctypes
callback) in the warm-up and in the node's constructor, and start the plant simulator with an
empty numba cache and interrupt it while it compiles.
"""

import os
import select
import signal
import subprocess
import sys
import time

import ros_harness
from ros_harness import scaled

SWALLOW = """
import ctypes, os, signal, sys, time

def swallow_interrupt():
    def callback():
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.2)                 # the handler runs here, inside the callback
    ctypes.CFUNCTYPE(None)(callback)()
"""

WARM_UP = SWALLOW + """
from emfc_ros.nodes.spin import run_node

def factory():
    print('FACTORY CALLED', flush=True)
    raise SystemExit(3)

def warm_up():
    swallow_interrupt()
    print('WARM-UP FINISHED', flush=True)

sys.exit(run_node(factory, [], warm_up=warm_up))
"""

CONSTRUCTOR = SWALLOW + """
from rclpy.node import Node
from std_msgs.msg import String
from emfc_ros.nodes.spin import run_node

class Late(Node):
    def __init__(self):
        super().__init__('late_node')
        swallow_interrupt()             # a compilation under way in the constructor
        print('CONSTRUCTOR GOES ON', flush=True)
        self.create_publisher(String, 'late', 1)
        self.create_timer(0.1, lambda: None)

sys.exit(run_node(Late, []))
"""


def _run(script: str, timeout_s: float = scaled(60.0)) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                          timeout=timeout_s, env=ros_harness.child_environment())


def test_interrupt_swallowed_during_warm_up_ends_before_the_node_exists():
    result = _run(WARM_UP)
    out = result.stdout + result.stderr
    assert 'Exception ignored' in out, out        # the interrupt really was swallowed
    assert 'WARM-UP FINISHED' in out, out
    assert 'FACTORY CALLED' not in out, out
    assert result.returncode == 0, out


def test_interrupt_swallowed_during_construction_ends_cleanly():
    result = _run(CONSTRUCTOR)
    out = result.stdout + result.stderr
    assert 'Exception ignored' in out, out
    assert 'CONSTRUCTOR GOES ON' in out, out
    assert result.returncode == 0, out


def test_plant_simulator_interrupted_while_compiling_exits_zero(tmp_path):
    cache = tmp_path / 'numba'
    env = ros_harness.child_environment({'NUMBA_CACHE_DIR': str(cache)})
    proc = subprocess.Popen([sys.executable, '-m', 'emfc_ros.nodes.plant_simulator',
                             '--ros-args', '-p', 'autostart:=false'], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        # imports done when the warm-up announces itself; then compiling for 12-17 s
        ready, _, _ = select.select([proc.stdout], [], [], 120.0)
        assert ready, 'no output within 120 s'
        first = proc.stdout.readline()
        assert 'preparing the simulator kernel' in first, first
        time.sleep(1.0)
        assert proc.poll() is None
        os.kill(proc.pid, signal.SIGINT)
        out, _ = proc.communicate(timeout=scaled(60.0))
        out = first + out
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=scaled(10.0))
    assert proc.returncode == 0, out
    assert 'Traceback' not in out, out
    # The compilation was cut short, not waited out: nothing was saved to the cache.
    assert not list(cache.rglob('chain_block*.nbi')), out
