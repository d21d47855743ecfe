"""
Parameters of the balance model with SI units, defaults and validated loading.

The defaults are the parameter set of ``emfc-model-notes.md`` section 3 and the paper's Table 1
with the unit reading documented in ``docs/model.md``. The same values ship in
``config/balance_default.yaml``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Dict, Mapping, Optional, Union

import numpy as np
import yaml

from emfc_ros.core.config import (get_float, get_float_list, get_int, get_mapping,
                                  join, reject_unknown)
from emfc_ros.core.errors import ConfigError
from emfc_ros.core.model.peripherals import (Amplifier, check_monotonic, LoadChanger,
                                             MotorCoefficient, PositionSensor)
from emfc_ros.core.model.uncertainties import StatedUncertainties
from emfc_ros.core.safe_yaml import load_yaml_file, one_line

#: Length bound used for geometry [m].
_MAX_LENGTH_M = 1.0
_MAX_MASS_KG = 100.0


def _p(default: float, minimum: Optional[float], maximum: Optional[float],
       exclusive: bool = False) -> Any:
    return field(default=default, metadata={'min': minimum, 'max': maximum,
                                            'exclusive': exclusive})


@dataclass(frozen=True)
class MechanicalParameters:
    """
    Two-beam mechanics (notes section 2 and 3). Angles absolute, counter-clockwise positive.

    Attributes
    ----------
    l1_m : float
        Pivot O to pan point [m].
    l2_m : float
        Pivot O to joint J [m] (other side of O).
    l3_m : float
        Joint J to coil, the lever end [m].
    mp_kg : float
        Pan and load carrier mass at the pan point [kg] (without load or load changer).
    m1_kg, r1_m, h1_m, J1c_kgm2 : float
        Transmission lever: mass [kg], centre of mass along the beam towards J [m] and
        perpendicular to it [m], inertia about the centre of mass [kg m^2].
    m2_kg, r2_m, h2_m, J2c_kgm2 : float
        Coil carrier arm (beam 2), the same quantities measured from J.
    m3_kg : float
        Coil and former, a point mass at the lever end [kg].
    c1_Nm_per_rad, d1_Nms_per_rad : float
        Pivot flexure stiffness [N m/rad] and damping [N m s/rad] on ``q1``.
    c2_Nm_per_rad, d2_Nms_per_rad : float
        Joint J stiffness [N m/rad] and damping [N m s/rad] on ``q2 - q1``.
    F_off_N : float
        Constant offset force at the lever end [N], same direction as the coil force.
    g_m_per_s2 : float
        Gravitational acceleration [m/s^2], acting along -z.
    load_changer_mass_kg : float
        Moving mass of the load changer [kg], added to the pan mass when coupled.
    """

    l1_m: float = _p(0.012, 0.0, _MAX_LENGTH_M, True)
    l2_m: float = _p(0.060, 0.0, _MAX_LENGTH_M, True)
    l3_m: float = _p(0.030, 0.0, _MAX_LENGTH_M, True)
    mp_kg: float = _p(0.060, 0.0, _MAX_MASS_KG)
    m1_kg: float = _p(0.030, 0.0, _MAX_MASS_KG)
    r1_m: float = _p(0.020, -_MAX_LENGTH_M, _MAX_LENGTH_M)
    h1_m: float = _p(0.0, -_MAX_LENGTH_M, _MAX_LENGTH_M)
    J1c_kgm2: float = _p(1.225e-5, 0.0, 10.0)
    m2_kg: float = _p(0.004, 0.0, _MAX_MASS_KG)
    r2_m: float = _p(0.015, -_MAX_LENGTH_M, _MAX_LENGTH_M)
    h2_m: float = _p(0.0, -_MAX_LENGTH_M, _MAX_LENGTH_M)
    J2c_kgm2: float = _p(3.0e-7, 0.0, 10.0)
    m3_kg: float = _p(0.015, 0.0, _MAX_MASS_KG)
    c1_Nm_per_rad: float = _p(0.10, 0.0, 1.0e6)
    d1_Nms_per_rad: float = _p(4.21e-4, 0.0, 1.0e3)
    c2_Nm_per_rad: float = _p(20.69, 0.0, 1.0e6, True)
    d2_Nms_per_rad: float = _p(2.28e-4, 0.0, 1.0e3)
    F_off_N: float = _p(0.0, -100.0, 100.0)
    g_m_per_s2: float = _p(9.81, 0.0, 30.0)
    load_changer_mass_kg: float = _p(0.025, 0.0, _MAX_MASS_KG)

    @property
    def J1_kgm2(self) -> float:
        """Inertia of the transmission lever about the pivot O [kg m^2]."""
        return self.J1c_kgm2 + self.m1_kg * (self.r1_m ** 2 + self.h1_m ** 2)

    @property
    def J2_kgm2(self) -> float:
        """Inertia of the coil carrier arm (without the coil) about J [kg m^2]."""
        return self.J2c_kgm2 + self.m2_kg * (self.r2_m ** 2 + self.h2_m ** 2)


@dataclass(frozen=True)
class ConverterParameters:
    """
    Converters, ranges and noise levels the simulator uses (defaults documented in the YAML).

    Attributes
    ----------
    adc_bits, dac_bits : int
        Resolution of the ADC and DAC [bit] (16).
    adc_range_V, dac_range_V : float
        Symmetric full scale, +/- value [V] (10 V: LSB 305 uV).
    coil_current_limit_A, load_changer_current_limit_A : float
        Amplifier output current limit, +/- value [A] (0.1 A).
    sensor_range_m : float
        Position sensor range, +/- value [m] (100e-6 m).
    stop_position_m : float
        Mechanical stops of the lever end, +/- value [m] (150e-6 m, beyond the sensor range).
    sensor_noise_m_rms : float
        Position sensor noise [m rms] (2e-9 m).
    coil_current_noise_A_rms, load_changer_current_noise_A_rms : float
        Amplifier output current noise [A rms] (1e-7 A).
    stop_stiffness_N_per_m : float
        Stiffness of the mechanical stops at the lever end [N/m] (1e6 N/m: about 2 um of
        penetration at the full coil force). Optional in a configuration (default used).
    stop_damping_Ns_per_m : float
        Damping of the mechanical stops while engaged [N s/m] (50 N s/m). Optional.
    current_monitor_V_per_A : float
        Scaling of the amplifiers' current monitor outputs read by the ADC [V/A] (100 V/A:
        +/-0.1 A uses +/-10 V). Optional.
    """

    adc_bits: int = field(default=16, metadata={'min': 1, 'max': 32, 'int': True})
    adc_range_V: float = _p(10.0, 0.0, 1000.0, True)
    dac_bits: int = field(default=16, metadata={'min': 1, 'max': 32, 'int': True})
    dac_range_V: float = _p(10.0, 0.0, 1000.0, True)
    coil_current_limit_A: float = _p(0.1, 0.0, 100.0, True)
    load_changer_current_limit_A: float = _p(0.1, 0.0, 100.0, True)
    sensor_range_m: float = _p(100.0e-6, 0.0, 0.1, True)
    stop_position_m: float = _p(150.0e-6, 0.0, 0.1, True)
    sensor_noise_m_rms: float = _p(2.0e-9, 0.0, 1.0e-3)
    coil_current_noise_A_rms: float = _p(1.0e-7, 0.0, 1.0)
    load_changer_current_noise_A_rms: float = _p(1.0e-7, 0.0, 1.0)
    stop_stiffness_N_per_m: float = field(default=1.0e6, metadata={
        'min': 0.0, 'max': 1.0e9, 'exclusive': True, 'optional': True})
    stop_damping_Ns_per_m: float = field(default=50.0, metadata={
        'min': 0.0, 'max': 1.0e6, 'exclusive': False, 'optional': True})
    current_monitor_V_per_A: float = field(default=100.0, metadata={
        'min': 0.0, 'max': 1.0e6, 'exclusive': True, 'optional': True})


#: Section names of the ``balance`` mapping and the peripheral classes with their single key.
_PERIPHERALS = {
    'coil_amplifier': (Amplifier, 'coeffs_A_per_V_pow'),
    'motor': (MotorCoefficient, 'coeffs_N_per_A_per_mm_pow'),
    'sensor': (PositionSensor, 'coeffs_V_per_m_pow'),
    'load_changer_amplifier': (Amplifier, 'coeffs_A_per_V_pow'),
    'load_changer': (LoadChanger, 'coeffs_N_per_A_pow'),
}


@dataclass(frozen=True)
class BalanceParameters:
    """
    The complete parameter set: mechanics, peripheral characteristics and converters.

    Attributes
    ----------
    mechanics : MechanicalParameters
        The two-beam mechanics.
    coil_amplifier : Amplifier
        Power amplifier of the balance coil (setpoint voltage to current).
    motor : MotorCoefficient
        Position-dependent motor coefficient of the balance coil.
    sensor : PositionSensor
        Lever-end position sensor.
    load_changer_amplifier : Amplifier
        Power amplifier of the load changer.
    load_changer : LoadChanger
        Load changer actuator (current to force on the pan).
    converters : ConverterParameters
        ADC, DAC, ranges, stops and noise levels.
    uncertainties : StatedUncertainties
        Standard uncertainties of the characteristics, geometry and masses the identification
        takes as known (optional section; the simulator does not use it).
    """

    mechanics: MechanicalParameters = field(default_factory=MechanicalParameters)
    coil_amplifier: Amplifier = field(default_factory=Amplifier)
    motor: MotorCoefficient = field(default_factory=MotorCoefficient)
    sensor: PositionSensor = field(default_factory=PositionSensor)
    load_changer_amplifier: Amplifier = field(default_factory=Amplifier)
    load_changer: LoadChanger = field(default_factory=LoadChanger)
    converters: ConverterParameters = field(default_factory=ConverterParameters)
    uncertainties: StatedUncertainties = field(default_factory=StatedUncertainties)

    @classmethod
    def from_mapping(cls, cfg: Mapping[str, Any], path: str = 'balance',
                     base: Optional['BalanceParameters'] = None) -> 'BalanceParameters':
        """
        Build and validate the parameters from the contents of a ``balance`` mapping.

        Parameters
        ----------
        cfg : Mapping
            Mapping with the sections ``mechanics``, ``coil_amplifier``, ``motor``, ``sensor``,
            ``load_changer_amplifier``, ``load_changer`` and ``converters``, and optionally
            ``uncertainties`` (every key optional, defaults of :class:`StatedUncertainties`).
        path : str
            Dotted path of ``cfg`` for error messages.
        base : BalanceParameters, optional
            When given, missing sections and keys take its values (partial overrides);
            without it every key is required.

        Returns
        -------
        BalanceParameters
            The validated parameters.

        Raises
        ------
        ConfigError
            Naming the dotted key and the allowed range of the first invalid value.
        """
        if not isinstance(cfg, Mapping):
            raise ConfigError(path, f'expected a mapping, got {cfg!r}')
        names = [f.name for f in fields(cls)]
        reject_unknown(cfg, names, path)
        values = {}
        for name in names:
            sub = join(path, name)
            current = getattr(base, name) if base is not None else None
            kwargs = {'default': None} if base is not None or name == 'uncertainties' else {}
            section = get_mapping(cfg, name, path, **kwargs)
            if section is None:
                values[name] = current if current is not None else StatedUncertainties()
            elif name in _PERIPHERALS:
                values[name] = _peripheral_from_mapping(name, section, sub, current)
            else:
                klass = {'mechanics': MechanicalParameters,
                         'uncertainties': StatedUncertainties}.get(name, ConverterParameters)
                values[name] = _flat_from_mapping(klass, section, sub, current)
        params = cls(**values)
        _check_consistency(params, path)
        return params

    def to_mapping(self) -> dict:
        """
        Return the contents of the ``balance`` mapping (plain floats, ints and lists).

        Returns
        -------
        dict
            Nested dictionaries that :meth:`from_mapping` accepts.
        """
        out: dict = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name in _PERIPHERALS:
                key = _PERIPHERALS[f.name][1]
                out[f.name] = {key: [float(c) for c in getattr(value, key)]}
            else:
                out[f.name] = {g.name: getattr(value, g.name) for g in fields(value)}
        return out

    @classmethod
    def load_yaml(cls, path: Union[str, Path]) -> 'BalanceParameters':
        """
        Load the parameters from a YAML file.

        Accepted forms: a ROS 2 params file (``<node or /**>: {ros__parameters: {balance:
        {...}}}``) or a plain YAML with a top-level ``balance:`` mapping.

        Parameters
        ----------
        path : str or pathlib.Path
            File name.

        Returns
        -------
        BalanceParameters
            The validated parameters.

        Raises
        ------
        ConfigError
            If the file is unreadable, has neither form or holds an invalid value.
        """
        try:
            doc = load_yaml_file(path)
        except (OSError, yaml.YAMLError) as exc:
            raise ConfigError(str(path), f'cannot read the YAML file: {one_line(exc)}') from exc
        return cls.from_document(doc)

    @classmethod
    def from_document(cls, doc: Any) -> 'BalanceParameters':
        """
        Build the parameters from a parsed YAML document (either accepted form).

        Parameters
        ----------
        doc : Any
            The parsed YAML document.

        Returns
        -------
        BalanceParameters
            The validated parameters.

        Raises
        ------
        ConfigError
            If the document has neither form or holds an invalid value.
        """
        if isinstance(doc, Mapping) and 'balance' in doc:
            return cls.from_mapping(get_mapping(doc, 'balance'), 'balance')
        if isinstance(doc, Mapping):
            for node, content in doc.items():
                ros = content.get('ros__parameters') if isinstance(content, Mapping) else None
                if isinstance(ros, Mapping) and 'balance' in ros:
                    path = f'{node}.ros__parameters'
                    return cls.from_mapping(get_mapping(ros, 'balance', path),
                                            join(path, 'balance'))
        raise ConfigError('balance', 'no top-level balance mapping and no '
                                     '<node>.ros__parameters.balance mapping in the document')

    def with_mechanics(self, **changes: float) -> 'BalanceParameters':
        """
        Return a copy with some mechanical parameters replaced.

        Parameters
        ----------
        **changes : float
            Field names of :class:`MechanicalParameters` and their new values (SI units).

        Returns
        -------
        BalanceParameters
            The modified copy.
        """
        return replace(self, mechanics=replace(self.mechanics, **changes))


def _spec_text(meta: Mapping[str, Any]) -> str:
    lo, hi = meta.get('min'), meta.get('max')
    left = '(' if meta.get('exclusive') else '['
    return f'allowed range {left}{lo!r}, {hi!r}]'


def _flat_from_mapping(klass: Any, cfg: Mapping[str, Any], path: str, base: Any) -> Any:
    names = [f.name for f in fields(klass)]
    reject_unknown(cfg, names, path)
    values: Dict[str, float] = {}
    for f in fields(klass):
        meta = f.metadata
        kwargs: dict = {}
        if base is not None:
            kwargs['default'] = getattr(base, f.name)
        elif meta.get('optional'):
            kwargs['default'] = f.default
        try:
            if meta.get('int'):
                values[f.name] = get_int(cfg, f.name, path, minimum=meta['min'],
                                         maximum=meta['max'], **kwargs)
            else:
                values[f.name] = get_float(cfg, f.name, path, minimum=meta['min'],
                                           maximum=meta['max'],
                                           min_exclusive=meta['exclusive'], **kwargs)
        except ConfigError as exc:
            raise ConfigError(exc.key, f'{exc.problem} ({_spec_text(meta)})') from None
    return klass(**values)


def _working_range(name: str, conv: ConverterParameters) -> Optional[tuple]:
    # Working range of a peripheral's argument, for the monotonicity check.
    if name in ('coil_amplifier', 'load_changer_amplifier'):
        return -conv.dac_range_V, conv.dac_range_V
    if name == 'sensor':
        return -conv.sensor_range_m, conv.sensor_range_m
    if name == 'load_changer':
        return -conv.load_changer_current_limit_A, conv.load_changer_current_limit_A
    return None


def _peripheral_from_mapping(name: str, cfg: Mapping[str, Any], path: str, base: Any) -> Any:
    klass, key = _PERIPHERALS[name]
    reject_unknown(cfg, [key], path)
    kwargs: dict = {}
    if base is not None:
        kwargs['default'] = list(getattr(base, key))
    try:
        coeffs = get_float_list(cfg, key, path, min_length=2, **kwargs)
    except ConfigError as exc:
        raise ConfigError(exc.key, f'{exc.problem} (allowed: a list of at least 2 finite '
                                   f'numbers, ascending powers)') from None
    return klass(tuple(coeffs))


def _check_consistency(params: BalanceParameters, path: str) -> None:
    conv = params.converters
    for name, (_, key) in _PERIPHERALS.items():
        span = _working_range(name, conv)
        coeffs = getattr(getattr(params, name), key)
        if span is not None:
            check_monotonic(coeffs, span[0], span[1], join(join(path, name), key))
    motor = params.motor.coefficient_N_per_A(np.linspace(-conv.stop_position_m,
                                                         conv.stop_position_m, 201))
    if not np.all(motor > 0.0):
        raise ConfigError(join(path, 'motor.coeffs_N_per_A_per_mm_pow'),
                          'the motor coefficient must be positive between the mechanical stops')
    mech = params.mechanics
    m22 = mech.J2_kgm2 + mech.m3_kg * mech.l3_m ** 2
    if not m22 > 0.0:
        raise ConfigError(join(path, 'mechanics'),
                          'beam 2 has no inertia: J2c_kgm2, m2_kg or m3_kg must be positive')
    m11 = mech.J1_kgm2 + mech.mp_kg * mech.l1_m ** 2
    if not m11 > 0.0:
        raise ConfigError(join(path, 'mechanics'),
                          'beam 1 has no inertia: J1c_kgm2, m1_kg or mp_kg must be positive')
