"""
A device run whose excitation was not applied fails, through the runner, as users run it.

``emfc-experiment`` (a child process) drives the daq_bridge on its udp back-end against the
device emulator in a process of its own (``emfc-device-emulator``), so each side can be
stalled or killed alone:

- the runner stopped (SIGSTOP) for 0.7 s: the device's watchdog (0.5 s) trips and holds the
  outputs at 0 V; the run must exit 1 naming the experiment samples not applied, the bag
  must carry the fault in its custom data, and ``emfc-identify`` must refuse the bag;
- the device killed mid-run: the run must end with the device named lost (within the
  device timeout, not the plan's ``timeout_s``), exit 1;
- forged control and data from another UDP socket (and, as root, with the device's or the
  bridge's own source address, as an attacker with raw sockets on a lab link could): FUNCGEN
  to 3 V / -4 V, STOP, START, RELEASE, CONFIGURE, heartbeats, setpoint frames to the device;
  measurement frames and heartbeat replies to the bridge. The run must be unaffected (exit
  0) and every forgery counted on the side it reached (the device's STATUS, the bridge's
  diagnostics in the bag);
- the runner stalled while forged heartbeats keep arriving: they do not feed the device's
  watchdog, which trips; the run fails;
- setpoint frames lost on their way to the device: the device fills the gaps with the safe
  values and says so in its heartbeat; the run fails naming the samples from the first gap
  (the device's own record), and the bag carries the fault. The plan's ``timeout_s``
  (:data:`PLAN_TIMEOUT_S`) is longer than this test's own bounded wait for the run
  (:data:`RUN_TIMEOUT_S`): a runner that waited for the plan's timeout would not have ended
  when the test stops waiting.
"""

import os
from pathlib import Path
import random
import select
import signal
import socket
import struct
import subprocess
import sys
import threading
import time

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
import yaml

import emfc_ros
from emfc_ros.core.device import protocol as proto
from emfc_ros.core.device.backend import default_device_config
from emfc_ros.core.device.function_generator import GeneratorSpec
from emfc_ros.core.paths import config_file
import ros_harness
from ros_harness import scaled

RUN_TIMEOUT_S = scaled(240)
PLAN_TIMEOUT_S = scaled(600.0)
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


def _emulator(tmp_path, *extra):
    yield from device_process(tmp_path, ['emfc_ros.cli.device_emulator', '--channels', '6',
                                         '--seed', '3', *extra])


def device_process(tmp_path, args):
    """A device emulator's module and arguments as a child; its port on ``.port``."""
    child = _Child(args, tmp_path)
    try:
        assert child.wait_line(lambda line: line.strip().isdigit(), 60.0), child.text()
        child.port = int(next(line for line in child.out if line.strip().isdigit()))
        yield child
    finally:
        if child.proc.poll() is None:
            child.proc.send_signal(signal.SIGINT)
        child.finish(15)


@pytest.fixture
def emulator(tmp_path):
    yield from _emulator(tmp_path)


@pytest.fixture
def lossy_emulator(tmp_path):
    """A device that loses a tenth of the setpoint frames on their way in."""
    yield from _emulator(tmp_path, '--faults', 'setpoint_drop=0.1')


def _plan(tmp_path: Path, port: int, bind_port: int = 0, identify: bool = True) -> Path:
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
    bridge['parameters']['udp.bind_port'] = bind_port
    bridge['parameters']['diagnostics_period_s'] = 0.2
    bridge.pop('emulator', None)
    if not identify:            # the run itself is what is tested: the device applied it all
        run['identification'] = {'enabled': False}
    path = tmp_path / 'plan.yaml'
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def _progress_lines(child):
    return [line for line in child.out if '%  section' in line]


def _start_run(tmp_path, emulator, bind_port=0, identify=True):
    plan = _plan(tmp_path, emulator.port, bind_port, identify)
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
                              capture_output=True, text=True, timeout=scaled(300), env=_env(),
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


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        sock.bind(('127.0.0.1', 0))
        return sock.getsockname()[1]


def _can_spoof() -> bool:
    """Raw sockets (root, as tools/test.sh runs the suite in its network namespace)."""
    try:
        socket.socket(socket.AF_INET, socket.SOCK_RAW, socket.IPPROTO_RAW).close()
        return True
    except PermissionError:
        return False


def _spoof(src, dst, payload: bytes) -> None:
    """Send a UDP datagram with a forged source address (raw IPv4, no UDP checksum)."""
    udp = struct.pack('!HHHH', src[1], dst[1], 8 + len(payload), 0) + payload
    ip = struct.pack('!BBHHHBBH4s4s', 0x45, 0, 20 + len(udp), 0, 0, 64, socket.IPPROTO_UDP,
                     0, socket.inet_aton(src[0]), socket.inet_aton(dst[0]))
    with socket.socket(socket.AF_INET, socket.SOCK_RAW, socket.IPPROTO_RAW) as raw:
        raw.sendto(ip + udp, (dst[0], 0))


