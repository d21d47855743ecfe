"""
A sample-exact FIFO of actuator setpoints fed by excitation blocks.

The plant simulator and the bridge read setpoints sample by sample on their own clock; the
excitation arrives in blocks with sample indices. This queue keeps the two aligned: a new
stream epoch (or the first block) restarts it, contiguous blocks are appended, a gap is
filled with the safe values (and counted, never hidden), late, duplicate and overlapping
blocks are dropped and counted, and reading more than is queued pads with the safe values
(an underrun, counted). A gap too large to fill resynchronises the queue at the new block:
``head_index`` jumps, so whoever stamps output with it shows the same gap.

Blocks that cannot be setpoints are refused with :class:`BlockError` (the caller counts it
with the reason): non-finite values, and a block more than ``max_gap_samples`` ahead of the
stream in the same epoch (a far-future index, by a bug or a forged message). Such a block
does not move the stream: later valid blocks go on as before. A sender that really jumped
ahead is followed once :data:`RESYNC_BLOCKS` contiguous blocks confirm the new position
(the first of them are refused; the queue resynchronises at the confirming block).
"""

from __future__ import annotations

import collections
from typing import Deque, Optional, Sequence, Tuple

import numpy as np

from emfc_ros.core.blocks import Block, Continuity, SequenceTracker
from emfc_ros.core.errors import BlockError

#: How a block the queue already has shows up (dropped and counted): a re-sent block.
DROPPED = frozenset({Continuity.DUPLICATE, Continuity.REORDERED, Continuity.OVERLAP})
#: Contiguous far-ahead blocks that confirm a jump of the stream (the last one is taken).
RESYNC_BLOCKS = 3


class JumpGuard:
    """
    Refuse a block far ahead of its stream until contiguous blocks confirm the jump.

    Parameters
    ----------
    max_gap_samples : int
        Largest jump ahead within an epoch that passes at once.
    """

    def __init__(self, max_gap_samples: int = 1_000_000) -> None:
        self.max_gap_samples = int(max_gap_samples)
        self.refused = 0
        self._candidate: Tuple[int, int, int] = (-1, -1, 0)   # next index, epoch, count

    def check(self, tracker: SequenceTracker, block: Block) -> None:
        """
        Pass the block, or refuse it (before ``tracker`` sees it).

        Parameters
        ----------
        tracker : SequenceTracker
            The stream's tracker (its expected index and epoch).
        block : Block
            The incoming block.

        Raises
        ------
        BlockError
            If the block is a far-future one not yet confirmed.
        """
        expected = tracker.expected
        first = block.first_sample_index
        if expected is None or block.epoch != tracker.epoch or \
                first - expected <= self.max_gap_samples:
            self._candidate = (-1, -1, 0)
            return
        nxt, epoch, count = self._candidate
        count = count + 1 if (first, block.epoch) == (nxt, epoch) else 1
        self._candidate = (first + block.n_samples, block.epoch, count)
        if count >= RESYNC_BLOCKS:
            self._candidate = (-1, -1, 0)
            return
        self.refused += 1
        raise BlockError(f'block at index {first} is {first - expected} samples ahead of the '
                         f'stream (more than {self.max_gap_samples}): refused; the stream '
                         f'goes on at {expected} ({RESYNC_BLOCKS} contiguous blocks there '
                         'would move it)')


