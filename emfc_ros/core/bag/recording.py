"""
A bag writer fed through a queue by a thread of its own, so that receivers never block.

The recorder node's callbacks call :meth:`QueuedBagWriter.put` (a non-blocking queue put);
the writer thread writes to :class:`~emfc_ros.core.bag.writer.BagWriter`, flushes every
``flush_period_s`` (so a killed process loses at most that much) and counts what it did. A
write error (disk full, file size limit) stops writing, keeps what is on disk repairable and
is reported by :meth:`QueuedBagWriter.stats`; the caller's process keeps running.
"""

from __future__ import annotations

import dataclasses
import queue
import threading
import time
from typing import Callable, Dict, Optional, Sequence

from emfc_ros.core.bag.qos import OfferedQos
from emfc_ros.core.bag.writer import BagWriter

_CONNECT, _WRITE, _CUSTOM, _CLOSE = range(4)


@dataclasses.dataclass
class RecorderStats:
    """
    A snapshot of what the writer thread has done.

    Attributes
    ----------
    state : str
        ``'recording'``, ``'closed'`` or ``'error'``.
    error : str
        The error message, if any.
    messages : dict
        Messages written per topic.
    bytes : dict
        Serialized bytes written per topic [B].
    queue_depth : int
        Messages taken and not yet written (one leaves the queue as it is counted written,
        so a snapshot with an empty queue has every taken message in ``messages``).
    queue_high_water : int
        Largest queue depth seen.
    dropped : int
        Messages refused because the queue was full or the writer had failed.
    files : list of str
        Storage files so far.
    flushes : int
        Flushes done.
    """

    state: str
    error: str
    messages: Dict[str, int]
    bytes: Dict[str, int]
    queue_depth: int
    queue_high_water: int
    dropped: int
    files: list
    flushes: int

    @property
    def total_messages(self) -> int:
        """
        Messages written on all topics.

        Returns
        -------
        int
            The sum.
        """
        return sum(self.messages.values())

    @property
    def total_bytes(self) -> int:
        """
        Bytes written on all topics [B].

        Returns
        -------
        int
            The sum.
        """
        return sum(self.bytes.values())


