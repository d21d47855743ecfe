"""
The daq_bridge node on its daqmx back-end for a minute, through NI's own ``nidaqmx`` client.

Three processes: ``emfc-daqmx-emulator`` (NI's gRPC service on loopback, the simulated
balance on its terminals), the daq_bridge node with the shipped ``config/daq_bridge_daqmx.yaml``
pointed at it, and this test, which subscribes to ``measurements`` over DDS and checks every
block's sample index for 60 s of the device clock at 10 kHz and at 100 kHz: no gap, one
epoch, no fault, and the bridge's own gap counter at 0.
"""

import json
from pathlib import Path
import sys

import pytest
import rclpy
from std_msgs.msg import Float64MultiArray, String

from emfc_ros.cli.daqmx_process import DaqmxEmulatorProcess
from emfc_ros.nodes.convert import BLOCK_QOS, LATCHED_QOS
import ros_harness
from ros_harness import scaled

REPO = Path(__file__).resolve().parents[2]
SECONDS = 60.0


@pytest.fixture
def device():
    emulator = DaqmxEmulatorProcess(seed=5)
    try:
        yield emulator
    finally:
        assert emulator.stop() == 0


@pytest.mark.slow(seconds=60)
@pytest.mark.parametrize('rate', [10000.0, 100000.0])
def test_the_bridge_streams_a_minute_through_nidaqmx_without_a_gap(rate, device, executor,
                                                                   ros_context, processes):
    block = int(rate / 10)
    bridge = processes.start([
        sys.executable, '-m', 'emfc_ros.nodes.daq_bridge', '--ros-args',
        '--params-file', str(REPO / 'config' / 'daq_bridge_daqmx.yaml'),
        '-p', f'daqmx.grpc_address:={device.host}:{device.port}',
        '-p', f'sample_rate_Hz:={rate}', '-p', f'block_size:={block}',
        '-p', 'publish_groups:=false', '-p', 'state_rate_Hz:=10.0',
        '-p', 'publisher_depth:=1000',
        # the device starts once this probe's subscription has matched, so block 0 is seen
        '-p', 'min_subscribers:=1'], cwd=REPO)
    node = rclpy.create_node('daqmx_probe', context=ros_context)
    executor.add_node(node)
    blocks = []
    descriptions = []
    node.create_subscription(
        Float64MultiArray, 'measurements',
        lambda m: blocks.append((int(m.data[0]), int(m.data[2]), m.layout.dim[1].size)),
        BLOCK_QOS)
    node.create_subscription(String, 'measurements/description',
                             lambda m: descriptions.append(json.loads(m.data)), LATCHED_QOS)

    def samples():
        return sum(n for _, _, n in blocks)

    assert ros_harness.spin_until(executor, lambda: blocks and descriptions, scaled(60.0)), \
        bridge.output()
    assert ros_harness.spin_until(executor, lambda: samples() >= SECONDS * rate,
                                  scaled(SECONDS + 60.0)), (samples(), bridge.output())
    firsts = [f for f, _, _ in blocks]
    assert firsts[0] == 0, firsts[:3]
    gaps = [(a, b) for (a, _, n), (b, _, _) in zip(blocks, blocks[1:]) if b != a + n]
    assert gaps == [], gaps[:5]
    assert len({e for _, e, _ in blocks}) == 1
    extra = descriptions[-1]['extra']
    assert extra['backend'] == 'daqmx' and extra['faults'] == []
    assert bridge.alive(), bridge.output()
    assert bridge.stop() in (0, -2), bridge.output()
