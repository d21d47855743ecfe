"""
Reading bags back to arrays: the fast CDR decoder, stream assembly, gaps, epochs, messages.

Bags are written by the core writer with messages serialised by rosbags' typestore.
"""

import time

from hypothesis import given, settings, strategies as st
import numpy as np
import pytest
from rosbags.typesys import get_typestore, Stores

from emfc_ros.core.bag import (
    BagFormatError, BagWriter, OfferedQos, read_messages, read_streams, StreamGapError)
from emfc_ros.core.bag.cdr import decode_block, decode_float64_multiarray
from emfc_ros.core.blocks import Channel, pack, StreamDescription
from emfc_ros.core.errors import BlockError

TS = get_typestore(Stores.ROS2_JAZZY)
F64 = 'std_msgs/msg/Float64MultiArray'
STR = 'std_msgs/msg/String'


def block_cdr(first, samples, rate=1000.0, epoch=1, labels=('channel', 'sample')):
    t = TS.types
    dim = t['std_msgs/msg/MultiArrayDimension']
    layout = t['std_msgs/msg/MultiArrayLayout'](dim=[
        dim(labels[0], samples.shape[0], samples.size),
        dim(labels[1], samples.shape[1], samples.shape[1])], data_offset=3)
    return TS.serialize_cdr(t[F64](layout=layout, data=pack(first, rate, epoch, samples)), F64)


def description_cdr(epoch, units=('V', 'A')):
    desc = StreamDescription('s', 1000.0, 10, tuple(
        Channel(f'n{i}', u) for i, u in enumerate(units)), epoch=epoch)
    return TS.serialize_cdr(TS.types[STR](data=desc.to_json()), STR)


def samples(first, n, channels=2):
    k = np.arange(first, first + n, dtype=float)
    return np.vstack([k * (c + 1) for c in range(channels)])


def make_bag(path, blocks, descriptions=(), other=()):
    """blocks: list of (first, n, epoch); written in the given order."""
    writer = BagWriter(path)
    writer.open()
    c = writer.add_connection('/s', F64, [OfferedQos()])
    d = writer.add_connection('/s/description', STR, [OfferedQos()])
    t = 1
    for epoch in descriptions:
        writer.write(d, t, description_cdr(epoch))
        t += 1
    for first, n, epoch in blocks:
        writer.write(c, t, block_cdr(first, samples(first, n), epoch=epoch))
        t += 1
    if other:
        j = writer.add_connection('/joint_states', 'sensor_msgs/msg/JointState')
        js = TS.types['sensor_msgs/msg/JointState']
        header = TS.types['std_msgs/msg/Header']
        stamp = TS.types['builtin_interfaces/msg/Time']
        for k in other:
            writer.write(j, t, TS.serialize_cdr(js(header=header(stamp(0, 0), ''), name=['l'],
                                                   position=np.array([k]), velocity=np.zeros(0),
                                                   effort=np.zeros(0)),
                                                'sensor_msgs/msg/JointState'))
            t += 1
    writer.close()
    return path


@settings(max_examples=40, deadline=None)
@given(channels=st.integers(1, 5), n=st.integers(0, 50), first=st.integers(0, 2 ** 53 - 1),
       labels=st.sampled_from([('channel', 'sample'), ('c', 'sample_long_label')]))
def test_fast_decoder_matches_rosbags_deserializer(channels, n, first, labels):
    x = np.random.default_rng(n).normal(size=(channels, n))
    raw = block_cdr(first, x, labels=labels)
    ref = TS.deserialize_cdr(raw, F64)
    dims, offset, data = decode_float64_multiarray(raw)
    assert dims == [(d.label, d.size, d.stride) for d in ref.layout.dim]
    assert offset == ref.layout.data_offset
    np.testing.assert_array_equal(data, ref.data)
    if labels == ('channel', 'sample'):
        block = decode_block(raw)
        assert block.first_sample_index == first
        np.testing.assert_array_equal(block.samples, x)


def test_fast_decoder_refuses_truncated_bytes_and_is_faster():
    raw = block_cdr(0, samples(0, 1000, 4))
    for cut in (3, 10, 40, len(raw) - 1):
        with pytest.raises(BlockError):
            decode_block(raw[:cut])
    t0 = time.perf_counter()
    for _ in range(200):
        decode_block(raw)
    fast = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(200):
        TS.deserialize_cdr(raw, F64)
    slow = time.perf_counter() - t0
    print(f'decode 1000x4 block: fast {fast / 200 * 1e6:.1f} us, '
          f'rosbags {slow / 200 * 1e6:.1f} us')
    assert decode_block(raw).samples.shape == (4, 1000)


