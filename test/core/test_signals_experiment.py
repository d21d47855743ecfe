"""Experiments: signal matching, clamping, sections in sequence and block boundaries."""

import numpy as np
import pytest

from emfc_ros.core.errors import BlockError, SignalError
from emfc_ros.core.signals import (ChannelLimits, ChannelPlan, Constant, Experiment, Section,
                                   Sine)

FS = 100.0


class Ramp:
    """Test signal: the local index times a slope, to see which index a signal gets."""

    def __init__(self, slope_V=1.0, sample_rate_Hz=FS):
        self.slope_V = slope_V
        self.sample_rate_Hz = sample_rate_Hz

    def samples(self, k):
        return self.slope_V * k.astype(np.float64)


def plan(**signals):
    return ChannelPlan(signals)


def test_gain_offset_then_clamp():
    section = Section('s', 10, {'coil': ChannelPlan({'r': Ramp()}, gain=2.0, offset_V=-3.0)})
    exp = Experiment([section], FS, limits={'coil': ChannelLimits(-2.5, 4.0)})
    coil = exp.block(0, 10)[0]
    np.testing.assert_array_equal(coil, np.clip(2.0 * np.arange(10) - 3.0, -2.5, 4.0))
    assert coil.min() == -2.5 and coil.max() == 4.0


def test_signals_summed_in_sorted_name_order():
    # float addition is not associative: only the sorted order gives (1 + 1e16) - 1e16 = 0
    signals = {'b': Constant(1e16, FS), 'c': Constant(-1e16, FS), 'a': Constant(1.0, FS)}
    exp = Experiment([Section('s', 3, {'coil': ChannelPlan(signals)})], FS,
                     limits={'coil': ChannelLimits(-1e17, 1e17)})
    np.testing.assert_array_equal(exp.block(0, 3)[0], (1.0 + 1e16) - 1e16)
    assert (1e16 + -1e16) + 1.0 != (1.0 + 1e16) - 1e16


def test_absent_channel_outputs_safe_value():
    exp = Experiment([Section('s', 5, {'coil': plan(r=Ramp())})], FS,
                     limits={'load_changer': ChannelLimits(0.5, 2.0)})
    block = exp.block(0, 5)
    np.testing.assert_array_equal(block[1], 0.5)     # 0 V clamped into [0.5, 2]
    exp2 = Experiment([Section('s', 5, {'coil': plan(r=Ramp())})], FS)
    np.testing.assert_array_equal(exp2.block(0, 5)[1], 0.0)


def test_sections_in_sequence_see_local_index():
    sections = [Section('a', 4, {'coil': plan(r=Ramp(1.0))}),
                Section('b', 3, {'load_changer': plan(r=Ramp(-1.0))}),
                Section('c', 2, {'coil': plan(k=Constant(7.0, FS))})]
    exp = Experiment(sections, FS)
    assert exp.total_samples == 9
    np.testing.assert_array_equal(exp.boundaries, [0, 4, 7, 9])
    block = exp.block(0, 11)
    np.testing.assert_array_equal(block[0], [0, 1, 2, 3, 0, 0, 0, 7, 7, 0, 0])
    np.testing.assert_array_equal(block[1], [0, 0, 0, 0, 0, -1, -2, 0, 0, 0, 0])
    assert [exp.section_at(k).name for k in (0, 3, 4, 6, 7, 8)] == list('aabbcc')
    assert exp.section_at(9) is None and exp.section_index_at(100) == -1


def test_blocks_spanning_boundaries_equal_whole():
    sections = [Section('a', 7, {'coil': plan(s=Sine(1.0, 3.0, 0.1, FS))}),
                Section('b', 1, {'coil': plan(r=Ramp())}),
                Section('c', 5, {'load_changer': plan(s=Sine(0.5, 7.0, 0.0, FS))})]
    exp = Experiment(sections, FS)
    whole = exp.block(0, 20)
    for size in (1, 2, 3, 6, 13, 20):
        parts = np.concatenate([exp.block(i, size) for i in range(0, 20, size)], axis=1)
        np.testing.assert_array_equal(parts[:, :20], whole)
    np.testing.assert_array_equal(exp.block(5, 10), whole[:, 5:15])


def test_past_the_end_is_safe_value_and_shape():
    exp = Experiment([Section('a', 3, {'coil': plan(k=Constant(1.0, FS))})], FS,
                     limits={'coil': ChannelLimits(-1.0, -0.25)})
    block = exp.block(100, 4)
    assert block.shape == (2, 4) and block.dtype == np.float64
    np.testing.assert_array_equal(block[0], -0.25)
    np.testing.assert_array_equal(block[1], 0.0)
    assert exp.block(0, 0).shape == (2, 0)


def test_block_rejects_negative_arguments():
    exp = Experiment([Section('a', 3, {})], FS)
    with pytest.raises(BlockError):
        exp.block(-1, 3)
    with pytest.raises(BlockError):
        exp.block(0, -3)


def test_experiment_validation():
    with pytest.raises(SignalError, match='unknown channel'):
        Experiment([Section('a', 3, {'coill': plan()})], FS)
    with pytest.raises(SignalError, match='Hz'):
        Experiment([Section('a', 3, {'coil': plan(s=Sine(1.0, 1.0, 0.0, 2 * FS))})], FS)
    with pytest.raises(SignalError, match='distinct'):
        Experiment([Section('a', 3, {}), Section('a', 3, {})], FS)
    with pytest.raises(SignalError):
        ChannelLimits(1.0, -1.0)


def test_section_from_duration_rounds():
    assert Section.from_duration('a', 0.0149, 1000.0, {}).n_samples == 15
