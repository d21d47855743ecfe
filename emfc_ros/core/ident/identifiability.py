"""
Which parameters an experiment determines: the Fisher information of a fit.

For residuals scaled to unit variance (as :func:`~emfc_ros.core.ident.balance_frf.fit_frfs`
builds them from the nonparametric noise model), ``F = J^T J`` is the Fisher information and
``F^-1`` the smallest covariance any unbiased estimator reaches. With the Jacobian taken in
relative variables (each column times its parameter's magnitude), the singular value
decomposition ``J = U S V^T`` says everything about identifiability:

* the direction ``v_i`` of parameter space (a combination ``sum_j v_ij dtheta_j/theta_j``) is
  determined to a relative standard uncertainty of ``1 / s_i``;
* a direction with ``1 / s_i`` above :data:`MAX_RELATIVE_UNCERTAINTY` is not determined by the
  data: those parameters cannot be separated, and one of them must be fixed;
* the condition number ``s_max / s_min`` and the correlation matrix of ``F^-1`` are reported.

:func:`choose_free` removes, one at a time, the parameter that carries most of the least
determined direction (among those allowed to be fixed) until every direction is determined,
and records each removed combination in words.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Dict, List, Sequence, Tuple

import numpy as np

#: A direction determined worse than this (relative standard uncertainty) is not identified.
MAX_RELATIVE_UNCERTAINTY = 0.3


@dataclass(frozen=True)
class Identifiability:
    """
    Fisher-information analysis of one parameter set.

    Attributes
    ----------
    names : tuple of str
        The parameters, in the column order of the Jacobian.
    singular_values : ndarray
        Of the relative Jacobian, largest first.
    directions : ndarray, shape (p, p)
        Rows: the right singular vectors (relative parameter combinations), same order.
    relative_uncertainty : ndarray
        ``1 / s_i``: how well each direction is determined.
    correlation : ndarray, shape (p, p)
        Correlation matrix of ``F^-1`` (pseudo-inverse).
    condition_number : float
        ``s_max / s_min`` (inf when rank deficient).
    rank : int
        Directions determined better than the threshold.
    threshold : float
        That threshold (relative standard uncertainty of a direction).
    """

    names: Tuple[str, ...]
    singular_values: np.ndarray
    directions: np.ndarray
    relative_uncertainty: np.ndarray
    correlation: np.ndarray
    condition_number: float
    rank: int
    threshold: float = MAX_RELATIVE_UNCERTAINTY

    def combination(self, index: int, min_weight: float = 0.1) -> str:
        """
        A direction written as a relative parameter combination.

        Parameters
        ----------
        index : int
            Which direction (0 = best determined).
        min_weight : float
            Components smaller than this (absolute) are left out.

        Returns
        -------
        str
            E.g. ``'+0.71 dJ1c_kgm2/J1c_kgm2 - 0.70 dm3_kg/m3_kg'``.
        """
        v = self.directions[index]
        v = v * np.sign(v[np.argmax(np.abs(v))])
        terms = [f'{"-" if c < 0 else "+"}{abs(c):.2f} d{n}/{n}'
                 for c, n in sorted(zip(v, self.names), key=lambda t: -abs(t[0]))
                 if abs(c) >= min_weight]
        return ' '.join(terms)

    def to_dict(self) -> dict:
        """
        Plain data for reports.

        Returns
        -------
        dict
            Names, singular values, relative uncertainties, directions, condition number,
            rank (with its threshold), the undetermined directions and the correlation matrix.
        """
        return {'names': list(self.names),
                'singular_values': [float(v) for v in self.singular_values],
                'relative_uncertainty_of_direction': [float(v)
                                                      for v in self.relative_uncertainty],
                'directions': [self.combination(i) for i in range(len(self.names))],
                'condition_number': float(self.condition_number), 'rank': int(self.rank),
                'rank_threshold_relative_uncertainty': float(self.threshold),
                'not_determined': [
                    {'combination': self.combination(i),
                     'relative_uncertainty': float(self.relative_uncertainty[i])}
                    for i in range(len(self.names))
                    if not self.relative_uncertainty[i] <= self.threshold],
                'correlation': np.asarray(self.correlation).tolist()}


def analyse(jacobian: np.ndarray, names: Sequence[str], magnitudes: Sequence[float],
            max_relative_uncertainty: float = MAX_RELATIVE_UNCERTAINTY) -> Identifiability:
    """
    Analyse the Fisher information of a unit-variance residual Jacobian.

    Parameters
    ----------
    jacobian : ndarray, shape (m, p)
        ``d r / d theta`` in the natural units of the parameters.
    names : sequence of str
        Parameter names.
    magnitudes : sequence of float
        Typical magnitude of each parameter (relative variables are ``theta / magnitude``).
    max_relative_uncertainty : float
        Threshold of a determined direction.

    Returns
    -------
    Identifiability
        The analysis.
    """
    scales = np.array([abs(float(m)) or 1.0 for m in magnitudes])
    jr = np.asarray(jacobian, dtype=float) * scales[None, :]
    _, s, vt = np.linalg.svd(jr, full_matrices=False)
    with np.errstate(divide='ignore'):
        rel = np.where(s > 0.0, 1.0 / s, np.inf)
    cov = np.linalg.pinv(jr.T @ jr)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(divide='ignore', invalid='ignore'):
        corr = cov / np.outer(sd, sd)
    cond = float(s[0] / s[-1]) if s[-1] > 0.0 else float('inf')
    rank = int(np.count_nonzero(rel <= max_relative_uncertainty))
    return Identifiability(tuple(names), s, vt, rel, corr, cond, rank,
                           float(max_relative_uncertainty))


def analyse_covariance(covariance: np.ndarray, names: Sequence[str],
                       magnitudes: Sequence[float],
                       max_relative_uncertainty: float = MAX_RELATIVE_UNCERTAINTY
                       ) -> Identifiability:
    """
    The same analysis from a fit's covariance (e.g. the time-domain fit's sandwich).

    The covariance in relative variables ``C_rel = C / (m m^T)`` has the eigen-decomposition
    ``V diag(l) V^T``; ``1 / sqrt(l_i)`` plays the role of the singular values of the relative
    Jacobian (exactly so when ``C = (J^T J)^-1``): direction ``v_i`` is determined to a relative
    standard uncertainty ``sqrt(l_i)``. This is what the final estimate says about
    identifiability, for the sections and inputs the fit used and whatever covariance it
    computed (coloured noise included).

    Parameters
    ----------
    covariance : ndarray, shape (p, p)
        Covariance in natural units.
    names : sequence of str
        Parameter names, its order.
    magnitudes : sequence of float
        Typical magnitude of each parameter (the estimates).
    max_relative_uncertainty : float
        Threshold of a determined direction.

    Returns
    -------
    Identifiability
        The analysis (best-determined direction first).
    """
    scales = np.array([abs(float(m)) or 1.0 for m in magnitudes])
    cov = np.asarray(covariance, dtype=float)
    finite = np.all(np.isfinite(cov))
    rel = cov / np.outer(scales, scales) if finite else np.full_like(cov, np.inf)
    if finite:
        w, v = np.linalg.eigh(0.5 * (rel + rel.T))
        w = np.maximum(w, 0.0)
    else:
        w, v = np.full(len(names), np.inf), np.eye(len(names))
    order = np.argsort(w)
    unc = np.sqrt(w[order])
    with np.errstate(divide='ignore'):
        s = np.where(unc > 0.0, 1.0 / unc, np.inf)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(divide='ignore', invalid='ignore'):
        corr = cov / np.outer(sd, sd)
    cond = float(s[0] / s[-1]) if np.isfinite(s[0]) and s[-1] > 0.0 else float('inf')
    rank = int(np.count_nonzero(unc <= max_relative_uncertainty))
    return Identifiability(tuple(names), s, v[:, order].T, unc, corr, cond, rank,
                           float(max_relative_uncertainty))


@dataclass
class FreeSetChoice:
    """
    The parameters left free and what was fixed, with the reasons.

    Attributes
    ----------
    free : tuple of str
        Parameters the data determine.
    fixed : dict of str to str
        Parameter to the reason it was fixed (the combination the data cannot resolve).
    analysis : Identifiability
        The analysis of the final free set.
    initial_analysis : Identifiability
        The analysis of the requested set.
    """

    free: Tuple[str, ...]
    fixed: Dict[str, str] = field(default_factory=dict)
    analysis: Identifiability = None
    initial_analysis: Identifiability = None


def choose_free(jacobian_of: Callable[[Sequence[str]], np.ndarray], names: Sequence[str],
                magnitudes: Dict[str, float], may_fix: Sequence[str],
                max_relative_uncertainty: float = MAX_RELATIVE_UNCERTAINTY,
                prefer_fix: Sequence[str] = (), min_share: float = 0.1) -> FreeSetChoice:
    """
    Drop parameters until every direction of the rest is determined.

    Parameters
    ----------
    jacobian_of : callable
        ``jacobian_of(names) -> (m, p)`` Jacobian of unit-variance residuals for those free
        parameters (natural units).
    names : sequence of str
        Requested free parameters.
    magnitudes : dict of str to float
        Typical magnitudes.
    may_fix : sequence of str
        Parameters that may be fixed (at their configured values), when they take part in an
        undetermined direction with a component of at least ``min_share``; the others stay
        free even when poorly determined (their uncertainty will show it).
    max_relative_uncertainty : float
        Threshold of a determined direction.
    prefer_fix : sequence of str
        Parameters fixed first when they take part in the undetermined direction (with a
        component of at least ``min_share``): those whose configured value is known best
        (the masses, from a balance's drawings and weighing).
    min_share : float
        Smallest component of a parameter in the direction for it to be fixed.

    Returns
    -------
    FreeSetChoice
        The free set, the fixed parameters with the reason, and both analyses.
    """
    current = list(names)
    fixed: Dict[str, str] = {}
    first = None
    while True:
        ana = analyse(jacobian_of(current), current, [magnitudes[n] for n in current],
                      max_relative_uncertainty)
        first = first or ana
        # the least determined direction that a parameter allowed to be fixed takes part in
        candidates = []
        for d in np.argsort(-ana.relative_uncertainty):
            if ana.relative_uncertainty[d] <= max_relative_uncertainty or len(current) <= 1:
                break
            v = np.abs(ana.directions[d])
            order = [i for i in np.argsort(-v) if current[i] in may_fix and v[i] >= min_share]
            if order:
                preferred = [i for i in order if current[i] in prefer_fix]
                candidates = [(d, (preferred + [i for i in order if i not in preferred])[0])]
                break
        if not candidates:
            return FreeSetChoice(tuple(current), fixed, ana, first)
        worst, index = candidates[0]
        drop = current[index]
        fixed[drop] = (f'not separable from the other parameters: the combination '
                       f'{ana.combination(worst)} is determined only to '
                       f'{100 * min(ana.relative_uncertainty[worst], 1e6):.3g} %')
        current.remove(drop)


def relative_jacobian_columns(fun: Callable[[Dict[str, float]], np.ndarray],
                              values: Dict[str, float], names: Sequence[str],
                              step: float = 1.0e-6) -> np.ndarray:
    """
    Central-difference Jacobian of a residual function in natural units.

    Parameters
    ----------
    fun : callable
        ``fun(values) -> residual vector``.
    values : dict of str to float
        The point (all parameters).
    names : sequence of str
        Columns.
    step : float
        Relative step (absolute for a value of 0).

    Returns
    -------
    ndarray, shape (m, len(names))
        The Jacobian.
    """
    cols: List[np.ndarray] = []
    for n in names:
        h = step * (abs(values[n]) or 1.0)
        up = dict(values, **{n: values[n] + h})
        down = dict(values, **{n: values[n] - h})
        cols.append((fun(up) - fun(down)) / (2.0 * h))
    return np.column_stack(cols)
