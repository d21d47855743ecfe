"""
The daq_bridge's decisions without ROS: every fault path of a ``BridgeSession``.

A fake host-paced back-end, a recording outputs object and injected clocks
(``bridge_fakes``) make each path deterministic: device blocks are fed by hand, time only
moves when a test moves it, and the session's worker jobs are waited for through the job
queue (they run in order). Times are put half a sample period after a sample boundary so
that every device-index estimate is exact.
"""

import dataclasses
import threading
from typing import Any

from bridge_fakes import BLOCK, Clock, device_block, EPOCH, FakeBackend, RATE, Recorder
import numpy as np
import pytest

from emfc_ros.core.blocks import Block
from emfc_ros.core.device import protocol
from emfc_ros.core.device.backend import default_device_config
from emfc_ros.core.device.bridge_session import BridgeSession, RETRY_PERIOD_S
from emfc_ros.core.device.bridge_settings import BridgeSettings
from emfc_ros.core.device.errors import DeviceError, DeviceRefusedError
from emfc_ros.core.device.function_generator import GeneratorSpec
from emfc_ros.core.device.sim_backend import SimBackend
from emfc_ros.core.model.actuation import coil_setpoint_for_force_V
from emfc_ros.core.model.balance_file import load_balance

LEAD = 100                      # excitation_lead_s 0.01 s at 10 kHz
NS = 100_000                    # ns per sample
T0 = 1_000_000_000_000          # the monotonic clock at the start [ns]
WALL0 = 1_700_000_000_000_000_000
BALANCE = load_balance()
OFF = [GeneratorSpec()] * 2
SAFE = [GeneratorSpec('constant', offset_V=0.0)] * 2


def at(sample: float) -> int:
    """The monotonic time half a sample after device sample ``sample`` (anchor T0) [ns]."""
    return T0 + int(round(sample * NS)) + NS // 2


def ramp(first: int, n: int) -> np.ndarray:
    """Distinct excitation values: sample k is (1 mV * k, -1 mV * k)."""
    row = 1e-3 * np.arange(first, first + n, dtype=float)
    return np.vstack([row, -row])


@dataclasses.dataclass
class Rig:
    session: BridgeSession
    fake: Any
    out: Recorder
    clock: Clock

    def feed(self, first, n=BLOCK, epoch=EPOCH, arrival=None):
        """A device block, arriving half a sample after its last sample (or later)."""
        arrival = max(self.clock.ns, at(first + n) if arrival is None else arrival)
        self.clock.ns = arrival
        self.session.on_device_block(device_block(first, n, epoch), arrival)

    def excite(self, first, n=BLOCK, epoch=1, samples=None):
        samples = ramp(first, n) if samples is None else samples
        self.session.on_excitation(Block(first, RATE, epoch, samples))

    def sync(self):
        """Wait for every device job queued so far."""
        self.session._jobs.submit('sync', lambda: None).result(timeout=10.0)

    def tick_at(self, ns):
        self.clock.ns = ns
        self.session.tick()

    def faults(self):
        return [(f.kind, f.device_index, f.samples, f.exact) for f in self.session.monitor.faults]

    def count(self, key):
        if key == 'faults':
            return self.session.counts['faults']
        return self.session.diagnostic_values()[key]


@pytest.fixture
def make():
    sessions = []

    def build(backend=None, mode='stream', specs=None, start=True, **runtime):
        fake = FakeBackend() if backend is None else backend
        values = {'watchdog_timeout_s': 1.0, 'command_timeout_s': 0.1,
                  'state_rate_Hz': 1000.0, 'excitation_lead_s': 0.01}
        values.update(runtime)
        settings = BridgeSettings(backend=fake, device=default_device_config(RATE, BLOCK),
                                  balance=BALANCE, mode=mode, specs=specs or OFF,
                                  runtime=values, pan={}, resolution={})
        out, clock = Recorder(), Clock(T0)
        session = BridgeSession(settings, out, 'bridge', clock_ns=clock,
                                time_ns=Clock(WALL0))
        sessions.append(session)
        if start:
            ok, message = session.start_now()
            assert ok, message
        return Rig(session, fake, out, clock)

    yield build
    for session in sessions:
        session.close()


