"""
The daq_bridge node: the only node that talks to the DAQ/FPGA device (or its stand-ins).

Same topics in and out as the plant simulator, so experiments, recorders and controllers
run unchanged on hardware. Topics (relative to the node namespace):

- ``excitation`` (``std_msgs/Float64MultiArray``, in): setpoint-voltage blocks [V], one row
  per device output (``coil``, ``load_changer``), block convention. Clamped to the output
  limits (counted) and streamed to the device ``excitation_lead_s`` ahead of its sample
  clock: excitation sample ``k`` of an epoch is applied at device sample ``k + offset``, the
  offset fixed when the epoch's first block arrives and published in the measurements
  description (``extra.excitation_offset_samples``). ``excitation/consumed``
  (``std_msgs/UInt64``, out): excitation samples the device has applied.
  ``excitation/ready`` (``std_msgs/String``, out, latched): JSON ``{node, ready, waiting}``,
  ready while the device runs with the excitation subscribed (a generator's start gate
  waits for it); otherwise what the bridge waits for.
- ``measurements`` (out): the device's input channels, one block per device frame, with the
  device's exact sample indices (never a block that spans a gap); latched
  ``measurements/description`` with names and units from the device configuration;
  ``measurements/position``, ``current`` and ``force`` (out): grouped by unit.
- ``joint_states`` (out), ``joint_commands`` and ``commands`` (in): the controller interface;
  an effort command [N] becomes a coil setpoint through the balance's motor and amplifier
  characteristics and is added to the coil output; zeroed after ``command_timeout_s``.
- ``/diagnostics`` (out): back-end health, excitation defects, clamping, watchdog, e-stop,
  arrival-to-publication latency.

Services (``std_srvs/Trigger``): ``~/start``, ``~/stop`` (acquisition), ``~/emergency_stop``
(outputs to their safe values at once, latched) and ``~/reset`` (release the e-stop). Nothing
that waits for the device runs on the executor: start, stop, the safe-output and generator
requests run in order in one worker thread (:class:`~emfc_ros.core.device.jobs.DeviceJobs`);
``~/start`` and ``~/stop`` answer at once that the request is under way, and ``~/status``
(``std_msgs/String``, latched JSON) says how it ended (``state``: ``starting``, ``running``,
``stopping``, ``stopped``, ``done`` (a replay published its last block) or ``error``, with
``error``, ``last_error``).
"""

from __future__ import annotations

import json
from typing import Any, Dict, List, Optional, Tuple

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import ParameterUninitializedException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String, UInt64
from std_srvs.srv import Trigger

from emfc_ros.core.blocks import Block, StreamDescription
from emfc_ros.core.device.bridge_session import BridgeSession
from emfc_ros.core.device.bridge_settings import (bridge_settings, generator_specs,
                                                  parameter_mapping, runtime_problem)
from emfc_ros.core.device.faults import Fault
from emfc_ros.core.device_contract import JOINT
from emfc_ros.core.errors import BlockError, ConfigError, EmfcError
from emfc_ros.core.start_gate import readiness_text
from emfc_ros.nodes.convert import (
    BLOCK_QOS, BlockMessageBuilder, CONTROL_QOS, description_to_msg, LATCHED_QOS, msg_to_block,
    node_diagnostics, steady_clock, subscribe_device_inputs, subscribe_excitation)
from emfc_ros.nodes.daq_bridge_parameters import (  # noqa: F401 (re-exported: --help, tests)
    FUNCGEN_FIELDS, funcgen_key, funcgen_limits, funcgen_table, LIMITS, PARAMETER_GROUPS,
    PARAMETERS, READ_ONLY, RUNTIME, STARTUP_KEYS)
from emfc_ros.nodes.params import declare_table, refuse_unknown
from emfc_ros.nodes.spin import node_main

STATE_QOS = QoSProfile(depth=1000)


