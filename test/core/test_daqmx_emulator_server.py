"""
The emulated NI-DAQmx device through NI's own client (``nidaqmx`` over gRPC on loopback).

The client code is NI's documented pattern for synchronised analog input and output (AO on
the AI sample clock), not the project's back-end; the server runs in this process on a real
gRPC port of 127.0.0.1.
"""

import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import time

import grpc
import nidaqmx
from nidaqmx.constants import (AcquisitionType, READ_ALL_AVAILABLE, RegenerationMode,
                               WatchdogAOExpirState)
from nidaqmx.system.watchdog import WatchdogTask
from nidaqmx.types import AOExpirationState
import numpy as np
import pytest

from emfc_ros.core.device import daqmx_errors as codes
from emfc_ros.core.device.daqmx_emulator.model import Device
from emfc_ros.core.device.daqmx_emulator.plant import BalancePlant
from emfc_ros.core.device.daqmx_emulator.server import DaqmxServicer, IMPLEMENTED, serve
from emfc_ros.core.device.daqmx_wiring import resolution_V
import readme_lines

RATE = 10000.0
STEP = resolution_V(10.0)


@pytest.fixture(scope='module')
def address():
    plant = BalancePlant(seed=21, simulator_options={'noise': False})
    device = Device(plant, clock=time.monotonic)
    servicer = DaqmxServicer(device)
    server, port = serve(servicer, '127.0.0.1:0')
    yield f'127.0.0.1:{port}', device
    servicer.close()
    server.stop(0).wait(2.0)


def _task(addr, name):
    channel = grpc.insecure_channel(addr, options=[('grpc.enable_http_proxy', 0)])
    return nidaqmx.Task(name, grpc_options=nidaqmx.GrpcSessionOptions(channel, name))


def _sync_tasks(addr, tag, buffer=100000):
    ai = _task(addr, f'ai-{tag}')
    ao = _task(addr, f'ao-{tag}')
    ai.ai_channels.add_ai_voltage_chan('Dev1/ai0:5', min_val=-10.0, max_val=10.0)
    ai.timing.cfg_samp_clk_timing(RATE, sample_mode=AcquisitionType.CONTINUOUS,
                                  samps_per_chan=buffer)
    ao.ao_channels.add_ao_voltage_chan('Dev1/ao0:1', min_val=-10.0, max_val=10.0)
    ao.timing.cfg_samp_clk_timing(RATE, source='/Dev1/ai/SampleClock',
                                  sample_mode=AcquisitionType.CONTINUOUS)
    ao.out_stream.regen_mode = RegenerationMode.DONT_ALLOW_REGENERATION
    return ai, ao


def test_ni_s_synchronised_ai_ao_pattern_measures_sample_k_at_tick_k(address):
    addr, _ = address
    ai, ao = _sync_tasks(addr, 'sync')
    with ai, ao:
        rng = np.random.default_rng(31)
        wave = np.vstack([rng.uniform(-0.5, 0.5, 8000), np.zeros(8000)])
        assert ao.write(wave) == 8000
        ao.start()
        ai.start()
        data = np.array(ai.read(number_of_samples_per_channel=5000, timeout=5.0))
        assert data.shape == (6, 5000)
        assert ai.timing.samp_clk_rate == RATE
        assert ao.timing.samp_clk_src == '/Dev1/ai/SampleClock'
        # ai3 is ao0 looped back: the same tick (a random wave: any lag would show)
        np.testing.assert_allclose(data[3], wave[0, :5000], atol=STEP / 2 + 1e-12)
        errors = [np.max(np.abs(data[3, lag:] - wave[0, :5000 - lag])) for lag in (1, 2)]
        assert min(errors) > 100 * STEP
        # the balance answers on the current monitor (ai0: 100 V/A) and the sensor (ai2)
        assert np.std(data[0]) > 10 * STEP
        assert np.std(data[2]) > 0.0


def test_writing_late_is_ni_s_underflow_error_not_a_repeat(address):
    addr, _ = address
    ai, ao = _sync_tasks(addr, 'under')
    with ai, ao:
        ao.write(np.zeros((2, 500)))
        ao.start()
        ai.start()
        ai.read(number_of_samples_per_channel=1000, timeout=5.0)   # 0.1 s: 500 were written
        with pytest.raises(nidaqmx.DaqError) as err:
            ao.write(np.zeros((2, 100)))
        assert err.value.error_code == codes.GEN_STOPPED_TO_PREVENT_REGEN_OF_OLD_SAMPLES
        assert 'regeneration of old samples' in str(err.value)


def test_reading_late_is_ni_s_overflow_error(address):
    addr, _ = address
    ai, ao = _sync_tasks(addr, 'over', buffer=2000)
    ao.close()
    with ai:
        ai.in_stream.input_buf_size = 2000
        ai.start()
        time.sleep(0.5)         # 5000 samples into a buffer of 2000
        with pytest.raises(nidaqmx.DaqError) as err:
            ai.read(number_of_samples_per_channel=100, timeout=1.0)
        assert err.value.error_code == codes.SAMPLES_NO_LONGER_AVAILABLE


def test_a_read_that_times_out_is_ni_s_timeout_error(address):
    addr, _ = address
    ai, ao = _sync_tasks(addr, 'timeout')
    ao.close()
    with ai:
        ai.start()
        with pytest.raises(nidaqmx.DaqError) as err:
            ai.read(number_of_samples_per_channel=100000, timeout=0.05)
        assert err.value.error_code == codes.SAMPLES_NOT_YET_AVAILABLE


