"""
The position_controller node closing the loop around the plant simulator in lockstep.

Both nodes run in this process on one executor and talk over real DDS (loopback discovery);
the plant owns simulated time and advances one controller period per effort command.
"""

import math
import time

from diagnostic_msgs.msg import DiagnosticArray
import rclpy
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from emfc_ros.nodes.plant_simulator import PlantSimulatorNode
from emfc_ros.nodes.position_controller import PositionControllerNode
import ros_harness
from ros_harness import scaled

TIMEOUT_S = scaled(60.0)
SENSOR_RANGE_M = 100e-6


class StateProbe:
    """Records the joint states (one per stamp) and the diagnostics of a namespace."""

    def __init__(self, context, namespace):
        self.node = rclpy.create_node('state_probe', namespace=namespace, context=context)
        self.by_stamp = {}
        self.diagnostics = []
        self.node.create_subscription(JointState, 'joint_states', self._on_state, 10000)
        self.node.create_subscription(DiagnosticArray, '/diagnostics',
                                      self.diagnostics.append, 100)

    def _on_state(self, msg):
        if msg.position and math.isfinite(msg.position[0]):
            stamp = msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec
            self.by_stamp.setdefault(stamp, (msg.position[0], msg.effort[0]))

    def positions(self):
        return [self.by_stamp[k][0] for k in sorted(self.by_stamp)]

    def stamps(self):
        return sorted(self.by_stamp)

    def diag(self, name_prefix, key):
        for msg in reversed(self.diagnostics):
            for status in msg.status:
                if status.name.startswith(name_prefix) and \
                        status.hardware_id.startswith(self.node.get_namespace()):
                    values = {kv.key: kv.value for kv in status.values}
                    if key in values:
                        return values[key]
        return None


def start_loop(context, executor, namespace, plant_extra=(), controller_extra=()):
    plant = PlantSimulatorNode(context=context, namespace=namespace, parameter_overrides=[
        Parameter('time_mode', value='lockstep'), Parameter('seed', value=3),
        Parameter('publish_groups', value=False), Parameter('state_rate_Hz', value=1000.0),
        Parameter('command_delay_periods', value=1)] + list(plant_extra))
    controller = PositionControllerNode(context=context, namespace=namespace,
                                        parameter_overrides=list(controller_extra))
    probe = StateProbe(context, namespace)
    for node in (plant, controller, probe.node):
        executor.add_node(node)
    return plant, controller, probe


def stop_loop(executor, nodes):
    for node in nodes:
        executor.remove_node(node)
        node.destroy_node()


