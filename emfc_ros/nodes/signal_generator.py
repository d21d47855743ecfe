"""
The signal_generator node: excitation blocks for the coil and load-changer amplifiers.

Topics (relative to the node namespace):

- ``excitation`` (``std_msgs/Float64MultiArray``, out): setpoint-voltage blocks [V] in the
  block convention of :mod:`emfc_ros.core.blocks`.
- ``excitation/description`` (``std_msgs/String``, out, latched): the stream description.
- ``excitation/consumed`` (``std_msgs/UInt64``, in): a consumer's acknowledgement, the
  number of samples it has consumed; drives ``pacing: consumer``. Sample 0 waits until a
  consumer is matched; an unacknowledged window is re-sent after ``ack_timeout_s`` and a
  consumer silent for ``consumer_timeout_s`` puts the node in state ``error``
  (:class:`emfc_ros.core.pacing.ConsumerPacer`).
- ``excitation/ready`` (``std_msgs/String``, in, latched): the applier's (plant simulator's,
  bridge's) readiness, JSON ``{node, ready, waiting}``; with ``start_gate`` ``applier``
  sample 0 waits until an applier is ready and matched (:mod:`emfc_ros.core.start_gate`).
- ``~/status`` (``std_msgs/String``, out, latched): JSON with state, sample index, section.
- ``~/done`` (``std_msgs/Bool``, out, latched): true once the experiment has been sent.
- ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``, out, 1 Hz).

Services (``std_srvs/Trigger``, private): ``~/arm`` (load the experiment, rewind to sample 0
in a new epoch), ``~/start`` (arm if needed, then publish), ``~/stop`` (stop publishing).
"""

from __future__ import annotations

import json
from pathlib import Path
import time
from typing import Dict, List, Optional

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy
from std_msgs.msg import Bool, Float64MultiArray, String, UInt64
from std_srvs.srv import Trigger

from emfc_ros.core.blocks import Channel, StreamDescription
from emfc_ros.core.config import unflatten
from emfc_ros.core.pacing import ClockPacer, ConsumerPacer
from emfc_ros.core.paths import config_file
from emfc_ros.core.signals import Experiment, experiment_from_config, load_experiment_file
from emfc_ros.core.start_gate import (parse_endpoints, Readiness, ReadinessError,
                                      resolve_gate, StartGate)
from emfc_ros.nodes.convert import (
    ACK_QOS, BLOCK_QOS, BlockMessageBuilder, description_to_msg, LATCHED_QOS,
    node_diagnostics)
from emfc_ros.nodes.params import (declare_table, pending_refusals, refuse_choice,
                                   refuse_unknown)
from emfc_ros.nodes.spin import node_main

DEFAULT_EXPERIMENT = 'identification_trajectory.yaml'
PACING = ('wall', 'consumer')
START_GATES = ('auto', 'applier', 'subscribers', 'none')
CHANNEL_TEXT = {
    'coil': 'setpoint voltage of the coil (compensation) power amplifier',
    'load_changer': 'setpoint voltage of the load-changer power amplifier',
}

