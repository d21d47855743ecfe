"""
The verdict on a grey-box fit of the balance: failures and warnings, with their thresholds.

:func:`check` (section fits, an optimiser that did not leave its start or converge, a
parameter at a bound, time- and frequency-domain estimates that disagree) and
:func:`check_masses` (a mass matrix that contradicts the configured masses: the sign of a
scale error in a sensor or actuator characteristic).
"""

from __future__ import annotations

from dataclasses import replace
import math
from typing import Any, Mapping, Optional, Sequence, Tuple

import numpy as np
from scipy import linalg

from emfc_ros.core.ident.balance_greybox import MASS_MATRIX_NAMES
from emfc_ros.core.ident.balance_result import Derived, MASS_KEYS, Setting, Verdict
from emfc_ros.core.ident.greybox import GreyboxResult, ParameterSpec
from emfc_ros.core.ident.systematic import SystematicBudget
from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.mechanics import mass_matrix

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
#: 99.9 % quantile of chi-square with 3 degrees of freedom: the identified mass matrix is
#: inconsistent with the configured masses when its three entries are further from the
#: configured ones than this (Mahalanobis distance squared, see :func:`check_masses`).
MASS_CONSISTENCY_CHI2 = 16.27
#: Two-sided 99.9 % quantile of the normal distribution: a common scale of the mass matrix
#: further from 1 than this many standard uncertainties fails (see :func:`check_masses`).
MASS_SCALE_SIGMAS = 3.29
#: The masses and inertias taken as known to ``greybox.mass_relative_uncertainty`` each.
MASS_PARAMETERS = ('mp_kg', 'm1_kg', 'J1c_kgm2', 'm2_kg', 'J2c_kgm2', 'm3_kg',
                   'load_changer_mass_kg')