def test_start_configures_then_starts_publishes_and_reads_due_blocks(make):
    rig = make()
    s, fake = rig.session, rig.fake
    assert fake.calls == ['configure', 'start'] and fake.config is s.settings.device
    assert s.state == 'running' and s.status_values()['stream_epoch'] == EPOCH
    desc = rig.out.descriptions[-1]
    assert set(desc) == {'measurements'} | {k for k in desc if k.startswith('measurements/')}
    assert len(desc) > 1 and all(d.epoch == EPOCH and d.start_time_ns == WALL0
                                 for d in desc.values())
    assert desc['measurements'].extra['fake_backend'] is True
    for first in (0, 100, 200):
        fake.script(first)
    rig.clock.ns = at(200)
    assert s.poll_host_paced() == 2                       # block 200..300 is not due yet
    assert [b.first_sample_index for b in rig.out.blocks] == [0, 100]
    assert rig.count('published_samples') == 200
    assert rig.out.states[0][0] == WALL0 and len(rig.out.states[0]) == 10


def test_a_refused_start_is_an_error_that_autostart_does_not_retry(make):
    rig = make(start=False)
    rig.fake.start_errors = [DeviceRefusedError(protocol.BAD_REQUEST, 'too many inputs')]
    rig.session.begin(True, 0)
    rig.sync()
    assert rig.session.state == 'error' and 'too many inputs' in rig.session.last_error
    assert 'not retried' in rig.out.logs[-1][1]
    rig.clock.ns = T0 + int(3 * RETRY_PERIOD_S * 1e9)
    rig.session.autostart_tick(0)
    rig.sync()
    assert rig.fake.calls.count('start') == 1 and rig.session.state == 'error'


def test_a_device_error_at_autostart_is_retried_after_the_retry_period(make):
    rig = make(start=False)
    rig.fake.start_errors = [DeviceError('no answer')]
    rig.session.begin(True, 0)
    rig.sync()
    assert rig.session.state == 'error'
    assert rig.session.readiness(1, 'm')[1] == 'refuses: start failed: no answer'
    rig.clock.ns = T0 + int((RETRY_PERIOD_S - 0.1) * 1e9)
    rig.session.autostart_tick(0)
    rig.sync()
    assert rig.fake.calls.count('start') == 1
    rig.clock.ns = T0 + int((RETRY_PERIOD_S + 0.1) * 1e9)
    rig.session.autostart_tick(0)
    rig.sync()
    assert rig.fake.calls.count('start') == 2 and rig.session.state == 'running'


def test_min_subscribers_hold_the_start_until_enough_listeners_matched(make):
    rig = make(start=False)
    rig.session.begin(True, 2)
    rig.session.autostart_tick(1)
    rig.sync()
    assert rig.fake.calls == [] and rig.session.holding and rig.out.opened == 0
    rig.session.autostart_tick(2)
    rig.sync()
    assert rig.fake.calls == ['configure', 'start'] and rig.out.opened == 1


@pytest.mark.parametrize('refused', [False, True])
def test_excitation_while_starting_is_held_for_the_start(make, refused):
    rig = make(start=False)
    rig.fake.gate = threading.Event()
    if refused:
        rig.fake.start_errors = [DeviceRefusedError(protocol.UNSUPPORTED, 'no')]
    rig.session.request_start('~/start')
    assert rig.session.state == 'starting'
    rig.excite(0)
    rig.excite(100)
    rig.fake.gate.set()
    rig.sync()
    s = rig.session
    if refused:                                      # the held blocks are counted
        assert s.state == 'error' and rig.count('excitation_not_running') == 2
        return
    assert s.state == 'running' and s.offset == LEAD and s.queue.queued == 200
    assert rig.faults() == [] and rig.count('excitation_blocks') == 2


def test_excitation_while_idle_or_stopped_is_dropped_and_counted(make):
    rig = make(start=False)
    rig.excite(0)
    assert rig.count('excitation_not_running') == 1
    assert rig.session.readiness(1, 'm') == (False, 'waits for a start (state idle: call '
                                                    '~/start)')
    assert rig.session.start_now()[0]
    rig.session.request_stop()
    rig.sync()
    assert rig.session.state == 'stopped' and rig.fake.calls[-1] == 'stop'
    rig.excite(0)
    assert rig.count('excitation_not_running') == 2 and rig.session.queue.queued == 0


