"""
The ``daqmx`` back-end through NI's ``nidaqmx`` client against ``emfc-daqmx-emulator``.

Every test talks gRPC on 127.0.0.1 to the emulator in its own process (as a real NI gRPC
Device Server is), and checks what the device did on its loopback inputs (ao0 on ai3, ao1 on
ai4), read back by the back-end or by a plain NI task.
"""

import os
import signal
import subprocess
import sys
import textwrap
import time

import grpc
import nidaqmx
from nidaqmx.constants import AcquisitionType
import numpy as np
import pytest

from emfc_ros.core.device import daqmx_errors as codes
from emfc_ros.core.device.backend import default_device_config
from emfc_ros.core.device.daqmx_backend import DaqmxBackend
from emfc_ros.core.device.daqmx_wiring import resolution_V
from emfc_ros.core.device.errors import DeviceConfigError, DeviceError
from emfc_ros.core.device.registry import backend_from_mapping

RATE = 10000.0
BLOCK = 1000
STEP = resolution_V(10.0)
SAFE = (0.25, -0.5)
ENV = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')


class Emulator:
    def __init__(self, *args):
        self.proc = subprocess.Popen(
            [sys.executable, '-m', 'emfc_ros.cli.daqmx_emulator', '--seed', '41', *args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV)
        line = self.proc.stdout.readline()
        if not line.strip().isdigit():
            self.close()
            raise RuntimeError(f'emulator did not start: {self.proc.stderr.read()}')
        self.address = f'127.0.0.1:{int(line)}'

    def close(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)


@pytest.fixture
def emulator():
    emu = Emulator()
    yield emu
    emu.close()


def _config(**kwargs):
    return default_device_config(RATE, BLOCK, safe_V=SAFE, **kwargs)


def _started(address, config=None, **options):
    # an output lead of 0.2 s (the default 0.5 s is for a busy ROS host): the tests write
    # their setpoints from sample 3000 on, right after the start
    options.setdefault('output_lead_s', 0.2)
    backend = DaqmxBackend(grpc_address=address, **options)
    backend.configure(config or _config())
    backend.start()
    return backend


def _blocks(backend, n, timeout_s=10.0):
    out = []
    end = time.monotonic() + timeout_s
    while len(out) < n and time.monotonic() < end:
        block = backend.read_block(0.05)
        if block is not None:
            out.append(block)
    assert len(out) == n, f'{len(out)} of {n} blocks in {timeout_s} s'
    return out


def _loopback(address, terminal='ai3', n=200):
    """What an output drives now, read by a plain NI task on its loopback input."""
    channel = grpc.insecure_channel(address, options=[('grpc.enable_http_proxy', 0)])
    name = f'probe-{time.monotonic_ns()}'
    with nidaqmx.Task(name, grpc_options=nidaqmx.GrpcSessionOptions(channel, name)) as task:
        task.ai_channels.add_ai_voltage_chan(f'Dev1/{terminal}', min_val=-10.0, max_val=10.0)
        task.timing.cfg_samp_clk_timing(RATE, sample_mode=AcquisitionType.CONTINUOUS)
        task.start()
        return np.array(task.read(number_of_samples_per_channel=n, timeout=5.0))


def _clear_session(address, name):
    """Attach to a session a dead host left on the server and clear it (as NI's tools do)."""
    channel = grpc.insecure_channel(address, options=[('grpc.enable_http_proxy', 0)])
    options = nidaqmx.GrpcSessionOptions(
        channel, name,
        initialization_behavior=nidaqmx.SessionInitializationBehavior.ATTACH_TO_SERVER_SESSION)
    nidaqmx.Task(name, grpc_options=options).close()


def test_excitation_sample_k_is_measured_at_device_sample_k(emulator):
    backend = _started(emulator.address)
    try:
        rng = np.random.default_rng(42)
        wave = np.vstack([rng.uniform(-1.0, 1.0, 12000), np.linspace(0.0, 1.0, 12000)])
        backend.write_setpoints(3000, wave)     # beyond output_lead_s (0.2 s) after start
        blocks = _blocks(backend, 11)
        assert [b.first_sample_index for b in blocks] == list(range(0, 11000, BLOCK))
        assert {b.epoch for b in blocks} == {backend.epoch}
        data = np.hstack([b.samples for b in blocks])
        rows = list(_config().input_names)
        coil, lc = data[rows.index('coil_setpoint_V')], data[rows.index('load_changer_setpoint_V')]
        np.testing.assert_allclose(coil[:3000], SAFE[0], atol=STEP)       # before the stream
        np.testing.assert_allclose(lc[:3000], SAFE[1], atol=STEP)
        np.testing.assert_allclose(coil[3000:11000], wave[0, :8000], atol=STEP / 2 + 1e-12)
        np.testing.assert_allclose(lc[3000:11000], wave[1, :8000], atol=STEP / 2 + 1e-12)
        lag = np.max(np.abs(coil[3001:11000] - wave[0, :7999]))
        assert lag > 100 * STEP                                           # not one tick off
        # the balance answered: the coil current follows the random setpoints
        current = data[rows.index('coil_current_A')]
        assert np.std(current[3000:11000]) > 100 * STEP * 0.01
        health = backend.health()
        assert health['daqmx_errors'] == 0 and health['device_underrun_samples'] == 0
        assert health['hardware_watchdog'] == 1 and health['watchdog_feeds'] > 0
        assert backend.take_faults() == []
        extra = backend.description_extra()['daqmx']
        assert extra['ao_sample_clock'] == '/Dev1/ai/SampleClock'
        assert extra['connection'] == f'grpc {emulator.address}'
    finally:
        backend.close()


def test_stop_drives_the_outputs_to_their_safe_values(emulator):
    backend = _started(emulator.address)
    try:
        backend.write_setpoints(3000, np.full((2, 30000), 1.5))
        blocks = _blocks(backend, 4)
        assert abs(blocks[-1].samples[3, -1] - 1.5) < STEP
        backend.stop()
        np.testing.assert_allclose(_loopback(emulator.address, 'ai3'), SAFE[0], atol=STEP)
        np.testing.assert_allclose(_loopback(emulator.address, 'ai4'), SAFE[1], atol=STEP)
    finally:
        backend.close()


def test_a_host_stall_is_ni_s_underflow_a_fault_and_the_outputs_go_safe(emulator):
    # a hardware watchdog of 3 s: far longer than the stall plus what a loaded CI host adds
    # before the I/O thread runs again (with 0.5 s it tripped too, once in CI)
    backend = _started(emulator.address, _config(watchdog_timeout_s=3.0))
    try:
        backend.write_setpoints(0, np.full((2, 100000), 2.0))
        _blocks(backend, 2)
        with backend._io:               # the I/O thread stalls (as in a host stall) for
            time.sleep(0.35)            # longer than output_lead_s (0.2 s), far shorter
            #                             than the hardware watchdog (3 s)
        blocks = _blocks(backend, 10)
        faults = backend.take_faults()
        assert [f[0] for f in faults] == ['device_underrun']
        # exact: where the samples written ended (NI's text names the same sample)
        assert faults[0][3] and f'Sample: {faults[0][1]}' in faults[0][2]
        assert f'NI-DAQmx error {codes.GEN_STOPPED_TO_PREVENT_REGEN_OF_OLD_SAMPLES}' in \
            faults[0][2]
        assert 'regeneration of old samples' in faults[0][2]
        # the inputs go on (nothing recorded is lost), and show the outputs driven safe
        assert [b.first_sample_index for b in blocks] == list(range(2000, 12000, BLOCK))
        np.testing.assert_allclose(blocks[-1].samples[3, -100:], SAFE[0], atol=STEP)
        assert backend.health()['last_daqmx_error'] == \
            codes.GEN_STOPPED_TO_PREVENT_REGEN_OF_OLD_SAMPLES
    finally:
        backend.close()


def test_reading_too_late_is_ni_s_overflow_and_the_device_counts_as_lost(emulator):
    backend = _started(emulator.address, input_buffer_s=0.1, output_lead_s=1.0)
    try:
        _blocks(backend, 1)
        with backend._io:               # the I/O thread stalls: 5000 samples into a
            time.sleep(0.5)             # buffer of 1000
        time.sleep(0.2)
        while backend.read_block(0.0) is not None:      # what was complete before
            pass
        assert backend.read_block(0.3) is None
        faults = backend.take_faults()
        assert faults and faults[0][0] == 'device_lost'
        assert f'NI-DAQmx error {codes.SAMPLES_NO_LONGER_AVAILABLE}' in faults[0][2]
        time.sleep(0.6)
        assert backend.health()['device_silent_ms'] > 500
    finally:
        backend.close()


def test_a_removed_device_is_lost_with_ni_s_code():
    emu = Emulator('--remove-after-s', '1.0')
    backend = _started(emu.address)
    try:
        end = time.monotonic() + 10.0
        faults = []
        while not faults and time.monotonic() < end:
            backend.read_block(0.05)
            faults = backend.take_faults()
        assert faults and faults[0][0] == 'device_lost'
        assert f'NI-DAQmx error {codes.DEVICE_REMOVED}' in faults[0][2]
    finally:
        backend.close()
        emu.close()


def test_a_dead_server_is_a_lost_device():
    emu = Emulator()
    backend = _started(emu.address)
    try:
        _blocks(backend, 1)
        emu.proc.kill()
        emu.proc.wait(5)
        end = time.monotonic() + 10.0
        faults = []
        while not faults and time.monotonic() < end:
            backend.read_block(0.05)
            faults = backend.take_faults()
        assert faults and faults[0][0] == 'device_lost'
        assert 'NI-DAQmx client failed' in faults[0][2] or 'NI-DAQmx error' in faults[0][2]
    finally:
        backend.close()
        emu.close()


def test_a_dead_host_leaves_the_outputs_safe_by_the_hardware_watchdog(emulator):
    # the host: the back-end in a process of its own, driving 3 V, then killed
    host = textwrap.dedent(f"""
        import sys, time, numpy as np
        from emfc_ros.core.device.backend import default_device_config
        from emfc_ros.core.device.daqmx_backend import DaqmxBackend
        b = DaqmxBackend(grpc_address={emulator.address!r})
        b.configure(default_device_config({RATE}, {BLOCK}, safe_V={SAFE!r},
                                          watchdog_timeout_s=0.3))
        b.start()
        b.write_setpoints(0, np.full((2, {20 * BLOCK}), 3.0))
        end = time.monotonic() + 60
        while time.monotonic() < end:
            block = b.read_block(0.05)
            if block is None:
                continue
            b.write_setpoints(block.first_sample_index + {20 * BLOCK},
                              np.full((2, {BLOCK}), 3.0))     # as the bridge streams
            if block.first_sample_index >= {7 * BLOCK}:
                print(block.samples[3, -1], flush=True)     # coil_setpoint_V: ao0 looped
    """)
    proc = subprocess.Popen([sys.executable, '-c', host], stdout=subprocess.PIPE, text=True,
                            env=ENV)
    try:
        assert abs(float(proc.stdout.readline()) - 3.0) < STEP     # the host drives 3 V
        proc.kill()                     # no stop, no safe write: only the device acts
        proc.wait(5)
        time.sleep(0.6)                 # > watchdog_timeout_s
        _clear_session(emulator.address, 'emfc-ai')     # the dead host's input task
        np.testing.assert_allclose(_loopback(emulator.address, 'ai3'), SAFE[0], atol=STEP)
        np.testing.assert_allclose(_loopback(emulator.address, 'ai4'), SAFE[1], atol=STEP)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)


