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
5. **Verdict** (:mod:`~emfc_ros.core.ident.balance_verdict`): failures (a section fit below
   its threshold, the optimiser that never left its start, a parameter at a bound, a mass
   matrix that contradicts the configured masses, two answers that fit equally well, data the
   fit cannot run on) and warnings.

The result types and their plain-data form are in :mod:`~emfc_ros.core.ident.balance_result`,
the derived numbers in :mod:`~emfc_ros.core.ident.balance_derived`.
"""

from __future__ import annotations

from concurrent.futures import Future
import dataclasses
import functools
import math
import os
from typing import Any, Callable, Dict, List, Mapping, Optional, Protocol, Sequence, Tuple

import numpy as np

from emfc_ros.core.blas_threads import with_single_blas_thread
from emfc_ros.core.ident import balance_frf
from emfc_ros.core.ident.balance_derived import derived_quantities
from emfc_ros.core.ident.balance_greybox import (BalanceGreyboxModel, MASS_COORDINATES,
                                                 mass_matrix_entries, MASS_MATRIX_NAMES,
                                                 PAN_FORCE_SCALE, REST_POSITION, unit_of,
                                                 with_values)
from emfc_ros.core.ident.balance_result import (BalanceGreyboxResult, characteristic_source,
                                                Setting, Verdict)
from emfc_ros.core.ident.balance_verdict import (check, check_masses, check_uncertainties,
                                                 POOR_RELATIVE_UNCERTAINTY)
from emfc_ros.core.ident.errors import IdentificationError
from emfc_ros.core.ident.greybox import (fit_greybox, ParameterSpec, prewhitened,
                                         weighted_transient_basis)
from emfc_ros.core.ident.identifiability import (analyse_covariance, choose_free,
                                                 FreeSetChoice, MAX_RELATIVE_UNCERTAINTY,
                                                 relative_jacobian_columns)
from emfc_ros.core.ident.initial_state import correct_record
from emfc_ros.core.ident.metrics import fit_percent, input_correlation_test, whiteness_test
from emfc_ros.core.ident.noise_model import whitening_weights
from emfc_ros.core.ident.pattern_search import PatternSearchOptions
from emfc_ros.core.ident.residual_coherence import residual_coherence
from emfc_ros.core.ident.systematic import components, fit_budget, fit_effects
from emfc_ros.core.model.linear import linearise
from emfc_ros.core.model.load import loaded
from emfc_ros.core.sim.kernel import resolved_backend

Progress = Callable[[str, float, str], None]

#: ``ftol``/``xtol`` of the time-domain fit. It starts next to the optimum (the frequency-domain
#: fit), so a relative cost change of 1e-6 (0.4 on a noise-weighted cost of about 4e5 on the
#: shipped trajectory) leaves the parameters within about 0.1 standard uncertainty of the
#: 1e-8 result (measured) at half the simulations.
TIME_DOMAIN_TOLERANCE = 1.0e-6
#: Most threads simulating the Jacobian's columns at once.
MAX_WORKERS = 4
#: Chi-square difference within which two frequency-domain optima fit equally well.
AMBIGUITY_CHI2 = 4.0
#: Two optima further apart than this many standard uncertainties are different answers.
AMBIGUITY_SIGMAS = 3.0
#: Two optima with no chi-square barrier between them are one answer (a flat floor the
#: optimiser left at two points) unless a parameter differs by more than this fraction.
AMBIGUITY_SAME_BASIN_RELATIVE = 0.01
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
    if name == PAN_FORCE_SCALE:
        return 1.0                      # the file's load-changer characteristic
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


def frequency_domain_stage(setting: Setting, channels: Mapping[str, np.ndarray],
                           jobs: Sequence[Tuple[str, int, int, Sequence[str]]],
                           modes: Sequence[Tuple[float, float, float]],
                           anti_resonance: Optional[Tuple[float, float, float]],
                           names: Sequence[str], band_Hz: Tuple[float, float], hold: str,
                           verdict: Verdict, report: Progress,
                           threshold: float = MAX_RELATIVE_UNCERTAINTY,
                           lower_factor: float = 0.2, executor: Optional['Offload'] = None
                           ) -> Tuple[Dict[str, float], Optional[balance_frf.FrfFit],
                                      Optional[FreeSetChoice], Optional['PendingProbe']]:
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
    lower_factor : float
        Lower bound of each free parameter as a multiple of its configured value (the lower
        of ``greybox.relative_bounds``): a model that cannot follow the data (e.g. masses
        fixed at values the data contradict) ends at a bound, which the verdict reports,
        instead of running a stiffness to zero.
    executor : Offload, optional
        Where the probe for a second optimum (:func:`probe_ambiguity`) runs while the caller
        goes on with the time-domain fit (e.g. a process pool); default here, before
        returning.

    Returns
    -------
    start : dict of str to float
        Values of the dynamic parameters for the time-domain fit (configured where the data
        say nothing).
    fit : FrfFit or None
        The frequency-domain fit.
    choice : FreeSetChoice or None
        The identifiability analysis (None without responses).
    probe : PendingProbe or None
        The probe running on ``executor`` (None: it ran here, or there was nothing to probe);
        :meth:`PendingProbe.outcome` gives its result.
    """
    configured = {n: configured_value(setting, n) for n in names}
    frfs = balance_frf.measure_frfs(channels, setting.sample_rate_Hz, jobs, setting.balance,
                                    frequency_min_Hz=band_Hz[0], frequency_max_Hz=band_Hz[1],
                                    hold=hold)
    if not frfs:
        verdict.warnings.append('greybox: no dynamic section gives a frequency response; the '
                                'mechanics start from their configured values')
        return configured, None, None, None
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
        return configured, None, choice, None
    fixed_now = {n: configured[n] for n in choice.fixed}
    at = dict(start, **fixed_now)
    report('greybox', 0.05, f'frequency-domain fit of {list(choice.free)}')
    lower = {n: lower_factor * configured[n] for n in choice.free}
    fit = balance_frf.fit_frfs(model, frfs, at, choice.free, lower=lower,
                               upper={n: 1e3 * configured[n] for n in choice.free})
    pending = None
    if executor is not None:
        pending = PendingProbe.submit(executor, model, frfs, fit, at, configured, lower)
        if pending is not None:
            report('greybox', 0.07, 'probe for a second optimum (restarts of the '
                   'frequency-domain fit) in a worker process')
    if pending is None:
        fit = probe_ambiguity(model, frfs, fit, at, configured, verdict, report, lower)
    out = dict(at, **fixed_now)
    out.update(fit.values)
    return out, fit, choice, pending


