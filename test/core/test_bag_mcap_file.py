"""
The fast MCAP writer writes, byte for byte, what the mcap package's writer writes.

Same schemas, channels, messages (sizes from empty to larger than a chunk, out-of-order
times, several channels), flushes in the middle and metadata; the files are compared byte for
byte, then read by the mcap package's reader with CRC checks. The CRC combination is checked
against ``zlib.crc32`` of the concatenation.
"""

import io
import os
import random
import zlib

from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
import pytest

from emfc_ros.core.bag.mcap_file import crc32_combine, McapFileWriter


def crc_cases():
    rng = random.Random(7)
    cases = [(b'', b''), (b'a', b''), (b'', b'b'), (b'123456789', b'abc')]
    for _ in range(40):
        cases.append((rng.randbytes(rng.randint(0, 5000)), rng.randbytes(rng.randint(0, 5000))))
    cases.append((rng.randbytes(10), rng.randbytes(3_000_017)))
    return cases


@pytest.mark.parametrize('a, b', crc_cases())
def test_crc32_combine_equals_crc_of_concatenation(a, b):
    for start in (0, 0xFFFFFFFF, 0x12345678):
        assert crc32_combine(zlib.crc32(a, start), zlib.crc32(b), len(b)) == \
            zlib.crc32(a + b, start)


def script(seed):
    """A recording's calls: registrations, messages of many sizes, flushes, metadata."""
    rng = random.Random(seed)
    calls = [('schema', 'std_msgs/msg/Float64MultiArray', 'ros2msg', b'float64[] data\n'),
             ('schema', 'std_msgs/msg/String', 'ros2msg', b'string data\n'),
             ('channel', '/a', 'cdr', 1, {'offered_qos_profiles': 'q', 'topic_type_hash': 'h'}),
             ('channel', '/a/description', 'cdr', 2, {'offered_qos_profiles': 'r'}),
             ('channel', '/b', 'cdr', 1, {})]
    t = 1_000_000_000
    seq = {1: 0, 2: 0, 3: 0}
    for i in range(300):
        cid = rng.choice((1, 1, 3, 2))
        size = rng.choice((0, 1, 17, 4096, 40_000, 64_000, rng.randint(0, 9000)))
        if i == 150:
            size = 300_000                         # larger than the 128 kB chunk
        t += rng.randint(-2_000, 100_000)         # not always increasing
        seq[cid] += 1
        calls.append(('message', cid, t, os.urandom(size), t + 5, seq[cid]))
        if rng.random() < 0.03:
            calls.append(('flush',))
        if i == 200:
            calls.append(('metadata', 'extra', {'k': 'v'}))
    calls.append(('metadata', 'rosbag2', {'serialized_metadata': 'x: 1\n'}))
    return calls


def play(writer, calls):
    writer.start('ros2', 'emfc_ros-test')
    for call in calls:
        kind, args = call[0], call[1:]
        if kind == 'schema':
            writer.register_schema(*args)
        elif kind == 'channel':
            writer.register_channel(*args)
        elif kind == 'message':
            writer.add_message(*args)
        elif kind == 'flush':
            writer.flush()
        else:
            writer.add_metadata(*args)
    writer.finish()


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_same_bytes_as_the_mcap_package_writer(seed):
    calls = script(seed)
    theirs, ours = io.BytesIO(), io.BytesIO()
    play(Writer(theirs, chunk_size=128 * 1024, compression=CompressionType.NONE,
                enable_data_crcs=True), calls)
    play(McapFileWriter(ours, chunk_size=128 * 1024), calls)
    assert ours.getvalue() == theirs.getvalue()
    # And the mcap reader accepts it, CRCs checked, every message back in order.
    ours.seek(0)
    reader = make_reader(ours, validate_crcs=True)
    got = [(m.channel_id, m.log_time, m.data) for _, _, m in reader.iter_messages(
        log_time_order=False)]
    sent = [(c[1], c[2], c[3]) for c in calls if c[0] == 'message']
    assert got == sent
    assert reader.get_summary().statistics.message_count == len(sent)
