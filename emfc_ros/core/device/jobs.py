"""
Requests that wait for the device, run in one worker thread, in the order they were asked for.

A node's executor thread must never wait for a device: a device that does not answer costs
its request timeouts and retries (about a second each), a STOP also waits for the reader
thread. :class:`DeviceJobs` runs such work (start, stop, safe outputs, generator changes,
restores) one job at a time in its own thread, so their order is kept (an emergency stop's
safe outputs are never overtaken by the restore that a later reset asks for) and the caller
only queues and returns. A job still waiting under the same name is not queued twice.
"""

from __future__ import annotations

import concurrent.futures
import queue
import threading
from typing import Any, Callable, Dict, Optional, Tuple

_STOP = object()


class DeviceJobs:
    """
    One worker thread running named jobs in order.

    Parameters
    ----------
    name : str
        Name of the thread.
    """

    def __init__(self, name: str = 'device-jobs') -> None:
        self._queue: 'queue.Queue[Any]' = queue.Queue()
        self._lock = threading.Lock()
        self._waiting: Dict[str, concurrent.futures.Future] = {}
        self._running: Optional[str] = None
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, name: str, fn: Callable[..., Any], *args: Any) -> concurrent.futures.Future:
        """
        Queue a job (or return the one of this name still waiting).

        Parameters
        ----------
        name : str
            What the job is (``'start'``, ``'stop'``...).
        fn : callable
            The work; its return value or exception goes to the future.
        *args
            Its arguments.

        Returns
        -------
        concurrent.futures.Future
            The job's outcome. After :meth:`close`, a future that is already cancelled.
        """
        with self._lock:
            waiting = self._waiting.get(name)
            if waiting is not None:
                return waiting
            future: concurrent.futures.Future = concurrent.futures.Future()
            if self._closed:
                future.cancel()
                return future
            self._waiting[name] = future
            self._queue.put((name, future, fn, args))
            return future

    def pending(self, name: Optional[str] = None) -> bool:
        """
        Whether a job (of this name) is waiting or running.

        Parameters
        ----------
        name : str, optional
            The job's name; None: any job.

        Returns
        -------
        bool
            True while one is queued or running.
        """
        with self._lock:
            if name is None:
                return bool(self._waiting) or self._running is not None
            return name in self._waiting or self._running == name

    def close(self, timeout_s: float = 5.0) -> bool:
        """
        Cancel the waiting jobs, let the running one finish (bounded), end the thread.

        Parameters
        ----------
        timeout_s : float
            Longest wait for the running job [s].

        Returns
        -------
        bool
            True if the thread ended in time.
        """
        with self._lock:
            self._closed = True
            for future in self._waiting.values():
                future.cancel()
            self._waiting.clear()
        self._queue.put(_STOP)
        self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is _STOP:
                return
            name, future, fn, args = item
            with self._lock:
                if self._waiting.get(name) is future:
                    del self._waiting[name]
                if not future.set_running_or_notify_cancel():
                    continue
                self._running = name
            try:
                future.set_result(fn(*args))
            except BaseException as exc:   # noqa: B902 the caller reads it from the future
                future.set_exception(exc)
            finally:
                with self._lock:
                    self._running = None


def outcome(future: concurrent.futures.Future) -> Tuple[bool, str]:
    """
    A finished job's ``(ok, message)`` result, or its exception as a failure.

    Parameters
    ----------
    future : concurrent.futures.Future
        A done future of a job returning ``(bool, str)``.

    Returns
    -------
    (bool, str)
        The job's result; ``(False, reason)`` when it raised or was cancelled.
    """
    if future.cancelled():
        return False, 'cancelled'
    exc = future.exception()
    if exc is not None:
        return False, f'{type(exc).__name__}: {exc}'
    result = future.result()
    if isinstance(result, tuple) and len(result) == 2:
        return bool(result[0]), str(result[1])
    return True, str(result)