class QueuedBagWriter:
    """
    Own a :class:`BagWriter` in a writer thread fed by a bounded queue.

    Parameters
    ----------
    writer : BagWriter
        The (not yet opened) bag writer.
    flush_period_s : float
        Flush period [s]: data reach the disk at least this often.
    max_queue_messages : int
        Queue bound [messages]; beyond it messages are dropped and counted.
    max_queue_B : int
        Queue bound [bytes of queued messages]; beyond it messages are dropped and counted.
    monotonic : callable
        Clock for the flush period [s] (injected for tests).
    """

    def __init__(self, writer: BagWriter, flush_period_s: float = 1.0,
                 max_queue_messages: int = 100_000, max_queue_B: int = 1 << 30,
                 monotonic: Callable[[], float] = time.monotonic) -> None:
        if flush_period_s <= 0:
            raise ValueError(f'flush_period_s must be positive, got {flush_period_s!r}')
        self.writer = writer
        self.flush_period_s = float(flush_period_s)
        self._monotonic = monotonic
        # Unbounded for control items; messages are bounded in put() by count and bytes.
        self._queue: queue.Queue = queue.Queue()
        self._max_messages = int(max_queue_messages)
        self._max_bytes = int(max_queue_B)
        self._queued_messages = 0
        self._queued_bytes = 0
        self._thread: Optional[threading.Thread] = None
        self._lock = threading.Lock()
        self._next_id = 0
        self._topics: Dict[int, str] = {}
        self._state = 'idle'
        self._error = ''
        self._dropped = 0
        self._high_water = 0
        self._flushes = 0
        self._messages: Dict[str, int] = {}
        self._bytes: Dict[str, int] = {}
        self._files: list = []

    # -- caller side -----------------------------------------------------------------------

    def start(self) -> None:
        """
        Open the bag (in the caller's thread, so that errors surface at once) and start.

        Raises
        ------
        emfc_ros.core.bag.errors.BagExistsError
            If the output folder exists and is not empty.
        emfc_ros.core.bag.errors.BagWriteError
            If the bag cannot be created.
        """
        self.writer.open()
        self._files = [f.path for f in self.writer.files]
        self._state = 'recording'
        self._thread = threading.Thread(target=self._run, name='bag-writer', daemon=True)
        self._thread.start()

    def add_connection(self, topic: str, msgtype: str,
                       offered_qos: Sequence[OfferedQos] = ()) -> int:
        """
        Register a topic; its definition is resolved now, the write happens in order.

        Parameters
        ----------
        topic : str
            Topic name.
        msgtype : str
            Message type.
        offered_qos : sequence of OfferedQos
            The publishers' offered QoS.

        Returns
        -------
        int
            Connection id for :meth:`put`.

        Raises
        ------
        emfc_ros.core.bag.msgdefs.MessageTypeError
            If the type has no known definition.
        """
        msgdef, rihs01 = self.writer.types.definition(msgtype)
        with self._lock:
            self._next_id += 1
            cid = self._next_id
            self._topics[cid] = topic
            self._messages.setdefault(topic, 0)
            self._bytes.setdefault(topic, 0)
        self._queue.put((_CONNECT, cid, (topic, msgtype, tuple(offered_qos), msgdef, rihs01)))
        return cid

    def put(self, connection_id: int, timestamp_ns: int, data: bytes) -> bool:
        """
        Queue one serialized message (never blocks).

        Parameters
        ----------
        connection_id : int
            From :meth:`add_connection`.
        timestamp_ns : int
            Receive time [ns].
        data : bytes
            The serialized message.

        Returns
        -------
        bool
            False if it was dropped (queue full, writer failed or stopped).
        """
        size = len(data)
        with self._lock:
            if self._state != 'recording' or self._queued_messages >= self._max_messages \
                    or self._queued_bytes + size > self._max_bytes:
                self._dropped += 1
                return False
            self._queued_messages += 1
            self._queued_bytes += size
            if self._queued_messages > self._high_water:
                self._high_water = self._queued_messages
        self._queue.put((_WRITE, connection_id, (timestamp_ns, data)))
        return True

    def set_custom_data(self, key: str, value: str) -> None:
        """
        Set a ``custom_data`` entry (in order with the messages; written at the next flush).

        Parameters
        ----------
        key : str
            The key.
        value : str
            The value.
        """
        if not isinstance(value, str):
            raise TypeError(f'custom_data value of {key!r} must be a string')
        self._queue.put((_CUSTOM, 0, (key, value)))

    def stop(self, timeout_s: float = 30.0) -> RecorderStats:
        """
        Write what is queued, close the bag properly and end the thread.

        Parameters
        ----------
        timeout_s : float
            Upper bound on the wait for the thread [s].

        Returns
        -------
        RecorderStats
            The final statistics.
        """
        if self._thread is not None:
            self._queue.put((_CLOSE, 0, None))
            self._thread.join(timeout_s)
            self._thread = None
        return self.stats()

    def stats(self) -> RecorderStats:
        """
        A snapshot of the counters.

        Returns
        -------
        RecorderStats
            The counters.
        """
        with self._lock:
            return RecorderStats(self._state, self._error, dict(self._messages),
                                 dict(self._bytes), self._queued_messages, self._high_water,
                                 self._dropped, list(self._files), self._flushes)

    @property
    def running(self) -> bool:
        """
        Whether the writer thread is alive.

        Returns
        -------
        bool
            True while it runs.
        """
        return self._thread is not None and self._thread.is_alive()

    # -- writer thread ---------------------------------------------------------------------

    def _run(self) -> None:
        next_flush = self._monotonic() + self.flush_period_s
        ids: Dict[int, int] = {}
        while True:
            timeout = max(0.0, next_flush - self._monotonic())
            try:
                kind, cid, payload = self._queue.get(timeout=timeout)
            except queue.Empty:
                kind = None
            if kind == _CLOSE:
                self._close()
                return
            if self._state == 'error':
                if kind == _WRITE:
                    self._unqueue(payload[1], dropped=True)
                continue
            try:
                self._handle(kind, cid, payload, ids)
            except Exception as exc:  # write errors, and anything else: never die silently
                if kind == _WRITE:
                    self._unqueue(payload[1], dropped=True)
                self._fail(exc)
                continue
            try:
                if self._monotonic() >= next_flush:
                    self.writer.flush()
                    self._flushes += 1
                    next_flush = self._monotonic() + self.flush_period_s
            except Exception as exc:
                self._fail(exc)

    def _unqueue(self, data: bytes, dropped: bool) -> None:
        """A message leaves the queue without being written (counted as dropped)."""
        with self._lock:
            self._queued_messages -= 1
            self._queued_bytes -= len(data)
            self._dropped += int(dropped)

    def _handle(self, kind, cid: int, payload, ids: Dict[int, int]) -> None:
        if kind == _WRITE:
            timestamp_ns, data = payload
            self.writer.write(ids[cid], timestamp_ns, data)
            topic = self._topics[cid]
            # A message leaves the queue and counts as written at one instant: a snapshot
            # with an empty queue has every taken message in its counts (stats()).
            with self._lock:
                self._queued_messages -= 1
                self._queued_bytes -= len(data)
                self._messages[topic] += 1
                self._bytes[topic] += len(data)
                if len(self.writer.files) != len(self._files):
                    self._files = [f.path for f in self.writer.files]
        elif kind == _CONNECT:
            topic, msgtype, qos, msgdef, rihs01 = payload
            ids[cid] = self.writer.add_connection(topic, msgtype, qos, msgdef, rihs01)
        elif kind == _CUSTOM:
            self.writer.set_custom_data(*payload)

    def _fail(self, exc: Exception) -> None:
        with self._lock:
            self._state = 'error'
            self._error = str(exc) if isinstance(exc, OSError) else \
                f'{type(exc).__name__}: {exc}'
        self.writer.abort()

    def _close(self) -> None:
        if self._state == 'error':
            return
        try:
            self.writer.close()
            with self._lock:
                self._files = [f.path for f in self.writer.files]
                self._state = 'closed'
        except Exception as exc:  # as in _run: report, never die silently
            self._fail(exc)
