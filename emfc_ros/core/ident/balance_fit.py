"""
The grey-box identification of the balance, from a start found in the data to a verdict.

A start from the data, the free set the data determine, the time-domain fit, honest
uncertainties and an honest verdict.

Steps (issue 12; ``docs/identification.md`` section 5):

1. **Frequency domain** (:mod:`~emfc_ros.core.ident.balance_frf`): LPM responses of the position
   per setpoint-derived force on the dynamic sections; the stiffnesses, dampings, lever and
   coil-carrier inertias and coil mass solved from the modal features (resonances, coil
   anti-resonance, mass-line levels) from several starts, so the result does not depend on the
   configured values; then the weighted least-squares fit to the responses.
2. **Identifiability** (:mod:`~emfc_ros.core.ident.identifiability`): the Fisher information of
   that fit; parameters the data cannot separate are fixed at their configured values, and the
   combination is reported.
3. **Time domain** (the paper's grey-box fit, :func:`~emfc_ros.core.ident.greybox.fit_greybox`):
   simulation error of the nonlinear model over the sections, started from step 1, with the
   offset force parametrised by the rest position it gives (so a changed mass cannot push the
   simulated lever out of the sensor range), covariance by the frequency-domain sandwich
   (coloured noise).
4. **Derived numbers with uncertainty**: ``F_off_N``, the mass-matrix entries (the inertia
   combinations the data determine), the modes and coil anti-resonance of the fitted model, by
   first-order propagation of the covariance.
5. **Verdict**: failures (a section fit below :data:`FIT_FAILURE_PERCENT`, the optimiser that
   never left its start, a parameter at a bound, no usable start) and warnings (a fit below
   :data:`FIT_WARNING_PERCENT`, time- and frequency-domain estimates that disagree by more than
   :data:`CONSISTENCY_SIGMAS` combined standard uncertainties).
"""

from __future__ import annotations

from dataclasses import dataclass, field
import functools
import math
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from emfc_ros.core.ident import balance_frf
from emfc_ros.core.ident.balance_greybox import (BalanceGreyboxModel, MASS_COORDINATES,
                                                 mass_matrix_entries, MASS_MATRIX_NAMES,
                                                 REST_POSITION, unit_of, with_values)
from emfc_ros.core.ident.errors import IdentificationError
from emfc_ros.core.ident.greybox import fit_greybox, GreyboxResult, ParameterSpec
from emfc_ros.core.ident.identifiability import (choose_free, FreeSetChoice,
                                                 MAX_RELATIVE_UNCERTAINTY,
                                                 relative_jacobian_columns)
from emfc_ros.core.ident.noise_model import whitening_weights
from emfc_ros.core.ident.pattern_search import PatternSearchOptions
from emfc_ros.core.model.linear import linearise, LinearModel
from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.mechanics import mass_matrix
from emfc_ros.core.model.parameters import BalanceParameters

Progress = Callable[[str, float, str], None]

#: A section whose simulation-error fit is below this [%] makes the identification fail. A
#: right model reproduces every section of the shipped trajectory to better than 99 % at the
#: documented noise (``bench/bench_ident_offnominal.py``); 90 % means a residual of a tenth of
#: the signal, far outside what noise explains: the model is wrong or the fit is lost.
FIT_FAILURE_PERCENT = 90.0
#: Below this [%] a section fit is reported as a warning.
FIT_WARNING_PERCENT = 97.0
#: Time- and frequency-domain estimates further apart than this many combined standard
#: uncertainties are reported (model error: the two weigh the data differently).
CONSISTENCY_SIGMAS = 5.0
#: ``ftol``/``xtol`` of the time-domain fit. It starts next to the optimum (the frequency-domain
#: fit), so a relative cost change of 1e-6 (0.4 on a noise-weighted cost of about 4e5 on the
#: shipped trajectory) leaves the parameters within about 0.1 standard uncertainty of the
#: 1e-8 result (measured) at half the simulations.
TIME_DOMAIN_TOLERANCE = 1.0e-6
#: 99.9 % quantile of chi-square with 3 degrees of freedom: the identified mass matrix is
#: inconsistent with the configured masses when its three entries are further from the
#: configured ones than this (in units of the configured masses' relative uncertainty).
MASS_CONSISTENCY_CHI2 = 16.27
#: Chi-square difference within which two frequency-domain optima fit equally well.
AMBIGUITY_CHI2 = 4.0
#: Two optima further apart than this many standard uncertainties are different answers.
AMBIGUITY_SIGMAS = 3.0
#: A free parameter within this fraction of its scale from a bound counts as at the bound.
BOUND_TOLERANCE = 1.0e-6

#: Masses and inertias: the data determine the mass matrix, these are its coordinates.
INERTIA_NAMES = ('J1c_kgm2', 'm3_kg', 'J2c_kgm2', 'm1_kg', 'm2_kg', 'mp_kg',
                 'load_changer_mass_kg')
#: Parameters the frequency-domain stage can estimate (positive, dynamic).
DYNAMIC_NAMES = ('c1_Nm_per_rad', 'd1_Nms_per_rad', 'c2_Nm_per_rad', 'd2_Nms_per_rad') + \
    INERTIA_NAMES + MASS_MATRIX_NAMES


def configured_value(setting: 'Setting', name: str) -> float:
    """
    A parameter's configured value (mass-matrix entries from the configured masses).

    Parameters
    ----------
    setting : Setting
        The configuration.
    name : str
        A mechanical parameter or one of the mass-matrix entries.

    Returns
    -------
    float
        The value.
    """
    if name in MASS_MATRIX_NAMES:
        entries = mass_matrix_entries(setting.balance.mechanics, setting.load_mass_kg,
                                      setting.load_changer_coupled)
        return float(entries[MASS_MATRIX_NAMES.index(name)])
    return float(getattr(setting.balance.mechanics, name))


