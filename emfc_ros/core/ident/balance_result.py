"""
What the balance's grey-box identification returns, and the same as plain data.

:class:`BalanceGreyboxResult` (fit, derived numbers with uncertainty, identifiability, where
each parameter comes from), :class:`Derived`, :class:`Verdict`, :class:`Setting`;
:func:`parameter_table` (every model parameter: identified or fixed, value, source) and
:func:`greybox_dict` for ``results.yaml``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any, Dict, List, Optional

import numpy as np

from emfc_ros.core.ident.balance_frf import FrfFit
from emfc_ros.core.ident.balance_greybox import (MASS_COORDINATES, MASS_MATRIX_NAMES,
                                                 REST_POSITION, unit_of)
from emfc_ros.core.ident.greybox import GreyboxResult
from emfc_ros.core.ident.identifiability import FreeSetChoice, Identifiability
from emfc_ros.core.ident.systematic import combined, SystematicBudget
from emfc_ros.core.model.linear import LinearModel
from emfc_ros.core.model.parameters import BalanceParameters

#: Keys of the derived modal numbers and their units.
MODE_KEYS = (('low_mode_frequency_Hz', 'Hz'), ('low_mode_damping_ratio', ''),
             ('high_mode_frequency_Hz', 'Hz'), ('high_mode_damping_ratio', ''),
             ('coil_anti_resonance_frequency_Hz', 'Hz'), ('coil_anti_resonance_damping_ratio', ''))
MASS_KEYS = (('mass_matrix_11_kgm2', 'kg m^2'), ('mass_matrix_12_kgm2', 'kg m^2'),
             ('mass_matrix_22_kgm2', 'kg m^2'))


@dataclass(frozen=True)
class Derived:
    """
    A number computed from the fitted parameters, with its standard uncertainty.

    Attributes
    ----------
    value : float
        The value.
    standard_uncertainty : float
        Statistical part: first-order propagation of the fit's covariance.
    unit : str
        SI unit.
    systematic_uncertainty : float
        Systematic part: the stated uncertainties of the known inputs propagated
        (:mod:`~emfc_ros.core.ident.systematic`; NaN when not propagated).
    """

    value: float
    standard_uncertainty: float
    unit: str
    systematic_uncertainty: float = math.nan

    @property
    def combined_uncertainty(self) -> float:
        """Combined standard uncertainty ``sqrt(statistical^2 + systematic^2)``."""
        return combined(self.standard_uncertainty, self.systematic_uncertainty)


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
    time_domain_identifiability : Identifiability or None
        The same analysis from the time-domain fit's covariance (the sections and inputs the
        fit used, coloured noise included; the rest position left out).
    time_s : dict of str to ndarray
        Per section: time from the section start [s].
    measured_m, simulated_m : dict of str to ndarray
        Per section: measured and simulated position [m].
    inputs_V : dict of str to ndarray
        Per section: the model's inputs, shape ``(n, 2)``: coil and load-changer setpoints
        [V] (for the residual-input correlation).
    initial_state : InitialState or None
        The record's estimated initial-state deviation from rest under the first setpoints
        (:mod:`~emfc_ros.core.ident.initial_state`); the simulated positions include its
        free response.
    systematic : SystematicBudget or None
        Every identified number's change per known input (type B,
        :mod:`~emfc_ros.core.ident.systematic`).
    balance : BalanceParameters or None
        The fitted balance: the characteristics the fit used (identified ones included), the
        fitted mechanics (None: the configuration's characteristics).
    characteristics : dict of str to str
        Per characteristic the fit took from elsewhere than the file (an amplifier curve
        identified from its staircase), where it came from and how it compares with the
        file's (:mod:`~emfc_ros.core.ident.unit_characteristics`).
    """

    fit: GreyboxResult
    initial: Dict[str, float]
    linear_model: LinearModel
    parameters: Dict[str, float] = field(default_factory=dict)
    derived: Dict[str, Derived] = field(default_factory=dict)
    frequency_domain: Optional[FrfFit] = None
    identifiability: Optional[FreeSetChoice] = None
    sources: Dict[str, str] = field(default_factory=dict)
    time_domain_identifiability: Optional[Identifiability] = None
    time_s: Dict[str, np.ndarray] = field(default_factory=dict)
    measured_m: Dict[str, np.ndarray] = field(default_factory=dict)
    simulated_m: Dict[str, np.ndarray] = field(default_factory=dict)
    inputs_V: Dict[str, np.ndarray] = field(default_factory=dict)
    initial_state: Optional[Any] = None
    systematic: Optional[SystematicBudget] = None
    balance: Optional[BalanceParameters] = None
    characteristics: Dict[str, str] = field(default_factory=dict)

    def systematic_uncertainty(self, name: str) -> float:
        """
        Systematic standard uncertainty of a free parameter or derived number.

        Parameters
        ----------
        name : str
            The number.

        Returns
        -------
        float
            NaN when not propagated.
        """
        return (self.systematic.standard_uncertainty(name) if self.systematic is not None
                else math.nan)


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


