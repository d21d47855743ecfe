"""
The fault matrix of the udp back-end, repeated for ``daqmx``, through the runner as users run it.

``emfc-experiment`` (a child process) drives the daq_bridge on its daqmx back-end, through NI's
``nidaqmx`` client, against ``emfc-daqmx-emulator`` in a process of its own, so each side can
be stalled or killed alone:

- the runner stopped (SIGSTOP) for 0.75 s, longer than the back-end's output lead (0.5 s)
  and shorter than the hardware watchdog (1 s): NI-DAQmx stops the generation rather than
  repeat old samples (-200290); the run exits 1 naming the samples not applied and the
  NI-DAQmx code, and the bag carries the fault;
- the runner stopped for 1.6 s: the device's watchdog timer expires and holds the outputs at
  their safe values (-200678 on the next write); the run fails, ``emfc-identify`` refuses the
  bag;
- the emulator killed mid-run: the device is lost; the run ends by the fault, not by the
  plan's timeout.
"""

import os
import signal
import subprocess
import sys
import time

import pytest
from test_experiment_faults import (_Child, _env, _progress_lines, device_process,
                                    PLAN_TIMEOUT_S, RUN_TIMEOUT_S)
import yaml

from emfc_ros.core.paths import config_file
from ros_harness import scaled


@pytest.fixture
def emulator(tmp_path):
    yield from device_process(tmp_path, ['emfc_ros.cli.daqmx_emulator', '--seed', '3'])


def _start_run(tmp_path, emulator):
    doc = yaml.safe_load(config_file('experiment_daqmx_emulator.yaml').read_text())
    run = doc['run']
    run['experiment_files'] = [str(config_file('experiment_daqmx_emulator.yaml'))]
    run['timeout_s'] = PLAN_TIMEOUT_S
    run['identification'] = {'enabled': False}
    bridge = run['bridge']
    bridge['parameters_file'] = str(config_file('daq_bridge_daqmx.yaml'))
    bridge['start_emulator'] = False
    bridge.pop('emulator', None)
    bridge['load_mass_kg'] = 0.0
    bridge['balance_file'] = str(config_file('balance_default.yaml'))
    bridge['parameters']['daqmx.grpc_address'] = f'127.0.0.1:{emulator.port}'
    bridge['parameters']['diagnostics_period_s'] = 0.2
    plan = tmp_path / 'plan.yaml'
    plan.write_text(yaml.safe_dump(doc, sort_keys=False))
    child = _Child(['emfc_ros.cli.experiment', str(plan), '-o', str(tmp_path / 'out')],
                   tmp_path)
    # Two progress lines: the experiment has run for a second on the device clock.
    assert child.wait_line(lambda line: len(_progress_lines(child)) >= 2, 120.0), \
        child.text()
    return child


def _stall(run, seconds):
    os.kill(run.proc.pid, signal.SIGSTOP)
    try:
        time.sleep(seconds)
    finally:
        os.kill(run.proc.pid, signal.SIGCONT)


def _bag_faults(tmp_path):
    meta = yaml.safe_load((tmp_path / 'out' / 'bag' / 'metadata.yaml').read_text())
    custom = meta['rosbag2_bagfile_information']['custom_data']
    return yaml.safe_load(custom['emfc_ros.faults'])


@pytest.mark.slow
def test_a_short_host_stall_is_ni_s_output_underflow_and_fails_the_run(tmp_path, emulator):
    run = _start_run(tmp_path, emulator)
    _stall(run, 0.75)
    rc = run.finish(RUN_TIMEOUT_S)
    text = run.text()
    assert rc == 1, text
    assert 'did not apply the excitation' in text and 'not applied' in text, text
    assert 'device_underrun' in text and 'NI-DAQmx error -200290' in text, text
    assert 'Traceback' not in text, text
    faults = _bag_faults(tmp_path)
    under = next(f for f in faults if f['kind'] == 'device_underrun')
    assert under['exact'] is True and under['device_index'] > 0, faults
    assert '-200290' in under['message'], faults


@pytest.mark.slow
def test_a_long_host_stall_expires_the_hardware_watchdog_and_the_bag_is_refused(tmp_path,
                                                                                emulator):
    run = _start_run(tmp_path, emulator)
    _stall(run, 1.6)
    rc = run.finish(RUN_TIMEOUT_S)
    text = run.text()
    assert rc == 1, text
    kinds = {f['kind'] for f in _bag_faults(tmp_path)}
    assert 'device_underrun' in kinds or 'device_watchdog' in kinds, kinds
    assert 'NI-DAQmx error' in text, text
    identify = subprocess.run([sys.executable, '-m', 'emfc_ros.cli.identify',
                               str(tmp_path / 'out' / 'bag'), '-o', str(tmp_path / 'ident'),
                               '--load-mass-kg', '0'],
                              capture_output=True, text=True, timeout=scaled(300), env=_env(),
                              cwd=tmp_path)
    assert identify.returncode == 1, identify.stdout + identify.stderr
    assert 'did not apply the excitation' in identify.stderr, identify.stderr


@pytest.mark.slow
def test_a_dead_device_ends_the_run_as_lost(tmp_path, emulator):
    run = _start_run(tmp_path, emulator)
    emulator.proc.kill()
    emulator.proc.wait(10)
    rc = run.finish(RUN_TIMEOUT_S)
    text = run.text()
    assert rc == 1, text
    assert 'device_lost' in text, text
    assert 'experiment not finished' not in text, text
    assert 'Traceback' not in text, text