#: A free parameter within this fraction of its scale from a bound counts as at the bound.
BOUND_TOLERANCE = 1.0e-6
#: A free stiffness or damping whose relative standard uncertainty exceeds this is reported
#: as poorly determined by the experiment (its 95 % interval spans more than +/-20 %; the
#: issue's targets are 2 % for stiffnesses and 10 % for dampings). On the shipped trajectory
#: the largest is below 1 % (d2; 3 s sections: 1.0 %), on a coil chirp alone with the masses
#: fixed 4 % (d2), so the warning fires on experiments that do not excite a parameter, not on
#: noise. Free mass-matrix entries use ``greybox.mass_relative_uncertainty`` instead: a mass
#: known worse from the data than from the configuration should have stayed fixed.
POOR_RELATIVE_UNCERTAINTY = 0.10
#: Family-wise false-alarm rate of each residual test (whiteness, input correlation,
#: coherence) over the sections of one identification: a section's test warns when its
#: p-value is below this divided by the number of sections tested (Bonferroni). Before issue
#: 28 the rule was fewer than 80 % of the lags inside their 99 % band, whose band is right
#: only for a white input: it warned on right models in 38 to 50 % of the lags of step
#: sections. The false-alarm rates measured over drawn balances are in docs/benchmarks.md
#: ("Residual checks").
RESIDUAL_TEST_ALPHA = 0.01


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
    tested = [sec for sec in fit.sections if sec.residual_tested.startswith('noise-weighted')]
    # the raw output error is coloured process noise: never white, not tested
    level = RESIDUAL_TEST_ALPHA / max(len(tested), 1)
    for sec in tested:
        for what, value, share in (
                ('is not white (Ljung-Box test of its autocorrelation)', sec.whiteness_p_value,
                 sec.whiteness_fraction),
                ('depends on the inputs (cross-correlation test)',
                 sec.input_correlation_p_value, sec.input_correlation_fraction)):
            if value < level:
                verdict.warnings.append(
                    f'greybox: section {sec.name!r}: the pre-whitened residual {what}: p = '
                    f'{value:.2g} (below {level:.2g}: {RESIDUAL_TEST_ALPHA:g} over '
                    f'{len(tested)} sections; {100 * share:.0f} % of the lags inside the 99 % '
                    f'band): the model misses part of the response')
        peak = getattr(sec, 'coherence', None)
        if peak is not None and peak.p_value < level:
            verdict.warnings.append(
                f'greybox: section {sec.name!r}: the pre-whitened residual is coherent with '
                f'the {peak.input} input at {peak.frequency_Hz:.4g} Hz (coherence '
                f'{peak.coherence:.2f}, p = {peak.p_value:.2g} over {peak.n_bins} frequencies): '
                f'the model lacks a dynamic there (an unmodelled mode or path)')
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
                 verdict: Verdict, budget: Optional[SystematicBudget] = None) -> None:
    """
    Fail when the identified mass matrix contradicts the configured masses.

    The data fix the mass matrix only up to the scale of the sensor and actuator
    characteristics (a sensor sensitivity 10 % off scales every stiffness, damping and
    inertia by 1/1.1 and fits as well). The configured masses are the check: each mass and
    inertia of the balance (:data:`MASS_PARAMETERS`) is taken as known to
    ``relative_uncertainty``, independently, the load on the pan as exact. That gives the
    covariance ``C`` of the three mass-matrix entries ``M11, M12, M22`` (they are linear in
    the masses), to which the identified entries' own variances are added and, with a
    ``budget``, their systematic covariance: ``sum_k v_k v_k^T`` over the known inputs ``k``
    other than the masses (sensor and ADC gains, force constants, amplifier and DAC gains,
    lever lengths, pan load), ``v_k`` the three entries' signed changes when input ``k`` is
    off by its stated standard uncertainty. A sensor within its stated uncertainty then passes
    (the check compares the two independent measures of the scale, masses and stated
    characteristics, each with its own uncertainty). Two tests, each a failure at 99.9 %:

    * consistency: ``r^T C^-1 r`` with ``r = M_id - M_cfg`` above
      :data:`MASS_CONSISTENCY_CHI2` (chi-square, 3 degrees of freedom);
    * common scale (the signature of a sensor or actuator scale error): the generalised
      least-squares scale ``s = d^T C^-1 r / d^T C^-1 d`` with ``d = M_cfg`` more than
      :data:`MASS_SCALE_SIGMAS` of its standard uncertainty ``(d^T C^-1 d)^-1/2`` from 0.
      The exactly known pan load anchors it: on 400 balances drawn within +/-10 % and
      masses taken as known to 5 % it flags none, and, without a budget, every one read
      through a sensor whose gain is 10 % off. With the budget (what the identification
      passes) the sensor's stated 2 % widens it: of the first 10 benchmark balances
      identified through a sensor 10 % high and 10 % low, 13 of 20 fail, the other 7 pass
      with the warning below.

    A warning (not a failure) names the scale when the masses alone would fail it but the
    stated characteristics allow it.

    Parameters
    ----------
    derived : mapping of str to Derived
        With the ``mass_matrix_*`` entries.
    setting : Setting
        The configured balance and load.
    relative_uncertainty : float
        Relative standard uncertainty of each configured mass and inertia (0 disables).
    verdict : Verdict
        Collects the failure.
    budget : SystematicBudget, optional
        The fit's systematic budget (its mass-matrix entries' changes per known input);
        without it the characteristics count as exact.
    """
    if not relative_uncertainty > 0.0 or not all(k in derived for k, _ in MASS_KEYS):
        return
    mech = setting.balance.mechanics
    configured = _entries(mech, setting)
    columns = []
    for name in MASS_PARAMETERS:
        value = float(getattr(mech, name))
        if value > 0.0:
            columns.append(_entries(replace(mech, **{name: 2.0 * value}), setting) - configured)
    if not columns:
        return
    sens = np.array(columns).T
    own = np.array([derived[k].standard_uncertainty for k, _ in MASS_KEYS])
    own = np.where(np.isfinite(own), own, 0.0)
    masses_only = relative_uncertainty ** 2 * sens @ sens.T + np.diag(own ** 2)
    steps = _stated_steps(budget) if budget is not None else np.zeros((3, 0))
    cov = masses_only + steps @ steps.T
    stated = ('the characteristics known to their stated uncertainties' if steps.size
              else 'the characteristics exact')
    identified = np.array([derived[k].value for k, _ in MASS_KEYS])
    r = identified - configured
    chi2, scale, z = _against(cov, configured, r)
    rel = [f'{name[-7:-5]} {100 * (i / c - 1.0):+.1f} %'
           for (name, _), i, c in zip(MASS_KEYS, identified, configured) if c != 0.0]
    shown = ', '.join(rel)
    known = f'{100 * relative_uncertainty:g} %'
    if abs(z) > MASS_SCALE_SIGMAS:
        verdict.failures.append(
            f'greybox: the identified mass matrix is the configured one scaled by '
            f'{100 * scale:+.1f} % ({abs(z):.1f} standard uncertainties with every mass known '
            f'to {known}, the pan load as told and {stated}; entries {shown}): a sensor or '
            f'actuator characteristic (gain) is off by about that much (every stiffness, '
            f'damping and inertia scales with it), or the configured masses or pan load are; set '
            f'greybox.mass_relative_uncertainty if the masses are known worse')
    elif chi2 > MASS_CONSISTENCY_CHI2:
        verdict.failures.append(
            f'greybox: the identified mass matrix differs from the configured masses by '
            f'{shown} (chi-square {chi2:.1f} with every mass known to {known} and {stated}): a '
            f'sensor or actuator characteristic is off, or the configured masses are; set '
            f'greybox.mass_relative_uncertainty if the masses are known worse')
    elif steps.size and abs(alone := _against(masses_only, configured, r)[2]) > \
            MASS_SCALE_SIGMAS:
        verdict.warnings.append(
            f'greybox: the identified mass matrix is the configured one scaled by '
            f'{100 * scale:+.1f} % (entries {shown}): {abs(alone):.1f} standard uncertainties '
            f'of the masses alone (each known to {known}), {abs(z):.1f} with the stated '
            f'uncertainties of the sensor and actuator characteristics: a characteristic may '
            f'be off by about that much; the combined uncertainties include it')


