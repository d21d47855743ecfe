"""
The plant_simulator node's graph checks and message builders (ROS side of its session).

What the node asks the ROS graph (outputs whose listed subscriptions have not matched yet, a
second publisher of its clock) and the messages of the session's events.
"""

from __future__ import annotations

from typing import Iterable, List, Tuple

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState

from emfc_ros.core.device_contract import JOINT
from emfc_ros.core.sim.plant_events import JointStates
from emfc_ros.core.start_gate import parse_endpoints

#: joint_states and /clock: many small messages per block. A reliable KEEP_LAST writer
#: repairs a message its reader missed (a burst of blocks filled the reader's port) only
#: after a heartbeat, which small messages do not bring with them (Fast DDS sends one
#: periodically): the history must outlast that, or the message is overwritten and lost (a
#: recorder saw one /clock tick in 400 lost with depth 100). 5000 messages hold more than
#: 10 s of the fastest simulation.
STATE_QOS = QoSProfile(depth=5000)
CLOCK_QOS = QoSProfile(depth=5000)
#: Longest wait, once min_subscribers matched, for the graph's other subscriptions to match
#: the outputs (a recorder's /clock subscription created with its measurements one) [s].
OUTPUT_MATCH_S = 5.0
#: The session's status levels as diagnostic levels.
LEVELS = {'OK': DiagnosticStatus.OK, 'WARN': DiagnosticStatus.WARN,
          'ERROR': DiagnosticStatus.ERROR}


def outputs_matched(node: Node, publishers: Iterable, waited_s: float) -> Tuple[bool, str]:
    """
    Whether every subscription the graph lists on the outputs matched, or the wait is over.

    Parameters
    ----------
    node : rclpy.node.Node
        The node that owns the publishers.
    publishers : iterable
        Its publishers (None entries are skipped).
    waited_s : float
        How long the node waited for them already [s].

    Returns
    -------
    tuple
        Go on (all matched, or :data:`OUTPUT_MATCH_S` passed), and a warning ('' if none)
        naming the outputs it goes on without.
    """
    pending = unmatched_outputs(node, publishers)
    if pending and waited_s < OUTPUT_MATCH_S:
        return False, ''
    if pending:
        return True, (f'subscriptions listed in the graph did not match in {OUTPUT_MATCH_S:g} s '
                      f'on {", ".join(pending)} (incompatible QoS, or gone): starting without '
                      'them')
    return True, ''


def unmatched_outputs(node: Node, publishers: Iterable) -> List[str]:
    """
    Output topics with fewer matched subscriptions than the graph lists.

    Parameters
    ----------
    node : rclpy.node.Node
        The node that owns the publishers.
    publishers : iterable
        Its publishers (None entries are skipped).

    Returns
    -------
    list of str
        ``topic (matched of listed)`` for each one still waiting.
    """
    out = []
    for pub in publishers:
        if pub is None:
            continue
        listed = parse_endpoints(
            (i.node_namespace, i.node_name,
             i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL)
            for i in node.get_subscriptions_info_by_topic(pub.topic_name))
        wanted = sum(1 for e in listed if e.compatible)
        if pub.get_subscription_count() < wanted:
            out.append(f'{pub.topic_name} ({pub.get_subscription_count()} of {wanted})')
    return out


def clock_conflict(node: Node, clock_pub) -> str:
    """
    Why the node must not publish its clock: another node publishes the same topic ('' if not).

    Parameters
    ----------
    node : rclpy.node.Node
        The node.
    clock_pub : rclpy.publisher.Publisher
        Its clock publisher.

    Returns
    -------
    str
        Empty, or the reason naming the other publishers.
    """
    topic = clock_pub.topic_name
    names = [i.node_namespace.rstrip('/') + '/' + i.node_name
             for i in node.get_publishers_info_by_topic(topic)]
    if len(names) <= 1:
        return ''
    others = sorted(set(n for n in names if n != node.get_fully_qualified_name()))
    return (f'{", ".join(others)} also publishes {topic}: the simulated time of two balances '
            'would mix (time running backwards in both); give each instance its own clock '
            '(launch argument clock_topic:=clock, or -r /clock:=<namespace>/clock for every '
            'node of the instance); this plant stopped simulating')


def clock_msg(stamp_ns: int) -> Clock:
    """
    The ``/clock`` message of a simulated time.

    Parameters
    ----------
    stamp_ns : int
        Simulated time [ns].

    Returns
    -------
    rosgraph_msgs.msg.Clock
        The message.
    """
    msg = Clock()
    msg.clock.sec, msg.clock.nanosec = divmod(int(stamp_ns), 10 ** 9)
    return msg


def joint_state_msgs(states: JointStates) -> List[JointState]:
    """
    One ``JointState`` of joint ``lever`` per state.

    Parameters
    ----------
    states : JointStates
        Stamps [ns], positions [m], velocities [m/s], efforts [N].

    Returns
    -------
    list of sensor_msgs.msg.JointState
        The messages, in order.
    """
    out = []
    for stamp, pos, vel, eff in zip(states.stamps_ns, states.position_m,
                                    states.velocity_m_per_s, states.effort_N):
        msg = JointState(name=[JOINT], position=[float(pos)], velocity=[float(vel)],
                         effort=[float(eff)])
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp), 10 ** 9)
        out.append(msg)
    return out
