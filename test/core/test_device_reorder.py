"""The host's reorder buffer: in-order delivery, gaps, duplicates, reordering, lateness."""

from hypothesis import given, settings, strategies as st

from emfc_ros.core.device.udp_backend import ReorderBuffer

N = 100


def _push(buf, seqs, now=0.0):
    out = []
    for s in seqs:
        out += buf.push(s, s * N, N, s, now)
    return out


def test_in_order_frames_are_delivered_at_once():
    buf = ReorderBuffer(window=4)
    assert _push(buf, range(10)) == list(range(10))
    assert buf.counters['delivered'] == 10
    assert sum(v for k, v in buf.counters.items() if k != 'delivered') == 0


def test_a_swapped_pair_is_put_back_in_order_and_counted_once():
    buf = ReorderBuffer(window=4)
    assert _push(buf, [0, 2, 1, 3]) == [0, 1, 2, 3]
    assert buf.counters['reordered'] == 1 and buf.counters['gaps'] == 0


def test_duplicates_are_dropped_whether_delivered_or_pending():
    buf = ReorderBuffer(window=4)
    assert _push(buf, [0, 0, 2, 2, 1, 1]) == [0, 1, 2]
    assert buf.counters['duplicates'] == 3


def test_a_missing_frame_becomes_a_gap_when_the_window_is_full():
    buf = ReorderBuffer(window=3)
    assert _push(buf, [0, 2, 3]) == [0]
    assert _push(buf, [4]) == [2, 3, 4]
    c = buf.counters
    assert (c['gaps'], c['missing_frames'], c['missing_samples']) == (1, 1, N)
    assert _push(buf, [1]) == [] and buf.counters['late'] == 1


def test_a_missing_frame_becomes_a_gap_after_the_timeout():
    buf = ReorderBuffer(window=8, timeout_s=0.1)
    assert buf.push(0, 0, N, 'a', 0.0) == ['a']
    assert buf.push(2, 2 * N, N, 'c', 1.0) == []
    assert buf.expire(1.05) == []
    assert buf.expire(1.1) == ['c']
    assert buf.counters['gaps'] == 1


def test_sequence_numbers_wrap_around():
    buf = ReorderBuffer(window=4)
    buf.reset(2 ** 32 - 2)
    out = []
    for i, s in enumerate([2 ** 32 - 2, 0, 2 ** 32 - 1, 1]):
        out += buf.push(s, i * N, N, s, 0.0)
    assert out == [2 ** 32 - 2, 2 ** 32 - 1, 0, 1]
    assert buf.counters['reordered'] == 1


@settings(max_examples=200, deadline=None)
@given(st.permutations(list(range(12))), st.lists(st.integers(0, 11), max_size=6),
       st.sets(st.integers(0, 11), max_size=4))
def test_fuzz_delivery_is_increasing_and_every_frame_is_accounted_for(order, dups, lost):
    buf = ReorderBuffer(window=4, timeout_s=1.0)
    arrivals = [s for s in order if s not in lost] + dups
    out = _push(buf, arrivals) + buf.expire(10.0)
    assert out == sorted(set(out))
    c = buf.counters
    received = len(arrivals)
    assert len(out) + c['duplicates'] + c['late'] == received
    assert c['index_discontinuities'] == 0
