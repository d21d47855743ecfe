"""The host's estimate of the device clock from block arrivals."""

import numpy as np

from emfc_ros.core.device.clock import device_index_at, earliest_start_ns

RATE_HZ = 10000.0
BLOCK = 1000


def test_a_late_first_block_does_not_leave_the_estimate_behind():
    # Device clock starts at host time 5 s; blocks of 0.1 s arrive 1 ms after their last
    # sample, except the first, which a stalled host read 0.4 s late.
    rng = np.random.default_rng(12)
    true_start = 5_000_000_000
    start = true_start + 100_000_000          # taken when START was confirmed, itself late
    delays = []
    for k in range(1, 30):
        end = k * BLOCK
        delay = 400_000_000 if k == 1 else 1_000_000 + int(rng.integers(0, 3_000_000))
        delays.append(delay)
        arrival = true_start + int(end * 1e9 / RATE_HZ) + delay
        start = earliest_start_ns(start, arrival, end, RATE_HZ)
        now = arrival
        truth = device_index_at(now, true_start, RATE_HZ)
        estimate = device_index_at(now, start, RATE_HZ)
        assert estimate <= truth                  # never ahead of the device
        if k >= 2:        # from the first on-time block: behind by the smallest delay seen
            assert truth - estimate <= min(delays) * RATE_HZ * 1e-9 + 1, (k, truth, estimate)
        else:             # the late first block alone: 0.4 s behind, as the old estimate stayed
            assert truth - estimate >= 0.1 * RATE_HZ
    assert start - true_start == min(delays)  # the smallest delay seen is the error


def test_the_estimate_only_moves_earlier_and_is_zero_before_the_start():
    start = earliest_start_ns(2_000_000_000, 2_500_000_000, 1000, RATE_HZ)
    assert start == 2_000_000_000                 # 0.5 s - 0.1 s of samples: no earlier bound
    assert earliest_start_ns(start, 2_050_000_000, 1000, RATE_HZ) == 1_950_000_000
    assert device_index_at(1_000_000_000, start, RATE_HZ) == 0
    assert device_index_at(start + 250_000_000, start, RATE_HZ) == 2500
