"""Tests of the wall-time rate limit of messages due on simulated time."""

import numpy as np
import pytest

from emfc_ros.core.sim.state_rate import BURST_S, StateRateLimiter


def test_no_limit_lets_everything_through():
    limiter = StateRateLimiter(0.0)
    np.testing.assert_array_equal(limiter.choose(100, 0.0), np.arange(100))
    assert limiter.decimated == 0


def test_a_burst_is_cut_to_the_bucket_and_spread_evenly():
    limiter = StateRateLimiter(500.0)
    chosen = limiter.choose(100, 10.0)
    assert len(chosen) == int(BURST_S * 500.0) == 50
    assert chosen[0] == 0 and chosen[-1] == 99
    steps = np.diff(chosen)
    assert steps.min() >= 1 and steps.max() - steps.min() <= 1     # evenly spread
    assert limiter.decimated == 50


@pytest.mark.parametrize('rate_Hz, due_per_call, period_s', [
    (500.0, 100, 0.0033),       # owner mode at 30x: 100 states due every 3.3 ms
    (200.0, 10, 0.001),
    (1000.0, 7, 0.02),          # fewer due than allowed: all through
])
def test_the_long_run_rate_never_exceeds_the_limit(rate_Hz, due_per_call, period_s):
    limiter = StateRateLimiter(rate_Hz)
    sent = 0
    calls = 2000
    for k in range(calls):
        sent += len(limiter.choose(due_per_call, k * period_s))
    wall_s = (calls - 1) * period_s
    assert sent <= rate_Hz * wall_s + limiter.capacity
    due = calls * due_per_call
    assert sent + limiter.decimated == due
    # As many as the limit allows (or all of them) got through.
    assert sent >= min(due, rate_Hz * wall_s) - 1


def test_time_going_backwards_adds_nothing():
    limiter = StateRateLimiter(100.0)
    assert len(limiter.choose(100, 5.0)) == 10
    assert len(limiter.choose(100, 4.0)) == 0
    assert limiter.decimated == 190


def test_a_limit_that_is_not_a_number_is_refused():
    with pytest.raises(ValueError, match='max_rate_Hz'):
        StateRateLimiter(float('nan'))
