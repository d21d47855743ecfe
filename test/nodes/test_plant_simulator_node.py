"""
The plant_simulator node over real DDS.

Lockstep with the signal generator in simulated time, exact sample indices, the same
samples as the simulator core, the controller interface, diagnostics, refused parameters.
"""

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String, UInt64

from emfc_ros.core.config import unflatten
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.paths import config_file
from emfc_ros.core.signals import experiment_from_config
from emfc_ros.core.sim.simulator import Simulator
from emfc_ros.nodes.convert import (
    BLOCK_QOS, block_to_msg, CONTROL_QOS, LATCHED_QOS, msg_to_block, msg_to_description)
from emfc_ros.nodes.plant_simulator import PlantSimulatorNode
from emfc_ros.nodes.signal_generator import SignalGeneratorNode
import ros_harness
from ros_harness import scaled

TIMEOUT_S = scaled(20.0)
RATE = 10000.0


def hold_coil_V():
    params = BalanceParameters.load_yaml(config_file('balance_default.yaml'))
    return float(Simulator(params, RATE).hold_setpoints_V[0])


def experiment(hold_V):
    return {
        'sample_rate_Hz': RATE, 'sections': ['a'],
        'section.a.duration_s': 0.0833,
        'section.a.coil.offset_V': hold_V,
        'section.a.coil.signals.s.type': 'sine',
        'section.a.coil.signals.s.amplitude_V': 0.002,
        'section.a.coil.signals.s.frequency_Hz': 50.0,
        'section.a.load_changer.signals.p.type': 'prbs',
        'section.a.load_changer.signals.p.order': 7,
        'section.a.load_changer.signals.p.low_V': -0.05,
        'section.a.load_changer.signals.p.high_V': 0.05,
    }


class Probe:
    """Records what the plant publishes."""

    def __init__(self, context):
        self.node = rclpy.create_node('probe', context=context)
        self.blocks = {}
        self.descriptions = {}
        self.clock_ns = []
        self.states = []
        self.diagnostics = []
        for topic in ('measurements', 'measurements/position', 'measurements/current',
                      'measurements/force'):
            self.blocks[topic] = []
            self.node.create_subscription(
                Float64MultiArray, topic,
                lambda m, t=topic: self.blocks[t].append(
                    (lambda b: (b.first_sample_index, b.epoch, np.array(b.samples)))(
                        msg_to_block(m))), BLOCK_QOS)
            self.node.create_subscription(
                String, f'{topic}/description',
                lambda m, t=topic: self.descriptions.__setitem__(t, msg_to_description(m)),
                LATCHED_QOS)
        self.node.create_subscription(
            Clock, '/clock',
            lambda m: self.clock_ns.append(m.clock.sec * 10 ** 9 + m.clock.nanosec), 10)
        self.node.create_subscription(JointState, 'joint_states', self.states.append, 1000)
        self.node.create_subscription(DiagnosticArray, '/diagnostics',
                                      self.diagnostics.append, 10)

    def samples(self, topic='measurements'):
        return sum(b[2].shape[1] for b in self.blocks[topic])

    def diag_value(self, key):
        for msg in reversed(self.diagnostics):
            for status in msg.status:
                if status.name.startswith('plant_simulator'):
                    values = {kv.key: kv.value for kv in status.values}
                    if key in values:
                        return values[key]
        return None


