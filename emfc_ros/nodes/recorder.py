"""
The recorder node: record topics to a rosbag2 bag (metadata version 9, MCAP storage).

A pure-Python stand-in for ``ros2 bag record -s mcap`` (rosbag2 is not installable from
PyPI) with what an EMFC experiment needs on top: the experiment description, every other
node's parameters and the package version in the bag's ``custom_data``, and crash safety
(data reach the disk every ``flush_period_s``; ``emfc-bag-repair`` makes a killed
recording readable). Messages are subscribed to raw (serialized CDR, never deserialised)
with a QoS matching the publishers' offered QoS, stamped with the receive time on the node's
clock and written by a writer thread fed through a queue, so the executor never waits for the
disk. With ``use_sim_time`` (a simulator that owns time publishes ``/clock``) the stamps, and
so the bag's start and duration, are simulated time, as with ``ros2 bag record
--use-sim-time``; record ``/clock`` too for ``ros2 bag play --clock``. The bag's custom data
say which clock stamped it (``emfc_ros.clock``: ``simulated`` or ``wall``) and keep the wall
time the recording started (``emfc_ros.start_time_ns``). Timers (discovery, diagnostics) run
on the steady clock whatever the node clock.

Topics (relative to the node namespace):

- every recorded topic (in): ``topics``, or all topics but ``/rosout`` and
  ``/parameter_events`` when empty;
- ``~/status`` (``std_msgs/String``, out, latched): JSON with state, output, files, counters
  and error;
- ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``, out, 1 Hz): messages and bytes per
  topic, queue depth, dropped messages, files written; ERROR after a write error.

Services (``std_srvs/Trigger``, private so that they never clash with the signal generator's
``start``/``stop`` in the same namespace): ``~/start`` (open the bag and record), ``~/stop``
(close the bag properly).
"""

from __future__ import annotations

import datetime
import importlib
import json
import os
from pathlib import Path
import time
from typing import Dict, List, Optional, Tuple

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rcl_interfaces.srv import GetParameters, ListParameters
from rclpy.clock import Clock as RosClock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.exceptions import ParameterUninitializedException
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from std_msgs.msg import String
from std_srvs.srv import Trigger
import yaml

from emfc_ros import __version__
from emfc_ros.core.bag import (
    BagWriter, MessageTypeError, MessageTypes, OfferedQos, QueuedBagWriter)
from emfc_ros.core.bag.qos import DURABILITY, HISTORY, LIVELINESS, policy_name, RELIABILITY
from emfc_ros.core.config import unflatten
from emfc_ros.core.device.faults import faults_from_extra
from emfc_ros.core.errors import ConfigError
from emfc_ros.core.json_text import load_json_text
from emfc_ros.core.safe_yaml import load_yaml_text, one_line, YamlRefused
from emfc_ros.nodes.convert import LATCHED_QOS, node_diagnostics
from emfc_ros.nodes.params import declare_table, pending_refusals, refuse_unknown
from emfc_ros.nodes.spin import node_logger, node_main

EXCLUDED_TOPICS = ('/rosout', '/parameter_events')
DESCRIPTION_SUFFIX = 'excitation/description'
STREAM_DESCRIPTION_SUFFIX = '/description'
STRING_TYPE = 'std_msgs/msg/String'