def internal_names(requested: Sequence[str]) -> List[str]:
    """
    The fit's free parameters: the three mass-matrix entries instead of their coordinates.

    Parameters
    ----------
    requested : sequence of str
        Free mechanical parameters as configured.

    Returns
    -------
    list of str
        The same, with ``J1c_kgm2``, ``m3_kg``, ``J2c_kgm2`` replaced by the entries
        ``M11_kgm2``, ``M12_kgm2``, ``M22_kgm2`` when all three are requested (the entries
        are what the data determine; each coordinate alone is a small part of its entry).
    """
    if not all(c in requested for c in MASS_COORDINATES):
        return list(requested)
    return [n for n in requested if n not in MASS_COORDINATES] + list(MASS_MATRIX_NAMES)


@dataclass(frozen=True)
class Derived:
    """
    A number computed from the fitted parameters, with its standard uncertainty.

    Attributes
    ----------
    value : float
        The value.
    standard_uncertainty : float
        First-order propagation of the fit's covariance.
    unit : str
        SI unit.
    """

    value: float
    standard_uncertainty: float
    unit: str


@dataclass
class BalanceGreyboxResult:
    """
    The grey-box fit of the balance model.

    Attributes
    ----------
    fit : GreyboxResult
        The time-domain fit: free parameters (``rest_position_m`` standing for ``F_off_N``),
        standard errors from the sandwich covariance, correlation, section fits, counts.
    initial : dict of str to float
        Start values of the free parameters (from the frequency-domain stage).
    linear_model : LinearModel
        Linearisation of the fitted model in the experiment's configuration.
    parameters : dict of str to float
        Every mechanical parameter of the fitted model (``F_off_N`` included).
    derived : dict of str to Derived
        ``F_off_N``, mass-matrix entries, modes and the coil anti-resonance with uncertainty.
    frequency_domain : FrfFit or None
        The frequency-domain fit (start and cross-check).
    identifiability : FreeSetChoice or None
        Fisher-information analysis and what it fixed.
    sources : dict of str to str
        Where every mechanical parameter's value comes from.
    time_s : dict of str to ndarray
        Per section: time from the section start [s].
    measured_m, simulated_m : dict of str to ndarray
        Per section: measured and simulated position [m].
    """

    fit: GreyboxResult
    initial: Dict[str, float]
    linear_model: LinearModel
    parameters: Dict[str, float] = field(default_factory=dict)
    derived: Dict[str, Derived] = field(default_factory=dict)
    frequency_domain: Optional[balance_frf.FrfFit] = None
    identifiability: Optional[FreeSetChoice] = None
    sources: Dict[str, str] = field(default_factory=dict)
    time_s: Dict[str, np.ndarray] = field(default_factory=dict)
    measured_m: Dict[str, np.ndarray] = field(default_factory=dict)
    simulated_m: Dict[str, np.ndarray] = field(default_factory=dict)


@dataclass
class Verdict:
    """
    What went wrong (failures) and what the user should know (warnings).

    Attributes
    ----------
    failures, warnings : list of str
        Messages, each starting with ``greybox:``.
    """

    failures: List[str] = field(default_factory=list)
    warnings: List[str] = field(default_factory=list)


@dataclass(frozen=True)
class Setting:
    """
    The experiment's configuration for the fit.

    Attributes
    ----------
    balance : BalanceParameters
        Configured balance (characteristics, fixed masses, lengths, start values).
    load_mass_kg : float
        Mass on the pan [kg].
    load_changer_coupled : bool
        Whether the load changer's moving mass rode on the pan.
    sample_rate_Hz : float
        Sample rate [Hz].
    """

    balance: BalanceParameters
    load_mass_kg: float
    load_changer_coupled: bool
    sample_rate_Hz: float