#: The characteristics that turn the recorded channels into the model's forces and position,
#: with what each does there (fixed on purpose: the data fix the mechanics only relative to
#: them, see ``docs/identification.md`` section 5, "Scale").
CHARACTERISTICS = (
    ('coil_amplifier', 'coeffs_A_per_V_pow', 'A/V^k, ascending powers k',
     'coil setpoint [V] to coil current [A] (model input)'),
    ('motor', 'coeffs_N_per_A_per_mm_pow', 'N/(A mm^k), ascending powers k',
     'coil current [A] and position [m] to coil force [N]'),
    ('load_changer_amplifier', 'coeffs_A_per_V_pow', 'A/V^k, ascending powers k',
     'load-changer setpoint [V] to its current [A] (model input)'),
    ('load_changer', 'coeffs_N_per_A_pow', 'N/A^k, ascending powers k',
     'load-changer current [A] to the force on the pan [N]'),
    ('sensor', 'coeffs_V_per_m_pow', 'V/m^k, ascending powers k',
     'position [m] to sensor voltage [V]: the source of the recording (plant simulator or '
     'daq_bridge, with its balance file) converted the voltage to position_m; the model '
     'applies it there and back (identity inside the sensor range)'),
)


def characteristic_source(balance: Optional[BalanceParameters], part: str,
                          name: Optional[str] = None) -> str:
    """
    Where a configured value of the identification's balance comes from.

    Parameters
    ----------
    balance : BalanceParameters or None
        The balance the identification used (``IdentificationConfig.balance``).
    part : str
        Field of :class:`BalanceParameters` (``'motor'``, ``'mechanics'``, ...).
    name : str, optional
        A field of that part (e.g. ``'m1_kg'``); default the whole part.

    Returns
    -------
    str
        ``'configuration (balance: identification options balance.<part>)'`` when the
        options changed it from the built-in defaults, else ``'configuration (balance:
        built-in defaults = config/balance_default.yaml)'``.
    """
    default = getattr(BalanceParameters(), part)
    if balance is not None:
        mine = getattr(balance, part)
        changed = (getattr(mine, name) != getattr(default, name)) \
            if name and hasattr(default, name) else mine != default
        if changed:
            return f'configuration (balance: identification options balance.{part})'
    return 'configuration (balance: built-in defaults = config/balance_default.yaml)'


