"""
Host and device over real UDP sockets on loopback: the udp back-end against the emulator.

Run inside a private network namespace (see ``tools/test.sh``); every socket binds 127.0.0.1
on an ephemeral port, every wait is bounded.
"""

import math
import select
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from emfc_ros.core.device import (default_device_config, DeviceEmulator, DeviceRefusedError,
                                  Faults, GeneratorSpec, SimBackend, UdpBackend)
from emfc_ros.core.device import protocol as proto
from emfc_ros.core.device.backend import from_codes, input_scaling, to_codes
from emfc_ros.core.device.errors import DeviceConfigError
from emfc_ros.core.sim.converters import convert_V
from ros_harness import scaled

RATE_HZ = 100000.0
BLOCK = 500                  # 200 frames per second
INPUTS = ('coil_current_A', 'load_changer_current_A', 'sensor_V', 'coil_setpoint_V',
          'load_changer_setpoint_V', 'position_m')
COIL = INPUTS.index('coil_setpoint_V')
SPECS = [GeneratorSpec('chirp', 0.2, 20.0, 2000.0, 0.02, offset_V=0.77),
         GeneratorSpec('prbs', 0.1, prbs_order=7, prbs_hold_samples=25)]
LOCAL = '127.0.0.1'


def _config(**kwargs):
    return default_device_config(RATE_HZ, BLOCK, INPUTS, **kwargs)


@pytest.fixture
def emulators():
    started = []

    def start(**kwargs):
        kwargs.setdefault('max_inputs', len(INPUTS))
        kwargs.setdefault('record', True)
        emu = DeviceEmulator(LOCAL, **kwargs)
        emu.start()
        started.append(emu)
        return emu

    yield start
    for emu in started:
        emu.stop()
        assert emu.error is None, emu.error


@pytest.fixture
def backends():
    made = []

    def make(port, **kwargs):
        backend = UdpBackend((LOCAL, port), **kwargs)
        made.append(backend)
        return backend

    yield make
    for backend in made:
        backend.close()


def _collect(backend, done, timeout_s=scaled(5.0)):
    blocks = []
    deadline = time.monotonic() + timeout_s
    while not done(blocks) and time.monotonic() < deadline:
        block = backend.read_block(0.1)
        if block is not None:
            blocks.append(block)
    return blocks


def _drain(backend, quiet_s=0.3):
    blocks = []
    while True:
        block = backend.read_block(quiet_s)
        if block is None:
            return blocks
        blocks.append(block)


def _check_exact(blocks, sent):
    """Every returned block is one produced frame, sample for sample; indices increase."""
    by_index = {(s.epoch, s.first_sample_index): s for s in sent}
    for block in blocks:
        frame = by_index[(block.epoch, block.first_sample_index)]
        assert np.array_equal(block.samples, frame.values)
    firsts = [b.first_sample_index for b in blocks]
    assert firsts == sorted(set(firsts))


def test_host_receives_exactly_what_the_emulator_sampled(emulators, backends):
    emu = emulators(seed=11)
    backend = backends(emu.port)
    backend.configure(_config(watchdog_timeout_s=2.0))
    backend.set_function_generator(SPECS)
    assert backend.start() == 1
    blocks = _collect(backend, lambda b: len(b) >= 40)
    assert [b.first_sample_index for b in blocks] == [i * BLOCK for i in range(40)]
    _check_exact(blocks, emu.sent)
    health = backend.health()
    for key in ('gaps', 'duplicates', 'reordered', 'corrupt', 'late', 'foreign', 'rejected',
                'reconnects'):
        assert health[key] == 0, key
    assert health['heartbeat_replies'] >= 1
    # the same seed and generator in the in-process sim back-end give the same samples
    sim = SimBackend(seed=11)
    sim.configure(_config())
    sim.set_function_generator(SPECS)
    sim.start()
    for block in blocks[:10]:
        assert np.array_equal(sim.read_block().samples, block.samples)
    status = backend.status()
    assert status.state == proto.STATE_RUNNING and status.config() == _config(
        watchdog_timeout_s=2.0)
    assert status.counters['frames_sent'] >= 40 and status.counters['watchdog_trips'] == 0
    backend.stop()
    assert backend.status().state == proto.STATE_CONFIGURED