def test_lockstep_with_generator_is_exact_and_matches_the_core(executor, ros_context):
    hold = hold_coil_V()
    flat = experiment(hold)
    gen = SignalGeneratorNode(context=ros_context, parameter_overrides=[
        Parameter(f'experiment.{k}', value=v) for k, v in flat.items()] + [
        Parameter('pacing', value='consumer'), Parameter('block_size', value=128),
        Parameter('autostart', value=False)])
    plant = PlantSimulatorNode(context=ros_context, parameter_overrides=[
        Parameter('time_mode', value='owner'), Parameter('seed', value=7),
        Parameter('state_rate_Hz', value=1000.0),
        # Every state, to compare with the core (a burst of 85 in a few ms of wall time).
        Parameter('max_state_wall_rate_Hz', value=0.0)])
    probe = Probe(ros_context)
    for node in (gen, plant, probe.node):
        executor.add_node(node)
    assert ros_harness.spin_until(
        executor, lambda: gen.count_subscribers('excitation') >= 1
        and plant.count_subscribers('measurements') >= 1
        and gen.count_subscribers('excitation/consumed') >= 0
        and plant.count_publishers('excitation/consumed') >= 1, TIMEOUT_S)
    assert ros_harness.spin_until(
        executor, lambda: gen.count_publishers('excitation/consumed') >= 1
        or gen.get_subscriptions_info_by_topic('excitation/consumed'), TIMEOUT_S)
    assert gen._start()[0]
    total = 833
    assert ros_harness.spin_until(executor, lambda: probe.samples() >= total, TIMEOUT_S)
    # 7 blocks of up to 128 samples at 10 kHz, states every 10 samples of the sample index
    # (the device contract's grid, not each block's start): samples 0, 10, ..., 830.
    assert ros_harness.spin_until(
        executor, lambda: len(probe.clock_ns) >= 7 and len(probe.states) >= 84
        and len(probe.descriptions) == 4, TIMEOUT_S)   # latched, matched in any order

    firsts = [b[0] for b in probe.blocks['measurements']]
    assert firsts == list(range(0, total, 128))
    got = np.concatenate([b[2] for b in probe.blocks['measurements']], axis=1)
    assert got.shape[1] == total

    # The same excitation through the core simulator in one shot gives the same samples.
    excitation = experiment_from_config(unflatten(flat)).block(0, total)
    params = BalanceParameters.load_yaml(config_file('balance_default.yaml'))
    sim = Simulator(params, RATE, seed=7)
    np.testing.assert_array_equal(got, sim.step_block(excitation))

    names = probe.descriptions['measurements'].channel_names
    applied = got[names.index('coil_setpoint_V')]
    np.testing.assert_allclose(applied, excitation[0], atol=20.0 / 65536)
    assert np.max(np.abs(got[names.index('position_true_m')])) < 100e-6
    desc = probe.descriptions['measurements/force']
    assert 'coil_force_N' in desc.channel_names and desc.channels[0].unit == 'N'
    # A group holds its channels in stream order, as its description lists them.
    pos_names = probe.descriptions['measurements/position'].channel_names
    assert pos_names == ('sensor_V', 'position_m', 'position_true_m')
    pos = np.concatenate([b[2] for b in probe.blocks['measurements/position']], axis=1)
    for k, name in enumerate(pos_names):
        np.testing.assert_array_equal(pos[k], got[names.index(name)])

    # Simulated time: /clock ends at total / rate; joint states are stamped with it.
    assert probe.clock_ns[-1] == round(total * 1e9 / RATE)
    assert probe.clock_ns == sorted(probe.clock_ns)
    stamps = [s.header.stamp.sec * 10 ** 9 + s.header.stamp.nanosec for s in probe.states]
    assert stamps == [k * 10 ** 6 for k in range(84)]
    position = np.array([s.position[0] for s in probe.states])
    np.testing.assert_array_equal(position, got[names.index('position_m'), ::10])
    assert probe.states[0].name == ['lever']


def _owner_plant_with_feeder(executor, ros_context, overrides):
    """A plant in ``owner`` mode, a probe and a feeder's excitation publisher, connected."""
    plant = PlantSimulatorNode(context=ros_context, parameter_overrides=[
        Parameter('time_mode', value='owner')] + overrides)
    probe = Probe(ros_context)
    feeder = rclpy.create_node('feeder', context=ros_context)
    pub = feeder.create_publisher(Float64MultiArray, 'excitation', BLOCK_QOS)
    for node in (plant, probe.node, feeder):
        executor.add_node(node)
    assert ros_harness.spin_until(executor, lambda: pub.get_subscription_count() >= 1
                                  and plant.count_subscribers('measurements') >= 1, TIMEOUT_S)
    return plant, probe, feeder, pub


def test_bad_excitation_is_counted_and_the_node_keeps_going(executor, ros_context):
    plant, probe, feeder, pub = _owner_plant_with_feeder(executor, ros_context, [
        Parameter('noise', value=False)])
    bad = [block_to_msg(0, RATE, 1, np.zeros((3, 10))),        # three channels
           block_to_msg(0, 5000.0, 1, np.zeros((2, 10)))]      # wrong sample rate
    broken = block_to_msg(0, RATE, 1, np.zeros((2, 10)))
    broken.layout.data_offset = 0                              # breaks the convention
    huge = block_to_msg(0, RATE, 1, np.zeros((2, 10)))
    huge.layout.dim[1].size = huge.layout.dim[1].stride = 5_000_000   # claims 2 x 5e6
    huge.layout.dim[0].stride = 10_000_000
    for msg in bad + [broken, huge]:
        pub.publish(msg)
    pub.publish(block_to_msg(0, RATE, 1, np.zeros((2, 100))))
    assert ros_harness.spin_until(executor, lambda: probe.samples() >= 100, TIMEOUT_S)
    # Non-finite setpoints and a far-future index (2**52) are refused; the stream goes on.
    nan = np.zeros((2, 100))
    nan[0, 50] = np.nan
    pub.publish(block_to_msg(2 ** 52, RATE, 1, np.zeros((2, 100))))
    pub.publish(block_to_msg(100, RATE, 1, nan))
    pub.publish(block_to_msg(100, RATE, 1, np.full((2, 100), np.inf)))
    pub.publish(block_to_msg(100, RATE, 1, np.zeros((2, 100))))
    assert ros_harness.spin_until(executor, lambda: probe.samples() >= 200, TIMEOUT_S)
    assert ros_harness.spin_until(
        executor, lambda: probe.diag_value('malformed_messages') == '7', TIMEOUT_S)
    assert [b[0] for b in probe.blocks['measurements']] == [0, 100]
    assert 'NaN or infinite' in probe.diag_value('last_error')


