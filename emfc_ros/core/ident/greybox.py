"""
Grey-box parameter estimation: a user simulation fitted to measured data sections.

The caller supplies ``simulate(params, inputs) -> outputs`` (``params`` a dict of all
parameters by name), the data as named sections (inputs and measured outputs, each an array of
shape (n,) or (n, channels)) and one :class:`ParameterSpec` per parameter.

Objective (identical for both optimisers): the residual vector stacks, per section ``s`` and
output column ``c``, ``sqrt(w_s / n_s) (y_hat - y) / std(y_c)``, so the cost
``sum r^2 = sum_s w_s sum_c mean((y_hat - y)^2) / var(y_c)`` is a dimensionless normalised
mean-square error (about ``(1 - fit/100)^2`` per section and output). Sections of different
length and units thus count by their weight only.

Optimisers:

* ``'least_squares'``: :func:`scipy.optimize.least_squares`, trust-region reflective with the
  bounds, ``x_scale`` = the parameter scales, on the residual vector.
* ``'gauss_newton'``: Gauss-Newton with Levenberg-Marquardt damping for a start next to the
  optimum (the balance's frequency-domain fit). The Jacobian is kept while the steps shrink
  (a chord method: one simulation per step). It comes from the caller's
  ``output_derivatives`` when given (e.g. the linearised model: no simulation), checked where
  the fit ends against central differences of ``simulate`` along the best and the worst
  determined direction (four simulations) and replaced by the full central-difference
  Jacobian when they differ by more than :data:`DERIVATIVE_TOLERANCE`; without them it
  starts as forward differences and ends as central differences. Either way the covariance's
  Jacobian is taken within :data:`GN_REUSE_SIGMAS` standard uncertainties of the final
  parameters. The fit stops when the step it would still take is below
  :data:`GN_SIGMA_TOLERANCE` standard uncertainties (or ``tolerance`` relative to the
  parameters) in every parameter, or when a step lowers the cost by less than
  :data:`GN_STALL` relative; it gives up after :data:`GN_MAX_STEPS` steps. With
  ``workers > 1`` the finite differences run in threads (``simulate`` must be thread-safe).
  On the shipped trajectory: 6 to 8 simulations against ``least_squares``' 27 and the 16 of
  its covariance (``docs/identification_results.md``, "Compute time").
* ``'pattern_search'``: :func:`~emfc_ros.core.ident.pattern_search.pattern_search` (MATLAB
  defaults) on the cost, in the scaled variables ``x_i = theta_i / scale_i`` so a mesh size of
  1 is a change of one scale (by default the magnitude of the initial value) in every
  parameter.

Scale of a parameter: ``spec.scale`` if given, else ``|initial|``, else half the bound range
when finite, else 1.

Uncertainty, with ``J`` the Jacobian of the residual vector with respect to the free
parameters at the optimum, by central differences with steps ``COVARIANCE_STEP * scale`` for
both optimisers (``least_squares``' own forward-difference Jacobian is too coarse for it;
these extra simulations are counted in ``n_evaluations`` but not in
``optimizer_evaluations``):

* ``covariance='white'``: ``Cov = s^2 (J^T J)^-1`` with ``s^2 = sum r^2 / (m - p)``. Right only
  for white residuals; output error with process noise is not white, and this covariance is
  then far too small.
* ``covariance='sandwich'`` (default): ``Cov = H^-1 S H^-1`` with ``H = J^T J`` and ``S`` the
  covariance of the score ``J^T r`` estimated in the frequency domain, section by section:
  ``S = N^-2 sum_k w_k Re(conj(J_k) J_k^T) P_k`` with ``J_k``, ``R_k`` the DFTs of the
  Jacobian columns and of the residual, ``P_k = |R_k|^2`` averaged over
  ``SANDWICH_SMOOTHING_LINES`` neighbouring lines and ``w_k`` 2 for the lines that stand for a
  conjugate pair. For stationary noise of any colour the DFT lines are nearly uncorrelated,
  so this is the heteroscedasticity-consistent (White) estimator written over frequencies:
  it reduces to ``s^2 (J^T J)^-1`` for white residuals and stays right for coloured process
  and measurement noise (the spectral form of a HAC estimator; Hannan, *Multiple Time
  Series*, 1970, ch. VII).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
import math
import threading
import time
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np
from scipy import optimize

from emfc_ros.core.blas_threads import with_single_blas_thread
from emfc_ros.core.ident.covariance import inverse, line_score_covariance, score_covariance
from emfc_ros.core.ident.errors import IdentificationError
from emfc_ros.core.ident.metrics import fit_percent, input_correlation_test, whiteness_test
from emfc_ros.core.ident.pattern_search import pattern_search, PatternSearchOptions

METHODS = ('least_squares', 'gauss_newton', 'pattern_search')
#: Relative forward-difference step of ``least_squares``' Jacobian. Its default (the square
#: root of the machine epsilon, 1.5e-8) is below the numerical noise of a long nonlinear
#: simulation (rounding in some 10^5 RK4 steps, the static solve of the start), which then
#: swamps the Jacobian columns of weakly determined parameters.
DIFF_STEP = 1.0e-6
#: Central-difference step of the Jacobian behind the covariance, relative to each parameter's
#: scale: about the cube root of that noise, where truncation and rounding errors balance.
COVARIANCE_STEP = 1.0e-5
#: Gauss-Newton stops when its next step is below this many standard uncertainties (white
#: estimate ``s^2 (J^T J)^-1``) in every parameter.
GN_SIGMA_TOLERANCE = 0.01
#: Gauss-Newton recomputes the central-difference Jacobian (the covariance's) when the
#: parameters moved more than this many standard uncertainties since it was computed.
GN_REUSE_SIGMAS = 0.1
#: A step whose actual cost reduction is below this fraction of the predicted one marks the
#: chord Jacobian as stale.
GN_STALE_RATIO = 0.25
#: Gauss-Newton ends when an accepted step lowers the cost by less than this, relative.
GN_STALL = 1.0e-9
#: Most trial steps (one simulation each) before Gauss-Newton gives up: a start next to the
#: optimum needs two or three; a model that cannot follow the data crawls on.
GN_MAX_STEPS = 30
COVARIANCES = ('sandwich', 'white')
#: The caller's output derivatives are used for the covariance when they agree with the
#: simulation's own derivative to this relative difference (else central differences).
DERIVATIVE_TOLERANCE = 0.01
#: How the Jacobian behind the covariance was obtained, by the fit's internal name.
JACOBIAN_METHODS = {'central': 'central differences of the simulation',
                    'derivatives': 'output derivatives, checked against the simulation',
                    'forward': 'forward differences of the simulation'}
Simulate = Callable[[Dict[str, float], np.ndarray], np.ndarray]
Derivatives = Callable[[Dict[str, float], Sequence[str], np.ndarray], Optional[np.ndarray]]
#: ``derivatives(params, names, inputs, outputs)`` of known inputs (``fit_greybox``'s
#: ``systematic``).
InputDerivatives = Callable[[Dict[str, float], Sequence[str], np.ndarray, np.ndarray],
                            Optional[np.ndarray]]


@dataclass(frozen=True)
class ParameterSpec:
    """
    One model parameter: start value, bounds, free or fixed, and scale.

    Attributes
    ----------
    name : str
        Parameter name (key of the dict passed to ``simulate``).
    initial : float
        Start value (the value used when fixed).
    lower, upper : float
        Bounds (may be infinite).
    free : bool
        Estimated when true, held at ``initial`` when false.
    scale : float, optional
        Typical magnitude (see the module docstring for the default).
    unit : str
        Unit for reports.
    """

    name: str
    initial: float
    lower: float = -math.inf
    upper: float = math.inf
    free: bool = True
    scale: Optional[float] = None
    unit: str = ''

    def resolved_scale(self) -> float:
        """
        The scale used for this parameter.

        Returns
        -------
        float
            ``scale``, else ``|initial|``, else half the finite bound range, else 1.
        """
        if self.scale is not None:
            return float(self.scale)
        if self.initial != 0.0:
            return abs(float(self.initial))
        if math.isfinite(self.lower) and math.isfinite(self.upper) and self.upper > self.lower:
            return 0.5 * (self.upper - self.lower)
        return 1.0


@dataclass(frozen=True)
class DataSection:
    """
    A named stretch of measured data.

    Attributes
    ----------
    name : str
        Section name (e.g. ``'chirp coil'``).
    inputs : ndarray
        Inputs, shape (n,) or (n, inputs).
    outputs : ndarray
        Measured outputs, shape (n,) or (n, outputs).
    weight : float
        Relative weight in the objective (> 0).
    """

    name: str
    inputs: np.ndarray
    outputs: np.ndarray
    weight: float = 1.0


@dataclass(frozen=True)
class SectionFit:
    """
    How well the final model reproduces one section.

    Attributes
    ----------
    name : str
        Section name.
    fit_percent : ndarray
        MATLAB ``compare`` fit per output [%].
    whiteness_fraction : float
        Fraction of residual autocorrelation lags 1..25 inside the 99 % band (mean over
        outputs), of the residual named by ``residual_tested``.
    input_correlation_fraction : float
        Fraction of residual-input cross-correlation lags -25..25 inside the 99 % band (mean
        over input-output pairs; NaN for constant inputs), same residual.
    rms_error : ndarray
        Root-mean-square of ``y - y_hat`` per output.
    residual_tested : str
        ``'noise-weighted'`` when the fit weighted the output error by the inverse noise
        spectrum (then the tests see that weighted, pre-whitened residual, with the noise
        transient projected out: what the fit treats as white), ``'raw'`` otherwise (the
        output error ``y - y_hat`` itself).
    whiteness_p_value : float
        Ljung-Box p-value of the autocorrelation (NaN when not tested this way).
    input_correlation_p_value : float
        p-value of the cross-correlation with the inputs, the smallest over the inputs times
        their number (Bonferroni; NaN when not tested this way).
    coherence : CoherencePeak or None
        Where the residual is most coherent with an input
        (:mod:`~emfc_ros.core.ident.residual_coherence`; None when not tested).
    """

    name: str
    fit_percent: np.ndarray
    whiteness_fraction: float
    input_correlation_fraction: float
    rms_error: np.ndarray
    residual_tested: str = 'raw'
    whiteness_p_value: float = math.nan
    input_correlation_p_value: float = math.nan
    coherence: Optional[Any] = None


@dataclass(frozen=True)
class GreyboxResult:
    """
    Estimated parameters, their uncertainty and the quality of the fit.

    Attributes
    ----------
    parameters : dict of str to float
        All parameters (free estimated, fixed as given).
    standard_errors : dict of str to float
        Standard errors (0 for fixed parameters, NaN when not computed).
    correlation : ndarray
        Correlation matrix of the free parameters (order of ``free_names``).
    free_names : tuple of str
        Names of the free parameters.
    cost : float
        Final objective ``sum r^2``.
    n_evaluations : int
        All calls of ``simulate`` (optimiser plus Jacobian for the uncertainty).
    optimizer_evaluations : int
        Calls made by the optimiser.
    time_s : float
        Wall time of the whole fit [s].
    method : str
        ``'least_squares'`` or ``'pattern_search'``.
    success : bool
        Whether the optimiser ended on a tolerance rather than a budget or failure.
    exit_reason : str
        The optimiser's message.
    sections : tuple of SectionFit
        Per-section fit and residual tests.
    covariance : ndarray
        Covariance of the free parameters (order of ``free_names``; NaN when not computed).
    covariance_method : str
        ``'sandwich'``, ``'white'`` or ``'none'``.
    initial : dict of str to float
        Start values of the free parameters.
    jacobian_method : str
        How the Jacobian behind the covariance was obtained (:data:`JACOBIAN_METHODS`).
    derivative_check : float
        With the caller's output derivatives: their largest relative difference from the
        simulation's own derivative along the two checked directions (NaN when not checked).
    systematic_names : tuple of str
        The known inputs of ``fit_greybox``'s ``systematic`` (empty without).
    systematic_sensitivity : ndarray or None
        ``d theta / d beta``, shape (free parameters, inputs): how the estimate moves per
        unit error of each known input.
    """

    parameters: Dict[str, float]
    standard_errors: Dict[str, float]
    correlation: np.ndarray
    free_names: Tuple[str, ...]
    cost: float
    n_evaluations: int
    optimizer_evaluations: int
    time_s: float
    method: str
    success: bool
    exit_reason: str
    sections: Tuple[SectionFit, ...]
    covariance: Optional[np.ndarray] = None
    covariance_method: str = 'none'
    initial: Optional[Dict[str, float]] = None
    jacobian_method: str = 'none'
    derivative_check: float = math.nan
    systematic_names: Tuple[str, ...] = ()
    systematic_sensitivity: Optional[np.ndarray] = None

    def moved(self, relative: float = 1.0e-6) -> bool:
        """
        Whether the optimiser left its start.

        Parameters
        ----------
        relative : float
            Smallest change counted, relative to the start value (absolute for a start of 0).

        Returns
        -------
        bool
            True when some free parameter changed by more than that.
        """
        if not self.initial:
            return True
        for name in self.free_names:
            v0 = self.initial[name]
            if abs(self.parameters[name] - v0) > relative * (abs(v0) or 1.0):
                return True
        return False

    def summary(self) -> str:
        """
        A short plain-text report.

        Returns
        -------
        str
            Parameters with standard errors, section fits and the exit reason.
        """
        lines = [f'{self.method}: {self.exit_reason} ({self.optimizer_evaluations} '
                 f'evaluations, {self.time_s:.2f} s, cost {self.cost:.4g})']
        for name, value in self.parameters.items():
            se = self.standard_errors[name]
            tag = '' if name in self.free_names else ' (fixed)'
            lines.append(f'  {name} = {value:.6g} +/- {se:.2g}{tag}')
        for sec in self.sections:
            fits = ', '.join(f'{v:.2f} %' for v in np.atleast_1d(sec.fit_percent))
            lines.append(f'  section {sec.name!r}: fit {fits}, white '
                         f'{100 * sec.whiteness_fraction:.0f} %, input-uncorrelated '
                         f'{100 * sec.input_correlation_fraction:.0f} %')
        return '\n'.join(lines)


class _Problem:
    """Residuals of all sections for a vector of free parameters (in natural units)."""

    def __init__(self, simulate: Simulate, sections: Sequence[DataSection],
                 specs: Sequence[ParameterSpec],
                 noise_weights: Optional[Sequence[np.ndarray]] = None,
                 transients: Optional[Sequence[np.ndarray]] = None,
                 output_derivatives: Optional[Derivatives] = None) -> None:
        self.simulate = simulate
        self.output_derivatives = output_derivatives
        self.noise_weights = None if noise_weights is None else \
            [np.asarray(w, dtype=float) for w in noise_weights]
        # Orthonormal bases of the weighted transient terms (real and imaginary parts stacked)
        self.transient_q: Optional[List[Optional[np.ndarray]]] = None
        if transients is not None and self.noise_weights is not None:
            self.transient_q = []
            for g, w in zip(transients, self.noise_weights):
                self.transient_q.append(weighted_transient_basis(g, w))
        self.specs = list(specs)
        self.free = [s for s in self.specs if s.free]
        self.sections = []
        for sec in sections:
            y = np.asarray(sec.outputs, dtype=float)
            y2 = y.reshape(y.shape[0], -1)
            std = y2.std(axis=0)
            std[std == 0.0] = 1.0
            self.sections.append((sec, y, np.sqrt(sec.weight / y.shape[0]) / std))
        self.evaluations = 0
        self._lock = threading.Lock()
        # outputs of the last point evaluated with keep=True (the optimiser's current point)
        self._kept: Optional[Tuple[bytes, list]] = None

    def params(self, theta: np.ndarray) -> Dict[str, float]:
        values = {s.name: float(s.initial) for s in self.specs}
        for spec, value in zip(self.free, theta):
            values[spec.name] = float(value)
        return values

    def outputs(self, theta: np.ndarray, keep: bool = False):
        key = np.asarray(theta, dtype=float).tobytes()
        kept = self._kept
        if kept is not None and kept[0] == key:
            return kept[1]
        values = self.params(theta)
        with self._lock:
            self.evaluations += 1
        outs = []
        for sec, y, _ in self.sections:
            yh = np.asarray(self.simulate(values, np.asarray(sec.inputs, dtype=float)),
                            dtype=float)
            if yh.shape != y.shape:
                raise IdentificationError(
                    f'simulate returned shape {yh.shape} for section {sec.name!r}, expected '
                    f'the measured shape {y.shape}')
            outs.append(yh)
        if keep:
            self._kept = (key, outs)
        return outs

    def residuals(self, theta: np.ndarray, keep: bool = False) -> np.ndarray:
        try:
            outs = self.outputs(theta, keep)
        except IdentificationError:
            raise
        except Exception:          # a failing simulation is a bad point
            return np.full(sum(y.size for _, y, _ in self.sections), np.inf)
        if self.noise_weights is None:
            parts = [((yh - y).reshape(y.shape[0], -1) * w).ravel()
                     for yh, (_, y, w) in zip(outs, self.sections)]
            return np.concatenate(parts)
        parts = []
        qs = self.transient_q or [None] * len(self.sections)
        for yh, (sec, y, _), nw, q in zip(outs, self.sections, self.noise_weights, qs):
            e = np.fft.rfft(yh - y) * nw * math.sqrt(2.0 * sec.weight / y.shape[0])
            stacked = np.concatenate((e.real, e.imag))
            if q is not None:      # the transient term, projected out
                stacked = stacked - q @ (q.T @ stacked)
            parts.append(stacked)
        return np.concatenate(parts)

    def derivative_jacobian(self, theta: np.ndarray) -> Optional[np.ndarray]:
        """The residuals' Jacobian from the output derivatives (None if any is missing)."""
        values = self.params(theta)
        names = [s.name for s in self.free]
        columns = []
        for sec, _, _ in self.sections:
            d = self.output_derivatives(values, names, np.asarray(sec.inputs, dtype=float))
            if d is None:
                return None
            columns.append(d)
        return self.weighted(columns)

    def weighted(self, columns: Sequence[np.ndarray]) -> np.ndarray:
        """
        Output-error derivatives per section, as the residual vector weighs them.

        Parameters
        ----------
        columns : sequence of ndarray
            Per section, ``d(y_hat - y) / d beta`` of shape (n, q) (one output column).

        Returns
        -------
        ndarray, shape (residuals, q)
            The residual vector's derivatives.
        """
        parts = []
        weights = self.noise_weights or [None] * len(self.sections)
        qs = self.transient_q or [None] * len(self.sections)
        for (sec, y, w), nw, q, d in zip(self.sections, weights, qs, columns):
            p = np.shape(d)[-1]
            d = np.asarray(d, dtype=float).reshape(y.shape[0], -1, p)
            if nw is None:
                parts.append((d * w[None, :, None]).reshape(-1, p))
                continue
            e = np.fft.rfft(d[:, 0, :], axis=0) * (nw * math.sqrt(
                2.0 * sec.weight / y.shape[0]))[:, None]
            stacked = np.concatenate((e.real, e.imag))
            if q is not None:
                stacked = stacked - q @ (q.T @ stacked)
            parts.append(stacked)
        return np.concatenate(parts)

    def lengths(self) -> List[int]:
        """Residuals per section (in the time or the frequency domain)."""
        if self.noise_weights is None:
            return [y.size for _, y, _ in self.sections]
        return [2 * w.size for w in self.noise_weights]