def test_injected_drop_duplicate_reorder_corrupt_are_counted_and_no_wrong_sample(
        emulators, backends):
    emu = emulators(seed=3, faults=Faults(drop=0.05, duplicate=0.05, reorder=0.05,
                                          corrupt=0.05))
    backend = backends(emu.port, reorder_timeout_s=0.2)
    backend.configure(_config(watchdog_timeout_s=2.0))
    backend.set_function_generator(SPECS)
    backend.start()
    deadline = time.monotonic() + scaled(10.0)
    while len(emu.sent) < 200 and time.monotonic() < deadline:
        backend.read_block(0.05)                      # keep the queue short while waiting
    backend.stop()
    _drain(backend)
    sent = list(emu.sent)
    # a second pass: the blocks returned while waiting were not kept, so count from health
    health = backend.health()
    fates = [s.fate for s in sent]
    assert len(sent) >= 200
    for fate in ('dropped', 'duplicated', 'reordered', 'corrupted'):
        assert fate in fates, fate
    counters = emu.all_counters()
    assert health['duplicates'] == counters['faults_duplicated'] == fates.count('duplicated')
    assert health['corrupt'] == counters['faults_corrupted'] == fates.count('corrupted')
    assert health['late'] == 0 and health['rejected'] == 0 and health['stale'] == 0
    lost = [s.sequence for s in sent if s.fate in ('dropped', 'corrupted')]
    last = max(s.sequence for s in sent if s.fate not in ('dropped', 'corrupted'))
    assert health['missing_frames'] == len([q for q in lost if q < last])
    assert health['blocks_delivered'] == len(sent) - len(lost)
    assert health['gaps'] >= 1
    # a held-back frame is seen as reordered unless the frame that overtook it was corrupted
    visible = 0
    for i, s in enumerate(sent):
        if s.fate == 'reordered':
            overtaking = ('sent', 'duplicated', 'corrupted')
            after = [t.fate for t in sent[i + 1:] if t.fate in overtaking]
            visible += bool(after) and after[0] != 'corrupted'
    assert health['reordered'] == visible


def test_blocks_returned_under_faults_equal_the_emulator_samples(emulators, backends):
    emu = emulators(seed=4, faults=Faults(drop=0.08, duplicate=0.08, reorder=0.08,
                                          corrupt=0.04, delay_ms=2.0))
    backend = backends(emu.port, reorder_timeout_s=0.2)
    backend.configure(_config(watchdog_timeout_s=2.0))
    backend.set_function_generator(SPECS)
    backend.start()
    blocks = _collect(backend, lambda b: len(b) >= 80)
    backend.stop()
    blocks += _drain(backend)
    assert len(blocks) >= 80
    _check_exact(blocks, emu.sent)
    assert all(b.n_samples == BLOCK for b in blocks)      # never spanning a gap
    assert backend.health()['gaps'] >= 1


SESSION = 0x1234_5678_9ABC_DEF0


class FakeDevice:
    """A plain socket that answers requests like a device and sends hand-made datagrams."""

    def __init__(self):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((LOCAL, 0))
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self.host = None
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        deadline = time.monotonic() + scaled(20.0)
        while not self.stop.is_set() and time.monotonic() < deadline:
            try:
                data, addr = self.sock.recvfrom(65536)
            except socket.timeout:
                continue
            msg = proto.decode_message(data)
            self.host = addr
            body = b''
            session = msg.session
            if msg.type == proto.CONFIGURE:
                (nonce,) = proto.CONFIGURE_NONCE.unpack_from(msg.body)
                body, session = proto.CONFIGURE_RESPONSE.pack(nonce, SESSION), SESSION
            elif msg.type == proto.START:
                body = proto.START_RESPONSE.pack(1, 42)
            elif msg.type == proto.HEARTBEAT:
                body = proto.encode_heartbeat_reply(proto.HeartbeatReply(
                    0, 0, 1, 42, proto.STATE_RUNNING, False, 0, 0))
            self.sock.sendto(proto.encode_message(proto.Message(
                msg.type, msg.request_id, proto.KIND_RESPONSE, proto.OK, body, session)), addr)

    def close(self):
        self.stop.set()
        self.thread.join(2.0)
        self.sock.close()


