"""
The weighing node over real DDS, fed by the simulated balance in closed loop.

The test process runs a :class:`ClosedLoopSimulator` (20 kHz, the position controller in the
sample loop), publishes its output as measurement blocks with their description, and calls
the node's services: zero, adjust with 100 g, weigh 50 g, tare, and the refusals.
"""

import math

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import rclpy
from rclpy.parameter import Parameter
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import Trigger

from emfc_ros.core.blocks import Channel, StreamDescription
from emfc_ros.core.control.loop_config import LoopConfig
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.paths import config_file
from emfc_ros.core.sim.closed_loop import ClosedLoopSimulator
from emfc_ros.core.sim.resolution import simulator_resolution
from emfc_ros.core.sim.simulator import Simulator
from emfc_ros.nodes.convert import (BLOCK_QOS, block_to_msg, BlockMessageBuilder,
                                    description_to_msg, LATCHED_QOS)
from emfc_ros.nodes.weighing import WeighingNode
import ros_harness
from ros_harness import scaled

TIMEOUT_S = scaled(30.0)
RATE_HZ = 20000.0
BLOCK = 1000
LOOP = LoopConfig()     # the default in-loop design: 10 kHz, 130 Hz, no notch
SOURCE = 'test_closed_loop'


class Balance:
    """The simulated balance in closed loop, published block by block; collects the output."""

    def __init__(self, context, executor, weighing, seed, namespace='/'):
        params = BalanceParameters.load_yaml(config_file('balance_default.yaml'))
        self.sim = ClosedLoopSimulator(Simulator(params, RATE_HZ, seed=seed,
                                                 reference_channels=False), LOOP)
        self.resolution = simulator_resolution(params, current_channel=self.sim.current_channel)
        self.executor = executor
        self.weighing = weighing
        self.node = rclpy.create_node('balance_stream', namespace=namespace, context=context)
        self.pub = self.node.create_publisher(Float64MultiArray, 'measurements', BLOCK_QOS)
        self.pub_desc = self.node.create_publisher(String, 'measurements/description',
                                                   LATCHED_QOS)
        self.builder = BlockMessageBuilder()
        self.sent = 0
        self.readings = []       # non-error statuses of ~/reading, as dicts
        self.errors = []         # ERROR statuses of ~/reading
        self.dynamic = []        # statuses of ~/dynamic, as dicts
        self.diagnostics = []
        self.node.create_subscription(DiagnosticArray, 'weighing/reading', self._on_reading,
                                      1000)
        self.node.create_subscription(DiagnosticArray, 'weighing/dynamic', self._on_dynamic,
                                      10000)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics,
                                      100)
        self.clients = {name: self.node.create_client(Trigger, f'weighing/{name}')
                        for name in ('zero', 'tare', 'adjust', 'clear_tare')}
        executor.add_node(self.node)
        assert self.spin(lambda: self.pub.get_subscription_count() >= 1
                         and self.pub_desc.get_subscription_count() >= 1
                         and self.weighing.count_subscribers('measurements') >= 1
                         and self.node.count_publishers('weighing/reading') >= 1
                         and all(c.service_is_ready() for c in self.clients.values()))

    def spin(self, predicate, timeout_s=TIMEOUT_S):
        return ros_harness.spin_until(self.executor, predicate, timeout_s)

    # -- input -------------------------------------------------------------------------------

    def describe(self, drop=(), resolution=True):
        channels = tuple(Channel(n, u) for n, u in zip(self.sim.channel_names,
                                                       self.sim.channel_units)
                         if n not in drop)
        extra = {'resolution': self.resolution} if resolution else {}
        self.pub_desc.publish(description_to_msg(StreamDescription(
            'measurements', RATE_HZ, BLOCK, channels, source=SOURCE, extra=extra)))

    def send(self, msg):
        self.pub.publish(msg)
        self.sent += 1
        assert self.spin(lambda: self.weighing.blocks_received >= self.sent)

    def run(self, seconds, publish=True):
        """Simulate (and publish) whole blocks; wait until the readings have arrived."""
        for _ in range(int(round(seconds * RATE_HZ / BLOCK))):
            first = self.sim.sample_index
            out = self.sim.step_block(np.zeros((2, BLOCK)))
            if publish:
                self.send(self.builder.build(first, RATE_HZ, 0, out))
        self.settle()

    def block(self):
        """The next simulated block as a message of its own."""
        first = self.sim.sample_index
        return first, self.sim.step_block(np.zeros((2, BLOCK)))

    def settle(self):
        counts = self.weighing._counts
        assert self.spin(lambda: len(self.readings) >= counts['readings']
                         and len(self.dynamic) >= counts['dynamic_readings'])

    # -- output ------------------------------------------------------------------------------

    @staticmethod
    def _doc(msg, name):
        assert len(msg.status) == 1 and msg.status[0].name == name
        status = msg.status[0]
        doc = {kv.key: kv.value for kv in status.values}
        doc.update(level=status.level, message=status.message, hardware_id=status.hardware_id,
                   stamp_ns=msg.header.stamp.sec * 10 ** 9 + msg.header.stamp.nanosec)
        return doc

    def _on_reading(self, msg):
        doc = self._doc(msg, 'mass')
        (self.errors if doc['level'] == DiagnosticStatus.ERROR else self.readings).append(doc)

    def _on_dynamic(self, msg):
        self.dynamic.append(self._doc(msg, 'dynamic_mass'))

    def _on_diagnostics(self, msg):
        for status in msg.status:
            if status.hardware_id == self.weighing.get_fully_qualified_name():
                values = {kv.key: kv.value for kv in status.values}
                self.diagnostics.append((status.level, status.message, values))

    def last(self):
        return self.readings[-1]

    def call(self, name):
        future = self.clients[name].call_async(Trigger.Request())
        assert self.spin(future.done)
        return future.result()

    def wait_diagnostic(self, predicate, timeout_s=scaled(5.0)):
        """Wait for a diagnostics status of the weighing node that satisfies ``predicate``."""
        seen = len(self.diagnostics)
        assert self.spin(lambda: any(predicate(d) for d in self.diagnostics[seen:]),
                         timeout_s), self.diagnostics[-3:]
        return next(d for d in self.diagnostics[seen:] if predicate(d))