def test_configuration_that_disagrees_with_the_device_is_refused(emulator):
    backend = DaqmxBackend(grpc_address=emulator.address)
    try:
        with pytest.raises(DeviceConfigError, match='input_scales'):
            config = _config()
            wrong = config.inputs[0].__class__(config.inputs[0].name, 'A', 1e-6)
            backend.configure(config.__class__(RATE, BLOCK, (wrong, *config.inputs[1:]),
                                               config.outputs))
        with pytest.raises(DeviceConfigError, match='not in the default wiring'):
            backend.configure(_config(inputs=('coil_current_A', 'position_true_m')))
        listed = DaqmxBackend(grpc_address=emulator.address, ai_terminals=('ai0', 'ai2'))
        with pytest.raises(DeviceConfigError, match='ai_terminals: need 6'):
            listed.configure(_config())
        listed.close()
        bad = DaqmxBackend(grpc_address=emulator.address, device='Dev7')
        with pytest.raises(DeviceConfigError, match='NI-DAQmx refused'):
            bad.configure(_config())
        bad.close()
    finally:
        backend.close()
    with pytest.raises(DeviceConfigError, match='output_lead_s'):
        DaqmxBackend(read_period_s=0.05, output_lead_s=0.05)


def test_a_restarted_host_clears_the_sessions_a_dead_one_left(emulator):
    host = DaqmxBackend(grpc_address=emulator.address)
    host.configure(_config())
    host.start()
    _blocks(host, 1)
    host._channel.close()           # the host is gone without closing its sessions
    again = _started(emulator.address)
    try:
        assert again.counters['stale_sessions_cleared'] >= 2
        assert len(_blocks(again, 2)) == 2
    finally:
        again.close()