def test_corrupt_truncated_foreign_and_mismatched_datagrams_never_crash_the_host(backends):
    fake = FakeDevice()
    try:
        backend = backends(fake.port, auto_reconnect=False)
        config = _config()
        backend.configure(config)
        backend.start()
        scale, offset = input_scaling(config)
        codes = to_codes(np.full((len(INPUTS), BLOCK), 0.5), scale, offset)

        def frame(seq, epoch=1, samples=codes, stream=proto.STREAM_MEASUREMENT,
                  session=SESSION):
            return proto.encode_frame(proto.Frame(stream, seq, epoch, seq * BLOCK, samples,
                                                  session))

        good = frame(0)
        bad_crc = bytearray(good)
        bad_crc[-1] ^= 1
        corrupt = (b'', b'garbage', good[:40], good[:-1], bytes(bad_crc), b'EMFC' + good[4:])
        for data in corrupt:
            fake.sock.sendto(data, fake.host)
        fake.sock.sendto(frame(0, samples=codes[:2]), fake.host)   # rejected: channels
        fake.sock.sendto(frame(0, stream=proto.STREAM_SETPOINT), fake.host)   # rejected
        fake.sock.sendto(frame(0, epoch=7), fake.host)             # stale epoch
        fake.sock.sendto(frame(0, session=SESSION + 1), fake.host)  # another session
        fake.sock.sendto(frame(0, session=0), fake.host)           # no session
        # Responses nobody asked for: an unknown request id, a request sent to the host.
        fake.sock.sendto(proto.encode_message(proto.Message(
            proto.STOP, 9999, proto.KIND_RESPONSE, proto.OK, b'', SESSION)), fake.host)
        fake.sock.sendto(proto.encode_message(proto.Message(
            proto.STOP, 9998, proto.KIND_REQUEST, proto.OK, b'', SESSION)), fake.host)
        fake.sock.sendto(good, fake.host)
        intruder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            intruder.bind((LOCAL, 0))
            intruder.sendto(frame(1), fake.host)                   # foreign source port
            intruder.sendto(b'garbage', fake.host)
        finally:
            intruder.close()
        fake.sock.sendto(frame(1), fake.host)
        blocks = _collect(backend, lambda b: len(b) >= 2, timeout_s=scaled(3.0))
        assert [b.first_sample_index for b in blocks] == [0, BLOCK]
        assert np.array_equal(blocks[0].samples, from_codes(codes, scale, offset))
        health = backend.health()
        assert (health['corrupt'], health['rejected'], health['stale'], health['foreign']) == \
            (6, 2, 1, 2)
        assert health['wrong_session'] == 2 and health['unsolicited'] == 2
        assert health['frames_received'] == 2 and health['duplicates'] == 0
    finally:
        fake.close()