def test_reordered_and_duplicate_blocks_assemble_in_sample_order(tmp_path):
    bag = make_bag(tmp_path / 'b', [(0, 10, 1), (20, 10, 1), (10, 10, 1), (10, 10, 1),
                                    (30, 5, 1)], descriptions=[1])
    s = read_streams(bag)['/s']
    assert s.duplicates == 1 and s.gaps == []
    assert s.channel_names == ('n0', 'n1') and s.channel_units == ('V', 'A')
    np.testing.assert_array_equal(s.samples, samples(0, 35))
    np.testing.assert_array_equal(s.block_first_index, [0, 10, 20, 30])
    np.testing.assert_array_equal(s.channel('n1'), 2 * np.arange(35.0))
    np.testing.assert_array_equal(s.time_s, np.arange(35) / 1000.0)
    with pytest.raises(KeyError, match='n0'):
        s.channel('nope')


def test_gaps_raise_by_default_or_are_nan_and_listed(tmp_path):
    bag = make_bag(tmp_path / 'b', [(100, 10, 1), (110, 10, 1), (125, 10, 1), (150, 10, 1)])
    with pytest.raises(StreamGapError, match='20 samples missing in 2 gaps'):
        read_streams(bag)
    s = read_streams(bag, on_gap='nan')['/s']
    assert s.first_sample_index == 100 and s.n_samples == 60
    assert s.gaps == [(120, 5), (135, 15)] and s.missing_samples == 20
    assert np.isnan(s.samples[:, 20:25]).all() and np.isnan(s.samples[:, 35:50]).all()
    np.testing.assert_array_equal(s.samples[:, :20], samples(100, 20))
    np.testing.assert_array_equal(s.samples[:, 50:], samples(150, 10))
    assert s.channel_names == ('ch0', 'ch1') and s.channel_units == ('', '')
    with pytest.raises(ValueError, match='on_gap'):
        read_streams(bag, on_gap='stitch')


def test_epochs_are_separate_streams_with_their_descriptions(tmp_path):
    bag = make_bag(tmp_path / 'b', [(0, 10, 1), (10, 10, 1), (0, 10, 2)], descriptions=[1, 2])
    streams = read_streams(bag)
    assert set(streams) == {'/s#1', '/s#2'}
    assert streams['/s#1'].n_samples == 20 and streams['/s#2'].n_samples == 10
    assert streams['/s#2'].description.epoch == 2


def test_overlapping_blocks_with_other_values_are_an_error(tmp_path):
    writer = BagWriter(tmp_path / 'b')
    writer.open()
    c = writer.add_connection('/s', F64)
    writer.write(c, 1, block_cdr(0, samples(0, 10)))
    writer.write(c, 2, block_cdr(5, samples(0, 10)))
    writer.close()
    with pytest.raises(BlockError, match='overlaps'):
        read_streams(tmp_path / 'b')


def test_non_block_arrays_are_skipped_unless_named(tmp_path):
    writer = BagWriter(tmp_path / 'b')
    writer.open()
    c = writer.add_connection('/commands', F64)
    t = TS.types
    writer.write(c, 1, TS.serialize_cdr(t[F64](layout=t['std_msgs/msg/MultiArrayLayout'](
        dim=[], data_offset=0), data=np.array([1.0, 2.0])), F64))
    writer.close()
    assert read_streams(tmp_path / 'b') == {}
    with pytest.raises(BlockError):
        read_streams(tmp_path / 'b', topics=['/commands'])
    with pytest.raises(BlockError, match='not a'):
        read_streams(tmp_path / 'b', topics=['/missing'])


def test_read_messages_of_other_types(tmp_path):
    bag = make_bag(tmp_path / 'b', [(0, 10, 1)], other=[0.5, 1.5])
    got = list(read_messages(bag, '/joint_states'))
    assert [m.position[0] for _, m in got] == [0.5, 1.5]
    assert [m.name for _, m in got] == [['l'], ['l']]
    with pytest.raises(KeyError, match='/joint_states'):
        list(read_messages(bag, '/nope'))


def test_missing_bag_is_a_format_error(tmp_path):
    with pytest.raises(BagFormatError, match='emfc-bag-repair'):
        read_streams(tmp_path / 'none')
