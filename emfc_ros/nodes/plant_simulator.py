"""
The plant_simulator node: the simulated balance, a drop-in for "bridge plus real balance".

Topics (relative to the node namespace):

- ``excitation`` (``std_msgs/Float64MultiArray``, in): setpoint-voltage blocks [V] (coil,
  load changer) in the block convention; ``excitation/consumed`` (``std_msgs/UInt64``, out):
  samples consumed so far, for a consumer-paced signal generator; ``excitation/ready``
  (``std_msgs/String``, out, latched): JSON ``{node, ready, waiting}``, ready once the
  excitation is subscribed and would be simulated (a generator's start gate waits for it).
- ``measurements`` (out): every simulated channel in one block stream, on the excitation's
  sample clock when owning time; ``measurements/position``, ``measurements/current`` and
  ``measurements/force`` (out): the same samples grouped as named streams. Each has a
  latched ``<topic>/description``; its ``extra`` states each channel's quantisation step and
  input noise (``resolution``), the load on the pan (``load_mass_kg``) and every run-time
  change with the sample it took effect at (``load_changes``; parameter ``load_mass_kg`` or
  ``load_schedule``).
- ``joint_states`` (``sensor_msgs/JointState``, out): joint ``lever``: position [m],
  velocity [m/s], effort = coil force [N], at ``state_rate_Hz``.
- ``joint_commands`` (``sensor_msgs/JointState``, in; ros2_control topic-based hardware) and
  ``commands`` (``std_msgs/Float64MultiArray``, in; forward_command_controller): an effort
  command, the coil force [N] added to the excitation; held until the next command, zeroed
  by a watchdog after ``command_timeout_s``. It takes effect from the next block on. In
  ``lockstep`` mode the command is the total coil force instead (below).
- ``/clock`` (``rosgraph_msgs/Clock``, out) when ``time_mode`` is ``owner`` or ``lockstep``;
  remap it (``-r /clock:=clock``: into the namespace) to run two simulated balances on one
  domain. A second publisher on the same clock topic is refused: the plant is not ready
  before the start and stops simulating during a run, with an error naming the other node.
- ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``, out, 1 Hz).

Service (``std_srvs/Trigger``, private): ``~/reset`` (back to the operating point; simulated
time and sample indices go on).

Time modes: ``owner`` (the simulator owns time: each excitation block is simulated as soon
as it arrives, measurement blocks carry the excitation's sample indices, ``/clock`` advances
by the simulated time: lockstep with the input, faster than real time), ``wall`` (paced
to the wall clock: the simulator runs continuously on its own sample clock, consuming queued
excitation and the safe value 0 V when there is none, which is counted as an underrun) and
``lockstep`` (lockstep with an external controller, see ``docs/ros_control.md``): the
simulator owns time and advances one controller period, ``N = sample_rate_Hz /
state_rate_Hz`` samples, per effort command. It publishes the joint state at ``t_k`` (sample
``k N``, stamped with simulated time) and ``/clock``, waits for the command answering it
(matched by header stamp on ``joint_commands`` with ``lockstep_match: stamp``; the next one
otherwise and always on ``commands``), converts the commanded TOTAL coil force to a coil
setpoint at the measured position, simulates samples ``k N + 1 .. (k + 1) N`` with it (zero-order
hold; the DAC is written one simulator sample after the ADC sample it answers) and
publishes that measurement block and the state at ``t_(k+1)``. ``command_delay_periods: 1``
applies each command one period later. Excitation blocks received in this mode are queued
and added sample by sample (coil: volts on top of the commanded setpoint). The first state
(sample 0, the lever held by the hold-point setpoint, so its effort is the holding force) is
published once ``joint_states`` has a subscriber; the current state is re-published every
``command_timeout_s`` of wall time while no command answers it.
"""

from __future__ import annotations

import time
from typing import Dict, List, Optional

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.logging import get_logger
from rclpy.node import Node
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String, UInt64
from std_srvs.srv import Trigger

from emfc_ros.core.errors import BlockError
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.sim.plant_config import load_balance, make_simulator, plant_config
from emfc_ros.core.sim.plant_events import (
    Acknowledgement, ClockTick, DescriptionChanged, JointStates, LogLine, MeasurementBlock)