def test_loop_holds_a_100_g_step_within_the_sensor_range(executor, ros_context):
    # 5 kHz controller (2 simulator samples per period): at 1 kHz no stable design has the
    # bandwidth to keep a 100 g step off the stop (docs/ros_control.md).
    plant, controller, probe = start_loop(
        ros_context, executor, '/loop_a',
        plant_extra=[Parameter('state_rate_Hz', value=5000.0)],
        controller_extra=[Parameter('rate_Hz', value=5000.0),
                          Parameter('crossover_Hz', value=80.0),
                          Parameter('loop_delay_periods', value=1.5)])
    rate = 5000
    before = int(0.2 * rate)
    after = int(0.3 * rate)
    t0 = time.monotonic()
    assert ros_harness.spin_until(executor, lambda: len(probe.by_stamp) >= before, TIMEOUT_S), \
        len(probe.by_stamp)
    wall = time.monotonic() - t0
    assert max(abs(y) for y in probe.positions()[-before // 2:]) < 2e-6
    # The loop started bumpless from the holding force of the empty pan.
    first_effort = probe.by_stamp[0][1]
    assert 0.15 < first_effort < 0.18

    result = plant.set_parameters([Parameter('load_mass_kg', value=0.1)])[0]
    assert result.successful, result.reason
    step_stamp = probe.stamps()[-1]
    assert ros_harness.spin_until(
        executor, lambda: len(probe.by_stamp) >= before + after, TIMEOUT_S)
    stamps = probe.stamps()
    positions = probe.positions()
    assert stamps[:before + after] == [round(k * 1e9 / rate) for k in range(before + after)]
    response = [y for s, y in zip(stamps, positions) if s > step_stamp]
    peak = max(abs(y) for y in response)
    assert peak < 0.9 * SENSOR_RANGE_M, peak
    assert peak > 5e-6           # the step did happen
    settled = [s for s, y in zip(stamps, positions) if s > step_stamp and abs(y) > 3e-6]
    settle_s = (settled[-1] - step_stamp) * 1e-9
    assert settle_s < 0.15, settle_s
    assert max(abs(y) for y in response[-int(0.05 * rate):]) < 3e-6
    print(f'\n100 g step at 5 kHz: peak {peak * 1e6:.1f} um, within 3 um after {settle_s:.4f} s '
          f'of simulated time; {before / wall:.0f} periods per wall second before the step')
    assert controller._runtime.saturated_samples == 0


def run_once(ros_context, executor, namespace, n_states):
    plant, controller, probe = start_loop(
        ros_context, executor, namespace,
        controller_extra=[Parameter('use_sim_time', value=True)])
    t0 = time.monotonic()
    assert ros_harness.spin_until(executor, lambda: len(probe.by_stamp) >= n_states, TIMEOUT_S)
    wall = time.monotonic() - t0
    stamps = probe.stamps()[:n_states]
    positions = [probe.by_stamp[k] for k in stamps]     # (position, effort) pairs
    # use_sim_time: the controller's clock follows the plant's /clock.
    assert ros_harness.spin_until(
        executor, lambda: controller.get_clock().now().nanoseconds > 0, TIMEOUT_S)
    stop_loop(executor, [plant, controller, probe.node])
    return positions, stamps, wall


def test_lockstep_loop_is_deterministic_in_simulated_time(executor, ros_context):
    n = 400
    first, stamps, wall = run_once(ros_context, executor, '/loop_b1', n)
    second, _, _ = run_once(ros_context, executor, '/loop_b2', n)
    assert stamps == [k * 1_000_000 for k in range(n)]
    assert len(set(y for y, _ in first)) > 5    # sensor noise through the 16-bit ADC
    assert first == second                      # positions and efforts, bit for bit
    print(f'\nlockstep at 1 kHz: {n / wall:.0f} periods per wall second '
          f'({n / 1000 / wall:.2f} s of simulated time per wall second)')


def test_bad_commands_are_reported_and_the_loop_keeps_running(executor, ros_context):
    plant, controller, probe = start_loop(ros_context, executor, '/loop_c')
    intruder = rclpy.create_node('intruder', namespace='/loop_c', context=ros_context)
    pub_joint = intruder.create_publisher(JointState, 'joint_commands', 10)
    pub_array = intruder.create_publisher(Float64MultiArray, 'commands', 10)
    pub_state = intruder.create_publisher(JointState, 'joint_states', 10)
    executor.add_node(intruder)
    assert ros_harness.spin_until(
        executor, lambda: len(probe.by_stamp) >= 100 and pub_joint.get_subscription_count() >= 1
        and pub_array.get_subscription_count() >= 1
        and pub_state.get_subscription_count() >= 2, TIMEOUT_S)

    nan = JointState(name=['lever'], effort=[math.nan])
    wrong = JointState(name=['wrong_joint'], effort=[1.0])
    pub_joint.publish(nan)
    pub_joint.publish(wrong)
    pub_array.publish(Float64MultiArray(data=[math.inf]))
    pub_array.publish(Float64MultiArray(data=[1.0, 2.0]))
    bad_state = JointState(name=['lever'], position=[math.nan], effort=[0.0])
    bad_state.header.stamp.sec = 999
    pub_state.publish(bad_state)
    count = len(probe.by_stamp)

    def reported():
        bad = probe.diag('plant_simulator', 'bad_commands')
        return bad is not None and int(bad) >= 4 and \
            (probe.diag('position_controller', 'bad_states') or '0') != '0'

    assert ros_harness.spin_until(executor, reported, TIMEOUT_S)
    last_error = probe.diag('plant_simulator', 'last_error')
    assert 'exactly 1 value' in last_error or 'not finite' in last_error \
        or 'wrong_joint' in last_error, last_error
    assert 'not finite' in probe.diag('position_controller', 'last_bad_state')
    # The plant and the loop kept running through it.
    assert ros_harness.spin_until(executor, lambda: len(probe.by_stamp) >= count + 200,
                                  TIMEOUT_S)
    assert max(abs(y) for y in probe.positions()[-100:]) < 3e-6
    assert probe.diag('plant_simulator', 'waiting_for_command') is not None
