"""
The plant session without DDS: time modes, commands, loads, acknowledgements, refusals.

Every call gets its time injected; the expected values are sample indices, counts and the
samples of the core simulator driven directly.
"""

import numpy as np
import pytest

from emfc_ros.core.blocks import Block
from emfc_ros.core.device_contract import measurement_groups
from emfc_ros.core.model.actuation import coil_setpoint_for_force_V
from emfc_ros.core.sim.channels import channel_names, channel_units
from emfc_ros.core.sim.closed_loop import EXTRA_CHANNELS, EXTRA_UNITS
from emfc_ros.core.sim.plant_config import (
    load_balance, make_simulator, plant_config, runtime_refusal)
from emfc_ros.core.sim.plant_events import (
    Acknowledgement, ClockTick, DescriptionChanged, JointStates, LogLine, MeasurementBlock)
from emfc_ros.core.sim.plant_parameters import PARAMETERS
from emfc_ros.core.sim.plant_session import ACK_REPEATS, PlantSession

RATE = 10000.0
START_S = 100.0


def values(**overrides):
    out = {name: entry[0] for name, entry in PARAMETERS.items()}
    out.update({'noise': False, 'quantisation': False, 'max_state_wall_rate_Hz': 0.0})
    out.update(overrides)
    return out


def session(**overrides):
    v = values(**overrides)
    cfg = plant_config(v.__getitem__)
    sim = None
    if not cfg.errors:
        sim, _ = make_simulator(load_balance('', {}), v.__getitem__, cfg.load_mass_kg,
                                cfg.load_changer_coupled)
    return PlantSession(cfg, sim, START_S)


def reference(**overrides):
    """The core simulator the session should equal, with the same options."""
    v = values(**overrides)
    sim, _ = make_simulator(load_balance('', {}), v.__getitem__, v['load_mass_kg'],
                            v['load_changer_coupled'])
    return sim


def block(first, n, epoch=1, value=0.0, rate=RATE):
    return Block(first, rate, epoch, np.full((2, n), value))


def of(events, kind):
    return [e for e in events if isinstance(e, kind)]


def row(s, name):
    return s.channel_names.index(name)


def test_owner_mode_simulates_each_block_on_arrival_with_clock_states_and_ack():
    s = session(state_rate_Hz=1000.0)
    events = s.on_excitation(block(0, 100), 0.0)
    assert [type(e) for e in events] == [DescriptionChanged, ClockTick, MeasurementBlock,
                                         JointStates, Acknowledgement]
    assert events[1] == ClockTick(10_000_000)
    assert events[2].first_index == 0 and events[2].samples.shape == (11, 100)
    np.testing.assert_array_equal(events[3].stamps_ns, np.arange(10) * 1_000_000)
    assert events[4] == Acknowledgement(100)
    # A block of 55 and one of 45: the states stay on the grid of the sample index.
    second = s.on_excitation(block(100, 55), 0.0)
    third = s.on_excitation(block(155, 45), 0.0)
    np.testing.assert_array_equal(of(second, JointStates)[0].stamps_ns,
                                  np.arange(10, 16) * 1_000_000)
    np.testing.assert_array_equal(of(third, JointStates)[0].stamps_ns,
                                  np.arange(16, 20) * 1_000_000)
    got = np.concatenate([of(e, MeasurementBlock)[0].samples
                          for e in (events, second, third)], axis=1)
    np.testing.assert_array_equal(got, reference().step_block(np.zeros((2, 200))))
    states = of(third, JointStates)[0]
    np.testing.assert_array_equal(states.position_m, got[row(s, 'position_m'), 160::10])
    np.testing.assert_array_equal(states.effort_N, got[row(s, 'coil_force_N'), 160::10])
    assert of(third, Acknowledgement) == [Acknowledgement(200)]
    assert (s.sim_samples, s.blocks_in, s.blocks_out, s.clocks_out) == (200, 3, 3, 3)
    assert s.states.published == 20


def test_owner_mode_limits_the_states_to_the_wall_rate():
    s = session(state_rate_Hz=1000.0, max_state_wall_rate_Hz=100.0)
    events = s.on_excitation(block(0, 1000), 0.0)
    # a bucket of 0.1 s at 100 Hz: 10 of the 100 due, evenly chosen, the first among them
    stamps = of(events, JointStates)[0].stamps_ns
    assert len(stamps) == 10 and stamps[0] == 0
    assert (s.states.published, s.states.decimated) == (10, 90)


