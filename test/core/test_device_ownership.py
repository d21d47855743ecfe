"""
Only the owner drives the device; keys, replays and forgeries; a dead device under host stalls.

Real UDP sockets on loopback (run inside a private network namespace, ``tools/test.sh``): the
udp back-end or a hand-written client owns the emulator, an intruder sends from another
socket what it may: requests with and without the owner's session id, heartbeats, setpoint
frames, responses, replays of authenticated datagrams. The owner's stream must go on
unchanged and every refused datagram must be counted where it arrived.
"""

import json
import os
import select
import signal
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from emfc_ros.core.device import (default_device_config, DeviceEmulator, DeviceRefusedError,
                                  DeviceTimeoutError, Faults, GeneratorSpec, UdpBackend)
from emfc_ros.core.device import protocol as proto
from emfc_ros.core.device.auth import KeyFileError, Signer
from emfc_ros.core.device.backend import input_scaling
from emfc_ros.core.sim.converters import convert_V
from ros_harness import scaled

RATE_HZ = 20000.0
BLOCK = 500
INPUTS = ('coil_setpoint_V', 'load_changer_setpoint_V', 'coil_current_A', 'position_m')
LOCAL = '127.0.0.1'
KEY = bytes.fromhex('00112233445566778899aabbccddeeff' * 2)
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _config(**kwargs):
    return default_device_config(RATE_HZ, BLOCK, INPUTS, **kwargs)


class Client:
    """A host written against the protocol alone (optionally with a key)."""

    def __init__(self, port, key=None):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((LOCAL, 0))
        self.device = (LOCAL, port)
        self.key = key
        self.signer = Signer(key) if key else None
        self.rid = 100
        self.session = 0
        self.frames = []
        self.sent = []

    def send(self, mtype, body=b'', session=None):
        self.rid += 1
        data = proto.encode_message(proto.Message(
            mtype, self.rid, body=body, session=self.session if session is None else session),
            self.signer)
        self.sent.append(data)
        self.sock.sendto(data, self.device)
        return self.rid

    def answer(self, rid, timeout_s=scaled(2.0)):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            ready, _, _ = select.select([self.sock], [], [], deadline - time.monotonic())
            if not ready:
                break
            data, _ = self.sock.recvfrom(65536)
            if data[:4] == proto.MAGIC_FRAME:
                self.frames.append(proto.decode_frame(data, self.key))
                continue
            msg = proto.decode_message(data, self.key)
            if msg.request_id == rid:
                return msg
        return None

    def request(self, mtype, body=b'', session=None):
        msg = self.answer(self.send(mtype, body, session))
        assert msg is not None, f'no answer to {proto.MESSAGE_TYPES[mtype]}'
        return msg

    def ok(self, mtype, body=b''):
        msg = self.request(mtype, body)
        assert msg.status == proto.OK, msg.error_text()
        return msg

    def configure(self, config):
        msg = self.ok(proto.CONFIGURE, proto.encode_configure_request(config, 1))
        self.session = proto.decode_configure_response(msg.body)[1]

    def beat(self):
        return self.request(proto.HEARTBEAT, proto.HEARTBEAT_REQUEST.pack(0))

    def pump(self, duration_s):
        self.answer(-1, duration_s)

    def close(self):
        self.sock.close()


@pytest.fixture
def emulator():
    made = []

    def start(**kwargs):
        kwargs.setdefault('max_inputs', len(INPUTS))
        emu = DeviceEmulator(LOCAL, record=True, **kwargs)
        emu.start()
        made.append(emu)
        return emu

    yield start
    for emu in made:
        emu.stop()
        assert emu.error is None, emu.error


def _read(backend, n, timeout_s=scaled(5.0)):
    blocks = []
    deadline = time.monotonic() + timeout_s
    while len(blocks) < n and time.monotonic() < deadline:
        block = backend.read_block(0.1)
        if block is not None:
            blocks.append(block)
    return blocks


