"""
Continuous-time rational fit ``H(s) = N(s) / D(s)`` to frequency-response data.

Steps (all in the scaled variable ``s~ = s / w_ref`` with ``w_ref`` the geometric mean of the
band edges, and the response divided by its median magnitude, so the polynomial coefficients
are of order one):

1. **Levy** linearised least squares: ``N(s~_i) - H_i D(s~_i) = 0`` with a monic ``D``,
   rows weighted by ``1 / sigma_i`` (``sigma_i`` the FRF's ``std`` when given and positive,
   else ``|H_i|``, i.e. relative error), real and imaginary parts stacked, columns
   equilibrated, solved with :func:`scipy.linalg.lstsq`.
2. **Sanathanan-Koerner** iterations: the same with rows also divided by
   ``|D_prev(s~_i)|`` until the poles stop moving (relative change below 1e-10) or
   ``sk_iterations``.
3. **Stability**: poles in the right half plane are reflected (``Re p -> -|Re p|``) and the
   numerator is refitted linearly with that denominator.
4. **Refinement** (optional): :func:`scipy.optimize.least_squares` (trust-region reflective)
   on the weighted complex error ``(H_model - H_i) / sigma_i`` with the denominator written as
   quadratic factors ``s~^2 + a s~ + b`` (and one ``s~ + c`` for odd order) bounded by
   ``a, b, c >= 0``, which keeps every pole in the closed left half plane, and the
   numerator as free polynomial coefficients.

Uncertainty: ``Cov = s^2 (J^T J)^-1`` from the Jacobian of the final fit with
``s^2 = chi^2 / (2 N - p)`` (or ``s^2 = 1/2`` with ``absolute_sigma``: ``sigma`` is the
complex standard deviation, so each real component has variance ``sigma^2 / 2``),
propagated to modes and anti-resonances in :mod:`emfc_ros.core.ident.modal`. Order
selection compares fits by ``AIC = n ln(chi^2 / n) + 2 p`` and
``BIC = n ln(chi^2 / n) + p ln(n)`` with ``n = 2 N`` real residuals and ``p`` real
parameters.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple

import numpy as np
from scipy import linalg, optimize

from emfc_ros.core.blas_threads import with_single_blas_thread
from emfc_ros.core.ident.errors import IdentificationError
from emfc_ros.core.ident.frf import FrequencyResponseData
from emfc_ros.core.ident.modal import Mode, quadratic_mode, root_modes
from emfc_ros.core.model.linear import Root

CRITERIA = ('aic', 'bic')


@dataclass(frozen=True)
class TransferFunctionFit:
    """
    A fitted continuous-time transfer function with modal parameters and fit statistics.

    Attributes
    ----------
    numerator, denominator : ndarray
        Coefficients in ``s`` [rad/s], highest power first (:mod:`scipy.signal` order);
        the denominator is monic.
    numerator_order, denominator_order : int
        Polynomial orders.
    reference_rad_per_s : float
        Frequency scaling ``w_ref`` used internally.
    poles, zeros : tuple of Root
        Roots of denominator and numerator.
    modes : tuple of Mode
        Complex pole pairs (resonances) with standard deviations, by frequency.
    anti_resonances : tuple of Mode
        Complex zero pairs with standard deviations, by frequency.
    chi2 : float
        Weighted residual sum of squares ``sum |H_model - H|^2 / sigma^2``.
    n_residuals : int
        Real residuals (twice the frequencies).
    n_parameters : int
        Real parameters.
    aic, bic : float
        Information criteria (see the module docstring).
    covariance : ndarray
        Covariance of the refined parameters (numerator coefficients, then quadratic/linear
        denominator factors, scaled variable); empty without refinement.
    sk_iterations : int
        Sanathanan-Koerner iterations done.
    refined : bool
        Whether the nonlinear refinement ran.
    message : str
        Refinement exit message (or why it was skipped).
    unit : str
        Unit of the response.
    """

    numerator: np.ndarray
    denominator: np.ndarray
    numerator_order: int
    denominator_order: int
    reference_rad_per_s: float
    poles: Tuple[Root, ...]
    zeros: Tuple[Root, ...]
    modes: Tuple[Mode, ...]
    anti_resonances: Tuple[Mode, ...]
    chi2: float
    n_residuals: int
    n_parameters: int
    aic: float
    bic: float
    covariance: np.ndarray
    sk_iterations: int
    refined: bool
    message: str
    unit: str = ''

    @property
    def is_stable(self) -> bool:
        """Whether all poles lie in the closed left half plane."""
        return all(p.s_rad_per_s.real <= 0.0 for p in self.poles)

    def response(self, frequency_Hz: Sequence[float]) -> np.ndarray:
        """
        Evaluate the fitted model.

        Parameters
        ----------
        frequency_Hz : sequence of float
            Frequencies [Hz].

        Returns
        -------
        ndarray
            Complex response.
        """
        s = 2j * np.pi * np.asarray(frequency_Hz, dtype=float) / self.reference_rad_per_s
        w = self.reference_rad_per_s
        nb, na = self.numerator_order, self.denominator_order
        num = self.numerator[::-1] / w ** (na - np.arange(nb + 1))
        den = self.denominator[::-1] / w ** (na - np.arange(na + 1))
        return _polyval(num, s) / _polyval(den, s)

    def to_lti(self) -> 'scipy.signal.TransferFunction':  # noqa: F821
        """
        The model as :class:`scipy.signal.TransferFunction`.

        Returns
        -------
        scipy.signal.TransferFunction
            Continuous-time transfer function in s [rad/s].
        """
        from scipy import signal as sps     # imported on use: a second to import
        return sps.TransferFunction(self.numerator, self.denominator)


@dataclass(frozen=True)
class OrderSelection:
    """
    Fits of several orders and the one chosen by an information criterion.

    Attributes
    ----------
    fits : tuple of TransferFunctionFit
        All candidate fits (failed candidates are left out).
    criterion : str
        ``'aic'`` or ``'bic'``.
    chosen : TransferFunctionFit
        The fit with the smallest criterion.
    table : tuple of dict
        Per candidate: ``numerator_order``, ``denominator_order``, ``n_parameters``,
        ``chi2``, ``aic``, ``bic``, ``stable``.
    """

    fits: Tuple[TransferFunctionFit, ...]
    criterion: str
    chosen: TransferFunctionFit
    table: Tuple[dict, ...]


@with_single_blas_thread
def fit_transfer_function(frd: FrequencyResponseData, numerator_order: int,
                          denominator_order: int, *, use_std: bool = True,
                          refine: bool = True, sk_iterations: int = 50,
                          reference_Hz: Optional[float] = None,
                          absolute_sigma: bool = False) -> TransferFunctionFit:
    """
    Fit ``N(s) / D(s)`` of given orders to an FRF (Levy, SK, stabilise, refine).

    Parameters
    ----------
    frd : FrequencyResponseData
        The data; NaN points are ignored.
    numerator_order, denominator_order : int
        Orders with ``0 <= numerator_order <= denominator_order`` and
        ``denominator_order >= 1``.
    use_std : bool
        Weight by ``1 / frd.std`` where it is finite and positive (else relative weighting
        ``1 / |H|`` for all points).
    refine : bool
        Run the bounded nonlinear refinement (needed for uncertainties).
    sk_iterations : int
        Maximum Sanathanan-Koerner iterations.
    reference_Hz : float, optional
        Frequency scaling ``w_ref / 2 pi``; default the geometric mean of the band edges.
    absolute_sigma : bool
        Treat the std as absolute (do not rescale the covariance by ``chi^2 / dof``).

    Returns
    -------
    TransferFunctionFit
        The model, modes, anti-resonances, statistics.

    Raises
    ------
    IdentificationError
        If the orders are invalid or there are too few frequencies.
    """
    nb, na = _check_orders(numerator_order, denominator_order)
    f, h, sigma, weighted = _prepare(frd, use_std)
    n_par = nb + 1 + na
    if 2 * f.size <= n_par:
        raise IdentificationError(f'{f.size} frequencies are too few for {n_par} parameters')
    w_ref = 2.0 * np.pi * (float(reference_Hz) if reference_Hz is not None
                           else float(np.sqrt(f.min() * f.max())))
    if not np.isfinite(w_ref) or w_ref <= 0.0:
        raise IdentificationError(f'reference_Hz must be > 0, got {reference_Hz!r}')
    scale = float(np.median(np.abs(h)))
    hs, sig = h / scale, sigma / scale
    s = 2j * np.pi * f / w_ref
    num, den, iters = _sanathanan_koerner(s, hs, sig, nb, na, sk_iterations)
    poles = np.roots(den[::-1])
    if np.any(poles.real > 0.0):
        poles = np.where(poles.real > 0.0, -poles.real + 1j * poles.imag, poles)
        den = np.real(np.poly(poles))[::-1]
        num = _fit_numerator(s, hs, sig, den, nb)
    cov = np.zeros((0, 0))
    refined, message = False, 'refinement not requested'
    num_cov = None
    quads: List[Tuple[float, float]] = []
    factors = [den]
    if refine:
        num, den, cov, quads, message, num_cov, quad_cov, factors = _refine(
            s, hs, sig, num, den, nb, na, absolute_sigma)
        refined = True
        dof = frd.details.get('dof') if isinstance(frd.details, dict) else None
        if weighted and dof:
            # The weights are estimates (the LPM's std from ``dof`` complex noise degrees
            # of freedom): the parameters scatter more than with known weights.
            inflate = estimated_weight_variance_factor(2.0 * float(dof))
            cov, num_cov = cov * inflate, num_cov * inflate
            quad_cov = [c * inflate for c in quad_cov]
    resid = (_polyval(num, s) / _polyval(den, s) - hs) / sig
    chi2 = float(np.sum(np.abs(resid) ** 2))
    n_res = 2 * f.size
    aic, bic = _criteria(chi2, n_res, n_par)
    # Back to unscaled s and the caller's magnitude.
    # D~(s/w) w^na = sum_k d_k w^(na - k) s^k is monic in s.
    num_s = scale * num * w_ref ** (na - np.arange(nb + 1))
    den_s = den * w_ref ** (na - np.arange(na + 1))
    nan = float('nan')
    if refined:
        modes = tuple(sorted(
            (quadratic_mode(a, b, c, w_ref) for (a, b), c in zip(quads, quad_cov)
             if a * a < 4.0 * b), key=lambda m: m.frequency_Hz))
        anti = root_modes(num, num_cov, w_ref)
    else:
        modes = tuple(Mode(r.frequency_Hz, r.damping_ratio, nan, nan)
                      for r in _roots(den_s[::-1]) if r.s_rad_per_s.imag > 0.0)
        anti = tuple(Mode(r.frequency_Hz, r.damping_ratio, nan, nan)
                     for r in _roots(num_s[::-1]) if r.s_rad_per_s.imag > 0.0)
    # Poles from the factors (exactly in the closed left half plane after refinement).
    pole_values = np.concatenate([np.roots(np.asarray(fac)[::-1]) for fac in factors]) * w_ref
    poles = tuple(sorted((Root(complex(v)) for v in pole_values),
                         key=lambda r: (abs(r.s_rad_per_s), r.s_rad_per_s.imag)))
    return TransferFunctionFit(num_s[::-1].copy(), den_s[::-1].copy(), nb, na, w_ref,
                               poles, _roots(num_s[::-1]), modes, anti, chi2,
                               n_res, n_par, aic, bic, cov, iters, refined, message,
                               frd.unit)


@with_single_blas_thread
def select_order(frd: FrequencyResponseData, candidates: Sequence[Tuple[int, int]], *,
                 criterion: str = 'bic', **options) -> OrderSelection:
    """
    Fit several (numerator, denominator) orders and choose by AIC or BIC.

    Parameters
    ----------
    frd : FrequencyResponseData
        The data.
    candidates : sequence of (int, int)
        ``(numerator_order, denominator_order)`` pairs.
    criterion : {'aic', 'bic'}
        Selection criterion (smallest wins).
    **options
        Passed to :func:`fit_transfer_function`.

    Returns
    -------
    OrderSelection
        All fits, the table and the chosen one.

    Raises
    ------
    IdentificationError
        If the criterion is unknown or no candidate could be fitted.
    """
    if criterion not in CRITERIA:
        raise IdentificationError(f'criterion must be one of {CRITERIA}, got {criterion!r}')
    fits = []
    for nb, na in candidates:
        try:
            fits.append(fit_transfer_function(frd, nb, na, **options))
        except (IdentificationError, np.linalg.LinAlgError):
            continue
    if not fits:
        raise IdentificationError(f'no candidate order could be fitted: {list(candidates)}')
    table = tuple({'numerator_order': fit.numerator_order,
                   'denominator_order': fit.denominator_order,
                   'n_parameters': fit.n_parameters, 'chi2': fit.chi2, 'aic': fit.aic,
                   'bic': fit.bic, 'stable': fit.is_stable} for fit in fits)
    chosen = min(fits, key=lambda fit: getattr(fit, criterion))
    return OrderSelection(tuple(fits), criterion, chosen, table)


def _check_orders(numerator_order: int, denominator_order: int) -> Tuple[int, int]:
    for name, value in (('numerator_order', numerator_order),
                        ('denominator_order', denominator_order)):
        if isinstance(value, bool) or int(value) != value or value < 0:
            raise IdentificationError(f'{name} must be an integer >= 0, got {value!r}')
    nb, na = int(numerator_order), int(denominator_order)
    if na < 1 or nb > na:
        raise IdentificationError(f'need 1 <= denominator_order and numerator_order <= '
                                  f'denominator_order (proper model), got {nb}/{na}')
    return nb, na


def _prepare(frd: FrequencyResponseData, use_std: bool):
    f = np.asarray(frd.frequency_Hz, dtype=float)
    h = np.asarray(frd.response, dtype=complex)
    std = np.asarray(frd.std, dtype=float)
    keep = np.isfinite(f) & np.isfinite(h) & (f > 0.0) & (np.abs(h) > 0.0)
    if np.count_nonzero(keep) < 2:
        raise IdentificationError('the FRF holds fewer than 2 usable (finite, non-zero) '
                                  'points above 0 Hz')
    f, h, std = f[keep], h[keep], std[keep]
    if use_std and np.all(np.isfinite(std) & (std > 0.0)):
        return f, h, std, True
    return f, h, np.abs(h), False


def estimated_weight_variance_factor(nu: float) -> float:
    """
    Variance inflation of a least-squares fit weighted by estimated noise variances.

    Each weight is ``1 / sigma_hat^2`` with ``sigma_hat^2 ~ sigma^2 chi2_nu / nu`` (``nu``
    real degrees of freedom: twice the complex ones of an FRF's noise estimate). The
    parameters' variance is ``E[w^2] / E[w]^2 = (nu - 2) / (nu - 4)`` times the one with
    known weights (sample maximum likelihood, Pintelon and Schoukens, System Identification,
    2nd ed., section 10.3), which the covariance from the Jacobian (rescaled by
    ``chi^2 / dof``) does not contain. For the LPM's 6 complex degrees of freedom
    (``nu = 12``) the factor is 1.25: measured, the transfer-function modes' ``z`` had a
    standard deviation of 1.0 to 1.25 before it was applied.

    Parameters
    ----------
    nu : float
        Real degrees of freedom of each noise variance estimate.

    Returns
    -------
    float
        The factor (1 for ``nu`` infinite or not finite; for ``nu <= 4``, where the
        variance does not exist, the factor at ``nu = 5``, 3).
    """
    nu = float(nu)
    if not np.isfinite(nu):
        return 1.0
    nu = max(nu, 5.0)
    return (nu - 2.0) / (nu - 4.0)


def _polyval(coef_ascending: np.ndarray, s: np.ndarray) -> np.ndarray:
    return np.polynomial.polynomial.polyval(s, coef_ascending)


def _roots(coef_descending: np.ndarray) -> Tuple[Root, ...]:
    values = np.roots(coef_descending) if np.asarray(coef_descending).size > 1 else []
    return tuple(sorted((Root(complex(v)) for v in values),
                        key=lambda r: (abs(r.s_rad_per_s), r.s_rad_per_s.imag)))


def _solve_real(rows: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Least squares of complex rows with real unknowns, columns equilibrated."""
    a = np.vstack((rows.real, rows.imag))
    b = np.concatenate((rhs.real, rhs.imag))
    norms = np.linalg.norm(a, axis=0)
    norms[norms == 0.0] = 1.0
    sol = linalg.lstsq(a / norms, b)[0]
    return sol / norms


def _sanathanan_koerner(s, h, sigma, nb, na, iterations):
    """Levy then SK iterations; returns ascending numerator, monic ascending denominator."""
    pw_b = s[:, None] ** np.arange(nb + 1)
    pw_a = s[:, None] ** np.arange(na)
    weight = 1.0 / sigma
    den = None
    poles_prev = None
    done = 0
    for it in range(max(int(iterations), 0) + 1):
        wt = weight if den is None else weight / np.abs(_polyval(den, s))
        rows = np.hstack((pw_b, -h[:, None] * pw_a)) * wt[:, None]
        rhs = h * s ** na * wt
        sol = _solve_real(rows, rhs)
        num = sol[:nb + 1]
        den = np.append(sol[nb + 1:], 1.0)
        done = it
        poles = np.sort_complex(np.roots(den[::-1]))
        if poles_prev is not None and poles.size == poles_prev.size and np.all(
                np.abs(poles - poles_prev) <= 1e-10 * np.maximum(np.abs(poles), 1e-12)):
            break
        poles_prev = poles
    return num, den, done


def _fit_numerator(s, h, sigma, den, nb):
    d = _polyval(den, s)
    wt = 1.0 / (sigma * np.abs(d))
    rows = (s[:, None] ** np.arange(nb + 1)) * wt[:, None]
    return _solve_real(rows, h * d * wt)


def _factor(den: np.ndarray) -> Tuple[List[Tuple[float, float]], Optional[float]]:
    """Monic ascending denominator -> quadratic factors (a, b) and an optional linear c."""
    roots = np.roots(den[::-1])
    roots = np.where(roots.real > 0.0, -roots.real + 1j * roots.imag, roots)
    cplx = sorted([r for r in roots if r.imag > 1e-12 * max(abs(r), 1e-300)],
                  key=lambda r: abs(r))
    reals = sorted([r.real for r in roots if abs(r.imag) <= 1e-12 * max(abs(r), 1e-300)])
    quads = [(-2.0 * r.real, abs(r) ** 2) for r in cplx]
    linear = None
    while len(reals) >= 2:
        r1, r2 = reals.pop(0), reals.pop(0)
        quads.append((-(r1 + r2), r1 * r2))
    if reals:
        linear = -reals[0]
    return [(max(a, 0.0), max(b, 0.0)) for a, b in quads], (
        None if linear is None else max(linear, 0.0))


def _den_from(params: np.ndarray, n_quad: int, has_linear: bool) -> np.ndarray:
    den = np.array([1.0])
    for i in range(n_quad):
        a, b = params[2 * i], params[2 * i + 1]
        den = np.polynomial.polynomial.polymul(den, [b, a, 1.0])
    if has_linear:
        den = np.polynomial.polynomial.polymul(den, [params[2 * n_quad], 1.0])
    return den


def _refine(s, h, sigma, num, den, nb, na, absolute_sigma):
    quads, linear = _factor(den)
    n_quad, has_linear = len(quads), linear is not None
    den_params = [v for q in quads for v in q] + ([linear] if has_linear else [])
    x0 = np.concatenate((num, den_params))
    lower = np.concatenate((np.full(nb + 1, -np.inf), np.zeros(len(den_params))))
    upper = np.full(x0.size, np.inf)
    x0 = np.clip(x0, lower, upper)
    x0[nb + 1:] = np.maximum(x0[nb + 1:], 1e-12)

    def residuals(p: np.ndarray) -> np.ndarray:
        model = _polyval(p[:nb + 1], s) / _polyval(_den_from(p[nb + 1:], n_quad, has_linear), s)
        e = (model - h) / sigma
        return np.concatenate((e.real, e.imag))

    res = optimize.least_squares(residuals, x0, bounds=(lower, upper), method='trf',
                                 x_scale='jac', xtol=1e-15, ftol=1e-15, gtol=1e-15,
                                 max_nfev=200 * x0.size)
    p = res.x
    jac = res.jac
    dof = max(jac.shape[0] - jac.shape[1], 1)
    # sigma is the complex std: each real component has variance sigma^2 / 2.
    s2 = 0.5 if absolute_sigma else float(2.0 * res.cost / dof)
    cov = s2 * linalg.pinvh(jac.T @ jac)
    num = p[:nb + 1]
    den = _den_from(p[nb + 1:], n_quad, has_linear)
    num_cov = cov[:nb + 1, :nb + 1]
    quad_params = [(float(p[nb + 1 + 2 * i]), float(p[nb + 2 + 2 * i])) for i in range(n_quad)]
    quad_cov = [cov[nb + 1 + 2 * i:nb + 3 + 2 * i, nb + 1 + 2 * i:nb + 3 + 2 * i]
                for i in range(n_quad)]
    factors = [np.array([b, a, 1.0]) for a, b in quad_params]
    if has_linear:
        factors.append(np.array([p[nb + 1 + 2 * n_quad], 1.0]))
    return num, den, cov, quad_params, str(res.message), num_cov, quad_cov, factors


def _criteria(chi2: float, n: int, p: int) -> Tuple[float, float]:
    base = n * np.log(max(chi2, 1e-300) / n)
    return float(base + 2.0 * p), float(base + p * np.log(n))
