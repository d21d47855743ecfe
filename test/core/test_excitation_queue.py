"""The setpoint FIFO between excitation blocks and a sample-clocked plant."""

import numpy as np
import pytest

from emfc_ros.core.blocks import Block, Continuity
from emfc_ros.core.errors import BlockError
from emfc_ros.core.excitation_queue import ExcitationQueue


def _block(first, n, epoch=1, value=None):
    k = np.arange(first, first + n, dtype=float)
    samples = np.vstack([k, -k]) if value is None else np.full((2, n), value)
    return Block(first, 100.0, epoch, samples)


def test_contiguous_blocks_read_back_in_any_chunking():
    q = ExcitationQueue([0.0, 0.0])
    for first in range(0, 100, 10):
        assert q.push(_block(first, 10)) in (Continuity.FIRST, Continuity.CONTIGUOUS)
    out = []
    for n in (3, 50, 1, 46):
        s, real = q.pop(n)
        assert real == n
        out.append(s)
    np.testing.assert_array_equal(np.hstack(out)[0], np.arange(100.0))
    assert q.head_index == 100 and q.queued == 0


def test_gap_is_filled_with_safe_values_and_counted():
    q = ExcitationQueue([0.5, -0.5])
    q.push(_block(0, 10))
    assert q.push(_block(15, 5)) is Continuity.GAP
    s, real = q.pop(20)
    assert real == 20
    np.testing.assert_array_equal(s[0, 10:15], 0.5)
    np.testing.assert_array_equal(s[1, 10:15], -0.5)
    np.testing.assert_array_equal(s[0, 15:], np.arange(15.0, 20.0))
    assert q.counters()['gap_filled_samples'] == 5
    assert q.counters()['missing_samples'] == 5


def test_underrun_pads_and_duplicates_are_dropped():
    q = ExcitationQueue([0.0, 0.0])
    q.push(_block(0, 10))
    assert q.push(_block(0, 10)) is Continuity.DUPLICATE
    s, real = q.pop(15)
    assert real == 10
    np.testing.assert_array_equal(s[:, 10:], 0.0)
    c = q.counters()
    assert (c['underrun_samples'], c['dropped_blocks'], c['duplicates']) == (5, 1, 1)


def test_new_epoch_restarts_the_queue():
    q = ExcitationQueue([0.0, 0.0])
    q.push(_block(0, 10, epoch=1))
    q.pop(4)
    assert q.push(_block(0, 10, epoch=2, value=7.0)) is Continuity.RESTART
    assert q.head_index == 0 and q.queued == 10 and q.epoch == 2
    s, _ = q.pop(10)
    np.testing.assert_array_equal(s, 7.0)


def test_wrong_channel_count_and_overflow():
    q = ExcitationQueue([0.0, 0.0], max_samples=15)
    with pytest.raises(BlockError, match='3 channels'):
        q.push(Block(0, 100.0, 1, np.zeros((3, 4))))
    q.push(_block(0, 10))
    q.push(_block(10, 10))
    assert q.counters()['overflow_blocks'] == 1
    assert q.queued == 10
    q.pop(10)
    assert q.push(_block(20, 5)) is Continuity.GAP       # the dropped block is not hidden
    s, _ = q.pop(15)
    np.testing.assert_array_equal(s[:, :10], 0.0)        # filled with safe values
    np.testing.assert_array_equal(s[0, 10:], np.arange(20.0, 25.0))
    assert q.counters()['gap_filled_samples'] == 10


def test_a_gap_too_large_to_fill_resynchronises_visibly():
    q = ExcitationQueue([0.0, 0.0], max_samples=100, max_gap_samples=10 ** 10)
    q.push(_block(0, 10))
    assert q.push(_block(10 ** 9, 10)) is Continuity.GAP
    assert q.head_index == 10 ** 9 and q.queued == 10
    s, real = q.pop(10)
    assert real == 10 and s[0, 0] == 10.0 ** 9
    c = q.counters()
    assert (c['resyncs'], c['resync_dropped_samples'], c['missing_samples']) == (
        1, 10, 10 ** 9 - 10)


def test_a_far_future_block_is_refused_and_does_not_block_the_stream():
    """One block at 2**52 (a bug or a forged message) must not swallow the stream."""
    q = ExcitationQueue([0.0, 0.0])
    q.push(_block(0, 10))
    with pytest.raises(BlockError, match='ahead of the stream'):
        q.push(_block(2 ** 52, 10))
    assert q.push(_block(10, 10)) is Continuity.CONTIGUOUS
    assert q.queued == 20 and q.counters()['far_future_blocks'] == 1
    # A sender that really jumped is followed once three contiguous blocks confirm it.
    far = 20_000_000                 # beyond max_samples: resynchronised, not filled
    for k in range(2):
        with pytest.raises(BlockError):
            q.push(_block(far + 10 * k, 10))
    assert q.push(_block(far + 20, 10)) is Continuity.GAP
    assert q.head_index == far + 20 and q.queued == 10
    c = q.counters()
    assert (c['far_future_blocks'], c['resyncs']) == (3, 1)


def test_non_finite_setpoints_are_refused():
    q = ExcitationQueue([0.0, 0.0])
    bad = _block(0, 10)
    samples = np.array(bad.samples)
    samples[1, 3] = np.nan
    with pytest.raises(BlockError, match='NaN or infinite'):
        q.push(Block(0, bad.sample_rate_Hz, bad.epoch, samples))
    assert q.queued == 0 and q.counters()['non_finite_blocks'] == 1
    assert q.push(_block(0, 10)) is Continuity.FIRST