class Offload(Protocol):
    """Where work can run beside the caller: :class:`concurrent.futures.Executor`'s ``submit``."""

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future:
        """
        Run ``fn(*args)`` elsewhere.

        Parameters
        ----------
        fn : callable
            A module-level function (picklable for a process pool).
        *args
            Its arguments.

        Returns
        -------
        concurrent.futures.Future
            Its result.
        """


@with_single_blas_thread
def probe_elsewhere(model: balance_frf.MechanicsFrfModel, frfs: Sequence[Any],
                    fit: balance_frf.FrfFit, values: Dict[str, float],
                    configured: Mapping[str, float], lower: Optional[Mapping[str, float]]
                    ) -> Tuple[Optional[balance_frf.FrfFit], List[str]]:
    """
    :func:`probe_ambiguity` as a task for another process.

    Parameters
    ----------
    model, frfs, fit, values, configured, lower
        As for :func:`probe_ambiguity`.

    Returns
    -------
    better : FrfFit or None
        The clearly better optimum found, None when ``fit`` stays the best.
    failures : list of str
        The failure the probe reports (two optima that fit equally well).
    """
    verdict = Verdict()
    best = probe_ambiguity(model, frfs, fit, values, configured, verdict,
                           lambda step, fraction, message: None, lower)
    return (None if best is fit else best), list(verdict.failures)


@dataclasses.dataclass
class PendingProbe:
    """
    The probe for a second optimum, running elsewhere while the time-domain fit runs.

    The time-domain fit starts from the frequency-domain fit before the probe has ended (the
    probe took 0.2-0.35 s of the main job's critical path). Its outcome decides what happens
    after: no better optimum (the usual case) leaves the fit as it is, exactly what the
    probe in line gives; a failure is added to the verdict; a clearly better optimum makes
    :func:`fit_balance` run again in line, from it.

    Attributes
    ----------
    future : concurrent.futures.Future
        The task (:func:`probe_elsewhere`).
    args : tuple
        Its arguments, to run it here if the other process fails.
    """

    future: Future
    args: Tuple[Any, ...]

    @classmethod
    def submit(cls, executor: Offload, *args: Any) -> Optional['PendingProbe']:
        """
        Start the probe on ``executor``; None if it cannot take it (the probe then runs here).

        Parameters
        ----------
        executor : Offload
            Where to run it.
        *args
            ``model, frfs, fit, values, configured, lower`` of :func:`probe_elsewhere`.

        Returns
        -------
        PendingProbe or None
            The running probe.
        """
        try:
            return cls(executor.submit(probe_elsewhere, *args), tuple(args))
        except Exception:                   # noqa: B902 (a pool shut down or broken)
            return None

    def outcome(self, timeout_s: float = 300.0
                ) -> Tuple[Optional[balance_frf.FrfFit], List[str]]:
        """
        The probe's result (:func:`probe_elsewhere`); computed here if the other process failed.

        Parameters
        ----------
        timeout_s : float
            Longest wait for the other process [s].

        Returns
        -------
        better : FrfFit or None
            A clearly better optimum, or None.
        failures : list of str
            Failures to add to the verdict.
        """
        try:
            return self.future.result(timeout=timeout_s)
        except Exception:                   # noqa: B902 (a worker died, a pickling error)
            self.future.cancel()
            return probe_elsewhere(*self.args)


