"""
The position_controller node: an external controller closing the loop over the controller topics.

It is written against the same topics a ros2_control setup with the topic-based hardware
component would use (``docs/ros_control.md``) and runs in lockstep with the plant simulator's
``time_mode: lockstep`` in simulated time.

Topics (relative to the node namespace):

- ``joint_states`` (``sensor_msgs/JointState``, in): joint ``lever``: position [m], velocity
  [m/s], effort = measured coil force [N].
- ``joint_commands`` (``sensor_msgs/JointState``, out, ``command_output: joint_commands``):
  name ``[lever]``, effort ``[F]`` [N], header stamp = the stamp of the state it answers; or
  ``commands`` (``std_msgs/Float64MultiArray``, out, ``command_output: commands``): ``[F]``.
- ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``, out, 1 Hz of wall time).

Service ``~/reset`` (``std_srvs/Trigger``): the controller restarts, bumpless, from the next
state.

The controller is :func:`emfc_ros.core.control.design_controller` (PID, lead, optional
notch) designed at start-up from the linearised balance model and run by
:class:`emfc_ros.core.control.runtime.RuntimeController` once per received state: error =
``position_setpoint_m`` - position, output clamped to +/- the coil current limit times the
motor coefficient at zero position, with conditional integration as anti-windup. With
``command_is_total`` (the lockstep plant) the output is the total coil force and starts from the
first state's effort (the measured holding force): a bumpless start.
"""

from __future__ import annotations

import math
from pathlib import Path
import time
from typing import List, Optional

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray
from std_srvs.srv import Trigger

from emfc_ros.core.control import ControllerDesign, design_controller, plant_from_model
from emfc_ros.core.control.runtime import RuntimeController
from emfc_ros.core.model.linear import linearise
from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.paths import config_file
from emfc_ros.nodes.convert import CONTROL_QOS, node_diagnostics
from emfc_ros.nodes.params import declare_table, refuse_unknown
from emfc_ros.nodes.spin import node_main

DEFAULT_BALANCE = 'balance_default.yaml'
OUTPUTS = ('joint_commands', 'commands')
STATE_QOS = QoSProfile(depth=1000)
#: Parameters that the controller design depends on (a change re-designs it).
DESIGN = ('balance_file', 'load_mass_kg', 'load_changer_coupled', 'rate_Hz', 'crossover_Hz',
          'phase_margin_deg', 'loop_delay_periods', 'notch_Hz', 'notch_quality')

# name: (default, description with units)
PARAMETERS = {
    'balance_file': ('', 'balance parameter YAML the design is based on; empty: the shipped '
                         'config/balance_default.yaml'),
    'load_mass_kg': (0.0, 'mass on the pan assumed by the design [kg], 0 to 2'),
    'load_changer_coupled': (False, 'design for the load changer coupled to the pan'),
    'rate_Hz': (1000.0, "controller sample rate [Hz]: the plant's state_rate_Hz"),
    'crossover_Hz': (40.0, 'requested gain crossover of the loop [Hz]'),
    'phase_margin_deg': (35.0, 'requested phase margin [deg], 0 to 90'),
    'loop_delay_periods': (1.1, 'loop delay the design assumes [controller periods]: the '
                                "plant's command_delay_periods plus one simulator sample "
                                '(0.1 period at 10 kHz / 1 kHz)'),
    'notch_Hz': (0.0, 'centre of a notch filter [Hz]; 0: no notch'),
    'notch_quality': (5.0, 'quality factor of the notch (centre over -3 dB width)'),
    'position_setpoint_m': (0.0, 'lever position setpoint [m]; settable at run time, within '
                                 'the sensor range'),
    'command_output': ('joint_commands', "'joint_commands': sensor_msgs/JointState effort "
                                         "stamped with the state's stamp; 'commands': "
                                         'std_msgs/Float64MultiArray [F]'),
    'command_is_total': (True, 'the command is the total coil force (plant_simulator '
                               'time_mode lockstep; starts from the first state effort); '
                               'false: it is added to the excitation (starts from 0 N)'),
    'joint_name': ('lever', 'name of the controlled joint'),
}
#: Inclusive limits of the numeric parameters (descriptors; ``ros2 param describe``).
LIMITS = {'load_mass_kg': (0.0, 2.0), 'phase_margin_deg': (0.0, 90.0),
          'position_setpoint_m': (-100e-6, 100e-6)}
