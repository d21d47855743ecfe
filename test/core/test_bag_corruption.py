"""
Damaged bags: a flipped byte in an MCAP chunk is reported, skipped as a gap, and repaired.

Bags are written with the project's writer (a chunk per flush), damaged by flipping one byte
inside a chunk, read back, repaired, and the repaired bag is read with rosbags (an independent
reader).
"""

import shutil
import warnings

from hypothesis import given, HealthCheck, settings, strategies as st
from mcap.reader import make_reader
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores

from emfc_ros.cli import bag_info, bag_repair
from emfc_ros.core.bag import (BagDamageWarning, BagWriter, OfferedQos, read_messages,
                               read_metadata, read_streams, repair_bag, StreamGapError)
from emfc_ros.core.bag.info import bag_info as info_text
from emfc_ros.core.blocks import Channel, pack, StreamDescription

TS = get_typestore(Stores.ROS2_JAZZY)
F64 = 'std_msgs/msg/Float64MultiArray'
STR = 'std_msgs/msg/String'
T0_NS = 1_795_600_000 * 10**9
BLOCK = 50                  # samples per block at 100 Hz: 0.5 s
PER_CHUNK = 5               # blocks per flush (per chunk)
N_BLOCKS = 20


def t_ns(i):
    return T0_NS + i * 500_000_000


def data(n):
    return np.vstack([np.arange(n, dtype=float), -np.arange(n, dtype=float)])


def block_cdr(first, x):
    t = TS.types
    dim = t['std_msgs/msg/MultiArrayDimension']
    layout = t['std_msgs/msg/MultiArrayLayout'](dim=[dim('channel', x.shape[0], x.size),
                                                     dim('sample', x.shape[1], x.shape[1])],
                                                data_offset=3)
    return TS.serialize_cdr(t[F64](layout=layout, data=pack(first, 100.0, 1, x)), F64)


def write_bag(path, close=True):
    """
    Write a description, then N_BLOCKS blocks, a chunk per PER_CHUNK blocks.

    The first chunk also holds the description.
    """
    writer = BagWriter(path, chunk_size_B=1 << 30)
    writer.open()
    c = writer.add_connection('/s', F64, [OfferedQos()])
    d = writer.add_connection('/s/description', STR, [OfferedQos()])
    desc = StreamDescription('s', 100.0, BLOCK, (Channel('up', 'V'), Channel('down', 'A')),
                             epoch=1)
    writer.write(d, T0_NS - 1, TS.serialize_cdr(TS.types[STR](data=desc.to_json()), STR))
    x = data(BLOCK * N_BLOCKS)
    for i in range(N_BLOCKS):
        writer.write(c, t_ns(i), block_cdr(BLOCK * i, x[:, BLOCK * i:BLOCK * (i + 1)]))
        if (i + 1) % PER_CHUNK == 0:
            writer.flush()
    if close:
        writer.close()
    else:
        writer.abort()          # a killed recorder: no summary, no footer
    return path / f'{path.name}_0.mcap'


def chunk_offsets(mcap_file):
    """(start, length) of every chunk record, from an intact copy's summary."""
    with open(mcap_file, 'rb') as handle:
        summary = make_reader(handle).get_summary()
    return [(c.chunk_start_offset, c.chunk_length) for c in
            sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)]


