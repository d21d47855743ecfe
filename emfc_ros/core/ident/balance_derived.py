"""
Numbers derived from the balance's fitted parameters, with first-order uncertainties.

``F_off_N``, the mass-matrix entries, the coordinates J1c, m3 and J2c, both modes and the coil
anti-resonance of the linearised fitted model (:func:`derived_quantities`), by propagating the
fit's covariance through a finite-difference gradient (:func:`gradient`), and their systematic part
from the fit's (:mod:`~emfc_ros.core.ident.systematic`).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
from typing import Callable, Dict, Mapping, Optional, Sequence, Tuple

import numpy as np

from emfc_ros.core.ident.balance_greybox import (BalanceGreyboxModel, MASS_COORDINATES,
                                                 REST_POSITION, unit_of)
from emfc_ros.core.ident.balance_result import Derived, MASS_KEYS, MODE_KEYS, Setting
from emfc_ros.core.ident.greybox import GreyboxResult
from emfc_ros.core.ident.systematic import LOAD_MASS, SystematicBudget
from emfc_ros.core.model.linear import linearise, LinearModel
from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.mechanics import mass_matrix
from emfc_ros.core.model.parameters import MechanicalParameters


def gradient(fun: Callable[[Dict[str, float]], np.ndarray], values: Dict[str, float],
             names: Sequence[str], steps: Mapping[str, float]) -> Tuple[np.ndarray, np.ndarray]:
    """
    Value and central-difference gradient of a vector function.

    Parameters
    ----------
    fun : callable
        ``fun(values) -> ndarray``.
    values : dict of str to float
        The estimate.
    names : sequence of str
        Parameters to differentiate by.
    steps : mapping of str to float
        Finite-difference step per parameter.

    Returns
    -------
    value : ndarray
        ``fun(values)``.
    grad : ndarray, shape (value.size, len(names))
        ``d fun / d parameter``.
    """
    f0 = np.asarray(fun(values), dtype=float)
    grads = []
    for n in names:
        h = float(steps[n])
        up = np.asarray(fun(dict(values, **{n: values[n] + h})), dtype=float)
        down = np.asarray(fun(dict(values, **{n: values[n] - h})), dtype=float)
        grads.append((up - down) / (2.0 * h))
    return f0, (np.column_stack(grads) if grads else np.zeros((f0.size, 0)))


def _std(g: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    """First-order standard uncertainties ``sqrt(diag(g C g^T))`` (NaN for a C not finite)."""
    cov = np.asarray(covariance, dtype=float)
    if not np.all(np.isfinite(cov)):
        return np.full(g.shape[0], np.nan)
    var = np.einsum('ij,jk,ik->i', g, cov, g)
    return np.sqrt(np.maximum(var, 0.0))


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


def derived_quantities(model: BalanceGreyboxModel, fit: GreyboxResult,
                       setting: Setting, budget: Optional[SystematicBudget] = None
                       ) -> Dict[str, Derived]:
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
    budget : SystematicBudget, optional
        The free parameters' systematic changes (:mod:`~emfc_ros.core.ident.systematic`):
        the derived numbers' are added to it and their systematic uncertainty set.

    Returns
    -------
    dict of str to Derived
        By name (units in the names).
    """
    names = list(fit.free_names)
    values = {n: fit.parameters[n] for n in names}
    steps = {n: 1e-5 * (abs(values[n]) or 1.0) if n != REST_POSITION else 1e-9 for n in names}
    cov = fit.covariance if fit.covariance is not None else np.full((len(names),) * 2, np.nan)

    value, grad = gradient(functools.partial(numbers_at, model, setting), values, names, steps)
    std = _std(grad, cov)
    keys = (('F_off_N', 'N'),) + MASS_KEYS + tuple((n, unit_of(n)) for n in MASS_COORDINATES) \
        + MODE_KEYS
    if budget is not None:
        # the fit's changes through the same gradient, the pan load's own part beside them
        changes = grad @ budget.parameter_steps(names)
        for k, c in enumerate(budget.components):
            # a known input that the numbers depend on themselves (the pan load and the fixed
            # lengths and masses convert mass-matrix entries to coordinates), the fit held
            moved, moved_setting = copy.copy(model), setting
            if c.effect == LOAD_MASS:
                moved.load_mass_kg = setting.load_mass_kg * (1.0 + c.step)
                moved_setting = dataclasses.replace(setting, load_mass_kg=moved.load_mass_kg)
            elif c.effect in MechanicalParameters.__dataclass_fields__:
                moved.params = model.params.with_mechanics(**{c.effect: float(
                    getattr(model.params.mechanics, c.effect)) + c.step})
            else:
                continue
            changes[:, k] += numbers_at(moved, moved_setting, values) - value
        for (key, _), row in zip(keys, changes):
            budget.add(key, {c.name: float(v) for c, v in zip(budget.components, row)})
    return {k: Derived(float(v), float(s), u,
                       budget.standard_uncertainty(k) if budget is not None else math.nan)
            for (k, u), v, s in zip(keys, value, std) if math.isfinite(v)}


def numbers_at(model: BalanceGreyboxModel, setting: Setting,
               values: Dict[str, float]) -> np.ndarray:
    """
    The derived numbers of :func:`derived_quantities` at some parameter values.

    Parameters
    ----------
    model : BalanceGreyboxModel
        The time-domain model (its pan load converts the mass-matrix entries).
    setting : Setting
        The configuration (pan load, coupling).
    values : dict of str to float
        The fit's free parameters.

    Returns
    -------
    ndarray
        ``F_off_N``, the mass-matrix entries, the mass coordinates, the modal summary.
    """
    own = model.balance(values).mechanics
    mech = loaded(own, setting.load_mass_kg, setting.load_changer_coupled)
    m = mass_matrix(np.zeros(2), mech)
    return np.concatenate(([own.F_off_N, m[0, 0], m[0, 1], m[1, 1]],
                           [getattr(own, n) for n in MASS_COORDINATES],
                           modal_summary(linearise(mech))))