def test_only_the_owner_drives_the_device_and_every_forgery_is_counted(emulator):
    emu = emulator(seed=21)
    owner = UdpBackend((LOCAL, emu.port))
    intruder = Client(emu.port)
    try:
        config = _config(watchdog_timeout_s=1.0)
        owner.configure(config)
        owner.set_function_generator([GeneratorSpec('constant', offset_V=0.5), GeneratorSpec()])
        epoch = owner.start()
        assert len(_read(owner, 4)) == 4
        session = owner.session
        assert session == emu.session != 0
        # From another socket: without a session, with a guessed one, with the owner's own.
        refused = []
        for guess in (0, 12345, session):
            intruder.session = guess
            for mtype, body in ((proto.FUNCGEN, proto.encode_funcgen(
                    [GeneratorSpec('constant', offset_V=3.0), GeneratorSpec('constant',
                                                                            offset_V=-4.0)])),
                                (proto.STOP, b''), (proto.START, b''), (proto.RELEASE, b''),
                                (proto.HEARTBEAT, proto.HEARTBEAT_REQUEST.pack(0))):
                refused.append(intruder.request(mtype, body).status)
            msg = intruder.request(proto.CONFIGURE, proto.encode_configure_request(
                _config(), 9))
            refused.append(msg.status)
            assert 'owned by a live session' in msg.error_text()
        assert refused == [proto.NOT_OWNER] * 5 + [proto.BUSY] \
            + [proto.NOT_OWNER] * 5 + [proto.BUSY] + [proto.NOT_OWNER] * 5 + [proto.BUSY]
        # Setpoint frames from the intruder, a response the device never asked for.
        for s in (0, session):
            intruder.sock.sendto(proto.encode_frame(proto.Frame(
                proto.STREAM_SETPOINT, 0, emu.device.epoch, 0, np.full((2, 100), 5.0), s)),
                emu.address)
        intruder.sock.sendto(proto.encode_message(proto.Message(
            proto.STATUS, 1, proto.KIND_RESPONSE, session=session)), emu.address)
        # STATUS answers anyone, and shows what was refused.
        status = proto.decode_status_reply(intruder.request(proto.STATUS, session=0).body)
        assert status.owned and not status.authenticated
        assert status.counters['foreign_requests'] == 18
        assert status.counters['foreign_datagrams'] == 2
        assert status.counters['unsolicited_datagrams'] == 1
        assert status.counters['heartbeats_received'] >= 1     # the owner's only
        # The owner's run went on untouched: same epoch, its generator, no watchdog trip.
        blocks = _read(owner, 10)
        assert len(blocks) == 10 and {b.epoch for b in blocks} == {epoch}
        firsts = [b.first_sample_index for b in blocks]
        assert firsts == list(range(firsts[0], firsts[0] + BLOCK * 10, BLOCK))
        coil = np.concatenate([b.samples[0] for b in blocks])
        assert np.all(coil == convert_V(0.5, 16, 10.0))
        health = owner.health()
        assert health['device_watchdog_tripped'] == 0 and health['reconnects'] == 0
        assert health['sessions_lost'] == 0 and health['device_losses'] == 0
        assert emu.device.state == 'running' and emu.session == session
    finally:
        intruder.close()
        owner.close()
    # RELEASE by the owner: the device is free at once (stopped, no owner).
    assert not emu.owner_alive() and emu.device.state != 'running'


