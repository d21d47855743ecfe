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

from dataclasses import dataclass
import math
from pathlib import Path
import time
from typing import Dict, List, Optional

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock as RosClock, ClockType
from rclpy.logging import get_logger
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String, UInt64
from std_srvs.srv import Trigger

from emfc_ros.core.blocks import Channel, StreamDescription
from emfc_ros.core.config import unflatten
from emfc_ros.core.control.loop_config import loop_config, loop_timing
from emfc_ros.core.errors import BlockError, ConfigError
from emfc_ros.core.excitation_queue import DROPPED, ExcitationQueue
from emfc_ros.core.model.actuation import coil_setpoint_for_force_V
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.paths import config_file
from emfc_ros.core.sim.channels import channel_names, channel_units, MEASURED, REFERENCE
from emfc_ros.core.sim.monitor import saturation_counts
from emfc_ros.core.sim.resolution import simulator_resolution
from emfc_ros.core.sim.simulator import Simulator
from emfc_ros.core.sim.state_rate import StateRateLimiter
from emfc_ros.core.start_gate import parse_endpoints, readiness_text
from emfc_ros.core.weighing.errors import WeighingError
from emfc_ros.core.weighing.profiles import parse_load_schedule
from emfc_ros.nodes.convert import (
    BLOCK_QOS, BlockMessageBuilder, CONTROL_QOS, description_to_msg, LATCHED_QOS, msg_to_block,
    node_diagnostics, steady_clock, subscribe_device_inputs, subscribe_excitation)
from emfc_ros.nodes.flow_control import AckFlowControl
from emfc_ros.nodes.params import declare_table, refuse_unknown
from emfc_ros.nodes.spin import node_main

DEFAULT_BALANCE = 'balance_default.yaml'
TIME_MODES = ('owner', 'wall', 'lockstep')
LOCKSTEP_MATCH = ('stamp', 'next')
GROUPS = {
    'position': ('position_m', 'sensor_V', 'position_true_m'),
    'current': ('coil_current_A', 'load_changer_current_A', 'coil_current_precise_A'),
    'force': ('coil_force_N', 'load_changer_force_N', 'pan_force_N', 'coil_force_true_N',
              'force_command_N'),
}
JOINT = 'lever'
#: joint_states and /clock: many small messages per block. A reliable KEEP_LAST writer
#: repairs a message its reader missed (a burst of blocks filled the reader's port) only
#: after a heartbeat, which small messages do not bring with them (Fast DDS sends one
#: periodically): the history must outlast that, or the message is overwritten and lost (a
#: recorder saw one /clock tick in 400 lost with depth 100). 5000 messages hold more than
#: 10 s of the fastest simulation.
STATE_QOS = QoSProfile(depth=5000)
CLOCK_QOS = QoSProfile(depth=5000)
#: An acknowledgement is published again after this long without new excitation [s]: the
#: last one of a window may be lost like any small message, and the generator would wait
#: ack_timeout_s before sending again.
ACK_REPEAT_S = 0.05
#: Repetitions of one acknowledgement at most (then the generator's re-send takes over).
ACK_REPEATS = 20
#: Longest wait, once min_subscribers matched, for the graph's other subscriptions to match
#: the outputs (a recorder's /clock subscription created with its measurements one) [s].
OUTPUT_MATCH_S = 5.0
#: Run-time load changes kept in the measurement description (the latest).
MAX_LOAD_CHANGES = 100

