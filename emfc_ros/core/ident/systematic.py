"""
Systematic (type B) uncertainty of the grey-box estimates, input by input (GUM).

The grey-box fit takes the balance file's characteristics, lever lengths and the load
changer's mass as known and the pan load as told. Their stated standard uncertainties
(:class:`~emfc_ros.core.model.uncertainties.StatedUncertainties`) are propagated to every
identified number by sensitivity coefficients:

* at the fit level, ``d theta / d beta = -(J^T J)^-1 J^T G``, the first-order change of the
  least-squares estimate when an input ``beta`` is off (``G`` the weighted derivative of the
  output error by ``beta`` from the linearised model;
  :meth:`~emfc_ros.core.ident.balance_greybox.BalanceGreyboxModel.input_derivatives`,
  ``fit_greybox``'s ``systematic``). Inputs sharing an effect (sensor gain and the ADC gain
  both scale the measured position; the motor constant, the amplifier gain and the DAC gain
  all scale the coil force) share one column;
* for the derived numbers (mass-matrix entries and coordinates, modes, ``F_off_N``) through
  the same gradient as their statistical part, plus the pan load's direct part (it converts
  mass-matrix entries to coordinates; its fit-level effect is not computed).

Each input is independent: the systematic variance of a number is the sum of its
contributions squared (:class:`SystematicBudget`), the combined standard uncertainty
``u_c = sqrt(u_statistical^2 + u_systematic^2)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
import math
from typing import Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from emfc_ros.core.ident.balance_names import PAN_FORCE_SCALE
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.model.uncertainties import EFFECTS, StatedUncertainties

#: Effects the fit-level propagation computes (the rest are mechanical parameters by name).
SCALE_EFFECTS = ('position_scale', 'coil_force_scale', 'pan_force_scale')
#: The pan load: derived numbers only.
LOAD_MASS = 'load_mass'


@dataclass(frozen=True)
class Component:
    """
    One independent known input as the propagation uses it.

    Attributes
    ----------
    name : str
        The input (a key of the ``uncertainties`` section; a lever length by its own name).
    key : str
        The ``uncertainties`` key it is stated under.
    effect : str
        What it changes (:data:`~emfc_ros.core.model.uncertainties.EFFECTS`).
    step : float
        One standard uncertainty in the effect's own unit (relative for the scales and the
        pan load, the mechanical parameter's unit otherwise).
    standard_uncertainty : float
        As stated.
    unit : str
        Unit of ``standard_uncertainty`` ('1' for relative ones).
    """

    name: str
    key: str
    effect: str
    step: float
    standard_uncertainty: float
    unit: str


#: Per amplifier: its force effect and the stated gains a staircase identification replaces.
AMPLIFIERS = {
    'coil_amplifier': ('coil_force_scale',
                       ('coil_amplifier_gain_relative', 'coil_dac_gain_relative')),
    'load_changer_amplifier': ('pan_force_scale', ('load_changer_amplifier_gain_relative',
                                                   'load_changer_dac_gain_relative')),
}


def components(balance: BalanceParameters, free: Sequence[str] = (),
               identified: Optional[Mapping[str, float]] = None) -> List[Component]:
    """
    The independent known inputs with a non-zero stated uncertainty.

    Parameters
    ----------
    balance : BalanceParameters
        The balance (its ``uncertainties`` and the values of relative mechanical inputs).
    free : sequence of str
        Parameters the fit identifies (a mechanical input among them is not a known input).
    identified : mapping of str to float, optional
        Amplifiers whose curve was identified from a staircase (``'coil_amplifier'``,
        ``'load_changer_amplifier'``) and the relative standard error of that curve's gain:
        their stated gain and DAC gain are replaced by one input ``<amplifier>_from_staircase``
        combining the current monitor's stated gain and that error (the DAC's error is in the
        measured curve).

    Returns
    -------
    list of Component
        In the order of the ``uncertainties`` section, the identified amplifiers last.
    """
    stated: StatedUncertainties = balance.uncertainties
    identified = dict(identified or {})
    replaced = {key for part in identified for key in AMPLIFIERS[part][1]}
    out = []
    for f in fields(stated):
        u = float(getattr(stated, f.name))
        effects, unit = EFFECTS[f.name]
        if u <= 0.0 or f.name in replaced:
            continue
        for effect in effects:
            if effect in free or (effect == 'pan_force_scale' and PAN_FORCE_SCALE in free):
                continue                # identified, not known
            if effect in SCALE_EFFECTS or effect == LOAD_MASS:
                step = u
            elif unit == '1':
                step = u * abs(float(getattr(balance.mechanics, effect)))
            else:
                step = u
            name = f.name if len(effects) == 1 else effect
            out.append(Component(name, f.name, effect, step, u, unit))
    for part, error in identified.items():
        if AMPLIFIERS[part][0] == 'pan_force_scale' and PAN_FORCE_SCALE in free:
            continue                    # the load changer's whole force scale is fitted
        u = math.hypot(float(stated.current_monitor_gain_relative), float(error))
        if u > 0.0:
            out.append(Component(f'{part}_from_staircase', 'current_monitor_gain_relative',
                                 AMPLIFIERS[part][0], u, u, '1'))
    return out


def fit_effects(parts: Sequence[Component]) -> List[str]:
    """
    The distinct effects the fit-level propagation needs, in first-seen order.

    Parameters
    ----------
    parts : sequence of Component
        The inputs.

    Returns
    -------
    list of str
        Names for ``BalanceGreyboxModel.input_derivatives`` (the pan load left out).
    """
    out: List[str] = []
    for c in parts:
        if c.effect != LOAD_MASS and c.effect not in out:
            out.append(c.effect)
    return out


@dataclass
class SystematicBudget:
    """
    Every estimate's change per known input, one standard uncertainty each.

    Attributes
    ----------
    components : tuple of Component
        The inputs.
    changes : dict of str to dict of str to float
        ``changes[number][input]``: the signed first-order change of the number when the
        input is off by one standard uncertainty (the number's unit).
    """

    components: Tuple[Component, ...]
    changes: Dict[str, Dict[str, float]] = field(default_factory=dict)

    def standard_uncertainty(self, number: str) -> float:
        """
        Systematic standard uncertainty of a number.

        Parameters
        ----------
        number : str
            Parameter or derived number.

        Returns
        -------
        float
            ``sqrt(sum of the changes squared)``; NaN when not propagated.
        """
        parts = self.changes.get(number)
        if parts is None:
            return math.nan
        return math.sqrt(sum(v * v for v in parts.values()))

    def dominant(self, number: str, share: float = 0.9) -> List[Tuple[str, float]]:
        """
        The inputs that make up most of a number's systematic variance.

        Parameters
        ----------
        number : str
            Parameter or derived number.
        share : float
            Fraction of the variance the list covers (largest first).

        Returns
        -------
        list of (str, float)
            Input and its fraction of the systematic variance.
        """
        parts = self.changes.get(number) or {}
        total = sum(v * v for v in parts.values())
        if not total > 0.0:
            return []
        out, acc = [], 0.0
        for name, v in sorted(parts.items(), key=lambda kv: -kv[1] ** 2):
            out.append((name, v * v / total))
            acc += v * v / total
            if acc >= share:
                break
        return out

    def add(self, number: str, changes: Mapping[str, float]) -> None:
        """
        Record a number's changes.

        Parameters
        ----------
        number : str
            Parameter or derived number.
        changes : mapping of str to float
            Change per input (one standard uncertainty each).
        """
        self.changes[number] = {k: float(v) for k, v in changes.items() if math.isfinite(v)}

    def parameter_steps(self, names: Sequence[str]) -> np.ndarray:
        """
        The free parameters' changes as a matrix.

        Parameters
        ----------
        names : sequence of str
            Free parameters (rows).

        Returns
        -------
        ndarray, shape (len(names), inputs)
            Column ``k`` is the change of every parameter when input ``k`` is off by one
            standard uncertainty (0 where not propagated).
        """
        out = np.zeros((len(names), len(self.components)))
        for i, n in enumerate(names):
            row = self.changes.get(n, {})
            for k, c in enumerate(self.components):
                out[i, k] = row.get(c.name, 0.0)
        return out

    def to_dict(self, numbers: Optional[Sequence[str]] = None) -> dict:
        """
        Plain data for ``results.yaml``.

        Parameters
        ----------
        numbers : sequence of str, optional
            The numbers to list (default all).

        Returns
        -------
        dict
            ``inputs`` (name, stated uncertainty, unit, what it changes) and per number its
            systematic standard uncertainty and dominant inputs.
        """
        keys = (list(self.changes) if numbers is None
                else [n for n in numbers if n in self.changes])
        return {
            'inputs': [{'name': c.name, 'stated_under': f'uncertainties.{c.key}',
                        'standard_uncertainty': c.standard_uncertainty, 'unit': c.unit,
                        'changes': c.effect} for c in self.components],
            'numbers': {n: {'systematic_standard_uncertainty': self.standard_uncertainty(n),
                            'dominant_inputs': [{'input': k, 'variance_share': s}
                                                for k, s in self.dominant(n)]}
                        for n in keys},
        }


def fit_budget(parts: Sequence[Component], effects: Sequence[str],
               free: Sequence[str], sensitivity: Optional[np.ndarray]) -> SystematicBudget:
    """
    The free parameters' changes from the fit's sensitivities.

    Parameters
    ----------
    parts : sequence of Component
        The inputs.
    effects : sequence of str
        The effects (columns of ``sensitivity``).
    free : sequence of str
        The free parameters (rows).
    sensitivity : ndarray or None
        ``d theta / d effect`` (``GreyboxResult.systematic_sensitivity``).

    Returns
    -------
    SystematicBudget
        Changes of the free parameters (none when the sensitivity is missing).
    """
    budget = SystematicBudget(tuple(parts))
    if sensitivity is None:
        return budget
    s = np.asarray(sensitivity, dtype=float)
    for i, n in enumerate(free):
        budget.add(n, {c.name: (s[i, list(effects).index(c.effect)] * c.step
                                if c.effect in effects else 0.0) for c in parts})
    return budget


def combined(statistical: float, systematic: float) -> float:
    """
    Combined standard uncertainty.

    Parameters
    ----------
    statistical, systematic : float
        The two parts (a NaN systematic part counts as 0: not propagated).

    Returns
    -------
    float
        ``sqrt(statistical^2 + systematic^2)``.
    """
    sys_part = systematic if math.isfinite(systematic) else 0.0
    return math.hypot(statistical, sys_part)
