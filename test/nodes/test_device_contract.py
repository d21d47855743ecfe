"""
The device contract, one test against both device nodes (``core/device_contract.py``).

The daq_bridge (its sim back-end) and the plant_simulator (wall mode) are drop-ins for each
other: the same grouped measurement streams by the same rule, joint states of the joint
``lever`` on the sample-index grid, effort commands on ``commands`` and ``joint_commands``
added to the coil setpoint through the balance's motor and amplifier and returned to 0 N by
the command watchdog, malformed commands counted as ``command_malformed`` on ``/diagnostics``.
"""

import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String

from emfc_ros.core.device_contract import GROUP_UNITS, JOINT, measurement_groups
from emfc_ros.core.model.actuation import coil_setpoint_for_force_V
from emfc_ros.core.model.balance_file import load_balance
from emfc_ros.nodes.convert import BLOCK_QOS, LATCHED_QOS, msg_to_block, msg_to_description
import ros_harness

TIMEOUT_S = 30.0
RATE_HZ = 10000.0
STATE_RATE_HZ = 1000.0
FORCE_N = 0.02
COMMAND_TIMEOUT_S = 0.2


def _bridge(context):
    from emfc_ros.nodes.daq_bridge import DaqBridgeNode
    return DaqBridgeNode(context=context, parameter_overrides=[
        Parameter('backend', value='sim'), Parameter('block_size', value=200),
        Parameter('excitation_lead_s', value=0.02),
        Parameter('command_timeout_s', value=COMMAND_TIMEOUT_S),
        Parameter('state_rate_Hz', value=STATE_RATE_HZ)])


def _plant(context):
    from emfc_ros.nodes.plant_simulator import PlantSimulatorNode
    return PlantSimulatorNode(context=context, parameter_overrides=[
        Parameter('time_mode', value='wall'), Parameter('block_size', value=200),
        Parameter('command_timeout_s', value=COMMAND_TIMEOUT_S),
        Parameter('state_rate_Hz', value=STATE_RATE_HZ)])


class Probe:
    """What a controller and a recorder see of a device node."""

    def __init__(self, context):
        self.node = rclpy.create_node('contract_probe', context=context)
        self.blocks = []
        self.group_blocks = {g: [] for g in GROUP_UNITS}
        self.descriptions = {}
        self.states = []
        self.diagnostics = []
        sub = self.node.create_subscription
        sub(Float64MultiArray, 'measurements', self.blocks.append, BLOCK_QOS)
        for topic in ['measurements'] + [f'measurements/{g}' for g in GROUP_UNITS]:
            sub(String, f'{topic}/description',
                lambda m, t=topic: self.descriptions.__setitem__(t, msg_to_description(m)),
                LATCHED_QOS)
        for group, got in self.group_blocks.items():
            sub(Float64MultiArray, f'measurements/{group}', got.append, BLOCK_QOS)
        sub(JointState, 'joint_states', self.states.append, 1000)
        sub(DiagnosticArray, '/diagnostics', self.diagnostics.append, 10)
        self.commands = self.node.create_publisher(Float64MultiArray, 'commands', 10)
        self.joint_commands = self.node.create_publisher(JointState, 'joint_commands', 10)

    def diag(self, key):
        for msg in reversed(self.diagnostics):
            for status in msg.status:
                values = {kv.key: kv.value for kv in status.values}
                if key in values:
                    return values[key]
        return None

    def channel(self, name):
        """(sample indices, values) of one channel over the measurement blocks so far."""
        names = self.descriptions['measurements'].channel_names
        blocks = [msg_to_block(m) for m in self.blocks]
        index = np.concatenate([np.arange(b.first_sample_index, b.end_index) for b in blocks])
        values = np.concatenate([b.samples[names.index(name)] for b in blocks])
        return index, values


