"""
Static characteristics: plateau averaging of staircase data and linear least-squares fits.

Fits are ordinary (optionally weighted) least squares solved with :func:`scipy.linalg.lstsq`
on an equilibrated design (polynomials in the scaled variable ``z = (x - centre) / half_range``,
the way :meth:`numpy.polynomial.Polynomial.fit` maps its domain; every column divided by its
norm). Standard errors follow from the residual variance ``s^2 = RSS / (n - p)`` and
``Cov = s^2 (X^T X)^-1``, transformed back to the caller's units. A condition number of the
equilibrated design above ``max_condition`` raises an :class:`IllConditionedFitWarning`.

Results print in the paper's form (Table 1), e.g.
``I(U) = -6.964e-06 A/V^2 * U^2 + 1.000e-02 A/V * U + 7.552e-06 A``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
import math
from typing import Dict, Mapping, Optional, Sequence
import warnings

import numpy as np
from numpy.polynomial import polynomial as npoly
from scipy import linalg

from emfc_ros.core.ident.errors import IdentificationError, IllConditionedFitWarning
from emfc_ros.core.ident.frf import as_record, as_records, check_rate

#: Default limit on the condition number of the equilibrated design matrix.
MAX_CONDITION = 1.0e8


@dataclass(frozen=True)
class LinearFit:
    """
    Result of a linear-in-parameters least-squares fit ``y = X theta``.

    Attributes
    ----------
    coefficients : ndarray
        Estimated parameters ``theta``.
    standard_errors : ndarray
        Their standard errors ``sqrt(diag(Cov))``.
    covariance : ndarray
        ``s^2 (X^T W X)^-1``.
    r_squared : float
        Coefficient of determination ``1 - RSS / TSS`` (weighted when weights are given).
    residual_std : float
        ``s = sqrt(RSS / (n - p))`` in the unit of y.
    condition_number : float
        2-norm condition number of the equilibrated (scaled) design.
    n_samples : int
        Number of samples n.
    """

    coefficients: np.ndarray
    standard_errors: np.ndarray
    covariance: np.ndarray
    r_squared: float
    residual_std: float
    condition_number: float
    n_samples: int

    @property
    def correlation(self) -> np.ndarray:
        """Correlation matrix of the parameters."""
        sd = np.where(self.standard_errors > 0.0, self.standard_errors, 1.0)
        return self.covariance / np.outer(sd, sd)


@dataclass(frozen=True)
class PolynomialFit:
    """
    A polynomial characteristic ``y(x) = sum_k c_k x^k`` with its statistics.

    Attributes
    ----------
    coefficients : ndarray
        ``c_0 .. c_degree`` in the caller's units (ascending powers).
    standard_errors : ndarray
        Standard errors of the coefficients.
    covariance : ndarray
        Covariance of the coefficients.
    r_squared : float
        Coefficient of determination.
    residual_std : float
        Residual standard deviation [y_unit].
    condition_number : float
        Condition number of the design in the scaled variable.
    x_name, y_name, x_unit, y_unit : str
        Names and units used by :meth:`formula`.
    """

    coefficients: np.ndarray
    standard_errors: np.ndarray
    covariance: np.ndarray
    r_squared: float
    residual_std: float
    condition_number: float
    x_name: str = 'x'
    y_name: str = 'y'
    x_unit: str = ''
    y_unit: str = ''

    @property
    def degree(self) -> int:
        """Polynomial degree."""
        return self.coefficients.size - 1

    def __call__(self, x: np.ndarray) -> np.ndarray:
        """
        Evaluate the polynomial.

        Parameters
        ----------
        x : array_like
            Abscissae [x_unit].

        Returns
        -------
        ndarray
            ``y(x)`` [y_unit].
        """
        return npoly.polyval(np.asarray(x, dtype=float), self.coefficients)

    def formula(self, digits: int = 3) -> str:
        """
        The fitted curve in the paper's form.

        Parameters
        ----------
        digits : int
            Digits after the decimal point of the mantissa.

        Returns
        -------
        str
            e.g. ``I(U) = -6.964e-06 A/V^2 * U^2 + 1.000e-02 A/V * U + 7.552e-06 A``.
        """
        terms = []
        for k in range(self.degree, -1, -1):
            unit = _unit(self.y_unit, self.x_unit, k)
            var = '' if k == 0 else (f' * {self.x_name}' if k == 1 else
                                     f' * {self.x_name}^{k}')
            terms.append((self.coefficients[k], f'{unit}{var}'))
        return f'{self.y_name}({self.x_name}) = ' + _join_terms(terms, digits)


@dataclass(frozen=True)
class MotorCoefficientFit:
    """
    Position-dependent motor coefficient ``F(I, y) = (a y^2 + b y + c) I``.

    Attributes
    ----------
    coefficients : ndarray
        ``[a, b, c]``: [F_unit/(I_unit y_unit^2), F_unit/(I_unit y_unit), F_unit/I_unit].
    standard_errors : ndarray
        Standard errors of ``a, b, c``.
    covariance : ndarray
        Their covariance.
    r_squared : float
        Coefficient of determination of the force.
    residual_std : float
        Residual standard deviation of the force [force_unit].
    condition_number : float
        Condition number of the equilibrated design.
    force_unit, current_unit, position_unit : str
        Units used by :meth:`formula`.
    """

    coefficients: np.ndarray
    standard_errors: np.ndarray
    covariance: np.ndarray
    r_squared: float
    residual_std: float
    condition_number: float
    force_unit: str = 'N'
    current_unit: str = 'A'
    position_unit: str = 'mm'

    def __call__(self, current: np.ndarray, position: np.ndarray) -> np.ndarray:
        """
        Evaluate the force.

        Parameters
        ----------
        current, position : array_like
            Current [current_unit] and position [position_unit].

        Returns
        -------
        ndarray
            Force [force_unit].
        """
        a, b, c = self.coefficients
        y = np.asarray(position, dtype=float)
        return (a * y * y + b * y + c) * np.asarray(current, dtype=float)

    def formula(self, digits: int = 3) -> str:
        """
        The fitted characteristic in the paper's form.

        Parameters
        ----------
        digits : int
            Digits after the decimal point of the mantissa.

        Returns
        -------
        str
            e.g. ``F(I, y) = (-5.273e-03 N/(A mm^2) * y^2 + ... + 2.169e+01 N/A) * I``.
        """
        cu, pu, fu = self.current_unit, self.position_unit, self.force_unit
        a, b, c = self.coefficients
        terms = [(a, f'{fu}/({cu} {pu}^2) * y^2'), (b, f'{fu}/({cu} {pu}) * y'),
                 (c, f'{fu}/{cu}')]
        return f'F(I, y) = ({_join_terms(terms, digits)}) * I'


@dataclass(frozen=True)
class Plateaus:
    """
    Averages of several channels over the settled part of each staircase level.

    Attributes
    ----------
    start_s, end_s : ndarray
        Averaging window of each plateau [s] (after the settle time).
    count : ndarray
        Samples averaged per plateau.
    mean : dict of str to ndarray
        Mean of each channel per plateau.
    std : dict of str to ndarray
        Sample standard deviation of each channel within each plateau.
    """

    start_s: np.ndarray
    end_s: np.ndarray
    count: np.ndarray
    mean: Dict[str, np.ndarray] = field(default_factory=dict)
    std: Dict[str, np.ndarray] = field(default_factory=dict)

    def standard_error(self, name: str) -> np.ndarray:
        """
        Standard error of each plateau mean (``std / sqrt(count)``, white noise assumed).

        Parameters
        ----------
        name : str
            Channel name.

        Returns
        -------
        ndarray
            Standard errors.
        """
        return self.std[name] / np.sqrt(self.count)


def plateau_means(channels: Mapping[str, np.ndarray], sample_rate_Hz: float,
                  starts_s: Sequence[float], ends_s: Optional[Sequence[float]] = None, *,
                  settle_s: float = 0.0, record_start_s: float = 0.0) -> Plateaus:
    """
    Average each channel over the plateaus of a staircase, skipping a settle time.

    Parameters
    ----------
    channels : mapping of str to ndarray
        Equally long records on one sample clock (sample 0 at ``record_start_s``).
    sample_rate_Hz : float
        Sample rate [Hz].
    starts_s : sequence of float
        Start time of each level (e.g. ``Steps.times_s`` of the staircase) [s].
    ends_s : sequence of float, optional
        End of each level; default the next start, and the end of the record for the last.
    settle_s : float
        Time skipped after each start before averaging [s].
    record_start_s : float
        Time of sample 0 on the same clock as ``starts_s`` [s].

    Returns
    -------
    Plateaus
        Means, standard deviations and windows.

    Raises
    ------
    IdentificationError
        If the channels differ in length, a window is empty or outside the record.
    """
    fs = check_rate(sample_rate_Hz)
    if not channels:
        raise IdentificationError('channels must hold at least one record')
    data = {name: as_record(f'channels[{name!r}]', v) for name, v in channels.items()}
    sizes = {v.size for v in data.values()}
    if len(sizes) != 1:
        raise IdentificationError(f'channels must have equal length, got sizes {sorted(sizes)}')
    n = sizes.pop()
    starts = np.asarray(starts_s, dtype=float)
    if starts.ndim != 1 or starts.size == 0 or np.any(np.diff(starts) <= 0.0):
        raise IdentificationError('starts_s must be a non-empty increasing list of times')
    if ends_s is None:
        ends = np.append(starts[1:], record_start_s + n / fs)
    else:
        ends = np.asarray(ends_s, dtype=float)
        if ends.shape != starts.shape:
            raise IdentificationError(f'ends_s must have {starts.size} entries, got '
                                      f'{ends.shape}')
    if settle_s < 0.0:
        raise IdentificationError(f'settle_s must be >= 0, got {settle_s!r}')
    first = np.ceil((starts + settle_s - record_start_s) * fs - 1e-9).astype(np.int64)
    last = np.floor((ends - record_start_s) * fs + 1e-9).astype(np.int64)   # exclusive
    for i, (a, b) in enumerate(zip(first, last)):
        if a < 0 or b > n or b - a < 2:
            raise IdentificationError(
                f'plateau {i} ({starts[i]:g} s + settle {settle_s:g} s to {ends[i]:g} s) '
                f'holds fewer than 2 samples of the record ({n} samples from '
                f'{record_start_s:g} s)')
    means, stds = {}, {}
    for name, v in data.items():
        means[name] = np.array([v[a:b].mean() for a, b in zip(first, last)])
        stds[name] = np.array([v[a:b].std(ddof=1) for a, b in zip(first, last)])
    return Plateaus(first / fs + record_start_s, last / fs + record_start_s, last - first,
                    means, stds)


def linear_least_squares(design: np.ndarray, y: np.ndarray, *,
                         weights: Optional[np.ndarray] = None,
                         max_condition: float = MAX_CONDITION) -> LinearFit:
    """
    Weighted linear least squares with standard errors and a conditioning check.

    Parameters
    ----------
    design : ndarray, shape (n, p)
        Regressor matrix X.
    y : ndarray, shape (n,)
        Observations.
    weights : ndarray, optional
        Non-negative weights (e.g. ``1 / sigma_i^2``).
    max_condition : float
        Warn (:class:`IllConditionedFitWarning`) above this condition number of the
        column-equilibrated design.

    Returns
    -------
    LinearFit
        Parameters, standard errors, covariance, R^2, residual std and condition number.

    Raises
    ------
    IdentificationError
        If the shapes disagree, data are not finite, or ``n <= p``.
    """
    x = np.asarray(design, dtype=float)
    obs = np.asarray(y, dtype=float)
    if x.ndim != 2 or obs.shape != (x.shape[0],):
        raise IdentificationError(f'design must be (n, p) and y (n,), got {x.shape} and '
                                  f'{obs.shape}')
    if not (np.isfinite(x).all() and np.isfinite(obs).all()):
        raise IdentificationError('design and y must be finite')
    n, p = x.shape
    if n <= p:
        raise IdentificationError(f'need more samples than parameters: {n} samples for {p} '
                                  f'parameters')
    if weights is None:
        sw = np.ones(n)
    else:
        w = np.asarray(weights, dtype=float)
        if w.shape != (n,) or not np.isfinite(w).all() or np.any(w < 0.0):
            raise IdentificationError('weights must be n finite non-negative numbers')
        sw = np.sqrt(w)
    xw, yw = x * sw[:, None], obs * sw
    norms = np.linalg.norm(xw, axis=0)
    norms[norms == 0.0] = 1.0
    xs = xw / norms
    sv = linalg.svdvals(xs)
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0.0 else float('inf')
    if cond > max_condition:
        warnings.warn(f'ill-conditioned least-squares design: condition number {cond:.3g} '
                      f'exceeds {max_condition:.3g} (parameters nearly collinear; vary the '
                      f'inputs more or lower the model order)', IllConditionedFitWarning,
                      stacklevel=3)
    theta_s, _, _, _ = linalg.lstsq(xs, yw)
    resid = yw - xs @ theta_s
    rss = float(resid @ resid)
    s2 = rss / (n - p)
    cov_s = s2 * linalg.pinvh(xs.T @ xs)
    theta = theta_s / norms
    cov = cov_s / np.outer(norms, norms)
    ybar = np.sum(sw * sw * obs) / np.sum(sw * sw)
    tss = float(np.sum((sw * (obs - ybar)) ** 2))
    r2 = 1.0 - rss / tss if tss > 0.0 else float('nan')
    return LinearFit(theta, np.sqrt(np.maximum(np.diag(cov), 0.0)), cov, r2,
                     float(np.sqrt(s2 * n / np.sum(sw * sw))), cond, n)


def with_std_floor(fit: PolynomialFit, floor: float) -> PolynomialFit:
    """
    The same fit with its covariance computed from ``max(residual_std, floor)``.

    For plateau means that a converter quantises without dither (noise well below one step),
    the residual scatter of a few plateaus can fall below the quantisation error it stands for,
    ``step / sqrt(12)`` per mean; the floor keeps the covariance from claiming less.

    Parameters
    ----------
    fit : PolynomialFit
        The fit.
    floor : float
        Smallest residual standard deviation, in the unit of y (0 leaves the fit as it is).

    Returns
    -------
    PolynomialFit
        The fit with ``covariance`` and ``standard_errors`` scaled (``residual_std`` kept).
    """
    if not floor > 0.0 or not fit.residual_std < floor:
        return fit
    factor = (floor / fit.residual_std) ** 2 if fit.residual_std > 0.0 else math.inf
    if not math.isfinite(factor):
        return fit
    cov = fit.covariance * factor
    return replace(fit, covariance=cov, standard_errors=np.sqrt(np.maximum(np.diag(cov), 0.0)))


def fit_polynomial(x: np.ndarray, y: np.ndarray, degree: int, *,
                   weights: Optional[np.ndarray] = None, x_name: str = 'x',
                   y_name: str = 'y', x_unit: str = '', y_unit: str = '',
                   max_condition: float = MAX_CONDITION) -> PolynomialFit:
    """
    Least-squares polynomial ``y(x)`` of a given degree, fitted in a scaled variable.

    Parameters
    ----------
    x, y : ndarray
        Samples (e.g. plateau means).
    degree : int
        Polynomial degree >= 0.
    weights : ndarray, optional
        Non-negative weights (e.g. ``1 / sigma_y^2``).
    x_name, y_name, x_unit, y_unit : str
        Names and units for :meth:`PolynomialFit.formula`.
    max_condition : float
        Condition-number limit of the scaled design (warning above).

    Returns
    -------
    PolynomialFit
        Coefficients in the caller's units with their standard errors.

    Raises
    ------
    IdentificationError
        If the inputs are invalid or there are not more samples than coefficients.
    """
    if isinstance(degree, bool) or int(degree) != degree or degree < 0:
        raise IdentificationError(f'degree must be an integer >= 0, got {degree!r}')
    deg = int(degree)
    xs, ys = as_records(('x', 'y'), (x, y))
    lo, hi = float(xs.min()), float(xs.max())
    centre = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo) if hi > lo else 1.0
    z = (xs - centre) / half
    fit = linear_least_squares(np.vander(z, deg + 1, increasing=True), ys, weights=weights,
                               max_condition=max_condition)
    # c = T a with column k of T the x-power coefficients of ((x - centre) / half)^k.
    t = np.zeros((deg + 1, deg + 1))
    for k in range(deg + 1):
        col = npoly.polypow([-centre / half, 1.0 / half], k)
        t[:col.size, k] = col
    coef = t @ fit.coefficients
    cov = t @ fit.covariance @ t.T
    return PolynomialFit(coef, np.sqrt(np.maximum(np.diag(cov), 0.0)), cov, fit.r_squared,
                         fit.residual_std, fit.condition_number, x_name, y_name, x_unit,
                         y_unit)


def fit_motor_coefficient(current: np.ndarray, position: np.ndarray, force: np.ndarray, *,
                          weights: Optional[np.ndarray] = None, force_unit: str = 'N',
                          current_unit: str = 'A', position_unit: str = 'mm',
                          max_condition: float = MAX_CONDITION) -> MotorCoefficientFit:
    """
    Fit ``F(I, y) = (a y^2 + b y + c) I`` from (current, position, force) samples.

    Bilinear in the variables but linear in ``a, b, c``: regressors ``y^2 I, y I, I``.

    Parameters
    ----------
    current, position, force : ndarray
        Samples [current_unit, position_unit, force_unit] (the notes read the paper's
        position in mm).
    weights : ndarray, optional
        Non-negative weights.
    force_unit, current_unit, position_unit : str
        Units for the formula.
    max_condition : float
        Condition-number limit of the equilibrated design (warning above).

    Returns
    -------
    MotorCoefficientFit
        ``a, b, c`` with standard errors.

    Raises
    ------
    IdentificationError
        If the inputs are invalid.
    """
    i, y, f = as_records(('current', 'position', 'force'), (current, position, force))
    fit = linear_least_squares(np.column_stack((y * y * i, y * i, i)), f, weights=weights,
                               max_condition=max_condition)
    return MotorCoefficientFit(fit.coefficients, fit.standard_errors, fit.covariance,
                               fit.r_squared, fit.residual_std, fit.condition_number,
                               force_unit, current_unit, position_unit)


def _unit(y_unit: str, x_unit: str, power: int) -> str:
    """Unit of the coefficient of ``x^power``: ``y_unit/x_unit^power``."""
    if power == 0 or not x_unit:
        return y_unit
    num = y_unit or '1'
    return f'{num}/{x_unit}' if power == 1 else f'{num}/{x_unit}^{power}'


def _join_terms(terms: Sequence, digits: int) -> str:
    """Join (value, 'unit * var') terms with explicit signs: ``a U + b`` -> ``a ... + b ...``."""
    out = ''
    for j, (value, rest) in enumerate(terms):
        mant = f'{abs(value):.{digits}e}'
        rest = f' {rest}' if rest and not rest.startswith(' ') else rest
        if j == 0:
            out = f'{"-" if value < 0 else ""}{mant}{rest}'
        else:
            out += f' {"-" if value < 0 else "+"} {mant}{rest}'
    return out