def test_the_watchdog_timer_drives_the_outputs_to_their_expiration_states(address):
    addr, device = address
    channel = grpc.insecure_channel(addr, options=[('grpc.enable_http_proxy', 0)])
    dog = WatchdogTask('Dev1', 'wd', timeout=0.1,
                       grpc_options=nidaqmx.GrpcSessionOptions(channel, 'wd'))
    ai, ao = _sync_tasks(addr, 'dog')
    with dog, ai, ao:
        dog.cfg_watchdog_ao_expir_states([
            AOExpirationState('Dev1/ao0', -2.0, WatchdogAOExpirState.VOLTAGE),
            AOExpirationState('Dev1/ao1', 0.0, WatchdogAOExpirState.VOLTAGE)])
        ao.out_stream.regen_mode = RegenerationMode.ALLOW_REGENERATION
        ao.write(np.vstack([np.full(100, 1.5), np.zeros(100)]))
        dog.start()
        ao.start()
        ai.start()
        for _ in range(3):          # fed: the outputs are the task's
            dog.reset_timer()
            time.sleep(0.03)
        fed = np.array(ai.read(number_of_samples_per_channel=READ_ALL_AVAILABLE))
        assert np.all(np.abs(fed[3] - 1.5) < STEP)
        time.sleep(0.3)             # not fed for 0.3 s > 0.1 s
        late = np.array(ai.read(number_of_samples_per_channel=READ_ALL_AVAILABLE))
        assert np.all(np.abs(late[3, -500:] + 2.0) < STEP)
        with pytest.raises(nidaqmx.DaqError) as err:
            ao.write(np.zeros((2, 10)))
        assert err.value.error_code == codes.WRITE_FAILED_BECAUSE_WATCHDOG_EXPIRED
    assert device.watchdog is None


def test_an_unimplemented_call_is_ni_s_function_not_supported(address):
    addr, _ = address
    with _task(addr, 'thermo') as task:
        with pytest.raises(nidaqmx.DaqError) as err:
            task.ai_channels.add_ai_thrmcpl_chan('Dev1/ai0')
        assert err.value.error_code == codes.FUNCTION_NOT_SUPPORTED_FOR_DEVICE
        assert 'CreateAIThrmcplChan' in str(err.value)
    assert 'CreateAIThrmcplChan' not in IMPLEMENTED
    assert {'ReadAnalogF64', 'WriteAnalogF64', 'CfgSampClkTiming'} <= set(IMPLEMENTED)


def test_the_console_script_serves_the_device_until_sigterm():
    # the README's span as typed, `emfc-daqmx-emulator`, with its defaults (127.0.0.1, a free
    # port), the installed console script
    argv = readme_lines.readme_argv('emfc-daqmx-emulator')
    assert argv == ['emfc-daqmx-emulator']
    script = shutil.which(argv[0]) or str(Path(sys.executable).parent / argv[0])
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    proc = subprocess.Popen([script], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env)
    try:
        port = int(proc.stdout.readline())
        addr = f'127.0.0.1:{port}'
        ai = _task(addr, 'cli-ai')
        with ai:
            ai.ai_channels.add_ai_voltage_chan('Dev1/ai2', min_val=-10.0, max_val=10.0)
            ai.timing.cfg_samp_clk_timing(RATE, sample_mode=AcquisitionType.CONTINUOUS)
            ai.start()
            data = np.array(ai.read(number_of_samples_per_channel=1000, timeout=5.0))
        assert data.shape == (1000,) and np.all(np.isfinite(data))
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(10) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)


def test_the_console_script_refuses_a_non_loopback_address():
    result = subprocess.run([sys.executable, '-m', 'emfc_ros.cli.daqmx_emulator',
                             '--listen', '192.0.2.1:0'], capture_output=True, text=True,
                            timeout=60)
    assert result.returncode == 2
    assert '--allow-remote' in result.stderr or 'loopback' in result.stderr


def test_a_write_that_does_not_fit_the_output_buffer_waits_for_space_or_is_refused(address):
    # NI's semantics with regeneration off: the buffer holds what is written and not yet
    # generated; a write waits up to its timeout for space, then fails with -200292 and
    # writes nothing.
    addr, _ = address
    ai, ao = _sync_tasks(addr, 'space')
    with ai, ao:
        ao.out_stream.output_buf_size = 2000
        rng = np.random.default_rng(5)
        wave = np.vstack([rng.uniform(-0.5, 0.5, 4000), np.zeros(4000)])
        assert ao.write(wave[:, :2000]) == 2000
        assert ao.out_stream.space_avail == 0
        with pytest.raises(nidaqmx.DaqError) as err:      # the task is not running
            ao.write(wave[:, 2000:2001], timeout=0.5)
        assert err.value.error_code == codes.SAMPLES_CAN_NOT_YET_BE_WRITTEN
        ao.start()
        ai.start()
        # 2000 more than the buffer takes now: they go in as the device generates
        assert ao.write(wave[:, 2000:], timeout=5.0) == 2000
        # 0.5 s of samples (more than the whole buffer) in a 0.02 s timeout: refused, with
        # what fitted written
        with pytest.raises(nidaqmx.DaqError) as err:
            ao.write(np.zeros((2, 5000)), timeout=0.02)
        assert err.value.error_code == codes.SAMPLES_CAN_NOT_YET_BE_WRITTEN
        assert 'Samples written:' in str(err.value)
        data = np.array(ai.read(number_of_samples_per_channel=4000, timeout=5.0))
        # every sample written, in order, at its tick (ao0 looped back on ai3)
        np.testing.assert_allclose(data[3], wave[0], atol=STEP / 2 + 1e-12)