READ_ONLY = ('command_output', 'joint_name', 'command_is_total')
#: Shown in the start-up log line (with every parameter set to a non-default value).
STARTUP_KEYS = ('rate_Hz', 'command_output', 'position_setpoint_m')


class PositionControllerNode(Node):
    """
    Hold the lever at a position setpoint: one controller update per received joint state.

    Parameters
    ----------
    **kwargs
        Passed to :class:`rclpy.node.Node` (for example ``parameter_overrides``).
    """

    def __init__(self, **kwargs) -> None:
        super().__init__('position_controller', **kwargs)
        refused = declare_table(self, PARAMETERS, LIMITS, READ_ONLY)
        refused += refuse_unknown(self)
        self._output = str(self._param('command_output'))
        self._joint = str(self._param('joint_name'))
        self._error = ''
        self._design: Optional[ControllerDesign] = None
        self._runtime: Optional[RuntimeController] = None
        self._limit_N = math.inf
        self._started = False
        self._last_stamp_ns: Optional[int] = None
        self._last_force_N = 0.0
        self._states = 0
        self._commands = 0
        self._repeated_states = 0
        self._bad_states = 0
        self._period_mismatches = 0
        self._last_bad = ''
        self._max_update_s = 0.0
        self._window = (time.monotonic(), 0, None)   # wall time, states, first stamp [ns]
        self._rates = ('0', '0')
        if self._output not in OUTPUTS:
            self._fail(f'command_output must be one of {list(OUTPUTS)}, got {self._output!r}')
        else:
            try:
                self._install(self._make_design())
            except (ValueError, OSError) as exc:
                self._fail(f'controller design refused: {exc}')
        if refused:     # no commands from values nobody asked for (logged already)
            self._error = '; '.join(refused) + '; set valid values or restart the node'
        if self._output == 'commands':
            self._pub = self.create_publisher(Float64MultiArray, 'commands', CONTROL_QOS)
        else:
            self._pub = self.create_publisher(JointState, 'joint_commands', CONTROL_QOS)
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_subscription(JointState, 'joint_states', self._on_state, STATE_QOS)
        self.create_service(Trigger, '~/reset', self._srv_reset)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        # Diagnostics on the wall clock: simulated time may run faster, slower, or stand still.
        self.create_timer(1.0, self._publish_diagnostics,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))

    # -- configuration ---------------------------------------------------------------------

    def _param(self, name: str):
        return self.get_parameter(name).value

    def _fail(self, reason: str) -> None:
        self._error = reason
        self.get_logger().error(reason)

    def _make_design(self, overrides: Optional[List[Parameter]] = None) -> tuple:
        """Design the controller from the balance model; returns (design, limit [N])."""
        values = {name: self._param(name) for name in DESIGN}
        for p in overrides or []:
            if p.name in values:
                values[p.name] = p.value
        for name in DESIGN[1:]:
            v = values[name]
            if name == 'load_changer_coupled':
                if not isinstance(v, bool):
                    raise ValueError(f'{name} must be true or false, got {v!r}')
            elif isinstance(v, bool) or not isinstance(v, (int, float)) or \
                    not math.isfinite(v):
                raise ValueError(f'{name} must be a finite number, got {v!r}')
        if not 0.0 <= float(values['load_mass_kg']) <= 2.0:
            raise ValueError(f'load_mass_kg must be from 0 to 2 kg, got {values["load_mass_kg"]}')
        path = values['balance_file']
        params = BalanceParameters.load_yaml(Path(path) if path else
                                             config_file(DEFAULT_BALANCE))
        model = linearise(loaded(params.mechanics, float(values['load_mass_kg']),
                                 bool(values['load_changer_coupled'])))
        notch = float(values['notch_Hz'])
        design = design_controller(
            plant_from_model(model), float(values['rate_Hz']), float(values['crossover_Hz']),
            float(values['phase_margin_deg']), delay_samples=float(values['loop_delay_periods']),
            notch_Hz=notch if notch > 0.0 else None,
            notch_quality=float(values['notch_quality']))
        limit = float(params.converters.coil_current_limit_A
                      * params.motor.coefficient_N_per_A(0.0))
        return design, limit

    def _install(self, designed: tuple) -> None:
        """Use a new design; the next state restarts it bumpless."""
        design, limit = designed
        self._design = design
        self._limit_N = limit
        self._runtime = RuntimeController(design.controller, (-limit, limit))
        self._started = False
        self._error = ''

        def fmt(v: Optional[float], unit: str) -> str:
            return 'none' if v is None else f'{v:.1f} {unit}'

        self.get_logger().info(
            f'controller designed at {design.controller.sample_rate_Hz:g} Hz: crossover '
            f'{design.crossover_Hz:.1f} Hz (asked {design.requested_crossover_Hz:g}), phase '
            f'margin {design.phase_margin_deg:.1f} deg, gain margins '
            f'{fmt(design.lower_gain_margin_dB, "dB")} / {fmt(design.upper_gain_margin_dB, "dB")}'
            f', sensitivity peak {design.sensitivity_peak:.2f} at '
            f'{design.sensitivity_peak_Hz:.1f} Hz, bandwidth {fmt(design.bandwidth_Hz, "Hz")}, '
            f'output limits +/-{limit:.3f} N')

    def _on_set_parameters(self, params: List[Parameter]) -> SetParametersResult:
        redesign = False
        for p in params:
            if p.name in ('command_output', 'joint_name', 'command_is_total'):
                return SetParametersResult(
                    successful=False, reason=f'{p.name} is fixed at start-up; restart the node '
                                             'with the new value')
            if p.name == 'position_setpoint_m':
                if p.type_ not in (Parameter.Type.DOUBLE, Parameter.Type.INTEGER) or \
                        not abs(float(p.value)) <= 100e-6:
                    return SetParametersResult(
                        successful=False, reason='position_setpoint_m must be a number within '
                                                 f'+/-100e-6 m, got {p.value!r}')
            redesign = redesign or p.name in DESIGN
        if redesign:
            try:
                designed = self._make_design(params)
            except (ValueError, OSError) as exc:
                return SetParametersResult(successful=False,
                                           reason=f'controller design refused: {exc}')
            self._install(designed)
        return SetParametersResult(successful=True)

    # -- the loop --------------------------------------------------------------------------

    def _bad_state(self, reason: str) -> None:
        self._bad_states += 1
        self._last_bad = reason
        self.get_logger().warning(f'joint state ignored: {reason}', throttle_duration_sec=2.0)

    def _on_state(self, msg: JointState) -> None:
        if self._runtime is None or self._error:
            return
        if self._joint not in msg.name or len(msg.position) != len(msg.name):
            self._bad_state(f'no position for joint {self._joint!r} (names {list(msg.name)})')
            return
        i = msg.name.index(self._joint)
        position = float(msg.position[i])
        if not math.isfinite(position):
            self._bad_state(f'position {position!r} m is not finite')
            return
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if stamp == self._last_stamp_ns and self._started:
            # The plant re-published a state it has not had an answer for: answer it again
            # without advancing the controller (keeps the loop deterministic).
            self._repeated_states += 1
            self._publish(self._last_force_N, msg.header.stamp)
            return
        if not self._started:
            effort = float(msg.effort[i]) if len(msg.effort) == len(msg.name) else math.nan
            initial = 0.0
            if self._param('command_is_total'):
                if not math.isfinite(effort):
                    self._bad_state('the first state needs a finite effort (the holding force) '
                                    'for a bumpless start')
                    return
                initial = min(max(effort, -self._limit_N), self._limit_N)
            self._runtime.reset(initial)
            self._started = True
            self.get_logger().info(f'loop closed at state stamp {stamp * 1e-9:.6f} s, '
                                   f'starting from {initial:.6f} N')
        elif self._last_stamp_ns is not None:
            expected = 1e9 / self._runtime.sample_rate_Hz
            if abs(stamp - self._last_stamp_ns - expected) > 1e-3 * expected + 1.0:
                self._period_mismatches += 1
        self._last_stamp_ns = stamp
        t0 = time.perf_counter()
        force = self._runtime.update(float(self._param('position_setpoint_m')) - position)
        self._max_update_s = max(self._max_update_s, time.perf_counter() - t0)
        self._last_force_N = force
        self._states += 1
        self._publish(force, msg.header.stamp)

    def _publish(self, force_N: float, stamp) -> None:
        if self._output == 'commands':
            self._pub.publish(Float64MultiArray(data=[force_N]))
        else:
            msg = JointState()
            msg.header.stamp = stamp
            msg.name = [self._joint]
            msg.effort = [force_N]
            self._pub.publish(msg)
        self._commands += 1

    # -- services and diagnostics ----------------------------------------------------------

    def _srv_reset(self, request: Trigger.Request, response: Trigger.Response):
        if self._runtime is None:
            response.success, response.message = False, self._error
            return response
        self._started = False
        response.success = True
        response.message = 'controller restarts bumpless from the next joint state'
        return response

    def _publish_diagnostics(self) -> None:
        now = time.monotonic()
        wall0, states0, stamp0 = self._window
        wall = now - wall0
        if wall > 0.0:
            sim = ((self._last_stamp_ns - stamp0) * 1e-9
                   if stamp0 is not None and self._last_stamp_ns is not None else 0.0)
            self._rates = (f'{(self._states - states0) / wall:.1f}', f'{sim / wall:.4f}')
        self._window = (now, self._states, self._last_stamp_ns)
        design = self._design
        values = {
            'command_output': self._output, 'started': self._started,
            'states_handled': self._states, 'commands_sent': self._commands,
            'updates_per_wall_s': self._rates[0], 'state_time_per_wall_time': self._rates[1],
            'repeated_states': self._repeated_states, 'bad_states': self._bad_states,
            'period_mismatches': self._period_mismatches,
            'saturated_updates': self._runtime.saturated_samples if self._runtime else 0,
            'output_limit_N': self._limit_N, 'last_force_N': self._last_force_N,
            'max_update_time_s': f'{self._max_update_s:.6f}',
            'position_setpoint_m': self._param('position_setpoint_m'),
            'last_bad_state': self._last_bad, 'error': self._error,
        }
        if design is not None:
            values.update({'rate_Hz': design.controller.sample_rate_Hz,
                           'crossover_Hz': f'{design.crossover_Hz:.2f}',
                           'phase_margin_deg': f'{design.phase_margin_deg:.1f}',
                           'upper_gain_margin_dB': design.upper_gain_margin_dB,
                           'lower_gain_margin_dB': design.lower_gain_margin_dB,
                           'sensitivity_peak': f'{design.sensitivity_peak:.3f}'})
        level = DiagnosticStatus.OK
        message = 'ok'
        if self._error:
            level, message = DiagnosticStatus.ERROR, self._error
        elif self._bad_states or (self._runtime and self._runtime.saturated_samples):
            level, message = DiagnosticStatus.WARN, 'bad states or saturated output'
        self._pub_diag.publish(node_diagnostics(self, 'loop', level, message, values))


main = node_main(PositionControllerNode, 'position_controller')


if __name__ == '__main__':
    raise SystemExit(main())