# name: (default, description with units)
PARAMETERS = {
    'experiment_file': ('', 'YAML file with the experiment (plain `experiment:` mapping or a '
                            'ROS params file); empty: use the experiment.* parameters, or the '
                            'shipped identification trajectory if there are none'),
    'block_size': (1000, 'samples per excitation block [samples], 1 to 1000000'),
    'pacing': ('wall', "'wall': paced to the wall clock; 'consumer': as fast as the consumer "
                       'acknowledges on excitation/consumed'),
    'lead_blocks': (2, 'wall pacing: blocks sent ahead of the wall clock [blocks], 0 to 1000'),
    'window_blocks': (8, 'consumer pacing: blocks in flight beyond the acknowledged index '
                         '[blocks], 1 to 1000'),
    'autostart': (True, 'arm and start when the node comes up'),
    'tick_period_s': (0.0, 'period of the publishing timer [s], 1e-4 to 1; 0: automatic '
                           '(half the lead time, 1 ms to 20 ms)'),
    'max_blocks_per_tick': (64, 'most blocks published per timer tick [blocks], 1 to 10000'),
    'start_gate': ('auto', "what sample 0 waits for after start: 'applier' = the node that "
                           'applies the excitation (plant_simulator, daq_bridge) announced '
                           'ready on excitation/ready and every subscription to the '
                           "excitation is matched; 'subscribers' = min_subscribers alone; "
                           "'none' = nothing; 'auto' = applier with consumer pacing, "
                           'subscribers with wall pacing'),
    'min_subscribers': (0, 'after start, hold sample 0 until this many subscriptions match '
                           "the excitation publisher [count], 0 to 100, the applier's "
                           'included (2: the applier and a recorder of the excitation); '
                           'consumer pacing always waits for at least 1 and for a publisher '
                           'on excitation/consumed'),
    'ack_timeout_s': (3.0, 'consumer pacing: samples unacknowledged for this long are sent '
                           'again from the last acknowledgement [s], 0.01 to 3600 (above the '
                           "plant simulator's 2 s bound on waiting for its subscribers)"),
    'consumer_timeout_s': (10.0, 'consumer pacing: no acknowledgement for this long while '
                                 'samples are in flight puts the node in state error [s], '
                                 'ack_timeout_s to 86400'),
}

#: Float parameters with their range [s].
TIME_LIMITS = {'ack_timeout_s': (0.01, 3600.0), 'consumer_timeout_s': (0.01, 86400.0)}
#: Inclusive limits of the numeric parameters (descriptors; ``ros2 param describe``).
LIMITS = {'block_size': (1, 1_000_000), 'lead_blocks': (0, 1000), 'window_blocks': (1, 1000),
          'tick_period_s': (0.0, 1.0), 'max_blocks_per_tick': (1, 10000),
          'min_subscribers': (0, 100), **TIME_LIMITS}
#: Shown in the start-up log line (with every parameter set to a non-default value).
STARTUP_KEYS = ('pacing', 'experiment_file', 'block_size', 'autostart')
HELP_EXTRA = ('experiment.*: the experiment as parameters (the keys of an experiment YAML, '
              'flattened), used when experiment_file is empty.')