def test_offset_setpoints_and_acknowledgements_follow_the_device(make):
    rig = make()
    rig.feed(0)
    rig.clock.ns = at(150)
    rig.excite(0, 300)
    assert rig.session.offset == 150 + LEAD          # device index now + lead
    assert rig.out.last_extra()['excitation_offset_samples'] == 250
    for first in range(100, 600, 100):
        rig.feed(first)
    firsts = [f for f, _ in rig.fake.setpoints]
    assert firsts == list(range(200, 700, 100))      # [device_end, device_end + lead)
    assert all(v.shape == (2, LEAD) for _, v in rig.fake.setpoints)
    written = np.hstack([v for _, v in rig.fake.setpoints])
    expected = np.zeros((2, 500))
    expected[:, 50:350] = ramp(0, 300)               # device 250..550 = excitation 0..300
    np.testing.assert_array_equal(written, expected)
    assert rig.out.consumed == [50, 150, 250, 300]   # min(device end - offset, received)
    assert rig.count('setpoint_samples_written') == 500 and rig.faults() == []


def test_late_excitation_latches_one_fault_and_counts_the_samples(make):
    rig = make()
    rig.clock.ns = at(150)
    rig.excite(0, 300)
    for first in range(100, 500, 100):
        rig.feed(first)                              # written up to 600
    rig.excite(300)                                  # due at device 550..650
    rig.feed(500)
    first, values = rig.fake.setpoints[-1]
    assert first == 600
    np.testing.assert_array_equal(values[:, :50], ramp(350, 50))
    assert rig.count('excitation_late_samples') == 50
    rig.excite(400)                                  # due at 650..750, written to 700
    rig.feed(600)
    assert rig.count('excitation_late_samples') == 100
    rig.session.tick()
    assert rig.faults() == [('excitation_late', 550, None, True)]
    rig.session.tick()
    assert rig.count('faults') == 1


def test_a_fault_the_back_end_reports_latches_once_with_its_message(make):
    rig = make()
    rig.feed(0)
    text = 'writing the outputs: NI-DAQmx error -200290: The generation has stopped'
    rig.fake.reported = [('device_underrun', 120, text, False)]
    rig.session.tick()
    assert rig.faults() == [('device_underrun', 120, None, False)]
    assert rig.session.monitor.faults[0].message == text
    rig.fake.reported = [('device_underrun', 300, text, False)]     # the same kind again
    rig.session.tick()
    assert rig.count('faults') == 1


def test_a_stream_taken_after_its_sample_0_is_excitation_start_missing(make):
    rig = make()
    rig.clock.ns = at(150)
    rig.excite(500)
    assert rig.session.offset == 250 - 500
    assert rig.faults() == [('excitation_start_missing', -250, 500, True)]
    assert rig.out.diagnostics == 1
    assert rig.out.last_extra()['faults'][0]['samples'] == 500


@pytest.mark.parametrize('health, fault', [
    ({'device_underrun_samples': 40}, ('device_underrun', 960, 40, False)),
    ({'device_watchdog_tripped': 1, 'device_watchdog_trip_index': 1234},
     ('device_watchdog', 1234, None, True)),
    ({'device_watchdog_tripped': 1}, ('device_watchdog', 1000, None, False)),
    ({'device_gap_filled_samples': 5, 'device_first_gap_index': 300},
     ('device_setpoint_gap', 300, None, True)),
    ({'device_setpoint_frames_rejected': 2, 'device_first_rejected_index': 400},
     ('device_setpoint_rejected', 400, None, True)),
    ({'device_silent_ms': 600}, ('device_lost', 300, None, False)),
    ({'device_silent_ms': 400}, None),
    ({'sessions_lost': 1}, ('device_lost', 300, None, False)),
    ({'reconnects': 1}, ('device_lost', 300, None, False)),
    ({'device_losses': 1}, ('device_lost', 300, None, False)),
])
def test_device_health_counters_become_latched_faults(make, health, fault):
    rig = make()
    for first in (0, 100, 200):
        rig.feed(first)
    rig.fake.health_values = health
    rig.tick_at(at(1000))
    rig.tick_at(at(1100))
    assert rig.faults() == ([] if fault is None else [fault])
    assert rig.count('faults') == (0 if fault is None else 1)
    assert rig.out.diagnostics == (0 if fault is None else 1)


def test_device_underrun_counts_from_the_start_baseline_and_grows(make):
    fake = FakeBackend()
    fake.health_values = {'device_underrun_samples': 10}  # an earlier run's
    rig = make(backend=fake)
    rig.tick_at(at(1000))
    assert rig.faults() == []
    fake.health_values = {'device_underrun_samples': 50}
    rig.tick_at(at(1000))
    assert rig.faults() == [('device_underrun', 960, 40, False)]
    fake.health_values = {'device_underrun_samples': 70}
    rig.tick_at(at(2000))
    assert rig.faults() == [('device_underrun', 1940, 60, False)]
    assert rig.count('faults') == 1