def test_wall_mode_steps_on_the_injected_clock_and_counts_underruns():
    s = session(time_mode='wall', block_size=100, state_rate_Hz=1000.0)
    assert s.tick(START_S, 5) == []
    events = s.tick(START_S + 0.025, 5_000)        # 250 samples due: two whole blocks
    blocks = of(events, MeasurementBlock)
    assert [b.first_index for b in blocks] == [0, 100]
    assert of(events, ClockTick) == [] and of(events, Acknowledgement) == []
    # the stamps of the states continue over both blocks from the node's clock
    stamps = np.concatenate([e.stamps_ns for e in of(events, JointStates)])
    np.testing.assert_array_equal(stamps, 5_000 + np.arange(20) * 1_000_000)
    assert s.queue.counters()['underrun_samples'] == 200
    # queued excitation is consumed by the next block and acknowledged
    assert s.on_excitation(block(0, 100, value=0.5), START_S + 0.026) == []
    events = s.tick(START_S + 0.031, 0)
    assert [b.first_index for b in of(events, MeasurementBlock)] == [200]
    np.testing.assert_array_equal(
        of(events, MeasurementBlock)[0].samples[row(s, 'coil_setpoint_V')], 0.5)
    assert of(events, Acknowledgement) == [Acknowledgement(100)]
    assert s.queue.counters()['underrun_samples'] == 200


def test_the_load_schedule_applies_at_its_sample_and_is_announced():
    s = session(load_schedule='0.005:0.1,0.012:0')
    events = s.on_excitation(block(0, 100), 0.0)
    changes = [e for e in events if isinstance(e, DescriptionChanged) and e.scheduled_load_kg
               is not None]
    assert changes == [DescriptionChanged(0.1)]
    assert any(isinstance(e, LogLine) and 'from sample 50' in e.text for e in events)
    assert events.index(changes[0]) < events.index(of(events, MeasurementBlock)[0])
    assert s.load_changes == [[50, 0.1]] and s.load_kg == 0.1
    later = s.on_excitation(block(100, 100), 0.0)
    assert DescriptionChanged(0.0) in later and s.load_changes == [[50, 0.1], [120, 0.0]]
    ref = reference()
    parts = [ref.step_block(np.zeros((2, 50)))]
    ref.set_load(0.1, False)
    parts.append(ref.step_block(np.zeros((2, 70))))
    ref.set_load(0.0, False)
    parts.append(ref.step_block(np.zeros((2, 80))))
    got = np.concatenate([of(events, MeasurementBlock)[0].samples,
                          of(later, MeasurementBlock)[0].samples], axis=1)
    np.testing.assert_array_equal(got, np.concatenate(parts, axis=1))
    extra = s.descriptions('/p')['measurements'].extra
    assert extra['load_changes'] == [[50, 0.1], [120, 0.0]] and extra['load_mass_kg'] == 0.0


def test_a_run_time_load_change_takes_effect_at_the_next_sample():
    s = session()
    s.on_excitation(block(0, 100), 0.0)
    assert s.set_load(0.2, True) == [DescriptionChanged(None)]
    assert s.load_changes == [[100, 0.2]] and (s.load_kg, s.coupled) == (0.2, True)
    desc = s.descriptions('/p')
    assert desc['measurements/force'].extra['load_mass_kg'] == 0.2
    assert desc['measurements/force'].extra['load_changer_coupled'] is True
    got = of(s.on_excitation(block(100, 100), 0.0), MeasurementBlock)[0].samples
    ref = reference()
    ref.step_block(np.zeros((2, 100)))
    ref.set_load(0.2, True)
    np.testing.assert_array_equal(got, ref.step_block(np.zeros((2, 100))))


def test_the_effort_command_is_added_until_the_watchdog_trips():
    s = session(command_timeout_s=0.1)
    assert s.on_array_command([0.01], 0.0) == []
    first = of(s.on_excitation(block(0, 10), 0.05), MeasurementBlock)[0].samples
    expected_V = coil_setpoint_for_force_V(s.sim.params, 0.01, 0.0)
    np.testing.assert_array_equal(first[row(s, 'coil_setpoint_V')], expected_V)
    assert s.command.effort_N == 0.01
    second = of(s.on_excitation(block(10, 10), 0.2), MeasurementBlock)[0].samples
    np.testing.assert_array_equal(second[row(s, 'coil_setpoint_V')], 0.0)
    assert (s.command.effort_N, s.command.watchdog_trips) == (0.0, 1)
    _, _, diag = s.diagnostics(1.0)
    assert diag['command_watchdog_trips'] == 1 and diag['command_N'] == 0.0


def lockstep(**overrides):
    s = session(time_mode='lockstep', state_rate_Hz=1000.0, **overrides)
    assert s.tick(0.0, 0, state_subscribed=False) == []
    first = s.tick(0.0, 0, state_subscribed=True)
    return s, first


