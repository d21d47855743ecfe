"""
The garbage collector of a short command's own process.

A command such as ``emfc-experiment`` imports a few hundred thousand objects that live until
it ends (rclpy, numba, scipy, the nodes). Every full collection walked them all again, most
of them while the imports went on: 0.14-0.22 s of collector time in a warm run of the main
job, of which 0.12-0.15 s full collections (issue 14, item 5; measured with
:data:`gc.callbacks`). The command turns the collector off for its imports
(:meth:`CommandHeap.start`) and freezes what they made once they are done
(:meth:`CommandHeap.settled`, :func:`gc.freeze`): the collector then walks only what the
run makes later (0.01 s in all).

Only for a command's own process: a library caller (a test, a script calling ``main``) keeps
its collector as it is. glibc's malloc was tried too (one arena, no trimming, no mmap below
1 GiB: fewer page faults in the grey-box fit), with no difference in the job's wall time.
"""

from __future__ import annotations

import gc


class CommandHeap:
    """
    The collector settings of one command's process.

    Attributes
    ----------
    active : bool
        Whether :meth:`start` was called (:meth:`settled` does nothing before).
    """

    def __init__(self) -> None:
        self.active = False

    def start(self) -> None:
        """Turn the collector off while the command imports what it needs."""
        self.active = True
        gc.disable()

    def settled(self) -> None:
        """Freeze what exists now (it lives to the end) and turn the collector on again."""
        if self.active:
            gc.freeze()
            gc.enable()


#: The settings of this process (one per process).
COMMAND_HEAP = CommandHeap()