def frequency_domain_stage(setting: Setting, channels: Mapping[str, np.ndarray],
                           jobs: Sequence[Tuple[str, int, int, Sequence[str]]],
                           modes: Sequence[Tuple[float, float, float]],
                           anti_resonance: Optional[Tuple[float, float, float]],
                           names: Sequence[str], band_Hz: Tuple[float, float], hold: str,
                           verdict: Verdict, report: Progress,
                           threshold: float = MAX_RELATIVE_UNCERTAINTY
                           ) -> Tuple[Dict[str, float], Optional[balance_frf.FrfFit],
                                      Optional[FreeSetChoice]]:
    """
    Start values, free set and frequency-domain estimate of the dynamic parameters.

    Parameters
    ----------
    setting : Setting
        The configuration.
    channels : mapping of str to ndarray
        The recording.
    jobs : sequence of (name, first, n, inputs)
        Dynamic sections and their excited inputs.
    modes : sequence of (float, float, float)
        Low and high mode ``(frequency_Hz, damping_ratio, frequency_std_Hz)`` (may be empty).
    anti_resonance : (float, float, float) or None
        Coil anti-resonance.
    names : sequence of str
        Requested free dynamic parameters.
    band_Hz : (float, float)
        Frequency band [Hz].
    hold : str
        DAC hold to remove.
    verdict : Verdict
        Collects warnings.
    report : callable
        Progress.
    threshold : float
        Largest relative standard uncertainty of a direction the data determine: the
        configured masses' own uncertainty, so that the data replace a mass only where they
        know it better than the configuration does.

    Returns
    -------
    start : dict of str to float
        Values of the dynamic parameters for the time-domain fit (configured where the data
        say nothing).
    fit : FrfFit or None
        The frequency-domain fit.
    choice : FreeSetChoice or None
        The identifiability analysis (None without responses).
    """
    configured = {n: configured_value(setting, n) for n in names}
    frfs = balance_frf.measure_frfs(channels, setting.sample_rate_Hz, jobs, setting.balance,
                                    frequency_min_Hz=band_Hz[0], frequency_max_Hz=band_Hz[1],
                                    hold=hold)
    if not frfs:
        verdict.warnings.append('greybox: no dynamic section gives a frequency response; the '
                                'mechanics start from their configured values')
        return configured, None, None
    model = balance_frf.MechanicsFrfModel(setting.balance, setting.load_mass_kg,
                                          setting.load_changer_coupled)
    positive = [n for n in names if configured[n] > 0.0]
    start = dict(configured)
    if len(modes) >= 2 and positive:
        report('greybox', 0.02, 'start from the modal features of the responses')
        feats = balance_frf.measured_features(frfs, modes, anti_resonance)
        try:
            solved, _ = balance_frf.feature_start(model, frfs, feats, positive, configured)
            start.update(solved)
        except IdentificationError as exc:
            verdict.warnings.append(f'greybox: {exc}; starting from the configured values')
    else:
        verdict.warnings.append('greybox: the responses show fewer than two modes; the '
                                'frequency-domain fit starts from the configured values')

    # Identifiability at the start (the feature start keeps directions the features do not
    # determine at their configured values), in variables relative to the configured values.
    def jacobian_of(free: Sequence[str]) -> np.ndarray:
        return relative_jacobian_columns(
            lambda v: balance_frf.weighted_residuals(model, frfs, v), start, free)

    # Only masses and inertias are fixed when the data do not determine them (the configured
    # masses are prior knowledge); a poorly determined stiffness or damping stays free and
    # its uncertainty says so (the time-domain fit also sees below the responses' band).
    masses = [n for n in positive if n in INERTIA_NAMES + MASS_MATRIX_NAMES]
    choice = choose_free(jacobian_of, positive, configured, may_fix=masses,
                         max_relative_uncertainty=threshold,
                         prefer_fix=INERTIA_NAMES + MASS_MATRIX_NAMES)
    partly = [n for n in MASS_MATRIX_NAMES if n in choice.fixed]
    if partly and any(n in choice.free for n in MASS_MATRIX_NAMES):
        # The mass matrix is identified as a whole or taken from the configured masses: with
        # one entry fixed the others bend the stiffnesses along a curved valley (measured on
        # a 5 s coil chirp: c2 24 % off at 4 of its standard uncertainties).
        reason = (f'fixed with {partly[0]}: the data do not determine the whole mass matrix '
                  f'({choice.fixed[partly[0]]})')
        rest = [n for n in positive if n not in MASS_MATRIX_NAMES]
        again = choose_free(jacobian_of, rest, configured,
                            may_fix=[n for n in rest if n in masses],
                            max_relative_uncertainty=threshold)
        fixed = dict(choice.fixed)
        fixed.update({n: reason for n in MASS_MATRIX_NAMES if n not in fixed})
        fixed.update(again.fixed)
        choice = FreeSetChoice(again.free, fixed, again.analysis, choice.initial_analysis)
    if not choice.free:
        return configured, None, choice
    fixed_now = {n: configured[n] for n in choice.fixed}
    at = dict(start, **fixed_now)
    report('greybox', 0.05, f'frequency-domain fit of {list(choice.free)}')
    fit = balance_frf.fit_frfs(model, frfs, at, choice.free,
                               upper={n: 1e3 * configured[n] for n in choice.free})
    fit = probe_ambiguity(model, frfs, fit, at, configured, verdict, report)
    out = dict(at, **fixed_now)
    out.update(fit.values)
    return out, fit, choice


def probe_ambiguity(model: balance_frf.MechanicsFrfModel, frfs: Sequence[Any],
                    fit: balance_frf.FrfFit, values: Dict[str, float],
                    configured: Mapping[str, float], verdict: Verdict, report: Progress
                    ) -> balance_frf.FrfFit:
    """
    Look for a second optimum along the least determined directions.

    A collocated response alone (e.g. a coil chirp without a pan-force section) can fit two
    different parameter sets equally well (measured: c2 +24 % with the same chi-square as the
    truth). The frequency-domain fit is restarted from points moved along the two least
    determined directions of its covariance (by 20 % or five standard uncertainties, whichever
    is larger, in relative units); an optimum that fits as well (chi-square within
    :data:`AMBIGUITY_CHI2`) but lies more than :data:`AMBIGUITY_SIGMAS` standard uncertainties
    away is a failure; one that fits clearly better replaces the first.

    Parameters
    ----------
    model : MechanicsFrfModel
        The model.
    frfs : sequence of MeasuredFrf
        The data.
    fit : FrfFit
        The fit.
    values : dict of str to float
        All parameter values the fit started from (fixed ones included).
    configured : mapping of str to float
        Configured values (bounds).
    verdict : Verdict
        Collects the failure.
    report : callable
        Progress.

    Returns
    -------
    FrfFit
        The best fit found.
    """
    names = list(fit.names)
    x = np.array([fit.values[n] for n in names])
    se = np.sqrt(np.maximum(np.diag(fit.covariance), 0.0))
    rel_cov = fit.covariance / np.outer(x, x)
    w, v = np.linalg.eigh(rel_cov)
    dof = max(fit.n_lines * 2 - len(names), 1)
    cost = fit.chi2_reduced * dof
    upper = {n: 1e3 * configured[n] for n in names}
    best = fit
    for k in range(1, min(2, len(names)) + 1):
        direction = v[:, -k]
        step = max(0.2, 5.0 * math.sqrt(max(w[-k], 0.0)))
        for sign in (1.0, -1.0):
            moved = x * np.exp(np.clip(sign * step * direction, -1.0, 1.0))
            start = dict(values, **dict(zip(names, moved)))
            report('greybox', 0.07, 'frequency-domain fit from a second start')
            try:
                other = balance_frf.fit_frfs(model, frfs, start, names, upper=upper)
            except (IdentificationError, ValueError, np.linalg.LinAlgError):
                continue
            other_cost = other.chi2_reduced * dof
            y = np.array([other.values[n] for n in names])
            apart = float(np.max(np.abs(y - x) / np.where(se > 0.0, se, np.inf)))
            if other_cost < cost - AMBIGUITY_CHI2:
                best, cost, x = other, other_cost, y
            elif other_cost <= cost + AMBIGUITY_CHI2 and apart > AMBIGUITY_SIGMAS:
                shown = ', '.join(f'{n} {a:.4g} or {b:.4g}' for n, a, b in zip(names, x, y)
                                  if abs(b - a) > AMBIGUITY_SIGMAS * se[names.index(n)])
                verdict.failures.append(
                    f'greybox: the data fit two parameter sets equally well ({shown}; '
                    f'chi-square {cost:.1f} and {other_cost:.1f}): this experiment cannot '
                    f'tell them apart; add a pan-force section or fix the masses '
                    f'(greybox.free without J1c_kgm2, m3_kg, J2c_kgm2)')
                return best
    return best