@pytest.mark.parametrize('make', [_bridge, _plant], ids=['daq_bridge', 'plant_simulator'])
def test_both_device_nodes_keep_the_device_contract(executor, ros_context, make):
    device = make(ros_context)
    probe = Probe(ros_context)
    executor.add_node(device)
    executor.add_node(probe.node)
    assert ros_harness.spin_until(
        executor, lambda: len(probe.blocks) >= 3 and len(probe.states) >= 20
        and 'measurements' in probe.descriptions
        and probe.commands.get_subscription_count() >= 1
        and probe.joint_commands.get_subscription_count() >= 1, TIMEOUT_S)

    # grouped streams: the channels of unit m, A, N (position also sensor_V), by one rule
    main = probe.descriptions['measurements']
    groups = measurement_groups(main.channel_names, [c.unit for c in main.channels])
    assert groups and set(groups) <= set(GROUP_UNITS)
    assert ros_harness.spin_until(
        executor, lambda: all(f'measurements/{g}' in probe.descriptions for g in groups)
        and all(probe.group_blocks[g] for g in groups), TIMEOUT_S)
    for group, rows in groups.items():
        described = probe.descriptions[f'measurements/{group}'].channel_names
        assert list(described) == [main.channel_names[i] for i in rows], group
        grouped = msg_to_block(probe.group_blocks[group][-1])
        whole = {msg_to_block(m).first_sample_index: msg_to_block(m) for m in probe.blocks}
        assert ros_harness.spin_until(
            executor, lambda: any(msg_to_block(m).first_sample_index
                                  == grouped.first_sample_index for m in probe.blocks),
            TIMEOUT_S)
        whole = {msg_to_block(m).first_sample_index: msg_to_block(m) for m in probe.blocks}
        np.testing.assert_array_equal(grouped.samples,
                                      whole[grouped.first_sample_index].samples[list(rows)])
    assert {t for t in probe.descriptions if t != 'measurements'} == {
        f'measurements/{g}' for g in groups}          # no group without its channels

    # joint states: joint lever, every 1 ms of the sample clock
    assert all(list(s.name) == [JOINT] and len(s.effort) == 1 for s in probe.states)
    stamps = np.array([s.header.stamp.sec * 10 ** 9 + s.header.stamp.nanosec
                       for s in probe.states[-50:]])
    steps = np.diff(stamps)
    assert np.all(steps > 0) and np.all(steps % 1_000_000 == 0), steps[steps % 1_000_000 != 0]

    # effort commands on both topics, then the watchdog; two malformed ones counted
    _, before = probe.channel('coil_setpoint_V')
    assert np.all(before == 0.0)
    start = msg_to_block(probe.blocks[-1]).end_index
    deadline = time.monotonic() + 0.6
    k = 0
    while time.monotonic() < deadline:
        if k % 2:
            probe.commands.publish(Float64MultiArray(data=[FORCE_N]))
        else:
            probe.joint_commands.publish(JointState(name=[JOINT], effort=[FORCE_N]))
        k += 1
        ros_harness.spin_until(executor, lambda: False, 0.02)
    probe.commands.publish(Float64MultiArray(data=[1.0, 2.0]))
    probe.joint_commands.publish(JointState(name=['other'], effort=[1.0]))
    assert ros_harness.spin_until(
        executor, lambda: probe.diag('command_watchdog_trips') not in (None, '0')
        and probe.diag('command_malformed') == '2', TIMEOUT_S), probe.diag('command_malformed')
    stopped = msg_to_block(probe.blocks[-1]).end_index
    assert ros_harness.spin_until(
        executor, lambda: msg_to_block(probe.blocks[-1]).end_index > stopped + 4000, TIMEOUT_S)
    index, coil = probe.channel('coil_setpoint_V')
    _, position = probe.channel('position_m')
    during = (index > start) & (index < stopped) & (coil != 0.0)
    assert during.sum() > 1000
    balance = load_balance()
    expected = np.array([coil_setpoint_for_force_V(balance, FORCE_N, p)
                         for p in position[during][::50]])
    ratio = np.median(coil[during][::50] / expected)
    assert 0.95 < ratio < 1.05, ratio          # the motor and amplifier inverted, both nodes
    assert np.all(coil[index > stopped + 2000] == 0.0)      # back to 0 N after the watchdog