from emfc_ros.core.sim.plant_parameters import (  # noqa: F401 (the table of --help)
    HELP_EXTRA, LIMITS, PARAMETERS, READ_ONLY, STARTUP_KEYS)
from emfc_ros.core.sim.plant_session import ACK_REPEAT_S, PlantSession
from emfc_ros.core.sim.simulator import Simulator
from emfc_ros.core.start_gate import readiness_text
from emfc_ros.nodes.convert import (
    BLOCK_QOS, BlockMessageBuilder, CONTROL_QOS, description_to_msg, LATCHED_QOS, msg_to_block,
    node_diagnostics, steady_clock, subscribe_device_inputs, subscribe_excitation)
from emfc_ros.nodes.flow_control import AckFlowControl
from emfc_ros.nodes.params import declare_table, refuse_unknown
from emfc_ros.nodes.plant_io import (
    clock_conflict, clock_msg, CLOCK_QOS, joint_state_msgs, LEVELS, outputs_matched, STATE_QOS)
from emfc_ros.nodes.spin import node_main


class PlantSimulatorNode(Node):
    """
    Simulate the balance between excitation blocks in and measurement blocks out.

    The wiring of a :class:`~emfc_ros.core.sim.plant_session.PlantSession`: parameters to its
    configuration, messages to its calls (from the executor), its events to messages.

    Parameters
    ----------
    **kwargs
        Passed to :class:`rclpy.node.Node`.
    """

    def __init__(self, **kwargs) -> None:
        super().__init__('plant_simulator', allow_undeclared_parameters=True,
                         automatically_declare_parameters_from_overrides=True, **kwargs)
        refused = declare_table(self, PARAMETERS, LIMITS, READ_ONLY)
        refused += refuse_unknown(self, [*PARAMETERS, 'balance.'])
        cfg = plant_config(self._param)
        sim = None
        if not (cfg.errors and cfg.errors[0].startswith('control configuration refused')):
            try:
                sim = self._make_simulator()
                # Compile (or load) the numba kernel now, on a throwaway copy and before any
                # topic exists, so that the first excitation block is not kept waiting.
                self._make_simulator(log=False).step_block(np.zeros((2, 1)))
            except (ValueError, OSError) as exc:
                # Keep running: report the reason on /diagnostics (at once, below), accept a
                # corrected balance_file or balance.*.
                sim = None
                cfg.errors.insert(0, f'balance configuration refused: {exc}')
        for reason in cfg.errors:
            self.get_logger().error(reason)
        if refused:     # does not simulate with values nobody asked for (logged already)
            sim = None
        self._session = s = PlantSession(cfg, sim, time.monotonic(), error='; '.join(
            refused) + '; restart the node with valid values' if refused else '')
        self._pub = {'measurements': self.create_publisher(Float64MultiArray, 'measurements',
                                                           BLOCK_QOS)}
        self._pub_desc = {'measurements': self.create_publisher(
            String, 'measurements/description', LATCHED_QOS)}
        for group in s.groups:
            topic = f'measurements/{group}'
            self._pub[topic] = self.create_publisher(Float64MultiArray, topic, BLOCK_QOS)
            self._pub_desc[topic] = self.create_publisher(String, f'{topic}/description',
                                                          LATCHED_QOS)
        self._builders: Dict[str, BlockMessageBuilder] = {}
        self._pub_ack = self.create_publisher(UInt64, 'excitation/consumed', CONTROL_QOS)
        self._pub_state = self.create_publisher(JointState, 'joint_states', STATE_QOS)
        # One /clock per block, as deep as the blocks: a recorder that falls behind for a
        # moment must not lose ticks (a writer's KEEP_LAST history drops them silently).
        self._pub_clock = self.create_publisher(Clock, '/clock', CLOCK_QOS) \
            if s.mode in ('owner', 'lockstep') else None
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._pub_ready = self.create_publisher(String, 'excitation/ready', LATCHED_QOS)
        self._readiness = ''
        # Owner mode owns time: a subscriber that was not scheduled for a moment slows the
        # simulation instead of losing blocks (flow_control; no waits in other modes).
        self._flow = AckFlowControl(self._pub['measurements'] if s.mode == 'owner' else None)
        self._min_subscribers = cfg.min_subscribers
        self._excitation_timer = None
        self._listeners_since: Optional[float] = None
        hold = s.mode == 'owner' and self._min_subscribers > 0
        subscribe_device_inputs(self, None if hold else self._on_excitation,
                                self._on_joint_command, self._on_array_command)
        if hold:
            # Steady timer: the excitation opens once the measurements are listened to.
            self.get_logger().info(f'waiting for {self._min_subscribers} subscription(s) to '
                                   'measurements before subscribing to the excitation')
            self._excitation_timer = self.create_timer(0.05, self._open_excitation,
                                                       clock=steady_clock())
        self.create_service(Trigger, '~/reset', self._srv_reset)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._publish_descriptions()
        self.create_timer(1.0, self._publish_diagnostics, clock=steady_clock())
        # Steady timer: acknowledgements again, the wall clock's steps, the lockstep start.
        period = {'wall': min(0.02, max(0.001, 0.5 * cfg.block_size / s.rate)),
                  'lockstep': 0.005}.get(s.mode, ACK_REPEAT_S)
        self.create_timer(period, self._tick, clock=steady_clock())
        s.start_s = time.monotonic()
        if s.error:
            self._publish_diagnostics()     # the status says why at start, not after 1 s
        self._announce_readiness()

    def _param(self, name: str):
        return self.get_parameter(name).value

    def _make_simulator(self, overrides: Dict[str, object] = None, log: bool = True):
        flat = {name: p.value for name, p in self.get_parameters_by_prefix('balance').items()}
        s = getattr(self, '_session', None)
        sim, line = make_simulator(
            load_balance(self._param('balance_file'), flat, overrides), self._param,
            s.load_kg if s else self._param('load_mass_kg'),
            s.coupled if s else self._param('load_changer_coupled'))
        if line and log:
            self.get_logger().info(line)
        return sim

    def _on_set_parameters(self, params: List[Parameter]) -> SetParametersResult:
        values = {p.name: p.value for p in params}
        if any(n == 'balance_file' or n.startswith('balance.') for n in values):
            try:
                candidate = self._make_simulator(values)
            except (ValueError, OSError) as exc:
                return SetParametersResult(successful=False,
                                           reason=f'balance configuration refused: {exc}')
            self._emit(self._session.replace_simulator(candidate))
        reason, events = self._session.set_parameters(values)
        self._emit(events)
        return SetParametersResult(successful=not reason, reason=reason)

    # -- the session's inputs and outputs -----------------------------------------------

    def _on_excitation(self, msg: Float64MultiArray) -> None:
        now = time.monotonic()
        try:
            block = msg_to_block(msg, expected_channels=2)
        except BlockError as exc:
            self._emit(self._session.refuse_excitation(str(exc), now))
            return
        self._emit(self._session.on_excitation(block, now))

    def _on_joint_command(self, msg: JointState) -> None:
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        self._emit(self._session.on_joint_command(msg.name, msg.effort, stamp,
                                                  time.monotonic()))

    def _on_array_command(self, msg: Float64MultiArray) -> None:
        self._emit(self._session.on_array_command(msg.data, time.monotonic()))

    def _tick(self) -> None:
        s = self._session
        subscribed = s.mode == 'lockstep' and not s.lock.started and \
            self._pub_state.get_subscription_count() >= 1
        self._emit(s.tick(time.monotonic(), self.get_clock().now().nanoseconds, subscribed))

    def _emit(self, events: list) -> None:
        """Publish what the session returned, in its order."""
        for e in events:
            if isinstance(e, MeasurementBlock):
                for topic, pub in self._pub.items():
                    rows = e.samples if topic == 'measurements' else \
                        e.samples[list(self._session.groups[topic.split('/', 1)[1]])]
                    builder = self._builders.setdefault(topic, BlockMessageBuilder())
                    pub.publish(builder.build(e.first_index, self._session.rate,
                                              self._session.epoch, rows))
                self._flow.published(e.samples.nbytes)
            elif isinstance(e, JointStates):
                for msg in joint_state_msgs(e):
                    self._pub_state.publish(msg)
            elif isinstance(e, ClockTick) and self._pub_clock is not None:
                self._pub_clock.publish(clock_msg(e.stamp_ns))
            elif isinstance(e, Acknowledgement):
                self._pub_ack.publish(UInt64(data=int(e.index)))
            elif isinstance(e, DescriptionChanged):
                if e.scheduled_load_kg is not None:   # the parameter shows the load on the pan
                    self.set_parameters([Parameter('load_mass_kg', value=e.scheduled_load_kg)])
                self._publish_descriptions()
            elif isinstance(e, LogLine):
                getattr(self.get_logger(), e.level)(e.text)

    def _publish_descriptions(self) -> None:
        for topic, d in self._session.descriptions(self.get_fully_qualified_name()).items():
            self._pub_desc[topic].publish(description_to_msg(d))

    def _srv_reset(self, request: Trigger.Request, response: Trigger.Response):
        response.success, response.message = self._session.reset()
        return response

    def published_counts(self) -> Dict[str, Dict[str, int]]:
        """
        Messages published per stream, for an in-process supervisor's accounting.

        Returns
        -------
        dict
            Relative topic name (``/clock`` absolute) to ``published`` and, for
            ``joint_states``, ``decimated`` (left out by ``max_state_wall_rate_Hz``) [count].
        """
        return self._session.published_counts(list(self._pub), self._pub_clock is not None)

    # -- the graph: start gate, a second clock, diagnostics -----------------------------

    def _open_excitation(self) -> None:
        """Subscribe to the excitation once enough subscriptions to measurements matched."""
        matched = self._pub['measurements'].get_subscription_count()
        if matched < self._min_subscribers:
            self._listeners_since = None
            return
        # Every subscription the graph lists on an output (a recorder's /clock, joint_states)
        # matched too, so that the first block's messages reach it (for a few seconds at most).
        now = time.monotonic()
        self._listeners_since = self._listeners_since or now
        pubs = [*self._pub.values(), self._pub_state, self._pub_clock]
        matched_all, warning = outputs_matched(self, pubs, now - self._listeners_since)
        if warning:
            self.get_logger().warning(warning)
        if not matched_all:
            return
        self._check_clock()
        self._excitation_timer.cancel()
        self.destroy_timer(self._excitation_timer)
        self._excitation_timer = None
        subscribe_excitation(self, self._on_excitation)
        self.get_logger().info(f'{matched} subscription(s) to measurements matched: '
                               'subscribed to the excitation')
        self._announce_readiness()

    def _check_clock(self) -> None:
        """Refuse a second publisher of our clock topic (two instances' simulated time)."""
        conflict = '' if self._pub_clock is None or self._session.clock_conflict else \
            clock_conflict(self, self._pub_clock)
        if not conflict:
            return
        self._session.fail(conflict, clock_conflict=True)
        self.get_logger().error(conflict)
        self._announce_readiness()

    def _announce_readiness(self) -> None:
        """Publish excitation/ready when what it says changes."""
        pub = self._pub['measurements']
        ready, waiting = self._session.readiness(self._excitation_timer is not None,
                                                 pub.topic_name, pub.get_subscription_count())
        text = readiness_text(self.get_fully_qualified_name(), ready, waiting)
        if text != self._readiness:
            self._readiness = text
            self._pub_ready.publish(String(data=text))

    def _publish_diagnostics(self) -> None:
        self._check_clock()
        self._announce_readiness()
        level, message, values = self._session.diagnostics(
            time.monotonic(), self._flow.timeouts, self._excitation_timer is not None)
        values.update({'excitation_subscribed': self._excitation_timer is None,
                       **self._flow.counters()})
        self._pub_diag.publish(node_diagnostics(self, 'simulation', LEVELS[level], message,
                                                values))


def compile_kernel() -> None:
    """
    Compile the simulator's numba kernel, or load it from numba's cache, before the node exists.

    The first start after an install compiles for about 12-15 s (``docs/simulator.md``); the
    node then appears ready to serve, and Ctrl-C during the compilation ends the process.
    One line says so, through the ROS logging system to the console: the node does not
    exist yet, so there is no node logger and the line cannot reach ``/rosout``.
    """
    get_logger('plant_simulator').info(
        'preparing the simulator kernel (numba: loaded from its cache, or compiled in about '
        '15 s on the first start after an install)')
    Simulator(BalanceParameters(), float(PARAMETERS['sample_rate_Hz'][0])).step_block(
        np.zeros((2, 1)))


main = node_main(PlantSimulatorNode, 'plant_simulator', warm_up=compile_kernel)


if __name__ == '__main__':
    raise SystemExit(main())