def _against(cov: np.ndarray, configured: np.ndarray,
             r: np.ndarray) -> Tuple[float, float, float]:
    """Chi-square, common scale and the scale's z of a mass-matrix deviation ``r``."""
    info = linalg.pinvh(cov)
    scale_info = float(configured @ info @ configured)
    scale = float(configured @ info @ r) / scale_info
    return float(r @ info @ r), scale, scale * math.sqrt(scale_info)


def _stated_steps(budget: SystematicBudget) -> np.ndarray:
    """Mass-matrix entries' changes (rows) per known input other than a mass (columns)."""
    names = [c.name for c in budget.components if c.effect not in MASS_PARAMETERS]
    rows = [budget.changes.get(k, {}) for k, _ in MASS_KEYS]
    return np.array([[row.get(n, 0.0) for n in names] for row in rows]).reshape(3, len(names))


def _entries(mech: Any, setting: Setting) -> np.ndarray:
    m = mass_matrix(np.zeros(2), loaded(mech, setting.load_mass_kg,
                                        setting.load_changer_coupled))
    return np.array([m[0, 0], m[0, 1], m[1, 1]])


def check_uncertainties(fit: GreyboxResult, mass_relative_uncertainty: float,
                        verdict: Verdict, skip: Sequence[str] = ()) -> None:
    """
    Warn about free parameters the fitted sections determine poorly.

    A free stiffness or damping with a relative standard uncertainty above
    :data:`POOR_RELATIVE_UNCERTAINTY`, or a free mass-matrix entry (or mass) above
    ``mass_relative_uncertainty`` (when that is > 0, else the same 10 %), is reported: the
    number is honest (its uncertainty says so), but the experiment does not determine it.

    Parameters
    ----------
    fit : GreyboxResult
        The time-domain fit (its standard errors).
    mass_relative_uncertainty : float
        The configured masses' relative standard uncertainty.
    verdict : Verdict
        Collects the warnings.
    skip : sequence of str
        Free parameters not checked (the rest position: an offset, not relative).
    """
    for name in fit.free_names:
        if name in skip:
            continue
        value, se = fit.parameters[name], fit.standard_errors.get(name, math.nan)
        if value == 0.0:
            continue
        rel = abs(se / value) if math.isfinite(se) else math.inf
        mass = name in MASS_MATRIX_NAMES or name in MASS_PARAMETERS
        limit = mass_relative_uncertainty if mass and mass_relative_uncertainty > 0.0 \
            else POOR_RELATIVE_UNCERTAINTY
        if rel > limit:
            what = ('known worse from these data than the configured masses '
                    f'({100 * limit:g} %)') if mass and limit != POOR_RELATIVE_UNCERTAINTY \
                else f'above {100 * limit:g} %: these sections do not determine it'
            verdict.warnings.append(
                f'greybox: {name} is poorly determined: standard uncertainty '
                f'{100 * rel:.3g} % of its value, {what}; add sections that excite it (the '
                f'identifiability section of the report says which combinations are weak) '
                f'or fix it (greybox.free)')