class Forger:
    """A second UDP socket that sends what an intruder on the machine could."""

    def __init__(self, device, bridge):
        self.device, self.bridge = device, bridge
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(('127.0.0.1', 0))
        self.rid = 5000
        self.guess = random.Random(7).getrandbits(64) | 1

    def message(self, mtype, body=b'', session=0, kind=proto.KIND_REQUEST, rid=None):
        self.rid += 1
        return proto.encode_message(proto.Message(mtype, self.rid if rid is None else rid,
                                                  kind, proto.OK, body, session))

    def requests(self, session):
        """Every request that would change the outputs or the ownership."""
        config = default_device_config(10000.0, 1000, ('coil_setpoint_V',))
        evil = proto.encode_funcgen([GeneratorSpec('constant', offset_V=3.0),
                                     GeneratorSpec('constant', offset_V=-4.0)])
        return [self.message(proto.FUNCGEN, evil, session),
                self.message(proto.STOP, b'', session),
                self.message(proto.START, b'', session),
                self.message(proto.RELEASE, b'', session),
                self.message(proto.HEARTBEAT, proto.HEARTBEAT_REQUEST.pack(0), session),
                self.message(proto.CONFIGURE, proto.encode_configure_request(config, 3),
                             session)]

    def frame(self, stream, channels, session, fmt=np.int16):
        return proto.encode_frame(proto.Frame(stream, 3, 1, 10000,
                                              np.full((channels, 10), 3, dtype=fmt), session))

    def heartbeat_reply(self, session):
        return self.message(proto.HEARTBEAT, proto.encode_heartbeat_reply(proto.HeartbeatReply(
            0, 0, 1, 1, proto.STATE_IDLE, True, 10 ** 6, 9, 0)), session,
            proto.KIND_RESPONSE, rid=1)

    def status(self):
        """The device's STATUS (it answers anyone)."""
        data = self.message(proto.STATUS)
        rid = self.rid
        self.sock.sendto(data, self.device)
        deadline = time.monotonic() + scaled(5.0)
        while time.monotonic() < deadline:
            ready, _, _ = select.select([self.sock], [], [], deadline - time.monotonic())
            if not ready:
                break
            msg = proto.decode_message(self.sock.recvfrom(65536)[0])
            if msg.request_id == rid and msg.type == proto.STATUS:
                return proto.decode_status_reply(msg.body)
        raise AssertionError('the device did not answer STATUS')

    def close(self):
        self.sock.close()


def _bridge_diagnostics(bag: Path):
    """The daq_bridge's last /diagnostics values in the bag (independent mcap reader)."""
    values = {}
    for path in sorted(bag.glob('*.mcap')):
        with open(path, 'rb') as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for _, _, _, msg in reader.iter_decoded_messages(topics=['/diagnostics']):
                for status in msg.status:
                    if status.name.startswith('daq_bridge'):
                        values = {kv.key: kv.value for kv in status.values}
    return values


@pytest.mark.slow
def test_forged_control_and_data_from_another_socket_leave_the_run_unaffected_and_counted(
        tmp_path, emulator):
    bind_port = _free_udp_port()
    device, bridge = ('127.0.0.1', emulator.port), ('127.0.0.1', bind_port)
    forger = Forger(device, bridge)
    try:
        before = forger.status().counters
        run = _start_run(tmp_path, emulator, bind_port, identify=False)
        # To the device, from the second socket: without a session and with a guessed one.
        requests = forger.requests(0) + forger.requests(forger.guess)
        for data in requests:
            forger.sock.sendto(data, device)
        setpoints = [forger.frame(proto.STREAM_SETPOINT, 2, s, np.float64)
                     for s in (0, forger.guess)]
        for data in setpoints:
            forger.sock.sendto(data, device)
        forger.sock.sendto(forger.heartbeat_reply(0), device)       # a response: unsolicited
        # To the bridge, from the second socket: data frames and replies it never asked for.
        to_bridge = [forger.frame(proto.STREAM_MEASUREMENT, 4, s) for s in (0, forger.guess)]
        to_bridge += [forger.heartbeat_reply(0), forger.heartbeat_reply(forger.guess)]
        for data in to_bridge:
            forger.sock.sendto(data, bridge)
        spoofed = 0
        if _can_spoof():
            # As the device (its address and port) to the bridge: another session. As the
            # bridge to the device: requests without the owner's session id.
            for data in (forger.frame(proto.STREAM_MEASUREMENT, 4, forger.guess),
                         forger.frame(proto.STREAM_MEASUREMENT, 4, 0),
                         forger.heartbeat_reply(forger.guess)):
                _spoof(device, bridge, data)
                spoofed += 1
            for data in forger.requests(forger.guess)[:2]:
                _spoof(bridge, device, data)
        rc = run.finish(RUN_TIMEOUT_S)
        text = run.text()
        assert rc == 0, text
        assert 'Traceback' not in text and 'did not apply the excitation' not in text, text
        assert '100.0 %  65000 samples measured' in text, text
        after = forger.status().counters
        delta = {k: after[k] - before[k] for k in after}
        # The device: every request refused and counted, setpoints and the response too.
        assert delta['foreign_requests'] >= len(requests) + (2 if spoofed else 0), delta
        assert delta['foreign_datagrams'] >= len(setpoints), delta
        assert delta['unsolicited_datagrams'] >= 1, delta
        assert delta['owner_changes'] == 1 and delta['owner_takeovers'] == 0, delta
        # The bridge: the second socket's datagrams as foreign, the spoofed ones (and the
        # device's refusals of the requests spoofed as the bridge) as another session.
        diag = _bridge_diagnostics(tmp_path / 'out' / 'bag')
        assert int(diag['foreign']) >= len(to_bridge), diag
        if spoofed:
            assert int(diag['wrong_session']) >= spoofed, diag
        assert int(diag['device_watchdog_trips']) == 0 and int(diag['reconnects']) == 0
    finally:
        forger.close()