def offset_start(model: BalanceGreyboxModel, values: Dict[str, float],
                 position_m: np.ndarray, sections: Sequence[Any]) -> float:
    """
    Rest position that makes the simulated sections' mean equal the measured one.

    A constant force shifts the whole response by the same amount, so one simulation from the
    measured start position gives the correction.

    Parameters
    ----------
    model : BalanceGreyboxModel
        The model.
    values : dict of str to float
        Parameters without the offset.
    position_m : ndarray
        Measured position of the record [m].
    sections : sequence of DataSection
        The fitted sections.

    Returns
    -------
    float
        The rest position [m].
    """
    y0 = float(np.median(position_m[:max(min(20, position_m.size), 1)]))
    sim = model.simulate_record(dict(values, **{REST_POSITION: y0}))
    shift = float(np.mean([np.mean(sec.outputs - sim[model.offset(sec.inputs):][
        :len(sec.outputs)]) for sec in sections]))
    return y0 + shift


def noise_weights(model: BalanceGreyboxModel, values: Dict[str, float],
                  data: Sequence[Any], setting: Setting
                  ) -> Tuple[List[np.ndarray], List[np.ndarray]]:
    """
    Whitening weights and transient bases per section from the output error at the start.

    The noise model's shapes are the start model's ``|H_coil|^2`` and ``|H_pan|^2``
    (:mod:`~emfc_ros.core.ident.noise_model`); the transient basis is
    ``C (z_k I - A_d)^-1 z_k`` of the start model discretised at the sample rate (the leakage
    of process noise through the mechanics, see :func:`~emfc_ros.core.ident.greybox.fit_greybox`).

    Parameters
    ----------
    model : BalanceGreyboxModel
        The time-domain model.
    values : dict of str to float
        Start values (free parameters and the rest position).
    data : sequence of DataSection
        The sections.
    setting : Setting
        The configuration.

    Returns
    -------
    weights : list of ndarray
        One weight array per section (``n // 2 + 1`` lines).
    transients : list of ndarray
        One complex basis of shape (``n // 2 + 1``, 4) per section.
    """
    from scipy import linalg as sla

    record = model.simulate_record(values)
    lin = linearise(loaded(model.balance(values).mechanics, setting.load_mass_kg,
                           setting.load_changer_coupled))
    a_d = sla.expm(lin.A / setting.sample_rate_Hz)
    eye = np.eye(a_d.shape[0])
    weights, bases = [], []
    for sec in data:
        n = len(sec.outputs)
        first = model.offset(sec.inputs)
        f = np.fft.rfftfreq(n, 1.0 / setting.sample_rate_Hz)
        shapes = [np.abs(lin.frequency_response(f, inp).response_m_per_N) ** 2
                  for inp in ('coil', 'pan')]
        weights.append(whitening_weights(sec.outputs - record[first:first + n], shapes))
        z = np.exp(2j * np.pi * np.arange(f.size) / n)
        # rows C (z I - A)^-1 z: solve (z I - A)^T v = C^T per line
        lhs = np.transpose(z[:, None, None] * eye[None] - a_d[None], (0, 2, 1))
        rhs = np.broadcast_to(lin.C[0].astype(complex), (f.size, eye.shape[0]))[..., None]
        bases.append(np.linalg.solve(lhs, rhs)[..., 0] * z[:, None])
    return weights, bases


def time_domain_specs(start: Mapping[str, float], free: Sequence[str],
                      relative_bounds: Tuple[float, float], rest_position_m: Optional[float]
                      ) -> List[ParameterSpec]:
    """
    Parameter specs of the time-domain fit.

    Parameters
    ----------
    start : mapping of str to float
        Start values.
    free : sequence of str
        Free mechanical parameters (not ``F_off_N``).
    relative_bounds : (float, float)
        Bounds of stiffnesses and dampings as multiples of the start; masses and inertias go
        from 0 to the upper multiple.
    rest_position_m : float or None
        Start of the offset's stand-in (None: the offset is not fitted).

    Returns
    -------
    list of ParameterSpec
        The specs.
    """
    specs = []
    for n in free:
        v = float(start[n])
        lo = 0.0 if n in INERTIA_NAMES and n not in MASS_COORDINATES \
            else relative_bounds[0] * v
        specs.append(ParameterSpec(n, v, lo, relative_bounds[1] * v, True, abs(v) or 1.0,
                                   unit_of(n)))
    if rest_position_m is not None:
        specs.append(ParameterSpec(REST_POSITION, float(rest_position_m), -1.0e-3, 1.0e-3,
                                   True, 1.0e-6, 'm'))
    return specs


