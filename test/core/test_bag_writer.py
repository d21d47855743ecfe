"""
Bag writing without ROS: layout, metadata, schemas, QoS, splitting, independent readers.

Messages are serialised with rosbags' typestore; every bag is read back by rosbags and by
mcap with mcap_ros2.
"""

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores
import yaml

from emfc_ros.core.bag import (
    BagExistsError, BagWriteError, BagWriter, MessageTypeError, OfferedQos, read_metadata,
    read_streams)
from emfc_ros.core.bag.qos import qos_yaml
from emfc_ros.core.blocks import Channel, pack, StreamDescription

TS = get_typestore(Stores.ROS2_JAZZY)
F64 = 'std_msgs/msg/Float64MultiArray'
STR = 'std_msgs/msg/String'


def block_cdr(first, samples, rate=1000.0, epoch=1):
    t = TS.types
    layout = t['std_msgs/msg/MultiArrayLayout'](dim=[
        t['std_msgs/msg/MultiArrayDimension']('channel', samples.shape[0], samples.size),
        t['std_msgs/msg/MultiArrayDimension']('sample', samples.shape[1], samples.shape[1])],
        data_offset=3)
    return TS.serialize_cdr(t[F64](layout=layout, data=pack(first, rate, epoch, samples)), F64)


def string_cdr(text):
    return TS.serialize_cdr(TS.types[STR](data=text), STR)


def write_stream(path, n_blocks=20, block=100, channels=2, **kwargs):
    rng = np.random.default_rng(3)
    data = rng.normal(size=(channels, n_blocks * block))
    writer = BagWriter(path, **kwargs)
    writer.open()
    c = writer.add_connection('/x', F64, [OfferedQos(depth=100)])
    d = writer.add_connection('/x/description', STR,
                              [OfferedQos(depth=1, durability='transient_local')])
    desc = StreamDescription('x', 1000.0, block, tuple(
        Channel(f'c{i}', 'V') for i in range(channels)), epoch=1)
    writer.write(d, 1_000, string_cdr(desc.to_json()))
    for i in range(n_blocks):
        writer.write(c, 1_000_000 * (i + 1), block_cdr(i * block,
                                                       data[:, i * block:(i + 1) * block]))
    return writer, data