# Where in the chunk record the byte is flipped: the stored CRC, the first record inside,
# the middle of the records.
WHERE = {'crc': lambda start, length: start + 9 + 8 + 8 + 8,
         'first record': lambda start, length: start + 9 + 8 + 8 + 8 + 4 + 4 + 8 + 3,
         'middle': lambda start, length: start + length // 2}


def flip(mcap_file, chunks, where='middle', k=1):
    start, length = chunks[k]
    raw = bytearray(mcap_file.read_bytes())
    raw[WHERE[where](start, length)] ^= 0x10
    mcap_file.write_bytes(bytes(raw))
    return start


@pytest.fixture
def damaged(tmp_path):
    bag = tmp_path / 'b'
    mcap_file = write_bag(bag)
    chunks = chunk_offsets(mcap_file)
    assert len(chunks) == N_BLOCKS // PER_CHUNK
    return bag, mcap_file, chunks


@pytest.mark.parametrize('where', sorted(WHERE))
def test_reader_reports_the_corrupt_chunk_and_returns_the_rest(damaged, where):
    bag, mcap_file, chunks = damaged
    offset = flip(mcap_file, chunks, where, k=1)
    with pytest.warns(BagDamageWarning):
        with pytest.raises(StreamGapError, match=f'corrupt chunk at byte {offset} '):
            read_streams(bag)
    with pytest.warns(BagDamageWarning, match=f'b_0.mcap: corrupt chunk at byte {offset}'):
        s = read_streams(bag, on_gap='nan')['/s']
    lost = slice(BLOCK * PER_CHUNK, 2 * BLOCK * PER_CHUNK)
    assert s.gaps == [(lost.start, lost.stop - lost.start)]
    assert s.n_samples == BLOCK * N_BLOCKS
    assert np.isnan(s.samples[:, lost]).all()
    keep = np.ones(s.n_samples, bool)
    keep[lost] = False
    np.testing.assert_array_equal(s.samples[:, keep], data(BLOCK * N_BLOCKS)[:, keep])
    assert s.channel_names == ('up', 'down')          # the description, in chunk 0
    [d] = s.damage
    assert (d.file, d.offset_B, d.length_B) == ('b_0.mcap', offset, chunks[1][1])
    assert (d.start_ns, d.end_ns) == (t_ns(PER_CHUNK), t_ns(2 * PER_CHUNK - 1))
    assert d.message_count == PER_CHUNK and d.topics == ('/s',)
    assert d.duration_s == pytest.approx(2.0)
    with pytest.warns(BagDamageWarning):
        stamps = [t for t, _ in read_messages(bag, '/s')]
    assert stamps == [t_ns(i) for i in range(N_BLOCKS) if not PER_CHUNK <= i < 2 * PER_CHUNK]


def test_a_lost_last_chunk_is_reported_though_no_gap_shows(damaged):
    bag, mcap_file, chunks = damaged
    flip(mcap_file, chunks, k=len(chunks) - 1)
    with pytest.warns(BagDamageWarning), pytest.raises(StreamGapError, match='corrupt chunk'):
        read_streams(bag)
    with pytest.warns(BagDamageWarning):
        s = read_streams(bag, on_gap='nan')['/s']
    assert s.gaps == [] and s.n_samples == BLOCK * (N_BLOCKS - PER_CHUNK)
    assert [d.message_count for d in s.damage] == [PER_CHUNK]


def test_info_lists_the_corrupt_chunk(damaged, capsys):
    bag, mcap_file, chunks = damaged
    assert bag_info.main([str(bag), '--check']) == 0
    assert '4 chunks checked (CRC), all intact' in capsys.readouterr().out
    offset = flip(mcap_file, chunks)
    assert bag_info.main([str(bag), '--check']) == 0
    out = capsys.readouterr().out
    assert 'Integrity:         DAMAGED, 4 chunks checked' in out
    assert f'b_0.mcap: corrupt chunk at byte {offset}' in out and '5 messages of /s lost' in out
    assert bag_info.main([str(bag), '--streams']) == 0
    captured = capsys.readouterr()
    assert '/s: 100 Hz, epoch 1, samples 0 to 999' in captured.out
    assert '1 gaps (250 samples missing)' in captured.out
    assert 'Traceback' not in captured.err


def read_independently(bag):
    """Messages per topic and the /s timestamps, read by rosbags."""
    with AnyReader([bag]) as reader:
        counts = {}
        stamps = []
        for conn, timestamp, _ in reader.messages():
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
            if conn.topic == '/s':
                stamps.append(timestamp)
        return reader.message_count, counts, stamps


def test_repair_rebuilds_the_bag_from_the_intact_chunks(damaged, capsys):
    bag, mcap_file, chunks = damaged
    offset = flip(mcap_file, chunks)
    with pytest.raises(Exception, match='[Cc]hecksum'):
        read_independently(bag)                       # rosbags stops at the chunk
    assert bag_repair.main([str(bag)]) == 0
    out = capsys.readouterr().out
    assert 'b_0.mcap: recovered, 16 messages (1 corrupt chunks skipped: 5 messages, ' \
           '2.000000 s of log time lost)' in out
    assert f'corrupt chunk at byte {offset}' in out
    assert (bag / 'b_0.mcap.damaged').is_file()
    total, counts, stamps = read_independently(bag)
    assert total == 16 and counts == {'/s': 15, '/s/description': 1}
    assert stamps == [t_ns(i) for i in range(N_BLOCKS) if not PER_CHUNK <= i < 2 * PER_CHUNK]
    assert read_metadata(bag)['message_count'] == 16
    with warnings.catch_warnings():
        warnings.simplefilter('error')               # no damage left to warn about
        s = read_streams(bag, on_gap='nan')['/s']
    assert s.gaps == [(BLOCK * PER_CHUNK, BLOCK * PER_CHUNK)] and s.damage == []
    again = repair_bag(bag)
    assert [f.status for f in again.files] == ['ok'] and again.message_count == 16


def test_repair_of_a_killed_recording_with_a_corrupt_chunk(tmp_path):
    template = tmp_path / 'template'
    write_bag(template)
    chunks = chunk_offsets(template / 'template_0.mcap')
    bag = tmp_path / 'b'
    mcap_file = write_bag(bag, close=False)            # same layout, without the summary
    flip(mcap_file, chunks, k=1)
    report = repair_bag(bag)
    [f] = report.files
    assert f.status == 'recovered' and f.message_count == 16
    assert [(d.offset_B, d.message_count, d.topics) for d in f.damage] == [
        (chunks[1][0], PER_CHUNK, ('/s',))]
    assert f.lost_messages == PER_CHUNK and f.lost_s == pytest.approx(2.0)
    total, counts, stamps = read_independently(bag)
    assert total == 16 and counts == {'/s': 15, '/s/description': 1}
    assert stamps[-1] == t_ns(N_BLOCKS - 1)            # the chunks after the bad one too


@pytest.fixture(scope='module')
def template(tmp_path_factory):
    bag = tmp_path_factory.mktemp('template') / 'b'
    write_bag(bag)
    return bag


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.data())
def test_any_flipped_byte_is_found_and_repaired_to_a_bag_rosbags_reads(
        template, tmp_path, data):
    mcap_name = 'b_0.mcap'
    raw = bytearray((template / mcap_name).read_bytes())
    pos = data.draw(st.integers(0, len(raw) - 1), label='byte')
    bit = data.draw(st.integers(0, 7), label='bit')
    bag = tmp_path / 'b'
    shutil.rmtree(bag, ignore_errors=True)     # hypothesis reuses the function's tmp_path
    shutil.copytree(template, bag)
    raw[pos] ^= 1 << bit
    (bag / mcap_name).write_bytes(bytes(raw))
    assert 'Integrity:         DAMAGED' in info_text(bag, check=True)
    report = repair_bag(bag)
    [f] = report.files
    assert f.status == 'recovered'
    total = N_BLOCKS + 1
    assert f.message_count + f.lost_messages == total
    assert read_independently(bag)[0] == f.message_count
    assert 'all intact' in info_text(bag, check=True)