def test_only_the_owners_heartbeats_feed_the_watchdog_and_a_lost_owner_can_be_replaced(
        emulator):
    emu = emulator(seed=22)
    owner, intruder = Client(emu.port), Client(emu.port)
    stop = threading.Event()

    def chatter():
        # The intruder keeps talking the whole time: heartbeats without and with the
        # owner's session, and setpoint frames. None of it may keep the outputs up.
        while not stop.is_set():
            for session in (0, owner.session):
                intruder.send(proto.HEARTBEAT, proto.HEARTBEAT_REQUEST.pack(0), session)
            intruder.sock.sendto(proto.encode_frame(proto.Frame(
                proto.STREAM_SETPOINT, 0, 1, 0, np.ones((2, 10)), owner.session)), emu.address)
            stop.wait(0.01)

    try:
        config = _config(watchdog_timeout_s=0.2, safe_V=(0.25, 0.0))
        owner.configure(config)
        owner.ok(proto.FUNCGEN, proto.encode_funcgen(
            [GeneratorSpec('constant', offset_V=1.0), GeneratorSpec()]))
        owner.ok(proto.START)
        thread = threading.Thread(target=chatter, daemon=True)
        thread.start()
        for _ in range(5):
            owner.beat()
            owner.pump(0.05)
        # The owner falls silent; the intruder does not.
        deadline = time.monotonic() + scaled(5.0)
        while not emu.device.watchdog_tripped and time.monotonic() < deadline:
            time.sleep(0.02)
        assert emu.device.watchdog_tripped
        assert emu.device.state == 'running'          # tripped, not stopped: frames go on
        owner.pump(0.2)
        scale, _ = input_scaling(config)
        coil = np.concatenate([f.samples[0] for f in owner.frames]) * scale[0]
        trip = emu.device.watchdog_trip_index
        index = np.concatenate([np.arange(f.first_sample_index,
                                          f.first_sample_index + f.n_samples)
                                for f in owner.frames])
        assert np.all(coil[index >= trip] == convert_V(0.25, 16, 10.0))
        assert np.all(coil[index < trip] == convert_V(1.0, 16, 10.0))
        counters = emu.all_counters()
        assert counters['foreign_requests'] >= 10 and counters['foreign_datagrams'] >= 5
        # The owner is lost: another host may take the device; its run is stopped first.
        stop.set()
        thread.join(2.0)
        intruder.session = 0
        intruder.configure(_config())
        assert emu.session == intruder.session != owner.session
        assert emu.device.state == 'configured'      # the lost owner's run: stopped
        counters = emu.all_counters()
        assert counters['owner_takeovers'] == 1 and counters['owner_changes'] == 2
        # The old owner is refused from now on (its heartbeat tells it so).
        assert owner.beat().status == proto.NOT_OWNER
    finally:
        stop.set()
        owner.close()
        intruder.close()


def test_a_key_on_both_sides_authenticates_everything_and_anything_else_is_refused(
        emulator, tmp_path):
    emu = emulator(seed=23, key=KEY, faults=Faults(duplicate=0.2))
    key_file = tmp_path / 'device.key'
    key_file.write_text(KEY.hex())
    key_file.chmod(0o600)
    backend = UdpBackend((LOCAL, emu.port), key_file=key_file)
    try:
        backend.configure(_config(watchdog_timeout_s=1.0))
        backend.set_function_generator([GeneratorSpec('sine', 0.5, 50.0), GeneratorSpec()])
        backend.start()
        blocks = _read(backend, 30)
        assert len(blocks) == 30
        produced = {s.first_sample_index: s.values for s in emu.sent}
        assert all(np.array_equal(b.samples, produced[b.first_sample_index]) for b in blocks)
        health = backend.health()
        # A duplicated authenticated frame is a replay: refused as one, never delivered.
        duplicated = emu.all_counters()['faults_duplicated']
        assert duplicated >= 1
        assert health['replayed'] >= 1 and health['duplicates'] == 0
        assert health['authenticated'] == 1 and health['unauthenticated'] == 0
        # A host without the key, or with another one, gets nothing done.
        plain = UdpBackend((LOCAL, emu.port), request_timeout_s=0.05, retries=1)
        with pytest.raises(DeviceRefusedError, match='AUTH_REQUIRED'):
            plain.configure(_config())
        plain.close()
        wrong = UdpBackend((LOCAL, emu.port), key=bytes(32), request_timeout_s=0.05,
                           retries=1)
        with pytest.raises(DeviceTimeoutError, match='AUTH_REQUIRED'):
            wrong.configure(_config())
        assert wrong.health()['unauthenticated'] >= 1
        wrong.close()
        # Forgeries with the owner's session but no valid tag, and a replayed request.
        intruder = Client(emu.port)
        intruder.sock.sendto(proto.encode_frame(proto.Frame(
            proto.STREAM_SETPOINT, 0, 1, 0, np.ones((2, 10)), backend.session)), emu.address)
        intruder.sock.sendto(proto.encode_message(proto.Message(
            proto.STOP, 7, session=backend.session)), emu.address)
        keyed = Client(emu.port, KEY)           # a key holder: its replays are refused
        msg = keyed.request(proto.STATUS, session=0)
        assert msg.status == proto.OK and msg.auth_counter is not None
        keyed.sock.sendto(keyed.sent[-1], emu.address)           # the same bytes again
        assert keyed.answer(keyed.rid, 0.3) is None
        status = backend.status()
        counters = status.counters
        assert status.authenticated
        assert counters['unauthenticated_datagrams'] >= 4         # plain x2, wrong x2, forged
        assert counters['replayed_datagrams'] == 1
        assert emu.device.state == 'running'
        intruder.close()
        keyed.close()
        assert len(_read(backend, 5)) == 5
    finally:
        backend.close()


