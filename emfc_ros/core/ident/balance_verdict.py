"""
The verdict on a grey-box fit of the balance: failures and warnings, with their thresholds.

:func:`check` (section fits, an optimiser that did not leave its start or converge, a
parameter at a bound, time- and frequency-domain estimates that disagree) and
:func:`check_masses` (a mass matrix that contradicts the configured masses: the sign of a
scale error in a sensor or actuator characteristic).
"""

from __future__ import annotations

import math
from typing import Any, Mapping, Optional, Sequence

import numpy as np

from emfc_ros.core.ident.balance_result import Derived, MASS_KEYS, Setting, Verdict
from emfc_ros.core.ident.greybox import GreyboxResult, ParameterSpec
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
#: configured ones than this (in units of the configured masses' relative uncertainty).
MASS_CONSISTENCY_CHI2 = 16.27
#: A free parameter within this fraction of its scale from a bound counts as at the bound.
BOUND_TOLERANCE = 1.0e-6


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
