"""
When a block producer may send its next blocks.

Two policies: paced to a clock (wall time injected by the caller, with a lead of a few
blocks), or paced by a consumer that acknowledges how far it has consumed (flow control with
a window of blocks in flight). Both are pure: the caller passes the time, the acknowledged
index and the matched endpoint counts.

Consumer pacing never waits silently (``docs/decisions.md``, consumer pacing): sample 0
waits until a consumer is there, a window that is not acknowledged in time is re-sent from
the last acknowledgement, and a consumer that stays silent is reported as an error.
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Optional


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


@dataclass(frozen=True)
class PacingDecision:
    """
    What a consumer-paced producer may do now.

    Attributes
    ----------
    allowed_index : int
        One past the last sample that may have been sent.
    resend_from : int or None
        Rewind the producer to this sample index (a block boundary) and send again from
        there: the window was not acknowledged in time. None: carry on.
    waiting : str
        Empty while the stream flows; otherwise what the producer waits for, in words.
    error : str
        Empty, or why the stream has failed (the consumer stayed silent too long).
    """

    allowed_index: int
    resend_from: Optional[int] = None
    waiting: str = ''
    error: str = ''


class ConsumerPacer:
    """
    Keep at most ``window_blocks`` blocks in flight ahead of the consumer's acknowledgement.

    The epoch's sample 0 is held until a consumer is matched: at least one publisher of
    acknowledgements and ``min_subscribers`` (at least 1) subscriptions to the blocks.
    Samples sent but not acknowledged for ``ack_timeout_s`` are sent again from the last
    acknowledged block boundary (go-back-N; a consumer drops what it already has as
    duplicates). No acknowledgement progress for ``consumer_timeout_s`` while samples are
    in flight is an error. Waiting for a consumer to appear has no time limit: it is
    reported (``waiting``), the consumer may still be starting.

    Parameters
    ----------
    block_size : int
        Samples per block.
    window_blocks : int
        Blocks that may be sent beyond the acknowledged index.
    ack_timeout_s : float
        Silence after which the unacknowledged samples are sent again [s].
    consumer_timeout_s : float
        Silence after which the stream is reported failed [s]; at least ``ack_timeout_s``.
    min_subscribers : int
        Subscriptions to the blocks needed before sample 0 is sent [count]; 0 counts as 1.

    Raises
    ------
    ValueError
        If a size or a time is out of range.
    """

    def __init__(self, block_size: int, window_blocks: int, ack_timeout_s: float = 1.0,
                 consumer_timeout_s: float = 10.0, min_subscribers: int = 1) -> None:
        if int(block_size) < 1 or int(window_blocks) < 1:
            raise ValueError(f'block_size and window_blocks must be >= 1, got {block_size} '
                             f'and {window_blocks}')
        if not (math.isfinite(ack_timeout_s) and ack_timeout_s > 0.0):
            raise ValueError(f'ack_timeout_s must be a positive number of seconds, got '
                             f'{ack_timeout_s!r}')
        if not (math.isfinite(consumer_timeout_s) and consumer_timeout_s >= ack_timeout_s):
            raise ValueError(f'consumer_timeout_s must be at least ack_timeout_s '
                             f'({ack_timeout_s} s), got {consumer_timeout_s!r}')
        self.block_size = int(block_size)
        self.window_blocks = int(window_blocks)
        self.ack_timeout_s = float(ack_timeout_s)
        self.consumer_timeout_s = float(consumer_timeout_s)
        self.min_subscribers = max(1, int(min_subscribers))
        self.reset()

    def reset(self, now_s: float = 0.0) -> None:
        """
        Forget acknowledgements and timers (a new stream epoch starts at index 0).

        Parameters
        ----------
        now_s : float
            Current monotonic time [s].
        """
        self.acknowledged = 0
        self.sent_end = 0
        self.started = False
        self.resends = 0
        self.rejected = 0
        self.error = ''
        self._progress_s = now_s
        self._resent_s = now_s

    def acknowledge(self, consumed_index: int, now_s: Optional[float] = None) -> bool:
        """
        Record that the consumer needs sample ``consumed_index`` next.

        Parameters
        ----------
        consumed_index : int
            Samples consumed so far; stale (smaller or equal) acknowledgements are ignored.
        now_s : float, optional
            Current monotonic time [s]; restarts the timeouts on progress.

        Returns
        -------
        bool
            Whether the acknowledgement moved the stream on.
        """
        index = int(consumed_index)
        if index <= self.acknowledged:
            return False
        self.acknowledged = index
        if now_s is not None:
            self._progress_s = self._resent_s = now_s
        return True

    def acceptable(self, consumed_index: int) -> bool:
        """
        Whether an acknowledgement can belong to this epoch.

        Parameters
        ----------
        consumed_index : int
            The acknowledged index.

        Returns
        -------
        bool
            False (and counted in ``rejected``) for an index beyond what was sent, which a
            consumer of this epoch cannot have consumed (a stale one from an earlier epoch).
        """
        if 0 <= int(consumed_index) <= self.sent_end:
            return True
        self.rejected += 1
        return False

    def sent(self, end_index: int) -> None:
        """
        Record that samples up to ``end_index`` (exclusive) have been sent.

        Parameters
        ----------
        end_index : int
            One past the last sample sent.
        """
        self.sent_end = max(self.sent_end, int(end_index))

    def allowed_index(self) -> int:
        """
        Sample index up to which blocks may have been sent, by the window alone.

        Returns
        -------
        int
            ``acknowledged + window_blocks * block_size``.
        """
        return self.acknowledged + self.window_blocks * self.block_size

    @property
    def in_flight(self) -> int:
        """
        Samples sent and not yet acknowledged.

        Returns
        -------
        int
            The count.
        """
        return max(0, self.sent_end - self.acknowledged)

    def poll(self, now_s: float, subscribers: int, acknowledgers: int) -> PacingDecision:
        """
        Decide what may be sent now.

        Parameters
        ----------
        now_s : float
            Current monotonic time [s].
        subscribers : int
            Subscriptions matched to the block publisher [count].
        acknowledgers : int
            Publishers of acknowledgements matched to the producer [count].

        Returns
        -------
        PacingDecision
            Allowed index, a rewind point if the window must be sent again, and what the
            producer waits for or why it failed.
        """
        if self.error:
            return PacingDecision(self.sent_end, error=self.error)
        if not self.started:
            missing = []
            if acknowledgers < 1:
                missing.append('a publisher of acknowledgements')
            if subscribers < self.min_subscribers:
                missing.append(f'{self.min_subscribers} subscription(s) to the blocks '
                               f'({subscribers} matched)')
            if missing:
                self._progress_s = self._resent_s = now_s
                return PacingDecision(0, waiting='consumer: ' + ' and '.join(missing))
            self.started = True
            self._progress_s = self._resent_s = now_s
        if not self.in_flight:
            self._progress_s = self._resent_s = now_s
            return PacingDecision(self.allowed_index())
        silent_s = now_s - self._progress_s
        if silent_s >= self.consumer_timeout_s:
            self.error = (f'no acknowledgement for {silent_s:.1f} s (consumer_timeout_s '
                          f'{self.consumer_timeout_s:g}): {self.in_flight} samples from index '
                          f'{self.acknowledged} unacknowledged after {self.resends} re-send(s); '
                          f'{subscribers} subscription(s), {acknowledgers} acknowledging '
                          'publisher(s) matched')
            return PacingDecision(self.sent_end, error=self.error)
        resend = None
        if now_s - self._resent_s >= self.ack_timeout_s:
            resend = self.acknowledged // self.block_size * self.block_size
            self._resent_s = now_s
            self.resends += 1
        waiting = ''
        if silent_s >= self.ack_timeout_s:
            waiting = (f'acknowledgement: {self.in_flight} samples from index '
                       f'{self.acknowledged} unacknowledged for {silent_s:.1f} s')
        return PacingDecision(self.allowed_index(), resend, waiting)
