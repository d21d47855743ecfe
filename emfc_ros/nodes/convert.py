"""
All conversions between ROS messages and core objects, plus the shared QoS profiles.

Nodes call these; the core never sees a message.
"""

from __future__ import annotations

import array
from typing import Callable, Mapping, Optional, Tuple

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rclpy.clock import Clock as RosClock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension, String

from emfc_ros.core import blocks
from emfc_ros.core.blocks import Block, StreamDescription

#: Block streams: reliable, keep last 100 (design section 2: not KEEP_ALL).
BLOCK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                       reliability=ReliabilityPolicy.RELIABLE,
                       durability=DurabilityPolicy.VOLATILE)

#: Latched topics (stream descriptions, status): a late subscriber gets the last message.
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)

#: Small control messages (acknowledgements, commands).
CONTROL_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)

#: A consumer's acknowledgements as the generator reads them: best effort. They are
#: cumulative (a later one says all an earlier one did), and a reliable reader delivers in
#: order, so one that its first transmission missed would hold every later one back until
#: the writer's periodic heartbeat repairs it (seconds, measured: the generator re-sent its
#: window). Compatible with the reliable writers of the plant and the bridge, which repeat
#: their last acknowledgement while nothing follows it.
ACK_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                     reliability=ReliabilityPolicy.BEST_EFFORT,
                     durability=DurabilityPolicy.VOLATILE)


class BlockMessageBuilder:
    """
    Fill a reusable ``Float64MultiArray`` from sample arrays with no per-block allocation.

    ``publish`` serialises synchronously, so one message and one buffer serve every block
    of the same shape.
    """

    def __init__(self) -> None:
        self._msg = Float64MultiArray()
        self._shape: Optional[Tuple[int, int]] = None
        self._buffer = array.array('d')
        self._view = np.frombuffer(self._buffer, dtype=np.float64)

    def build(self, first_sample_index: int, sample_rate_Hz: float, epoch: int,
              samples: np.ndarray) -> Float64MultiArray:
        """
        Return the message for one block (valid until the next call).

        Parameters
        ----------
        first_sample_index : int
            Index of the first sample.
        sample_rate_Hz : float
            Sample rate [Hz].
        epoch : int
            Stream epoch.
        samples : numpy.ndarray
            Shape ``(channels, n)``.

        Returns
        -------
        std_msgs.msg.Float64MultiArray
            The filled message.
        """
        shape = (int(samples.shape[0]), int(samples.shape[1]))
        if shape != self._shape:
            self._shape = shape
            self._buffer = array.array('d', bytes(8 * (blocks.HEADER_LENGTH + shape[0]
                                                       * shape[1])))
            self._view = np.frombuffer(self._buffer, dtype=np.float64)
            self._msg.layout.dim = [
                MultiArrayDimension(label=label, size=size, stride=stride)
                for label, size, stride in blocks.layout(*shape)]
            self._msg.layout.data_offset = blocks.HEADER_LENGTH
        blocks.pack_into(self._view, first_sample_index, sample_rate_Hz, epoch, samples)
        self._msg.data = self._buffer
        return self._msg


def block_to_msg(first_sample_index: int, sample_rate_Hz: float, epoch: int,
                 samples: np.ndarray) -> Float64MultiArray:
    """
    Build a new block message (allocates; use :class:`BlockMessageBuilder` in loops).

    Parameters
    ----------
    first_sample_index : int
        Index of the first sample.
    sample_rate_Hz : float
        Sample rate [Hz].
    epoch : int
        Stream epoch.
    samples : numpy.ndarray
        Shape ``(channels, n)``.

    Returns
    -------
    std_msgs.msg.Float64MultiArray
        A message of its own.
    """
    msg = Float64MultiArray()
    samples = np.asarray(samples, dtype=np.float64)
    msg.layout.dim = [MultiArrayDimension(label=label, size=size, stride=stride)
                      for label, size, stride in blocks.layout(*samples.shape)]
    msg.layout.data_offset = blocks.HEADER_LENGTH
    msg.data = array.array('d', blocks.pack(first_sample_index, sample_rate_Hz, epoch,
                                            samples).tobytes())
    return msg


def msg_to_block(msg: Float64MultiArray, expected_channels: Optional[int] = None) -> Block:
    """
    Decode a block message.

    Parameters
    ----------
    msg : std_msgs.msg.Float64MultiArray
        The message.
    expected_channels : int, optional
        Refuse blocks with another channel count.

    Returns
    -------
    Block
        The decoded block (samples are a read-only view of the message data).

    Raises
    ------
    emfc_ros.core.errors.BlockError
        If the message does not follow the block convention.
    """
    dims = [(d.label, int(d.size), int(d.stride)) for d in msg.layout.dim]
    return blocks.unpack(dims, int(msg.layout.data_offset), msg.data, expected_channels)


