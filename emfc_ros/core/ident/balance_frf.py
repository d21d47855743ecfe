"""
The balance's linearised mechanics fitted to measured frequency responses.

This is the frequency-domain half of the grey-box identification (issue 12): a start for the
time-domain fit that comes from the data, not from the nominal parameters, and an estimate of
its own with a covariance from the nonparametric noise model.

* :func:`measure_frfs`: local polynomial FRFs (:mod:`~emfc_ros.core.ident.local_polynomial`)
  of the lever-end position per coil force and per pan force, the forces computed from the
  recorded setpoints through the configured amplifier, motor and load-changer characteristics
  (as the time-domain model uses them: no current-monitor noise on the input), the DAC hold
  removed. The LPM's noise variance per line (6 degrees of freedom) is averaged over
  neighbouring lines so that a weight does not rest on a handful of residuals.
* :class:`MechanicsFrfModel`: the response of the linearised two-beam model
  (:func:`~emfc_ros.core.model.linear.linearise`) at those lines for a set of mechanical
  parameters.
* :func:`fit_frfs`: the weighted least-squares fit ``sum |H_model - H|^2 / sigma^2`` over the
  lines (a frequency-domain maximum-likelihood estimator for Gaussian errors with the
  nonparametric variances; Pintelon & Schoukens, *System Identification*, 2nd ed., ch. 9),
  with the covariance ``(J^T J)^-1`` scaled by the reduced chi-square when that exceeds 1.
* :func:`feature_start`: the robust start: stiffnesses, dampings, masses and inertias solved
  from modal features of the measured responses (the two resonances and their dampings, the
  coil anti-resonance, and the mass-line levels ``|H| w^2`` between and above the modes),
  a small least-squares problem in the logarithms of the parameters solved from several
  starts.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np
from scipy import optimize

from emfc_ros.core.blas_threads import with_single_blas_thread
from emfc_ros.core.ident.errors import IdentificationError
from emfc_ros.core.ident.hold import hold_factor
from emfc_ros.core.ident.local_polynomial import local_polynomial_frf
from emfc_ros.core.model.linear import linearise, LinearModel
from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.parameters import BalanceParameters

#: Lines over which the LPM noise variance is averaged (odd).
VARIANCE_SMOOTHING_LINES = 9
#: Smallest relative std of a line used as a weight (the LPM's local polynomials and the hold
#: compensation are good to about 0.1 %).
RELATIVE_STD_FLOOR = 1.0e-3
#: Weight of the start values in the feature start (per unit of natural logarithm).
PRIOR_WEIGHT = 0.01
#: Largest relative std of a line that counts in a mass-line level.
MAX_LEVEL_RELATIVE_STD = 0.05


@dataclass(frozen=True)
class MeasuredFrf:
    """
    One measured response for the physical fit.

    Attributes
    ----------
    name : str
        ``<section>.<input>``.
    input : str
        ``'coil'`` or ``'pan'`` (force input; output the lever-end position).
    frequency_Hz : ndarray
        Lines [Hz].
    response : ndarray
        Complex response [m/N], hold removed.
    std : ndarray
        Complex standard deviation per line [m/N] (smoothed LPM noise, floored).
    two_input : bool
        From a section that excited both inputs (solved jointly).
    """

    name: str
    input: str
    frequency_Hz: np.ndarray
    response: np.ndarray
    std: np.ndarray
    two_input: bool = False


def setpoint_forces(channels: Mapping[str, np.ndarray], balance: BalanceParameters
                    ) -> Dict[str, np.ndarray]:
    """
    Coil and pan forces from the recorded setpoints through the configured characteristics.

    Parameters
    ----------
    channels : mapping of str to ndarray
        ``coil_setpoint_V``, ``load_changer_setpoint_V`` and ``position_m`` (for the
        position-dependent motor coefficient).
    balance : BalanceParameters
        The characteristics.

    Returns
    -------
    dict
        ``'coil'`` and ``'pan'`` force [N] per sample.
    """
    i_coil = np.asarray(balance.coil_amplifier.current_A(channels['coil_setpoint_V']),
                        dtype=float)
    coil = np.asarray(balance.motor.force_N(i_coil, channels['position_m']), dtype=float)
    i_lc = np.asarray(balance.load_changer_amplifier.current_A(
        channels['load_changer_setpoint_V']), dtype=float)
    pan = np.asarray(balance.load_changer.force_N(i_lc), dtype=float)
    return {'coil': coil, 'pan': pan}


def smoothed_std(std: np.ndarray, response: np.ndarray,
                 lines: int = VARIANCE_SMOOTHING_LINES) -> np.ndarray:
    """
    Average the noise variance over neighbouring lines and floor it relative to ``|H|``.

    Parameters
    ----------
    std : ndarray
        Complex std per line.
    response : ndarray
        The response (for the floor).
    lines : int
        Width of the moving average (odd; shrinks at the ends).

    Returns
    -------
    ndarray
        The smoothed std.
    """
    var = np.asarray(std, dtype=float) ** 2
    half = max(int(lines) // 2, 0)
    c = np.concatenate(([0.0], np.cumsum(var)))
    idx = np.arange(var.size)
    lo = np.maximum(idx - half, 0)
    hi = np.minimum(idx + half + 1, var.size)
    mean = (c[hi] - c[lo]) / (hi - lo)
    return np.maximum(np.sqrt(mean), RELATIVE_STD_FLOOR * np.abs(response))


def measure_frfs(channels: Mapping[str, np.ndarray], sample_rate_Hz: float,
                 jobs: Sequence[Tuple[str, int, int, Sequence[str]]],
                 balance: BalanceParameters, *, frequency_min_Hz: float,
                 frequency_max_Hz: float, hold: str = 'zoh', degree: int = 2
                 ) -> List[MeasuredFrf]:
    """
    LPM responses of the position per setpoint-derived force, for the physical fit.

    Parameters
    ----------
    channels : mapping of str to ndarray
        The recording (setpoints and position on one clock).
    sample_rate_Hz : float
        Sample rate [Hz].
    jobs : sequence of (name, first_sample_index, n_samples, inputs)
        Sections and which inputs were excited (``['coil']``, ``['pan']`` or both).
    balance : BalanceParameters
        Characteristics for the forces.
    frequency_min_Hz, frequency_max_Hz : float
        Band [Hz].
    hold : {'zoh', 'foh', 'none'}
        DAC hold removed from the response.
    degree : int
        LPM polynomial degree.

    Returns
    -------
    list of MeasuredFrf
        One per section and input with at least 8 lines.
    """
    forces = setpoint_forces(channels, balance)
    y = np.asarray(channels['position_m'], dtype=float)
    out = []
    for name, first, n, inputs in jobs:
        sl = slice(int(first), int(first) + int(n))
        us = [forces[i][sl] for i in inputs]
        if any(np.ptp(u) == 0.0 for u in us):
            continue
        try:
            frds = local_polynomial_frf(us, y[sl], sample_rate_Hz, degree=degree,
                                        frequency_min_Hz=frequency_min_Hz,
                                        frequency_max_Hz=frequency_max_Hz,
                                        input_units=['N'] * len(us), output_unit='m')
        except IdentificationError:
            continue
        for inp, frd in zip(inputs, frds):
            factor = hold_factor(frd.frequency_Hz, sample_rate_Hz, hold)
            h = frd.response / factor
            sd = frd.std / np.abs(factor)
            keep = np.isfinite(h) & np.isfinite(sd) & (sd > 0.0)
            if np.count_nonzero(keep) < 8:
                continue
            h, sd, f = h[keep], sd[keep], frd.frequency_Hz[keep]
            out.append(MeasuredFrf(f'{name}.{inp}', inp, f, h, smoothed_std(sd, h),
                                   len(inputs) > 1))
    return out


class MechanicsFrfModel:
    """
    Responses of the linearised balance at the measured lines.

    Parameters
    ----------
    balance : BalanceParameters
        The fixed parameters (and defaults of the free ones).
    load_mass_kg : float
        Mass on the pan [kg].
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan.
    """

    def __init__(self, balance: BalanceParameters, load_mass_kg: float,
                 load_changer_coupled: bool) -> None:
        self.balance = balance
        self.load_mass_kg = float(load_mass_kg)
        self.load_changer_coupled = bool(load_changer_coupled)

    def linear(self, values: Mapping[str, float]) -> LinearModel:
        """
        Linearisation for some mechanical parameters.

        Parameters
        ----------
        values : mapping of str to float
            Mechanical parameters replacing the balance's (mass-matrix entries too, see
            :func:`~emfc_ros.core.ident.balance_greybox.with_values`).

        Returns
        -------
        LinearModel
            At rest at ``q = 0`` in the experiment's configuration.
        """
        from emfc_ros.core.ident.balance_greybox import with_values

        mech = with_values(self.balance, {k: v for k, v in values.items() if k != 'F_off_N'},
                           self.load_mass_kg, self.load_changer_coupled).mechanics
        return linearise(loaded(mech, self.load_mass_kg, self.load_changer_coupled))

    def responses(self, values: Mapping[str, float], frfs: Sequence[MeasuredFrf]
                  ) -> List[np.ndarray]:
        """
        Model responses at every measured FRF's lines.

        Parameters
        ----------
        values : mapping of str to float
            Mechanical parameters.
        frfs : sequence of MeasuredFrf
            Where to evaluate.

        Returns
        -------
        list of ndarray
            Complex responses [m/N].
        """
        lin = self.linear(values)
        return [lin.frequency_response(m.frequency_Hz, m.input).response_m_per_N
                for m in frfs]


@dataclass(frozen=True)
class FrfFit:
    """
    Result of the frequency-domain fit.

    Attributes
    ----------
    values : dict of str to float
        Fitted free parameters.
    covariance : ndarray
        Covariance of the free parameters (order of ``names``).
    names : tuple of str
        Free parameter names.
    chi2_reduced : float
        ``sum r^2 / (m - p)`` (about 1 when the model and the noise model hold).
    n_lines : int
        Lines used.
    jacobian : ndarray
        Weighted residual Jacobian in the scaled variables ``theta / scale``.
    scales : ndarray
        The scales.
    success : bool
        Whether the optimiser converged.
    message : str
        The optimiser's message.
    """

    values: Dict[str, float]
    covariance: np.ndarray
    names: Tuple[str, ...]
    chi2_reduced: float
    n_lines: int
    jacobian: np.ndarray
    scales: np.ndarray
    success: bool
    message: str

    def standard_errors(self) -> Dict[str, float]:
        """Standard uncertainty of each fitted parameter."""
        se = np.sqrt(np.maximum(np.diag(self.covariance), 0.0))
        return dict(zip(self.names, (float(v) for v in se)))


def weighted_residuals(model: MechanicsFrfModel, frfs: Sequence[MeasuredFrf],
                       values: Mapping[str, float]) -> np.ndarray:
    """
    Residuals ``sqrt(2) (H_model - H) / std``, real and imaginary parts stacked.

    Each element has unit variance when the noise model holds.

    Parameters
    ----------
    model : MechanicsFrfModel
        The model.
    frfs : sequence of MeasuredFrf
        The data.
    values : mapping of str to float
        Mechanical parameters.

    Returns
    -------
    ndarray
        The residual vector.
    """
    parts = []
    for m, h in zip(frfs, model.responses(values, frfs)):
        e = np.sqrt(2.0) * (h - m.response) / m.std
        parts.append(np.concatenate((e.real, e.imag)))
    return np.concatenate(parts)


@with_single_blas_thread
def fit_frfs(model: MechanicsFrfModel, frfs: Sequence[MeasuredFrf],
             start: Mapping[str, float], names: Sequence[str],
             lower: Optional[Mapping[str, float]] = None,
             upper: Optional[Mapping[str, float]] = None) -> FrfFit:
    """
    Weighted least-squares fit of mechanical parameters to measured responses.

    Parameters
    ----------
    model : MechanicsFrfModel
        The model.
    frfs : sequence of MeasuredFrf
        The data (at least one).
    start : mapping of str to float
        Start values (all ``names`` and any fixed override).
    names : sequence of str
        Free parameters (positive quantities).
    lower, upper : mapping of str to float, optional
        Bounds (default 0 and infinity).

    Returns
    -------
    FrfFit
        Values, covariance and fit statistics.

    Raises
    ------
    IdentificationError
        Without data or free parameters.
    """
    if not frfs:
        raise IdentificationError('frequency-domain fit: no measured response')
    names = tuple(names)
    if not names:
        raise IdentificationError('frequency-domain fit: no free parameter')
    fixed = {k: float(v) for k, v in start.items() if k not in names}
    scales = np.array([abs(float(start[n])) or 1.0 for n in names])
    lo = np.array([float((lower or {}).get(n, 0.0)) for n in names]) / scales
    hi = np.array([float((upper or {}).get(n, np.inf)) for n in names]) / scales
    x0 = np.clip(np.array([float(start[n]) for n in names]) / scales, lo, hi)

    def values_at(x: np.ndarray) -> Dict[str, float]:
        return dict(fixed, **{n: float(v * s) for n, v, s in zip(names, x, scales)})

    def residual(x: np.ndarray) -> np.ndarray:
        return weighted_residuals(model, frfs, values_at(x))

    res = optimize.least_squares(residual, x0, bounds=(lo, hi), method='trf',
                                 x_scale='jac', xtol=1e-12, ftol=1e-12, gtol=1e-12,
                                 max_nfev=200 * (len(names) + 1))
    r = res.fun
    dof = max(r.size - len(names), 1)
    chi2 = float(r @ r) / dof
    jtj_inv = np.linalg.pinv(res.jac.T @ res.jac)
    cov_x = jtj_inv * max(chi2, 1.0)
    cov = cov_x * np.outer(scales, scales)
    n_lines = sum(m.frequency_Hz.size for m in frfs)
    return FrfFit(values_at(res.x), cov, names, chi2, n_lines, res.jac, scales,
                  bool(res.status > 0), str(res.message))


# ---------------------------------------------------------------- the start from features


@dataclass(frozen=True)
class ModalFeatures:
    """
    What the start matches: modes, the coil anti-resonance and mass-line levels.

    Attributes
    ----------
    modes : list of (float, float, float)
        ``(frequency_Hz, damping_ratio, frequency_std_Hz)`` of the low and the high mode.
    anti_resonance : (float, float, float) or None
        The coil input's anti-resonance, the same fields.
    levels : list of (str, float, float, float)
        ``(input, f_lo_Hz, f_hi_Hz, median |H| w^2)`` over the well-measured lines in that
        band [1/kg] (the inverse of an effective mass).
    """

    modes: List[Tuple[float, float, float]]
    anti_resonance: Optional[Tuple[float, float, float]]
    levels: List[Tuple[str, float, float, float]]


def _level(frfs: Sequence[MeasuredFrf], input: str, f_lo: float, f_hi: float,
           responses: Optional[Sequence[np.ndarray]] = None) -> Optional[float]:
    values = []
    singles = any(m.input == input and not m.two_input for m in frfs)
    for i, m in enumerate(frfs):
        if m.input != input or (singles and m.two_input):
            continue
        # lines measured to better than 5 % only (a two-input section's steps leave most
        # lines of that input's response in the noise)
        sel = (m.frequency_Hz >= f_lo) & (m.frequency_Hz <= f_hi) & \
            (m.std < MAX_LEVEL_RELATIVE_STD * np.abs(m.response))
        h = m.response if responses is None else responses[i]
        values.append(np.abs(h[sel]) * (2.0 * np.pi * m.frequency_Hz[sel]) ** 2)
    if not values:
        return None
    v = np.concatenate(values)
    return float(np.median(v)) if v.size >= 3 else None


def measured_features(frfs: Sequence[MeasuredFrf],
                      modes: Sequence[Tuple[float, float, float]],
                      anti_resonance: Optional[Tuple[float, float, float]]) -> ModalFeatures:
    """
    Modal features of the measurement for :func:`feature_start`.

    Parameters
    ----------
    frfs : sequence of MeasuredFrf
        The measured responses.
    modes : sequence of (float, float, float)
        Low and high mode ``(frequency_Hz, damping_ratio, frequency_std_Hz)``, each from the
        transfer-function fit that measured it best.
    anti_resonance : (float, float, float) or None
        The coil anti-resonance from the coil response's fit.

    Returns
    -------
    ModalFeatures
        With the mass-line levels between the modes (coil: below the anti-resonance) and above
        the high mode, for every input measured.
    """
    f1, f2 = sorted(m[0] for m in modes)[:2]
    bands = []
    for inp in ('coil', 'pan'):
        top = min(anti_resonance[0], f2) if (inp == 'coil' and anti_resonance) else f2
        bands.append((inp, 3.0 * f1, 0.6 * top))
        bands.append((inp, 1.6 * f2, 4.0 * f2))
    levels = []
    for inp, lo, hi in bands:
        v = _level(frfs, inp, lo, hi)
        if v is not None and v > 0.0:
            levels.append((inp, lo, hi, v))
    return ModalFeatures(sorted(tuple(m) for m in modes)[:2],
                         tuple(anti_resonance) if anti_resonance else None, levels)


def _model_features(model: MechanicsFrfModel, values: Mapping[str, float],
                    feats: ModalFeatures, frfs: Sequence[MeasuredFrf]) -> Optional[np.ndarray]:
    lin = model.linear(values)
    poles = sorted({(round(p.frequency_Hz, 9), p.damping_ratio) for p in lin.poles()
                    if p.s_rad_per_s.imag > 0.0})
    if len(poles) != 2:
        return None
    tiny = 1e-12
    out = [np.log(max(poles[0][0], tiny)), np.log(max(poles[1][0], tiny)),
           np.log(max(poles[0][1], tiny)), np.log(max(poles[1][1], tiny))]
    if feats.anti_resonance is not None:
        zeros = [z for z in lin.zeros('coil') if z.s_rad_per_s.imag > 0.0]
        if not zeros:
            return None
        z = min(zeros, key=lambda r: abs(np.log(r.frequency_Hz / feats.anti_resonance[0])))
        out += [np.log(max(z.frequency_Hz, tiny)), np.log(max(z.damping_ratio, tiny))]
    responses = [lin.frequency_response(m.frequency_Hz, m.input).response_m_per_N
                 for m in frfs]
    for inp, lo, hi, _ in feats.levels:
        v = _level(frfs, inp, lo, hi, responses)
        if v is None or not v > 0.0:
            return None
        out.append(np.log(v))
    return np.array(out)


def _frequency_weight(f: float, f_std: float) -> float:
    # inverse relative uncertainty, at most 1 / 0.2 %
    rel = f_std / f if np.isfinite(f_std) and f_std > 0.0 else 0.0
    return 1.0 / max(rel, 0.002)


def _feature_vector(feats: ModalFeatures) -> Tuple[np.ndarray, np.ndarray]:
    (f1, z1, s1), (f2, z2, s2) = feats.modes
    target = [np.log(f1), np.log(f2), np.log(z1), np.log(z2)]
    # Weights are inverse tolerances: frequencies by their uncertainty, dampings 10 %.
    weight = [_frequency_weight(f1, s1), _frequency_weight(f2, s2), 10.0, 10.0]
    if feats.anti_resonance is not None:
        fa, za, sa = feats.anti_resonance
        target += [np.log(fa), np.log(max(za, 1e-12))]
        weight += [_frequency_weight(fa, sa), 10.0]
    for _, _, _, v in feats.levels:
        target.append(np.log(v))
        weight.append(1.0 / 0.01)
    return np.array(target), np.array(weight)


@with_single_blas_thread
def feature_start(model: MechanicsFrfModel, frfs: Sequence[MeasuredFrf],
                  feats: ModalFeatures, names: Sequence[str], start: Mapping[str, float],
                  multipliers: Sequence[float] = (1.0, 0.5, 2.0),
                  progress: Optional[Callable[[str], None]] = None
                  ) -> Tuple[Dict[str, float], float]:
    """
    Solve the free parameters from the modal features, from several starts.

    The unknowns are the logarithms of the (positive) free parameters; each start multiplies
    every stiffness and damping by one of ``multipliers`` (masses and inertias stay), so the
    result does not depend on the start values being close. The starts are tried in order
    until one matches every feature within its tolerance (weighted mismatch below 1 each on
    average).

    Parameters
    ----------
    model : MechanicsFrfModel
        The model.
    frfs : sequence of MeasuredFrf
        The data (for the mass-line levels).
    feats : ModalFeatures
        The measured features.
    names : sequence of str
        Free parameters.
    start : mapping of str to float
        Nominal start values.
    multipliers : sequence of float
        Start variants.
    progress : callable, optional
        Called with a message per start.

    Returns
    -------
    values : dict of str to float
        The best solution (free parameters).
    cost : float
        Its weighted squared feature mismatch (0 when every feature is matched).

    Raises
    ------
    IdentificationError
        If no start gives a model with two modes.
    """
    names = tuple(names)
    target, weight = _feature_vector(feats)
    base = {k: float(v) for k, v in start.items()}
    prior = np.log([base[n] for n in names])

    def residual(logs: np.ndarray) -> np.ndarray:
        vals = dict(base, **{n: float(np.exp(v)) for n, v in zip(names, logs)})
        got = _model_features(model, vals, feats, frfs)
        # A weak pull towards the start values (a factor e costs as much as one feature off by
        # PRIOR_WEIGHT of its tolerance) keeps a direction the features do not determine where
        # it was instead of letting it drift to extremes; determined ones do not notice it.
        pull = PRIOR_WEIGHT * (logs - prior)
        if got is None or got.size != target.size or not np.all(np.isfinite(got)):
            return np.concatenate((np.full(target.size, 1e3), pull))
        return np.concatenate(((got - target) * weight, pull))

    best: Optional[Tuple[float, np.ndarray]] = None
    for mult in multipliers:
        x0 = np.log([base[n] * (mult if n.startswith(('c', 'd')) else 1.0) for n in names])
        if progress is not None:
            progress(f'start x{mult:g}')
        try:
            res = optimize.least_squares(residual, x0, method='lm', xtol=1e-10, ftol=1e-12,
                                         max_nfev=100 * (len(names) + 1))
        except (ValueError, np.linalg.LinAlgError):
            continue
        cost = float(res.fun @ res.fun)
        if best is None or cost < best[0]:
            best = (cost, res.x)
        if cost < target.size + len(names):     # every feature matched within its tolerance
            break
    if best is None or best[0] >= 1e6 * (target.size + len(names)):
        raise IdentificationError('frequency-domain start: no parameter set reproduces two '
                                  'modes of the measured responses')
    return {n: float(np.exp(v)) for n, v in zip(names, best[1])}, best[0]