class RawClient:
    """A minimal host written against the protocol alone, to drive the device by hand."""

    def __init__(self, port):
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((LOCAL, 0))
        self.device = (LOCAL, port)
        self.rid = 0
        self.session = 0
        self.frames = []

    def _receive(self, timeout_s):
        ready, _, _ = select.select([self.sock], [], [], max(0.0, timeout_s))
        if not ready:
            return None
        data, _ = self.sock.recvfrom(65536)
        if data[:4] == proto.MAGIC_FRAME:
            self.frames.append(proto.decode_frame(data))
            return None
        return proto.decode_message(data)

    def send(self, mtype, body=b'', session=None):
        self.rid += 1
        session = self.session if session is None else session
        self.sock.sendto(proto.encode_message(proto.Message(mtype, self.rid, body=body,
                                                            session=session)), self.device)
        return self.rid

    def answer(self, rid, timeout_s=scaled(2.0)):
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            msg = self._receive(deadline - time.monotonic())
            if msg is not None and msg.request_id == rid:
                return msg
        raise AssertionError(f'no response to request {rid}')

    def request(self, mtype, body=b'', timeout_s=scaled(2.0)):
        msg = self.answer(self.send(mtype, body), timeout_s)
        assert msg.status == proto.OK, msg.error_text()
        return msg

    def configure(self, config):
        msg = self.request(proto.CONFIGURE, proto.encode_configure_request(config, 77))
        nonce, self.session = proto.decode_configure_response(msg.body)
        assert nonce == 77 and msg.session == self.session != 0
        return msg

    def pump(self, duration_s):
        end = time.monotonic() + duration_s
        while time.monotonic() < end:
            self._receive(end - time.monotonic())

    def close(self):
        self.sock.close()


def test_device_watchdog_drives_outputs_safe_within_one_block_when_heartbeats_stop(emulators):
    emu = emulators(seed=2)
    client = RawClient(emu.port)
    try:
        # Heartbeats 30 ms apart keep a 0.5 s watchdog fed (a stall of the test of 0.47 s
        # would trip it early: then the last reply below says so).
        timeout_s = 0.5
        config = _config(watchdog_timeout_s=timeout_s, safe_V=(0.25, 0.0))
        client.configure(config)
        client.request(proto.FUNCGEN, proto.encode_funcgen(
            [GeneratorSpec('constant', offset_V=1.0), GeneratorSpec()]))
        client.request(proto.START)
        for _ in range(8):
            last = proto.decode_heartbeat_reply(client.request(
                proto.HEARTBEAT, proto.HEARTBEAT_REQUEST.pack(0)).body)
            client.pump(0.03)
        assert not last.watchdog_tripped and last.watchdog_trips == 0
        scale, offset = input_scaling(config)
        dac = convert_V(np.array([1.0, 0.25]), 16, 10.0)

        def coil():
            return np.concatenate([f.samples[COIL] for f in client.frames]) * scale[COIL] \
                if client.frames else np.zeros(0)

        # Heartbeats stop: read frames (bounded) until one block after the first safe sample.
        deadline = time.monotonic() + scaled(10.0)
        while time.monotonic() < deadline:
            tripped = np.flatnonzero(coil() == dac[1])
            if tripped.size and coil().size >= tripped[0] + BLOCK:
                break
            client.pump(0.05)
        # The device's record of the heartbeat it last heard, read before the next one.
        heard_s, started_s = emu._last_heard, emu._t0
        assert [f.first_sample_index for f in client.frames] == \
            [i * BLOCK for i in range(len(client.frames))]
        coil = coil()
        tripped = np.flatnonzero(coil == dac[1])
        assert tripped.size and np.all(coil[:tripped[0]] == dac[0])
        assert np.all(coil[tripped[0]:] == dac[1])               # stays safe until START
        # Safe from the device sample at which the watchdog timeout after the last heartbeat
        # ended, on the device's own sample clock (not rounded to a block), whatever the
        # machine's speed: never before the sample the last heartbeat's reply announced
        # plus the timeout.
        device = emu.device.config
        expected = int(math.ceil((heard_s + device.watchdog_timeout_s - started_s)
                                 * device.sample_rate_Hz))
        assert tripped[0] == expected, (tripped[0], expected)
        assert tripped[0] >= last.next_sample_index + int(timeout_s * RATE_HZ) - 1
        reply = proto.decode_heartbeat_reply(client.request(
            proto.HEARTBEAT, proto.HEARTBEAT_REQUEST.pack(0)).body)
        assert reply.watchdog_tripped and reply.watchdog_trips == 1
        assert reply.watchdog_trip_index == tripped[0]
        client.request(proto.START)
        reply = proto.decode_heartbeat_reply(client.request(
            proto.HEARTBEAT, proto.HEARTBEAT_REQUEST.pack(0)).body)
        assert not reply.watchdog_tripped and reply.epoch == 2
    finally:
        client.close()