def test_a_bad_key_file_is_refused_with_the_reason(tmp_path):
    short = tmp_path / 'short.key'
    short.write_text('abcd')
    short.chmod(0o600)
    with pytest.raises(KeyFileError, match='at least 16'):
        UdpBackend((LOCAL, 5005), key_file=short)
    with pytest.raises(KeyFileError, match='cannot be read'):
        UdpBackend((LOCAL, 5005), key_file=tmp_path / 'missing.key')
    from emfc_ros.cli.device_emulator import main
    assert main(['--key-file', str(short)]) == 2


class DoubleAnsweringDevice:
    """Answers every request twice (a late second answer) and adds unsolicited replies."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((LOCAL, 0))
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        session = 77
        while not self.stop.is_set():
            try:
                data, addr = self.sock.recvfrom(65536)
            except socket.timeout:
                continue
            msg = proto.decode_message(data)
            body = b''
            reply_session = msg.session
            if msg.type == proto.CONFIGURE:
                (nonce,) = proto.CONFIGURE_NONCE.unpack_from(msg.body)
                body, reply_session = proto.CONFIGURE_RESPONSE.pack(nonce, session), session
                # A CONFIGURE answer with a wrong nonce first: not ours, refused.
                self.sock.sendto(proto.encode_message(proto.Message(
                    msg.type, msg.request_id, proto.KIND_RESPONSE, proto.OK,
                    proto.CONFIGURE_RESPONSE.pack(nonce ^ 1, session), session)), addr)
            elif msg.type == proto.HEARTBEAT:
                body = proto.encode_heartbeat_reply(proto.HeartbeatReply(
                    0, 0, 0, 42, proto.STATE_CONFIGURED, False, 0, 0))
            reply = proto.encode_message(proto.Message(msg.type, msg.request_id,
                                                       proto.KIND_RESPONSE, proto.OK, body,
                                                       reply_session))
            self.sock.sendto(reply, addr)
            self.sock.sendto(reply, addr)
            self.sock.sendto(proto.encode_message(proto.Message(
                proto.HEARTBEAT, 0xFFFFFF, proto.KIND_RESPONSE, proto.OK,
                body=proto.encode_heartbeat_reply(proto.HeartbeatReply(
                    0, 0, 0, 42, proto.STATE_RUNNING, True, 0, 9, 5)),
                session=session)), addr)

    def close(self):
        self.stop.set()
        self.thread.join(2.0)
        self.sock.close()


def test_late_unsolicited_and_forged_replies_are_counted_not_believed():
    device = DoubleAnsweringDevice()
    backend = UdpBackend((LOCAL, device.port), heartbeat_period_s=0.05)
    try:
        backend.configure(_config())
        assert backend.session == 77
        deadline = time.monotonic() + scaled(5.0)
        while backend.health()['heartbeat_replies'] < 5 and time.monotonic() < deadline:
            time.sleep(0.02)
        health = backend.health()
        assert health['heartbeat_replies'] >= 5
        assert health['wrong_session'] >= 1                 # the CONFIGURE with another nonce
        assert health['late_responses'] >= 5                # every second copy
        assert health['unsolicited'] >= 5                   # heartbeat replies nobody asked
        # ...and the forged "tripped" heartbeat reply was not believed.
        assert health['device_watchdog_tripped'] == 0 and health['device_watchdog_trips'] == 0
    finally:
        backend.close()
        device.close()


CHILD = r"""
import json, sys, time
from emfc_ros.core.device import UdpBackend, default_device_config
backend = UdpBackend(('127.0.0.1', int(sys.argv[1])), auto_reconnect=False)
backend.configure(default_device_config(10000.0, 500, ('coil_setpoint_V',),
                                        watchdog_timeout_s=2.0))