class SignalGeneratorNode(Node):
    """
    Publish an experiment's excitation as sample blocks.

    Parameters
    ----------
    **kwargs
        Passed to :class:`rclpy.node.Node` (for example ``parameter_overrides``).
    """

    def __init__(self, **kwargs) -> None:
        super().__init__('signal_generator', allow_undeclared_parameters=True,
                         automatically_declare_parameters_from_overrides=True, **kwargs)
        declare_table(self, PARAMETERS, LIMITS)
        refuse_unknown(self, [*PARAMETERS, 'experiment.'])
        refuse_choice(self, 'pacing', PACING)       # blocks ~/arm until set (pending_refusals)
        refuse_choice(self, 'start_gate', START_GATES)
        self._state = 'idle'
        self._error = ''
        self._experiment: Optional[Experiment] = None
        self._epoch = 0
        self._next_index = 0
        self._blocks_sent = 0
        self._blocks_repeated = 0     # sent again (a window not acknowledged in time)
        self._sent_end = 0            # end of the furthest block sent [sample index]
        self._started_at = 0.0
        self._clock_pacer: Optional[ClockPacer] = None
        self._consumer_pacer: Optional[ConsumerPacer] = None
        self._builder = BlockMessageBuilder()
        self._rejected_acks = 0
        self._waiting = ''
        self._gate: Optional[StartGate] = None
        self._gate_checked_s = 0.0
        self._gate_waiting = ''
        self._announcements: Dict[str, Readiness] = {}
        self._bad_readiness = 0
        # Timers run on the steady clock: with use_sim_time the node clock stands still
        # until /clock moves, which is what a waiting generator must report, not wait for.
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)

        self._pub_blocks = self.create_publisher(Float64MultiArray, 'excitation', BLOCK_QOS)
        self._pub_description = self.create_publisher(String, 'excitation/description',
                                                      LATCHED_QOS)
        # Control and state are private (~/...) so that nodes sharing a namespace never clash.
        self._pub_status = self.create_publisher(String, '~/status', LATCHED_QOS)
        self._pub_done = self.create_publisher(Bool, '~/done', LATCHED_QOS)
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self._sub_ack = self.create_subscription(UInt64, 'excitation/consumed',
                                                 self._on_consumed, ACK_QOS)
        self.create_subscription(String, 'excitation/ready', self._on_ready, LATCHED_QOS)
        self.create_service(Trigger, '~/arm', self._srv_arm)
        self.create_service(Trigger, '~/start', self._srv_start)
        self.create_service(Trigger, '~/stop', self._srv_stop)
        self.add_on_set_parameters_callback(self._on_set_parameters)

        self._timer = None
        self._block_size = 0
        self._max_blocks_per_tick = 0
        self._min_subscribers = 0
        self.create_timer(1.0, self._publish_diagnostics, clock=self._steady)
        self._publish_done(False)
        ok, reason = self._arm()    # refused while a start-up value was refused
        if not ok:
            self.get_logger().error(f'experiment refused: {reason}; fix the parameters and '
                                    'call ~/arm or ~/start')
        elif self._param('autostart'):
            ok, reason = self._start()
            if not ok:
                self._state, self._error = 'error', reason
                self.get_logger().error(f'autostart refused: {reason}')
        self._publish_status()

    # -- configuration ---------------------------------------------------------------------

    def _param(self, name: str):
        return self.get_parameter(name).value

    def _build_experiment(self, overrides: Optional[List[Parameter]] = None) -> Experiment:
        """Build the experiment from the parameters, with proposed changes applied."""
        flat = {name: p.value
                for name, p in self.get_parameters_by_prefix('experiment').items()}
        path = self._param('experiment_file')
        for p in overrides or []:
            if p.name == 'experiment_file':
                path = p.value
            elif p.name.startswith('experiment.'):
                flat[p.name[len('experiment.'):]] = p.value
        flat = {k: v for k, v in flat.items() if v is not None}
        if path:
            return load_experiment_file(Path(path))
        if not flat:
            return load_experiment_file(config_file(DEFAULT_EXPERIMENT))
        flat = {k: (list(v) if not isinstance(v, (str, bytes, bool, int, float)) else v)
                for k, v in flat.items()}
        return experiment_from_config(unflatten(flat))

    def _on_set_parameters(self, params: List[Parameter]) -> SetParametersResult:
        limits = {'block_size': (1, 1_000_000), 'lead_blocks': (0, 1000),
                  'window_blocks': (1, 1000), 'max_blocks_per_tick': (1, 10000),
                  'min_subscribers': (0, 100)}
        touches_experiment = False
        for p in params:
            if p.name in limits:
                lo, hi = limits[p.name]
                if p.type_ != Parameter.Type.INTEGER or not lo <= p.value <= hi:
                    return SetParametersResult(
                        successful=False,
                        reason=f'{p.name} must be an integer from {lo} to {hi}, got {p.value!r}')
            elif p.name == 'pacing' and p.value not in PACING:
                return SetParametersResult(
                    successful=False, reason=f'pacing must be one of {list(PACING)}, '
                                             f'got {p.value!r}')
            elif p.name == 'start_gate' and p.value not in START_GATES:
                return SetParametersResult(
                    successful=False, reason=f'start_gate must be one of {list(START_GATES)}, '
                                             f'got {p.value!r}')
            elif p.name == 'tick_period_s' and (
                    p.type_ != Parameter.Type.DOUBLE or not (
                        p.value == 0.0 or 1e-4 <= p.value <= 1.0)):
                return SetParametersResult(
                    successful=False, reason='tick_period_s must be 0 (automatic) or a float '
                                             f'from 1e-4 to 1 s, got {p.value!r}')
            elif p.name in TIME_LIMITS:
                lo, hi = TIME_LIMITS[p.name]
                if p.type_ != Parameter.Type.DOUBLE or not lo <= p.value <= hi:
                    return SetParametersResult(
                        successful=False,
                        reason=f'{p.name} must be a float from {lo} to {hi} s, got {p.value!r}')
            elif p.name == 'autostart' and p.type_ != Parameter.Type.BOOL:
                return SetParametersResult(successful=False,
                                           reason='autostart must be true or false')
            if p.name == 'experiment_file' or p.name.startswith('experiment.'):
                touches_experiment = True
        proposed = {p.name: p.value for p in params}
        ack_s = proposed.get('ack_timeout_s', self._param('ack_timeout_s'))
        consumer_s = proposed.get('consumer_timeout_s', self._param('consumer_timeout_s'))
        if set(proposed) & set(TIME_LIMITS) and consumer_s < ack_s:
            return SetParametersResult(
                successful=False, reason=f'consumer_timeout_s ({consumer_s} s) must be at '
                                         f'least ack_timeout_s ({ack_s} s)')
        if touches_experiment or any(p.name in ('block_size', 'pacing') for p in params):
            if self._state == 'running':
                return SetParametersResult(
                    successful=False, reason='cannot change the experiment, block_size or '
                                             'pacing while running; call ~/stop first')
        if touches_experiment:
            try:
                self._build_experiment(params)
            except (ValueError, OSError) as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    # -- state machine ---------------------------------------------------------------------

    def _arm(self, overrides: Optional[List[Parameter]] = None) -> tuple:
        refused = pending_refusals(self)
        if refused:
            self._state, self._error = 'error', refused
            return False, refused
        try:
            experiment = self._build_experiment(overrides)
        except (ValueError, OSError) as exc:
            self._state = 'error'
            self._error = str(exc)
            return False, str(exc)
        self._restart_timer(0.0)
        self._waiting = ''
        self._experiment = experiment
        self._epoch += 1
        self._next_index = 0
        self._blocks_sent = 0
        self._blocks_repeated = 0
        self._sent_end = 0
        self._state = 'armed'
        self._error = ''
        self._publish_done(False)
        self._publish_description(start_time_ns=0)
        return True, (f'armed epoch {self._epoch}: {experiment.total_samples} samples at '
                      f'{experiment.sample_rate_Hz} Hz')

    def _start(self) -> tuple:
        if self._state == 'running':
            return False, 'already running'
        if self._state != 'armed':
            ok, reason = self._arm()
            if not ok:
                return False, reason
        # Read once per run: the hot path touches no parameter.
        block = self._block_size = int(self._param('block_size'))
        self._max_blocks_per_tick = int(self._param('max_blocks_per_tick'))
        self._min_subscribers = int(self._param('min_subscribers'))
        rate = self._experiment.sample_rate_Hz
        self._started_at = time.monotonic()
        lead_blocks = int(self._param('lead_blocks'))
        pacing = str(self._param('pacing'))
        self._gate = StartGate(resolve_gate(str(self._param('start_gate')), pacing),
                               self._min_subscribers, dict(self._announcements))
        self._gate_checked_s = 0.0
        self._gate_waiting = ''
        if self._param('pacing') == 'wall':
            self._clock_pacer = ClockPacer(rate, block, lead_blocks, self._started_at)
            self._consumer_pacer = None
        else:
            try:
                self._consumer_pacer = ConsumerPacer(
                    block, int(self._param('window_blocks')),
                    ack_timeout_s=float(self._param('ack_timeout_s')),
                    consumer_timeout_s=float(self._param('consumer_timeout_s')),
                    min_subscribers=self._min_subscribers)
            except (TypeError, ValueError) as exc:
                return False, f'consumer pacing refused: {exc}'
            self._consumer_pacer.reset(self._started_at)
            self._clock_pacer = None
        self._waiting = ''
        period = float(self._param('tick_period_s'))
        if period == 0.0:
            period = min(0.02, max(0.001, 0.5 * max(lead_blocks, 1) * block / rate))
        self._restart_timer(period)
        self._state = 'running'
        self._publish_description(start_time_ns=self.get_clock().now().nanoseconds)
        self._publish_status()
        self._tick()
        return True, f'running epoch {self._epoch}'

    def _restart_timer(self, period_s: float) -> None:
        if self._timer is not None:
            self.destroy_timer(self._timer)
            self._timer = None
        if period_s > 0:
            self._timer = self.create_timer(period_s, self._tick, clock=self._steady)

    def _stop(self) -> tuple:
        if self._state != 'running':
            return False, f'not running (state {self._state})'
        self._restart_timer(0.0)
        self._state = 'stopped'
        self._waiting = ''
        self._publish_status()
        return True, f'stopped at sample {self._next_index}'

    def _srv_arm(self, request: Trigger.Request, response: Trigger.Response):
        if self._state == 'running':
            response.success, response.message = False, 'running; call ~/stop first'
        else:
            response.success, response.message = self._arm()
        self._publish_status()
        return response

    def _srv_start(self, request: Trigger.Request, response: Trigger.Response):
        response.success, response.message = self._start()
        self._publish_status()
        return response

    def _srv_stop(self, request: Trigger.Request, response: Trigger.Response):
        response.success, response.message = self._stop()
        return response

    # -- streaming -------------------------------------------------------------------------

    def _on_ready(self, msg: String) -> None:
        try:
            readiness = Readiness.from_json(msg.data)
        except ReadinessError as exc:
            self._bad_readiness += 1
            self.get_logger().warning(f'malformed excitation/ready ignored: {exc}',
                                      throttle_duration_sec=5.0)
            return
        self._announcements[readiness.node] = readiness
        if self._gate is not None:
            self._gate.announce(readiness)
            self._gate_checked_s = 0.0          # look again at the next tick

    def _gate_closed(self) -> bool:
        """
        Whether sample 0 still waits (start_gate); says what for when that changes.

        The graph is looked at every 20 ms at most (and at once after an announcement).
        """
        now = time.monotonic()
        if now - self._gate_checked_s < 0.02:
            return bool(self._gate_waiting)
        self._gate_checked_s = now
        topic = self._pub_blocks.topic_name
        endpoints = parse_endpoints(
            (i.node_namespace, i.node_name,
             i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL)
            for i in self.get_subscriptions_info_by_topic(topic))
        waiting = self._gate.waiting_for(endpoints, self._pub_blocks.get_subscription_count())
        if waiting != self._gate_waiting:
            self._gate_waiting = waiting
            self._waiting = f'start gate: {waiting}' if waiting else ''
            if waiting:
                self.get_logger().info(f'epoch {self._epoch}: sample 0 waits for {waiting}')
            else:
                self.get_logger().info(
                    f'epoch {self._epoch}: start gate ({self._gate.kind}) open with '
                    f'{self._pub_blocks.get_subscription_count()} subscription(s) matched; '
                    'sending from sample 0')
            self._publish_status()
        return bool(waiting)

    def _on_consumed(self, msg: UInt64) -> None:
        pacer = self._consumer_pacer
        if pacer is None or self._state not in ('running', 'done'):
            return
        if not pacer.acceptable(msg.data):
            self._rejected_acks += 1
            return
        if pacer.acknowledge(msg.data, time.monotonic()):
            self._tick()

    def _consumer_allowed(self) -> Optional[int]:
        """Poll the consumer pacer: rewind for a re-send, report waiting, or fail."""
        pacer = self._consumer_pacer
        if not pacer.started and self._next_index == 0 and self._gate_closed():
            pacer.reset(time.monotonic())
            return None
        decision = pacer.poll(time.monotonic(), self._pub_blocks.get_subscription_count(),
                              self._sub_ack.get_publisher_count())
        if decision.error:
            self._restart_timer(0.0)
            self._state = 'error'
            self._error = decision.error
            self._waiting = ''
            self.get_logger().error(
                f'consumer pacing stalled: {decision.error}; the node that applies the '
                'excitation stopped answering (is it running? its /diagnostics say why); '
                'call ~/start to run the experiment again in a new epoch')
            self._publish_status()
            return None
        before, self._waiting = self._waiting, decision.waiting
        if before.split(':')[0] != decision.waiting.split(':')[0]:
            # Log and publish the status when what we wait for changes, not at every tick.
            if decision.waiting.startswith('consumer'):
                self.get_logger().info(f'epoch {self._epoch}: waiting for a '
                                       f'{decision.waiting}')
            elif decision.waiting:
                self.get_logger().warning(f'epoch {self._epoch}: waiting for an '
                                          f'{decision.waiting}')
            elif before.startswith('consumer'):
                self.get_logger().info(
                    f'epoch {self._epoch}: consumer matched '
                    f'({self._pub_blocks.get_subscription_count()} subscription(s)); '
                    'sending from sample 0')
            self._publish_status()
        if decision.resend_from is not None:
            self.get_logger().warning(
                f'epoch {self._epoch}: no acknowledgement for {pacer.ack_timeout_s:g} s, '
                f'sending again from sample {decision.resend_from} (re-send '
                f'{pacer.resends})', throttle_duration_sec=5.0)
            self._next_index = decision.resend_from
        return decision.allowed_index

    def _tick(self) -> None:
        if self._state == 'done' and self._consumer_pacer is not None:
            self._drain()
            return
        if self._state != 'running':
            return
        experiment = self._experiment
        total = experiment.total_samples
        if self._clock_pacer is not None:
            if self._next_index == 0 and self._gate_closed():
                # Not started yet: the clock of sample 0 starts when the gate opens.
                self._started_at = time.monotonic()
                self._clock_pacer.start_time_s = self._started_at
                return
            allowed = self._clock_pacer.allowed_index(time.monotonic())
        else:
            allowed = self._consumer_allowed()
            if allowed is None:
                return
        section_before = experiment.section_index_at(self._next_index)
        self._send(allowed)
        if self._next_index < total and \
                experiment.section_index_at(self._next_index) != section_before:
            self._publish_status()
        if self._next_index >= total:
            if self._consumer_pacer is None or not self._consumer_pacer.in_flight:
                self._restart_timer(0.0)
            self._state = 'done'
            self._publish_done(True)
            self._publish_status()
            self.get_logger().info(f'experiment done: {total} samples in '
                                   f'{self._blocks_sent} blocks, epoch {self._epoch}')

    def _drain(self) -> None:
        """Everything sent: watch the consumer acknowledge the tail, re-send it if needed."""
        pacer = self._consumer_pacer
        if not pacer.in_flight:
            if self._timer is not None:     # the whole experiment acknowledged: say so once
                self._restart_timer(0.0)
                self._waiting = ''
                self._publish_status()
            return
        total = self._experiment.total_samples
        allowed = self._consumer_allowed()
        if allowed is None or self._next_index >= total:
            return
        self._send(allowed)     # the unacknowledged tail again; the state stays done

    def _send(self, allowed: int) -> None:
        """Publish blocks from the next sample index up to ``allowed`` (bounded per tick)."""
        experiment = self._experiment
        total = experiment.total_samples
        allowed = min(allowed, total)
        budget = self._max_blocks_per_tick
        rate = experiment.sample_rate_Hz
        while self._next_index < allowed and budget > 0:
            n = min(self._block_size, total - self._next_index)
            samples = experiment.block(self._next_index, n)
            self._pub_blocks.publish(self._builder.build(self._next_index, rate, self._epoch,
                                                         samples))
            if self._next_index < self._sent_end:
                self._blocks_repeated += 1
            self._next_index += n
            self._sent_end = max(self._sent_end, self._next_index)
            self._blocks_sent += 1
            budget -= 1
        if self._consumer_pacer is not None:
            self._consumer_pacer.sent(self._next_index)

    # -- announcements ---------------------------------------------------------------------

    def _publish_description(self, start_time_ns: int) -> None:
        experiment = self._experiment
        sections = [{'name': s.name, 'first_sample_index': int(first),
                     'n_samples': int(s.n_samples)}
                    for s, first in zip(experiment.sections, experiment.boundaries)]
        description = StreamDescription(
            stream='excitation', sample_rate_Hz=experiment.sample_rate_Hz,
            block_size=int(self._param('block_size')),
            channels=tuple(Channel(name, 'V', CHANNEL_TEXT.get(name, 'setpoint voltage'))
                           for name in experiment.channels),
            epoch=self._epoch, start_time_ns=start_time_ns,
            total_samples=experiment.total_samples, source=self.get_fully_qualified_name(),
            extra={'sections': sections})
        self._pub_description.publish(description_to_msg(description))

    def _status_dict(self) -> dict:
        section = ''
        if self._experiment is not None:
            current = self._experiment.section_at(self._next_index)
            section = current.name if current is not None else ''
        total = self._experiment.total_samples if self._experiment is not None else 0
        status = {'state': self._state, 'epoch': self._epoch, 'next_sample_index':
                  self._next_index, 'total_samples': total, 'section': section,
                  'error': self._error, 'waiting': self._waiting}
        if self._consumer_pacer is not None:
            status.update({'acknowledged_sample_index': self._consumer_pacer.acknowledged,
                           'resends': self._consumer_pacer.resends})
        return status

    def _publish_status(self) -> None:
        self._pub_status.publish(String(data=json.dumps(self._status_dict())))

    def _publish_done(self, done: bool) -> None:
        self._pub_done.publish(Bool(data=done))

    def published_counts(self) -> Dict[str, Dict[str, int]]:
        """
        Blocks published in the current epoch (for an in-process supervisor's accounting).

        Returns
        -------
        dict
            ``{'excitation': {'published': n, 'repeated': m}}`` [count]: ``published``
            includes the ``repeated`` blocks sent again because a window was not
            acknowledged in time.
        """
        return {'excitation': {'published': self._blocks_sent,
                               'repeated': self._blocks_repeated}}

    def _publish_diagnostics(self) -> None:
        status = self._status_dict()
        elapsed = time.monotonic() - self._started_at if self._started_at else 0.0
        rate = self._experiment.sample_rate_Hz if self._experiment else 0.0
        values = dict(status)
        values.update({'blocks_sent': self._blocks_sent,
                       'elapsed_s': f'{elapsed:.3f}',
                       'sample_rate_Hz': rate,
                       'rejected_acknowledgements': self._rejected_acks,
                       'malformed_readiness': self._bad_readiness,
                       'start_gate': self._gate.kind if self._gate is not None else '',
                       'appliers_ready': ','.join(sorted(
                           n for n, r in self._announcements.items() if r.ready))})
        if self._clock_pacer is not None and self._state == 'running':
            lag = self._clock_pacer.lag_s(time.monotonic(), self._next_index, rate)
            values['lag_s'] = f'{lag:.6f}'
        if self._state == 'error':
            level, message = DiagnosticStatus.ERROR, self._error
        elif self._waiting.startswith('start gate: '):
            level, message = DiagnosticStatus.WARN, f'{self._state}: sample 0 waits for ' \
                f'{self._waiting[len("start gate: "):]}'
        elif self._waiting:
            article = 'a' if self._waiting.startswith('consumer') else 'an'
            level, message = DiagnosticStatus.WARN, f'{self._state}: waiting for {article} ' \
                f'{self._waiting}'
        else:
            level, message = DiagnosticStatus.OK, self._state
        self._pub_diag.publish(node_diagnostics(self, 'excitation', level, message, values))


main = node_main(SignalGeneratorNode, 'signal_generator')


if __name__ == '__main__':
    raise SystemExit(main())