PARAMETERS = {
    'balance_file': ('', 'balance parameter YAML; empty: the balance.* parameters, or the '
                         'shipped config/balance_default.yaml if there are none'),
    'sample_rate_Hz': (10000.0, 'sample clock of the simulation [Hz]; excitation blocks must '
                                'carry the same rate'),
    'block_size': (1000, 'wall mode: samples simulated per step [samples], 1 to 1000000'),
    'time_mode': ('owner', "'owner': lockstep with the excitation, publishes /clock; 'wall': "
                           "paced to the wall clock; 'lockstep': one controller period "
                           '(sample_rate_Hz / state_rate_Hz samples) per effort command, '
                           'publishes /clock'),
    'seed': (0, 'seed of the sensor and amplifier noise'),
    'noise': (True, 'simulate sensor and amplifier current noise'),
    'quantisation': (True, 'simulate 16-bit DAC and ADC quantisation and saturation'),
    'substeps': (0, 'RK4 steps per sample, 1 to 64; 0: the fewest that resolve the fastest '
                    'mode'),
    'hold': ('zoh', "setpoint hold between samples: 'zoh' or 'foh'"),
    'load_mass_kg': (0.0, 'mass on the pan [kg], 0 to 2; settable at run time'),
    'load_changer_coupled': (False, 'load changer moving mass coupled to the pan; settable at '
                                    'run time'),
    'load_schedule': ('', "mass on the pan over simulated time: 'time_s:mass_kg,...' (e.g. "
                          "'0:0,2:0.0734829,5:0'), each applied at the sample of its time "
                          '(simulated samples since the start) and announced in the '
                          'measurement description; empty: none; fixed at start-up'),
    'state_rate_Hz': (1000.0, 'rate of joint_states [Hz], 0 disables, at most sample_rate_Hz'),
    'command_timeout_s': (0.1, 'effort command watchdog [s]; the command returns to 0 N after '
                               'this long without a new one; lockstep mode: the current state '
                               'is re-published after this long of wall time without an '
                               'answer'),
    'command_delay_periods': (1, 'lockstep mode: 0 = the command answering the state at t_k '
                                 'acts over [t_k, t_k+1) (plus one simulator sample), 1 = one '
                                 'controller period later [periods]'),
    'lockstep_match': ('stamp', "lockstep mode: 'stamp' = a joint_commands message answers the "
                                "state with the same header stamp; 'next' = the next command "
                                'answers the pending state whatever its stamp (ros2_control '
                                'topic-based hardware stamps with its own clock)'),
    'publish_groups': (True, 'also publish measurements/position, current and force'),
    'max_state_wall_rate_Hz': (500.0, 'owner mode: at most this many joint_states per second '
                                      'of wall time [Hz] (evenly chosen from those due at '
                                      'state_rate_Hz of simulated time; the others are counted '
                                      'as states_decimated), so that subscribers keep up when '
                                      'the simulation runs faster than real time; 0: no limit; '
                                      'fixed at start-up'),
    'min_subscribers': (0, 'owner mode: subscribe to the excitation only once this many '
                           'subscriptions to measurements have matched [count], 0 to 100; a '
                           'consumer-paced generator holds sample 0 until then, so a recorder '
                           'started after the plant loses nothing; fixed at start-up'),
    'control.enabled': (False, 'run the position controller inside the sample loop (closed '
                               'loop, docs/closed_loop.md); owner and wall modes only; the '
                               'coil excitation is then added to the controller output'),
    'control.rate_Hz': (10000.0, 'in-loop controller rate [Hz]; sample_rate_Hz must be a '
                                 'whole multiple'),
    'control.crossover_Hz': (130.0, 'design crossover of the in-loop controller [Hz]'),
    'control.phase_margin_deg': (40.0, 'design phase margin [deg]'),
    'control.delay_samples': (1.0, 'controller computation and transport delay [controller '
                                   'samples] (the hold adds half a sample); times the '
                                   'simulator samples per controller sample a whole number '
                                   '>= 1'),
    'control.notch_Hz': (0.0, 'notch centre [Hz]; 0: none (the default: the lever mode, 410 Hz '
                              'empty, 333 Hz with 200 g, stays phase-stabilised at 10 kHz)'),
    'control.max_load_kg': (0.2, 'top of the weighing range [kg]: the design is checked '
                                 '(margins, exact closed-loop poles) at loads from 0 to here and '
                                 'refused if it fails'),
    'control.position_setpoint_m': (0.0, 'lever-end position the loop holds [m]'),
}
CONTROL_PREFIX = 'control.'
#: Inclusive limits of the numeric parameters (descriptors; ``ros2 param describe``).
LIMITS = {'block_size': (1, 1_000_000), 'seed': (0, 2 ** 63 - 1), 'substeps': (0, 64),
          'sample_rate_Hz': (1.0, 10.0e6),
          'load_mass_kg': (0.0, 2.0), 'command_delay_periods': (0, 1),
          'min_subscribers': (0, 100), 'max_state_wall_rate_Hz': (0.0, 1.0e6)}
#: Parameters fixed at start-up (``state_rate_Hz`` too in lockstep mode: refused then).
READ_ONLY = ('sample_rate_Hz', 'block_size', 'time_mode', 'seed', 'noise', 'quantisation',
             'substeps', 'hold', 'publish_groups', 'command_delay_periods', 'lockstep_match',
             'min_subscribers', 'max_state_wall_rate_Hz', 'load_schedule') + \
    tuple(n for n in PARAMETERS if n.startswith(CONTROL_PREFIX))
#: Shown in the start-up log line (with every parameter set to a non-default value).
STARTUP_KEYS = ('time_mode', 'sample_rate_Hz', 'load_mass_kg', 'balance_file',
                'control.enabled')
HELP_EXTRA = ('balance.*: balance parameters (the keys of config/balance_default.yaml, '
              'flattened), used when balance_file is empty; settable at run time.')


@dataclass
class _Lockstep:
    """Bookkeeping of the lockstep time mode (one controller period per command)."""

    period: int = 0                 # samples per controller period; 0: not configured
    delay: int = 1                  # command_delay_periods
    match: str = 'stamp'            # lockstep_match
    started: bool = False           # the first state has been published
    waiting: bool = False           # a state is published and waits for its command
    index: int = 0                  # sample index of the next simulated sample
    stamp_ns: int = 0               # stamp of the state waiting for its command
    published_at: float = 0.0       # monotonic time that state was (re-)published [s]
    state_msg: Optional[JointState] = None
    hold_V: Optional[float] = None  # coil setpoint before the first command [V]
    coil_V: float = 0.0             # coil setpoint held over the current period [V]
    pending_V: float = 0.0          # command_delay_periods 1: setpoint of the next period [V]
    periods: int = 0                # periods simulated
    republished: int = 0            # states re-published for lack of an answer
    stale: int = 0                  # joint_commands whose stamp matches no waiting state
    unexpected: int = 0             # commands while no state waits (before the start)
    first_wall_s: float = 0.0       # monotonic time of the first state [s]


