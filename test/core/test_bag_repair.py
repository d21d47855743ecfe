"""
Repair of bags whose writer died: truncated files at any point, intact bags, the commands.

A "killed" writer is one that flushed and then never closed its file.
"""

import shutil
import subprocess
import sys

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores

from emfc_ros.cli import bag_info, bag_repair
from emfc_ros.core.bag import (
    BagFormatError, BagWriter, OfferedQos, read_metadata, read_streams, repair_bag)
from emfc_ros.core.blocks import pack
from ros_harness import scaled

TS = get_typestore(Stores.ROS2_JAZZY)
F64 = 'std_msgs/msg/Float64MultiArray'


def block_cdr(first, x):
    t = TS.types
    dim = t['std_msgs/msg/MultiArrayDimension']
    layout = t['std_msgs/msg/MultiArrayLayout'](dim=[dim('channel', x.shape[0], x.size),
                                                     dim('sample', x.shape[1], x.shape[1])],
                                                data_offset=3)
    return TS.serialize_cdr(t[F64](layout=layout, data=pack(first, 100.0, 1, x)), F64)


def data(n):
    return np.vstack([np.arange(n, dtype=float), -np.arange(n, dtype=float)])


def killed_bag(path, n_blocks=30, flush_every=5, **kwargs):
    """Write blocks of 50 samples, flushing every few blocks, and never close (a crash)."""
    writer = BagWriter(path, chunk_size_B=1 << 30, **kwargs)
    writer.open()
    writer.set_custom_data('emfc_ros.version', '9.9')
    c = writer.add_connection('/s', F64, [OfferedQos(depth=7)])
    x = data(50 * n_blocks)
    flushed = 0
    for i in range(n_blocks):
        writer.write(c, 1000 + i, block_cdr(50 * i, x[:, 50 * i:50 * (i + 1)]))
        if (i + 1) % flush_every == 0:
            writer.flush()
            flushed = i + 1
    return writer, flushed


def test_every_truncation_point_recovers_all_flushed_blocks(tmp_path):
    template = tmp_path / 'template'
    writer, flushed = killed_bag(template, n_blocks=12, flush_every=5)
    writer.abort()  # the process dies: unflushed blocks (10, 11) never reach the file
    size = (template / 'template_0.mcap').stat().st_size
    raw = (template / 'template_0.mcap').read_bytes()
    assert flushed == 10
    previous = 0
    for cut in list(range(0, size + 1, max(1, size // 37))) + [size]:
        bag = tmp_path / f'cut{cut}'
        shutil.copytree(template, bag)
        (bag / 'template_0.mcap').write_bytes(raw[:cut])
        report = repair_bag(bag)
        assert report.files[0].status == 'recovered'
        got = report.message_count
        assert got >= previous and got in (0, 5, 10)  # whole flushed chunks only
        previous = got
        meta = read_metadata(bag)
        assert meta['message_count'] == got
        assert meta['custom_data'] == {'emfc_ros.version': '9.9'}
        if got:
            s = read_streams(bag)['/s']
            np.testing.assert_array_equal(s.samples, data(50 * got))
            [topic] = meta['topics_with_message_count']
            assert topic['topic_metadata']['offered_qos_profiles'][0]['depth'] == 7
        with AnyReader([bag]) as reader:
            assert reader.message_count == got
    assert previous == 10


def test_split_bag_killed_in_its_last_file(tmp_path):
    bag = tmp_path / 'b'
    writer, flushed = killed_bag(bag, n_blocks=40, flush_every=1, max_bag_size_B=10_000)
    writer.abort()
    files = sorted(p.name for p in bag.glob('*.mcap'))
    assert len(files) >= 3
    with pytest.raises(BagFormatError):
        read_streams(bag)
    report = repair_bag(bag)
    assert [f.status for f in report.files] == ['ok'] * (len(files) - 1) + ['recovered']
    assert (bag / f'{files[-1]}.damaged').exists()
    s = read_streams(bag)['/s']
    assert s.gaps == [] and s.n_samples == 50 * flushed == 2000
    # Repairing again changes nothing: every file is intact now.
    again = repair_bag(bag, keep_damaged=False)
    assert {f.status for f in again.files} == {'ok'}
    assert again.message_count == report.message_count


def test_intact_bag_is_not_rewritten(tmp_path):
    bag = tmp_path / 'b'
    writer, _ = killed_bag(bag, n_blocks=10)
    writer.close()
    before = (bag / 'b_0.mcap').read_bytes()
    report = repair_bag(bag)
    assert not report.repaired and report.message_count == 10
    assert (bag / 'b_0.mcap').read_bytes() == before
    assert read_metadata(bag)['custom_data']['emfc_ros.version'] == '9.9'


def test_repair_without_metadata_and_with_an_empty_file(tmp_path):
    bag = tmp_path / 'b'
    writer, _ = killed_bag(bag, n_blocks=10, flush_every=10)
    writer.abort()
    (bag / 'metadata.yaml').unlink()
    (bag / 'b_1.mcap').write_bytes(b'')  # created, then killed before the header
    report = repair_bag(bag, keep_damaged=False)
    assert [f.message_count for f in report.files] == [10, 0]
    assert not list(bag.glob('*.damaged'))
    assert read_streams(bag)['/s'].n_samples == 500


def test_repair_and_info_commands(tmp_path):
    bag = tmp_path / 'b'
    writer, _ = killed_bag(bag, n_blocks=10, flush_every=5)
    writer.abort()
    out = subprocess.run([sys.executable, '-m', 'emfc_ros.cli.bag_repair', str(bag)],
                         capture_output=True, text=True, timeout=scaled(60))
    assert out.returncode == 0, out.stderr
    assert 'recovered, 10 messages' in out.stdout
    assert bag_repair.main([str(tmp_path / 'nothing')]) == 2
    assert bag_info.main([str(bag), '--streams']) == 0
    from emfc_ros.core.bag.info import bag_info as info_text
    text = info_text(bag, streams=True)
    assert 'Topic: /s | Type: std_msgs/msg/Float64MultiArray | Count: 10' in text
    assert '/s: 100 Hz, epoch 1, samples 0 to 499' in text
    assert 'emfc_ros.version: 9.9' in text
    assert bag_info.main([str(tmp_path / 'nothing')]) == 2


@pytest.mark.parametrize('clock, note', [('simulated', 'of simulated time (stamps from /clock)'),
                                         ('wall', 'of wall time'), (None, '')])
def test_info_says_which_clock_stamped_the_bag(tmp_path, clock, note):
    bag = tmp_path / 'b'
    writer, _ = killed_bag(bag, n_blocks=4, flush_every=4)
    if clock is not None:
        writer.set_custom_data('emfc_ros.clock', clock)
        writer.set_custom_data('emfc_ros.start_time_ns', str(1_795_600_000 * 10 ** 9))
    writer.close()
    from emfc_ros.core.bag.info import bag_info as info_text
    duration = [line for line in info_text(bag).splitlines() if line.startswith('Duration:')]
    assert duration == [f'Duration:          0.000000003 s {note}'.rstrip()]
    assert ('Recorded (wall):   2026-11-25' in info_text(bag)) == (clock == 'simulated')