def propagate(fun: Callable[[Dict[str, float]], np.ndarray], values: Dict[str, float],
              names: Sequence[str], covariance: np.ndarray, steps: Mapping[str, float]
              ) -> Tuple[np.ndarray, np.ndarray]:
    """
    Value and standard uncertainty of a vector function by first-order propagation.

    Parameters
    ----------
    fun : callable
        ``fun(values) -> ndarray``.
    values : dict of str to float
        The estimate.
    names : sequence of str
        Free parameters (covariance order).
    covariance : ndarray
        Their covariance.
    steps : mapping of str to float
        Finite-difference step per parameter.

    Returns
    -------
    value, std : ndarray
        ``fun(values)`` and the standard uncertainties.
    """
    f0 = np.asarray(fun(values), dtype=float)
    grads = []
    for n in names:
        h = float(steps[n])
        up = np.asarray(fun(dict(values, **{n: values[n] + h})), dtype=float)
        down = np.asarray(fun(dict(values, **{n: values[n] - h})), dtype=float)
        grads.append((up - down) / (2.0 * h))
    g = np.column_stack(grads) if grads else np.zeros((f0.size, 0))
    cov = np.asarray(covariance, dtype=float)
    if not np.all(np.isfinite(cov)):
        return f0, np.full(f0.size, np.nan)
    var = np.einsum('ij,jk,ik->i', g, cov, g)
    return f0, np.sqrt(np.maximum(var, 0.0))


def modal_summary(lin: LinearModel) -> np.ndarray:
    """
    Low and high mode frequency and damping, coil anti-resonance frequency and damping.

    Parameters
    ----------
    lin : LinearModel
        The linearised model.

    Returns
    -------
    ndarray, shape (6,)
        ``[f1_Hz, zeta1, f2_Hz, zeta2, fa_Hz, zeta_a]`` (NaN where absent).
    """
    poles = sorted((p.frequency_Hz, p.damping_ratio) for p in lin.poles()
                   if p.s_rad_per_s.imag > 0.0)
    zeros = sorted((z.frequency_Hz, z.damping_ratio) for z in lin.zeros('coil')
                   if z.s_rad_per_s.imag > 0.0)
    out = np.full(6, np.nan)
    if len(poles) >= 2:
        out[:4] = [poles[0][0], poles[0][1], poles[-1][0], poles[-1][1]]
    if zeros:
        out[4:] = zeros[-1]
    return out


MODE_KEYS = (('low_mode_frequency_Hz', 'Hz'), ('low_mode_damping_ratio', ''),
             ('high_mode_frequency_Hz', 'Hz'), ('high_mode_damping_ratio', ''),
             ('coil_anti_resonance_frequency_Hz', 'Hz'), ('coil_anti_resonance_damping_ratio', ''))
MASS_KEYS = (('mass_matrix_11_kgm2', 'kg m^2'), ('mass_matrix_12_kgm2', 'kg m^2'),
             ('mass_matrix_22_kgm2', 'kg m^2'))


def derived_quantities(model: BalanceGreyboxModel, fit: GreyboxResult,
                       setting: Setting) -> Dict[str, Derived]:
    """
    ``F_off_N``, mass-matrix entries, modes and anti-resonance with uncertainties.

    Parameters
    ----------
    model : BalanceGreyboxModel
        The time-domain model.
    fit : GreyboxResult
        The fit.
    setting : Setting
        The configuration.

    Returns
    -------
    dict of str to Derived
        By name (units in the names).
    """
    names = list(fit.free_names)
    values = {n: fit.parameters[n] for n in names}
    steps = {n: 1e-5 * (abs(values[n]) or 1.0) if n != REST_POSITION else 1e-9 for n in names}
    cov = fit.covariance if fit.covariance is not None else np.full((len(names),) * 2, np.nan)

    def mechanics(v: Dict[str, float]) -> Any:
        return loaded(model.balance(v).mechanics, setting.load_mass_kg,
                      setting.load_changer_coupled)

    def numbers(v: Dict[str, float]) -> np.ndarray:
        own = model.balance(v).mechanics
        mech = mechanics(v)
        m = mass_matrix(np.zeros(2), mech)
        return np.concatenate(([own.F_off_N, m[0, 0], m[0, 1], m[1, 1]],
                               [getattr(own, n) for n in MASS_COORDINATES],
                               modal_summary(linearise(mech))))

    value, std = propagate(numbers, values, names, cov, steps)
    keys = (('F_off_N', 'N'),) + MASS_KEYS + tuple((n, unit_of(n)) for n in MASS_COORDINATES) \
        + MODE_KEYS
    return {k: Derived(float(v), float(s), u) for (k, u), v, s in zip(keys, value, std)
            if math.isfinite(v)}


