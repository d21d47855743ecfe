"""Pacing policies of block producers."""

import numpy as np
import pytest

from emfc_ros.core.blocks import Block, Continuity
from emfc_ros.core.excitation_queue import DROPPED, ExcitationQueue
from emfc_ros.core.pacing import ClockPacer, ConsumerPacer


def test_clock_pacer_allows_blocks_as_time_passes_with_lead():
    p = ClockPacer(sample_rate_Hz=1000.0, block_size=100, lead_blocks=2, start_time_s=5.0)
    assert p.allowed_index(5.0) == 300          # block 0 due now, plus 2 ahead
    assert p.allowed_index(5.0999) == 300
    assert p.allowed_index(5.1) == 400
    assert p.allowed_index(4.0) == 0            # before the start nothing is due
    assert abs(p.lag_s(5.5, 300, 1000.0) - 0.2) < 1e-12


def test_consumer_pacer_window_and_stale_acknowledgements():
    p = ConsumerPacer(block_size=100, window_blocks=4)
    assert p.allowed_index() == 400
    p.acknowledge(250)
    assert p.allowed_index() == 650
    p.acknowledge(100)                          # stale: ignored
    assert p.allowed_index() == 650
    p.reset()
    assert p.allowed_index() == 400


def _started(pacer, now_s=0.0):
    """A pacer whose consumer is matched (one subscription, one acknowledging publisher)."""
    decision = pacer.poll(now_s, subscribers=1, acknowledgers=1)
    assert decision.waiting == '' and decision.error == ''
    return decision


def test_consumer_pacer_holds_sample_0_until_a_consumer_is_matched_without_time_limit():
    p = ConsumerPacer(block_size=100, window_blocks=4, ack_timeout_s=1.0,
                      consumer_timeout_s=5.0)
    d = p.poll(0.0, subscribers=0, acknowledgers=0)
    assert d.allowed_index == 0 and d.resend_from is None and d.error == ''
    assert 'publisher of acknowledgements' in d.waiting and 'subscription' in d.waiting
    # A subscriber alone (a recorder, say) is not a consumer that acknowledges.
    d = p.poll(100.0, subscribers=1, acknowledgers=0)
    assert d.allowed_index == 0 and 'acknowledgements' in d.waiting
    # Waiting for a consumer to appear is reported, never an error: it may be starting.
    d = p.poll(1e6, subscribers=0, acknowledgers=1)
    assert d.allowed_index == 0 and d.error == '' and 'subscription' in d.waiting
    d = p.poll(1e6 + 1.0, subscribers=1, acknowledgers=1)
    assert d.allowed_index == 400 and d.waiting == '' and d.resend_from is None
    assert p.started


def test_consumer_pacer_min_subscribers():
    p = ConsumerPacer(block_size=10, window_blocks=2, min_subscribers=3)
    assert 'subscription' in p.poll(0.0, subscribers=2, acknowledgers=1).waiting
    assert p.poll(0.0, subscribers=3, acknowledgers=1).allowed_index == 20
    # 0 counts as 1: consumer pacing always needs a subscription.
    q = ConsumerPacer(block_size=10, window_blocks=2, min_subscribers=0)
    assert q.poll(0.0, subscribers=0, acknowledgers=1).allowed_index == 0


def test_consumer_pacer_resends_an_unacknowledged_window_from_the_acknowledged_block():
    p = ConsumerPacer(block_size=100, window_blocks=4, ack_timeout_s=1.0,
                      consumer_timeout_s=10.0)
    _started(p, 0.0)
    p.sent(400)
    assert p.in_flight == 400
    d = p.poll(0.99, 1, 1)
    assert d.resend_from is None and d.waiting == ''
    d = p.poll(1.0, 1, 1)
    assert d.resend_from == 0 and p.resends == 1 and 'acknowledgement' in d.waiting
    assert d.allowed_index == 400
    # The next re-send comes one ack_timeout_s later, not at every poll.
    assert p.poll(1.5, 1, 1).resend_from is None
    assert p.poll(2.0, 1, 1).resend_from == 0 and p.resends == 2
    # A partial acknowledgement (mid-block) moves the window and restarts the timers; the
    # re-send starts at the block boundary so that re-sent blocks are the original blocks.
    assert p.acknowledge(250, now_s=2.5)
    assert not p.acknowledge(250, now_s=2.6)              # no progress
    p.sent(650)
    d = p.poll(3.4, 1, 1)
    assert d.resend_from is None and d.allowed_index == 650 and d.waiting == ''
    d = p.poll(3.5, 1, 1)
    assert d.resend_from == 200


def test_consumer_pacer_reports_a_silent_consumer_as_an_error_and_stays_failed():
    p = ConsumerPacer(block_size=100, window_blocks=2, ack_timeout_s=0.5,
                      consumer_timeout_s=3.0)
    _started(p, 10.0)
    p.sent(200)
    resends = [p.poll(10.0 + 0.25 * k, 1, 1).resend_from for k in range(1, 12)]
    assert resends.count(0) == 5 and p.error == ''
    d = p.poll(13.0, 1, 1)
    assert d.error and 'no acknowledgement for 3.0 s' in d.error
    assert '200 samples from index 0' in d.error and '5 re-send' in d.error
    assert d.resend_from is None and d.allowed_index == 200
    # Sticky until reset (a new epoch).
    assert p.acknowledge(200, now_s=13.1)
    assert p.poll(13.2, 1, 1).error == d.error
    p.reset(20.0)
    assert p.error == '' and p.acknowledged == 0 and not p.started and p.sent_end == 0
    assert p.poll(20.0, 1, 1).allowed_index == 200