# name: (default, description with units); 'topics' is declared as a typed string array.
PARAMETERS = {
    'output': ('', 'bag folder to create [path]; refused if it exists and is not empty; '
                   "empty: 'rosbag2_<YYYY_MM_DD-HH_MM_SS>' in the working directory"),
    'max_bag_size_B': (0, 'split the bag into a new MCAP file at this size [bytes]; '
                          '0: no size split'),
    'max_bag_duration_s': (0.0, 'split the bag into a new MCAP file after this much '
                                'recorded time [s]; 0: no duration split'),
    'discovery_period_s': (0.1, 'period of the topic (and node) discovery [s], 0.01 to 60 '
                                '(ros2 bag record polls every 0.1 s too)'),
    'flush_period_s': (1.0, 'data reach the disk at least this often [s], 0.01 to 60: a '
                            'killed recorder loses at most about this much'),
    'autostart': (True, 'start recording when the node comes up'),
    'experiment_description': ('', 'experiment configuration as YAML text, stored in the '
                                   "bag's custom_data 'emfc_ros.experiment'; empty: the "
                                   'latest <ns>/excitation/description message recorded'),
    'custom_data': ('', "YAML mapping of extra entries for the bag's custom_data (key: text "
                        'or mapping, a mapping stored as YAML text), written when recording '
                        'starts; set while recording, its entries are added to (or replace '
                        'those of) the open bag; the experiment runner stores the '
                        'identification options, the plant configuration (pan load) and, at '
                        'the end, the message accounting per stream here'),
    'subscription_depth': (1000, 'history depth of the recording subscriptions [messages], '
                                 '1 to 100000'),
    'max_queue_messages': (100000, 'bound of the writer queue [messages], 10 to 10000000; '
                                   'beyond it messages are dropped and counted'),
    'max_queue_B': (1 << 30, 'bound of the writer queue [bytes], 1e6 to 2**40; beyond it '
                             'messages are dropped and counted'),
    'parameter_timeout_s': (2.0, "bound on fetching another node's parameters [s], "
                                 '0.1 to 60'),
}
TOPICS_TEXT = ('topics to record (string array, names resolved in the node namespace); '
               'empty or unset: every topic except /rosout and /parameter_events')
LIMITS = {'max_bag_size_B': (0, 2 ** 62), 'max_bag_duration_s': (0.0, 1e9),
          'discovery_period_s': (0.01, 60.0), 'flush_period_s': (0.01, 60.0),
          'subscription_depth': (1, 100000), 'max_queue_messages': (10, 10_000_000),
          'max_queue_B': (1_000_000, 2 ** 40),
          'parameter_timeout_s': (0.1, 60.0)}
#: Shown in the start-up log line (with every parameter set to a non-default value).
STARTUP_KEYS = ('output', 'autostart')
HELP_EXTRA = f'topics: string array, unset; {TOPICS_TEXT}.'
FIXED_WHILE_RECORDING = ('output', 'topics', 'max_bag_size_B', 'max_bag_duration_s',
                         'flush_period_s', 'subscription_depth', 'max_queue_messages',
                         'max_queue_B')


def custom_entries(text: str) -> Dict[str, str]:
    """
    The ``custom_data`` parameter as key to text.

    Parameters
    ----------
    text : str
        YAML mapping (empty: none).

    Returns
    -------
    dict of str to str
        Mappings and lists dumped as YAML text.

    Raises
    ------
    ValueError
        If the text is not a YAML mapping with string keys.
    """
    if not text.strip():
        return {}
    try:
        doc = load_yaml_text(text, 'parameter custom_data')
    except YamlRefused as exc:
        raise ValueError(str(exc)) from None
    except yaml.YAMLError as exc:
        raise ValueError(f'custom_data must be a YAML mapping: {one_line(exc)}') from None
    if not isinstance(doc, dict) or not all(isinstance(k, str) for k in doc):
        raise ValueError('custom_data must be a YAML mapping with string keys')
    return {k: v if isinstance(v, str) else yaml.safe_dump(v, sort_keys=False)
            for k, v in doc.items()}


def _msg_class(msgtype: str):
    package, kind, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)


def _offered(info) -> OfferedQos:
    q = info.qos_profile
    return OfferedQos(
        history=policy_name(HISTORY, q.history), depth=int(q.depth),
        reliability=policy_name(RELIABILITY, q.reliability),
        durability=policy_name(DURABILITY, q.durability),
        deadline_ns=int(q.deadline.nanoseconds), lifespan_ns=int(q.lifespan.nanoseconds),
        liveliness=policy_name(LIVELINESS, q.liveliness),
        liveliness_lease_duration_ns=int(q.liveliness_lease_duration.nanoseconds),
        avoid_ros_namespace_conventions=bool(q.avoid_ros_namespace_conventions))