def test_inputs_in_another_order_follow_the_default_wiring_by_name(emulator):
    names = ('position_m', 'coil_setpoint_V', 'coil_current_A')
    backend = _started(emulator.address, _config(inputs=names))
    try:
        assert backend.ai_terminals == ('ai5', 'ai3', 'ai0')
        backend.write_setpoints(0, np.full((2, 20000), 0.75))
        block = _blocks(backend, 4)[-1]
        np.testing.assert_allclose(block.samples[1], 0.75, atol=STEP)
    finally:
        backend.close()


def test_the_registry_builds_it_from_the_bridge_parameters(emulator):
    backend, config = backend_from_mapping({
        'backend': 'daqmx', 'inputs': ['coil_current_A', 'sensor_V'],
        'daqmx': {'grpc_address': emulator.address, 'ai_terminals': ['ai0', 'ai2'],
                  'ai_units_per_V': [0.01, 1.0], 'ai_range_V': [10.0, 10.0],
                  'watchdog': 'off'}})
    try:
        assert isinstance(backend, DaqmxBackend) and not backend.host_paced
        backend.configure(config)
        backend.start()
        block = _blocks(backend, 1)[0]
        assert block.samples.shape == (2, BLOCK)
        assert backend.health()['hardware_watchdog'] == 0
        assert 'off' in backend.watchdog_note
    finally:
        backend.close()