def check(fit: GreyboxResult, specs: Sequence[ParameterSpec], fd: Optional[Any],
          verdict: Verdict) -> None:
    """
    Add the failures and warnings of a time-domain fit to a verdict.

    Parameters
    ----------
    fit : GreyboxResult
        The time-domain fit.
    specs : sequence of ParameterSpec
        Its parameter specs (bounds).
    fd : FrfFit or None
        The frequency-domain fit for the consistency check.
    verdict : Verdict
        Collects the messages.
    """
    for sec in fit.sections:
        worst = float(np.min(sec.fit_percent))
        if worst < FIT_FAILURE_PERCENT:
            verdict.failures.append(f'greybox: section {sec.name!r} fits only {worst:.1f} % '
                                    f'(a usable model fits at least {FIT_FAILURE_PERCENT:g} %)')
        elif worst < FIT_WARNING_PERCENT:
            verdict.warnings.append(f'greybox: section {sec.name!r} fits only {worst:.2f} %')
    if not fit.moved():
        verdict.failures.append('greybox: the optimiser never left its start '
                                f'({fit.exit_reason})')
    elif not fit.success:
        verdict.failures.append(f'greybox: the optimiser did not converge ({fit.exit_reason})')
    for spec in specs:
        v = fit.parameters[spec.name]
        tol = BOUND_TOLERANCE * spec.resolved_scale()
        if v - spec.lower <= tol or spec.upper - v <= tol:
            verdict.failures.append(f'greybox: {spec.name} = {v:.6g} {spec.unit} ended at its '
                                    f'bound [{spec.lower:.6g}, {spec.upper:.6g}]: the model '
                                    f'cannot reproduce the data inside its range')
    if fd is None:
        return
    se_fd = fd.standard_errors()
    for n in fd.names:
        if n not in fit.free_names:
            continue
        a, b = fit.parameters[n], fd.values[n]
        s = math.hypot(fit.standard_errors.get(n, 0.0), se_fd[n])
        if s > 0.0 and abs(a - b) > CONSISTENCY_SIGMAS * s:
            verdict.warnings.append(
                f'greybox: {n} from the time domain ({a:.6g}) and the frequency domain '
                f'({b:.6g}) differ by {abs(a - b) / s:.1f} combined standard uncertainties: '
                f'model error (characteristics, nonlinearity) weighs on the estimate')


def check_masses(derived: Mapping[str, Derived], setting: Setting, relative_uncertainty: float,
                 verdict: Verdict) -> None:
    """
    Fail when the identified mass matrix contradicts the configured masses.

    The data fix the mass matrix only up to the scale of the sensor and actuator
    characteristics (a sensor sensitivity 10 % off scales every stiffness, damping and
    inertia by 1/1.1 and fits as well). The configured masses, known to
    ``relative_uncertainty``, are the check: ``sum ((M_id - M_cfg) / (u M_cfg))^2`` over the
    three entries above :data:`MASS_CONSISTENCY_CHI2` is a failure.

    Parameters
    ----------
    derived : mapping of str to Derived
        With the ``mass_matrix_*`` entries.
    setting : Setting
        The configured balance and load.
    relative_uncertainty : float
        Relative standard uncertainty of the configured mass-matrix entries (0 disables).
    verdict : Verdict
        Collects the failure.
    """
    if not relative_uncertainty > 0.0 or not all(k in derived for k, _ in MASS_KEYS):
        return
    m = mass_matrix(np.zeros(2), loaded(setting.balance.mechanics, setting.load_mass_kg,
                                        setting.load_changer_coupled))
    configured = (m[0, 0], m[0, 1], m[1, 1])
    rel = [derived[k].value / c - 1.0 for (k, _), c in zip(MASS_KEYS, configured) if c != 0.0]
    chi2 = float(sum((r / relative_uncertainty) ** 2 for r in rel))
    if chi2 > MASS_CONSISTENCY_CHI2:
        shown = ', '.join(f'{100 * r:+.1f} %' for r in rel)
        verdict.failures.append(
            f'greybox: the identified mass matrix differs from the configured masses by '
            f'{shown} (chi-square {chi2:.1f} with the masses known to '
            f'{100 * relative_uncertainty:g} %): a sensor or actuator characteristic is off '
            f'(every stiffness, damping and inertia scales with it), or the configured masses '
            f'are; set greybox.mass_relative_uncertainty if the masses are known worse')


def _fail_closed(fit: Callable[..., Tuple[Optional[BalanceGreyboxResult], Verdict]]
                 ) -> Callable[..., Tuple[Optional[BalanceGreyboxResult], Verdict]]:
    """Turn an error raised by the numbers (data the model cannot follow) into a failure."""
    @functools.wraps(fit)
    def wrapped(*args: Any, **kwargs: Any) -> Tuple[Optional[BalanceGreyboxResult], Verdict]:
        try:
            return fit(*args, **kwargs)
        except (IdentificationError, ValueError, RuntimeError, ArithmeticError,
                np.linalg.LinAlgError) as exc:
            verdict = Verdict()
            verdict.failures.append(f'greybox: the fit could not run on these data: {exc}')
            return None, verdict

    return wrapped


