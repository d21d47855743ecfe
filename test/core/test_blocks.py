"""The block convention: packing, checking and sequence tracking."""

import numpy as np
import pytest

from emfc_ros.core import blocks
from emfc_ros.core.blocks import (
    Block, Channel, Continuity, SequenceTracker, StreamDescription)
from emfc_ros.core.errors import BlockError


def _dims(c, n):
    return blocks.layout(c, n)


def test_pack_unpack_round_trip_is_exact():
    rng = np.random.default_rng(1)
    samples = rng.normal(size=(3, 17))
    flat = blocks.pack(2 ** 40 + 3, 300000.0, 7, samples)
    assert flat.size == blocks.HEADER_LENGTH + 51
    block = blocks.unpack(_dims(3, 17), blocks.HEADER_LENGTH, flat.tobytes())
    assert block.first_sample_index == 2 ** 40 + 3
    assert block.sample_rate_Hz == 300000.0
    assert block.epoch == 7
    np.testing.assert_array_equal(block.samples, samples)
    assert block.end_index == 2 ** 40 + 20


def test_layout_is_channel_major():
    samples = np.arange(6.0).reshape(2, 3)
    flat = blocks.pack(0, 10.0, 0, samples)
    np.testing.assert_array_equal(flat[blocks.HEADER_LENGTH:], [0, 1, 2, 3, 4, 5])
    assert _dims(2, 3) == [('channel', 2, 6), ('sample', 3, 3)]


@pytest.mark.parametrize('dims, offset, size, match', [
    ([('channel', 2, 6)], 3, 9, '2 layout dimensions'),
    ([('sample', 3, 3), ('channel', 2, 6)], 3, 9, 'labels'),
    ([('channel', 2, 5), ('sample', 3, 3)], 3, 9, 'strides'),
    ([('channel', 2, 6), ('sample', 3, 3)], 0, 9, 'data_offset'),
    ([('channel', 2, 6), ('sample', 3, 3)], 3, 8, 'needs 9'),
    # Oversized: refused from the layout, before the data are looked at.
    ([('channel', 2, 2 * 5_000_000), ('sample', 5_000_000, 5_000_000)], 3, 9, 'maximum'),
    ([('channel', 300, 300), ('sample', 1, 1)], 3, 9, 'maximum'),
])
def test_malformed_layouts_are_refused_with_the_reason(dims, offset, size, match):
    data = np.zeros(size)
    data[1] = 10.0
    with pytest.raises(BlockError, match=match):
        blocks.unpack(dims, offset, data)


@pytest.mark.parametrize('header, match', [
    ([-1.0, 10.0, 0.0], 'first_sample_index'),
    ([1.5, 10.0, 0.0], 'first_sample_index'),
    ([np.nan, 10.0, 0.0], 'first_sample_index'),
    ([0.0, 0.0, 0.0], 'sample_rate_Hz'),
    ([0.0, 10.0, 0.5], 'epoch'),
])
def test_bad_headers_are_refused(header, match):
    data = np.concatenate([header, np.zeros(6)])
    with pytest.raises(BlockError, match=match):
        blocks.unpack(_dims(2, 3), 3, data)


def test_expected_channel_count_is_enforced():
    flat = blocks.pack(0, 10.0, 0, np.zeros((2, 4)))
    with pytest.raises(BlockError, match='expected 4'):
        blocks.unpack(_dims(2, 4), 3, flat, expected_channels=4)


def test_pack_refuses_indices_beyond_exact_float_range():
    with pytest.raises(BlockError):
        blocks.pack(2 ** 53, 10.0, 0, np.zeros((1, 1)))


def test_description_round_trip_and_refusal():
    d = StreamDescription('excitation', 10000.0, 1000,
                          (Channel('coil', 'V', 'x'), Channel('load_changer', 'V')),
                          epoch=3, start_time_ns=12, total_samples=400000, source='/emfc/sg',
                          extra={'sections': [{'name': 'a'}]})
    back = StreamDescription.from_json(d.to_json())
    assert back == d
    assert back.channel_names == ('coil', 'load_changer')
    with pytest.raises(BlockError, match='convention'):
        StreamDescription.from_json('{"convention": "other"}')
    with pytest.raises(BlockError, match='malformed'):
        StreamDescription.from_json('not json')


def test_sequence_tracker_classifies_every_defect():
    t = SequenceTracker()
    assert t.observe(0, 10) is Continuity.FIRST
    assert t.observe(10, 10) is Continuity.CONTIGUOUS
    assert t.observe(40, 10) is Continuity.GAP          # 20..39 missing
    assert t.observe(40, 10) is Continuity.DUPLICATE
    assert t.observe(20, 10) is Continuity.REORDERED    # late block from the gap
    assert t.observe(45, 10) is Continuity.OVERLAP
    assert t.observe(50, 10) is Continuity.CONTIGUOUS
    assert t.observe(0, 10, epoch=1) is Continuity.RESTART
    assert t.counters() == {'blocks': 8, 'gaps': 1, 'missing_samples': 20, 'duplicates': 1,
                            'reordered': 1, 'overlaps': 1, 'restarts': 1}


def test_block_dataclass_properties():
    b = Block(5, 10.0, 0, np.zeros((2, 4)))
    assert (b.n_samples, b.end_index) == (4, 9)