def probe_ambiguity(model: balance_frf.MechanicsFrfModel, frfs: Sequence[Any],
                    fit: balance_frf.FrfFit, values: Dict[str, float],
                    configured: Mapping[str, float], verdict: Verdict, report: Progress,
                    lower: Optional[Mapping[str, float]] = None) -> balance_frf.FrfFit:
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
    lower : mapping of str to float, optional
        Lower bounds (default 0).

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
                other = balance_frf.fit_frfs(model, frfs, start, names, lower=lower,
                                             upper=upper)
            except (IdentificationError, ValueError, np.linalg.LinAlgError):
                continue
            other_cost = other.chi2_reduced * dof
            y = np.array([other.values[n] for n in names])
            apart = float(np.max(np.abs(y - x) / np.where(se > 0.0, se, np.inf)))
            if other_cost < cost - AMBIGUITY_CHI2:
                best, cost, x = other, other_cost, y
            elif other_cost <= cost + AMBIGUITY_CHI2 and apart > AMBIGUITY_SIGMAS and \
                    _separate_optima(model, frfs, values, names, x, y,
                                     max(cost, other_cost)):
                shown = ', '.join(f'{n} {a:.4g} or {b:.4g}' for n, a, b in zip(names, x, y)
                                  if abs(b - a) > AMBIGUITY_SIGMAS * se[names.index(n)])
                verdict.failures.append(
                    f'greybox: the data fit two parameter sets equally well ({shown}; '
                    f'chi-square {cost:.1f} and {other_cost:.1f}): this experiment cannot '
                    f'tell them apart; add a pan-force section or fix the masses '
                    f'(greybox.free without J1c_kgm2, m3_kg, J2c_kgm2)')
                return best
    return best


def _separate_optima(model: balance_frf.MechanicsFrfModel, frfs: Sequence[Any],
                     values: Mapping[str, float], names: Sequence[str], x: np.ndarray,
                     y: np.ndarray, cost: float) -> bool:
    # Two optima are two answers when a chi-square barrier separates them (the cost at their
    # geometric midpoint exceeds both by AMBIGUITY_CHI2) or when they differ materially; a
    # random-noise coil section put the two starts 1e-5 apart on one flat floor (issue 28).
    if float(np.max(np.abs(y / x - 1.0))) > AMBIGUITY_SAME_BASIN_RELATIVE:
        return True
    mid = dict(values, **{n: float(v) for n, v in zip(names, np.sqrt(x * y))})
    r = balance_frf.weighted_residuals(model, frfs, mid)
    return float(r @ r) > cost + AMBIGUITY_CHI2


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