def mass(doc):
    return float(doc['mass_kg'])


def start(context, executor, seed, **parameters):
    weighing = WeighingNode(context=context, parameter_overrides=[
        Parameter(k, value=v) for k, v in parameters.items()])
    executor.add_node(weighing)
    balance = Balance(context, executor, weighing, seed)
    balance.describe()
    assert balance.spin(lambda: weighing._rows is not None)
    return weighing, balance


def readings_after(balance, sample_index):
    return [r for r in balance.readings if int(r['sample_index']) >= sample_index]


def test_zero_adjust_weigh_and_tare(executor, ros_context):
    # stale_timeout_s: the service calls follow the last block at once; be generous on a
    # loaded machine.
    weighing, balance = start(ros_context, executor, seed=11, stale_timeout_s=30.0)

    balance.run(0.3)
    assert balance.readings and balance.last()['stable'] == 'false'
    refused = balance.call('zero')
    assert not refused.success and 'not full' in refused.message, refused.message

    balance.run(1.5)
    empty = balance.last()
    # before the first zero: steady, but uncalibrated and never stable (the nominal
    # calibration reads the empty pan as about -127 g)
    assert empty['steady'] == 'true' and empty['calibrated'] == 'false'
    assert empty['stable'] == 'false' and empty['level'] == DiagnosticStatus.WARN
    assert empty['message'].startswith('uncalibrated'), empty['message']
    assert -0.13 < mass(empty) < -0.12
    assert all(r['stable'] == 'false' for r in balance.readings)
    assert balance.dynamic and all(d['settled'] == 'false' and d['calibrated'] == 'false'
                                   for d in balance.dynamic)
    for action in ('tare', 'adjust'):
        assert weighing.set_parameters([Parameter('reference_mass_kg', value=0.1)])[0] \
            .successful
        refused = balance.call(action)
        assert not refused.success and 'not zeroed' in refused.message, refused.message
    assert weighing.set_parameters([Parameter('reference_mass_kg', value=0.0)])[0].successful
    answer = balance.call('zero')
    assert answer.success, answer.message
    balance.run(0.2)
    assert abs(mass(balance.last())) < 1e-6
    assert balance.last()['stable'] == 'true' and balance.last()['calibrated'] == 'true'

    refused = balance.call('adjust')
    assert not refused.success and 'reference_mass_kg' in refused.message, refused.message

    # The 100 g reference weight goes on: unstable readings, zero refused.
    step = balance.sim.sample_index
    balance.sim.set_load(0.1)
    balance.run(0.2)
    after = readings_after(balance, step)
    assert after and all(r['stable'] == 'false' and r['level'] == DiagnosticStatus.WARN
                         and r['message'] == 'unstable' for r in after)
    refused = balance.call('zero')
    assert not refused.success and 'not stable' in refused.message, refused.message

    balance.run(1.6)
    assert balance.last()['stable'] == 'true'
    assert weighing.set_parameters([Parameter('reference_mass_kg', value=0.1)])[0].successful
    answer = balance.call('adjust')
    assert answer.success, answer.message
    balance.run(0.1)
    assert abs(mass(balance.last()) - 0.1) < 1e-6

    # The reference weight comes off, 50 g go on.
    step = balance.sim.sample_index
    balance.sim.set_load(0.05)
    balance.run(0.3)
    after = readings_after(balance, step)
    assert after and all(r['stable'] == 'false' for r in after)
    # The dynamic estimate is there long before the moving average (docs/weighing.md 5).
    assert abs(mass(balance.dynamic[-1]) - 0.05) < 1e-6, balance.dynamic[-1]
    assert abs(mass(balance.last()) - 0.05) > 1e-6
    # every dynamic reading is placed on the sample clock: every 0.01 s (200 samples),
    # stamped with its sample; not settled right after the step, settled once there
    dynamic = [d for d in balance.dynamic if int(d['sample_index']) >= step]
    for d in dynamic:
        index = int(d['sample_index'])
        assert (index + 1) % 200 == 0 and d['stamp_ns'] == index * 50_000
    assert dynamic[0]['settled'] == 'false' and dynamic[0]['level'] == DiagnosticStatus.WARN
    assert dynamic[-1]['settled'] == 'true' and dynamic[-1]['level'] == DiagnosticStatus.OK
    settled = [d for d in dynamic if d['settled'] == 'true']
    assert all(abs(mass(d) - 0.05) < 1e-6 for d in settled)
    assert all(0.0 < float(d['standard_uncertainty_kg']) < 1e-6 for d in settled)

    balance.run(1.5)
    reading = balance.last()
    assert reading['stable'] == 'true' and reading['level'] == DiagnosticStatus.OK
    assert reading['message'] == 'stable' and reading['unit'] == 'kg'
    assert abs(mass(reading) - 0.05) < 1e-6, reading
    assert 0.0 < float(reading['standard_uncertainty_kg']) < 1e-6, reading
    assert int(reading['n_samples']) == 20000 and float(reading['averaging_time_s']) == 1.0
    assert float(reading['tare_kg']) == 0.0 and reading['gross_mass_kg'] == reading['mass_kg']
    assert reading['hardware_id'] == SOURCE
    # stamp: the last sample of the window on the sample clock (start_time_ns = 0)
    index = int(reading['sample_index'])
    assert (index + 1) % 2000 == 0
    assert reading['stamp_ns'] == index * 50_000
    assert abs(mass(balance.dynamic[-1]) - 0.05) < 1e-6
    # released one reading period after its last sample: the next dynamic readings are in
    assert int(balance.dynamic[-1]['sample_index']) > index

    answer = balance.call('tare')
    assert answer.success, answer.message
    balance.run(0.2)
    tared = balance.last()
    assert tared['stable'] == 'true' and abs(mass(tared)) < 1e-6, tared
    assert abs(float(tared['tare_kg']) - 0.05) < 1e-6
    assert abs(float(tared['gross_mass_kg']) - 0.05) < 1e-6

    answer = balance.call('clear_tare')
    assert answer.success, answer.message
    balance.run(0.1)
    assert abs(mass(balance.last()) - 0.05) < 1e-6 and float(balance.last()['tare_kg']) == 0.0
    # no ERROR reading but, perhaps, 'waiting for measurements/description' at the start
    assert all('waiting for' in e['message'] for e in balance.errors), balance.errors