def test_device_dying_and_coming_back_leads_to_a_reconnect(emulators, backends):
    first = emulators(seed=5)
    backend = backends(first.port, heartbeat_period_s=0.05, request_timeout_s=0.1,
                       device_timeout_s=0.3)
    backend.configure(_config(watchdog_timeout_s=1.0))
    backend.set_function_generator(SPECS)
    assert backend.start() == 1
    assert len(_collect(backend, lambda b: len(b) >= 5)) >= 5
    first.die()
    assert first.dead.wait(2.0)
    time.sleep(0.2)
    _drain(backend, 0.05)
    second = emulators(seed=6, port=first.port)
    blocks = _collect(backend, lambda b: any(x.epoch == 2 for x in b) and len(b) >= 5)
    health = backend.health()
    assert health['reconnects'] == 1 and health['heartbeat_misses'] >= 1
    new = [b for b in blocks if b.epoch == 2]
    assert new and new[0].first_sample_index == 0
    produced = {s.first_sample_index: s.values for s in second.sent}
    assert all(np.array_equal(b.samples, produced[b.first_sample_index]) for b in new)
    assert backend.status().boot_id == second.boot_id != first.boot_id


def test_a_stall_loses_its_samples_and_shows_as_one_gap(emulators, backends):
    emu = emulators(seed=9, faults=Faults(stall_s=0.1, stall_after_s=0.1))
    backend = backends(emu.port)
    backend.configure(_config(watchdog_timeout_s=2.0))
    backend.set_function_generator(SPECS)
    backend.start()
    blocks = _collect(backend, lambda b: b and b[-1].first_sample_index >= 80 * BLOCK)
    stalled = [s.first_sample_index for s in emu.sent if s.fate == 'stalled']
    assert len(stalled) >= 10 and stalled == list(range(stalled[0], stalled[-1] + 1, BLOCK))
    health = backend.health()
    assert (health['gaps'], health['missing_frames'], health['missing_samples']) == \
        (1, len(stalled), len(stalled) * BLOCK)
    assert health['reconnects'] == 0
    _check_exact(blocks, emu.sent)
    firsts = {b.first_sample_index for b in blocks}
    assert firsts.isdisjoint(stalled)


@pytest.mark.parametrize('setpoint_format', ['float64', 'int16'])
def test_streamed_setpoints_are_applied_and_underruns_counted_over_udp(emulators, backends,
                                                                       setpoint_format):
    emu = emulators(seed=8)
    backend = backends(emu.port, setpoint_format=setpoint_format)
    config = _config(watchdog_timeout_s=2.0)
    backend.configure(config)
    backend.start()
    ramp = np.vstack([np.linspace(-1.0, 1.0, 10000), np.linspace(0.3, -0.3, 10000)])
    backend.write_setpoints(2000, ramp)          # float64: 3 frames of at most 4092 samples
    frames = 3 if setpoint_format == 'float64' else 1
    blocks = _collect(backend, lambda b: len(b) >= 30)
    applied = np.hstack([b.samples[[COIL, COIL + 1]] for b in blocks])
    assert np.all(applied[:, :2000] == 0.0)
    assert np.array_equal(applied[:, 2000:12000], convert_V(ramp, 16, 10.0))
    assert np.all(applied[:, 12000:] == 0.0)
    status = backend.status()
    assert status.counters['setpoint_frames_received'] == frames
    assert status.counters['underrun_samples'] >= 30 * BLOCK - 12000
    intruder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        intruder.bind((LOCAL, 0))
        intruder.sendto(proto.encode_frame(proto.Frame(proto.STREAM_SETPOINT, 9, 1, 20000,
                                                       ramp[:, :10])), emu.address)
    finally:
        intruder.close()
    deadline = time.monotonic() + scaled(2.0)
    while backend.status().counters['foreign_datagrams'] < 1 and time.monotonic() < deadline:
        time.sleep(0.02)
    assert backend.status().counters['setpoint_frames_received'] == frames
    with pytest.raises(DeviceRefusedError, match='unknown input'):
        backend.stop()
        backend.configure(default_device_config(RATE_HZ, BLOCK, ('coil_voltage_V',)))