def test_a_block_sent_again_is_dropped_and_acknowledged_again(executor, ros_context):
    # A consumer-paced generator that did not hear the acknowledgement sends the window
    # again: the plant must not simulate it twice, and must say again how far it is.
    plant, probe, feeder, pub = _owner_plant_with_feeder(executor, ros_context, [])
    acks = []
    feeder.create_subscription(UInt64, 'excitation/consumed', lambda m: acks.append(m.data),
                               CONTROL_QOS)
    assert ros_harness.spin_until(
        executor, lambda: feeder.count_publishers('excitation/consumed') >= 1, TIMEOUT_S)
    first = block_to_msg(0, RATE, 1, np.zeros((2, 100)))
    second = block_to_msg(100, RATE, 1, np.zeros((2, 100)))
    pub.publish(first)
    pub.publish(second)
    assert ros_harness.spin_until(executor, lambda: acks == [100, 200], TIMEOUT_S), acks
    pub.publish(first)
    pub.publish(second)
    assert ros_harness.spin_until(executor, lambda: acks == [100, 200, 200, 200],
                                  TIMEOUT_S), acks
    assert ros_harness.spin_until(
        executor, lambda: probe.diag_value('duplicates') == '2', TIMEOUT_S)
    assert [b[0] for b in probe.blocks['measurements']] == [0, 100]
    assert probe.diag_value('simulated_samples') == '200'


@pytest.mark.slow
def test_separate_process_refuses_bad_parameters(tmp_path, processes, executor, ros_context):
    bad = tmp_path / 'balance.yaml'
    text = config_file('balance_default.yaml').read_text()
    assert 'mp_kg: 0.060' in text
    bad.write_text(text.replace('mp_kg: 0.060', 'mp_kg: -1.0'))
    proc = processes.start(ros_harness.node_executable('plant_simulator') + [
        '--ros-args', '-r', '__ns:=/emfc', '-p', 'time_mode:=owner'])
    probe = rclpy.create_node('client', namespace='/emfc', context=ros_context)
    executor.add_node(probe)
    client = AsyncParameterClient(probe, '/emfc/plant_simulator')
    assert ros_harness.spin_until(executor, client.services_are_ready, TIMEOUT_S), proc.output()

    def set_one(name, value):
        # each request is idempotent: sent again if the answer to the first was lost
        future = ros_harness.call_until_answered(
            executor, lambda: client.set_parameters([Parameter(name, value=value)]), TIMEOUT_S)
        assert future is not None, (name, proc.output())
        return future.result().results[0]

    for name, value, needle in [('load_mass_kg', -0.1, 'load_mass_kg'),
                                ('load_mass_kg', 5.0, 'out of range'),
                                ('seed', 3, 'read-only'),
                                ('balance_file', str(bad), 'mp_kg'),
                                ('balance_file', str(tmp_path / 'none.yaml'), 'none.yaml')]:
        result = set_one(name, value)
        assert not result.successful, name
        assert needle in result.reason, result.reason
    assert set_one('load_mass_kg', 0.1).successful
    assert set_one('load_changer_coupled', True).successful
    assert proc.alive()
    assert proc.stop() == 0, proc.output()


class LockstepProbe(Probe):
    """A probe that also answers joint states by hand."""

    def __init__(self, context):
        super().__init__(context)
        self.pub = self.node.create_publisher(JointState, 'joint_commands', 10)

    def stamps(self):
        return [s.header.stamp.sec * 10 ** 9 + s.header.stamp.nanosec for s in self.states]

    def answer(self, stamp_ns, effort_N):
        msg = JointState(name=['lever'], effort=[effort_N])
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10 ** 9)
        self.pub.publish(msg)