def test_consumer_pacer_has_no_timeout_while_nothing_is_in_flight():
    p = ConsumerPacer(block_size=100, window_blocks=2, ack_timeout_s=0.5,
                      consumer_timeout_s=1.0)
    _started(p, 0.0)
    p.sent(200)
    assert p.acknowledge(200, now_s=0.1)
    d = p.poll(100.0, 1, 1)               # all acknowledged: the producer is not waiting
    assert d.error == '' and d.resend_from is None and d.waiting == ''
    p.sent(400)
    assert p.poll(100.4, 1, 1).resend_from is None
    assert p.poll(100.5, 1, 1).resend_from == 200


def test_consumer_pacer_rejects_acknowledgements_beyond_what_was_sent():
    p = ConsumerPacer(block_size=100, window_blocks=2)
    _started(p)
    p.sent(200)
    assert p.acceptable(200) and p.acceptable(0)
    assert not p.acceptable(201) and not p.acceptable(-1)
    assert p.rejected == 2


@pytest.mark.parametrize('kwargs, match', [
    ({'block_size': 0}, 'block_size'),
    ({'window_blocks': 0}, 'window_blocks'),
    ({'ack_timeout_s': 0.0}, 'ack_timeout_s'),
    ({'ack_timeout_s': float('nan')}, 'ack_timeout_s'),
    ({'ack_timeout_s': 2.0, 'consumer_timeout_s': 1.0}, 'consumer_timeout_s'),
])
def test_consumer_pacer_refuses_bad_settings(kwargs, match):
    args = dict(block_size=100, window_blocks=2)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        ConsumerPacer(**args)


class _LossyLink:
    """
    Producer, consumer and the two directions between them, in simulated time.

    Blocks sent before ``blocks_from_s`` and acknowledgements sent before ``acks_from_s``
    are lost (the subscription or the acknowledging publisher not yet matched on the far
    side); the consumer is an ExcitationQueue that acknowledges what it consumed and, as
    the plant simulator and the bridge do, acknowledges again when a block it has comes
    again.
    """

    def __init__(self, total, block, window, blocks_from_s, acks_from_s,
                 consumer_up_s=0.0):
        self.total, self.block = total, block
        self.pacer = ConsumerPacer(block, window, ack_timeout_s=1.0, consumer_timeout_s=10.0)
        self.queue = ExcitationQueue([0.0])
        self.blocks_from_s, self.acks_from_s = blocks_from_s, acks_from_s
        self.consumer_up_s = consumer_up_s
        self.next_index = 0
        self.consumed = []
        self.kinds = []

    def step(self, now_s):
        up = now_s >= self.consumer_up_s
        d = self.pacer.poll(now_s, subscribers=int(up), acknowledgers=int(up))
        if d.error:
            return d.error
        if d.resend_from is not None:
            self.next_index = d.resend_from
        allowed = min(d.allowed_index, self.total)
        while self.next_index < allowed:
            n = min(self.block, self.total - self.next_index)
            samples = np.arange(self.next_index, self.next_index + n, dtype=float)[None, :]
            self.next_index += n
            self.pacer.sent(self.next_index)
            if now_s >= self.blocks_from_s:
                self._deliver(Block(self.next_index - n, 1000.0, 1, samples), now_s)
        return ''

    def _deliver(self, block, now_s):
        kind = self.queue.push(block)
        self.kinds.append(kind)
        if kind in DROPPED:
            ack = self.queue.head_index
        else:
            samples, real = self.queue.pop(self.queue.queued)
            self.consumed.append(samples[0, :real])
            ack = self.queue.head_index
        if now_s >= self.acks_from_s and self.pacer.acceptable(ack):
            self.pacer.acknowledge(ack, now_s)


@pytest.mark.parametrize('blocks_from_s, acks_from_s, consumer_up_s', [
    (0.0, 0.0, 0.0),        # everything matched at once
    (0.0, 0.0, 3.0),        # the consumer starts 3 s late: sample 0 waits for it
    (2.5, 0.0, 0.0),        # the first window is lost (subscription matched late)
    (0.0, 4.2, 0.0),        # the first acknowledgements are lost
    (1.7, 3.3, 0.5),        # both, after a late start
])
def test_consumer_pacing_recovers_every_sample_from_0_after_lost_blocks_or_acks(
        blocks_from_s, acks_from_s, consumer_up_s):
    link = _LossyLink(total=2550, block=100, window=4, blocks_from_s=blocks_from_s,
                      acks_from_s=acks_from_s, consumer_up_s=consumer_up_s)
    now = 0.0
    while link.pacer.acknowledged < link.total and now < 60.0:
        assert link.step(now) == ''
        now += 0.05
    assert link.pacer.acknowledged == link.total
    got = np.concatenate(link.consumed)
    np.testing.assert_array_equal(got, np.arange(link.total, dtype=float))
    assert link.kinds[0] is Continuity.FIRST
    assert link.queue.counters()['gap_filled_samples'] == 0
    assert (link.pacer.resends > 0) == (blocks_from_s > consumer_up_s
                                        or acks_from_s > consumer_up_s)


def test_consumer_pacing_reports_a_consumer_that_never_acknowledges():
    link = _LossyLink(total=2550, block=100, window=4, blocks_from_s=0.0,
                      acks_from_s=float('inf'))
    now, error = 0.0, ''
    while not error and now < 60.0:
        error = link.step(now)
        now += 0.05
    assert error and 'no acknowledgement' in error
    assert 10.0 <= now <= 10.2
    assert link.pacer.resends == 9
