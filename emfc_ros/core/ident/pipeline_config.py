"""
Configuration of the identification pipeline (:mod:`emfc_ros.core.ident.pipeline`).

Built from a plain mapping (the ``identification`` section of a YAML or ROS parameters file),
validated, every key with its unit; a bad value raises :class:`~emfc_ros.core.errors.ConfigError`
naming the dotted key and what is allowed. See ``docs/identification_results.md`` for the table.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any, Dict, Mapping, Optional, Tuple

from emfc_ros.core.config import (get_bool, get_float, get_float_list, get_int, get_mapping,
                                  get_str, get_str_list, join, reject_unknown)
from emfc_ros.core.errors import ConfigError
from emfc_ros.core.ident.balance_names import DEFAULT_FREE, free_names, mechanical_names
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.pan_load import MAX_LOAD_MASS_KG

FRF_METHODS = ('lpm', 'welch')
HOLDS = ('zoh', 'foh', 'none')
GREYBOX_METHODS = ('gauss_newton', 'least_squares', 'pattern_search')
CRITERIA = ('bic', 'aic')


@dataclass(frozen=True)
class FrfConfig:
    """
    Step (a): frequency responses. Keys under ``frf``.

    Attributes
    ----------
    enabled : bool
        Run the step.
    method : {'lpm', 'welch'}
        Local polynomial method (transient-exact, default) or Welch H1 / two-input H1.
    coil_sections, pan_sections : tuple of str
        Single-input sections: position per coil force, position per pan force.
    two_input_sections : tuple of str
        Simultaneous sections: both responses solved jointly.
    frequency_min_Hz, frequency_max_Hz : float
        Band of the FRFs and fits [Hz].
    lpm_degree : int
        Polynomial degree of the LPM.
    lpm_half_width_lines : int
        LPM window half width [DFT lines]; 0 chooses it from the degree.
    welch_segment_samples : int
        Welch segment length [samples].
    hold_compensation : {'zoh', 'foh', 'none'}
        Remove the DAC hold (half-sample delay and sinc of a zero-order hold) from the sampled
        response so that it compares with the continuous model.
    selected_frequencies_Hz : tuple of float
        Frequencies of the paper-style table of amplitude and phase [Hz].
    """

    enabled: bool = True
    method: str = 'lpm'
    coil_sections: Tuple[str, ...] = ('coil_chirp',)
    pan_sections: Tuple[str, ...] = ('load_changer_chirp',)
    two_input_sections: Tuple[str, ...] = ('coil_chirp_load_changer_steps',
                                           'load_changer_chirp_coil_steps')
    frequency_min_Hz: float = 5.0
    frequency_max_Hz: float = 1500.0
    lpm_degree: int = 2
    lpm_half_width_lines: int = 0
    welch_segment_samples: int = 8192
    hold_compensation: str = 'zoh'
    selected_frequencies_Hz: Tuple[float, ...] = (10.0, 20.0, 50.0, 100.0, 200.0, 300.0,
                                                  350.0, 400.0, 500.0, 1000.0)


@dataclass(frozen=True)
class TfFitConfig:
    """
    Step (b): transfer-function and modal fits of the single-input FRFs. Keys under ``tf_fit``.

    Attributes
    ----------
    enabled : bool
        Run the step.
    numerator_orders, denominator_orders : tuple of int
        Candidate orders, pairwise.
    criterion : {'bic', 'aic'}
        Order selection criterion.
    """

    enabled: bool = True
    numerator_orders: Tuple[int, ...] = (0, 2, 3, 4)
    denominator_orders: Tuple[int, ...] = (2, 4, 4, 6)
    criterion: str = 'bic'


@dataclass(frozen=True)
class StaticConfig:
    """
    Step (c): static characteristics from staircase sections. Keys under ``static``.

    Attributes
    ----------
    enabled : bool
        Run the step when staircase sections are present.
    sections : tuple of str
        Staircase sections; empty: every section whose name contains ``staircase``.
    settle_s : float
        Time dropped at the start of each plateau [s].
    min_plateau_s : float
        Shortest plateau used [s].
    amplifier_degree : int
        Degree of the amplifier polynomial ``I(U)`` (the paper: 2).
    load_changer_degree : int
        Degree of the load-changer polynomial ``F(I)`` (the paper: 1).
    """

    enabled: bool = True
    sections: Tuple[str, ...] = ()
    settle_s: float = 0.05
    min_plateau_s: float = 0.1
    amplifier_degree: int = 2
    load_changer_degree: int = 1


@dataclass(frozen=True)
class GreyboxConfig:
    """
    Step (d): grey-box fit of the two-beam model by simulation error. Keys under ``greybox``.

    Attributes
    ----------
    enabled : bool
        Run the step.
    method : {'gauss_newton', 'least_squares', 'pattern_search'}
        Optimiser (:func:`~emfc_ros.core.ident.greybox.fit_greybox`): Gauss-Newton from the
        frequency-domain start (default), scipy's trust-region least squares, or the pattern
        search.
    free : tuple of str
        Free mechanical parameters (names of ``MechanicalParameters``).
    sections : tuple of str
        Sections fitted; empty: all.
    relative_bounds : (float, float)
        Bounds of each free parameter as multiples of its start value.
    offset_force_bound_N : float
        ``F_off_N`` is bounded to +/- this [N].
    max_evaluations : int
        Evaluation budget (0: the optimiser's default).
    initial : dict of str to float
        Start values overriding the balance's mechanics (SI units as the names say).
    initialise_from_frf : bool
        Start the stiffnesses and dampings where the linearised model reproduces the modes of
        the coil FRF fit (when available).
    noise_weighting : bool
        Weight the simulation error by the inverse noise spectrum (estimated from the residual
        at the frequency-domain start): the maximum-likelihood criterion for coloured noise.
        False: the paper's plain simulation error, whose estimates of the high mode and the
        inertias are far less precise where low-frequency process noise dominates.
    mass_relative_uncertainty : float
        Relative standard uncertainty of the configured masses and inertias (mass-matrix
        entries); the identified mass matrix must agree within it (0 disables the check).
    pattern_search_initial_mesh_size : float
        First mesh of the pattern search as a fraction of each parameter's scale (its start
        value; 1 mN for ``F_off_N``). MATLAB's default 1 (steps of 100 %) jumps between the
        local minima of the simulation error of a lightly damped resonance; 0.0625 (6 %)
        stays in the basin found from the FRF.
    initial_setpoints_V : (float, float) or None
        Coil and load-changer setpoints the balance rested under before the record's first
        sample [V] (default 0 V: the outputs of an idle bridge, generator or simulated
        balance); the simulation starts at rest there and applies the first setpoints at
        sample 0. None: at rest under the first setpoints (before issue 28).
    amplifiers_from_static : bool
        The grey-box takes the amplifier curves the static step identified from the
        staircases (current monitors) instead of the balance file's (issue 28: a unit's own
        characteristics); the file's are checked against them. False: the file's.
    """

    enabled: bool = True
    method: str = 'gauss_newton'
    free: Tuple[str, ...] = DEFAULT_FREE
    sections: Tuple[str, ...] = ()
    relative_bounds: Tuple[float, float] = (0.2, 5.0)
    offset_force_bound_N: float = 0.05
    max_evaluations: int = 0
    initial: Dict[str, float] = field(default_factory=dict)
    initialise_from_frf: bool = True
    noise_weighting: bool = True
    mass_relative_uncertainty: float = 0.05
    pattern_search_initial_mesh_size: float = 0.0625
    initial_setpoints_V: Optional[Tuple[float, float]] = (0.0, 0.0)
    amplifiers_from_static: bool = True


@dataclass(frozen=True)
class IdentificationConfig:
    """
    Everything the pipeline needs besides the recording.

    Attributes
    ----------
    load_mass_kg : float or None
        Mass on the pan during the experiment [kg] (sets the model's configuration). None:
        not given; the grey-box step then refuses to run (never a silent 0 kg), see
        :func:`~emfc_ros.core.ident.pipeline.identify`.
    load_changer_coupled : bool or None
        Whether the load changer's moving mass rode on the pan (None: not given, as above).
    frf, tf_fit, static, greybox
        The steps.
    balance : BalanceParameters
        Model parameters: characteristics and start values of the mechanics (key ``balance``,
        partial overrides of the defaults).
    """

    load_mass_kg: Optional[float] = None
    load_changer_coupled: Optional[bool] = None
    frf: FrfConfig = field(default_factory=FrfConfig)
    tf_fit: TfFitConfig = field(default_factory=TfFitConfig)
    static: StaticConfig = field(default_factory=StaticConfig)
    greybox: GreyboxConfig = field(default_factory=GreyboxConfig)
    balance: BalanceParameters = field(default_factory=BalanceParameters)

    @classmethod
    def from_mapping(cls, cfg: Optional[Mapping[str, Any]],
                     path: str = 'identification') -> 'IdentificationConfig':
        """
        Build and validate a configuration; absent keys take their defaults.

        Parameters
        ----------
        cfg : Mapping or None
            The ``identification`` mapping.
        path : str
            Dotted path for error messages.

        Returns
        -------
        IdentificationConfig
            The configuration.

        Raises
        ------
        ConfigError
            Naming the key and what is allowed.
        """
        cfg = {} if cfg is None else cfg
        if not isinstance(cfg, Mapping):
            raise ConfigError(path, f'expected a mapping, got {cfg!r}')
        reject_unknown(cfg, ('load_mass_kg', 'load_changer_coupled', 'frf', 'tf_fit',
                             'static', 'greybox', 'balance'), path)
        d = cls()
        balance = d.balance
        if 'balance' in cfg:
            balance = BalanceParameters.from_mapping(get_mapping(cfg, 'balance', path),
                                                     join(path, 'balance'), base=balance)
        given = {k: v for k, v in cfg.items() if v is not None}    # null: not given
        return cls(
            load_mass_kg=(get_float(given, 'load_mass_kg', path, minimum=0.0,
                                    maximum=MAX_LOAD_MASS_KG)
                          if 'load_mass_kg' in given else None),
            load_changer_coupled=(get_bool(given, 'load_changer_coupled', path)
                                  if 'load_changer_coupled' in given else None),
            frf=_frf(get_mapping(cfg, 'frf', path, default={}), join(path, 'frf')),
            tf_fit=_tf_fit(get_mapping(cfg, 'tf_fit', path, default={}),
                           join(path, 'tf_fit')),
            static=_static(get_mapping(cfg, 'static', path, default={}),
                           join(path, 'static')),
            greybox=_greybox(get_mapping(cfg, 'greybox', path, default={}),
                             join(path, 'greybox')),
            balance=balance)

    def to_dict(self) -> dict:
        """
        Return the configuration as plain data (the ``balance`` as its mapping).

        Returns
        -------
        dict
            Keys as accepted by :meth:`from_mapping`.
        """
        out = {'load_mass_kg': self.load_mass_kg,
               'load_changer_coupled': self.load_changer_coupled}
        for name in ('frf', 'tf_fit', 'static', 'greybox'):
            part = asdict(getattr(self, name))
            out[name] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in part.items()}
        out['balance'] = self.balance.to_mapping()
        return out


def _frf(cfg: Mapping[str, Any], path: str) -> FrfConfig:
    d = FrfConfig()
    reject_unknown(cfg, d.__dataclass_fields__, path)
    lo = get_float(cfg, 'frequency_min_Hz', path, default=d.frequency_min_Hz, minimum=0.0)
    hi = get_float(cfg, 'frequency_max_Hz', path, default=d.frequency_max_Hz, minimum=lo,
                   min_exclusive=True)
    return FrfConfig(
        enabled=get_bool(cfg, 'enabled', path, default=d.enabled),
        method=get_str(cfg, 'method', path, default=d.method, choices=FRF_METHODS),
        coil_sections=tuple(get_str_list(cfg, 'coil_sections', path,
                                         default=list(d.coil_sections))),
        pan_sections=tuple(get_str_list(cfg, 'pan_sections', path,
                                        default=list(d.pan_sections))),
        two_input_sections=tuple(get_str_list(cfg, 'two_input_sections', path,
                                              default=list(d.two_input_sections))),
        frequency_min_Hz=lo, frequency_max_Hz=hi,
        lpm_degree=get_int(cfg, 'lpm_degree', path, default=d.lpm_degree, minimum=0,
                           maximum=6),
        lpm_half_width_lines=get_int(cfg, 'lpm_half_width_lines', path,
                                     default=d.lpm_half_width_lines, minimum=0, maximum=1000),
        welch_segment_samples=get_int(cfg, 'welch_segment_samples', path,
                                      default=d.welch_segment_samples, minimum=16),
        hold_compensation=get_str(cfg, 'hold_compensation', path,
                                  default=d.hold_compensation, choices=HOLDS),
        selected_frequencies_Hz=tuple(get_float_list(
            cfg, 'selected_frequencies_Hz', path, default=list(d.selected_frequencies_Hz),
            minimum=0.0)))


def _tf_fit(cfg: Mapping[str, Any], path: str) -> TfFitConfig:
    d = TfFitConfig()
    reject_unknown(cfg, d.__dataclass_fields__, path)
    nums = get_float_list(cfg, 'numerator_orders', path, default=list(d.numerator_orders),
                          min_length=1, minimum=0, maximum=20)
    dens = get_float_list(cfg, 'denominator_orders', path,
                          default=list(d.denominator_orders), min_length=1, minimum=1,
                          maximum=20)
    if len(nums) != len(dens) or any(int(v) != v for v in nums + dens) or \
            any(n > m for n, m in zip(nums, dens)):
        raise ConfigError(join(path, 'numerator_orders'),
                          'numerator_orders and denominator_orders must be integer lists of '
                          'equal length with numerator <= denominator pairwise')
    return TfFitConfig(enabled=get_bool(cfg, 'enabled', path, default=d.enabled),
                       numerator_orders=tuple(int(v) for v in nums),
                       denominator_orders=tuple(int(v) for v in dens),
                       criterion=get_str(cfg, 'criterion', path, default=d.criterion,
                                         choices=CRITERIA))


def _static(cfg: Mapping[str, Any], path: str) -> StaticConfig:
    d = StaticConfig()
    reject_unknown(cfg, d.__dataclass_fields__, path)
    return StaticConfig(
        enabled=get_bool(cfg, 'enabled', path, default=d.enabled),
        sections=tuple(get_str_list(cfg, 'sections', path, default=list(d.sections))),
        settle_s=get_float(cfg, 'settle_s', path, default=d.settle_s, minimum=0.0),
        min_plateau_s=get_float(cfg, 'min_plateau_s', path, default=d.min_plateau_s,
                                minimum=0.0, min_exclusive=True),
        amplifier_degree=get_int(cfg, 'amplifier_degree', path, default=d.amplifier_degree,
                                 minimum=1, maximum=5),
        load_changer_degree=get_int(cfg, 'load_changer_degree', path,
                                    default=d.load_changer_degree, minimum=1, maximum=5))


def _greybox(cfg: Mapping[str, Any], path: str) -> GreyboxConfig:
    d = GreyboxConfig()
    reject_unknown(cfg, d.__dataclass_fields__, path)
    names = mechanical_names()
    free = tuple(get_str_list(cfg, 'free', path, default=list(d.free), min_length=1))
    bad = [n for n in free if n not in free_names()]
    if bad or len(set(free)) != len(free):
        raise ConfigError(join(path, 'free'), f'unknown or repeated parameters {bad or free}; '
                                              f'allowed: {list(free_names())}')
    bounds = get_float_list(cfg, 'relative_bounds', path, default=list(d.relative_bounds),
                            min_length=2, minimum=0.0)
    if len(bounds) != 2 or not 0.0 < bounds[0] <= 1.0 <= bounds[1]:
        raise ConfigError(join(path, 'relative_bounds'),
                          f'need [lower, upper] with 0 < lower <= 1 <= upper, got {bounds}')
    initial_cfg = get_mapping(cfg, 'initial', path, default={})
    reject_unknown(initial_cfg, names, join(path, 'initial'))
    initial = {k: get_float(initial_cfg, k, join(path, 'initial')) for k in initial_cfg}
    start: Optional[Tuple[float, float]] = d.initial_setpoints_V
    if 'initial_setpoints_V' in cfg and cfg['initial_setpoints_V'] is None:
        start = None
    elif 'initial_setpoints_V' in cfg:
        pair = get_float_list(cfg, 'initial_setpoints_V', path, min_length=2)
        if len(pair) != 2:
            raise ConfigError(join(path, 'initial_setpoints_V'),
                              f'need [coil_V, load_changer_V] or null, got {pair}')
        start = (float(pair[0]), float(pair[1]))
    return GreyboxConfig(
        enabled=get_bool(cfg, 'enabled', path, default=d.enabled),
        method=get_str(cfg, 'method', path, default=d.method, choices=GREYBOX_METHODS),
        free=free,
        sections=tuple(get_str_list(cfg, 'sections', path, default=list(d.sections))),
        relative_bounds=(float(bounds[0]), float(bounds[1])),
        offset_force_bound_N=get_float(cfg, 'offset_force_bound_N', path,
                                       default=d.offset_force_bound_N, minimum=0.0,
                                       min_exclusive=True),
        max_evaluations=get_int(cfg, 'max_evaluations', path, default=d.max_evaluations,
                                minimum=0),
        initial=initial,
        initialise_from_frf=get_bool(cfg, 'initialise_from_frf', path,
                                     default=d.initialise_from_frf),
        noise_weighting=get_bool(cfg, 'noise_weighting', path, default=d.noise_weighting),
        mass_relative_uncertainty=get_float(cfg, 'mass_relative_uncertainty', path,
                                            default=d.mass_relative_uncertainty, minimum=0.0,
                                            maximum=10.0),
        pattern_search_initial_mesh_size=get_float(
            cfg, 'pattern_search_initial_mesh_size', path,
            default=d.pattern_search_initial_mesh_size, minimum=0.0, maximum=100.0,
            min_exclusive=True),
        initial_setpoints_V=start,
        amplifiers_from_static=get_bool(cfg, 'amplifiers_from_static', path,
                                        default=d.amplifiers_from_static))
