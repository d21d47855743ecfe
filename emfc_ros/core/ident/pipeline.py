"""
The identification pipeline: a recorded experiment in, identified balance out (no ROS).

``identify(recording, experiment_sections, config)`` runs, each step optional by configuration
(:mod:`emfc_ros.core.ident.pipeline_config`):

(a) FRFs of the lever-end position per coil force and per pan force on the single-input
    sections, the two-input solve on the simultaneous sections (local polynomial method by
    default, with coherence and standard deviation), the DAC hold removed, and the response at
    selected frequencies as the paper reports it;
(b) transfer-function fits with order selection: resonances, anti-resonances, damping, each
    with its standard deviation;
(c) static characteristics of staircase sections: ``I(U)`` of both amplifiers and the load
    changer's ``F(I)`` in the paper's form;
(d) the grey-box fit of the two-beam model by simulation error over the sections
    (:mod:`emfc_ros.core.ident.balance_greybox`): parameters, standard errors, correlations,
    fit % per section, residual tests, and the linearisation of the fitted model.

Progress goes to an optional ``progress(step, fraction, message)`` callable. The result
serialises to plain data with :meth:`IdentificationResult.to_dict` (every key with its unit).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
import math
import time
from types import SimpleNamespace
from typing import Any, Callable, Dict, List, Mapping, Optional, Sequence, Tuple
import warnings

import numpy as np
from scipy import special     # Student's t quantile: stdtrit (scipy.stats takes 1 s to load)

from emfc_ros.core.blas_threads import with_single_blas_thread
from emfc_ros.core.ident import balance_fit
from emfc_ros.core.ident.balance_names import PAN_FORCE_SCALE
from emfc_ros.core.ident.balance_result import (BalanceGreyboxResult, greybox_dict,
                                                parameter_table, Setting)
from emfc_ros.core.ident.errors import IdentificationError
from emfc_ros.core.ident.frf import estimate_frf, FrequencyResponseData
from emfc_ros.core.ident.hold import hold_factor
from emfc_ros.core.ident.local_polynomial import detect_excitation, local_polynomial_frf
from emfc_ros.core.ident.mimo import estimate_two_input_frf
from emfc_ros.core.ident.pipeline_config import IdentificationConfig
from emfc_ros.core.ident.plant import PLANT_KEYS, PlantConfigurationError
from emfc_ros.core.ident.scale_budget import frf_budget, ScaleBudget, static_budget
from emfc_ros.core.ident.static_fit import fit_polynomial, PolynomialFit, with_std_floor
from emfc_ros.core.ident.tf_fit import OrderSelection, select_order
from emfc_ros.core.ident.unit_characteristics import unit_amplifiers

Progress = Callable[[str, float, str], None]

#: Channels the pipeline needs.
REQUIRED_CHANNELS = ('coil_setpoint_V', 'load_changer_setpoint_V', 'coil_current_A',
                     'load_changer_current_A', 'position_m')


#: Smallest FRF std used as a fit weight, relative to |H|: the hold compensation and the
#: LPM's local polynomials are good to about 0.1 %, so a noise-free record must not claim more
#: (order selection would otherwise add poles to fit those systematic errors).
STD_FLOOR = 1.0e-3
#: LPM windows kept clear of the band's lowest line by the transfer-function fit
#: (:func:`tf_fit_lines`).
EDGE_WINDOWS = 2
#: Fewest lines for which the edge is cleared (shorter FRFs keep every line).
MIN_TF_LINES = 20

INPUT_NAMES = {'coil': 'coil force', 'pan': 'pan force'}


@dataclass(frozen=True)
class Span:
    """
    A section of the recording.

    Attributes
    ----------
    name : str
        Section name.
    first_sample_index : int
        First sample (index into the recording's arrays).
    n_samples : int
        Length.
    """

    name: str
    first_sample_index: int
    n_samples: int

    @property
    def slice(self) -> slice:
        """The section as a slice of the recording."""
        return slice(self.first_sample_index, self.first_sample_index + self.n_samples)


@dataclass
class FrfResult:
    """
    FRF of one section and input, with its fits.

    Attributes
    ----------
    section : str
        Section name.
    input : str
        ``'coil'`` or ``'pan'`` (force input; output the lever-end position).
    frd : FrequencyResponseData
        The measured response [m/N] with coherence and std (hold removed).
    two_input : bool
        From the joint solve of a simultaneous section.
    selected : FrequencyResponseData or None
        Response at the selected frequencies (LPM at the nearest DFT line).
    fit : OrderSelection or None
        Transfer-function fits and the chosen one.
    model_response : ndarray or None
        Response of the grey-box model's linearisation at ``frd.frequency_Hz`` [m/N].
    systematic : ScaleBudget or None
        The systematic (type B) part of the magnitude and of the fit's gain, relative, from
        the stated uncertainties of the sensor, the current monitor and the force constant
        (:func:`~emfc_ros.core.ident.scale_budget.frf_budget`); phases, poles and zeros have
        none.
    """

    section: str
    input: str
    frd: FrequencyResponseData
    two_input: bool = False
    selected: Optional[FrequencyResponseData] = None
    fit: Optional[OrderSelection] = None
    model_response: Optional[np.ndarray] = None
    systematic: Optional[ScaleBudget] = None

    @property
    def name(self) -> str:
        """Identifier ``<section>.<input>``."""
        return f'{self.section}.{self.input}'


@dataclass
class StaticResult:
    """
    Static characteristics from staircase sections.

    Attributes
    ----------
    fits : dict of str to PolynomialFit
        ``coil_amplifier``, ``load_changer_amplifier``, ``load_changer`` (as available).
    n_plateaus : dict of str to int
        Plateaus behind each fit.
    points : dict of str to (ndarray, ndarray)
        The plateau means behind each fit, ``(x, y)`` in the fit's units (``U`` [V] and
        ``I`` [A] for the amplifiers, ``I`` [A] and ``F`` [N] for the load changer).
    std_floor : dict of str to float
        Smallest residual standard deviation behind each fit's standard errors, in the unit
        of y: the current monitors' ADC step over ``sqrt(12)`` (plateau means of currents
        quantised without dither are off by up to half a step; for the load changer seen
        through its slope), :func:`~emfc_ros.core.ident.static_fit.with_std_floor`.
    systematic : dict of str to list of ScaleBudget
        Per fit, per coefficient (ascending powers), its systematic (type B) part, relative
        (:func:`~emfc_ros.core.ident.scale_budget.static_budget`).
    """

    fits: Dict[str, PolynomialFit] = field(default_factory=dict)
    n_plateaus: Dict[str, int] = field(default_factory=dict)
    points: Dict[str, Tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    std_floor: Dict[str, float] = field(default_factory=dict)
    systematic: Dict[str, List[ScaleBudget]] = field(default_factory=dict)


@dataclass
class IdentificationResult:
    """
    Everything the pipeline identified.

    Attributes
    ----------
    sample_rate_Hz : float
        Sample rate of the recording [Hz].
    n_samples : int
        Samples in the recording.
    sections : list of Span
        The section table.
    config : IdentificationConfig
        The configuration used.
    frfs : list of FrfResult
        Step (a) and (b).
    static : StaticResult or None
        Step (c).
    greybox : BalanceGreyboxResult or None
        Step (d).
    warnings : list of str
        What the user should know (skipped steps, poor fits, failed residual tests).
    failures : list of str
        Why the identification did not reach a usable model (empty when it did): a failed
        step, a section fit below its threshold, a stalled optimiser, a parameter at a bound.
        :attr:`success` is False when any is listed.
    timings_s : dict of str to float
        Wall time per step [s].
    plant_source : str
        Where the pan load and the load-changer coupling came from (set by the caller that
        resolved them; ``'identification options'`` when they were given there).
    """

    sample_rate_Hz: float
    n_samples: int
    sections: List[Span]
    config: IdentificationConfig
    frfs: List[FrfResult] = field(default_factory=list)
    static: Optional[StaticResult] = None
    greybox: Optional[BalanceGreyboxResult] = None
    warnings: List[str] = field(default_factory=list)
    failures: List[str] = field(default_factory=list)
    timings_s: Dict[str, float] = field(default_factory=dict)
    plant_source: str = 'identification options'

    @property
    def success(self) -> bool:
        """Whether the identification reached a usable model (no failure listed)."""
        return not self.failures

    def frf(self, section: str, input: str) -> FrfResult:
        """
        Look up the FRF result of a section and input.

        Parameters
        ----------
        section : str
            Section name.
        input : str
            ``'coil'`` or ``'pan'``.

        Returns
        -------
        FrfResult
            The result.

        Raises
        ------
        KeyError
            If there is none.
        """
        for r in self.frfs:
            if r.section == section and r.input == input:
                return r
        raise KeyError(f'no FRF for section {section!r}, input {input!r}')

    def to_dict(self) -> dict:
        """
        Plain data for YAML or JSON; every key carries its unit.

        Returns
        -------
        dict
            Nested dicts, lists, floats, ints, strings and booleans.
        """
        return _to_plain({
            'status': {'success': self.success, 'failures': list(self.failures)},
            'sample_rate_Hz': self.sample_rate_Hz,
            'n_samples': self.n_samples,
            'duration_s': self.n_samples / self.sample_rate_Hz,
            'sections': [{'name': s.name, 'first_sample_index': s.first_sample_index,
                          'n_samples': s.n_samples} for s in self.sections],
            'configuration': {'load_mass_kg': self.config.load_mass_kg,
                              'load_changer_coupled': self.config.load_changer_coupled,
                              'source': self.plant_source},
            'frequency_responses': [_frf_dict(r) for r in self.frfs],
            'static_characteristics': _static_dict(self.static),
            'greybox': greybox_dict(self.greybox),
            'model_parameters': (parameter_table(
                self.greybox, self.config.balance,
                {'load_mass_kg': self.config.load_mass_kg,
                 'load_changer_coupled': self.config.load_changer_coupled,
                 'source': self.plant_source})
                if self.greybox is not None else None),
            'warnings': list(self.warnings),
            'timings_s': dict(self.timings_s),
            'pipeline_config': self.config.to_dict(),
        })


def identify(recording: Any, experiment_sections: Sequence[Any],
             config: Optional[Any] = None, *, sample_rate_Hz: Optional[float] = None,
             progress: Optional[Progress] = None,
             on_step: Optional[Callable[[str, 'IdentificationResult'], None]] = None,
             executor: Optional[Any] = None) -> IdentificationResult:
    """
    Identify the balance from a recorded experiment.

    Parameters
    ----------
    recording : mapping or object
        Channels as 1-D arrays on one sample clock, by name (at least ``coil_setpoint_V``,
        ``load_changer_setpoint_V``, ``coil_current_A``, ``load_changer_current_A``,
        ``position_m``; optionally ``coil_force_N``, ``load_changer_force_N``,
        ``pan_force_N``): a mapping (which may also hold ``sample_rate_Hz``) or an object with
        ``channels`` and ``sample_rate_Hz`` attributes.
    experiment_sections : sequence
        The section table: ``(name, first_sample_index, n_samples)`` tuples, mappings with
        those keys, or objects with those attributes.
    config : IdentificationConfig or mapping, optional
        The configuration (a mapping is validated with
        :meth:`IdentificationConfig.from_mapping`); default all defaults.
    sample_rate_Hz : float, optional
        Sample rate [Hz] when the recording does not carry it.
    progress : callable, optional
        Called as ``progress(step, fraction, message)`` with ``fraction`` in [0, 1].
    on_step : callable, optional
        Called as ``on_step(step, result)`` after each step (``'frf'``, ``'tf_fit'``,
        ``'static'``, ``'greybox'``) with the result so far, e.g. to draw its plots while the
        next step runs (:class:`~emfc_ros.core.report.background.PlotPool`); and as
        ``on_step('greybox_fit', view)`` once the grey-box's time-domain fit has ended, before
        its residual tests and checks, with ``view.frfs`` (copies carrying the model's
        responses) and ``view.greybox`` (a
        :class:`~emfc_ros.core.ident.balance_fit.FittedSignals`); before that, as
        ``on_step('greybox_model', view)`` once the fit has converged and its derivatives
        are being checked, with the model alone (``view.frfs`` with the model's responses,
        ``view.greybox.linear_model`` and ``view.greybox.fit.parameters``: what the result
        holds if the check passes).
    executor : concurrent.futures.Executor, optional
        Another process to run part of the work in while this one goes on (anything with
        ``submit(fn, *args)``, :class:`~emfc_ros.core.ident.balance_fit.Offload`): the
        grey-box's probe for a second optimum runs there during the time-domain fit. The
        result is the same as without.

    Returns
    -------
    IdentificationResult
        The results, warnings and timings.

    Raises
    ------
    PlantConfigurationError
        If the grey-box step is enabled and the configuration does not give the pan load
        (``load_mass_kg``) or the load-changer coupling (``load_changer_coupled``): the model
        is never identified with a guessed load.
    IdentificationError
        If channels are missing or inconsistent, or the section table does not fit.
    ConfigError
        If the configuration is invalid.
    """
    cfg = config if isinstance(config, IdentificationConfig) else \
        IdentificationConfig.from_mapping(config)
    channels, fs = _channels(recording, sample_rate_Hz)
    n = channels['position_m'].size
    spans = _spans(experiment_sections, n)
    missing = [k for k in PLANT_KEYS if getattr(cfg, k) is None]
    if cfg.greybox.enabled and missing:
        raise PlantConfigurationError(
            f'the identification options do not give {" and ".join(missing)}: the grey-box '
            f'model needs the mass on the pan and whether the load changer rode on it, and is '
            f'not identified with a guessed load; give `load_mass_kg: KG` and '
            f'`load_changer_coupled: true|false` (or set greybox.enabled: false)')
    report = progress if progress is not None else (lambda step, fraction, message: None)
    result = IdentificationResult(fs, n, spans, cfg)
    if missing:
        result.plant_source = ('not given (not needed: the grey-box step, the only one that '
                               'uses it, is disabled)')
    by_name = {s.name: s for s in spans}
    forces = _forces(channels, cfg)

    done = on_step if on_step is not None else (lambda step, partial: None)
    if cfg.frf.enabled:
        start = time.perf_counter()
        report('frf', 0.0, 'frequency responses')
        _guarded(result, 'frf', _frf_step, result, channels, forces, by_name, report)
        result.timings_s['frf'] = time.perf_counter() - start
        report('frf', 1.0, f'{len(result.frfs)} frequency responses')
        done('frf', result)
    if cfg.tf_fit.enabled and result.frfs:
        start = time.perf_counter()
        _guarded(result, 'tf_fit', _tf_step, result, report)
        result.timings_s['tf_fit'] = time.perf_counter() - start
        done('tf_fit', result)
    if cfg.static.enabled:
        start = time.perf_counter()
        _guarded(result, 'static', _static_step, result, channels, forces, spans)
        result.timings_s['static'] = time.perf_counter() - start
        done('static', result)
    if cfg.greybox.enabled:
        start = time.perf_counter()
        _guarded(result, 'greybox', _greybox_step, result, channels, spans, report, on_step,
                 executor)
        result.timings_s['greybox'] = time.perf_counter() - start
        done('greybox', result)
    report('done', 1.0, f'identification finished with {len(result.warnings)} warning(s)')
    return result


def _guarded(result: IdentificationResult, step: str, run: Callable, *args: Any) -> None:
    """
    Run a step; an identification error it raises is that step's failure, not a crash.

    The result then carries the reason in ``failures`` (its report is written, its status
    is failed) and the next steps still run.
    """
    try:
        run(*args)
    except (IdentificationError, np.linalg.LinAlgError) as exc:
        result.failures.append(f'{step}: {exc}')


# ---------------------------------------------------------------- inputs


def _channels(recording: Any, sample_rate_Hz: Optional[float]
              ) -> Tuple[Dict[str, np.ndarray], float]:
    if hasattr(recording, 'channels') and not isinstance(recording, Mapping):
        source = dict(recording.channels)
        rate = getattr(recording, 'sample_rate_Hz', None)
    elif isinstance(recording, Mapping):
        source = dict(recording)
        rate = source.pop('sample_rate_Hz', None)
    else:
        raise IdentificationError(f'recording must be a mapping of channel arrays or have '
                                  f'.channels and .sample_rate_Hz, got {type(recording)!r}')
    if sample_rate_Hz is not None:
        rate = sample_rate_Hz
    try:
        fs = float(rate)
    except (TypeError, ValueError):
        fs = float('nan')
    if not (math.isfinite(fs) and fs > 0.0):
        raise IdentificationError(f'sample_rate_Hz must be a positive number, got {rate!r}')
    missing = [c for c in REQUIRED_CHANNELS if c not in source]
    if missing:
        raise IdentificationError(f'recording lacks the channels {missing}; it has '
                                  f'{sorted(source)}')
    out = {}
    n = None
    for name, values in source.items():
        arr = np.asarray(values, dtype=float)
        if arr.ndim != 1:
            raise IdentificationError(f'channel {name!r} must be 1-D, got shape {arr.shape}')
        if n is None:
            n = arr.size
        if arr.size != n:
            raise IdentificationError(f'channel {name!r} has {arr.size} samples, others {n}')
        if not np.all(np.isfinite(arr)):
            raise IdentificationError(f'channel {name!r} holds NaN or infinite samples')
        out[name] = arr
    return out, fs


def _spans(table: Sequence[Any], n: int) -> List[Span]:
    spans = []
    for row in table:
        if isinstance(row, Mapping):
            name, first, count = row['name'], row['first_sample_index'], row['n_samples']
        elif hasattr(row, 'first_sample_index'):
            name, first, count = row.name, row.first_sample_index, row.n_samples
        else:
            name, first, count = row
        first, count = int(first), int(count)
        if first < 0 or count < 2 or first + count > n:
            raise IdentificationError(f'section {name!r} [{first}, {first + count}) does not '
                                      f'fit the recording of {n} samples')
        spans.append(Span(str(name), first, count))
    if len({s.name for s in spans}) != len(spans):
        raise IdentificationError('section names must be distinct')
    return spans


#: The recorded force channel each FRF input takes when the recording has it.
FORCE_CHANNELS = {'coil': 'coil_force_N', 'pan': 'load_changer_force_N'}


def _forces(channels: Mapping[str, np.ndarray], cfg: IdentificationConfig
            ) -> Dict[str, np.ndarray]:
    bal = cfg.balance
    coil = channels.get(FORCE_CHANNELS['coil'])
    if coil is None:
        coil = np.asarray(bal.motor.force_N(channels['coil_current_A'], channels['position_m']),
                          dtype=float)
    pan = channels.get(FORCE_CHANNELS['pan'])
    if pan is None:
        pan = np.asarray(bal.load_changer.force_N(channels['load_changer_current_A']),
                         dtype=float)
    return {'coil': coil, 'pan': pan}


# ---------------------------------------------------------------- step (a)


def _compensate(frd: FrequencyResponseData, fs: float, hold: str) -> FrequencyResponseData:
    factor = hold_factor(frd.frequency_Hz, fs, hold)
    details = dict(frd.details, hold_compensation=hold)
    return FrequencyResponseData(frd.frequency_Hz, frd.response / factor, frd.coherence,
                                 frd.std / np.abs(factor), frd.n_averages, frd.estimator,
                                 frd.input_unit, frd.output_unit, details)


@with_single_blas_thread
def _frf_step(result: IdentificationResult, channels: Mapping[str, np.ndarray],
              forces: Mapping[str, np.ndarray], by_name: Mapping[str, Span],
              report: Progress) -> None:
    cfg = result.config.frf
    fs = result.sample_rate_Hz
    y = channels['position_m']
    jobs = [(name, 'coil') for name in cfg.coil_sections] + \
        [(name, 'pan') for name in cfg.pan_sections] + \
        [(name, 'both') for name in cfg.two_input_sections]
    for count, (name, which) in enumerate(jobs):
        span = by_name.get(name)
        if span is None:
            result.warnings.append(f'frf: section {name!r} is not in the recording; skipped')
            continue
        report('frf', count / max(len(jobs), 1), f'FRF of section {name!r}')
        inputs = ['coil', 'pan'] if which == 'both' else [which]
        sl = span.slice
        try:
            frds = _estimate(cfg, [forces[i][sl] for i in inputs], y[sl], fs)
        except IdentificationError as exc:
            result.warnings.append(f'frf: section {name!r}: {exc}')
            continue
        for inp, frd in zip(inputs, frds):
            frd = _compensate(frd, fs, cfg.hold_compensation)
            recorded = FORCE_CHANNELS[inp] in channels
            r = FrfResult(name, inp, frd, two_input=which == 'both', systematic=frf_budget(
                result.config.balance.uncertainties, inp, force_recorded=recorded))
            if which != 'both' and cfg.selected_frequencies_Hz:
                r.selected = _selected(cfg, forces[inp][sl], y[sl], fs, frd)
            result.frfs.append(r)


def _estimate(cfg: Any, inputs: List[np.ndarray], y: np.ndarray, fs: float
              ) -> List[FrequencyResponseData]:
    units = ['N'] * len(inputs)
    if cfg.method == 'lpm':
        return local_polynomial_frf(inputs, y, fs, degree=cfg.lpm_degree,
                                    half_width=cfg.lpm_half_width_lines or None,
                                    frequency_min_Hz=cfg.frequency_min_Hz,
                                    frequency_max_Hz=cfg.frequency_max_Hz,
                                    input_units=units, output_unit='m')
    nperseg = min(cfg.welch_segment_samples, y.size)
    if len(inputs) == 1:
        frds = [estimate_frf(inputs[0], y, fs, nperseg=nperseg, input_unit='N',
                             output_unit='m')]
    else:
        with warnings.catch_warnings():
            warnings.simplefilter('ignore', RuntimeWarning)
            two = estimate_two_input_frf(inputs, y, fs, nperseg=nperseg,
                                         input_units=units, output_unit='m')
        frds = list(two.responses)
    return [f.band(cfg.frequency_min_Hz, cfg.frequency_max_Hz) for f in frds]


#: How far the paper-style table looks for an excited line [DFT lines].
SELECTED_SEARCH_LINES = 50


def _selected(cfg: Any, u: np.ndarray, y: np.ndarray, fs: float,
              frd: FrequencyResponseData) -> Optional[FrequencyResponseData]:
    # The LPM at the DFT line nearest each frequency: unlike the single-frequency DFT it is
    # not spoilt by a transient that has not died out by the end of the section.
    resolution = fs / y.size
    freqs = [f for f in cfg.selected_frequencies_Hz if resolution <= f < fs / 2.0 - resolution]
    if not freqs:
        return None
    values, stds, cohs, lines, requested = [], [], [], [], []
    excitation = detect_excitation([u], degree=cfg.lpm_degree,
                                   half_width=cfg.lpm_half_width_lines or None)
    for f in freqs:
        k = round(f / resolution)
        got = None
        # a sparse multisine may leave the line itself unexcited: the nearest excited one
        for reach in (0.5, 0.5 + SELECTED_SEARCH_LINES):
            try:
                got, = local_polynomial_frf([u], y, fs, degree=cfg.lpm_degree,
                                            half_width=cfg.lpm_half_width_lines or None,
                                            stride=1, frequency_min_Hz=(k - reach) * resolution,
                                            frequency_max_Hz=(k + reach) * resolution,
                                            input_units=['N'], output_unit='m',
                                            excitation=excitation)
                break
            except IdentificationError:
                continue
        if got is None:
            continue
        j = int(np.argmin(np.abs(got.frequency_Hz - f)))
        requested.append(f)
        values.append(got.response[j])
        stds.append(got.std[j])
        cohs.append(got.coherence[j])
        lines.append(got.frequency_Hz[j])
    if not lines:
        return None
    sel = FrequencyResponseData(np.array(lines), np.array(values), np.array(cohs),
                                np.array(stds), frd.n_averages, 'LPM', 'N', 'm',
                                {'requested_frequency_Hz': requested})
    return _compensate(sel, fs, cfg.hold_compensation)


def _spacing(frd: FrequencyResponseData) -> float:
    f = frd.frequency_Hz
    return float(np.median(np.diff(f))) if f.size > 1 else float('inf')


# ---------------------------------------------------------------- step (b)


@with_single_blas_thread
def _tf_step(result: IdentificationResult, report: Progress) -> None:
    cfg = result.config.tf_fit
    candidates = list(zip(cfg.numerator_orders, cfg.denominator_orders))
    singles = [r for r in result.frfs if not r.two_input]
    for count, r in enumerate(singles):
        report('tf_fit', count / max(len(singles), 1), f'transfer-function fit of {r.name}')
        frd = r.frd.select(tf_fit_lines(r.frd))
        # model-structure floor (see STD_FLOOR)
        floor = STD_FLOOR * np.abs(frd.response)
        if np.any(frd.std < floor):
            frd = FrequencyResponseData(frd.frequency_Hz, frd.response, frd.coherence,
                                        np.maximum(frd.std, floor), frd.n_averages,
                                        frd.estimator, frd.input_unit, frd.output_unit,
                                        frd.details)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter('ignore')
                r.fit = select_order(frd, candidates, criterion=cfg.criterion)
        except (IdentificationError, ValueError, np.linalg.LinAlgError) as exc:
            result.warnings.append(f'tf_fit: {r.name}: {exc}')
            continue
        if not r.fit.chosen.is_stable:
            result.warnings.append(f'tf_fit: {r.name}: the chosen fit is not stable')
        lo, hi = fitted_band(r)
        for kind, roots in (('resonance', r.fit.chosen.modes),
                            ('anti-resonance', r.fit.chosen.anti_resonances)):
            for m in roots:
                if not lo <= m.frequency_Hz <= hi:
                    result.warnings.append(
                        f'tf_fit: {r.name}: the {kind} at {m.frequency_Hz:.4g} Hz lies outside '
                        f'the fitted band {lo:.4g} to {hi:.4g} Hz (extrapolated; its '
                        f'uncertainty rests on the model order)')
    report('tf_fit', 1.0, 'transfer-function fits done')


# ---------------------------------------------------------------- step (c)


def find_plateaus(setpoint: np.ndarray, sample_rate_Hz: float, settle_s: float,
                  min_plateau_s: float) -> List[Tuple[int, int]]:
    """
    Runs of a constant setpoint, without their settling time.

    Parameters
    ----------
    setpoint : ndarray
        Setpoint as applied (piecewise constant on a staircase) [V].
    sample_rate_Hz : float
        Sample rate [Hz].
    settle_s : float
        Time dropped at the start of each run [s].
    min_plateau_s : float
        Shortest run kept (after dropping the settling time) [s].

    Returns
    -------
    list of (int, int)
        ``[start, stop)`` sample ranges.
    """
    x = np.asarray(setpoint, dtype=float)
    if x.size == 0:
        return []
    edges = np.flatnonzero(np.diff(x) != 0.0) + 1
    starts = np.concatenate(([0], edges))
    stops = np.concatenate((edges, [x.size]))
    settle = int(round(settle_s * sample_rate_Hz))
    shortest = max(int(round(min_plateau_s * sample_rate_Hz)), 2)
    return [(int(a + settle), int(b)) for a, b in zip(starts, stops) if b - a - settle >= shortest]


@with_single_blas_thread
def _static_step(result: IdentificationResult, channels: Mapping[str, np.ndarray],
                 forces: Mapping[str, np.ndarray], spans: Sequence[Span]) -> None:
    cfg = result.config.static
    fs = result.sample_rate_Hz
    names = cfg.sections or tuple(s.name for s in spans if 'staircase' in s.name)
    chosen = [s for s in spans if s.name in names]
    for missing in sorted(set(names) - {s.name for s in chosen}):
        result.warnings.append(f'static: section {missing!r} is not in the recording; skipped')
    if not chosen:
        return
    pan_force = channels.get('pan_force_N', channels.get('load_changer_force_N'))
    # the current monitors' ADC step in amperes: plateau means of quantised currents are off
    # by up to half of it without dither (see static_fit.with_std_floor)
    conv = result.config.balance.converters
    current_step_A = 2.0 * conv.adc_range_V / 2.0 ** conv.adc_bits / conv.current_monitor_V_per_A
    jobs = [('coil_amplifier', 'coil_setpoint_V', 'coil_current_A', cfg.amplifier_degree,
             'U', 'I', 'V', 'A'),
            ('load_changer_amplifier', 'load_changer_setpoint_V', 'load_changer_current_A',
             cfg.amplifier_degree, 'U', 'I', 'V', 'A')]
    static = StaticResult()
    for key, x_name, y_name, degree, xs, ys, xu, yu in jobs:
        xm, ym = [], []
        for span in chosen:
            sl = span.slice
            for a, b in find_plateaus(channels[x_name][sl], fs, cfg.settle_s,
                                      cfg.min_plateau_s):
                xm.append(channels[x_name][sl][a:b].mean())
                ym.append(channels[y_name][sl][a:b].mean())
        levels = len(set(np.round(xm, 12)))
        if levels <= degree + 1:
            # A curve of degree d has d + 1 coefficients; with no more plateaus than that the
            # fit has no residual to say how good it is (and the least squares refuses).
            if levels:
                result.warnings.append(
                    f'static: {key}: {levels} distinct setpoint levels for a degree-{degree} '
                    f'curve ({degree + 1} coefficients): at least {degree + 2} needed; not '
                    'fitted (the configured characteristic is used)')
            continue
        with warnings.catch_warnings():
            warnings.simplefilter('ignore')
            static.std_floor[key] = current_step_A / math.sqrt(12.0)
            static.fits[key] = with_std_floor(
                fit_polynomial(np.array(xm), np.array(ym), degree, x_name=xs, y_name=ys,
                               x_unit=xu, y_unit=yu), static.std_floor[key])
        static.n_plateaus[key] = len(xm)
        static.points[key] = (np.array(xm), np.array(ym))
        if key == 'load_changer_amplifier' and pan_force is not None:
            im, fm = [], []
            for span in chosen:
                sl = span.slice
                for a, b in find_plateaus(channels[x_name][sl], fs, cfg.settle_s,
                                          cfg.min_plateau_s):
                    im.append(channels[y_name][sl][a:b].mean())
                    fm.append(pan_force[sl][a:b].mean())
            if len(set(np.round(im, 12))) > cfg.load_changer_degree + 1:
                with warnings.catch_warnings():
                    warnings.simplefilter('ignore')
                    fit = fit_polynomial(np.array(im), np.array(fm), cfg.load_changer_degree,
                                         x_name='I', y_name='F', x_unit='A', y_unit='N')
                    # the current (x) is quantised: its step seen through the slope
                    slope = abs(float(np.polynomial.polynomial.polyval(
                        np.median(im), np.polynomial.polynomial.polyder(fit.coefficients))))
                    static.std_floor['load_changer'] = slope * current_step_A / math.sqrt(12.0)
                    static.fits['load_changer'] = with_std_floor(
                        fit, static.std_floor['load_changer'])
                static.n_plateaus['load_changer'] = len(im)
                static.points['load_changer'] = (np.array(im), np.array(fm))
    if not static.fits:
        result.warnings.append('static: no staircase with enough distinct levels')
    stated = result.config.balance.uncertainties
    static.systematic = {key: [static_budget(stated, key, k) for k in range(fit.degree + 1)]
                         for key, fit in static.fits.items()}
    result.static = static


# ---------------------------------------------------------------- step (d)


@with_single_blas_thread
def _greybox_step(result: IdentificationResult, channels: Mapping[str, np.ndarray],
                  spans: Sequence[Span], report: Progress,
                  done: Optional[Callable[[str, Any], None]] = None,
                  executor: Optional[Any] = None) -> None:
    cfg = result.config
    gcfg = cfg.greybox
    # Default: every section but the static staircases, which drive the lever to its stops.
    names = gcfg.sections or tuple(s.name for s in spans if 'staircase' not in s.name)
    chosen = [s for s in spans if s.name in names]
    for missing in sorted(set(names) - {s.name for s in chosen}):
        result.warnings.append(f'greybox: section {missing!r} is not in the recording; '
                               f'skipped')
    if not chosen:
        result.failures.append('greybox: no section to fit')
        return
    jobs = greybox_frf_jobs(cfg, chosen)
    unlisted = [s.name for s in chosen if s.name not in {j[0] for j in jobs}]
    if unlisted:
        result.warnings.append(
            f'greybox: sections {unlisted} are in none of frf.coil_sections, '
            f'frf.pan_sections, frf.two_input_sections: the start and the identifiability '
            f'analysis do not see them (the time-domain fit does)')
    modes, anti = modal_features(result)
    balance, gain_errors, characteristics = cfg.balance, {}, {}
    if gcfg.amplifiers_from_static and result.static is not None and result.static.fits:
        spans_V = {ch: max(float(np.max(np.abs(channels[ch][s.slice]))) for s in chosen)
                   for ch in ('coil_setpoint_V', 'load_changer_setpoint_V')}
        balance, gain_errors, characteristics, warned = unit_amplifiers(
            cfg.balance, result.static.fits, result.static.points, spans_V)
        result.warnings.extend(warned)
    setting = Setting(balance.with_mechanics(**gcfg.initial), cfg.load_mass_kg,
                      cfg.load_changer_coupled, result.sample_rate_Hz)
    responses: Dict[str, np.ndarray] = {}

    def inputs(signals: Any) -> None:
        for s in chosen:
            if s.name in signals.time_s:
                signals.inputs_V[s.name] = np.column_stack((
                    channels['coil_setpoint_V'][s.slice],
                    channels['load_changer_setpoint_V'][s.slice]))

    def with_model(linear_model: Any) -> List[FrfResult]:
        for r in result.frfs:
            responses[r.name] = linear_model.frequency_response(
                r.frd.frequency_Hz, r.input).response_m_per_N
        return [dataclasses.replace(r, model_response=responses[r.name]) for r in result.frfs]

    def model_ready(linear_model: Any, parameters: Dict[str, float]) -> None:
        # The time-domain fit has converged (its derivatives are being checked): the
        # figures of the model alone are drawn meanwhile (the final ones replace them if the
        # fit goes on).
        view = SimpleNamespace(fit=SimpleNamespace(parameters=parameters),
                               linear_model=linear_model)
        done('greybox_model', SimpleNamespace(frfs=with_model(linear_model), greybox=view))

    def fitted(signals: Any) -> None:
        # The time-domain fit has ended: its figures are drawn while its residual tests and
        # checks run (a copy of each FRF carries the model; the result gets it at the end).
        frfs = with_model(signals.linear_model)
        inputs(signals)
        if done is not None:
            done('greybox_fit', SimpleNamespace(frfs=frfs, greybox=signals))

    out, verdict = balance_fit.fit_balance(
        setting, channels, [(s.name, s.first_sample_index, s.n_samples) for s in chosen],
        jobs, modes, anti, gcfg, (cfg.frf.frequency_min_Hz, cfg.frf.frequency_max_Hz),
        cfg.frf.hold_compensation, report, on_fit=fitted, executor=executor,
        on_model=model_ready if done is not None else None,
        identified_amplifiers=gain_errors)
    if out is not None:
        out.characteristics = characteristics
        if PAN_FORCE_SCALE in out.fit.free_names:
            scale = out.fit.parameters[PAN_FORCE_SCALE]
            se = out.fit.standard_errors.get(PAN_FORCE_SCALE, float('nan'))
            out.characteristics = dict(characteristics, load_changer=(
                f"identified (time-domain fit: the file's force constant times {scale:.6g} "
                f"+/- {se:.2g}, relative to the coil's)"))
    result.warnings.extend(verdict.warnings)
    result.failures.extend(verdict.failures)
    if out is None:
        return
    for r in result.frfs:
        r.model_response = responses[r.name]
    inputs(out)
    result.greybox = out
    report('greybox', 1.0, f'grey-box fit done ({out.fit.optimizer_evaluations} evaluations)')


def greybox_frf_jobs(cfg: IdentificationConfig, chosen: Sequence[Span]
                     ) -> List[Tuple[str, int, int, List[str]]]:
    """
    The grey-box's own sections with the inputs each excites (from the FRF section lists).

    The frequency-domain stage (start, identifiability, second start) sees exactly the
    sections and inputs the time-domain fit is given, so that the Fisher information is that
    of the experiment fitted: with ``greybox.sections: [coil_chirp]`` only the coil response,
    which does not separate the mass matrix (issue 12, audit).

    Parameters
    ----------
    cfg : IdentificationConfig
        The configuration (``frf.*_sections`` say which inputs a section excites).
    chosen : sequence of Span
        The sections the grey-box fits.

    Returns
    -------
    list of (str, int, int, list of str)
        ``(name, first_sample_index, n_samples, inputs)``, inputs ``'coil'`` and/or ``'pan'``.
    """
    by_name = {s.name: s for s in chosen}
    return [(n, by_name[n].first_sample_index, by_name[n].n_samples, inputs)
            for group, inputs in ((cfg.frf.coil_sections, ['coil']),
                                  (cfg.frf.pan_sections, ['pan']),
                                  (cfg.frf.two_input_sections, ['coil', 'pan']))
            for n in group if n in by_name]


def modal_features(result: IdentificationResult
                   ) -> Tuple[List[Tuple[float, float, float]],
                              Optional[Tuple[float, float, float]]]:
    """
    The best-measured low and high mode and the coil anti-resonance of the TF fits.

    Parameters
    ----------
    result : IdentificationResult
        Result with step (b) done.

    Returns
    -------
    modes : list of (float, float, float)
        ``(frequency_Hz, damping_ratio, frequency_std_Hz)`` of the low and the high mode,
        each from the single-input fit with the smallest relative uncertainty (empty when no
        fit shows two modes).
    anti_resonance : (float, float, float) or None
        The coil anti-resonance nearest below the high mode, from a coil fit.
    """
    fits = [r for r in result.frfs if r.fit is not None and not r.two_input]
    candidates = [m for r in fits if len(r.fit.chosen.modes) >= 2 for m in
                  (r.fit.chosen.modes[0], r.fit.chosen.modes[-1])]
    if not candidates:
        return [], None
    split = math.sqrt(min(m.frequency_Hz for m in candidates)
                      * max(m.frequency_Hz for m in candidates))

    def best(group: List[Any]) -> Tuple[float, float, float]:
        m = min(group, key=lambda m: (m.frequency_std_Hz / m.frequency_Hz
                                      if math.isfinite(m.frequency_std_Hz) else math.inf))
        return (m.frequency_Hz, m.damping_ratio, m.frequency_std_Hz)

    low = [m for m in candidates if m.frequency_Hz < split]
    high = [m for m in candidates if m.frequency_Hz >= split]
    if not low or not high:
        return [], None
    modes = [best(low), best(high)]
    anti = [a for r in fits if r.input == 'coil' for a in r.fit.chosen.anti_resonances
            if low[0].frequency_Hz < a.frequency_Hz < modes[1][0] * 1.2]
    return modes, (best(anti) if anti else None)


# ---------------------------------------------------------------- serialisation


def _mode_dict(mode: Any, band: Tuple[float, float]) -> dict:
    return {'frequency_Hz': mode.frequency_Hz, 'frequency_std_Hz': mode.frequency_std_Hz,
            'damping_ratio': mode.damping_ratio, 'damping_ratio_std': mode.damping_std,
            'extrapolated': not band[0] <= mode.frequency_Hz <= band[1]}


def tf_fit_lines(frd: FrequencyResponseData) -> np.ndarray:
    """
    Lines of an FRF that its transfer-function fit uses.

    Finite lines with a positive std, and, for an LPM estimate, only lines at least
    :data:`EDGE_WINDOWS` window widths (``2 n + 1`` lines each) above the band's lowest line.
    The band starts where the excitation starts (the chirps' ``f_start_Hz``); below it the
    transient of the lightly damped low mode dominates the output, and near the edge its
    spectrum bends faster than a local polynomial over one window follows. On 100 noise
    repetitions of a drawn balance (``bench/bench_ident_offnominal.py``'s draw 1000, noise
    seeds 50000-50099) the extrapolated 3.5 Hz mode of the coil FRF was biased by -0.91, -0.46
    and +0.02 of its standard uncertainty on average with 0, 1 and 2 windows left out
    (coverage of its 95 % interval 79, 85 and 91 %); the modes inside the band did not change.

    Parameters
    ----------
    frd : FrequencyResponseData
        The FRF.

    Returns
    -------
    ndarray of bool
        The mask.
    """
    keep = np.isfinite(frd.response) & np.isfinite(frd.std) & (frd.std > 0.0)
    details = frd.details or {}
    if frd.estimator == 'LPM' and 'half_width_lines' in details and frd.frequency_Hz.size:
        width_Hz = (2 * int(details['half_width_lines']) + 1) * float(details['resolution_Hz'])
        edge = float(np.min(frd.frequency_Hz)) + EDGE_WINDOWS * width_Hz
        inside = keep & (frd.frequency_Hz >= edge)
        if np.count_nonzero(inside) >= MIN_TF_LINES:
            keep = inside
    return keep


def fitted_band(r: FrfResult) -> Tuple[float, float]:
    """
    Frequency range of the lines an FRF's transfer-function fit saw.

    Parameters
    ----------
    r : FrfResult
        The FRF.

    Returns
    -------
    (float, float)
        Lowest and highest line [Hz] (NaN without lines).
    """
    f = r.frd.frequency_Hz[tf_fit_lines(r.frd)]
    return (float(f.min()), float(f.max())) if f.size else (math.nan, math.nan)


def _frf_dict(r: FrfResult) -> dict:
    frd = r.frd
    out: dict = {
        'name': r.name, 'section': r.section,
        'input': f'{INPUT_NAMES[r.input]} [N]', 'output': 'lever-end position [m]',
        'unit': 'm/N', 'estimator': frd.estimator, 'two_input': r.two_input,
        'n_frequencies': int(frd.frequency_Hz.size),
        'frequency_min_Hz': float(frd.frequency_Hz.min()) if frd.frequency_Hz.size else None,
        'frequency_max_Hz': float(frd.frequency_Hz.max()) if frd.frequency_Hz.size else None,
        'median_coherence': float(np.nanmedian(frd.coherence)) if frd.coherence.size else None,
        'hold_compensation': frd.details.get('hold_compensation', 'none'),
    }
    rel = r.systematic.relative if r.systematic is not None else None
    if r.systematic is not None:
        # the stated characteristics scale the magnitude (not the phase): type B, relative
        out['magnitude_systematic_relative_standard_uncertainty'] = rel
        out['systematic_inputs'] = r.systematic.as_dict()
    # An LPM std comes from a noise variance of few complex residuals (6 or 7, 12 or 14 real
    # degrees of freedom): a 95 % interval of the magnitude or the phase needs Student's t
    # with those degrees of freedom, not 1.96 (GUM G.3); both are reported.
    dof = frd.details.get('dof')
    if dof:
        out['std_degrees_of_freedom'] = 2 * int(dof)
        out['coverage_factor_95'] = float(special.stdtrit(2 * int(dof), 0.975))
    if r.selected is not None:
        s = r.selected
        out['selected_frequencies'] = [
            {'frequency_Hz': f, 'magnitude_m_per_N': abs(h),
             'magnitude_dB_re_1m_per_N': 20.0 * math.log10(abs(h)) if h != 0 else None,
             'phase_deg': math.degrees(float(np.angle(h))),
             'magnitude_std_m_per_N': sd / math.sqrt(2.0),
             'magnitude_systematic_std_m_per_N': abs(h) * (rel or 0.0),
             'magnitude_combined_std_m_per_N': math.hypot(sd / math.sqrt(2.0),
                                                          abs(h) * (rel or 0.0)),
             'phase_std_deg': math.degrees(sd / (math.sqrt(2.0) * abs(h))) if h != 0 else None}
            for f, h, sd in zip(s.frequency_Hz, s.response, s.std)]
    if r.fit is not None:
        c = r.fit.chosen
        out['transfer_function'] = {
            'numerator_order': c.numerator_order, 'denominator_order': c.denominator_order,
            'numerator_s_rad_per_s': list(c.numerator), 'denominator_s_rad_per_s':
                list(c.denominator),
            'stable': bool(c.is_stable), 'criterion': r.fit.criterion,
            'resonances': [_mode_dict(m, fitted_band(r)) for m in c.modes],
            'anti_resonances': [_mode_dict(m, fitted_band(r)) for m in c.anti_resonances],
            'real_zeros_Hz': [z.signed_frequency_Hz for z in c.zeros if z.is_real],
            'order_table': [dict(row) for row in r.fit.table],
            # a scale of the FRF scales the numerator and moves no pole or zero
            'gain_systematic_relative_standard_uncertainty': rel,
        }
    return out


def _static_dict(static: Optional[StaticResult]) -> Optional[dict]:
    if static is None:
        return None
    out = {}
    for key, fit in static.fits.items():
        units = [f'{fit.y_unit}/{fit.x_unit}^{k}' if k > 1 else
                 (f'{fit.y_unit}/{fit.x_unit}' if k == 1 else fit.y_unit)
                 for k in range(fit.degree + 1)]
        budgets = static.systematic.get(key) or [ScaleBudget()] * (fit.degree + 1)
        out[key] = {'formula': fit.formula(),
                    'coefficients_ascending': [
                        {'power': k, 'value': float(v), 'standard_error': float(se),
                         'systematic_standard_uncertainty': abs(float(v)) * b.relative,
                         'combined_standard_uncertainty': math.hypot(
                             float(se), abs(float(v)) * b.relative),
                         'systematic_inputs': b.as_dict(), 'unit': u}
                        for k, (v, se, u, b) in enumerate(
                            zip(fit.coefficients, fit.standard_errors, units, budgets))],
                    'r_squared': fit.r_squared, 'residual_std': fit.residual_std,
                    'residual_std_unit': fit.y_unit, 'n_plateaus': static.n_plateaus.get(key)}
        floor = static.std_floor.get(key, 0.0)
        dof = (static.n_plateaus.get(key) or 0) - (fit.degree + 1)
        out[key]['residual_std_floor'] = floor
        if fit.residual_std < floor:
            # the quantisation floor (a known distribution) sets the standard errors
            out[key]['std_degrees_of_freedom'] = None
            out[key]['coverage_factor_95'] = 1.96
        elif dof > 0:
            # Student t: the standard errors rest on the residuals of a few plateaus
            out[key]['std_degrees_of_freedom'] = dof
            out[key]['coverage_factor_95'] = float(special.stdtrit(dof, 0.975))
    return out


def _to_plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _to_plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_to_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return [_to_plain(v) for v in value.tolist()]
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return v if math.isfinite(v) else None
    if isinstance(value, complex):
        return {'real': value.real, 'imag': value.imag}
    return value