def test_emulator_refuses_a_non_loopback_bind_and_bad_faults():
    with pytest.raises(DeviceConfigError, match='allow_remote'):
        DeviceEmulator('192.0.2.1')
    with pytest.raises(DeviceConfigError):
        Faults.parse('drop=2')
    with pytest.raises(DeviceConfigError):
        Faults.parse('explode=1')
    assert Faults.parse('drop=0.01, delay_ms=5') == Faults(drop=0.01, delay_ms=5.0)


def test_cli_refuses_non_loopback_and_bad_options():
    from emfc_ros.cli.device_emulator import main
    assert main(['--bind', '192.0.2.1']) == 2
    assert main(['--bind', 'example.org']) == 2
    assert main(['--faults', 'drop=x']) == 2
    for mass in ('-1', 'abc', 'nan', '1e300', 'inf'):
        assert main(['--load-mass-kg', mass]) == 2, mass


def test_cli_prints_its_port_serves_and_dies_as_injected(backends):
    proc = subprocess.Popen([sys.executable, '-m', 'emfc_ros.cli.device_emulator', '--port',
                             '0', '--seed', '1', '--faults', 'die_after_s=1.5'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # Generous: a fresh install compiles the simulator kernel (numba) at first use.
        ready, _, _ = select.select([proc.stdout], [], [], 180.0)
        assert ready, 'no port printed'
        port = int(proc.stdout.readline())
        backend = backends(port)
        status = backend.status()
        assert status.state == proto.STATE_IDLE
        assert proc.wait(timeout=scaled(30.0)) == 3
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5.0)
        proc.stdout.close()
        proc.stderr.close()


def test_a_retried_request_is_answered_again_but_not_executed_twice(emulators):
    emu = emulators(seed=12)
    client = RawClient(emu.port)
    try:
        client.configure(_config())
        start = proto.encode_message(proto.Message(proto.START, 500, session=client.session))
        replies = []
        for _ in range(2):
            client.sock.sendto(start, client.device)
            deadline = time.monotonic() + scaled(2.0)
            msg = None
            while msg is None and time.monotonic() < deadline:
                msg = client._receive(deadline - time.monotonic())
            replies.append(msg)
        assert replies[0] == replies[1] and replies[0].request_id == 500
        assert proto.START_RESPONSE.unpack(replies[0].body) == (1, emu.boot_id)
        reply = proto.decode_heartbeat_reply(client.request(
            proto.HEARTBEAT, proto.HEARTBEAT_REQUEST.pack(0)).body)
        assert reply.epoch == 1 and reply.state == proto.STATE_RUNNING
        refused = proto.decode_message(_exchange(client, proto.Message(proto.FUNCGEN, 501, body=(
            proto.encode_funcgen([GeneratorSpec('sine', 1.0, 1e6), GeneratorSpec()])),
            session=client.session)))
        assert refused.status == proto.BAD_REQUEST and 'Nyquist' in refused.error_text()
    finally:
        client.close()


def _exchange(client, message):
    client.sock.sendto(proto.encode_message(message), client.device)
    deadline = time.monotonic() + scaled(2.0)
    while time.monotonic() < deadline:
        ready, _, _ = select.select([client.sock], [], [], deadline - time.monotonic())
        if ready:
            data, _ = client.sock.recvfrom(65536)
            if data[:4] == proto.MAGIC_CONTROL:
                return data
    raise AssertionError('no response')