def subscription_qos(publishers, depth: int) -> QoSProfile:
    """
    A subscription QoS compatible with every publisher (as ``ros2 bag record`` chooses).

    Parameters
    ----------
    publishers : list of rclpy.topic_endpoint_info.TopicEndpointInfo
        The topic's publishers.
    depth : int
        History depth [messages].

    Returns
    -------
    rclpy.qos.QoSProfile
        Reliable if all publishers are reliable, transient-local if all are, keep last.
    """
    reliable = bool(publishers) and all(
        p.qos_profile.reliability == ReliabilityPolicy.RELIABLE for p in publishers)
    latched = bool(publishers) and all(
        p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in publishers)
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


class _ParameterFetch:
    """Fetch one remote node's parameters with list_parameters, then get_parameters."""

    def __init__(self, node: Node, fqn: str, deadline: float) -> None:
        self.fqn = fqn
        self.deadline = deadline
        self.node = node
        self.list_client = node.create_client(ListParameters, f'{fqn}/list_parameters')
        self.get_client = node.create_client(GetParameters, f'{fqn}/get_parameters')
        self.names: List[str] = []
        self.future = None
        self.stage = 'wait'
        self.result: Optional[dict] = None
        self.error = ''

    def step(self, now: float) -> bool:
        """Advance; return True when finished (result or error set)."""
        if self.stage == 'wait':
            if self.list_client.service_is_ready() and self.get_client.service_is_ready():
                self.future = self.list_client.call_async(ListParameters.Request())
                self.stage = 'list'
        elif self.stage == 'list' and self.future.done():
            self.names = sorted(self.future.result().result.names)
            self.future = self.get_client.call_async(GetParameters.Request(names=self.names))
            self.stage = 'get'
        elif self.stage == 'get' and self.future.done():
            values = self.future.result().values
            flat = {n: parameter_value_to_python(v) for n, v in zip(self.names, values)}
            self.result = flat
            self.stage = 'done'
            return True
        if now > self.deadline:
            self.error = f'no answer within the timeout (stage {self.stage})'
            self.stage = 'done'
            return True
        return False

    def destroy(self) -> None:
        self.node.destroy_client(self.list_client)
        self.node.destroy_client(self.get_client)


def _plain(value):
    if isinstance(value, (str, bool, int, float)) or value is None:
        return value
    if isinstance(value, bytes):
        return list(value)
    return [_plain(v) for v in value]


def parameters_yaml(parameters: Dict[str, dict], unreachable: Dict[str, str]) -> str:
    """
    Other nodes' parameters as a ROS params file (``<node>: {ros__parameters: ...}``).

    Parameters
    ----------
    parameters : dict
        Fully qualified node name to flat ``{parameter: value}``.
    unreachable : dict
        Node name to the reason its parameters are missing.

    Returns
    -------
    str
        YAML text usable with ``--params-file``; unreachable nodes listed under
        ``_unreachable``.
    """
    doc: dict = {}
    for fqn, flat in sorted(parameters.items()):
        values = {k: _plain(v) for k, v in flat.items()}
        try:
            nested = unflatten(values)
        except ConfigError:
            nested = values
        doc[fqn] = {'ros__parameters': nested}
    if unreachable:
        doc['_unreachable'] = dict(sorted(unreachable.items()))
    return yaml.safe_dump(doc, default_flow_style=False, sort_keys=False)