def parameter_table(g: BalanceGreyboxResult, balance: Optional[BalanceParameters] = None,
                    plant: Optional[Dict[str, Any]] = None) -> List[Dict[str, Any]]:
    """
    Every model parameter: identified or fixed, value and source.

    The mechanics of the fitted model, the pan load and the load-changer coupling (the
    experiment's configuration) and the characteristics that convert setpoints and currents to
    forces and the sensor voltage to position (:data:`CHARACTERISTICS`, fixed on purpose).

    Parameters
    ----------
    g : BalanceGreyboxResult
        The result.
    balance : BalanceParameters, optional
        The balance the identification used (for the characteristics' rows).
    plant : dict, optional
        ``load_mass_kg``, ``load_changer_coupled`` and ``source`` (for the configuration's
        rows).

    Returns
    -------
    list of dict
        ``name, value, unit, status, source, standard_uncertainty`` (None when fixed; the
        statistical part, with ``systematic_standard_uncertainty`` and
        ``combined_standard_uncertainty`` beside it for identified ones, the
        ``stated_standard_uncertainty`` for fixed ones that have one), and a
        ``note`` for identified parameters that hold only together with fixed ones and for
        the characteristics (what each converts).
    """
    rows = []
    for name, value in g.parameters.items():
        through = {'F_off_N': (REST_POSITION,)}
        through.update({n: MASS_MATRIX_NAMES for n in MASS_COORDINATES})
        identified = name in g.fit.free_names or (
            name in through and all(t in g.fit.free_names for t in through[name]))
        sys_u = math.nan
        if identified and name in through and name in g.derived:
            se: Optional[float] = g.derived[name].standard_uncertainty
            sys_u = g.derived[name].systematic_uncertainty
        else:
            se = g.fit.standard_errors.get(name) if identified else None
            sys_u = g.systematic_uncertainty(name) if identified else math.nan
        row = {'name': name, 'value': value, 'unit': unit_of(name),
               'status': 'identified' if identified else 'fixed',
               'source': g.sources.get(name, 'configuration (balance)'),
               'standard_uncertainty': se}
        if identified and se is not None:
            _uncertainties(row, se, sys_u)
        elif not identified and balance is not None:
            stated = stated_uncertainty(balance, name)
            if stated is not None:
                row['stated_standard_uncertainty'] = stated
        if identified and name in CONDITIONAL:
            row['note'] = CONDITIONAL[name]
        rows.append(row)
    if plant is not None:
        rows.append({'name': 'load_mass_kg', 'value': plant.get('load_mass_kg'), 'unit': 'kg',
                     'status': 'fixed', 'source': plant.get('source', ''),
                     'standard_uncertainty': None,
                     'note': 'mass on the pan during the experiment; taken as exact (it '
                             'anchors the mass check)'})
        rows.append({'name': 'load_changer_coupled', 'value': plant.get('load_changer_coupled'),
                     'unit': '', 'status': 'fixed', 'source': plant.get('source', ''),
                     'standard_uncertainty': None,
                     'note': "whether the load changer's moving mass rode on the pan"})
    if balance is not None:
        used = g.balance if g.balance is not None else balance
        for part, key, unit, role in CHARACTERISTICS:
            identified = g.characteristics.get(part, '').startswith('identified')
            rows.append({'name': f'{part}.{key}',
                         'value': [float(c) for c in getattr(getattr(used, part), key)],
                         'unit': unit,
                         'status': (('identified (static)' if 'staircase' in
                                     g.characteristics[part] else 'identified (time-domain fit)')
                                    if identified else 'fixed'),
                         'source': (g.characteristics.get(part)
                                    or characteristic_source(balance, part)),
                         'standard_uncertainty': None,
                         'stated_relative_standard_uncertainty': float(getattr(
                             balance.uncertainties, STATED_GAIN[part])),
                         'note': (f'identified from its staircase: converts {role}'
                                  if identified else f'fixed on purpose: converts {role}')})
    return rows


#: The ``uncertainties`` key stating each characteristic's gain uncertainty.
STATED_GAIN = {'coil_amplifier': 'coil_amplifier_gain_relative',
               'motor': 'motor_coefficient_relative', 'sensor': 'sensor_gain_relative',
               'load_changer_amplifier': 'load_changer_amplifier_gain_relative',
               'load_changer': 'load_changer_force_relative'}


def stated_uncertainty(balance: BalanceParameters, name: str) -> Optional[float]:
    """
    The stated standard uncertainty of a fixed mechanical parameter, in its unit.

    Parameters
    ----------
    balance : BalanceParameters
        The balance (its ``uncertainties``).
    name : str
        A mechanical parameter.

    Returns
    -------
    float or None
        None where the ``uncertainties`` section states none for it.
    """
    stated = balance.uncertainties
    if name in ('l1_m', 'l2_m', 'l3_m'):
        return float(stated.lever_length_m)
    if name == 'load_changer_mass_kg':
        return float(stated.load_changer_mass_relative
                     * balance.mechanics.load_changer_mass_kg)
    return None


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


