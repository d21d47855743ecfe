"""
The numba kernels, compiled into numba's on-disk cache ahead of their first use.

numba compiles a kernel the first time a process calls it and keeps the machine code in a
cache next to the module (``__pycache__`` of the installed package, e.g. the virtual
environment's ``site-packages``; a user-wide cache when that folder is read-only). Later
processes load it in a fraction of a second. The simulator's chain takes about 15 s to compile
here, the other kernels a few seconds each: :func:`prepare` compiles (or loads) them all, so
that the first run after an install does not wait (``emfc-compile-kernels``,
``tools/setup_env.sh`` runs it after installing). numba keys its cache by the content of the
source file: a reinstall of the same sources keeps the cache valid, changed sources compile
again.

Without numba every kernel runs interpreted (the same code, about 500 times slower); there is
nothing to prepare.
"""

from __future__ import annotations

from dataclasses import dataclass
import time
from typing import Callable, Dict, List, Optional, Sequence, Tuple

import numpy as np


@dataclass(frozen=True)
class KernelStatus:
    """
    What preparing one kernel did.

    Attributes
    ----------
    name : str
        The kernel (:data:`KERNELS`).
    compiled : int
        Signatures numba compiled (0: everything came from the cache).
    loaded : int
        Signatures loaded from the cache.
    seconds : float
        Wall time [s].
    cache_path : str
        Where numba keeps this kernel's cache.
    """

    name: str
    compiled: int
    loaded: int
    seconds: float
    cache_path: str


def _simulator() -> List[Callable]:
    from emfc_ros.core.model.parameters import BalanceParameters
    from emfc_ros.core.sim.simulator import _jitted, Simulator
    sim = Simulator(BalanceParameters(), 10000.0, backend='numba')
    sim.step_block(np.zeros((2, 8)))
    return [_jitted()]


def _plant_kernel() -> List[Callable]:
    from emfc_ros.core.model.parameters import BalanceParameters
    from emfc_ros.core.sim.kernel import _jitted, PlantKernel
    PlantKernel(BalanceParameters(), 10000.0, backend='numba').run(np.zeros(8), np.zeros(8))
    return [_jitted()]


def _weighing() -> List[Callable]:
    from emfc_ros.core.model.parameters import BalanceParameters
    from emfc_ros.core.weighing.dynamic import _adaptive_jitted, _jitted, DynamicWeigher
    for adaptive in (True, False):
        weigher = DynamicWeigher(BalanceParameters().mechanics, 10000.0, backend='numba',
                                 adaptive=adaptive)
        weigher.update_block_detailed(np.zeros(8), np.zeros(8))
    return [_jitted(), _adaptive_jitted()]


def _modal_filter() -> List[Callable]:
    from emfc_ros.core.ident.modal_filter import _jitted, modal_pair
    modal_pair(0.5 + 0.1j, np.zeros(8))
    return [_jitted()]


#: The kernels by name, each with the call that compiles or loads it through its real code path
#: (so the signatures are the ones the programs use). Not here: the closed loop's
#: ``loop_block`` takes the chain's dispatcher as an argument, which numba does not cache; it
#: compiles in every process that closes the loop (about 5 s here).
KERNELS: Dict[str, Callable[[], List[Callable]]] = {
    'simulator chain': _simulator,
    'plant kernel (bare mechanics)': _plant_kernel,
    'weighing filter': _weighing,
    'modal filter (grey-box Jacobian)': _modal_filter,
}


def _counts(dispatchers: Sequence[Callable]) -> Tuple[int, int, str]:
    hits = sum(d.stats.cache_hits.total() for d in dispatchers)
    misses = sum(d.stats.cache_misses.total() for d in dispatchers)
    return misses, hits, str(dispatchers[0].stats.cache_path) if dispatchers else ''


def prepare(names: Optional[Sequence[str]] = None,
            report: Optional[Callable[[KernelStatus], None]] = None) -> List[KernelStatus]:
    """
    Compile (or load from numba's cache) the kernels.

    Parameters
    ----------
    names : sequence of str, optional
        Keys of :data:`KERNELS` (default all).
    report : callable, optional
        Called with each kernel's status as soon as it is ready.

    Returns
    -------
    list of KernelStatus
        One per kernel.

    Raises
    ------
    ImportError
        If numba is not installed.
    KeyError
        For an unknown kernel name.
    """
    import numba  # noqa: F401  (the interpreted fallback has nothing to compile)

    out = []
    for name in (list(KERNELS) if names is None else list(names)):
        start = time.monotonic()
        dispatchers = KERNELS[name]()
        compiled, loaded, path = _counts(dispatchers)
        status = KernelStatus(name, compiled, loaded, time.monotonic() - start, path)
        if report is not None:
            report(status)
        out.append(status)
    return out