def test_lockstep_starts_at_the_hold_point_and_steps_one_period_per_matching_command():
    s, first = lockstep(command_delay_periods=0)
    assert [type(e) for e in first] == [MeasurementBlock, JointStates, ClockTick]
    assert first[0].first_index == 0 and first[0].samples.shape[1] == 1
    assert first[2] == ClockTick(0) and s.lock.waiting
    hold_N = float(first[1].effort_N[0])
    # another stamp answers nothing; the matching one steps samples 1..10
    assert s.on_joint_command(['lever'], [1.0], 5_000_000, 0.0) == []
    assert s.lock.stale == 1
    events = s.on_joint_command(['lever'], [hold_N], 0, 0.0)
    blk = of(events, MeasurementBlock)[0]
    assert (blk.first_index, blk.samples.shape[1]) == (1, 10)
    assert of(events, ClockTick) == [ClockTick(1_000_000)]
    np.testing.assert_array_equal(of(events, JointStates)[0].stamps_ns, [1_000_000])
    position = float(first[0].samples[row(s, 'position_m'), -1])
    np.testing.assert_array_equal(blk.samples[row(s, 'coil_setpoint_V')],
                                  coil_setpoint_for_force_V(s.sim.params, hold_N, position))
    # commands has no stamp: it answers whatever waits
    events = s.on_array_command([hold_N], 0.0)
    assert of(events, MeasurementBlock)[0].first_index == 11
    assert (s.lock.periods, s.next_index, s.sim_samples) == (2, 21, 21)
    # no state waits while a step is not published: none here, so a command is unexpected
    s.lock.waiting = False
    assert s.on_array_command([hold_N], 0.0) == [] and s.lock.unexpected == 1


def test_lockstep_next_matching_takes_any_stamp():
    s, _ = lockstep(lockstep_match='next')
    events = s.on_joint_command(['lever'], [0.1], 123_456_789, 0.0)
    assert of(events, MeasurementBlock)[0].first_index == 1 and s.lock.stale == 0


def test_command_delay_periods_applies_each_command_one_period_later():
    s, first = lockstep(command_delay_periods=1)
    hold_V = float(s.sim.hold_setpoints_V[0])
    a = s.on_joint_command(['lever'], [0.1], 0, 0.0)
    position = s.last_position_m
    b = s.on_joint_command(['lever'], [0.2], 1_000_000, 0.0)
    coil = row(s, 'coil_setpoint_V')
    np.testing.assert_array_equal(of(a, MeasurementBlock)[0].samples[coil], hold_V)
    position_a = float(first[0].samples[row(s, 'position_m'), -1])
    np.testing.assert_array_equal(of(b, MeasurementBlock)[0].samples[coil],
                                  coil_setpoint_for_force_V(s.sim.params, 0.1, position_a))
    assert s.lock.pending_V == coil_setpoint_for_force_V(s.sim.params, 0.2, position)


def test_lockstep_republishes_an_unanswered_state_after_the_timeout():
    s, first = lockstep(command_timeout_s=0.2)
    assert s.tick(0.1) == []
    again = s.tick(0.2)
    assert again == [first[1], ClockTick(0)] and s.lock.republished == 1
    assert s.tick(0.3) == [] and len(s.tick(0.4)) == 2 and s.lock.republished == 2


def test_a_fractional_lockstep_period_is_refused_and_nothing_steps():
    s = session(time_mode='lockstep', state_rate_Hz=3000.0)
    assert 'whole number of samples' in s.error
    assert s.tick(0.0, 0, state_subscribed=True) == []
    level, message, _ = s.diagnostics(0.0)
    assert level == 'ERROR' and 'whole number of samples' in message


def test_acknowledgements_repeat_while_no_excitation_follows():
    s = session()
    s.on_excitation(block(0, 100), 0.0)
    assert s.tick(0.01) == []
    repeats = [e for k in range(1, 40) for e in s.tick(0.05 * k)]
    assert repeats == [Acknowledgement(100)] * ACK_REPEATS
    assert s.acks_repeated == ACK_REPEATS
    # a block sent again is dropped (counted) and answered with the acknowledgement
    assert s.on_excitation(block(0, 100), 3.0) == [Acknowledgement(100)]
    assert s.queue.counters()['duplicates'] == 1 and s.sim_samples == 100


def test_reset_returns_to_the_operating_point_and_the_indices_go_on():
    s, first = lockstep(command_delay_periods=0)
    s.on_array_command([0.3], 0.0)
    hold_V = float(s.sim.hold_setpoints_V[0])
    assert s.lock.coil_V != hold_V
    assert s.reset() == (True, 'simulator state reset to the operating point')
    assert s.lock.coil_V == s.lock.pending_V == hold_V
    assert s.next_index == 11
    owner = session()
    owner.on_excitation(block(0, 100, value=0.5), 0.0)
    owner.reset()
    got = of(owner.on_excitation(block(100, 100), 0.0), MeasurementBlock)[0]
    assert got.first_index == 100
    np.testing.assert_array_equal(got.samples, reference().step_block(np.zeros((2, 100))))


