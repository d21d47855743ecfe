"""
A device run whose excitation was not applied fails, through the runner, as users run it.

``emfc-experiment`` (a child process) drives the daq_bridge on its udp back-end against the
device emulator in a process of its own (``emfc-device-emulator``), so each side can be
stalled or killed alone:

- the runner stopped (SIGSTOP) for 0.7 s: the device's watchdog (0.5 s) trips and holds the
  outputs at 0 V; the run must exit 1 naming the experiment samples not applied, the bag
  must carry the fault in its custom data, and ``emfc-identify`` must refuse the bag;
- the device killed mid-run: the run must end with the device named lost (within the
  device timeout, not the plan's ``timeout_s``), exit 1. The plan's ``timeout_s``
  (:data:`PLAN_TIMEOUT_S`) is longer than this test's own bounded wait for the run
  (:data:`RUN_TIMEOUT_S`): a runner that waited for the plan's timeout would not have ended
  when the test stops waiting.
"""

import os
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time

import pytest
import yaml

import emfc_ros
from emfc_ros.core.paths import config_file
import ros_harness

RUN_TIMEOUT_S = 240
PLAN_TIMEOUT_S = 600.0
assert RUN_TIMEOUT_S < PLAN_TIMEOUT_S


def _env():
    package_root = str(Path(emfc_ros.__file__).resolve().parents[1])
    return ros_harness.child_environment(
        {'PYTHONPATH': os.pathsep.join(filter(None, [package_root,
                                                     os.environ.get('PYTHONPATH', '')]))})


class _Child:
    """A child process whose output lines are collected by a thread."""

    def __init__(self, args, cwd):
        self.proc = subprocess.Popen([sys.executable, '-m', *args], cwd=cwd, env=_env(),
                                     stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)
        self.out, self.err = [], []
        self._threads = [threading.Thread(target=self._pump, args=(s, lines), daemon=True)
                         for s, lines in ((self.proc.stdout, self.out),
                                          (self.proc.stderr, self.err))]
        for t in self._threads:
            t.start()

    @staticmethod
    def _pump(stream, lines):
        for line in stream:
            lines.append(line)

    def wait_line(self, predicate, timeout_s):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and self.proc.poll() is None:
            if any(predicate(line) for line in list(self.out)):
                return True
            time.sleep(0.02)
        return False

    def finish(self, timeout_s):
        try:
            rc = self.proc.wait(timeout_s)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait(10)
        for t in self._threads:
            t.join(5)
        return rc

    def text(self):
        return ''.join(self.out) + ''.join(self.err)


@pytest.fixture
def emulator(tmp_path):
    child = _Child(['emfc_ros.cli.device_emulator', '--channels', '6', '--seed', '3'],
                   tmp_path)
    try:
        assert child.wait_line(lambda line: line.strip().isdigit(), 30.0), child.text()
        child.port = int(next(line for line in child.out if line.strip().isdigit()))
        yield child
    finally:
        if child.proc.poll() is None:
            child.proc.send_signal(signal.SIGINT)
        child.finish(15)


def _plan(tmp_path: Path, port: int) -> Path:
    doc = yaml.safe_load(config_file('experiment_bridge_emulator.yaml').read_text())
    run = doc['run']
    run['experiment_files'] = [str(config_file('experiment_bridge_emulator.yaml'))]
    run['timeout_s'] = PLAN_TIMEOUT_S
    bridge = run['bridge']
    bridge['parameters_file'] = str(config_file('daq_bridge_udp.yaml'))
    bridge['start_emulator'] = False
    bridge['load_mass_kg'] = 0.0
    bridge['balance_file'] = str(config_file('balance_default.yaml'))
    bridge['parameters']['udp.device_port'] = port
    bridge['parameters']['udp.device_host'] = '127.0.0.1'
    bridge.pop('emulator', None)
    path = tmp_path / 'plan.yaml'
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def _progress_lines(child):
    return [line for line in child.out if '%  section' in line]


def _start_run(tmp_path, emulator):
    plan = _plan(tmp_path, emulator.port)
    run = _Child(['emfc_ros.cli.experiment', str(plan), '-o', str(tmp_path / 'out')],
                 tmp_path)
    # Two progress lines: the experiment has run for a second on the device clock.
    started = run.wait_line(lambda line: len(_progress_lines(run)) >= 2, 120.0)
    assert started, run.text()
    return run


@pytest.mark.slow
def test_a_stalled_host_fails_the_run_and_the_bag_is_refused(tmp_path, emulator):
    run = _start_run(tmp_path, emulator)
    os.kill(run.proc.pid, signal.SIGSTOP)
    try:
        time.sleep(0.7)
    finally:
        os.kill(run.proc.pid, signal.SIGCONT)
    rc = run.finish(RUN_TIMEOUT_S)
    text = run.text()
    assert rc == 1, text
    assert 'did not apply the excitation' in text, text
    assert 'device_watchdog' in text, text
    assert 'experiment samples' in text and 'not applied' in text, text
    assert 'Traceback' not in text, text
    bag = tmp_path / 'out' / 'bag'
    # The bag, read without our code: its metadata carries the fault.
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())
    custom = meta['rosbag2_bagfile_information']['custom_data']
    faults = yaml.safe_load(custom['emfc_ros.faults'])
    kinds = {f['kind'] for f in faults}
    assert 'device_watchdog' in kinds, faults
    trip = next(f for f in faults if f['kind'] == 'device_watchdog')
    assert trip['exact'] is True and trip['device_index'] > 0
    assert all(f['topic'] == '/emfc/measurements/description' for f in faults)
    identify = subprocess.run([sys.executable, '-m', 'emfc_ros.cli.identify', str(bag),
                               '-o', str(tmp_path / 'ident'), '--load-mass-kg', '0'],
                              capture_output=True, text=True, timeout=300, env=_env(),
                              cwd=tmp_path)
    assert identify.returncode == 1, identify.stdout + identify.stderr
    assert 'did not apply the excitation' in identify.stderr, identify.stderr
    assert 'device_watchdog' in identify.stderr


@pytest.mark.slow
def test_a_dead_device_ends_the_run_within_the_device_timeout(tmp_path, emulator):
    run = _start_run(tmp_path, emulator)
    emulator.proc.kill()
    emulator.proc.wait(10)
    rc = run.finish(RUN_TIMEOUT_S)
    text = run.text()
    assert rc == 1, text
    assert 'device_lost' in text and 'no valid datagram from the device' in text, text
    # Ended by the fault, not by the plan's timeout.
    assert 'experiment not finished' not in text, text
    assert 'Traceback' not in text, text