def test_a_grown_underrun_reaches_the_description_once_a_second(make):
    rig = make()
    rig.fake.health_values = {'device_underrun_samples': 40}
    rig.tick_at(at(1000))
    assert rig.out.last_extra()['faults'][0]['samples'] == 40
    rig.fake.health_values = {'device_underrun_samples': 60}
    rig.tick_at(at(2000))                            # 0.1 s after the latch: not yet
    assert rig.out.last_extra()['faults'][0]['samples'] == 40
    rig.tick_at(at(11000))                           # 1.0 s after it
    assert rig.out.last_extra()['faults'][0]['samples'] == 60


def test_the_watchdog_counts_from_the_played_stream_and_trips_without_a_fault(make):
    rig = make()
    rig.clock.ns = at(150)
    rig.excite(0)                                    # device 250..350, written by block 300
    rig.feed(100)
    rig.feed(200)
    assert rig.session.queue.queued == 0
    rig.tick_at(at(10200))                           # 1.0 s after arrival, 0.985 s after play
    assert not rig.session.tripped
    rig.tick_at(at(10400))
    s = rig.session
    assert s.tripped and rig.count('watchdog_trips') == 1
    assert rig.count('watchdog_trip_device_index') == 10400 and rig.faults() == []
    rig.sync()
    assert rig.fake.generators == [SAFE] and s.counts['safe_outputs_confirmed'] == 1
    rig.feed(300)
    assert rig.fake.setpoints[-1][0] == 400
    assert not rig.fake.setpoints[-1][1].any()       # safe setpoints go on
    assert s.diagnostic_status()[:2] == (1, 'excitation watchdog tripped: outputs safe')


@pytest.mark.parametrize('first, epoch, faults', [
    (1000, 1, [('excitation_watchdog', 250, 1000, False),
               ('excitation_watchdog', 15150, None, False)]),
    (0, 2, [('excitation_watchdog', 250, 1000, False)]),
])
def test_a_trip_with_queued_excitation_is_a_fault_and_new_excitation_restores(
        make, first, epoch, faults):
    rig = make()
    rig.clock.ns = at(150)
    rig.excite(0, 1000)
    rig.tick_at(at(15150))                           # 1.5 s later: nothing written
    assert rig.faults() == faults[:1] and rig.count('watchdog_trip_device_index') == 15150
    rig.excite(first, epoch=epoch)                   # the same stream goes on, or a new one
    assert not rig.session.tripped and rig.faults() == faults
    assert rig.session.offset == 15150 + LEAD - first
    rig.sync()
    assert rig.fake.generators == [SAFE, OFF]


def test_emergency_stop_drops_excitation_and_reset_restores_the_generator(make):
    rig = make()
    s = rig.session
    rig.clock.ns = at(150)
    rig.excite(0, 300)
    rig.feed(100)
    s.emergency_stop()
    assert s.estop and rig.count('emergency_stop_device_index') == 200
    assert rig.faults() == [('emergency_stop', 200, None, False)]
    assert s.queue.queued == 0 and s.offset is None
    rig.excite(300)
    assert rig.count('excitation_dropped_estop') == 1 and s.queue.queued == 0
    rig.feed(200)
    assert rig.fake.setpoints[-1][0] == 300 and not rig.fake.setpoints[-1][1].any()
    rig.sync()
    assert rig.fake.generators == [SAFE] and s.counts['safe_outputs_confirmed'] == 1
    assert s.diagnostic_status()[0] == 2
    s.reset()
    rig.sync()
    assert not s.estop and rig.faults() == [] and rig.fake.generators == [SAFE, OFF]
    assert rig.out.last_extra()['faults'] == []
    rig.feed(300)
    rig.excite(400)                                  # accepted again, a new offset
    assert s.offset == 400 + LEAD - 400 and s.queue.queued == 100


def test_refused_safe_outputs_latch_a_fault_on_the_next_tick_and_stop(make):
    rig = make()
    rig.fake.generator_error = DeviceRefusedError(protocol.BUSY, 'busy')
    rig.feed(0)
    rig.session.emergency_stop()
    rig.sync()
    assert rig.fake.generators == [SAFE] and rig.session.state == 'running'
    rig.tick_at(at(300))
    assert rig.faults() == [('emergency_stop', 100, None, False),
                            ('safe_outputs_unconfirmed', 300, None, False)]
    assert 'did not confirm the safe outputs' in rig.session.last_error
    rig.sync()
    assert rig.session.state == 'stopped' and rig.fake.calls[-1] == 'stop'