def description_to_msg(description: StreamDescription) -> String:
    """
    Build the latched description message.

    Parameters
    ----------
    description : StreamDescription
        The stream description.

    Returns
    -------
    std_msgs.msg.String
        JSON text.
    """
    return String(data=description.to_json())


def msg_to_description(msg: String) -> StreamDescription:
    """
    Parse a description message.

    Parameters
    ----------
    msg : std_msgs.msg.String
        The message.

    Returns
    -------
    StreamDescription
        The description.

    Raises
    ------
    emfc_ros.core.errors.BlockError
        If the text is not a stream description.
    """
    return StreamDescription.from_json(msg.data)


def diagnostic_status(name: str, hardware_id: str, level: bytes, message: str,
                      values: Mapping[str, object]) -> DiagnosticStatus:
    """
    Build one diagnostic status with key-value pairs.

    Parameters
    ----------
    name : str
        Status name, conventionally ``'<node>: <aspect>'``.
    hardware_id : str
        Device or simulator identifier.
    level : bytes
        ``DiagnosticStatus.OK``, ``WARN``, ``ERROR`` or ``STALE``.
    message : str
        Summary.
    values : Mapping
        Values; keys state their unit (for example ``'rate_Hz'``).

    Returns
    -------
    diagnostic_msgs.msg.DiagnosticStatus
        The status.
    """
    return DiagnosticStatus(level=level, name=name, message=message,
                            hardware_id=hardware_id,
                            values=[KeyValue(key=str(k), value=str(v))
                                    for k, v in values.items()])


def node_diagnostics(node: object, aspect: str, level: bytes, message: str,
                     values: Mapping[str, object]) -> DiagnosticArray:
    """
    A node's periodic ``/diagnostics`` message: one status, stamped with the node's clock.

    Parameters
    ----------
    node : rclpy.node.Node
        The node (its name, fully qualified name and clock).
    aspect : str
        What the status is about; the status is named ``'<node>: <aspect>'``.
    level : bytes
        ``DiagnosticStatus.OK``, ``WARN``, ``ERROR`` or ``STALE``.
    message : str
        Summary.
    values : Mapping
        Values; keys state their unit.

    Returns
    -------
    diagnostic_msgs.msg.DiagnosticArray
        The message, ready to publish.
    """
    msg = DiagnosticArray()
    msg.header.stamp = node.get_clock().now().to_msg()
    msg.status = [diagnostic_status(f'{node.get_name()}: {aspect}',
                                    node.get_fully_qualified_name(), level, message, values)]
    return msg


def subscribe_device_inputs(node: Node, on_excitation: Optional[Callable],
                            on_joint_command: Callable, on_array_command: Callable) -> None:
    """
    Subscribe a node to the inputs of the device interface (design section 4).

    The plant simulator and the daq_bridge take the same inputs: excitation blocks on
    ``excitation`` and controller commands on ``joint_commands`` (JointState, effort [N]) and
    ``commands`` (Float64MultiArray, [N]).

    Parameters
    ----------
    node : rclpy.node.Node
        The node.
    on_excitation, on_joint_command, on_array_command : callable
        The callbacks, in that order; ``on_excitation`` None: no excitation subscription
        (the node subscribes later, :func:`subscribe_excitation`).
    """
    if on_excitation is not None:
        subscribe_excitation(node, on_excitation)
    node.create_subscription(JointState, 'joint_commands', on_joint_command, CONTROL_QOS)
    node.create_subscription(Float64MultiArray, 'commands', on_array_command, CONTROL_QOS)


def subscribe_excitation(node: Node, on_excitation: Callable) -> None:
    """
    Subscribe a node to excitation blocks on ``excitation``.

    Parameters
    ----------
    node : rclpy.node.Node
        The node.
    on_excitation : callable
        Called with each ``std_msgs/Float64MultiArray`` block.
    """
    node.create_subscription(Float64MultiArray, 'excitation', on_excitation, BLOCK_QOS)


def steady_clock() -> RosClock:
    """
    A steady (monotonic wall) clock for timers that must not follow ``/clock``.

    Watchdogs, device polling, discovery and diagnostics run in wall time whatever
    ``use_sim_time`` says (under simulated time a node-clock timer stops while ``/clock``
    does not tick and fires in bursts while it runs fast).

    Returns
    -------
    rclpy.clock.Clock
        A new clock of type ``STEADY_TIME``.
    """
    return RosClock(clock_type=ClockType.STEADY_TIME)
