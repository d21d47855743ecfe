"""
The host's estimate of a device's sample clock, from the arrivals of its measurement blocks.

A block whose last sample is device sample ``end_index - 1`` cannot arrive before the device
took that sample, ``end_index / rate`` after the device's clock started. So every arrival
bounds the start from above: ``start <= arrival - end_index / rate``. The estimate keeps the
earliest bound seen (the one closest to the truth: arrivals are only ever delayed), so one
late block (a stalled host, a delayed first block) does not leave the estimate behind for the
rest of the run. The estimate of the device's index is then never ahead of the device by more
than the clocks' drift, and behind it only by the smallest transit delay seen.
"""

from __future__ import annotations


def earliest_start_ns(start_ns: int, arrival_ns: int, end_index: int,
                      sample_rate_Hz: float) -> int:
    """
    The device clock's start after one more block arrival.

    Parameters
    ----------
    start_ns : int
        The estimate so far (host monotonic clock) [ns].
    arrival_ns : int
        When the block arrived (host monotonic clock) [ns].
    end_index : int
        Device index one past the block's last sample.
    sample_rate_Hz : float
        The device's sample rate [Hz].

    Returns
    -------
    int
        The earlier of the estimate and the bound this arrival gives [ns].
    """
    return min(int(start_ns), int(arrival_ns) - int(end_index * 1e9 / sample_rate_Hz))


def device_index_at(now_ns: int, start_ns: int, sample_rate_Hz: float) -> int:
    """
    The device's sample index at a host time.

    Parameters
    ----------
    now_ns : int
        Host monotonic time [ns].
    start_ns : int
        The device clock's start on the host clock [ns].
    sample_rate_Hz : float
        The device's sample rate [Hz].

    Returns
    -------
    int
        The index of the sample the device takes at that time (0 before the start).
    """
    return max(0, int((int(now_ns) - int(start_ns)) * 1e-9 * sample_rate_Hz))
