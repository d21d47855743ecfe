"""
One BLAS thread around small-matrix linear algebra, without touching the environment.

OpenBLAS (bundled with numpy and scipy) starts a thread pool of one thread per core for every
call above a tiny size. On the small and tall-skinny matrices of the transfer-function fit, the
local polynomial method and the grey-box fit (tens of columns) the hand-over costs more than it
saves, and on a machine whose cores are busy with other work a call waits for a thread to be
scheduled: measured on the project's 2-core machine under load (issue 14), the
transfer-function step of ``identify`` took 1.1 to 3.4 s with the default two threads against
0.4 s with one (``bench/bench_ident_core.py`` prints the same-run ratio).

:func:`single_blas_thread` limits the BLAS libraries loaded in the process to one thread for the
duration of a block, with ``threadpoolctl``, and restores them afterwards; nested and
concurrent blocks (several threads of one process) are counted so that the last one out
restores the original setting. Setting ``OPENBLAS_NUM_THREADS=1`` instead would pin the
whole process, large products included, and must be set before numpy is imported.
The FFTs (pocketfft, ``workers``) are not BLAS and are not affected either way.

Without ``threadpoolctl`` installed (it is an install requirement; a ROS installation from
system packages may lack it) the block runs unchanged with the default threads: the numbers
are the same, only slower on a loaded machine.
"""

from __future__ import annotations

from contextlib import contextmanager
import functools
import threading
from typing import Any, Callable, Iterator, Optional, TypeVar

F = TypeVar('F', bound=Callable[..., Any])

_lock = threading.Lock()
_depth = 0
_saved: list = []
_controller: Any = None
_controller_checked = False
_enabled = True


def _get_controller() -> Optional[Any]:
    """The process's threadpoolctl controller, created once (None without threadpoolctl)."""
    global _controller, _controller_checked
    if not _controller_checked:
        try:
            import scipy.linalg  # noqa: F401  (loads scipy's BLAS before the scan)
            from threadpoolctl import ThreadpoolController
            _controller = ThreadpoolController()
        except ImportError:
            _controller = None
        _controller_checked = True
    return _controller


def available() -> bool:
    """
    Whether BLAS threads can be limited here.

    Returns
    -------
    bool
        True when threadpoolctl is installed and found at least one BLAS library.
    """
    ctl = _get_controller()
    return ctl is not None and bool(ctl.select(user_api='blas').lib_controllers)


def blas_threads() -> Optional[int]:
    """
    Threads the loaded BLAS libraries use now.

    Returns
    -------
    int or None
        The largest thread count among them; None without threadpoolctl or BLAS.
    """
    ctl = _get_controller()
    if ctl is None:
        return None
    counts = [lib.num_threads for lib in ctl.select(user_api='blas').lib_controllers]
    return max(counts) if counts else None


def set_limiting(enabled: bool) -> bool:
    """
    Switch the limiting on or off for the whole process (for same-run benchmarks).

    Parameters
    ----------
    enabled : bool
        False makes :func:`single_blas_thread` leave the thread count alone.

    Returns
    -------
    bool
        The previous setting.
    """
    global _enabled
    previous, _enabled = _enabled, bool(enabled)
    return previous


def _release_openblas_control() -> None:
    """Let any thread set OpenBLAS's count (threadpoolctl >= 3.7 keeps one controlling thread)."""
    try:
        from threadpoolctl import OpenBLASController
    except ImportError:
        return
    clear = getattr(OpenBLASController, 'clear_controlling_thread', None)
    if clear is not None:
        clear(force=True)


def pin_single_blas_thread() -> bool:
    """
    Limit BLAS to one thread for the rest of the process (a worker without large products).

    The plot workers draw figures and run small fits (the grey-box's probe for a second
    optimum) next to the run's own process on a 2-core machine: with two BLAS threads their
    residual tests' dot products of 10^5 samples took 1 s of CPU per figure instead of
    0.02 s in some runs (the threads waited for a core the other process held).

    Returns
    -------
    bool
        Whether a BLAS library was limited (False without threadpoolctl or BLAS).
    """
    ctl = _get_controller()
    if ctl is None:
        return False
    libs = ctl.select(user_api='blas').lib_controllers
    with _lock:
        _release_openblas_control()
        for lib in libs:
            lib.set_num_threads(1)
        _release_openblas_control()
    return bool(libs)


@contextmanager
def single_blas_thread() -> Iterator[None]:
    """
    Limit BLAS to one thread inside the block.

    Yields
    ------
    None
        Control, with BLAS on one thread (unchanged without threadpoolctl).
    """
    global _depth, _saved
    ctl = _get_controller() if _enabled else None
    if ctl is None:
        yield
        return
    libs = ctl.select(user_api='blas').lib_controllers
    with _lock:
        if _depth == 0:
            # threadpoolctl >= 3.7 ignores a set from a thread other than the first one that
            # set a limit; the count is process-wide and this lock orders the changes, so
            # take the control for the change and give it back.
            _saved = [lib.num_threads for lib in libs]
            _release_openblas_control()
            for lib in libs:
                lib.set_num_threads(1)
            _release_openblas_control()
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                _release_openblas_control()
                for lib, count in zip(libs, _saved):
                    if count is not None:
                        lib.set_num_threads(count)
                _release_openblas_control()
                _saved = []


def with_single_blas_thread(func: F) -> F:
    """
    Run a function with BLAS on one thread (decorator form of :func:`single_blas_thread`).

    Parameters
    ----------
    func : callable
        The function.

    Returns
    -------
    callable
        The wrapped function.
    """
    @functools.wraps(func)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with single_blas_thread():
            return func(*args, **kwargs)
    return wrapper  # type: ignore[return-value]