backend.start()
end = time.monotonic() + 120.0
while time.monotonic() < end:
    while backend.read_block(0.0) is not None:
        pass
    h = backend.health()
    print(json.dumps({k: h[k] for k in ('device_losses', 'host_stalls', 'frames_received',
                                        'device_silent_ms')}), flush=True)
    time.sleep(0.05)
"""


def _stall_cycles(proc, lines, cycles, stop_s, run_s, until=None):
    """SIGSTOP the host for stop_s, let it run for run_s; repeat (bounded)."""
    for _ in range(cycles):
        os.kill(proc.pid, signal.SIGSTOP)
        time.sleep(stop_s)
        os.kill(proc.pid, signal.SIGCONT)
        time.sleep(run_s)
        if until is not None and lines and until(lines[-1]):
            return True
    return False


def test_a_dead_device_is_declared_lost_even_when_the_host_stalls_again_and_again(emulator):
    emu = emulator(seed=24, max_inputs=1)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([REPO, os.environ.get('PYTHONPATH', '')]))
    proc = subprocess.Popen([sys.executable, '-c', CHILD, str(emu.port)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines = []

    def pump():
        for line in proc.stdout:
            lines.append(json.loads(line))

    reader = threading.Thread(target=pump, daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + scaled(60.0)
        while not (lines and lines[-1]['frames_received'] > 5) and \
                time.monotonic() < deadline:
            time.sleep(0.05)
        assert lines and lines[-1]['frames_received'] > 5, proc.stderr.read()
        # A live device: the host stalls 0.3 s, runs 0.15 s, again and again. Its own
        # stalls are not the device's silence: never lost.
        _stall_cycles(proc, lines, 8, 0.3, 0.15)
        time.sleep(0.3)
        assert lines[-1]['host_stalls'] >= 4, lines[-1]
        assert lines[-1]['device_losses'] == 0, lines[-1]
        # The device dies; the host keeps stalling (0.3 s stopped, 0.1 s running). The
        # silence is counted across the stalls, so the loss is declared (a rule that
        # restarted the clock after every stall never would).
        emu.die()
        assert emu.dead.wait(5.0)
        found = _stall_cycles(proc, lines, 60, 0.3, 0.1,
                              until=lambda line: line['device_losses'] >= 1)
        assert found, lines[-1]
        assert lines[-1]['device_silent_ms'] > 500
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGCONT)
            proc.kill()
        proc.wait(10)
        reader.join(5)


def test_lost_and_refused_setpoint_frames_are_reported_where_they_began(emulator):
    emu = emulator(seed=25, faults=Faults(setpoint_drop=0.2))
    backend = UdpBackend((LOCAL, emu.port))
    try:
        backend.configure(_config(watchdog_timeout_s=1.0))
        backend.start()
        first = _read(backend, 1)[0]
        # 40 contiguous setpoint frames of 500 samples, well ahead of the device clock.
        start = first.end_index + 4 * BLOCK
        for i in range(40):
            backend.write_setpoints(start + i * BLOCK, np.full((2, BLOCK), 0.5))
        # One frame of the wrong channel count, as the owner: refused by the device.
        backend._send(proto.encode_frame(proto.Frame(
            proto.STREAM_SETPOINT, 999, backend.epoch, start + 100 * BLOCK, np.ones((3, 10)),
            backend.session)))
        deadline = time.monotonic() + scaled(5.0)
        while backend.health()['device_setpoint_frames_rejected'] < 1 and \
                time.monotonic() < deadline:
            backend.read_block(0.1)
        health = backend.health()
        dropped = sorted(emu.dropped_setpoints)
        # Lost frames that a later frame followed are gaps the device filled, from the
        # first one on; the last frames' losses (nothing after them) are underruns instead.
        inner = [d for d in dropped if d < start + 39 * BLOCK]
        assert inner, dropped
        assert health['device_gap_filled_samples'] >= len(inner) * BLOCK
        assert health['device_first_gap_index'] == inner[0]
        assert health['device_setpoint_frames_rejected'] == 1
        assert health['device_first_rejected_index'] == start + 100 * BLOCK
        assert emu.all_counters()['faults_setpoint_dropped'] == len(dropped)
    finally:
        backend.close()