#: What ``results.yaml``'s ``greybox.systematic`` holds.
SYSTEMATIC_NOTE = ('type B (GUM): the stated standard uncertainties of the inputs the fit '
                   "takes as known (the balance file's uncertainties section) propagated to "
                   'every number by first-order sensitivities; standard_error / '
                   'standard_uncertainty are the statistical part, '
                   'systematic_standard_uncertainty the type B part, '
                   'combined_standard_uncertainty both (k = 1); docs/identification.md, '
                   '"Systematic uncertainties"')


def _finite(value: float) -> Optional[float]:
    """A float, or None for NaN (not tested)."""
    return float(value) if math.isfinite(value) else None


def _uncertainties(row: dict, statistical: float, systematic: float) -> dict:
    """A row with its systematic and combined standard uncertainty added."""
    row['systematic_standard_uncertainty'] = systematic if math.isfinite(systematic) else None
    row['combined_standard_uncertainty'] = (combined(statistical, systematic)
                                            if math.isfinite(systematic) else None)
    return row


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
    params = {name: _uncertainties({'value': fit.parameters[name],
                                    'standard_error': fit.standard_errors[name],
                                    'initial': g.initial.get(name), 'unit': unit_of(name)},
                                   fit.standard_errors[name], g.systematic_uncertainty(name))
              for name in free}
    if 'F_off_N' in g.derived and REST_POSITION in free:
        d = g.derived['F_off_N']
        params['F_off_N'] = _uncertainties(
            {'value': d.value, 'standard_error': d.standard_uncertainty, 'initial': None,
             'unit': 'N', 'note': f'from {REST_POSITION} through the static equilibrium'},
            d.standard_uncertainty, d.systematic_uncertainty)
    lin = g.linear_model
    fd = g.frequency_domain
    choice = g.identifiability
    out = {
        'method': fit.method, 'success': fit.success, 'exit_reason': fit.exit_reason,
        'cost': fit.cost, 'optimizer_evaluations': fit.optimizer_evaluations,
        'n_evaluations': fit.n_evaluations, 'time_s': fit.time_s,
        'covariance_method': fit.covariance_method,
        'jacobian_method': fit.jacobian_method,
        'derivative_check': fit.derivative_check,
        'parameters': params,
        'derived': {k: _uncertainties({'value': v.value,
                                       'standard_uncertainty': v.standard_uncertainty,
                                       'unit': v.unit},
                                      v.standard_uncertainty, v.systematic_uncertainty)
                    for k, v in g.derived.items()},
        'systematic': None if g.systematic is None else dict(
            g.systematic.to_dict(), note=SYSTEMATIC_NOTE),
        'correlation': {'names': free, 'matrix': np.asarray(fit.correlation).tolist()},
        'sections': [{'name': s.name, 'fit_percent': float(np.min(s.fit_percent)),
                      'rms_error_m': float(np.max(s.rms_error)),
                      'whiteness_fraction': s.whiteness_fraction,
                      'input_correlation_fraction': s.input_correlation_fraction,
                      'residual_tested': s.residual_tested,
                      'whiteness_p_value': _finite(s.whiteness_p_value),
                      'input_correlation_p_value': _finite(s.input_correlation_p_value),
                      'coherence': None if s.coherence is None else {
                          'input': s.coherence.input,
                          'frequency_Hz': s.coherence.frequency_Hz,
                          'squared_coherence': s.coherence.coherence,
                          'p_value': s.coherence.p_value,
                          'frequencies_tested': s.coherence.n_bins,
                          'segments': s.coherence.n_segments}}
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
        'time_domain_identifiability': (None if g.time_domain_identifiability is None
                                        else g.time_domain_identifiability.to_dict()),
        'initial_state': None if g.initial_state is None else {
            'position_m': g.initial_state.position_m,
            'deviation': [float(v) for v in g.initial_state.deviation],
            'deviation_units': ['rad', 'rad', 'rad/s', 'rad/s'][:len(g.initial_state.deviation)],
            'rms_error_without_m': g.initial_state.rms_before_m,
            'rms_error_with_m': g.initial_state.rms_after_m,
            'note': "estimated deviation of the record's initial state from rest under the "
                    'first setpoints; the simulated positions include its free response'},
    }
    return out