def test_a_device_whose_watchdog_covers_no_analog_output_runs_without_one_and_says_so():
    # An X Series device's watchdog timer covers its DIO and PFI lines only (NI's X Series
    # user manual, Watchdog Timer): with daqmx.watchdog auto the back-end runs without a
    # hardware watchdog and says why; with on it refuses to start.
    emu = Emulator('--watchdog', 'dio-pfi')
    try:
        backend = _started(emu.address)
        try:
            assert len(_blocks(backend, 2)) == 2
            assert backend.health()['hardware_watchdog'] == 0
            assert backend.health()['watchdog_feeds'] == 0
            assert 'no hardware watchdog on Dev1' in backend.watchdog_note
            assert f'NI-DAQmx error {codes.ATTR_NOT_SUPPORTED}' in backend.watchdog_note
            extra = backend.description_extra()['daqmx']
            assert extra['hardware_watchdog'] is False and 'no hardware watchdog' in \
                extra['watchdog_note']
            assert backend.take_faults() == []
        finally:
            backend.close()
        refused = DaqmxBackend(grpc_address=emu.address, watchdog='on', output_lead_s=0.2,
                               session_prefix='emfc-on')
        try:
            refused.configure(_config())
            with pytest.raises(DeviceError, match='daqmx.watchdog is on'):
                refused.start()
        finally:
            refused.close()
    finally:
        emu.close()


def test_a_server_gone_while_writing_is_a_fault_not_a_dead_thread():
    # The emulator killed between a read and the top-up that follows it (CI saw the I/O
    # thread die there with the client's RpcError and a traceback): the write's error is
    # a latched device_lost naming what failed.
    emu = Emulator()
    backend = _started(emu.address)
    try:
        _blocks(backend, 2)
        with backend._io:
            emu.proc.kill()
            emu.proc.wait(10)
            backend._top_up(backend._read_index + 20000)
        faults = backend.take_faults()
        assert faults and faults[0][0] == 'device_lost', faults
        assert faults[0][2].startswith('writing the outputs: the NI-DAQmx client failed')
        assert backend._ao_failed
    finally:
        backend.close()
        emu.close()
