"""
When a block producer may send its next blocks.

Two policies: paced to a clock (wall time injected by the caller, with a lead of a few
blocks), or paced by a consumer that acknowledges how far it has consumed (flow control with
a window of blocks in flight). Both are pure: the caller passes the time or the
acknowledged index.
"""

from __future__ import annotations

import math


class ClockPacer:
    """
    Allow block ``b`` once the clock reaches its first sample time minus a lead.

    Parameters
    ----------
    sample_rate_Hz : float
        Sample rate [Hz].
    block_size : int
        Samples per block.
    lead_blocks : int
        How many blocks may be sent ahead of the clock (a sink buffers them).
    start_time_s : float
        Clock time of sample 0 [s].
    """

    def __init__(self, sample_rate_Hz: float, block_size: int, lead_blocks: int,
                 start_time_s: float) -> None:
        self.block_period_s = block_size / sample_rate_Hz
        self.block_size = block_size
        self.lead_blocks = lead_blocks
        self.start_time_s = start_time_s

    def allowed_index(self, now_s: float) -> int:
        """
        Sample index up to which blocks may have been sent at time ``now_s``.

        Parameters
        ----------
        now_s : float
            Current clock time [s].

        Returns
        -------
        int
            One past the last sample that may be sent.
        """
        # 1e-9 block of tolerance so that a tick exactly at a boundary is not lost to rounding
        elapsed_blocks = math.floor((now_s - self.start_time_s) / self.block_period_s + 1e-9)
        return max(0, elapsed_blocks + 1 + self.lead_blocks) * self.block_size

    def lag_s(self, now_s: float, next_index: int, sample_rate_Hz: float) -> float:
        """
        How far the producer is behind the clock.

        Parameters
        ----------
        now_s : float
            Current clock time [s].
        next_index : int
            Next sample index the producer will send.
        sample_rate_Hz : float
            Sample rate [Hz].

        Returns
        -------
        float
            Seconds by which sample ``next_index`` is late (negative when early).
        """
        return now_s - (self.start_time_s + next_index / sample_rate_Hz)


class ConsumerPacer:
    """
    Keep at most ``window_blocks`` blocks in flight ahead of the consumer's acknowledgement.

    Parameters
    ----------
    block_size : int
        Samples per block.
    window_blocks : int
        Blocks that may be sent beyond the acknowledged index.
    """

    def __init__(self, block_size: int, window_blocks: int) -> None:
        self.block_size = block_size
        self.window_blocks = window_blocks
        self.acknowledged = 0

    def acknowledge(self, consumed_index: int) -> None:
        """
        Record that the consumer needs sample ``consumed_index`` next.

        Parameters
        ----------
        consumed_index : int
            Samples consumed so far; stale (smaller) acknowledgements are ignored.
        """
        self.acknowledged = max(self.acknowledged, int(consumed_index))

    def reset(self) -> None:
        """Forget acknowledgements (a new stream epoch starts at index 0)."""
        self.acknowledged = 0

    def allowed_index(self) -> int:
        """
        Sample index up to which blocks may have been sent.

        Returns
        -------
        int
            ``acknowledged + window_blocks * block_size``.
        """
        return self.acknowledged + self.window_blocks * self.block_size