@_fail_closed
def fit_balance(setting: Setting, channels: Mapping[str, np.ndarray],
                sections: Sequence[Tuple[str, int, int]],
                frf_jobs: Sequence[Tuple[str, int, int, Sequence[str]]],
                modes: Sequence[Tuple[float, float, float]],
                anti_resonance: Optional[Tuple[float, float, float]], gcfg: Any,
                band_Hz: Tuple[float, float], hold: str, report: Progress
                ) -> Tuple[Optional[BalanceGreyboxResult], Verdict]:
    """
    The whole grey-box identification (see the module docstring).

    Parameters
    ----------
    setting : Setting
        The configuration (``setting.balance`` already holds ``greybox.initial``).
    channels : mapping of str to ndarray
        The recording.
    sections : sequence of (name, first_sample_index, n_samples)
        Sections of the time-domain fit.
    frf_jobs : sequence of (name, first, n, inputs)
        Sections for the frequency-domain stage.
    modes, anti_resonance
        Modal features from the transfer-function fits (see :func:`frequency_domain_stage`).
    gcfg : GreyboxConfig
        The grey-box options.
    band_Hz : (float, float)
        Frequency band [Hz].
    hold : str
        DAC hold.
    report : callable
        Progress.

    Returns
    -------
    result : BalanceGreyboxResult or None
        None when the fit could not run (the verdict says why).
    verdict : Verdict
        Failures and warnings.
    """
    verdict = Verdict()
    mech = setting.balance.mechanics
    requested = internal_names([n for n in gcfg.free if n != 'F_off_N'])
    fit_offset = 'F_off_N' in gcfg.free
    fixed_by_user = set(gcfg.initial)
    sources = {n: 'configuration (balance)' for n in mech.__dataclass_fields__}
    for n in fixed_by_user:
        sources[n] = 'options (greybox.initial)'
    dynamic = [n for n in requested if n in DYNAMIC_NAMES]
    start = {n: configured_value(setting, n) for n in requested}
    fd, choice = None, None
    if gcfg.initialise_from_frf and dynamic:
        threshold = min(MAX_RELATIVE_UNCERTAINTY, gcfg.mass_relative_uncertainty or
                        MAX_RELATIVE_UNCERTAINTY)
        solved, fd, choice = frequency_domain_stage(setting, channels, frf_jobs, modes,
                                                    anti_resonance, dynamic, band_Hz, hold,
                                                    verdict, report, threshold)
        start.update(solved)
    free = [n for n in requested if choice is None or n not in choice.fixed]
    if choice is not None:
        for n, reason in choice.fixed.items():
            sources[n] = f'configuration (balance): {reason}'
            verdict.warnings.append(f'greybox: {n} fixed at its configured value '
                                    f'{start[n]:.6g} {unit_of(n)}: {reason}')
    if not free and not fit_offset:
        verdict.failures.append('greybox: no parameter the data determine is left free')
        return None, verdict
    n_end = max(first + n for _, first, n in sections)
    setpoints = np.column_stack([channels['coil_setpoint_V'][:n_end],
                                 channels['load_changer_setpoint_V'][:n_end]])
    balance = with_values(setting.balance, {k: v for k, v in start.items() if k not in free},
                          setting.load_mass_kg, setting.load_changer_coupled)
    model = BalanceGreyboxModel(balance, setting.sample_rate_Hz, setpoints,
                                setting.load_mass_kg, setting.load_changer_coupled)
    data = model.sections(channels['position_m'], sections)
    rest = None
    if fit_offset:
        rest = offset_start(model, {n: start[n] for n in free}, channels['position_m'], data)
    specs = time_domain_specs(start, free, gcfg.relative_bounds, rest)
    budget = gcfg.max_evaluations or (100 * (len(specs) + 1) if gcfg.method == 'least_squares'
                                      else 2000 * len(specs))

    def simulate(values: Dict[str, float], inputs: np.ndarray) -> np.ndarray:
        before = model.n_simulations
        out = model.simulate(values, inputs)
        if model.n_simulations != before and model.n_simulations % 5 == 0:
            report('greybox', min(0.1 + 0.9 * model.n_simulations / budget, 0.99),
                   f'{model.n_simulations} simulations')
        return out

    report('greybox', 0.1, f'time-domain fit of {[s.name for s in specs]} with {gcfg.method}')
    options, max_nfev = None, gcfg.max_evaluations or None
    if gcfg.method == 'pattern_search':
        options = PatternSearchOptions(initial_mesh_size=gcfg.pattern_search_initial_mesh_size,
                                       max_function_evaluations=gcfg.max_evaluations or None)
        max_nfev = None
    weights, transients = None, None
    if gcfg.noise_weighting:
        weights, transients = noise_weights(model, {s.name: s.initial for s in specs}, data,
                                            setting)
    try:
        fit = fit_greybox(simulate, data, specs, method=gcfg.method, options=options,
                          max_nfev=max_nfev, noise_weights=weights, transients=transients,
                          tolerance=TIME_DOMAIN_TOLERANCE)
    except (IdentificationError, ValueError, RuntimeError) as exc:
        verdict.failures.append(f'greybox: {exc}')
        return None, verdict
    check(fit, specs, fd, verdict)
    derived = derived_quantities(model, fit, setting)
    check_masses(derived, setting, gcfg.mass_relative_uncertainty, verdict)
    for n in free:
        sources[n] = 'identified (time-domain fit)'
    if all(n in free for n in MASS_MATRIX_NAMES):
        for n in MASS_COORDINATES:
            sources[n] = 'identified (time-domain fit, through the mass-matrix entries)'
    fitted = model.balance(fit.parameters)
    if fit_offset:
        sources['F_off_N'] = 'identified (time-domain fit, through the rest position)'
    parameters = {n: float(getattr(fitted.mechanics, n))
                  for n in fitted.mechanics.__dataclass_fields__}
    lin = linearise(loaded(fitted.mechanics, setting.load_mass_kg,
                           setting.load_changer_coupled))
    out = BalanceGreyboxResult(fit, {s.name: s.initial for s in specs}, lin, parameters,
                               derived, fd, choice, sources)
    record = model.simulate_record(fit.parameters)
    fs = setting.sample_rate_Hz
    for name, first, n in sections:
        sl = slice(first, first + n)
        out.time_s[name] = np.arange(n) / fs
        out.measured_m[name] = np.asarray(channels['position_m'][sl])
        out.simulated_m[name] = record[sl]
    return out, verdict