class ExcitationQueue:
    """
    FIFO of setpoint samples, ``n_channels`` rows.

    Parameters
    ----------
    safe_values : sequence of float
        Per-channel value used for gaps and underruns (for example 0 V).
    max_samples : int
        Most samples held; pushing beyond it drops the block (counted as overflow).
    max_gap_samples : int
        Largest jump ahead within an epoch taken at once; a block further ahead is refused
        until :data:`RESYNC_BLOCKS` contiguous blocks confirm it.
    """

    def __init__(self, safe_values: Sequence[float], max_samples: int = 10_000_000,
                 max_gap_samples: int = 1_000_000) -> None:
        self.guard = JumpGuard(max_gap_samples)
        self.non_finite_blocks = 0
        self.safe = np.asarray(safe_values, dtype=np.float64).reshape(-1, 1)
        self.n_channels = int(self.safe.shape[0])
        self.max_samples = int(max_samples)
        self.tracker = SequenceTracker()
        self._chunks: Deque[np.ndarray] = collections.deque()
        self._offset = 0          # samples already read from the first chunk
        self._queued = 0
        self.head_index = 0       # excitation index of the next sample to be read
        self.epoch = None
        self.underrun_samples = 0
        self.gap_filled_samples = 0
        #: Index of the first sample a gap filled (or a resynchronisation skipped); None.
        self.first_gap_index: Optional[int] = None
        self.dropped_blocks = 0
        self.overflow_blocks = 0
        self.resyncs = 0
        self.resync_dropped_samples = 0

    @property
    def queued(self) -> int:
        """
        Samples waiting to be read.

        Returns
        -------
        int
            The count.
        """
        return self._queued

    def push(self, block: Block) -> Continuity:
        """
        Add a received block.

        Parameters
        ----------
        block : Block
            The excitation block; its channel count must match.

        Returns
        -------
        Continuity
            How the block continued the stream (duplicates and the like are dropped).

        Raises
        ------
        BlockError
            If the channel count differs.
        """
        if block.samples.shape[0] != self.n_channels:
            raise BlockError(f'excitation block has {block.samples.shape[0]} channels, '
                             f'expected {self.n_channels}')
        if not np.all(np.isfinite(block.samples)):
            self.non_finite_blocks += 1
            raise BlockError(f'excitation block at index {block.first_sample_index} holds NaN '
                             'or infinite values')
        self.guard.check(self.tracker, block)
        expected = self.tracker.expected
        kind = self.tracker.observe(block.first_sample_index, block.n_samples, block.epoch)
        if kind in (Continuity.FIRST, Continuity.RESTART):
            self._chunks.clear()
            self._offset = 0
            self._queued = 0
            self.head_index = block.first_sample_index
            self.epoch = block.epoch
        elif kind is Continuity.GAP:
            missing = block.first_sample_index - expected
            if self.first_gap_index is None:
                self.first_gap_index = expected
            if self._queued + missing + block.n_samples <= self.max_samples:
                self._append(np.repeat(self.safe, missing, axis=1))
                self.gap_filled_samples += missing
            else:
                # Too large to fill: resynchronise at the block, dropping what is queued.
                # The reader sees the jump in head_index, so the gap stays visible.
                self.resync_dropped_samples += self._queued
                self.resyncs += 1
                self._chunks.clear()
                self._offset = 0
                self._queued = 0
                self.head_index = block.first_sample_index
        elif kind is not Continuity.CONTIGUOUS:
            self.dropped_blocks += 1
            return kind
        if self._queued + block.n_samples > self.max_samples:
            # Dropped: rewind the tracker so the next block shows the hole as a gap, which
            # is then filled with safe values and counted, never hidden.
            self.overflow_blocks += 1
            self.tracker.expected = block.first_sample_index
            return kind
        self._append(np.array(block.samples, dtype=np.float64))
        return kind

    def _append(self, samples: np.ndarray) -> None:
        if samples.shape[1]:
            self._chunks.append(samples)
            self._queued += samples.shape[1]

    def pop(self, n: int) -> Tuple[np.ndarray, int]:
        """
        Read the next ``n`` samples, padding with the safe values if fewer are queued.

        Parameters
        ----------
        n : int
            Samples to read.

        Returns
        -------
        samples : numpy.ndarray
            Shape ``(n_channels, n)``.
        real : int
            How many of them came from the stream (the rest are padding).
        """
        out = np.empty((self.n_channels, n))
        filled = 0
        while filled < n and self._chunks:
            chunk = self._chunks[0]
            take = min(n - filled, chunk.shape[1] - self._offset)
            out[:, filled:filled + take] = chunk[:, self._offset:self._offset + take]
            filled += take
            self._offset += take
            if self._offset == chunk.shape[1]:
                self._chunks.popleft()
                self._offset = 0
        self._queued -= filled
        self.head_index += filled
        if filled < n:
            out[:, filled:] = self.safe
            self.underrun_samples += n - filled
        return out, filled

    def counters(self) -> dict:
        """
        Stream defects and queue figures.

        Returns
        -------
        dict
            Tracker counters plus gap-filled, underrun, dropped, overflow, far-future and
            non-finite counts.
        """
        out = self.tracker.counters()
        out.update({'queued_samples': self._queued,
                    'gap_filled_samples': self.gap_filled_samples,
                    'underrun_samples': self.underrun_samples,
                    'dropped_blocks': self.dropped_blocks,
                    'overflow_blocks': self.overflow_blocks, 'resyncs': self.resyncs,
                    'resync_dropped_samples': self.resync_dropped_samples,
                    'far_future_blocks': self.guard.refused,
                    'non_finite_blocks': self.non_finite_blocks})
        return out


def fill_outputs(queue: Optional[ExcitationQueue], first: int, n: int, out: np.ndarray,
                 unstreamed_end: int) -> Tuple[int, int, int]:
    """
    Write a device's streamed outputs for samples ``first .. first + n`` from its queue.

    ``out`` holds the safe values on entry; where the stream covers a sample its value
    replaces them. Queued samples behind the clock are dropped as late; samples the stream
    does not cover once it has begun are underruns (left at the safe values). Before the
    host's first setpoint (the queue has seen no block) every sample is left safe and the
    samples are remembered as unstreamed: a late first block's samples there were output
    safe, underruns too where they were not the safe values.

    Parameters
    ----------
    queue : ExcitationQueue or None
        The epoch's setpoint queue (None: no stream).
    first, n : int
        The device samples to fill.
    out : numpy.ndarray
        ``(outputs, n)``, the safe values on entry; filled in place.
    unstreamed_end : int
        End of the samples output before the first setpoint block came.

    Returns
    -------
    late : int
        Queued samples dropped because their device samples had passed.
    underrun : int
        Samples output at the safe values for want of setpoints.
    unstreamed_end : int
        The new end of the unstreamed samples.
    """
    if queue is None or queue.tracker.expected is None:
        return 0, 0, first + n                   # the host has not streamed yet
    late = underrun = 0
    if queue.head_index < first:                 # queued samples behind the clock
        late = min(first - queue.head_index, queue.queued)
        if late:
            head = queue.head_index
            values = queue.pop(late)[0]
            # Late samples of a first frame were output at the safe values before the frame
            # came, when no stream was there to run dry: underruns too, unless they were the
            # safe values themselves (what was output is what was asked for); later ones
            # were counted as underruns when their blocks ran.
            missed = values[:, :max(0, min(head + late, unstreamed_end) - head)]
            underrun += int(np.count_nonzero(np.any(missed != queue.safe, axis=0)))
    lead = max(0, queue.head_index - first)      # before the stream's next sample
    if lead >= n:
        return late, underrun, unstreamed_end
    take = min(n - lead, queue.queued)
    if take:
        out[:, lead:lead + take] = queue.pop(take)[0]
    return late, underrun + n - lead - take, unstreamed_end