def test_lockstep_steps_one_period_per_matching_command(executor, ros_context):
    plant = PlantSimulatorNode(context=ros_context, parameter_overrides=[
        Parameter('time_mode', value='lockstep'), Parameter('noise', value=False),
        Parameter('state_rate_Hz', value=1000.0), Parameter('command_timeout_s', value=0.2),
        Parameter('command_delay_periods', value=0)])
    probe = LockstepProbe(ros_context)
    for node in (plant, probe.node):
        executor.add_node(node)
    # The first state (t = 0, held at the hold point) once a subscriber exists, then
    # re-published while unanswered.
    assert ros_harness.spin_until(executor, lambda: len(probe.states) >= 2, TIMEOUT_S)
    assert probe.stamps()[:2] == [0, 0]
    hold_N = probe.states[0].effort[0]
    assert 0.15 < hold_N < 0.18 and abs(probe.states[0].position[0]) < 1e-8
    assert probe.blocks['measurements'][0][0] == 0
    assert probe.blocks['measurements'][0][2].shape[1] == 1

    # A command with another stamp answers nothing: ignored (counted as stale).
    assert ros_harness.spin_until(executor, lambda: plant.count_publishers('joint_commands')
                                  >= 1 and probe.pub.get_subscription_count() >= 1, TIMEOUT_S)
    probe.answer(5_000_000, 1.0)
    assert ros_harness.spin_until(executor, lambda: plant._session.lock.stale >= 1, TIMEOUT_S)
    # Answer every state with the holding force: one period (10 samples) per answer.
    for k in range(20):
        probe.answer(k * 1_000_000, hold_N)
        assert ros_harness.spin_until(
            executor, lambda: (k + 1) * 1_000_000 in probe.stamps(), TIMEOUT_S), k
    firsts = [(b[0], b[2].shape[1]) for b in probe.blocks['measurements']]
    assert firsts == [(0, 1)] + [(1 + 10 * k, 10) for k in range(20)]
    assert probe.clock_ns[-1] == 20_000_000
    assert max(abs(s.position[0]) for s in probe.states) < 1e-6
    assert plant._session.lock.republished >= 1


def test_lockstep_refuses_a_fractional_period(executor, ros_context):
    plant = PlantSimulatorNode(context=ros_context, parameter_overrides=[
        Parameter('time_mode', value='lockstep'), Parameter('state_rate_Hz', value=3000.0)])
    probe = Probe(ros_context)
    for node in (plant, probe.node):
        executor.add_node(node)
    assert ros_harness.spin_until(executor, lambda: probe.diag_value('error'), TIMEOUT_S)
    assert 'whole number of samples' in probe.diag_value('error')
    assert probe.states == []
    result = plant.set_parameters([Parameter('state_rate_Hz', value=1000.0)])[0]
    assert not result.successful and 'fixed at start-up' in result.reason


def test_in_loop_controller_holds_a_100_g_step_over_dds(executor, ros_context):
    """control.enabled: the loop runs inside the node's sample loop; excitation adds to it."""
    rate = 20000.0
    plant, probe, feeder, pub = _owner_plant_with_feeder(executor, ros_context, [
        Parameter('sample_rate_Hz', value=rate), Parameter('seed', value=3),
        Parameter('control.enabled', value=True)])
    block = 2000
    pub.publish(block_to_msg(0, rate, 1, np.zeros((2, block))))
    assert ros_harness.spin_until(executor, lambda: probe.samples() >= block, TIMEOUT_S)
    client = AsyncParameterClient(feeder, 'plant_simulator')
    assert client.wait_for_services(TIMEOUT_S)
    future = client.set_parameters([Parameter('load_mass_kg', value=0.1)])
    assert ros_harness.spin_until(executor, future.done, TIMEOUT_S)
    assert future.result().results[0].successful
    # 0.5 s after the step, in simulated time
    for k in range(1, 6):
        pub.publish(block_to_msg(k * block, rate, 1, np.zeros((2, block))))
    assert ros_harness.spin_until(executor, lambda: probe.samples() >= 6 * block
                                  and len(probe.descriptions) == 4, TIMEOUT_S)
    names = probe.descriptions['measurements'].channel_names
    assert 'coil_current_precise_A' in names and 'force_command_N' in names
    got = np.concatenate([b[2] for b in probe.blocks['measurements']], axis=1)
    y = got[names.index('position_true_m')]
    assert np.max(np.abs(y)) < 100e-6
    assert np.max(np.abs(y[block:])) > 5e-6           # the step reached the lever
    assert abs(np.mean(y[-block:])) < 1e-8            # and the loop brought it back
    force = got[names.index('force_command_N')]
    assert np.mean(force[-block:]) < np.mean(force[:block]) - 0.1   # 100 g less coil force
    assert 'coil_current_precise_A' in probe.descriptions['measurements/current'].channel_names