class DaqBridgeNode(Node):
    """
    Bridge between ROS topics and a device back-end: wiring over a :class:`BridgeSession`.

    Parameters
    ----------
    **kwargs
        Passed to :class:`rclpy.node.Node` (for example ``parameter_overrides``).
    """

    def __init__(self, **kwargs) -> None:
        super().__init__('daq_bridge', allow_undeclared_parameters=True,
                         automatically_declare_parameters_from_overrides=True, **kwargs)
        refused = declare_table(self, PARAMETERS, LIMITS, READ_ONLY)
        funcgen = funcgen_table(self._param('outputs'))
        refused += declare_table(self, funcgen, funcgen_limits(funcgen))
        refused += refuse_unknown(self, [*PARAMETERS, *funcgen])
        self.session: Optional[BridgeSession] = None
        self._error = ''
        self._builders: Dict[str, BlockMessageBuilder] = {}
        self._pub: Dict[str, Any] = {}
        self._pub_desc: Dict[str, Any] = {}
        self._readiness = ''
        self._pub_status = self.create_publisher(String, '~/status', LATCHED_QOS)
        self._pub_ready = self.create_publisher(String, 'excitation/ready', LATCHED_QOS)
        self._pub_ack = self.create_publisher(UInt64, 'excitation/consumed', CONTROL_QOS)
        self._pub_state = self.create_publisher(JointState, 'joint_states', STATE_QOS)
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        try:
            if refused:     # no device started with values nobody asked for
                raise ConfigError('parameters', '; '.join(refused))
            settings = bridge_settings(parameter_mapping((*PARAMETERS, *funcgen), self._param))
            self.session = BridgeSession(settings, self, self.get_fully_qualified_name(),
                                         time_ns=lambda: self.get_clock().now().nanoseconds)
        except EmfcError as exc:       # the one error root: every refusal
            self._error = f'configuration refused: {exc}'
            self.get_logger().error(self._error)
        self._make_publishers()
        wanted = int(self._param('min_subscribers'))     # declare_table: 0 to 100
        hold = self.session is not None and bool(self._param('autostart')) and wanted > 0
        # Holding for listeners, the excitation is subscribed only once started, so that a
        # generator waiting for its consumer (min_subscribers) waits for the listeners too.
        subscribe_device_inputs(self, None if hold else self._on_excitation,
                                self._on_joint_command, self._on_array_command)
        for name, call in (('start', self._srv_start), ('stop', self._srv_stop),
                           ('emergency_stop', self._srv_estop), ('reset', self._srv_reset)):
            self.create_service(Trigger, f'~/{name}', call)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        period = min(60.0, max(0.05, float(self._param('diagnostics_period_s'))))
        self.create_timer(period, self.diagnostics_due, clock=steady_clock())
        if self.session is None:
            self.status_changed()
            return
        session = self.session
        self.create_timer(0.01, session.tick, clock=steady_clock())
        if session.backend.host_paced:
            period = min(0.02, max(0.001, 0.5 * session.config.block_size / session.rate))
            self.create_timer(period, session.poll_host_paced, clock=steady_clock())
        session.begin(bool(self._param('autostart')), wanted)
        if session.autostart_active:
            self.create_timer(0.05, lambda: session.autostart_tick(self._matched()),
                              clock=steady_clock())

    def _param(self, name: str):
        try:
            return self.get_parameter(name).value
        except ParameterUninitializedException:
            return None

    def _matched(self) -> int:
        pub = self._pub.get('measurements')
        return pub.get_subscription_count() if pub is not None else 0

    # -- BridgeOutputs: what the session publishes -----------------------------------------

    def publish_block(self, block: Block) -> None:
        """Publish a measurement block on ``measurements`` and the group topics."""
        groups = self.session.groups
        for topic, pub in self._pub.items():
            rows = block.samples if topic == 'measurements' else \
                block.samples[list(groups[topic[13:]])]
            builder = self._builders.setdefault(topic, BlockMessageBuilder())
            pub.publish(builder.build(block.first_sample_index, block.sample_rate_Hz,
                                      block.epoch, rows))

    def publish_descriptions(self, descriptions: Dict[str, StreamDescription]) -> None:
        """Publish the latched descriptions of the block topics."""
        for topic, pub in self._pub_desc.items():
            pub.publish(description_to_msg(descriptions[topic]))

    def publish_consumed(self, samples: int) -> None:
        """Publish ``excitation/consumed``."""
        self._pub_ack.publish(UInt64(data=int(samples)))

    def publish_states(self, stamps_ns: np.ndarray, position_m: np.ndarray,
                       velocity_m_per_s: np.ndarray, effort_N: np.ndarray) -> None:
        """Publish the joint states of the lever."""
        for ns, p, v, e in zip(stamps_ns.tolist(), position_m.tolist(),
                               velocity_m_per_s.tolist(), effort_N.tolist()):
            msg = JointState(name=[JOINT], position=[p], velocity=[v], effort=[e])
            msg.header.stamp = Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
            self._pub_state.publish(msg)

    def status_changed(self) -> None:
        """Publish ``~/status`` and, when what it says changed, ``excitation/ready``."""
        try:
            self._pub_status.publish(String(data=json.dumps(self.status_values())))
            if self.session is None:
                ready, waiting = False, f'refuses: {self._error}'
            else:
                pub = self._pub.get('measurements')
                ready, waiting = self.session.readiness(
                    self._matched(), pub.topic_name if pub is not None else 'measurements')
            text = readiness_text(self.get_fully_qualified_name(), ready, waiting)
            if text != self._readiness:
                self._readiness = text
                self._pub_ready.publish(String(data=text))
        except Exception:   # noqa: B902 during shutdown the publisher may be gone
            if self.context.ok():
                raise

    def diagnostics_due(self) -> None:
        """Publish ``/diagnostics`` now."""
        if self.session is None:
            level, message, values = 2, self._error, self.diagnostic_values()
        else:
            level, message, values = self.session.diagnostic_status()
        # the session's levels are DiagnosticStatus's numbers (bridge_health)
        self._pub_diag.publish(node_diagnostics(self, 'device', bytes([level]), message,
                                                values))

    def open_excitation(self) -> None:
        """Subscribe to the excitation (the session's wait for listeners ended)."""
        subscribe_excitation(self, self._on_excitation)

    def log(self, level: str, message: str) -> None:
        """Log a line of the session's (rclpy wants one call site per severity)."""
        if level == 'error':
            self.get_logger().error(message)
        elif level == 'warning':
            self.get_logger().warning(message)
        else:
            self.get_logger().info(message)

    # -- what supervisors and tests read ---------------------------------------------------

    def status_values(self) -> Dict[str, Any]:
        """
        What ``~/status`` says (:meth:`BridgeSession.status_values`; state error without one).

        Returns
        -------
        dict
            The status.
        """
        if self.session is None:
            return {'state': 'error', 'error': self._error, 'last_error': '',
                    'stream_epoch': -1, 'faults': 0, 'device_busy': False}
        return self.session.status_values()

    def diagnostic_values(self) -> Dict[str, Any]:
        """
        Everything ``/diagnostics`` reports, as one mapping.

        Returns
        -------
        dict
            Counter and state names (units in the names) to values.
        """
        if self.session is None:
            return {'state': 'error', 'error': self._error, 'last_error': self._error,
                    'backend': str(self._param('backend'))}
        return self.session.diagnostic_values()

    def published_counts(self) -> Dict[str, Dict[str, int]]:
        """
        Messages published per stream (for an in-process supervisor's accounting).

        Returns
        -------
        dict
            Relative topic name to ``published`` [count].
        """
        counts = self.session.counts if self.session is not None else {}
        out = {topic: {'published': int(counts.get('published_blocks', 0))}
               for topic in self._pub}
        out['joint_states'] = {'published': int(counts.get('published_states', 0))}
        return out

    def faults(self) -> Tuple[Fault, ...]:
        """
        The latched faults of this run (for in-process supervisors).

        Returns
        -------
        tuple of Fault
            Oldest first; empty when the run is clean.
        """
        return self.session.monitor.faults if self.session is not None else ()

    # -- messages in -----------------------------------------------------------------------

    def _on_excitation(self, msg: Float64MultiArray) -> None:
        if self.session is None:
            return
        try:
            block = msg_to_block(msg, expected_channels=len(self.session.config.outputs))
        except BlockError as exc:
            self.session.refuse_excitation(str(exc))
            return
        self.session.on_excitation(block)

    def _on_joint_command(self, msg: JointState) -> None:
        if self.session is not None:
            self.session.on_joint_command(list(msg.name), list(msg.effort))

    def _on_array_command(self, msg: Float64MultiArray) -> None:
        if self.session is not None:
            self.session.on_array_command(list(msg.data))

    def _on_set_parameters(self, params: List[Parameter]) -> SetParametersResult:
        funcgen: Dict[str, Any] = {}
        rate = self.session.rate if self.session is not None else 1e7
        for p in params:
            if p.name.startswith('funcgen.'):
                funcgen[p.name] = p.value
            elif p.name in RUNTIME:
                problem = runtime_problem(p.name, p.value, rate)
                if problem is not None:
                    return SetParametersResult(successful=False,
                                               reason=f'{p.name} {problem}')
            elif p.name in PARAMETERS:
                return SetParametersResult(successful=False, reason=f'{p.name} is fixed at '
                                           'start-up; restart the node with the new value')
        if funcgen and self.session is not None:
            values = {n: self._param(n) for n in funcgen_table(self._param('outputs'))}
            try:
                specs = generator_specs(self.session.config, {**values, **funcgen})
            except ConfigError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
            self.session.set_generator(specs)
        if self.session is not None:
            self.session.runtime.update({p.name: float(p.value) for p in params
                                         if p.name in RUNTIME})
        return SetParametersResult(successful=True)

    # -- services --------------------------------------------------------------------------

    def _answer(self, response: Trigger.Response, call) -> Trigger.Response:
        if self.session is None:
            response.success, response.message = False, self._error or 'no back-end'
        else:
            response.success, response.message = True, call(self.session)
        return response

    def _srv_start(self, request: Trigger.Request, response: Trigger.Response):
        # Answers at once: the device's answer (or its silence, seconds of retries) is
        # waited for in the session's worker thread; ~/status says how the start ended.
        def start(session: BridgeSession) -> str:
            session.end_hold()              # an explicit start does not wait for listeners
            return session.request_start('~/start')
        return self._answer(response, start)

    def _srv_stop(self, request: Trigger.Request, response: Trigger.Response):
        def stop(session: BridgeSession) -> str:
            session.cancel_retry()
            return session.request_stop()
        if self.session is None:
            response.success, response.message = True, 'not running'
            return response
        return self._answer(response, stop)

    def _srv_estop(self, request: Trigger.Request, response: Trigger.Response):
        return self._answer(response, BridgeSession.emergency_stop)

    def _srv_reset(self, request: Trigger.Request, response: Trigger.Response):
        return self._answer(response, BridgeSession.reset)

    # -- publishers and shutdown -----------------------------------------------------------

    def _make_publishers(self) -> None:
        qos = BLOCK_QOS
        depth = self._param('publisher_depth')
        if isinstance(depth, int) and not isinstance(depth, bool) and 1 <= depth <= 100000:
            qos = QoSProfile(history=BLOCK_QOS.history, depth=depth,
                             reliability=BLOCK_QOS.reliability,
                             durability=BLOCK_QOS.durability)
        groups = self.session.groups if self.session is not None else {}
        topics = ['measurements'] + ([f'measurements/{g}' for g in groups]
                                     if self._param('publish_groups') else [])
        for topic in topics:
            self._pub[topic] = self.create_publisher(Float64MultiArray, topic, qos)
            self._pub_desc[topic] = self.create_publisher(String, f'{topic}/description',
                                                          LATCHED_QOS)

    def destroy_node(self) -> None:
        """Stop the acquisition and release the back-end, then destroy the node."""
        try:
            if self.session is not None:
                self.session.close()
        finally:
            super().destroy_node()


main = node_main(DaqBridgeNode, 'daq_bridge')


if __name__ == '__main__':
    raise SystemExit(main())