def test_layout_metadata_and_both_independent_readers(tmp_path):
    bag = tmp_path / 'run'
    writer, data = write_stream(bag)
    writer.set_custom_data('emfc_ros.experiment', 'a: 1\n')
    writer.close()
    assert sorted(p.name for p in bag.iterdir()) == ['metadata.yaml', 'run_0.mcap']
    meta = read_metadata(bag)
    assert meta['version'] == 9 and meta['storage_identifier'] == 'mcap'
    assert meta['relative_file_paths'] == ['run_0.mcap']
    assert meta['message_count'] == 21
    assert meta['starting_time']['nanoseconds_since_epoch'] == 1_000
    assert meta['duration']['nanoseconds'] == 20_000_000 - 1_000
    assert meta['files'][0]['message_count'] == 21
    assert meta['custom_data'] == {'emfc_ros.experiment': 'a: 1\n'}
    assert meta['ros_distro'] == 'jazzy'
    assert meta['compression_format'] == '' and meta['compression_mode'] == ''
    topics = {t['topic_metadata']['name']: t for t in meta['topics_with_message_count']}
    assert topics['/x']['message_count'] == 20
    assert topics['/x']['topic_metadata']['type_description_hash'] == TS.hash_rihs01(F64)
    assert topics['/x/description']['topic_metadata']['offered_qos_profiles'][0][
        'durability'] == 'transient_local'

    with Reader(bag) as reader:
        assert reader.message_count == 21
        conn = next(c for c in reader.connections if c.topic == '/x')
        assert conn.msgtype == F64
        assert conn.ext.offered_qos_profiles[0].depth == 100
        got = [TS.deserialize_cdr(raw, F64) for _, _, raw in reader.messages([conn])]
    np.testing.assert_array_equal(np.concatenate([m.data[3:].reshape(2, 100) for m in got],
                                                 axis=1), data)
    with AnyReader([bag]) as reader:  # definitions from the bag itself, no typestore given
        assert sum(1 for _ in reader.messages()) == 21
    with open(bag / 'run_0.mcap', 'rb') as handle:
        reader = make_reader(handle, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        assert header.profile == 'ros2'
        summary = reader.get_summary()
        assert {s.encoding for s in summary.schemas.values()} == {'ros2msg'}
        channel = next(c for c in summary.channels.values() if c.topic == '/x')
        assert channel.message_encoding == 'cdr'
        assert channel.metadata['offered_qos_profiles'] == qos_yaml([OfferedQos(depth=100)])
        assert channel.metadata['topic_type_hash'] == TS.hash_rihs01(F64)
        decoded = [m for _, c, _, m in reader.iter_decoded_messages() if c.topic == '/x']
    assert len(decoded) == 20 and decoded[3].layout.dim[1].label == 'sample'
    np.testing.assert_array_equal(np.asarray(decoded[3].data[3:]).reshape(2, 100),
                                  data[:, 300:400])
    # The MCAP metadata record carries the bag metadata as rosbag2 writes it.
    with open(bag / 'run_0.mcap', 'rb') as handle:
        records = list(make_reader(handle).iter_metadata())
    assert records[0].name == 'rosbag2'
    assert yaml.safe_load(records[0].metadata['serialized_metadata'])['version'] == 9


def test_split_by_size_and_by_duration(tmp_path):
    writer, data = write_stream(tmp_path / 'size', n_blocks=40, block=500,
                                max_bag_size_B=30_000)
    writer.close()
    files = read_metadata(tmp_path / 'size')['relative_file_paths']
    assert files == [f'size_{i}.mcap' for i in range(len(files))] and len(files) >= 5
    for name in files:
        assert (tmp_path / 'size' / name).stat().st_size < 30_000 + 10_000
    s = read_streams(tmp_path / 'size')['/x']
    assert s.gaps == [] and s.channel_names == ('c0', 'c1')
    np.testing.assert_array_equal(s.samples, data)

    writer, data = write_stream(tmp_path / 'dur', n_blocks=20, max_bag_duration_ns=5_000_000)
    writer.close()
    meta = read_metadata(tmp_path / 'dur')
    assert [f['message_count'] for f in meta['files']] == [6, 5, 5, 5]
    assert all(f['duration']['nanoseconds'] < 5_000_000 for f in meta['files'])
    np.testing.assert_array_equal(read_streams(tmp_path / 'dur')['/x'].samples, data)
    with AnyReader([tmp_path / 'dur']) as reader:
        assert [t for _, t, _ in reader.messages()] == sorted(
            [1_000] + [1_000_000 * (i + 1) for i in range(20)])


def test_existing_non_empty_folder_and_unwritable_paths_are_refused(tmp_path):
    (tmp_path / 'busy').mkdir()
    (tmp_path / 'busy' / 'x').write_text('keep')
    with pytest.raises(BagExistsError, match='not empty'):
        BagWriter(tmp_path / 'busy').open()
    assert (tmp_path / 'busy' / 'x').read_text() == 'keep'
    (tmp_path / 'empty').mkdir()
    writer = BagWriter(tmp_path / 'empty')
    writer.open()
    writer.close()
    assert read_metadata(tmp_path / 'empty')['message_count'] == 0
    (tmp_path / 'file').write_text('')
    with pytest.raises(BagWriteError, match='file'):
        BagWriter(tmp_path / 'file').open()
    with pytest.raises(BagWriteError, match='cannot create'):
        BagWriter(tmp_path / 'file' / 'below').open()
    assert isinstance(BagWriteError('x'), OSError)
    assert isinstance(BagExistsError('x'), FileExistsError)


def test_unknown_message_type_is_a_clear_error(tmp_path):
    writer = BagWriter(tmp_path / 'b')
    writer.open()
    with pytest.raises(MessageTypeError, match='foo_msgs/msg/Bar'):
        writer.add_connection('/foo', 'foo_msgs/msg/Bar')
    writer.close()


def test_unknown_type_is_found_in_a_share_folder(tmp_path):
    share = tmp_path / 'prefix' / 'share' / 'foo_msgs' / 'msg'
    share.mkdir(parents=True)
    (share / 'Bar.msg').write_text('float64 x_m\nfoo_msgs/Baz baz\n')
    (share / 'Baz.msg').write_text('string label\n')
    from emfc_ros.core.bag import MessageTypes
    writer = BagWriter(tmp_path / 'b', types=MessageTypes([tmp_path / 'prefix']))
    writer.open()
    cid = writer.add_connection('/foo', 'foo_msgs/msg/Bar')
    bar = writer.types.typestore.types['foo_msgs/msg/Bar']
    baz = writer.types.typestore.types['foo_msgs/msg/Baz']
    writer.write(cid, 5, writer.types.typestore.serialize_cdr(bar(x_m=1.5, baz=baz('z')),
                                                              'foo_msgs/msg/Bar'))
    writer.close()
    with open(tmp_path / 'b' / 'b_0.mcap', 'rb') as handle:
        [(_, _, _, msg)] = list(make_reader(handle, decoder_factories=[
            DecoderFactory()]).iter_decoded_messages())
    assert msg.x_m == 1.5 and msg.baz.label == 'z'