@pytest.mark.slow
def test_forged_heartbeats_do_not_keep_the_watchdog_of_a_stalled_host_fed(tmp_path, emulator):
    bind_port = _free_udp_port()
    device, bridge = ('127.0.0.1', emulator.port), ('127.0.0.1', bind_port)
    forger = Forger(device, bridge)
    stop = threading.Event()

    def heartbeats():
        spoof = _can_spoof()
        while not stop.is_set():
            for session in (0, forger.guess):
                beat = forger.message(proto.HEARTBEAT, proto.HEARTBEAT_REQUEST.pack(0),
                                      session)
                forger.sock.sendto(beat, device)
                if spoof:                                   # as the bridge itself
                    _spoof(bridge, device, beat)
            stop.wait(0.02)

    try:
        before = forger.status().counters
        run = _start_run(tmp_path, emulator, bind_port)
        thread = threading.Thread(target=heartbeats, daemon=True)
        thread.start()
        os.kill(run.proc.pid, signal.SIGSTOP)
        try:
            time.sleep(0.7)
        finally:
            os.kill(run.proc.pid, signal.SIGCONT)
        stop.set()
        thread.join(5)
        rc = run.finish(RUN_TIMEOUT_S)
        text = run.text()
        assert rc == 1, text
        assert 'device_watchdog' in text and 'Traceback' not in text, text
        delta = forger.status().counters['foreign_requests'] - before['foreign_requests']
        assert delta >= 20, delta
    finally:
        stop.set()
        forger.close()


@pytest.mark.slow
def test_setpoints_lost_on_the_way_fail_the_run_from_the_devices_record(
        tmp_path, lossy_emulator):
    plan = _plan(tmp_path, lossy_emulator.port, identify=False)
    # The shipped lead (0.1 s, one block) leaves the device at the samples of a block whose
    # last frame was lost about when the next block's first frame arrives: the device may
    # see that as an underrun first (a clean-clone CI run failed so). With a lead of five
    # blocks the frame after a lost one arrives 0.4 s before the device needs the lost
    # samples, so the device records the gap itself, which is what this test checks.
    doc = yaml.safe_load(plan.read_text())
    doc['run']['bridge']['parameters']['excitation_lead_s'] = 0.5
    doc['run']['bridge']['window_blocks'] = 6     # lead + one measured block (plan check)
    doc['run']['bridge']['parameters']['watchdog_timeout_s'] = 2.0   # above lead + window
    plan.write_text(yaml.safe_dump(doc, sort_keys=False))
    run = _Child(['emfc_ros.cli.experiment', str(plan), '-o', str(tmp_path / 'out')],
                 tmp_path)
    rc = run.finish(RUN_TIMEOUT_S)
    text = run.text()
    assert rc == 1, text
    assert 'device_setpoint_gap' in text and 'filled with the safe values' in text, text
    assert 'experiment samples' in text and 'not applied' in text, text
    assert 'Traceback' not in text, text
    meta = yaml.safe_load((tmp_path / 'out' / 'bag' / 'metadata.yaml').read_text())
    faults = yaml.safe_load(meta['rosbag2_bagfile_information']['custom_data'][
        'emfc_ros.faults'])
    gap = next(f for f in faults if f['kind'] == 'device_setpoint_gap')
    assert gap['exact'] is True and gap['device_index'] > 0