@with_single_blas_thread
def fit_greybox(simulate: Simulate, sections: Sequence[DataSection],
                parameters: Sequence[ParameterSpec], *, method: str = 'least_squares',
                options: Optional[PatternSearchOptions] = None,
                max_nfev: Optional[int] = None, uncertainty: bool = True,
                max_lag: int = 25, covariance: str = 'sandwich',
                noise_weights: Optional[Sequence[np.ndarray]] = None,
                transients: Optional[Sequence[np.ndarray]] = None,
                tolerance: float = 1.0e-8, workers: int = 1,
                output_derivatives: Optional[Derivatives] = None,
                residual_tests: bool = True,
                on_candidate: Optional[Callable[[Dict[str, float]], None]] = None,
                systematic: Optional[Tuple[Sequence[str], InputDerivatives]] = None
                ) -> GreyboxResult:
    """
    Fit the free parameters of a simulation to measured sections.

    Parameters
    ----------
    simulate : callable
        ``simulate(params: dict, inputs: ndarray) -> outputs`` with the measured shape.
    sections : sequence of DataSection
        The data (at least one).
    parameters : sequence of ParameterSpec
        All parameters ``simulate`` needs, free or fixed (unique names).
    method : {'least_squares', 'gauss_newton', 'pattern_search'}
        Optimiser (see the module docstring).
    options : PatternSearchOptions, optional
        Pattern-search settings (MATLAB defaults).
    max_nfev : int, optional
        Evaluation budget of ``least_squares`` and ``gauss_newton`` (default ``100 (p + 1)``
        for both).
    uncertainty : bool
        Compute standard errors and correlations.
    covariance : {'sandwich', 'white'}
        Covariance estimator (see the module docstring).
    noise_weights : sequence of ndarray, optional
        Frequency weighting of the simulation error, one array per section (single-output
        sections) with a weight per ``rfft`` line, normally ``1 / sqrt(noise spectrum)``
        (:mod:`~emfc_ros.core.ident.noise_model`): the residuals become the weighted DFT lines
        of the output error, the maximum-likelihood criterion for Gaussian noise of that
        spectrum (the weights must not come from the same noise line by line).
    transients : sequence of ndarray, optional
        With ``noise_weights``: per section a complex array of shape (lines, q) whose columns
        span the transient term of the noise, ``T_k = sum_i c_i G_ki`` with real ``c_i``
        (for noise through a linear system ``x+ = A x + B w``, ``y = C x``:
        ``G_k = C (z_k I - A)^-1 z_k``, ``c`` the state at the section start minus the state
        at its end). The term is projected out of each section's residual: a finite section
        of strongly resonant noise leaks (its own start and end) into the lines near the
        resonance, which would otherwise bias the estimate and fool its covariance.
    max_lag : int
        Largest lag of the residual tests.
    tolerance : float
        ``ftol`` and ``xtol`` of ``least_squares`` (relative change of the cost and of the
        parameters that ends the fit); for ``gauss_newton`` the relative step that ends it
        (besides :data:`GN_SIGMA_TOLERANCE`).
    workers : int
        Threads evaluating the finite-difference Jacobians (``simulate`` must then be
        thread-safe and, to gain, release the GIL as a numba kernel with ``nogil`` does).
    output_derivatives : callable, optional
        ``gauss_newton`` only: ``output_derivatives(params, free_names, inputs)`` gives a
        section's ``d outputs / d free parameters`` (shape ``outputs.shape + (p,)``; None when
        it cannot), e.g. from a linearised model. The fit iterates with the Jacobian they
        give; where it ends it compares them with central differences of ``simulate`` along
        the best and the worst determined direction (4 simulations) and takes them for the
        covariance when they agree within :data:`DERIVATIVE_TOLERANCE`, else the central
        differences in every parameter.
    residual_tests : bool
        Run the whiteness and input-correlation tests of each section (False: NaN, for a
        caller that tests the residuals its own way).
    on_candidate : callable, optional
        ``method='gauss_newton'`` with ``output_derivatives``: called with all parameter
        values (as :attr:`GreyboxResult.parameters` would hold them) where the iteration has
        converged, before the derivatives are checked against the simulation. The fit
        usually ends there (the result then holds exactly these values), so a caller can
        start on what depends only on the values (e.g. the model's figures) while the check
        runs; when the check fails the iteration goes on and the result differs.
    systematic : (names, derivatives), optional
        Inputs taken as known (``beta``) whose errors the fit cannot see, and
        ``derivatives(params, names, inputs, outputs)`` giving a section's ``d(y_hat - y) /
        d beta`` of shape (n, len(names)) at the estimate (a model input moves ``y_hat``, a
        measurement scale ``y``). With ``uncertainty``: the estimate's first-order change
        per unit of each input, ``d theta / d beta = -(J^T J)^-1 J^T G`` with ``G`` those
        derivatives weighted as the residuals are (the fit re-minimising with the input
        changed), in :attr:`GreyboxResult.systematic_sensitivity`.

    Returns
    -------
    GreyboxResult
        Parameters, standard errors, correlation, counts, time, section fits, exit reason.

    Raises
    ------
    IdentificationError
        If the specification is inconsistent (names, bounds, shapes, no free parameter) or
        the simulation fails at the start point.
    """
    if method not in METHODS:
        raise IdentificationError(f'method must be one of {METHODS}, got {method!r}')
    if covariance not in COVARIANCES:
        raise IdentificationError(f'covariance must be one of {COVARIANCES}, got '
                                  f'{covariance!r}')
    _check_specs(parameters)
    _check_sections(sections)
    if noise_weights is not None:
        if len(noise_weights) != len(sections) or any(
                np.asarray(sec.outputs).ndim != 1
                or np.asarray(w).shape != (np.asarray(sec.outputs).size // 2 + 1,)
                for sec, w in zip(sections, noise_weights)):
            raise IdentificationError('noise_weights need one array of n // 2 + 1 weights per '
                                      'single-output section')
    start = time.perf_counter()
    sensitivity = None
    problem = _Problem(simulate, sections, parameters, noise_weights, transients,
                       output_derivatives if method == 'gauss_newton' else None)
    free = problem.free
    theta0 = np.array([s.initial for s in free], dtype=float)
    lower = np.array([s.lower for s in free], dtype=float)
    upper = np.array([s.upper for s in free], dtype=float)
    scales = np.array([s.resolved_scale() for s in free], dtype=float)
    r0 = problem.residuals(theta0, keep=True)
    if not np.all(np.isfinite(r0)):
        raise IdentificationError('the simulation fails or is not finite at the initial '
                                  'parameters')
    before = problem.evaluations
    workers = max(1, int(workers))
    r = None
    jacobian_method, check = JACOBIAN_METHODS['central'], math.nan
    if method == 'least_squares':
        res = optimize.least_squares(problem.residuals, theta0, bounds=(lower, upper),
                                     method='trf', x_scale=scales, max_nfev=max_nfev,
                                     ftol=tolerance, xtol=tolerance, diff_step=DIFF_STEP)
        theta, jac = res.x, None
        success, reason = bool(res.status > 0), str(res.message)
    elif method == 'gauss_newton':
        gn = _gauss_newton(problem, theta0, r0, lower, upper, scales, tolerance,
                           max_nfev or 100 * (theta0.size + 1), workers, uncertainty,
                           on_candidate)
        theta, jac, r, success, reason, kind, check = gn
        if jac is not None:
            jacobian_method = JACOBIAN_METHODS[kind]
    else:
        def natural(x: np.ndarray) -> np.ndarray:
            # Clip away the rounding of (bound / scale) * scale.
            return np.clip(x * scales, lower, upper)

        def cost(x: np.ndarray) -> float:
            r = problem.residuals(natural(x))
            return float(r @ r)

        ps = pattern_search(cost, theta0 / scales, lower / scales, upper / scales, options)
        theta, jac = natural(ps.x), None
        success, reason = ps.success, ps.message
    # Every residual evaluation of the optimiser, finite-difference Jacobians included.
    opt_evals = problem.evaluations - before
    if r is None:
        r = problem.residuals(theta, keep=True)
    cost_final = float(r @ r)
    k = theta.size
    se = np.full(k, np.nan)
    corr = np.full((k, k), np.nan)
    cov = np.full((k, k), np.nan)
    if uncertainty:
        if jac is None:
            jac = _central_jacobian(problem.residuals, theta, COVARIANCE_STEP * scales, lower,
                                    upper, workers)
        jac = np.asarray(jac, dtype=float)
        h_inv = inverse(jac.T @ jac)
        if covariance == 'white':
            dof = max(r.size - k, 1)
            cov = (cost_final / dof) * h_inv
        else:
            correction = r.size / max(r.size - k, 1)
            if noise_weights is None:
                score = score_covariance(jac, r, problem.lengths())
            else:
                score = line_score_covariance(jac, r, problem.lengths())
            finite = np.all(np.isfinite(h_inv), axis=1)
            cov = np.full((k, k), np.inf)
            sub = np.ix_(finite, finite)
            cov[sub] = h_inv[sub] @ score[sub] @ h_inv[sub] * correction
        se = np.sqrt(np.maximum(np.diag(cov), 0.0))
        with np.errstate(divide='ignore', invalid='ignore'):
            corr = cov / np.outer(se, se)
        if systematic is not None and len(systematic[0]):
            sensitivity = _systematic_sensitivity(problem, theta, jac, h_inv, systematic)
    values = problem.params(theta)
    errors = {s.name: 0.0 for s in parameters}
    for spec, value in zip(free, se):
        errors[spec.name] = float(value)
    fits = _section_fits(problem, theta, max_lag, residual_tests)
    return GreyboxResult(values, errors, corr, tuple(s.name for s in free), cost_final,
                         problem.evaluations, opt_evals, time.perf_counter() - start, method,
                         success, reason, fits, cov,
                         covariance if uncertainty else 'none',
                         {s.name: float(s.initial) for s in free},
                         jacobian_method if uncertainty else 'none', check,
                         tuple(systematic[0]) if sensitivity is not None else (),
                         sensitivity)


def _systematic_sensitivity(problem: _Problem, theta: np.ndarray, jac: np.ndarray,
                            h_inv: np.ndarray,
                            systematic: Tuple[Sequence[str], InputDerivatives]
                            ) -> Optional[np.ndarray]:
    """``d theta / d beta`` of the known inputs (see :func:`fit_greybox`), or None."""
    names, derivatives = list(systematic[0]), systematic[1]
    values = problem.params(theta)
    columns = []
    for sec, y, _ in problem.sections:
        d = derivatives(values, names, np.asarray(sec.inputs, dtype=float), y)
        if d is None:
            return None
        columns.append(np.asarray(d, dtype=float).reshape(y.shape[0], len(names)))
    g = problem.weighted(columns)
    with np.errstate(invalid='ignore'):
        return -(h_inv @ (jac.T @ g))


def _check_specs(parameters: Sequence[ParameterSpec]) -> None:
    names = [p.name for p in parameters]
    if len(set(names)) != len(names):
        raise IdentificationError(f'parameter names must be unique, got {names}')
    if not any(p.free for p in parameters):
        raise IdentificationError('at least one parameter must be free')
    for p in parameters:
        if not math.isfinite(p.initial):
            raise IdentificationError(f'parameter {p.name!r}: initial must be finite')
        if p.free and not p.lower <= p.initial <= p.upper:
            raise IdentificationError(f'parameter {p.name!r}: initial {p.initial!r} outside '
                                      f'[{p.lower!r}, {p.upper!r}]')
        if p.scale is not None and not (math.isfinite(p.scale) and p.scale > 0.0):
            raise IdentificationError(f'parameter {p.name!r}: scale must be finite and > 0')


def _check_sections(sections: Sequence[DataSection]) -> None:
    if not sections:
        raise IdentificationError('need at least one data section')
    for sec in sections:
        u, y = np.asarray(sec.inputs), np.asarray(sec.outputs)
        if y.ndim not in (1, 2) or y.shape[0] < 2 or u.shape[0] != y.shape[0]:
            raise IdentificationError(f'section {sec.name!r}: inputs and outputs need the same '
                                      f'number of samples (>= 2), got {u.shape} and {y.shape}')
        if not (np.isfinite(u).all() and np.isfinite(y).all()):
            raise IdentificationError(f'section {sec.name!r} holds NaN or infinite samples')
        if not sec.weight > 0.0:
            raise IdentificationError(f'section {sec.name!r}: weight must be > 0')


def _evaluate_all(fun: Callable[[np.ndarray], np.ndarray], points: Sequence[np.ndarray],
                  workers: int) -> List[np.ndarray]:
    """``fun`` at every point, in ``workers`` threads."""
    if workers <= 1 or len(points) <= 1:
        return [fun(p) for p in points]
    with ThreadPoolExecutor(max_workers=min(workers, len(points))) as pool:
        return list(pool.map(fun, points))


def _central_jacobian(fun: Callable[[np.ndarray], np.ndarray], x: np.ndarray,
                      steps: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                      workers: int = 1) -> np.ndarray:
    """Central differences (one-sided at a bound)."""
    points, spans = [], []
    for i, h in enumerate(steps):
        up, down = x.copy(), x.copy()
        up[i] = min(x[i] + h, upper[i])
        down[i] = max(x[i] - h, lower[i])
        points += [up, down]
        spans.append(up[i] - down[i])
    values = _evaluate_all(fun, points, workers)
    return np.column_stack([(values[2 * i] - values[2 * i + 1]) / spans[i]
                            for i in range(len(spans))])


def _forward_jacobian(fun: Callable[[np.ndarray], np.ndarray], x: np.ndarray, f0: np.ndarray,
                      steps: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                      workers: int = 1) -> np.ndarray:
    """Forward differences (backward at the upper bound)."""
    points, spans = [], []
    for i, h in enumerate(steps):
        moved = x.copy()
        moved[i] = x[i] + h if x[i] + h <= upper[i] else x[i] - h
        moved[i] = min(max(moved[i], lower[i]), upper[i])
        points.append(moved)
        spans.append(moved[i] - x[i])
    values = _evaluate_all(fun, points, workers)
    return np.column_stack([(v - f0) / h for v, h in zip(values, spans)])


def _white_sigma(gram: np.ndarray, cost: float, m: int) -> Tuple[np.ndarray, np.ndarray]:
    """White covariance ``s^2 (J^T J)^-1`` and standard uncertainties (inf where undetermined)."""
    p = gram.shape[0]
    cov = np.linalg.pinv(gram) * cost / max(m - p, 1)
    sigma = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return cov, np.where(sigma > 0.0, sigma, np.inf)


def _check_derivatives(problem: _Problem, theta: np.ndarray, jac: np.ndarray, cov: np.ndarray,
                       scales: np.ndarray, lower: np.ndarray, upper: np.ndarray,
                       workers: int) -> float:
    """
    Largest relative difference between a Jacobian and the simulation's own derivative.

    Along the best and the worst determined direction of the covariance (scaled variables),
    by central differences of the simulation with :data:`COVARIANCE_STEP`.
    """
    _, vectors = np.linalg.eigh(cov)
    points, deltas = [], []
    for v in (vectors[:, -1], vectors[:, 0]):
        v = v / np.max(np.abs(v))
        up = np.clip(theta + COVARIANCE_STEP * v * scales, lower, upper)
        down = np.clip(theta - COVARIANCE_STEP * v * scales, lower, upper)
        points += [up, down]
        deltas.append(up - down)
    values = _evaluate_all(problem.residuals, points, workers)
    worst = 0.0
    for k, delta in enumerate(deltas):
        exact = values[2 * k] - values[2 * k + 1]
        size = float(np.linalg.norm(exact))
        if not np.isfinite(size) or size == 0.0:
            return math.inf
        worst = max(worst, float(np.linalg.norm(exact - jac @ delta)) / size)
    return worst


def _gauss_newton(problem: _Problem, theta0: np.ndarray, r0: np.ndarray, lower: np.ndarray,
                  upper: np.ndarray, scales: np.ndarray, tolerance: float, budget: int,
                  workers: int, central_at_end: bool,
                  on_candidate: Optional[Callable[[Dict[str, float]], None]] = None
                  ) -> Tuple[np.ndarray, Optional[np.ndarray], np.ndarray, bool, str, str,
                             float]:
    """
    Bounded Gauss-Newton with Levenberg-Marquardt damping and Jacobian reuse.

    The Jacobian comes from the problem's output derivatives when it has them (checked against
    the simulation where the fit ends), else from forward differences of the simulation
    while iterating and central differences at the end. Returns the parameters, the Jacobian
    for the covariance at (or within :data:`GN_REUSE_SIGMAS` standard uncertainties of) them
    (None when ``central_at_end`` is false or the budget ran out first), their residual
    vector, success, the reason, how the Jacobian was obtained and the check's relative
    difference (NaN when not checked).
    """
    start = problem.evaluations
    theta, r = theta0.copy(), r0
    cost = float(r @ r)
    m = r.size
    check = math.nan

    def jacobian(exact: bool) -> Tuple[np.ndarray, str]:
        if not exact and problem.output_derivatives is not None:
            derived = problem.derivative_jacobian(theta)
            if derived is not None:
                return derived, 'derivatives'
        if exact:
            return _central_jacobian(problem.residuals, theta, COVARIANCE_STEP * scales,
                                     lower, upper, workers), 'central'
        return _forward_jacobian(problem.residuals, theta, r, DIFF_STEP * scales, lower,
                                 upper, workers), 'forward'

    jac, kind = jacobian(False)
    theta_j, fresh, checked = theta.copy(), True, False
    lam = 0.0
    # the last accepted step lowered the cost by less than GN_STALL relative: nothing more to
    # gain (for a noise-weighted cost of 4e5, 4e-4: a step of about 0.02 standard uncertainty)
    stalled = False
    steps = 0
    reason, success = 'evaluation budget exhausted', False
    converged = (f'the next Gauss-Newton step is below {GN_SIGMA_TOLERANCE:g} standard '
                 f'uncertainty')
    while problem.evaluations - start < budget:
        if steps >= GN_MAX_STEPS:
            reason = f'no convergence in {GN_MAX_STEPS} Gauss-Newton steps'
            break
        js = jac * scales
        if not np.all(np.isfinite(js)):
            if kind == 'derivatives':       # fall back on the simulation's own
                jac, kind = jacobian(True)
                theta_j, fresh = theta.copy(), True
                continue
            reason = 'the Jacobian is not finite'
            break
        # normal equations: p is small and the columns scaled (a QR of the m x p matrix costs
        # ten times more and changes the step by far less than its tolerance)
        gram = js.T @ js
        grad = js.T @ r
        cov, sigma = _white_sigma(gram, cost, m)
        damp = lam * np.diag(np.diag(gram))
        step = -np.linalg.lstsq(gram + damp, grad, rcond=None)[0]
        small = (np.max(np.abs(step) / sigma) < GN_SIGMA_TOLERANCE
                 or np.linalg.norm(step) <= tolerance * (tolerance + np.linalg.norm(
                     theta / scales)) or stalled)
        if small and lam == 0.0:
            moved = np.max(np.abs((theta - theta_j) / scales) / sigma)
            if moved > GN_REUSE_SIGMAS and not stalled:
                jac, kind = jacobian(kind == 'central')
                theta_j, fresh, checked = theta.copy(), True, False
                continue
            if not central_at_end:
                reason, success = converged, True
                break
            if kind == 'central':
                reason, success = converged, True
                break
            if kind == 'derivatives' and not checked:
                if on_candidate is not None:    # where the fit ends if the check passes
                    on_candidate(problem.params(theta))
                check = _check_derivatives(problem, theta, jac, cov, scales, lower, upper,
                                           workers)
                checked = True
                if check <= DERIVATIVE_TOLERANCE:
                    reason, success = converged, True
                    break
            jac, kind = jacobian(True)
            theta_j, fresh = theta.copy(), True
            continue
        trial = np.clip(theta + step * scales, lower, upper)
        steps += 1
        r_new = problem.residuals(trial, keep=True)
        cost_new = float(r_new @ r_new) if np.all(np.isfinite(r_new)) else math.inf
        taken = (trial - theta) / scales
        # cost - |r + J d|^2 of the linear model
        predicted = -float(2.0 * taken @ grad + taken @ gram @ taken)
        if cost_new < cost:
            actual = cost - cost_new
            stalled = actual <= GN_STALL * cost
            theta, r, cost = trial, r_new, cost_new
            lam = 0.0 if lam <= 1.0e-6 else lam / 10.0
            if predicted > 0.0 and actual < GN_STALE_RATIO * predicted and not fresh:
                jac, kind = jacobian(kind == 'central')
                theta_j, fresh, checked = theta.copy(), True, False
            else:
                fresh = False
            continue
        if not fresh:
            # the Jacobian is stale: a new one at the current point
            jac, kind = jacobian(kind == 'central')
            theta_j, fresh, checked = theta.copy(), True, False
            continue
        lam = max(lam * 10.0, 1.0e-3)
        if lam > 1.0e8:
            if kind == 'derivatives':       # the derivatives may be what is wrong
                jac, kind = jacobian(True)
                theta_j, fresh, lam = theta.copy(), True, 0.0
                continue
            # no step along the fresh Jacobian lowers the cost: a minimum within rounding
            reason, success = ('no step lowers the cost (minimum within the simulation '
                               'noise)'), True
            if central_at_end and kind != 'central':
                jac, kind = jacobian(True)
            break
    covariance_ready = kind == 'central' or (kind == 'derivatives' and checked
                                             and check <= DERIVATIVE_TOLERANCE)
    if not covariance_ready:
        jac = None
    problem.residuals(theta, keep=True)
    return theta, jac, r, success, reason, kind, check


def weighted_transient_basis(transient: Optional[np.ndarray], weights: np.ndarray
                             ) -> Optional[np.ndarray]:
    """
    Orthonormal basis of a section's weighted transient term (real and imaginary stacked).

    Parameters
    ----------
    transient : ndarray or None
        Complex basis of shape (lines, q) (see :func:`fit_greybox`'s ``transients``).
    weights : ndarray
        The section's noise weights (lines).

    Returns
    -------
    ndarray or None
        Shape (2 lines, q); None without a transient.
    """
    if transient is None or np.size(transient) == 0:
        return None
    gw = np.asarray(transient, dtype=complex).reshape(weights.size, -1) * weights[:, None]
    q, _ = np.linalg.qr(np.vstack((gw.real, gw.imag)))
    return q


def prewhitened(err: np.ndarray, weights: np.ndarray,
                q: Optional[np.ndarray] = None) -> np.ndarray:
    """
    The output error as the noise-weighted fit sees it, back in the time domain.

    ``irfft(W(k) E(k))`` with the transient term projected out: for a right model and a right
    noise model a white sequence (the maximum-likelihood criterion's assumption), so the
    residual tests are meaningful; the raw output error of the balance is dominated by
    process noise ringing at the low mode and is never white.

    Parameters
    ----------
    err : ndarray, shape (n,)
        Output error ``y - y_hat``.
    weights : ndarray, shape (n // 2 + 1,)
        The fit's whitening weights.
    q : ndarray, optional
        Orthonormal basis of the weighted transient term (real and imaginary parts stacked).

    Returns
    -------
    ndarray, shape (n,)
        The pre-whitened residual (arbitrary scale).
    """
    e = np.fft.rfft(err) * weights
    if q is not None:
        stacked = np.concatenate((e.real, e.imag))
        stacked = stacked - q @ (q.T @ stacked)
        e = stacked[:e.size] + 1j * stacked[e.size:]
    return np.fft.irfft(e, err.size)


def _section_fits(problem: _Problem, theta: np.ndarray, max_lag: int,
                  tests: bool = True) -> Tuple[SectionFit, ...]:
    outs = problem.outputs(theta)
    fits = []
    weights = problem.noise_weights or [None] * len(problem.sections)
    qs = problem.transient_q or [None] * len(problem.sections)
    for yh, (sec, y, _), nw, q in zip(outs, problem.sections, weights, qs):
        y2, yh2 = y.reshape(y.shape[0], -1), yh.reshape(y.shape[0], -1)
        u2 = np.asarray(sec.inputs, dtype=float).reshape(y.shape[0], -1)
        err = y2 - yh2
        white, cross = [], []
        if tests:
            tested = err if nw is None else prewhitened(err[:, 0], nw, q)[:, None]
        for c in range(err.shape[1] if tests else 0):
            if y.shape[0] >= max_lag + 2 and np.any(err[:, c] != err[0, c]):
                white.append(whiteness_test(tested[:, c], max_lag).fraction_inside)
                for j in range(u2.shape[1]):
                    if np.ptp(u2[:, j]) > 0.0:
                        cross.append(input_correlation_test(tested[:, c], u2[:, j],
                                                            max_lag).fraction_inside)
        fits.append(SectionFit(sec.name, np.atleast_1d(fit_percent(y2, yh2)),
                               float(np.mean(white)) if white else float('nan'),
                               float(np.mean(cross)) if cross else float('nan'),
                               np.sqrt(np.mean(err ** 2, axis=0)),
                               'raw' if nw is None else 'noise-weighted'))
    return tuple(fits)


def specs_from_mapping(values: Mapping[str, float], free: Sequence[str] = (),
                       relative_bounds: Tuple[float, float] = (0.1, 10.0)
                       ) -> Tuple[ParameterSpec, ...]:
    """
    Build parameter specs from a dict of values (helper for physical models).

    Parameters
    ----------
    values : mapping of str to float
        All parameter values (start values of the free ones).
    free : sequence of str
        Names to estimate; the others are fixed.
    relative_bounds : (float, float)
        Bounds of a free positive parameter as multiples of its start value.

    Returns
    -------
    tuple of ParameterSpec
        One spec per entry of ``values``.

    Raises
    ------
    IdentificationError
        If a free name is not in ``values``.
    """
    missing = [name for name in free if name not in values]
    if missing:
        raise IdentificationError(f'free parameters {missing} are not in the values')
    specs = []
    for name, value in values.items():
        v = float(value)
        if name in free:
            lo, hi = sorted((relative_bounds[0] * v, relative_bounds[1] * v))
            specs.append(ParameterSpec(name, v, lo, hi, True))
        else:
            specs.append(ParameterSpec(name, v, free=False))
    return tuple(specs)