def noise_shapes(model: BalanceGreyboxModel, values: Dict[str, float],
                 data: Sequence[Any], setting: Setting
                 ) -> Tuple[List[List[np.ndarray]], List[np.ndarray]]:
    """
    Spectral shapes of the noise model and transient bases per section, for a parameter set.

    The noise model's shapes are the model's ``|H_coil|^2`` and ``|H_pan|^2``
    (:mod:`~emfc_ros.core.ident.noise_model`); the transient basis is
    ``C (z_k I - A_d)^-1 z_k`` of the model discretised at the sample rate (the leakage
    of process noise through the mechanics, see :func:`~emfc_ros.core.ident.greybox.fit_greybox`).

    Parameters
    ----------
    model : BalanceGreyboxModel
        The time-domain model.
    values : dict of str to float
        Parameter values (free parameters and the rest position).
    data : sequence of DataSection
        The sections.
    setting : Setting
        The configuration.

    Returns
    -------
    shapes : list of list of ndarray
        Per section the two shapes on its ``n // 2 + 1`` lines.
    transients : list of ndarray
        One complex basis of shape (``n // 2 + 1``, 4) per section.
    """
    from scipy import linalg as sla

    lin = linearise(loaded(model.balance(values).mechanics, setting.load_mass_kg,
                           setting.load_changer_coupled))
    a_d = sla.expm(lin.A / setting.sample_rate_Hz)
    # C (z I - A_d)^-1 = (C V) diag(1 / (z - mu)) V^-1 with A_d = V diag(mu) V^-1: every line
    # at once (the balance's modes are distinct, V well conditioned; otherwise a solve per line)
    mu, v = np.linalg.eig(a_d)
    modal = np.linalg.cond(v) < 1.0e8
    if modal:
        cv, v_inv = lin.C[0] @ v, np.linalg.inv(v)
    eye = np.eye(a_d.shape[0])
    shapes, bases = [], []
    for sec in data:
        n = len(sec.outputs)
        f = np.fft.rfftfreq(n, 1.0 / setting.sample_rate_Hz)
        shapes.append([np.abs(lin.frequency_response(f, inp).response_m_per_N) ** 2
                       for inp in ('coil', 'pan')])
        z = np.exp(2j * np.pi * np.arange(f.size) / n)
        if modal:
            bases.append(((cv * z[:, None]) / (z[:, None] - mu[None, :])) @ v_inv)
            continue
        # rows C (z I - A)^-1 z: solve (z I - A)^T v = C^T per line
        lhs = np.transpose(z[:, None, None] * eye[None] - a_d[None], (0, 2, 1))
        rhs = np.broadcast_to(lin.C[0].astype(complex), (f.size, eye.shape[0]))[..., None]
        bases.append(np.linalg.solve(lhs, rhs)[..., 0] * z[:, None])
    return shapes, bases