def test_a_refused_restore_at_reset_is_generator_unconfirmed(make):
    rig = make()
    rig.session.emergency_stop()
    rig.sync()
    rig.fake.generator_error = DeviceError('no answer')
    rig.clock.ns = at(400)
    rig.session.reset()
    rig.sync()
    assert rig.faults() == []
    rig.tick_at(at(500))
    assert rig.faults() == [('generator_unconfirmed', 400, None, False)]   # when refused


def test_a_refused_generator_change_is_generator_unconfirmed(make):
    sine = GeneratorSpec('sine', amplitude_V=1.0, frequency_Hz=10.0)
    rig = make(mode='function_generator')
    assert rig.fake.calls == ['configure', 'set_function_generator', 'start']
    rig.fake.generator_error = DeviceRefusedError(protocol.BAD_REQUEST, 'no')
    rig.clock.ns = at(700)
    rig.session.set_generator([sine, GeneratorSpec()])
    rig.sync()
    assert rig.fake.generators == [OFF, [sine, GeneratorSpec()]] and rig.faults() == []
    rig.tick_at(at(900))
    assert rig.faults() == [('generator_unconfirmed', 700, None, False)]


def test_an_emergency_stop_before_the_start_starts_with_safe_outputs(make):
    rig = make(start=False)
    rig.session.emergency_stop()
    rig.sync()
    assert rig.fake.generators == [] and rig.faults() == []
    assert rig.session.start_now()[0]
    assert rig.fake.calls == ['configure', 'set_function_generator', 'start']
    assert rig.fake.generators == [SAFE]
    assert rig.faults() == [('emergency_stop', 0, None, False)]
    assert [f['kind'] for f in rig.out.last_extra()['faults']] == ['emergency_stop']


def epoch_change(rig):
    """A mapped stream, then the device restarts (epoch 8) at arrival T0 + 100 ms."""
    rig.clock.ns = at(150)
    rig.excite(0, 300)
    rig.feed(100)
    rig.feed(200)
    n_desc = len(rig.out.descriptions)
    rig.feed(0, epoch=8, arrival=T0 + 100_000_000)
    assert rig.out.descriptions[n_desc]['measurements'].epoch == 8
    rig.clock.ns = T0 + 100_000_000 + NS // 2        # device sample 100 of epoch 8
    rig.excite(300)


def test_an_epoch_change_remaps_the_excitation(make):
    rig = make()
    epoch_change(rig)
    s = rig.session
    assert rig.count('epoch_changes') == 1 and s.epoch == 8
    assert s.offset == 100 + LEAD - 300
    assert rig.out.last_extra()['excitation_offset_samples'] == -100
    assert rig.faults() == [('excitation_start_missing', -100, 300, True)]
    rig.feed(100, epoch=8)
    first, values = rig.fake.setpoints[-1]
    assert first == 200
    np.testing.assert_array_equal(values, ramp(300, 100))


def test_a_fault_after_an_epoch_change_carries_the_new_epoch(make):
    rig = make()
    epoch_change(rig)
    assert rig.session.monitor.faults[0].epoch == 8


def test_refused_device_blocks_are_counted_and_not_published(make):
    rig = make()
    rig.session.on_device_block(device_block(0, rows=5), at(100))
    rig.session.on_device_block(device_block(0, n=0), at(100))
    assert rig.count('malformed_blocks') == 2 and rig.out.blocks == []
    for first in (0, 100, 50, 300):
        rig.feed(first)
    assert [b.first_sample_index for b in rig.out.blocks] == [0, 100, 300]
    assert rig.count('dropped_out_of_order_blocks') == 1
    assert rig.count('published_gaps') == 1 and rig.count('published_missing_samples') == 100
    assert rig.session.diagnostic_status()[0] == 1