def test_refused_excitation_and_commands_leave_the_session_running():
    s = session()
    warned = s.refuse_excitation('layout broken', 0.0)
    assert [e.level for e in warned] == ['warning'] and 'layout broken' in warned[0].text
    assert s.on_excitation(block(0, 10, rate=5000.0), 1.0) == []     # throttled warning
    nan = block(0, 10)
    nan.samples[0, 3] = np.nan
    assert of(s.on_excitation(nan, 6.0), LogLine)[0].level == 'warning'
    assert s.malformed == 3 and 'NaN or infinite' in s.last_error
    assert of(s.on_joint_command(['other'], [1.0], 0, 0.0), LogLine)
    assert s.on_array_command([1.0, 2.0], 0.5) == []                # throttled
    assert s.on_command(float('inf'), None, 'commands', 3.0)[0].level == 'warning'
    assert (s.bad_commands, s.malformed) == (3, 6)
    assert 'not finite' in s.last_error and s.command.effort_N == 0.0
    events = s.on_excitation(block(0, 10), 7.0)
    assert of(events, MeasurementBlock)[0].first_index == 0 and s.blocks_in == 1
    level, message, _ = s.diagnostics(7.0)
    assert (level, message) == ('WARN', 'excitation defects')


def test_a_session_without_simulator_refuses_everything_with_its_reason():
    cfg = plant_config(values().__getitem__)
    s = PlantSession(cfg, None, START_S, error='seed out of range; restart')
    assert s.on_excitation(block(0, 10), 0.0) == []
    assert s.malformed == 1 and s.last_error == 'seed out of range; restart'
    assert s.reset() == (False, 'seed out of range; restart')
    assert s.set_load(0.1, False) == [] and s.diagnostics(0.0)[0] == 'ERROR'


def test_a_second_clock_stops_the_simulation_and_survives_a_balance_change():
    s = session()
    s.fail('another node publishes /clock', clock_conflict=True)
    assert s.on_excitation(block(0, 10), 0.0) == [] and s.blocks_out == 0
    s.replace_simulator(reference())
    assert s.error == 'another node publishes /clock' and not s.simulating


@pytest.mark.parametrize('looped', [False, True])
def test_the_group_rule_selects_the_old_named_channels(looped):
    names, units = channel_names(reference=True), channel_units(reference=True)
    if looped:
        names, units = names + EXTRA_CHANNELS, units + EXTRA_UNITS
    old = {'position': ('position_m', 'sensor_V', 'position_true_m'),
           'current': ('coil_current_A', 'load_changer_current_A', 'coil_current_precise_A'),
           'force': ('coil_force_N', 'load_changer_force_N', 'pan_force_N',
                     'coil_force_true_N', 'force_command_N')}
    groups = measurement_groups(names, units)
    assert {g: {names[i] for i in rows} for g, rows in groups.items()} == \
        {g: set(n for n in wanted if n in names) for g, wanted in old.items()}


def test_run_time_parameter_checks_name_the_reason():
    assert runtime_refusal('load_mass_kg', 1, RATE, 'owner') == ''
    assert 'from 0 to 2 kg' in runtime_refusal('load_mass_kg', 2.5, RATE, 'owner')
    assert 'true or false' in runtime_refusal('load_changer_coupled', 1, RATE, 'owner')
    assert 'fixed at start-up' in runtime_refusal('state_rate_Hz', 100.0, RATE, 'lockstep')
    assert runtime_refusal('state_rate_Hz', 100.0, RATE, 'owner') == ''
    assert 'fixed at start-up' in runtime_refusal('seed', 3, RATE, 'owner')
    assert '(0, 60] s' in runtime_refusal('command_timeout_s', 0.0, RATE, 'owner')


def test_plant_config_lists_each_refusal():
    cfg = plant_config(values(time_mode='lockstep', state_rate_Hz=1000.0,
                              load_schedule='x', **{'control.enabled': True}).__getitem__)
    assert len(cfg.errors) == 2
    assert cfg.errors[0].startswith('control configuration refused')
    assert cfg.errors[1].startswith('load_schedule refused')
    ok = plant_config(values(load_schedule='0:0,0.5:0.1').__getitem__)
    assert ok.errors == [] and ok.load_schedule == [(0, 0.0, None), (5000, 0.1, None)]