def noise_weights(model: BalanceGreyboxModel, values: Dict[str, float],
                  data: Sequence[Any], setting: Setting
                  ) -> Tuple[List[np.ndarray], List[np.ndarray]]:
    """
    Whitening weights and transient bases per section from the output error at the start.

    The weights come from the smooth noise model (:func:`noise_shapes`,
    :func:`~emfc_ros.core.ident.noise_model.whitening_weights`) fitted to the output error at
    ``values``.

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
    record = model.simulate_record(values)
    shapes, bases = noise_shapes(model, values, data, setting)
    weights = []
    for sec, shape in zip(data, shapes):
        first = model.offset(sec.inputs)
        weights.append(whitening_weights(sec.outputs - record[first:first + len(sec.outputs)],
                                         shape))
    return weights, bases


def residual_tests(model: BalanceGreyboxModel, fit: Any, data: Sequence[Any],
                   setting: Setting, max_lag: int = 25,
                   record: Optional[np.ndarray] = None,
                   with_estimation_error: bool = True,
                   band_Hz: Optional[Tuple[float, float]] = None) -> Tuple[Any, ...]:
    """
    Whiteness and input-correlation tests of the final residuals, pre-whitened.

    The raw output error of the balance is process noise ringing at the low mode: never white,
    so a whiteness test on it says nothing about the model (it showed 0 % on every section).
    The fit's criterion treats the output error divided by a smooth noise model as white; the
    weights it used were estimated at the start, whose model error inflates them where the
    chirps excite strongly. The tests here re-estimate the same smooth noise model
    (:func:`noise_weights`: the physical shapes ``|H_coil|^2``, ``|H_pan|^2``, a white floor
    and a correction over +/-25 % of the frequency) from the **final** residual, pre-whiten
    it with that (transient projected out), and test what is left: structure a smooth noise
    spectrum cannot explain (a mis-fitted resonance, a missing input path) shows as lags
    outside the 99 % band; for a right model about 99 % of the lags are inside. The noise
    model is estimated from the residual without its transient term (the leakage of the noise
    state at the section's ends, which the fit projects out): estimated with it, the smooth
    spectrum overstated the noise between 5 and 200 Hz threefold on the sections with steps,
    and the projected residual looked coloured (56 to 60 % of the lags inside, measured)
    although the fit was right.

    Parameters
    ----------
    model : BalanceGreyboxModel
        The model.
    fit : GreyboxResult
        The time-domain fit.
    data : sequence of DataSection
        Its sections.
    setting : Setting
        The configuration.
    max_lag : int
        Largest lag tested [samples].
    record : ndarray, optional
        The simulated record at ``fit.parameters`` when the caller has it.
    with_estimation_error : bool
        The cross-correlation's null covariance includes the fitted parameters' estimation
        error (:func:`~emfc_ros.core.ident.metrics.input_correlation_test`'s
        ``parameter_terms``, issue 28); False: noise only.
    band_Hz : (float, float), optional
        Frequencies of the coherence check (default up to Nyquist).

    Returns
    -------
    tuple of SectionFit
        ``fit.sections`` with the tests replaced (``residual_tested`` says which residual).
    """
    shapes, bases = noise_shapes(model, fit.parameters, data, setting)
    if record is None:
        record = model.simulate_record(fit.parameters)
    errors = [np.asarray(sec.outputs) - record[model.offset(sec.inputs):][:len(sec.outputs)]
              for sec in data]
    weights = []
    for e, shape, g in zip(errors, shapes, bases):
        # the noise model from the residual without its transient term
        w = whitening_weights(e, shape)
        clean = np.fft.irfft(np.fft.rfft(prewhitened(e, w, weighted_transient_basis(g, w)))
                             / w, e.size)
        weights.append(whitening_weights(clean, shape))
    out = []
    for sec, err, w, g, old in zip(data, errors, weights, bases, fit.sections):
        n = len(sec.outputs)
        q = weighted_transient_basis(g, w)
        tested = prewhitened(err, w, q)
        u = np.asarray(sec.inputs, dtype=float).reshape(n, -1)
        terms = None
        if with_estimation_error and fit.covariance is not None:
            d = model.output_derivatives(fit.parameters, fit.free_names, sec.inputs)
            if d is not None:
                d = np.asarray(d, dtype=float).reshape(n, -1)
                terms = (np.column_stack([prewhitened(d[:, i], w, q)
                                          for i in range(d.shape[1])]), fit.covariance)
        cross = [input_correlation_test(tested, u[:, j], max_lag, parameter_terms=terms)
                 for j in range(u.shape[1]) if np.ptp(u[:, j]) > 0.0]
        white = whiteness_test(tested, max_lag)
        out.append(dataclasses.replace(
            old, whiteness_fraction=white.fraction_inside,
            input_correlation_fraction=(float(np.mean([c.fraction_inside for c in cross]))
                                        if cross else float('nan')),
            residual_tested='noise-weighted (noise model of the final residual)',
            whiteness_p_value=white.p_value,
            input_correlation_p_value=(min(1.0, len(cross) * min(c.p_value for c in cross))
                                       if cross else float('nan')),
            coherence=residual_coherence(
                tested, {'coil': u[:, 0], 'load_changer': u[:, 1]}, setting.sample_rate_Hz,
                band_Hz or (0.0, 0.5 * setting.sample_rate_Hz))))
    return tuple(out)


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


def expected_simulations(method: str, n_parameters: int) -> int:
    """
    Simulations of the whole record a time-domain fit typically needs (measured).

    Parameters
    ----------
    method : str
        The optimiser.
    n_parameters : int
        Free parameters.

    Returns
    -------
    int
        Gauss-Newton with the linearised Jacobian: the start, about three steps and the four
        of its check, plus four around the fit; ``least_squares``: about three Jacobians and
        the central one of the covariance; the pattern search: its usual budget.
    """
    if method == 'gauss_newton':
        return 12
    if method == 'least_squares':
        return 4 * (n_parameters + 1) + 2 * n_parameters + 4
    return 200 * n_parameters


def interpreted_estimate_s(model: BalanceGreyboxModel, values: Dict[str, float],
                           simulations: int, probe_samples: int = 2000) -> float:
    """
    Wall time of ``simulations`` full-record simulations, from timing a short one.

    Parameters
    ----------
    model : BalanceGreyboxModel
        The model (its record length and backend).
    values : dict of str to float
        Parameters to simulate with.
    simulations : int
        How many.
    probe_samples : int
        Samples simulated for the measurement.

    Returns
    -------
    float
        The estimate [s].
    """
    import time

    n = model.setpoints_V.shape[0]
    probe = np.array(model.setpoints_V[:min(probe_samples, n)])
    start = time.perf_counter()
    model.simulate_setpoints(values, probe)
    per_sample = (time.perf_counter() - start) / probe.shape[0]
    return float(per_sample * n * simulations)


def simulation_workers(model: BalanceGreyboxModel) -> int:
    """
    Threads for the fit's Jacobian simulations.

    Parameters
    ----------
    model : BalanceGreyboxModel
        The model (its simulator backend).

    Returns
    -------
    int
        The processors this process may use, at most :data:`MAX_WORKERS`, with the compiled
        kernel (it releases the GIL); 1 for the interpreted one.
    """
    if resolved_backend(model.backend) != 'numba':
        return 1
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:          # not on Linux
        cpus = os.cpu_count() or 1
    return max(1, min(MAX_WORKERS, cpus))


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
                band_Hz: Tuple[float, float], hold: str, report: Progress,
                on_fit: Optional[Callable[[Any], None]] = None,
                executor: Optional[Offload] = None,
                on_model: Optional[Callable[[Any, Dict[str, float]], None]] = None,
                identified_amplifiers: Optional[Mapping[str, float]] = None
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
    on_fit : callable, optional
        Called once the time-domain fit has ended, before its residual tests and checks,
        with a :class:`FittedSignals` (e.g. to draw the fit's figures meanwhile).
    executor : Offload, optional
        Runs the frequency-domain fit's probe for a second optimum while the time-domain fit
        runs (:class:`PendingProbe`); the result is the same as without.
    on_model : callable, optional
        Called as ``on_model(linear_model, parameters)`` where the time-domain fit has
        converged, before its derivatives are checked (``fit_greybox``'s ``on_candidate``):
        the fitted mechanics linearised at rest and the fit's parameter values, as the
        result will hold them if the check passes (usually; else the result differs and
        ``on_fit`` says so), e.g. to draw the model's Bode diagrams meanwhile.
    identified_amplifiers : mapping of str to float, optional
        Amplifiers whose curve in ``setting.balance`` was identified from a staircase, with
        the relative standard error of its gain (for the systematic uncertainty,
        :func:`~emfc_ros.core.ident.systematic.components`).

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
    sources = {n: characteristic_source(setting.balance, 'mechanics', n)
               for n in mech.__dataclass_fields__}
    for n in fixed_by_user:
        sources[n] = 'options (greybox.initial)'
    dynamic = [n for n in requested if n in DYNAMIC_NAMES]
    start = {n: configured_value(setting, n) for n in requested}
    fd, choice, probe = None, None, None
    if gcfg.initialise_from_frf and dynamic:
        threshold = min(MAX_RELATIVE_UNCERTAINTY, gcfg.mass_relative_uncertainty or
                        MAX_RELATIVE_UNCERTAINTY)
        solved, fd, choice, probe = frequency_domain_stage(
            setting, channels, frf_jobs, modes, anti_resonance, dynamic, band_Hz, hold,
            verdict, report, threshold, gcfg.relative_bounds[0], executor)
        start.update(solved)
    probe_at = len(verdict.failures)    # where the probe in line puts its failure
    free = [n for n in requested if choice is None or n not in choice.fixed]
    if choice is not None:
        for n, reason in choice.fixed.items():
            sources[n] = f'{characteristic_source(setting.balance, "mechanics", n)}: {reason}'
            if n in MASS_MATRIX_NAMES:      # the coordinates stay at their configured values
                for c in MASS_COORDINATES:
                    sources[c] = (f'{characteristic_source(setting.balance, "mechanics", c)}: '
                                  f'the mass matrix is fixed ({n}: {reason})')
            verdict.warnings.append(f'greybox: {n} fixed at its configured value '
                                    f'{start[n]:.6g} {unit_of(n)}: {reason}')
    if PAN_FORCE_SCALE in free and not any(
            np.ptp(channels['load_changer_setpoint_V'][first:first + n]) > 0.0
            for _, first, n in sections):
        free.remove(PAN_FORCE_SCALE)
        verdict.warnings.append(f"greybox: {PAN_FORCE_SCALE} fixed at 1 (the file's "
                                f'load-changer characteristic): no fitted section moves the '
                                f'load changer')
    if not free and not fit_offset:
        verdict.failures.append('greybox: no parameter the data determine is left free')
        return None, verdict
    n_end = max(first + n for _, first, n in sections)
    setpoints = np.column_stack([channels['coil_setpoint_V'][:n_end],
                                 channels['load_changer_setpoint_V'][:n_end]])
    balance = with_values(setting.balance, {k: v for k, v in start.items() if k not in free},
                          setting.load_mass_kg, setting.load_changer_coupled)
    model = BalanceGreyboxModel(balance, setting.sample_rate_Hz, setpoints,
                                setting.load_mass_kg, setting.load_changer_coupled,
                                initial_setpoints_V=gcfg.initial_setpoints_V)
    data = model.sections(channels['position_m'], sections)
    if resolved_backend(model.backend) != 'numba':
        # the interpreted simulator: say up front how long this takes
        count = expected_simulations(gcfg.method, len(free) + int(fit_offset))
        estimate = interpreted_estimate_s(model, {n: start[n] for n in free}, count)
        message = (f'the simulator runs interpreted (numba is not installed): the time-domain '
                   f'fit takes about {estimate / 60.0:.0f} min ({estimate:.0f} s, {count} '
                   f'simulations of {n_end} samples); with numba about a second (pip install '
                   f'numba)')
        report('greybox', 0.1, message)
        if estimate > 60.0:
            verdict.warnings.append(f'greybox: {message}')
    rest = None
    if fit_offset:
        rest = offset_start(model, {n: start[n] for n in free}, channels['position_m'], data)
    specs = time_domain_specs(start, free, gcfg.relative_bounds, rest)
    budget = gcfg.max_evaluations or (2000 * len(specs) if gcfg.method == 'pattern_search'
                                      else 100 * (len(specs) + 1))

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

    def linearised(parameters: Mapping[str, float]) -> Any:
        fitted = model.balance(parameters)
        return fitted, linearise(loaded(fitted.mechanics, setting.load_mass_kg,
                                        setting.load_changer_coupled))

    def candidate(parameters: Dict[str, float]) -> None:
        on_model(linearised(parameters)[1], parameters)

    # the known inputs' stated uncertainties, propagated by the fit (systematic.py)
    known = components(setting.balance, [s.name for s in specs], identified_amplifiers)
    effects = fit_effects(known)
    try:
        fit = fit_greybox(simulate, data, specs, method=gcfg.method, options=options,
                          max_nfev=max_nfev, noise_weights=weights, transients=transients,
                          tolerance=TIME_DOMAIN_TOLERANCE, workers=simulation_workers(model),
                          output_derivatives=model.output_derivatives,
                          residual_tests=not gcfg.noise_weighting,
                          on_candidate=candidate if on_model is not None else None,
                          systematic=(effects, model.input_derivatives) if effects else None)
    except (IdentificationError, ValueError, RuntimeError) as exc:
        verdict.failures.append(f'greybox: {exc}')
        if probe is not None:           # what the probe in line would have added
            verdict.failures[probe_at:probe_at] = probe.outcome()[1]
        return None, verdict
    if probe is not None:
        better, failures = probe.outcome()
        if better is not None:
            # A clearly better optimum: the time-domain fit started from the wrong one. The
            # whole grey-box again, in line, as without an executor.
            return fit_balance(setting, channels, sections, frf_jobs, modes, anti_resonance,
                               gcfg, band_Hz, hold, report, on_fit, on_model=on_model,
                               identified_amplifiers=identified_amplifiers)
        verdict.failures[probe_at:probe_at] = failures
    fitted, lin = linearised(fit.parameters)
    # The record's initial state estimated (a balance not at rest under the first setpoints
    # rings in the data, not in the simulation): the fit percentages and the figures are of
    # the simulation with it (initial_state.py; the parameters were not affected).
    record, start_state = correct_record(
        lin.A, lin.C[0], setting.sample_rate_Hz, channels['position_m'],
        model.simulate_record(fit.parameters), [(first, n) for _, first, n in sections])
    fit = with_section_fits(fit, sections, channels['position_m'], record)
    signals = FittedSignals(fit, lin, *section_signals(channels, sections, record,
                                                       setting.sample_rate_Hz))
    if on_fit is not None:
        on_fit(signals)
    if gcfg.noise_weighting and n_end >= 2:
        fit = dataclasses.replace(fit, sections=residual_tests(model, fit, data, setting,
                                                               record=record, band_Hz=band_Hz))
    check(fit, specs, fd, verdict)
    budget = fit_budget(known, effects, fit.free_names, fit.systematic_sensitivity)
    derived = derived_quantities(model, fit, setting, budget)
    check_masses(derived, setting, gcfg.mass_relative_uncertainty, verdict, budget)
    check_uncertainties(fit, gcfg.mass_relative_uncertainty, verdict, skip=(REST_POSITION,))
    mass_fixed = [n for n in (choice.fixed if choice is not None else {})
                  if n in MASS_MATRIX_NAMES + INERTIA_NAMES]
    if mass_fixed and verdict.failures:
        verdict.warnings.append(
            f'greybox: {", ".join(mass_fixed)} were fixed at their configured values because '
            f'these sections ({", ".join(name for name, _, _ in sections)}) do not determine '
            f'them; if the configured masses are off, the model cannot follow the data: fit a '
            f'section that excites the pan too (frf.pan_sections, e.g. load_changer_chirp), or '
            f'correct the masses in the balance options')
    td_names = [n for n in fit.free_names if n != REST_POSITION]
    td_index = [fit.free_names.index(n) for n in td_names]
    time_domain = None
    if td_names and fit.covariance is not None:
        time_domain = analyse_covariance(
            np.asarray(fit.covariance)[np.ix_(td_index, td_index)], td_names,
            [fit.parameters[n] for n in td_names], POOR_RELATIVE_UNCERTAINTY)
    for n in free:
        sources[n] = 'identified (time-domain fit)'
    if all(n in free for n in MASS_MATRIX_NAMES):
        for n in MASS_COORDINATES:
            sources[n] = 'identified (time-domain fit, through the mass-matrix entries)'
    if fit_offset:
        sources['F_off_N'] = 'identified (time-domain fit, through the rest position)'
    parameters = {n: float(getattr(fitted.mechanics, n))
                  for n in fitted.mechanics.__dataclass_fields__}
    out = BalanceGreyboxResult(fit, {s.name: s.initial for s in specs}, lin, parameters,
                               derived, fd, choice, sources, time_domain,
                               initial_state=start_state, systematic=budget,
                               balance=fitted)
    out.time_s.update(signals.time_s)
    out.measured_m.update(signals.measured_m)
    out.simulated_m.update(signals.simulated_m)
    return out, verdict


def with_section_fits(fit: Any, sections: Sequence[Tuple[str, int, int]],
                      position_m: np.ndarray, record: np.ndarray) -> Any:
    """
    The fit with each section's fit percentage and rms error from a simulated record.

    Parameters
    ----------
    fit : GreyboxResult
        The time-domain fit.
    sections : sequence of (name, first_sample_index, n_samples)
        The fitted sections.
    position_m, record : ndarray
        Measured and simulated lever-end position over the record [m].

    Returns
    -------
    GreyboxResult
        A copy with ``sections`` replaced (whiteness fields kept).
    """
    spans = {name: slice(first, first + n) for name, first, n in sections}
    fits = []
    for sec in fit.sections:
        sl = spans.get(sec.name)
        if sl is None:
            fits.append(sec)
            continue
        y, yh = np.asarray(position_m[sl])[:, None], np.asarray(record[sl])[:, None]
        fits.append(dataclasses.replace(sec, fit_percent=np.atleast_1d(fit_percent(y, yh)),
                                        rms_error=np.sqrt(np.mean((y - yh) ** 2, axis=0))))
    return dataclasses.replace(fit, sections=tuple(fits))


@dataclasses.dataclass
class FittedSignals:
    """
    What the time-domain fit gives for figures, before its residual tests and checks.

    Attributes
    ----------
    fit : GreyboxResult
        The time-domain fit (its sections' fit percentages are final; the residual tests
        replace only their whiteness fields).
    linear_model : LinearModel
        The fitted mechanics linearised at rest.
    time_s, measured_m, simulated_m : dict of str to ndarray
        Per section: time from the section start [s], measured and simulated lever-end
        position [m].
    inputs_V : dict of str to ndarray
        Per section the setpoints ``(n, 2)`` [V] (filled by the pipeline).
    """

    fit: Any
    linear_model: Any
    time_s: Dict[str, np.ndarray]
    measured_m: Dict[str, np.ndarray]
    simulated_m: Dict[str, np.ndarray]
    inputs_V: Dict[str, np.ndarray] = dataclasses.field(default_factory=dict)


def section_signals(channels: Mapping[str, np.ndarray], sections: Sequence[Tuple[str, int, int]],
                    record: np.ndarray, sample_rate_Hz: float
                    ) -> Tuple[Dict[str, np.ndarray], Dict[str, np.ndarray],
                               Dict[str, np.ndarray]]:
    """
    Per section: time axis, measured and simulated position.

    Parameters
    ----------
    channels : mapping of str to ndarray
        The recording (``position_m``).
    sections : sequence of (name, first_sample_index, n_samples)
        The fitted sections.
    record : ndarray
        The simulated position over the record [m].
    sample_rate_Hz : float
        Sample rate [Hz].

    Returns
    -------
    time_s, measured_m, simulated_m : dict of str to ndarray
        By section name.
    """
    time_s, measured, simulated = {}, {}, {}
    for name, first, n in sections:
        sl = slice(first, first + n)
        time_s[name] = np.arange(n) / sample_rate_Hz
        measured[name] = np.asarray(channels['position_m'][sl])
        simulated[name] = record[sl]
    return time_s, measured, simulated
