"""
No description or status text crashes a node: deep nesting, wrong types, garbage.

``'[' * 100000`` makes ``json.loads`` raise ``RecursionError`` (not a ``ValueError``); a
document nested 500 levels deep parses, then breaks whoever walks it recursively (the
recorder's YAML dump into the bag's custom data). Every node that parses descriptions gets
each of them on a real topic (in-process nodes over DDS): it must keep running, count the
refusal, say so, and go on to take a valid description afterwards.
"""

import json

import rclpy
from rclpy.parameter import Parameter
from std_msgs.msg import String

from emfc_ros.core.blocks import Channel, StreamDescription
from emfc_ros.core.errors import BlockError
from emfc_ros.core.json_text import JsonRefused, load_json_text, MAX_JSON_DEPTH
from emfc_ros.nodes.convert import description_to_msg, LATCHED_QOS
from emfc_ros.nodes.identifier import IdentifierNode
from emfc_ros.nodes.recorder import RecorderNode
from emfc_ros.nodes.weighing import WeighingNode
import ros_harness
from ros_harness import scaled

TIMEOUT_S = scaled(20.0)
VALID = StreamDescription('measurements', 10000.0, 1000,
                          (Channel('coil_current_precise_A', 'A'), Channel('position_m', 'm')))
#: Each is refused: too deep to parse at all, parses but nested too deep, a deep ``extra``
#: inside an otherwise valid description, not an object, an object of another convention.
HOSTILE = ['[' * 100000,
           '[' * 500 + ']' * 500,
           json.dumps(dict(json.loads(VALID.to_json()),
                           extra={'x': json.loads('[' * 300 + ']' * 300)})),
           '[1, 2, 3]',
           '{"convention": "something else"}']


def test_the_bounded_parser_refuses_every_hostile_text_with_one_error_class():
    for text in HOSTILE[:3]:
        try:
            load_json_text(text, 'probe')
        except JsonRefused as exc:
            assert 'nested' in str(exc) and 'probe' in str(exc)
        else:
            raise AssertionError(f'accepted {text[:40]}...')
    assert load_json_text('[' * MAX_JSON_DEPTH + ']' * MAX_JSON_DEPTH) is not None
    for text in HOSTILE:
        try:
            StreamDescription.from_json(text)
        except BlockError:
            continue
        raise AssertionError(f'description accepted: {text[:40]}...')
    assert StreamDescription.from_json(VALID.to_json()) == VALID


class Publisher:
    """Publishes raw strings on latched description topics once they are matched."""

    def __init__(self, context, executor, topics):
        self.node = rclpy.create_node('hostile', context=context)
        self.executor = executor
        self.pubs = {t: self.node.create_publisher(String, t, LATCHED_QOS) for t in topics}
        executor.add_node(self.node)

    def matched(self):
        return all(p.get_subscription_count() >= 1 for p in self.pubs.values())

    def send(self, topic, text, settle, state=lambda: ''):
        self.pubs[topic].publish(String(data=text))
        assert ros_harness.spin_until(self.executor, settle, TIMEOUT_S), \
            f'{topic}: {text[:40]}...: {state()}'


def test_identifier_counts_hostile_descriptions_and_takes_a_valid_one(executor, ros_context):
    node = IdentifierNode(context=ros_context, parameter_overrides=[])
    executor.add_node(node)
    pub = Publisher(ros_context, executor, ['measurements/description',
                                            'excitation/description'])
    assert ros_harness.spin_until(executor, pub.matched, TIMEOUT_S)
    for topic in pub.pubs:
        for text in HOSTILE:
            before = node._malformed
            pub.send(topic, text, lambda: node._malformed == before + 1)
    assert node._malformed == 2 * len(HOSTILE)
    assert 'description' in node._last_error
    pub.send('measurements/description', VALID.to_json(),
             lambda: node._names == VALID.channel_names)


def test_weighing_counts_hostile_descriptions_and_takes_a_valid_one(executor, ros_context):
    # VALID states no channel resolution (extra.resolution), which the weighing node needs
    # for its uncertainty budget: the converter steps are given as parameters instead.
    node = WeighingNode(context=ros_context, parameter_overrides=[
        Parameter('current_resolution_A', value=1.0e-7),
        Parameter('dynamic_position_noise_m_rms', value=1.0e-9)])
    executor.add_node(node)
    pub = Publisher(ros_context, executor, ['measurements/description'])
    assert ros_harness.spin_until(executor, pub.matched, TIMEOUT_S)
    for i, text in enumerate(HOSTILE, 1):
        pub.send('measurements/description', text,
                 lambda: node._counts['bad_descriptions'] == i)
    pub.send('measurements/description', description_to_msg(VALID).data,
             lambda: node._rows is not None)


def test_recorder_records_hostile_descriptions_counts_them_and_keeps_recording(
        executor, ros_context, tmp_path):
    topics = ['/t/excitation/description', '/t/measurements/description']
    pub = Publisher(ros_context, executor, topics)
    bag = tmp_path / 'bag'
    recorder = RecorderNode(context=ros_context, parameter_overrides=[
        Parameter('output', value=str(bag)), Parameter('discovery_period_s', value=0.05)])
    executor.add_node(recorder)
    assert ros_harness.spin_until(executor, lambda: set(topics) <= set(recorder._recorded)
                                  and pub.matched(), TIMEOUT_S)
    expected = 0
    for topic in topics:
        for text in HOSTILE:
            # The experiment description needs to be JSON within bounds (the nested ones
            # are refused); the stream description, where faults are read, an object too
            # (another convention's object simply carries no faults).
            stream = topic.endswith('/measurements/description')
            refused = text in HOSTILE[:3] or (stream and text == HOSTILE[3])
            expected += refused
            written = recorder.written_messages().get(topic, 0)
            pub.send(topic, text, lambda: recorder._bad_descriptions == expected
                     and recorder.written_messages().get(topic, 0) == written + 1,
                     lambda: (recorder._bad_descriptions, expected,
                              recorder.written_messages()))
    assert expected == 7
    status = recorder._status_dict()
    assert status['state'] == 'recording' and status['bad_descriptions'] == expected
    # Still recording, and a valid description is taken as before.
    written = recorder.written_messages()['/t/measurements/description']
    pub.send('/t/measurements/description', VALID.to_json(),
             lambda: recorder.written_messages()['/t/measurements/description'] == written + 1)
    assert recorder._bad_descriptions == expected