def test_malformed_excitation_is_counted_and_the_session_runs(make):
    rig = make()
    good = ramp(0, BLOCK)
    nan = good.copy()
    nan[1, 3] = np.nan
    rig.session.on_excitation(Block(0, 5000.0, 1, good))
    rig.session.on_excitation(Block(0, RATE, 1, nan))
    assert 'NaN' in rig.session.last_error
    rig.session.on_excitation(Block(0, RATE, 1, np.zeros((3, BLOCK))))
    rig.session.on_excitation(Block(0, RATE, 1, np.zeros((2, 0))))
    assert rig.count('excitation_malformed') == 4 and rig.session.offset is None
    assert rig.session.state == 'running'
    rig.excite(0)
    assert rig.count('excitation_blocks') == 1 and rig.session.queue.queued == BLOCK


def test_an_effort_command_joins_the_setpoints_and_times_out(make):
    rig = make()
    volts = coil_setpoint_for_force_V(BALANCE, 0.01, 0.0)
    assert volts > 0.0
    rig.clock.ns = at(150)
    rig.excite(0, 1000)
    rig.session.on_command(0.01)
    rig.feed(100)
    first, values = rig.fake.setpoints[-1]
    expected = np.zeros((2, 100))
    expected[:, 50:] = ramp(0, 50)
    expected[0] += volts
    assert first == 200
    np.testing.assert_allclose(values, expected, rtol=0, atol=1e-12)
    assert rig.count('command_N') == 0.01
    rig.clock.ns = at(150) + 100_000_001 + NS    # command_timeout_s passed
    rig.feed(200)
    np.testing.assert_array_equal(rig.fake.setpoints[-1][1], ramp(50, 100))
    assert rig.count('command_watchdog_trips') == 1 and rig.count('command_N') == 0.0
    rig.session.on_command(None, 'why')
    assert rig.count('command_malformed') == 1 and rig.session.last_error == 'why'


def test_command_messages_follow_the_device_contract(make):
    """Both topics' messages parsed by the contract: one effort for lever, else refused."""
    rig = make()
    s = rig.session
    s.on_joint_command(['other', 'lever'], [1.0, 0.02])
    assert s.command.effort_N == 0.02
    s.on_array_command([0.03])
    assert s.command.effort_N == 0.03
    s.on_joint_command(['other'], [1.0])
    assert 'lever' in s.last_error
    s.on_array_command([1.0, 2.0])
    assert s.last_error.startswith('commands needs exactly 1 value')
    s.on_array_command([float('nan')])
    assert rig.count('command_malformed') == 3 and s.command.effort_N == 0.03


def test_diagnostic_levels(make):
    rig = make()
    s = rig.session
    rig.feed(0)
    assert s.diagnostic_status()[:2] == (0, 'ok')
    samples = ramp(0, BLOCK)
    samples[0, 7] = 20.0
    rig.excite(0, samples=samples)
    assert rig.count('clamped_samples') == 1 and s.queue.pop(8)[0][0, 7] == 10.0
    assert s.diagnostic_status()[:2] == (1, 'stream defects or clamped setpoints')
    s.emergency_stop()
    level, message, values = s.diagnostic_status()
    assert level == 2 and values['emergency_stop'] == 1 and message.startswith('1 fault(s)')
    s.reset()
    assert s.diagnostic_status()[0] == 1
    rig.fake.health_values = {'device_underrun_samples': 3}
    rig.tick_at(at(500))
    assert s.diagnostic_status()[0] == 2


def test_an_emergency_stop_keeps_the_safe_generator_after_a_trip(make):
    sine = GeneratorSpec('sine', amplitude_V=1.0, frequency_Hz=10.0)
    rig = make(mode='function_generator', specs=[sine, GeneratorSpec()])
    assert rig.fake.generators == [[sine, GeneratorSpec()]]
    rig.clock.ns = at(150)
    rig.excite(0)
    rig.tick_at(at(15150))
    assert rig.session.tripped
    rig.session.emergency_stop()
    rig.excite(100)
    rig.sync()
    assert rig.session.estop and rig.count('excitation_dropped_estop') == 1
    assert rig.fake.generators[-1] == SAFE


def test_a_timed_out_command_leaves_no_device_underrun_on_the_sim(make):
    rig = make(backend=SimBackend())
    s = rig.session
    rig.clock.ns = at(200)
    assert s.poll_host_paced() == 2
    s.on_command(0.01)
    rig.clock.ns = at(300)
    assert s.poll_host_paced() == 1 and s.counts['setpoint_samples_written'] == LEAD
    rig.clock.ns = at(4000)                          # the command timed out at 0.12 s
    for _ in range(2):
        s.poll_host_paced()
    assert s.last_end == 4000 and rig.count('command_watchdog_trips') == 1
    s.tick()
    assert rig.faults() == []