#: What each mass-matrix coordinate is identified together with (the data see only the entries).
CONDITIONAL = {
    'J1c_kgm2': 'identified through M11 = J1c + m1 (r1^2 + h1^2) + (mp + pan load + coupled '
                'load changer) l1^2 + (m2 + m3) l2^2: right only if the fixed masses and the '
                'pan load are',
    'm3_kg': 'identified through M12 = l2 (m3 l3 + m2 r2) and M22: right only if m2, r2 and '
             'the lengths are',
    'J2c_kgm2': 'identified through M22 = J2c + m2 (r2^2 + h2^2) + m3 l3^2: right only if m2 '
                'and the lengths are',
    'F_off_N': 'tied to the weights of the identified masses (the static moment balance)',
}


def parameter_table(g: BalanceGreyboxResult) -> List[Dict[str, Any]]:
    """
    Every mechanical parameter of the fitted model: identified or fixed, value and source.

    Parameters
    ----------
    g : BalanceGreyboxResult
        The result.

    Returns
    -------
    list of dict
        ``name, value, unit, status, source, standard_uncertainty`` (None when fixed), and a
        ``note`` for identified parameters that hold only together with fixed ones.
    """
    rows = []
    for name, value in g.parameters.items():
        through = {'F_off_N': (REST_POSITION,)}
        through.update({n: MASS_MATRIX_NAMES for n in MASS_COORDINATES})
        identified = name in g.fit.free_names or (
            name in through and all(t in g.fit.free_names for t in through[name]))
        if identified and name in through and name in g.derived:
            se: Optional[float] = g.derived[name].standard_uncertainty
        else:
            se = g.fit.standard_errors.get(name) if identified else None
        row = {'name': name, 'value': value, 'unit': unit_of(name),
               'status': 'identified' if identified else 'fixed',
               'source': g.sources.get(name, 'configuration (balance)'),
               'standard_uncertainty': se}
        if identified and name in CONDITIONAL:
            row['note'] = CONDITIONAL[name]
        rows.append(row)
    return rows


def root_dict(root: Any) -> dict:
    """
    A pole or zero as plain data.

    Parameters
    ----------
    root : Root
        The root.

    Returns
    -------
    dict
        Real and imaginary part [rad/s], frequency [Hz] (signed for real roots), damping.
    """
    return {'real_rad_per_s': float(root.s_rad_per_s.real),
            'imag_rad_per_s': float(abs(root.s_rad_per_s.imag)),
            'frequency_Hz': root.frequency_Hz, 'signed_frequency_Hz': root.signed_frequency_Hz,
            'damping_ratio': root.damping_ratio}


def greybox_dict(g: Optional[BalanceGreyboxResult]) -> Optional[dict]:
    """
    The grey-box result as plain data (units in the keys or next to the values).

    Parameters
    ----------
    g : BalanceGreyboxResult or None
        The result.

    Returns
    -------
    dict or None
        Fit, free parameters with standard uncertainties, derived quantities, identifiability,
        the frequency-domain fit, section fits and the linearised model.
    """
    if g is None:
        return None
    fit = g.fit
    free = list(fit.free_names)
    params = {name: {'value': fit.parameters[name],
                     'standard_error': fit.standard_errors[name],
                     'initial': g.initial.get(name), 'unit': unit_of(name)}
              for name in free}
    if 'F_off_N' in g.derived and REST_POSITION in free:
        d = g.derived['F_off_N']
        params['F_off_N'] = {'value': d.value, 'standard_error': d.standard_uncertainty,
                             'initial': None, 'unit': 'N',
                             'note': f'from {REST_POSITION} through the static equilibrium'}
    lin = g.linear_model
    fd = g.frequency_domain
    choice = g.identifiability
    out = {
        'method': fit.method, 'success': fit.success, 'exit_reason': fit.exit_reason,
        'cost': fit.cost, 'optimizer_evaluations': fit.optimizer_evaluations,
        'n_evaluations': fit.n_evaluations, 'time_s': fit.time_s,
        'covariance_method': fit.covariance_method,
        'parameters': params,
        'derived': {k: {'value': v.value, 'standard_uncertainty': v.standard_uncertainty,
                        'unit': v.unit} for k, v in g.derived.items()},
        'correlation': {'names': free, 'matrix': np.asarray(fit.correlation).tolist()},
        'sections': [{'name': s.name, 'fit_percent': float(np.min(s.fit_percent)),
                      'rms_error_m': float(np.max(s.rms_error)),
                      'whiteness_fraction': s.whiteness_fraction,
                      'input_correlation_fraction': s.input_correlation_fraction}
                     for s in fit.sections],
        'linearised_model': {
            'poles': [root_dict(p) for p in lin.poles()],
            'zeros_coil': [root_dict(z) for z in lin.zeros('coil')],
            'zeros_pan': [root_dict(z) for z in lin.zeros('pan')],
            'static_gain_coil_m_per_N': lin.static_gain_m_per_N('coil'),
            'static_gain_pan_m_per_N': lin.static_gain_m_per_N('pan'),
        },
        'frequency_domain_fit': None if fd is None else {
            'parameters': {n: {'value': fd.values[n], 'standard_error': se, 'unit': unit_of(n)}
                           for n, se in fd.standard_errors().items()},
            'chi2_reduced': fd.chi2_reduced, 'n_lines': fd.n_lines, 'success': fd.success},
        'identifiability': None if choice is None else {
            'requested': choice.initial_analysis.to_dict(),
            'free': choice.analysis.to_dict(),
            'fixed': dict(choice.fixed)},
    }
    return out