def test_bad_input_missing_channel_and_recovery(executor, ros_context):
    weighing, balance = start(ros_context, executor, seed=12, stale_timeout_s=30.0)
    balance.run(0.2)
    good = len(balance.readings)
    assert good >= 1

    # A malformed block, one with the wrong channel count, one with a NaN current.
    broken = Float64MultiArray()
    broken.data = [1.0, 2.0, 3.0]
    balance.send(broken)
    first, out = balance.block()
    balance.send(block_to_msg(first, RATE_HZ, 0, out[:5]))
    first, out = balance.block()
    out[balance.sim.channel_names.index('coil_current_precise_A'), 10] = math.nan
    balance.send(block_to_msg(first, RATE_HZ, 0, out))
    assert weighing._counts['bad_blocks'] == 3
    # A lost block: a gap in the sample indices restarts the window.
    balance.run(0.05, publish=False)
    balance.run(0.2)
    after = balance.readings[good:]
    assert after and all(r['stable'] == 'false' for r in after)
    assert int(after[0]['n_samples']) < 20000
    level, _, values = balance.wait_diagnostic(lambda d: int(d[2]['bad_blocks']) == 3)
    assert level == DiagnosticStatus.WARN
    # the tracker saw two gaps (the undecodable block and the lost one), the filter one
    assert int(values['stream_gaps']) == 2 and int(values['window_resets']) == 1
    assert 'non-finite' in values['last_error']

    # A description without the current channel's resolution: weighing is refused, saying
    # what to set (a reading without it could be confidently wrong).
    seen = len(balance.errors)
    balance.describe(resolution=False)
    assert balance.spin(lambda: len(balance.errors) > seen)
    text = balance.errors[-1]['message']
    assert "resolution of 'coil_current_precise_A' is unknown" in text, text
    assert 'current_resolution_A' in text

    # A description without the current channel: reported, blocks ignored, no crash.
    seen = len(balance.errors)
    balance.describe(drop=('coil_current_precise_A',))
    assert balance.spin(lambda: len(balance.errors) > seen)
    assert 'coil_current_precise_A' in balance.errors[-1]['message']
    level, message, _ = balance.wait_diagnostic(lambda d: d[0] == DiagnosticStatus.ERROR)
    assert 'coil_current_precise_A' in message
    count = len(balance.readings)
    balance.run(0.2)
    assert len(balance.readings) == count and weighing._counts['ignored_blocks'] == 4
    refused = balance.call('zero')
    assert not refused.success and 'coil_current_precise_A' in refused.message

    # The correct description again: weighing resumes.
    balance.describe()
    assert balance.spin(lambda: weighing._rows is not None)
    balance.run(0.2)
    assert len(balance.readings) > count
    balance.wait_diagnostic(lambda d: d[0] != DiagnosticStatus.ERROR)


def test_bad_balance_file_keeps_running(executor, ros_context, tmp_path):
    weighing = WeighingNode(context=ros_context, namespace='broken', parameter_overrides=[
        Parameter('balance_file', value=str(tmp_path / 'missing.yaml'))])
    executor.add_node(weighing)
    probe = rclpy.create_node('probe', context=ros_context)
    seen = []
    probe.create_subscription(DiagnosticArray, '/diagnostics', lambda m: seen.extend(
        s for s in m.status if s.hardware_id == '/broken/weighing'), 10)
    executor.add_node(probe)
    assert ros_harness.spin_until(executor, lambda: seen, 5.0)
    assert seen[-1].level == DiagnosticStatus.ERROR and 'missing.yaml' in seen[-1].message
