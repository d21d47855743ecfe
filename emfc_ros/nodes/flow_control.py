"""
Back-pressure from reliable subscribers on a node that owns time.

A reliable KEEP_LAST writer overwrites its oldest unacknowledged message when its history
is full: a subscriber that was not scheduled for a moment (a recorder on a loaded host)
then loses messages for good, and only its ``message_lost`` event says so. Where the
publishing node owns time (the plant simulator in ``owner`` mode) nothing is lost by
waiting, so after every batch of blocks it waits, bounded, until every matched reliable
subscription has acknowledged them. Nodes in real time never wait: the DAQ bridge, and the
signal generator, whose consumer may be a device (a consumer-paced generator feeding a plant
in owner mode is held back by the plant's acknowledgements, ``window_blocks`` ahead of it, so
its excitation writer cannot overrun either).

A subscriber acknowledges when the writer sends a heartbeat. Fast DDS sends one with the
data each time about half the socket send buffer (``net.core.wmem_default``, 208 KiB here:
about 104 KiB) has been sent, otherwise only periodically (about 1 s). A batch is therefore
at least :data:`BATCH_BYTES` (measured: waits returned at once from 120 KB per batch and
waited for the periodic heartbeat up to 100 KB), and at most :data:`MAX_BLOCKS`, half a
block writer's history (100). Blocks too small for both (under 5.2 KB) are not waited for;
the diagnostics count those batches (``ack_skipped``).
"""

from __future__ import annotations

import time

from rclpy.duration import Duration

#: Blocks published between two waits at least.
EVERY_BLOCKS = 20
#: Bytes of block data published between two waits at least [B] (see the module text).
BATCH_BYTES = 256 * 1024
#: Blocks between two waits at most: half the depth of a block writer's history.
MAX_BLOCKS = 50
#: Bound of one wait [s]; a subscriber that stays silent this long is counted, then the
#: publisher goes on (its history may then overrun that subscriber's unread messages).
ACK_TIMEOUT_S = 2.0


class AckFlowControl:
    """
    Wait after each batch of blocks until all reliable subscriptions acknowledged them.

    Parameters
    ----------
    publisher : rclpy.publisher.Publisher or None
        The reliable block publisher; None never waits.
    timeout_s : float
        Bound of one wait [s].
    """

    def __init__(self, publisher, timeout_s: float = ACK_TIMEOUT_S) -> None:
        self._publisher = publisher
        self._timeout = Duration(nanoseconds=int(timeout_s * 1e9))
        self._blocks = 0
        self._bytes = 0
        self.waits = 0
        self.timeouts = 0
        self.skipped = 0
        self.waited_s = 0.0
        self.longest_wait_s = 0.0

    def published(self, nbytes: int) -> None:
        """
        Count one published block; wait for the acknowledgements when a batch is complete.

        Parameters
        ----------
        nbytes : int
            The block's sample data [B].
        """
        if self._publisher is None:
            return
        self._blocks += 1
        self._bytes += int(nbytes)
        if self._blocks < EVERY_BLOCKS or (self._bytes < BATCH_BYTES
                                           and self._blocks < MAX_BLOCKS):
            return
        small = self._bytes < BATCH_BYTES
        self._blocks = self._bytes = 0
        if small:       # would wait for the periodic heartbeat: not waited for, counted
            self.skipped += 1
            return
        start = time.monotonic()
        if not self._publisher.wait_for_all_acked(self._timeout):
            self.timeouts += 1
        waited = time.monotonic() - start
        self.waits += 1
        self.waited_s += waited
        self.longest_wait_s = max(self.longest_wait_s, waited)

    def counters(self) -> dict:
        """
        The diagnostics of the flow control.

        Returns
        -------
        dict
            ``ack_waits``, ``ack_timeouts`` (waits that ended at the bound),
            ``ack_skipped`` (batches of blocks too small to wait for), ``ack_wait_s`` (time
            spent waiting [s]) and ``ack_longest_wait_s`` [s].
        """
        return {'ack_waits': self.waits, 'ack_timeouts': self.timeouts,
                'ack_skipped': self.skipped, 'ack_wait_s': round(self.waited_s, 3),
                'ack_longest_wait_s': round(self.longest_wait_s, 3)}