class PlantSimulatorNode(Node):
    """
    Simulate the balance between excitation blocks in and measurement blocks out.

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
        self._error = ''
        self._rate = float(self._param('sample_rate_Hz'))
        self._mode = str(self._param('time_mode'))
        self._names = channel_names(reference=True)
        self._units = channel_units(reference=True)
        control_error = self._control_error()
        try:
            if control_error:
                raise ValueError(control_error)
            self._sim = self._make_simulator()
            self._names = tuple(self._sim.channel_names)
            self._units = tuple(self._sim.channel_units)
        except (ValueError, OSError) as exc:
            # Keep running: report the reason on /diagnostics (at once, below), accept a
            # corrected balance_file or balance.*.
            self._sim = None
            self._error = control_error or f'balance configuration refused: {exc}'
            self.get_logger().error(self._error)
        else:
            # Compile (or load) the numba kernel now, on a throwaway copy and before any
            # topic exists, so that the first excitation block is not kept waiting.
            self._make_simulator().step_block(np.zeros((2, 1)))
        self._queue = ExcitationQueue([0.0, 0.0])
        self._epoch = 0
        self._wall_index = 0
        self._sim_samples = 0
        self._blocks_in = 0
        self._blocks_out = 0
        self._clocks_out = 0
        self._malformed = 0
        self._last_error = ''
        self._command_N = 0.0
        self._command_time = -math.inf
        self._command_watchdog_trips = 0
        self._builders = {}
        self._row = {name: i for i, name in enumerate(self._names)}
        self._saturation = {}
        self._last_position_m = 0.0
        self._bad_commands = 0
        self._lock = _Lockstep()
        self._states = self._state_limiter()
        self._load_kg = float(self._param('load_mass_kg'))
        self._coupled = bool(self._param('load_changer_coupled'))
        self._load_changes: List[list] = []      # [stream sample index, load [kg]] as applied
        self._schedule = self._load_schedule()
        self._next_first_index = 0               # index the next simulated sample will carry
        self._applying_schedule = False
        if self._mode not in TIME_MODES:
            self._fail(f'time_mode must be one of {list(TIME_MODES)}, got {self._mode!r}')
        elif self._mode == 'lockstep':
            self._configure_lockstep()
        if refused:     # does not simulate with values nobody asked for (logged already)
            self._sim = None
            self._error = '; '.join(refused) + '; restart the node with valid values'

        self._pub = {'measurements': self.create_publisher(Float64MultiArray, 'measurements',
                                                           BLOCK_QOS)}
        self._pub_desc = {'measurements': self.create_publisher(
            String, 'measurements/description', LATCHED_QOS)}
        if self._param('publish_groups'):
            for group in GROUPS:
                topic = f'measurements/{group}'
                self._pub[topic] = self.create_publisher(Float64MultiArray, topic, BLOCK_QOS)
                self._pub_desc[topic] = self.create_publisher(String, f'{topic}/description',
                                                              LATCHED_QOS)
        self._pub_ack = self.create_publisher(UInt64, 'excitation/consumed', CONTROL_QOS)
        self._ack: Optional[tuple] = None       # (index, monotonic time, repetitions)
        self._acks_repeated = 0
        self.create_timer(ACK_REPEAT_S, self._repeat_acknowledgement, clock=steady_clock())
        # Deep enough for a block's burst of states (a block of 1000 samples at 10 kHz
        # with states at 1 kHz is 100 messages).
        self._pub_state = self.create_publisher(JointState, 'joint_states', STATE_QOS)
        # One /clock per block, as deep as the blocks: a recorder that falls behind for a
        # moment must not lose ticks (a writer's KEEP_LAST history drops them silently).
        self._pub_clock = self.create_publisher(Clock, '/clock', CLOCK_QOS) \
            if self._mode in ('owner', 'lockstep') else None
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._pub_ready = self.create_publisher(String, 'excitation/ready', LATCHED_QOS)
        self._readiness = ''
        self._clock_conflict = ''
        # Owner mode owns time: a subscriber that was not scheduled for a moment slows the
        # simulation instead of losing blocks (flow_control; no waits in other modes).
        self._flow = AckFlowControl(self._pub['measurements'] if self._mode == 'owner'
                                    else None)
        self._min_subscribers = self._min_subscribers_param()
        self._excitation_timer = None
        self._listeners_since: Optional[float] = None
        hold = self._mode == 'owner' and self._min_subscribers > 0
        subscribe_device_inputs(self, None if hold else self._on_excitation,
                                self._on_joint_command, self._on_array_command)
        if hold:
            # Steady timer: the excitation opens once the measurements are listened to.
            self.get_logger().info(f'waiting for {self._min_subscribers} subscription(s) to '
                                   'measurements before subscribing to the excitation')
            self._excitation_timer = self.create_timer(
                0.05, self._open_excitation, clock=RosClock(clock_type=ClockType.STEADY_TIME))
        self.create_service(Trigger, '~/reset', self._srv_reset)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self._publish_descriptions()
        self.create_timer(1.0, self._publish_diagnostics, clock=steady_clock())
        self._wall_start = time.monotonic()
        if self._mode == 'wall':
            block = int(self._param('block_size'))
            self.create_timer(min(0.02, max(0.001, 0.5 * block / self._rate)), self._wall_tick,
                              clock=steady_clock())
        elif self._mode == 'lockstep':
            # Wall-clock (steady) timer: starts the loop and re-publishes an unanswered state.
            self.create_timer(0.005, self._lockstep_tick,
                              clock=RosClock(clock_type=ClockType.STEADY_TIME))
        if self._error:
            self._publish_diagnostics()     # the status says why at start, not after 1 s
        self._announce_readiness()

    def _load_schedule(self) -> list:
        """The load schedule as ``[(simulated sample, mass [kg])]``, or [] (error reported)."""
        try:
            entries = parse_load_schedule(str(self._param('load_schedule')))
        except WeighingError as exc:
            self._fail(f'load_schedule refused: {exc}; restart the node with a valid schedule')
            return []
        return [(int(round(t * self._rate)), m) for t, m in entries]

    def _state_limiter(self) -> StateRateLimiter:
        value = self._param('max_state_wall_rate_Hz')
        if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                not math.isfinite(value) or value < 0.0:
            self._fail(f'max_state_wall_rate_Hz must be a number >= 0 [Hz], got {value!r}; '
                       'using 500 Hz until the node is restarted with a valid value')
            value = PARAMETERS['max_state_wall_rate_Hz'][0]
        return StateRateLimiter(float(value))

    def _min_subscribers_param(self) -> int:
        value = self._param('min_subscribers')
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 100:
            self._fail(f'min_subscribers must be a whole number from 0 to 100, got {value!r}; '
                       'using 0 until the node is restarted with a valid value')
            return 0
        return value

    def _open_excitation(self) -> None:
        """Subscribe to the excitation once enough subscriptions to measurements matched."""
        matched = self._pub['measurements'].get_subscription_count()
        if matched < self._min_subscribers:
            self._listeners_since = None
            return
        # Every subscription the graph lists on an output (a recorder's /clock, joint_states)
        # matched too, so that the first block's messages reach it: at most OUTPUT_MATCH_S.
        now = time.monotonic()
        if self._listeners_since is None:
            self._listeners_since = now
        pending = self._unmatched_outputs()
        if pending and now - self._listeners_since < OUTPUT_MATCH_S:
            return
        if pending:
            self.get_logger().warning(
                f'subscriptions listed in the graph did not match in {OUTPUT_MATCH_S:g} s on '
                f'{", ".join(pending)} (incompatible QoS, or gone): starting without them')
        self._check_clock()
        self._excitation_timer.cancel()
        self.destroy_timer(self._excitation_timer)
        self._excitation_timer = None
        subscribe_excitation(self, self._on_excitation)
        self.get_logger().info(f'{matched} subscription(s) to measurements matched: '
                               'subscribed to the excitation')
        self._announce_readiness()

    def _unmatched_outputs(self) -> List[str]:
        """Output topics with fewer matched subscriptions than the graph lists."""
        pubs = [*self._pub.values(), self._pub_state]
        if self._pub_clock is not None:
            pubs.append(self._pub_clock)
        out = []
        for pub in pubs:
            listed = parse_endpoints(
                (i.node_namespace, i.node_name,
                 i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL)
                for i in self.get_subscriptions_info_by_topic(pub.topic_name))
            wanted = sum(1 for e in listed if e.compatible)
            if pub.get_subscription_count() < wanted:
                out.append(f'{pub.topic_name} ({pub.get_subscription_count()} of {wanted})')
        return out

    def _check_clock(self) -> None:
        """Refuse a second publisher of our clock topic (two instances' simulated time)."""
        if self._pub_clock is None or self._clock_conflict:
            return
        topic = self._pub_clock.topic_name
        names = [i.node_namespace.rstrip('/') + '/' + i.node_name
                 for i in self.get_publishers_info_by_topic(topic)]
        if len(names) <= 1:
            return
        me = self.get_fully_qualified_name()
        if me in names:
            names.remove(me)
        others = sorted(set(names))
        self._clock_conflict = (
            f'{", ".join(others)} also publishes {topic}: the simulated time of two balances '
            'would mix (time running backwards in both); give each instance its own clock '
            '(launch argument clock_topic:=clock, or -r /clock:=<namespace>/clock for every '
            'node of the instance); this plant stopped simulating')
        self._fail(self._clock_conflict)
        self._announce_readiness()

    def _announce_readiness(self) -> None:
        """Publish excitation/ready when what it says changes."""
        if self._sim is None or self._error:
            ready, waiting = False, f'refuses to simulate: {self._error or "no simulator"}'
        elif self._excitation_timer is not None:
            ready = False
            waiting = (f'waits for {self._min_subscribers} subscription(s) to '
                       f'{self._pub["measurements"].topic_name} (a recorder; '
                       f'{self._pub["measurements"].get_subscription_count()} matched)')
        else:
            ready, waiting = True, ''
        text = readiness_text(self.get_fully_qualified_name(), ready, waiting)
        if text != self._readiness:
            self._readiness = text
            self._pub_ready.publish(String(data=text))

    def _fail(self, reason: str) -> None:
        """Report a configuration error; the node keeps running but does not simulate."""
        self._error = reason
        self.get_logger().error(reason)

    def _configure_lockstep(self) -> None:
        """Check the lockstep parameters: a whole number of samples per controller period."""
        rate = float(self._param('state_rate_Hz'))
        ratio = self._rate / rate if rate > 0.0 else 0.0
        n = int(round(ratio))
        if rate <= 0.0 or n < 1 or abs(ratio - n) > 1e-9 * ratio:
            self._fail(f'time_mode lockstep needs state_rate_Hz > 0 dividing sample_rate_Hz into '
                       f'a whole number of samples per period; got {self._rate} Hz / {rate} Hz '
                       f'= {ratio:g} samples')
            return
        delay = self._param('command_delay_periods')
        if isinstance(delay, bool) or delay not in (0, 1):
            self._fail(f'command_delay_periods must be 0 or 1, got {delay!r}')
            return
        match = self._param('lockstep_match')
        if match not in LOCKSTEP_MATCH:
            self._fail(f'lockstep_match must be one of {list(LOCKSTEP_MATCH)}, got {match!r}')
            return
        self._lock.period = n
        self._lock.delay = int(delay)
        self._lock.match = str(match)

    # -- configuration ---------------------------------------------------------------------

    def _param(self, name: str):
        return self.get_parameter(name).value

    def _balance(self, overrides: Optional[List[Parameter]] = None) -> BalanceParameters:
        path = self._param('balance_file')
        flat = {name: p.value for name, p in self.get_parameters_by_prefix('balance').items()}
        for p in overrides or []:
            if p.name == 'balance_file':
                path = p.value
            elif p.name.startswith('balance.'):
                flat[p.name[len('balance.'):]] = p.value
        if path:
            return BalanceParameters.load_yaml(Path(path))
        if not flat:
            return BalanceParameters.load_yaml(config_file(DEFAULT_BALANCE))
        flat = {k: (list(v) if not isinstance(v, (str, bytes, bool, int, float)) else v)
                for k, v in flat.items()}
        return BalanceParameters.from_mapping(unflatten(flat)['balance']
                                              if 'balance' in unflatten(flat)
                                              else unflatten(flat))

    def _control_error(self) -> str:
        """The reason the ``control.*`` parameters do not fit the node, or ''."""
        flat = {name[len(CONTROL_PREFIX):]: self._param(name) for name in PARAMETERS
                if name.startswith(CONTROL_PREFIX)}
        try:
            loop = loop_config(flat)
            if loop is not None:
                loop_timing(loop, self._rate)
        except ConfigError as exc:
            return (f'control configuration refused: {exc} (control.* and sample_rate_Hz are '
                    'fixed at start-up: restart the node with values that fit; '
                    'docs/closed_loop.md)')
        if loop is not None and self._mode == 'lockstep':
            return ('control configuration refused: control.enabled: the in-loop controller '
                    'and the lockstep mode (an external controller) exclude each other')
        return ''

    def _make_simulator(self, overrides: Optional[List[Parameter]] = None):
        substeps = int(self._param('substeps'))
        sim = Simulator(self._balance(overrides), self._rate, seed=int(self._param('seed')),
                        noise=bool(self._param('noise')),
                        quantisation=bool(self._param('quantisation')),
                        substeps=substeps or None, hold=str(self._param('hold')),
                        load_mass_kg=float(getattr(self, '_load_kg', self._param('load_mass_kg'))),
                        load_changer_coupled=bool(getattr(self, '_coupled',
                                                          self._param('load_changer_coupled'))))
        flat = {name[len(CONTROL_PREFIX):]: self._param(name) for name in PARAMETERS
                if name.startswith(CONTROL_PREFIX)}
        try:
            loop = loop_config(flat)
        except ConfigError as exc:
            raise ValueError(str(exc)) from exc
        if loop is None:
            return sim
        if self._mode == 'lockstep':
            raise ValueError('control.enabled: the in-loop controller and the lockstep mode '
                             '(an external controller) exclude each other')
        # Imported here: the controller design needs scipy.signal (a second of start-up).
        from emfc_ros.core.sim.closed_loop import ClosedLoopSimulator
        looped = ClosedLoopSimulator(sim, loop)
        d = looped.design
        self.get_logger().info(
            f'in-loop controller at {loop.rate_Hz:g} Hz: crossover {d.crossover_Hz:.1f} Hz, '
            f'phase margin {d.phase_margin_deg:.1f} deg, gain margins '
            f'{d.lower_gain_margin_dB} / {d.upper_gain_margin_dB} dB, sensitivity peak '
            f'{d.sensitivity_peak:.2f}')
        return looped

    def _on_set_parameters(self, params: List[Parameter]) -> SetParametersResult:
        fixed = ('sample_rate_Hz', 'block_size', 'time_mode', 'seed', 'noise',
                 'quantisation', 'substeps', 'hold', 'publish_groups', 'command_delay_periods',
                 'lockstep_match', 'min_subscribers', 'max_state_wall_rate_Hz',
                 'load_schedule') + \
            tuple(n for n in PARAMETERS if n.startswith(CONTROL_PREFIX))
        if self._mode == 'lockstep':
            fixed += ('state_rate_Hz',)
        load = None
        coupled = None
        if any(p.name == 'balance_file' or p.name.startswith('balance.') for p in params):
            try:
                candidate = self._make_simulator(params)
            except (ValueError, OSError) as exc:
                return SetParametersResult(successful=False,
                                           reason=f'balance configuration refused: {exc}')
            self._sim = candidate
            if self._mode != 'lockstep' or self._lock.period:
                self._error = self._clock_conflict     # a second clock stays refused
            if self._lock.started:
                self._lock.hold_V = float(candidate.hold_setpoints_V[0])
            self.get_logger().info('new balance parameters: simulator restarted at its '
                                   'operating point')
            self._publish_descriptions()
        for p in params:
            if p.name in fixed:
                return SetParametersResult(
                    successful=False, reason=f'{p.name} is fixed at start-up; restart the node '
                                             'with the new value')
            if p.name == 'load_mass_kg':
                if p.type_ not in (Parameter.Type.DOUBLE, Parameter.Type.INTEGER) or \
                        not 0.0 <= float(p.value) <= 2.0:
                    return SetParametersResult(
                        successful=False,
                        reason=f'load_mass_kg must be a number from 0 to 2 kg, got {p.value!r}')
                load = float(p.value)
            elif p.name == 'load_changer_coupled':
                if p.type_ != Parameter.Type.BOOL:
                    return SetParametersResult(
                        successful=False, reason='load_changer_coupled must be true or false')
                coupled = bool(p.value)
            elif p.name == 'state_rate_Hz':
                if p.type_ not in (Parameter.Type.DOUBLE, Parameter.Type.INTEGER) or \
                        not 0.0 <= float(p.value) <= self._rate:
                    return SetParametersResult(
                        successful=False, reason=f'state_rate_Hz must be from 0 to '
                                                 f'{self._rate} Hz, got {p.value!r}')
            elif p.name == 'command_timeout_s':
                if p.type_ not in (Parameter.Type.DOUBLE, Parameter.Type.INTEGER) or \
                        not 0.0 < float(p.value) <= 60.0:
                    return SetParametersResult(
                        successful=False, reason='command_timeout_s must be in (0, 60] s, got '
                                                 f'{p.value!r}')
        if self._applying_schedule:
            return SetParametersResult(successful=True)     # the schedule applies it itself
        if (load is not None or coupled is not None) and self._sim is not None:
            self._change_load(load if load is not None else self._load_kg,
                              coupled if coupled is not None else self._coupled)
        return SetParametersResult(successful=True)

    # -- streams ---------------------------------------------------------------------------

    def _descriptions(self) -> dict:
        meanings = {name: text for name, _unit, text in MEASURED + REFERENCE}
        out = {}
        channels = tuple(Channel(n, u, meanings.get(n, ''))
                         for n, u in zip(self._names, self._units))
        extra = {'time_mode': self._mode, 'load_mass_kg': self._load_kg,
                 'load_changer_coupled': self._coupled,
                 # [stream sample index, load [kg]] of the run-time changes, the latest last
                 'load_changes': [list(c) for c in self._load_changes]}
        if self._sim is not None:
            sim = getattr(self._sim, 'sim', self._sim)      # the closed loop's plant
            extra['resolution'] = {
                name: value for name, value in simulator_resolution(
                    sim.params, sim.noise, sim.quantisation,
                    getattr(self._sim, 'current_channel', None)).items()
                if name in self._names}
        out['measurements'] = StreamDescription(
            'measurements', self._rate, 0, channels, epoch=self._epoch,
            source=self.get_fully_qualified_name(), extra=extra)
        for topic in self._pub:
            if topic == 'measurements':
                continue
            group = topic.split('/', 1)[1]
            out[topic] = StreamDescription(
                group, self._rate, 0, tuple(c for c in channels if c.name in GROUPS[group]),
                epoch=self._epoch, source=self.get_fully_qualified_name(), extra=extra)
        return out

    def _publish_descriptions(self) -> None:
        for topic, description in self._descriptions().items():
            self._pub_desc[topic].publish(description_to_msg(description))

    def _publish_block(self, first_index: int, out: np.ndarray) -> None:
        for topic, pub in self._pub.items():
            if topic == 'measurements':
                rows = out
            else:
                group = GROUPS[topic.split('/', 1)[1]]
                rows = out[[self._row[n] for n in group if n in self._row]]
            builder = self._builders.setdefault(topic, BlockMessageBuilder())
            pub.publish(builder.build(first_index, self._rate, self._epoch, rows))
        self._blocks_out += 1
        self._flow.published(out.nbytes)

    def _simulate(self, first_index: int, setpoints: np.ndarray, stamp_ns: int) -> None:
        """Apply the effort command, simulate, publish the clock, the block and the states."""
        command = self._command_setpoint_V()
        if command:
            setpoints = setpoints.copy()
            setpoints[0] += command
        out = self._step(first_index, setpoints)
        for key, count in saturation_counts(out, self._names, self._sim.params).items():
            self._saturation[key] = self._saturation.get(key, 0) + count
        self._last_position_m = float(out[self._row['position_m'], -1])
        self._sim_samples += setpoints.shape[1]
        if self._pub_clock is not None:
            # Tick, then /clock (the end of the block: when its last sample exists), then
            # the outputs, so that a use_sim_time subscriber stamps them with simulated time.
            self._pub_clock.publish(Clock(clock=_time_msg(self._sim_time_ns())))
            self._clocks_out += 1
        self._publish_block(first_index, out)
        self._publish_states(out, stamp_ns)

    def _step(self, first_index: int, setpoints: np.ndarray) -> np.ndarray:
        """Simulate a block, applying the load schedule at its samples."""
        n = setpoints.shape[1]
        self._next_first_index = first_index
        if not self._schedule or self._schedule[0][0] >= self._sim_samples + n:
            out = self._sim.step_block(setpoints)
            self._next_first_index = first_index + n
            return out
        parts = []
        pos = 0
        while pos < n:
            while self._schedule and self._schedule[0][0] <= self._sim_samples + pos:
                _, mass = self._schedule.pop(0)
                self._next_first_index = first_index + pos
                self._apply_scheduled_load(mass)
            due = self._schedule[0][0] - self._sim_samples if self._schedule else n
            end = min(n, max(due, pos + 1))
            parts.append(self._sim.step_block(setpoints[:, pos:end]))
            pos = end
        self._next_first_index = first_index + n
        return np.concatenate(parts, axis=1)

    def _apply_scheduled_load(self, mass_kg: float) -> None:
        """A load of the schedule: the parameter follows, the description announces it."""
        self._applying_schedule = True
        try:
            self.set_parameters([Parameter('load_mass_kg', value=float(mass_kg))])
        finally:
            self._applying_schedule = False
        self._change_load(float(mass_kg), self._coupled)
        self.get_logger().info(f'load schedule: {mass_kg!r} kg on the pan from sample '
                               f'{self._next_first_index} ({self._sim_samples / self._rate:g} s '
                               'simulated)')

    def _change_load(self, mass_kg: float, coupled: bool) -> None:
        """Put a load on the pan from the next simulated sample; announce it."""
        if self._sim is None:
            return
        self._sim.set_load(mass_kg, coupled)
        self._load_kg, self._coupled = mass_kg, coupled
        index = self._lock.index if self._mode == 'lockstep' else (
            self._wall_index if self._mode == 'wall' else self._next_first_index)
        self._load_changes.append([int(index), float(mass_kg)])
        del self._load_changes[:-MAX_LOAD_CHANGES]
        self._publish_descriptions()

    def _sim_time_ns(self) -> int:
        return int(round(self._sim_samples * 1e9 / self._rate))

    def _on_excitation(self, msg: Float64MultiArray) -> None:
        if self._sim is None or self._clock_conflict:
            self._malformed += 1
            self._last_error = self._error
            return
        try:
            block = msg_to_block(msg, expected_channels=2)
            if abs(block.sample_rate_Hz - self._rate) > 1e-9 * self._rate:
                raise BlockError(f'excitation at {block.sample_rate_Hz} Hz, simulator runs at '
                                 f'{self._rate} Hz')
            kind = self._queue.push(block)
        except BlockError as exc:
            self._malformed += 1
            self._last_error = str(exc)
            self.get_logger().warning(f'excitation block dropped: {exc}',
                                      throttle_duration_sec=5.0)
            return
        self._blocks_in += 1
        if kind in DROPPED and block.epoch == self._queue.epoch and self._queue.head_index:
            # A block we already have (counted): its sender did not hear our acknowledgement,
            # so say again how far we are, or a consumer-paced generator waits for nothing.
            self._acknowledge(self._queue.head_index)
            return
        if self._epoch != block.epoch and self._mode == 'owner':
            self._epoch = block.epoch
            self._publish_descriptions()
        if self._mode == 'lockstep':
            return      # queued; consumed sample by sample as the controller steps the plant
        if self._mode == 'owner' and self._queue.queued:
            first = self._queue.head_index
            setpoints, _ = self._queue.pop(self._queue.queued)
            self._simulate(first, setpoints, self._sim_time_ns())
            self._acknowledge(self._queue.head_index)

    def _acknowledge(self, index: int) -> None:
        """Publish how far the excitation is consumed (again later if nothing follows)."""
        self._pub_ack.publish(UInt64(data=int(index)))
        self._ack = (int(index), time.monotonic(), 0)

    def _repeat_acknowledgement(self) -> None:
        """Steady timer: the last acknowledgement again while no excitation follows it."""
        if self._ack is None:
            return
        index, at, repeats = self._ack
        now = time.monotonic()
        if repeats >= ACK_REPEATS or now - at < ACK_REPEAT_S:
            return
        self._pub_ack.publish(UInt64(data=index))
        self._ack = (index, now, repeats + 1)
        self._acks_repeated += 1

    def _wall_tick(self) -> None:
        if self._sim is None:
            return
        block = int(self._param('block_size'))
        due = int((time.monotonic() - self._wall_start) * self._rate) // block * block
        budget = 64
        while self._wall_index + block <= due and budget > 0:
            had = self._queue.queued
            setpoints, _ = self._queue.pop(block)
            stamp = self.get_clock().now().nanoseconds
            self._simulate(self._wall_index, setpoints, stamp)
            self._wall_index += block
            budget -= 1
            if had:
                self._acknowledge(self._queue.head_index)

    # -- controller interface --------------------------------------------------------------

    def _bad_command(self, reason: str) -> None:
        """Count and report a refused command; the plant keeps running."""
        self._malformed += 1
        self._bad_commands += 1
        self._last_error = reason
        self.get_logger().warning(f'effort command refused: {reason}',
                                  throttle_duration_sec=2.0)

    def _on_joint_command(self, msg: JointState) -> None:
        if JOINT not in msg.name or len(msg.effort) != len(msg.name):
            self._bad_command(f'joint_commands needs an effort for joint {JOINT!r}; got names '
                              f'{list(msg.name)} with {len(msg.effort)} efforts')
            return
        effort = float(msg.effort[msg.name.index(JOINT)])
        if self._mode == 'lockstep':
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            self._lockstep_command(effort, stamp, 'joint_commands')
        else:
            self._set_command(effort)

    def _on_array_command(self, msg: Float64MultiArray) -> None:
        if len(msg.data) != 1:
            self._bad_command(f'commands needs exactly 1 value (effort [N]), got '
                              f'{len(msg.data)}')
        elif self._mode == 'lockstep':
            self._lockstep_command(float(msg.data[0]), None, 'commands')
        else:
            self._set_command(float(msg.data[0]))

    def _set_command(self, effort_N: float) -> None:
        if not math.isfinite(effort_N):
            self._bad_command(f'effort command {effort_N!r} N is not finite')
            return
        self._command_N = effort_N
        self._command_time = time.monotonic()

    # -- lockstep time mode ----------------------------------------------------------------

    def _lockstep_ready(self) -> bool:
        return self._sim is not None and self._lock.period > 0 and not self._error

    def _lockstep_tick(self) -> None:
        """Wall-clock timer: publish the first state, re-publish an unanswered one."""
        lock = self._lock
        if not self._lockstep_ready():
            return
        if not lock.started:
            if self._pub_state.get_subscription_count() < 1:
                return
            lock.started = True
            lock.first_wall_s = time.monotonic()
            lock.hold_V = float(self._sim.hold_setpoints_V[0])
            lock.coil_V = lock.pending_V = lock.hold_V
            self._lockstep_step(1)          # sample 0: the state at t_0
            return
        if lock.waiting and \
                time.monotonic() - lock.published_at >= float(self._param('command_timeout_s')):
            lock.republished += 1
            self._pub_state.publish(lock.state_msg)
            self._pub_clock.publish(Clock(clock=lock.state_msg.header.stamp))
            self._clocks_out += 1
            lock.published_at = time.monotonic()

    def _lockstep_command(self, effort_N: float, stamp_ns: Optional[int], topic: str) -> None:
        """A command arrived in lockstep mode: if it answers the waiting state, step."""
        lock = self._lock
        if not math.isfinite(effort_N):
            self._bad_command(f'{topic}: effort command {effort_N!r} N is not finite')
            return
        if not lock.waiting:
            lock.unexpected += 1
            return
        if stamp_ns is not None and lock.match == 'stamp' and stamp_ns != lock.stamp_ns:
            lock.stale += 1         # answers an earlier (or no) state: ignored
            return
        lock.waiting = False
        volts = coil_setpoint_for_force_V(self._sim.params, effort_N, self._last_position_m)
        if lock.delay == 0:
            lock.coil_V = volts
        else:
            lock.coil_V, lock.pending_V = lock.pending_V, volts
        self._command_N = effort_N
        self._lockstep_step(lock.period)

    def _lockstep_step(self, n: int) -> None:
        """Simulate ``n`` samples with the held coil setpoint, publish block, state, clock."""
        lock = self._lock
        if self._queue.queued:
            setpoints, real = self._queue.pop(n)
        else:
            setpoints, real = np.zeros((2, n)), 0
        setpoints[0] += lock.coil_V
        out = self._step(lock.index, setpoints)
        for key, count in saturation_counts(out, self._names, self._sim.params).items():
            self._saturation[key] = self._saturation.get(key, 0) + count
        self._last_position_m = float(out[self._row['position_m'], -1])
        first = lock.index
        self._publish_block(first, out)
        lock.index += n
        self._sim_samples = lock.index
        if real:
            self._acknowledge(self._queue.head_index)
        # The state at t_k is the block's last sample, k N; stamped with simulated time.
        stamp_ns = int(round((lock.index - 1) * 1e9 / self._rate))
        truth = out[self._row['position_true_m']]
        msg = JointState()
        msg.header.stamp = _time_msg(stamp_ns)
        msg.name = [JOINT]
        msg.position = [self._last_position_m]
        msg.velocity = [float((truth[-1] - truth[-2]) * self._rate) if n > 1 else 0.0]
        msg.effort = [float(out[self._row['coil_force_N'], -1])]
        lock.state_msg = msg
        lock.stamp_ns = stamp_ns
        lock.waiting = True
        lock.periods += 1 if n == lock.period else 0
        self._pub_state.publish(msg)
        self._pub_clock.publish(Clock(clock=msg.header.stamp))
        self._clocks_out += 1
        lock.published_at = time.monotonic()

    def _command_setpoint_V(self) -> float:
        """Coil setpoint [V] that produces the commanded force at the current position."""
        if self._command_N == 0.0:
            return 0.0
        if time.monotonic() - self._command_time > float(self._param('command_timeout_s')):
            self._command_N = 0.0
            self._command_watchdog_trips += 1
            return 0.0
        position_m = float(self._last_position_m)
        return coil_setpoint_for_force_V(self._sim.params, self._command_N, position_m)

    def _publish_states(self, out: np.ndarray, first_stamp_ns: int) -> None:
        rate = float(self._param('state_rate_Hz'))
        if rate <= 0.0:
            return
        step = max(1, int(round(self._rate / rate)))
        n = out.shape[1]
        position = out[self._row['position_m']]
        truth = out[self._row['position_true_m']] if 'position_true_m' in self._row \
            else position
        velocity = np.gradient(truth) * self._rate if n > 1 else np.zeros(n)
        effort = out[self._row['coil_force_N']]
        candidates = np.arange(0, n, step)
        chosen = self._states.choose(len(candidates), time.monotonic()) \
            if self._mode == 'owner' else np.arange(len(candidates))
        for i in candidates[chosen]:
            msg = JointState()
            msg.header.stamp = _time_msg(first_stamp_ns + int(round(i * 1e9 / self._rate)))
            msg.name = [JOINT]
            msg.position = [float(position[i])]
            msg.velocity = [float(velocity[i])]
            msg.effort = [float(effort[i])]
            self._pub_state.publish(msg)
        self._states.published += len(chosen)

    # -- services and diagnostics ----------------------------------------------------------

    def _srv_reset(self, request: Trigger.Request, response: Trigger.Response):
        if self._sim is None:
            response.success, response.message = False, self._error
            return response
        self._sim.reset()
        if self._mode == 'lockstep' and self._lock.hold_V is not None:
            # Back to the hold point; simulated time and sample indices go on.
            self._lock.coil_V = self._lock.pending_V = self._lock.hold_V
        response.success = True
        response.message = 'simulator state reset to the operating point'
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
        counts = {topic: {'published': self._blocks_out} for topic in self._pub}
        counts['joint_states'] = {'published': self._states.published,
                                  'decimated': self._states.decimated}
        if self._pub_clock is not None:
            counts['/clock'] = {'published': self._clocks_out}
        return counts

    def _publish_diagnostics(self) -> None:
        self._check_clock()
        self._announce_readiness()
        values = dict(self._queue.counters())
        values.update({'time_mode': self._mode, 'sample_rate_Hz': self._rate,
                       'simulated_samples': self._sim_samples,
                       'simulated_time_s': f'{self._sim_samples / self._rate:.6f}',
                       'wall_time_s': f'{time.monotonic() - self._wall_start:.3f}',
                       'blocks_in': self._blocks_in, 'blocks_out': self._blocks_out,
                       'malformed_messages': self._malformed,
                       'command_N': self._command_N,
                       'command_watchdog_trips': self._command_watchdog_trips,
                       'bad_commands': self._bad_commands,
                       'last_error': self._last_error, 'error': self._error,
                       'min_subscribers': self._min_subscribers,
                       'states_published': self._states.published,
                       'states_decimated': self._states.decimated,
                       'excitation_subscribed': self._excitation_timer is None,
                       'acknowledgements_repeated': self._acks_repeated,
                       **self._flow.counters()})
        if self._mode == 'lockstep':
            lock = self._lock
            wall = time.monotonic() - lock.first_wall_s if lock.started else 0.0
            values.update({
                'lockstep_samples_per_period': lock.period,
                'command_delay_periods': lock.delay, 'lockstep_match': lock.match,
                'lockstep_periods': lock.periods,
                'lockstep_periods_per_wall_s': f'{lock.periods / wall:.1f}' if wall else '0',
                'sim_time_per_wall_time': (f'{lock.index / self._rate / wall:.4f}' if wall
                                           else '0'),
                'waiting_for_command': lock.waiting,
                'states_republished': lock.republished,
                'stale_commands': lock.stale, 'unexpected_commands': lock.unexpected})
        values.update(self._saturation)
        defects = self._malformed + values['gaps'] + values['duplicates'] + \
            values['reordered'] + values['overlaps']
        level = DiagnosticStatus.WARN if defects else DiagnosticStatus.OK
        if self._sim is None or self._error:
            level = DiagnosticStatus.ERROR
        message = self._error or ('excitation defects' if defects else 'ok')
        if not self._error and not defects and self._flow.timeouts:
            level = DiagnosticStatus.WARN
            message = (f'{self._flow.timeouts} wait(s) for acknowledgements by the subscribers '
                       'ended at the 2 s bound: a subscriber stalled or died (the simulation '
                       'slowed down; a subscriber that fell 100 blocks behind lost blocks)')
        if not self._error and self._excitation_timer is not None:
            message = (f'waiting for {self._min_subscribers} subscription(s) to measurements '
                       'before subscribing to the excitation')
        self._pub_diag.publish(node_diagnostics(self, 'simulation', level, message, values))


def _time_msg(ns: int) -> Time:
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


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