class RecorderNode(Node):
    """
    Record topics raw into a rosbag2 bag with MCAP storage.

    Parameters
    ----------
    **kwargs
        Passed to :class:`rclpy.node.Node` (for example ``parameter_overrides``).
    """

    def __init__(self, **kwargs) -> None:
        super().__init__('recorder', **kwargs)
        # Floats accept integers too (`-p flush_period_s:=2`), taken as floats.
        refused = declare_table(self, PARAMETERS, LIMITS)
        refused += refuse_unknown(self, ['topics'])
        self.declare_parameter('topics', Parameter.Type.STRING_ARRAY,
                               ParameterDescriptor(description=TOPICS_TEXT))
        self._state = 'idle'
        self._error = ''
        self._output: Optional[Path] = None
        self._writer: Optional[QueuedBagWriter] = None
        self._recorded: Dict[str, Tuple[object, int]] = {}
        self._faults: Dict[tuple, dict] = {}
        # Messages the middleware reports lost before they reached a subscription, per topic.
        self._lost: Dict[str, int] = {}
        # Descriptions and experiment documents that did not parse (recorded anyway).
        self._bad_descriptions = 0
        self._bad_description_error = ''
        self._unrecordable: Dict[str, str] = {}
        self._fetches: Dict[str, _ParameterFetch] = {}
        self._node_parameters: Dict[str, dict] = {}
        self._unreachable: Dict[str, str] = {}
        self._types = MessageTypes(os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep))
        self._discovery_timer = None
        self._reported_error = ''

        self._pub_status = self.create_publisher(String, '~/status', LATCHED_QOS)
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_service(Trigger, '~/start', self._srv_start)
        self.create_service(Trigger, '~/stop', self._srv_stop)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._after_set_parameters)
        self._steady = RosClock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(1.0, self._publish_diagnostics, clock=self._steady)
        initial = self._on_set_parameters([self.get_parameter(n) for n in PARAMETERS])
        if refused:     # not recording with values nobody asked for
            initial = SetParametersResult(successful=False, reason='; '.join(refused))
        if not initial.successful:
            self._state, self._error = 'error', initial.reason
            self.get_logger().error(f'invalid parameter: {initial.reason}; set a valid value '
                                    'and call ~/start')
        elif self._param('autostart'):
            self._start()
        self._publish_status()

    # -- configuration ---------------------------------------------------------------------

    def _param(self, name: str):
        return self.get_parameter(name).value

    def _topics_param(self) -> List[str]:
        try:
            value = self.get_parameter('topics').value
        except ParameterUninitializedException:
            return []
        return [t for t in (value or []) if t]

    def _on_set_parameters(self, params: List[Parameter]) -> SetParametersResult:
        for p in params:
            if p.name in LIMITS:
                lo, hi = LIMITS[p.name]
                kinds = (Parameter.Type.INTEGER,) if isinstance(lo, int) else (
                    Parameter.Type.DOUBLE, Parameter.Type.INTEGER)
                if p.type_ not in kinds or not lo <= p.value <= hi:
                    what = 'an integer' if len(kinds) == 1 else 'a number'
                    return SetParametersResult(
                        successful=False,
                        reason=f'{p.name} must be {what} from {lo} to {hi}, got {p.value!r}')
            elif p.name in ('output', 'experiment_description', 'custom_data') and \
                    p.type_ != Parameter.Type.STRING:
                return SetParametersResult(successful=False,
                                           reason=f'{p.name} must be a string')
            elif p.name == 'custom_data':
                try:
                    custom_entries(p.value)
                except ValueError as exc:
                    return SetParametersResult(successful=False, reason=str(exc))
            elif p.name == 'autostart' and p.type_ != Parameter.Type.BOOL:
                return SetParametersResult(successful=False,
                                           reason='autostart must be true or false')
            if p.name in FIXED_WHILE_RECORDING and self._state == 'recording':
                return SetParametersResult(
                    successful=False, reason=f'cannot change {p.name} while recording; call '
                                             '~/stop first')
        return SetParametersResult(successful=True)

    def _after_set_parameters(self, params: List[Parameter]) -> None:
        """Add the entries of a ``custom_data`` set while recording to the open bag."""
        for p in params:
            if p.name == 'custom_data' and self._writer is not None:
                for key, text in custom_entries(p.value).items():
                    self._writer.set_custom_data(key, text)

    # -- state machine ---------------------------------------------------------------------

    def _start(self) -> Tuple[bool, str]:
        if self._writer is not None:
            return False, (f'a recording to {self._output} is open (state {self._state}); '
                           'call ~/stop first')
        output = self._param('output') or datetime.datetime.now().strftime(
            'rosbag2_%Y_%m_%d-%H_%M_%S')
        path = Path(output).expanduser().absolute()
        try:
            writer = BagWriter(path, max_bag_size_B=int(self._param('max_bag_size_B')),
                               max_bag_duration_ns=int(round(
                                   float(self._param('max_bag_duration_s')) * 1e9)),
                               types=self._types)
            queued = QueuedBagWriter(writer, float(self._param('flush_period_s')),
                                     int(self._param('max_queue_messages')),
                                     int(self._param('max_queue_B')))
            queued.start()
        except (OSError, ValueError) as exc:
            self._state, self._error = 'error', str(exc)
            self._reported_error = self._error  # logged here, not again by diagnostics
            self._output = path
            self.get_logger().error(f'cannot record: {exc}')
            self._publish_status()
            return False, str(exc)
        self._writer = queued
        self._output = path
        self._state, self._error, self._reported_error = 'recording', '', ''
        self._recorded = {}
        self._unrecordable = {}
        self._node_parameters, self._unreachable, self._fetches = {}, {}, {}
        self._faults = {}
        self._lost = {}
        queued.set_custom_data('emfc_ros.version', __version__)
        # Wall time, whatever clock stamps the messages (simulated time starts near 0).
        queued.set_custom_data('emfc_ros.start_time_ns', str(time.time_ns()))
        queued.set_custom_data('emfc_ros.clock', self._clock_kind())
        description = self._param('experiment_description')
        if description:
            queued.set_custom_data('emfc_ros.experiment', description)
        for key, text in custom_entries(self._param('custom_data')).items():
            queued.set_custom_data(key, text)
        self._discover()
        self._discovery_timer = self.create_timer(float(self._param('discovery_period_s')),
                                                  self._discover, clock=self._steady)
        self._publish_status()
        self.get_logger().info(f'recording to {path} (stamps: {self._clock_kind()} time)')
        return True, f'recording to {path}'

    def _clock_kind(self) -> str:
        """'simulated' when the node clock is ``/clock`` (``use_sim_time``), else 'wall'."""
        return 'simulated' if self.get_parameter('use_sim_time').value else 'wall'

    def end_subscriptions(self) -> None:
        """
        Take no more messages (the bag stays open): what is written from now on is final.

        An in-process supervisor calls this before it reads :meth:`written_messages` for the
        bag's own accounting, so that no message arriving between the count and the close
        makes the bag hold more than its counts say.
        """
        if self._discovery_timer is not None:
            self.destroy_timer(self._discovery_timer)
            self._discovery_timer = None
        for sub, _ in self._recorded.values():
            self.destroy_subscription(sub)
        self._recorded = {}

    def queued_messages(self) -> int:
        """
        Messages taken but not yet written to the bag.

        Returns
        -------
        int
            The writer's queue depth (0 when not recording).
        """
        return self._writer.stats().queue_depth if self._writer is not None else 0

    def _stop(self) -> Tuple[bool, str]:
        if self._writer is None:
            return False, f'not recording (state {self._state})'
        self.end_subscriptions()
        self._finish_fetches(force=True)
        stats = self._writer.stop()
        self._writer = None
        if stats.state == 'error':
            self._state, self._error = 'error', stats.error
            self._publish_status()
            return False, f'bag {self._output} ended with an error: {stats.error}'
        self._state = 'stopped'
        self._publish_status()
        message = (f'closed {self._output}: {stats.total_messages} messages in '
                   f'{len(stats.files)} files, {stats.dropped} dropped')
        node_logger(self).info(message)     # after Ctrl-C: the console only
        return True, message

    def _srv_start(self, request: Trigger.Request, response: Trigger.Response):
        refused = pending_refusals(self)    # not with a default nobody asked for
        response.success, response.message = (False, refused) if refused else self._start()
        return response

    def _srv_stop(self, request: Trigger.Request, response: Trigger.Response):
        response.success, response.message = self._stop()
        return response

    def destroy_node(self) -> None:
        """Close the bag properly, then destroy the node."""
        if self._writer is not None:
            self._stop()
        super().destroy_node()

    # -- discovery and recording -----------------------------------------------------------

    def _wanted(self, topic: str, explicit: List[str]) -> bool:
        if explicit:
            return topic in explicit
        return topic not in EXCLUDED_TOPICS and not any(
            part.startswith('_') for part in topic.split('/'))

    def _discover(self) -> None:
        if self._writer is None:
            return
        explicit = [self.resolve_topic_name(t) for t in self._topics_param()]
        for topic, types in self.get_topic_names_and_types():
            if topic in self._recorded or topic in self._unrecordable or \
                    not self._wanted(topic, explicit):
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue
            self._subscribe(topic, types[0], publishers)
        self._fetch_parameters()

    def _subscribe(self, topic: str, msgtype: str, publishers) -> None:
        try:
            msg_class = _msg_class(msgtype)
            cid = self._writer.add_connection(topic, msgtype,
                                              [_offered(p) for p in publishers])
        except (ImportError, AttributeError, ValueError, MessageTypeError) as exc:
            self._unrecordable[topic] = f'{msgtype}: {exc}'
            self.get_logger().warning(f'cannot record {topic} ({msgtype}): {exc}')
            return
        qos = subscription_qos(publishers, int(self._param('subscription_depth')))
        put = self._writer.put
        clock = self.get_clock()
        if topic.endswith(DESCRIPTION_SUFFIX) and msgtype == STRING_TYPE:
            def callback(raw, cid=cid):
                put(cid, clock.now().nanoseconds, raw)
                self._on_description(raw)
        elif topic.endswith(STREAM_DESCRIPTION_SUFFIX) and msgtype == STRING_TYPE:
            def callback(raw, cid=cid, topic=topic):
                put(cid, clock.now().nanoseconds, raw)
                self._on_stream_description(topic, raw)
        else:
            def callback(raw, cid=cid):
                put(cid, clock.now().nanoseconds, raw)
        sub = self.create_subscription(
            msg_class, topic, callback, qos, raw=True,
            event_callbacks=SubscriptionEventCallbacks(
                message_lost=lambda info, topic=topic: self._on_lost(topic, info)))
        self._recorded[topic] = (sub, cid)
        self.get_logger().info(f'recording {topic} ({msgtype}, {qos.reliability.name}, '
                               f'{qos.durability.name})')

    def _on_lost(self, topic: str, info) -> None:
        """Messages lost in transport (a publisher's history overran): counted, kept."""
        if self._writer is None:
            return
        self._lost[topic] = self._lost.get(topic, 0) + int(info.total_count_change)
        self.get_logger().error(
            f'{topic}: {info.total_count_change} message(s) lost before they reached the '
            f'recorder ({self._lost[topic]} in all): the bag has gaps (custom data '
            'emfc_ros.lost_messages)', throttle_duration_sec=5.0)
        self._writer.set_custom_data('emfc_ros.lost_messages',
                                     yaml.safe_dump(dict(self._lost), sort_keys=True))

    def _bad_description(self, topic: str, exc: Exception) -> None:
        """A description that did not parse: recorded as it came, counted and reported."""
        self._bad_descriptions += 1
        self._bad_description_error = f'{topic}: {exc}'
        self.get_logger().warning(f'malformed description on {topic} (recorded as received, '
                                  f'not interpreted): {exc}', throttle_duration_sec=5.0)

    def _on_description(self, raw: bytes) -> None:
        if self._param('experiment_description') or self._writer is None:
            return
        try:
            doc = load_json_text(deserialize_message(raw, String).data,
                                 'experiment description')
        except (ValueError, TypeError) as exc:
            self._bad_description('excitation/description', exc)
            return
        self._writer.set_custom_data('emfc_ros.experiment', yaml.safe_dump(
            doc, default_flow_style=False, sort_keys=True))

    def _on_stream_description(self, topic: str, raw: bytes) -> None:
        """Keep the device faults a stream description reports in the bag's custom data."""
        if self._writer is None:
            return
        try:
            doc = load_json_text(deserialize_message(raw, String).data, 'stream description')
            if not isinstance(doc, dict):
                raise ValueError(f'a stream description is a JSON object, got '
                                 f'{type(doc).__name__}')
            extra = doc.get('extra') or {}
            if not isinstance(extra, dict):
                raise ValueError(f'extra must be an object, got {type(extra).__name__}')
            faults = faults_from_extra(extra)
        except (ValueError, TypeError, AttributeError) as exc:
            self._bad_description(topic, exc)
            return
        new = False
        for fault in faults:
            # one record per kind and epoch, as the bridge latches them: a fault it widens
            # (a driver's exact index after the health counters' estimate) replaces its
            # earlier record instead of standing beside it
            key = (topic, fault.epoch, fault.kind)
            record = dict(fault.to_dict(), topic=topic)
            if self._faults.get(key) != record:
                new = new or key not in self._faults
                self._faults[key] = record
        if new:
            self.get_logger().error(f'{topic} reports device faults: the recording holds data '
                                    'whose excitation was not applied (bag custom data '
                                    'emfc_ros.faults)')
        if faults:
            self._writer.set_custom_data('emfc_ros.faults', yaml.safe_dump(
                list(self._faults.values()), sort_keys=False))

    def _fetch_parameters(self) -> None:
        me = self.get_fully_qualified_name()
        deadline = time.monotonic() + float(self._param('parameter_timeout_s'))
        for name, namespace in self.get_node_names_and_namespaces():
            fqn = (namespace.rstrip('/') + '/' + name) if namespace != '/' else '/' + name
            if fqn == me or name.startswith('_') or fqn in self._fetches or \
                    fqn in self._node_parameters or fqn in self._unreachable:
                continue
            self._fetches[fqn] = _ParameterFetch(self, fqn, deadline)
        self._finish_fetches(force=False)

    def _finish_fetches(self, force: bool) -> None:
        now = time.monotonic()
        changed = False
        for fqn, fetch in list(self._fetches.items()):
            try:
                finished = fetch.step(now)
            except Exception as exc:  # a malformed or failed answer: note it, never crash
                fetch.error, finished = f'{type(exc).__name__}: {exc}', True
            if finished or force:
                if fetch.result is not None:
                    self._node_parameters[fqn] = fetch.result
                else:
                    self._unreachable[fqn] = fetch.error or 'recording stopped first'
                fetch.destroy()
                del self._fetches[fqn]
                changed = True
        if changed and self._writer is not None:
            self._writer.set_custom_data('emfc_ros.node_parameters', parameters_yaml(
                self._node_parameters, self._unreachable))

    # -- status ----------------------------------------------------------------------------

    def recorded_topics(self) -> List[str]:
        """
        Topics the recorder has subscribed to (for in-process supervisors).

        Returns
        -------
        list of str
            Fully qualified topic names.
        """
        return sorted(self._recorded)

    def recorded_faults(self) -> int:
        """
        Device faults the recorded stream descriptions reported (for in-process supervisors).

        Returns
        -------
        int
            Distinct faults kept in the bag's custom data ``emfc_ros.faults``.
        """
        return len(self._faults)

    def written_messages(self) -> Dict[str, int]:
        """
        Messages written to the bag so far, per topic (for in-process supervisors).

        Returns
        -------
        dict
            Topic name to message count; empty before recording starts.
        """
        return dict(self._writer.stats().messages) if self._writer is not None else {}

    def _status_dict(self) -> dict:
        status = {'state': self._state, 'output': str(self._output or ''),
                  'error': self._error, 'topics': sorted(self._recorded),
                  'device_faults': len(self._faults),
                  'lost_messages': sum(self._lost.values()),
                  'bad_descriptions': self._bad_descriptions,
                  'unrecordable': dict(self._unrecordable)}
        if self._writer is not None:
            stats = self._writer.stats()
            if stats.state == 'error' and self._state == 'recording':
                self._state, self._error = 'error', stats.error
                status.update(state=self._state, error=self._error)
            status.update(files=stats.files, messages=stats.total_messages,
                          bytes_B=stats.total_bytes, dropped=stats.dropped,
                          queue_depth=stats.queue_depth)
        return status

    def _publish_status(self) -> None:
        status = json.dumps(self._status_dict())
        if self.context.ok():  # not after Ctrl-C: destroy_node closes the bag then
            self._pub_status.publish(String(data=status))

    def _publish_diagnostics(self) -> None:
        if self._fetches:
            self._finish_fetches(force=False)
        status = self._status_dict()
        values = {k: status[k] for k in ('state', 'output') if k in status}
        level = DiagnosticStatus.OK
        message = self._state
        if self._writer is not None:
            stats = self._writer.stats()
            values.update({'files_written': len(stats.files), 'files': ' '.join(stats.files),
                           'messages': stats.total_messages, 'bytes_B': stats.total_bytes,
                           'queue_depth': stats.queue_depth,
                           'queue_high_water': stats.queue_high_water,
                           'dropped': stats.dropped, 'flushes': stats.flushes})
            for topic in sorted(stats.messages):
                values[f'messages {topic}'] = stats.messages[topic]
                values[f'bytes_B {topic}'] = stats.bytes[topic]
            if stats.dropped:
                level, message = DiagnosticStatus.WARN, f'{stats.dropped} messages dropped'
        values['bad_descriptions'] = self._bad_descriptions
        if self._bad_descriptions:
            values['bad_description_error'] = self._bad_description_error
            if level == DiagnosticStatus.OK:
                level = DiagnosticStatus.WARN
                message = (f'{self._bad_descriptions} malformed description(s) recorded as '
                           'received, not interpreted')
        if self._lost:
            values['lost_messages'] = sum(self._lost.values())
            values.update({f'lost {t}': n for t, n in sorted(self._lost.items())})
            level, message = DiagnosticStatus.ERROR, (
                f'{sum(self._lost.values())} message(s) lost before they reached the recorder: '
                'the bag has gaps (custom data emfc_ros.lost_messages)')
        if self._faults:
            values['device_faults'] = len(self._faults)
            level, message = DiagnosticStatus.ERROR, (
                f'{len(self._faults)} device fault(s) recorded: the bag holds data whose '
                'excitation was not applied (custom data emfc_ros.faults)')
        if self._state == 'error':
            level, message = DiagnosticStatus.ERROR, self._error
            values['error'] = self._error
            if self._error != self._reported_error:
                self._reported_error = self._error
                self.get_logger().error(f'recording failed: {self._error}; what was '
                                        f'written stays repairable with `emfc-bag-repair '
                                        f'{self._output}`')
        self._publish_status()
        self._pub_diag.publish(node_diagnostics(self, 'bag', level, message, values))


main = node_main(RecorderNode, 'recorder',
                 note='The bag is closed properly on Ctrl-C.')


if __name__ == '__main__':
    raise SystemExit(main())
