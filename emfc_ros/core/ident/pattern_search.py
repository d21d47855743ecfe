"""
Generalised pattern search (GPS) with MATLAB ``patternsearch``'s documented defaults.

Defaults as listed by ``optimoptions('patternsearch')`` (MathWorks, "Set Options",
https://uk.mathworks.com/help/gads/setting-options.html) and described in "Set Mesh Options",
"Pattern Search Terminology" and "Setting Solver Tolerances" of the Global Optimization
Toolbox documentation:

* poll method ``GPSPositiveBasis2N``: directions ``+e_1 .. +e_N, -e_1 .. -e_N`` polled in that
  (consecutive) order;
* initial mesh size 1, expansion factor 2 after a successful poll, contraction 0.5 after an
  unsuccessful one;
* ``UseCompletePoll`` off: opportunistic, the poll stops at the first better point;
* ``MeshTolerance`` 1e-6: stop when the mesh size falls below it;
* ``StepTolerance`` 1e-6 and ``FunctionTolerance`` 1e-6: after a successful poll, stop when
  the step length (resp. the decrease of the objective) *and* the mesh size are below the
  tolerance (the exit conditions 2 and 3 of MATLAB's ``exitflag``);
* ``MaxFunctionEvaluations`` ``2000 N`` and ``MaxIterations`` ``100 N``.

Bounds: a poll point outside the box is projected onto it (MATLAB likewise "modifies poll
points to be feasible"); if the projection coincides with the current point the direction is
skipped without an evaluation. The objective is evaluated only at feasible points.
Scaling is the caller's business (:mod:`~emfc_ros.core.ident.greybox` polls in variables
scaled so one mesh size fits all).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np

from emfc_ros.core.ident.errors import IdentificationError

EXIT_MESSAGES = {
    0: 'maximum number of function evaluations or iterations reached',
    1: 'mesh size below MeshTolerance',
    2: 'step and mesh size below StepTolerance',
    3: 'change in objective below FunctionTolerance and mesh size below StepTolerance',
}


@dataclass(frozen=True)
class PatternSearchOptions:
    """
    Options of :func:`pattern_search`, named after MATLAB's and with its defaults.

    Attributes
    ----------
    initial_mesh_size : float
        ``InitialMeshSize`` (1).
    mesh_expansion_factor : float
        ``MeshExpansionFactor`` (2).
    mesh_contraction_factor : float
        ``MeshContractionFactor`` (0.5).
    mesh_tolerance : float
        ``MeshTolerance`` (1e-6).
    step_tolerance : float
        ``StepTolerance`` (1e-6).
    function_tolerance : float
        ``FunctionTolerance`` (1e-6).
    max_function_evaluations : int, optional
        ``MaxFunctionEvaluations`` (default ``2000 N``).
    max_iterations : int, optional
        ``MaxIterations`` (default ``100 N``).
    complete_poll : bool
        ``UseCompletePoll`` (False: opportunistic).
    """

    initial_mesh_size: float = 1.0
    mesh_expansion_factor: float = 2.0
    mesh_contraction_factor: float = 0.5
    mesh_tolerance: float = 1.0e-6
    step_tolerance: float = 1.0e-6
    function_tolerance: float = 1.0e-6
    max_function_evaluations: Optional[int] = None
    max_iterations: Optional[int] = None
    complete_poll: bool = False

    def __post_init__(self) -> None:
        if not self.initial_mesh_size > 0.0:
            raise IdentificationError(f'initial_mesh_size must be > 0, got '
                                      f'{self.initial_mesh_size!r}')
        if not self.mesh_expansion_factor >= 1.0:
            raise IdentificationError(f'mesh_expansion_factor must be >= 1, got '
                                      f'{self.mesh_expansion_factor!r}')
        if not 0.0 < self.mesh_contraction_factor < 1.0:
            raise IdentificationError(f'mesh_contraction_factor must be in (0, 1), got '
                                      f'{self.mesh_contraction_factor!r}')


@dataclass(frozen=True)
class PatternSearchResult:
    """
    Outcome of :func:`pattern_search`.

    Attributes
    ----------
    x : ndarray
        Best point found.
    fun : float
        Objective at ``x``.
    n_evaluations : int
        Objective evaluations (including the initial point).
    n_iterations : int
        Polls done.
    mesh_size : float
        Final mesh size.
    exit_flag : int
        0 budget exhausted, 1 mesh tolerance, 2 step tolerance, 3 function tolerance.
    message : str
        Reason for stopping.
    """

    x: np.ndarray
    fun: float
    n_evaluations: int
    n_iterations: int
    mesh_size: float
    exit_flag: int
    message: str

    @property
    def success(self) -> bool:
        """Whether a tolerance (not the budget) ended the search."""
        return self.exit_flag > 0


def pattern_search(fun: Callable[[np.ndarray], float], x0: Sequence[float],
                   lower: Optional[Sequence[float]] = None,
                   upper: Optional[Sequence[float]] = None,
                   options: Optional[PatternSearchOptions] = None) -> PatternSearchResult:
    """
    Minimise ``fun`` by GPS polling on the 2N positive basis within bounds.

    Parameters
    ----------
    fun : callable
        Objective ``f(x) -> float``; non-finite values count as worse than anything.
    x0 : sequence of float
        Start point (must satisfy the bounds).
    lower, upper : sequence of float, optional
        Bounds (default unbounded).
    options : PatternSearchOptions, optional
        Settings (MATLAB defaults).

    Returns
    -------
    PatternSearchResult
        Best point, objective, counts and exit reason.

    Raises
    ------
    IdentificationError
        If the start point is outside the bounds or the bounds are inconsistent.
    """
    opts = options or PatternSearchOptions()
    x = np.asarray(x0, dtype=float).copy()
    n = x.size
    lo = np.full(n, -np.inf) if lower is None else np.asarray(lower, dtype=float)
    hi = np.full(n, np.inf) if upper is None else np.asarray(upper, dtype=float)
    if lo.shape != (n,) or hi.shape != (n,) or np.any(lo > hi):
        raise IdentificationError('lower and upper must be N values with lower <= upper')
    if np.any(x < lo) or np.any(x > hi):
        raise IdentificationError(f'x0 {x.tolist()} lies outside the bounds')
    max_evals = opts.max_function_evaluations or 2000 * n
    max_iter = opts.max_iterations or 100 * n
    directions = np.vstack((np.eye(n), -np.eye(n)))

    def evaluate(point: np.ndarray) -> float:
        value = float(fun(point))
        return value if np.isfinite(value) else np.inf

    f = evaluate(x)
    evals, iters, mesh = 1, 0, float(opts.initial_mesh_size)
    flag = 0
    while iters < max_iter and evals < max_evals:
        iters += 1
        best_x, best_f = None, f
        for d in directions:
            trial = np.clip(x + mesh * d, lo, hi)
            if np.array_equal(trial, x):
                continue
            ft = evaluate(trial)
            evals += 1
            if ft < best_f:
                best_x, best_f = trial, ft
                if not opts.complete_poll:
                    break
            if evals >= max_evals:
                break
        if best_x is not None:
            step = float(np.linalg.norm(best_x - x))
            decrease = f - best_f
            x, f = best_x, best_f
            if step < opts.step_tolerance and mesh < opts.step_tolerance:
                flag = 2
                break
            if decrease < opts.function_tolerance and mesh < opts.step_tolerance:
                flag = 3
                break
            mesh *= opts.mesh_expansion_factor
        else:
            mesh *= opts.mesh_contraction_factor
            if mesh < opts.mesh_tolerance:
                flag = 1
                break
    return PatternSearchResult(x, f, evals, iters, mesh, flag, EXIT_MESSAGES[flag])
