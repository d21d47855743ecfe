"""PRBS: period, autocorrelation, equality with scipy and purity for order 31."""

import numpy as np
import pytest
from scipy.signal import max_len_seq

from emfc_ros.core.errors import SignalError
from emfc_ros.core.signals import Prbs


@pytest.mark.parametrize('order,hold', [(2, 1), (3, 1), (4, 3), (5, 2), (7, 1), (10, 4)])
def test_period_is_exactly_2n_minus_1_times_hold(order, hold):
    prbs = Prbs(order, hold, -1.0, 1.0, 1000.0)
    period = (2 ** order - 1) * hold
    assert prbs.period_samples == period
    x = prbs.samples(np.arange(3 * period, dtype=np.int64))
    np.testing.assert_array_equal(x[:period], x[period:2 * period])
    np.testing.assert_array_equal(x[:period], x[2 * period:])
    for shift in range(1, period):
        if period % shift == 0:      # any shorter period divides the period
            assert not np.array_equal(x[:period], np.roll(x[:period], shift)), shift
    # each bit held for `hold` samples
    np.testing.assert_array_equal(x[:period].reshape(-1, hold), x[:period:hold, None]
                                  * np.ones((1, hold)))


@pytest.mark.parametrize('order', range(2, 13))
def test_two_valued_periodic_autocorrelation(order):
    n = 2 ** order - 1
    x = Prbs(order, 1, -1.0, 1.0, 1000.0).samples(np.arange(n, dtype=np.int64))
    spectrum = np.fft.fft(x)
    r = np.rint(np.fft.ifft(spectrum * np.conj(spectrum)).real)
    assert r[0] == n
    np.testing.assert_array_equal(r[1:], -1.0)


@pytest.mark.parametrize('order', range(2, 21))
def test_equals_scipy_max_len_seq_full_period(order):
    ref, _ = max_len_seq(order)
    x = Prbs(order, 1, 0.0, 1.0, 1000.0).samples(np.arange(2 ** order - 1, dtype=np.int64))
    np.testing.assert_array_equal(x, ref)


@pytest.mark.parametrize('order', range(21, 32))
def test_equals_scipy_prefix_and_state_large_orders(order):
    length = 50000
    ref, state = max_len_seq(order, length=length)
    prbs = Prbs(order, 1, 0.0, 1.0, 1000.0)
    np.testing.assert_array_equal(prbs.samples(np.arange(length, dtype=np.int64)), ref)
    np.testing.assert_array_equal(prbs.state_at(length), state)


def test_equals_scipy_with_initial_state_and_levels():
    state = [1, 0, 0, 1, 0, 1, 1, 0, 0]
    ref, _ = max_len_seq(9, state=state)
    prbs = Prbs(9, 2, -0.25, 0.75, 1000.0, state=state)
    x = prbs.samples(np.arange(2 * 511, dtype=np.int64))
    np.testing.assert_array_equal(x[::2], np.where(ref == 1, 0.75, -0.25))
    np.testing.assert_array_equal(prbs.bits(np.arange(511, 1022)), ref)


def test_order_31_block_far_in_equals_forward_generation():
    # scipy generated forward from the start, versus our direct jump to the block
    ref, _ = max_len_seq(31, length=2_000_000)
    fresh = Prbs(31, 1, 0.0, 1.0, 1000.0)
    k = np.arange(1_990_000, 2_000_000, dtype=np.int64)
    np.testing.assert_array_equal(fresh.samples(k), ref[k])


def test_order_31_jump_to_the_end_of_the_period_wraps_to_the_start():
    prbs = Prbs(31, 1, 0.0, 1.0, 1000.0)
    n = 2 ** 31 - 1
    start = n - 40_000
    x = prbs.samples(np.arange(start, start + 80_000, dtype=np.int64))
    # forward from the jumped-to state with scipy's own register
    forward, _ = max_len_seq(31, state=prbs.state_at(start), length=80_000)
    np.testing.assert_array_equal(x, forward)
    # the jump is right: 40 000 bits later the sequence starts over exactly
    head, _ = max_len_seq(31, length=40_000)
    np.testing.assert_array_equal(x[40_000:], head)
    np.testing.assert_array_equal(prbs.state_at(n), np.ones(31, dtype=np.int8))


def test_order_31_with_hold_is_pure():
    prbs = Prbs(31, 7, -1.0, 1.0, 1000.0)
    k = np.array([0, 6, 7, 10 ** 12, 10 ** 12 + 6, 10 ** 12 + 7, 3 * 10 ** 9], dtype=np.int64)
    whole = prbs.samples(k)
    single = np.array([Prbs(31, 7, -1.0, 1.0, 1000.0).samples(np.array([kk]))[0] for kk in k])
    np.testing.assert_array_equal(whole, single)
    bits = Prbs(31, 1, -1.0, 1.0, 1000.0).samples((k // 7) % (2 ** 31 - 1))
    np.testing.assert_array_equal(whole, bits)


@pytest.mark.parametrize('kwargs', [dict(order=1), dict(order=32), dict(hold_samples=0),
                                    dict(state=[0] * 5), dict(state=[1, 0])])
def test_rejects_bad_parameters(kwargs):
    args = dict(order=5, hold_samples=1, low_V=0.0, high_V=1.0, sample_rate_Hz=1000.0)
    args.update(kwargs)
    with pytest.raises(SignalError):
        Prbs(**args)
