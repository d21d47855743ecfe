"""
Grey-box model of the balance for :func:`~emfc_ros.core.ident.greybox.fit_greybox`.

The model is the plant simulator itself (:class:`~emfc_ros.core.sim.Simulator`, numba kernel)
with noise and quantisation switched off: the recorded setpoint voltages (as applied by the DAC,
so already quantised and exactly known) go through the amplifier, motor and load-changer
characteristics and the nonlinear two-beam mechanics to the lever-end position, including the
sensor's range clipping. Setpoints rather than measured currents are the inputs because they
carry no measurement noise (the current monitors add ADC quantisation, an errors-in-variables
problem); the characteristics come from the configuration (or the static fits).

The whole record is simulated once per parameter set, starting at rest under the setpoints the
balance rested under before the record (``initial_setpoints_V``, default 0 V; the first
setpoints act from sample 0), and each section's simulate call returns its slice: the sections
then start from the state the previous sections left, as in the experiment. Sections are
recognised because their input arrays are views into the recorded setpoints (as
:meth:`BalanceGreyboxModel.sections` builds them); any other input array is simulated on its
own, from rest.

:meth:`BalanceGreyboxModel.output_derivatives` gives the fit its Jacobian from the linearised
model (:mod:`~emfc_ros.core.ident.linear_sensitivity`), which the fit checks against the
simulation (issue 14).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import replace
import threading
from typing import Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from emfc_ros.core.ident.balance_names import (DEFAULT_FREE, mechanical_names,  # noqa: F401
                                               PAN_FORCE_SCALE)
from emfc_ros.core.ident.greybox import DataSection
from emfc_ros.core.ident.linear_sensitivity import LinearSensitivity
from emfc_ros.core.model.operating_point import equilibrium, rest_position
from emfc_ros.core.model.parameters import BalanceParameters, MechanicalParameters
from emfc_ros.core.model.peripherals import LoadChanger
from emfc_ros.core.sim import min_substeps, Simulator

#: Pseudo-parameters standing for the lever and coil-carrier inertias and the coil mass: the
#: entries of the mass matrix at rest in the experiment's configuration [kg m^2], which is
#: what the data determine. ``J1c_kgm2``, ``m3_kg`` and ``J2c_kgm2`` follow from them (the
#: entries are affine in those three) given the fixed masses, lengths and pan load.
MASS_MATRIX_NAMES = ('M11_kgm2', 'M12_kgm2', 'M22_kgm2')
#: The mechanical parameters the mass-matrix entries set.
MASS_COORDINATES = ('J1c_kgm2', 'm3_kg', 'J2c_kgm2')
#: Steps of the coordinates for the affine map (exact for any step: M is linear in them).
_COORDINATE_STEPS = (1.0e-6, 1.0e-3, 1.0e-7)

#: Pseudo-parameter of the time-domain fit standing for ``F_off_N``: the lever-end rest
#: position under the initial setpoints (before the record's first sample) [m]. The offset
#: force that gives it is solved from the static equilibrium for every parameter set, so
#: that changing a mass (and with it the weight moments) does not move the simulated lever
#: out of the sensor range.
REST_POSITION = 'rest_position_m'

#: Units of the mechanical parameters by name suffix (longest first).
_UNITS = (('_Nms_per_rad', 'N m s/rad'), ('_Nm_per_rad', 'N m/rad'), ('_m_per_s2', 'm/s^2'),
          ('_kgm2', 'kg m^2'), ('_kg', 'kg'), ('_N', 'N'), ('_m', 'm'))

#: Row of the position channel in the simulator output.
_POSITION = 'position_m'
#: Full-record simulations kept (one per thread evaluating residuals, and the last point).
_CACHED_RECORDS = 4


def unit_of(name: str) -> str:
    """
    Unit of a mechanical parameter from the suffix of its name.

    Parameters
    ----------
    name : str
        Field name of :class:`MechanicalParameters`.

    Returns
    -------
    str
        The SI unit ('' if unknown).
    """
    for suffix, unit in _UNITS:
        if name.endswith(suffix):
            return unit
    return ''


def rest_state(params: BalanceParameters, setpoints_V: Sequence[float], load_mass_kg: float,
               load_changer_coupled: bool) -> np.ndarray:
    """
    State of rest of the open-loop balance under constant setpoints (no stops).

    Parameters
    ----------
    params : BalanceParameters
        The balance.
    setpoints_V : sequence of float
        Coil and load-changer setpoints [V].
    load_mass_kg : float
        Mass on the pan [kg].
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan.

    Returns
    -------
    ndarray, shape (4,)
        ``[q1, q2, 0, 0]`` [rad, rad/s].
    """
    i_coil = float(params.coil_amplifier.current_A(float(setpoints_V[0])))
    i_lc = float(params.load_changer_amplifier.current_A(float(setpoints_V[1])))
    f_pan = float(params.load_changer.force_N(i_lc))
    y = 0.0
    op = None
    for _ in range(3):        # the motor coefficient depends (weakly) on the position
        f_coil = float(params.motor.force_N(i_coil, y))
        op = rest_position(params.mechanics, f_coil, load_mass_kg, load_changer_coupled,
                           F_p_N=f_pan)
        y = op.y_m
    return op.x


def offset_force_N(params: BalanceParameters, setpoints_V: Sequence[float],
                   load_mass_kg: float, load_changer_coupled: bool, rest_position_m: float
                   ) -> float:
    """
    Offset force that puts the lever end at rest at a given position under given setpoints.

    Parameters
    ----------
    params : BalanceParameters
        The balance (its ``F_off_N`` is ignored).
    setpoints_V : sequence of float
        Coil and load-changer setpoints [V].
    load_mass_kg : float
        Mass on the pan [kg].
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan.
    rest_position_m : float
        Wanted rest position of the lever end [m].

    Returns
    -------
    float
        ``F_off_N`` [N]: the lever-end force that holds the beams at that position
        (:func:`~emfc_ros.core.model.operating_point.equilibrium`, one Newton solve) less the
        coil force there.
    """
    return _offset_and_rest(params, setpoints_V, load_mass_kg, load_changer_coupled,
                            rest_position_m)[0]


def _offset_and_rest(params: BalanceParameters, setpoints_V: Sequence[float],
                     load_mass_kg: float, load_changer_coupled: bool, rest_position_m: float
                     ) -> Tuple[float, np.ndarray]:
    """``F_off_N`` for a rest position (see :func:`offset_force_N`) and that rest state."""
    i_coil = float(params.coil_amplifier.current_A(float(setpoints_V[0])))
    i_lc = float(params.load_changer_amplifier.current_A(float(setpoints_V[1])))
    f_pan = float(params.load_changer.force_N(i_lc))
    y = float(rest_position_m)
    op = equilibrium(params.mechanics, load_mass_kg, load_changer_coupled, F_off_N=0.0,
                     F_p_N=f_pan, y_m=y)
    return float(op.F_c_N - params.motor.force_N(i_coil, y)), op.x


def mass_matrix_entries(mech: MechanicalParameters, load_mass_kg: float,
                        load_changer_coupled: bool) -> np.ndarray:
    """
    ``[M11, M12, M22]`` at rest in a configuration.

    Parameters
    ----------
    mech : MechanicalParameters
        The empty, uncoupled mechanics.
    load_mass_kg : float
        Mass on the pan [kg].
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan.

    Returns
    -------
    ndarray, shape (3,)
        The entries [kg m^2].
    """
    from emfc_ros.core.model.load import loaded
    from emfc_ros.core.model.mechanics import mass_matrix

    m = mass_matrix(np.zeros(2), loaded(mech, load_mass_kg, load_changer_coupled))
    return np.array([m[0, 0], m[0, 1], m[1, 1]])


def coordinates_for(mech: MechanicalParameters, load_mass_kg: float,
                    load_changer_coupled: bool, entries: Sequence[float]) -> Dict[str, float]:
    """
    ``J1c``, ``m3`` and ``J2c`` that give wanted mass-matrix entries (others fixed).

    Parameters
    ----------
    mech : MechanicalParameters
        The mechanics (fixed masses and lengths).
    load_mass_kg : float
        Mass on the pan [kg].
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan.
    entries : sequence of float
        Wanted ``[M11, M12, M22]`` [kg m^2].

    Returns
    -------
    dict of str to float
        The three coordinates (may be negative when the fixed masses cannot give the entries;
        :class:`MechanicalParameters` then refuses them).
    """
    base = np.array([getattr(mech, n) for n in MASS_COORDINATES], dtype=float)
    m0 = mass_matrix_entries(mech, load_mass_kg, load_changer_coupled)
    cols = []
    for i, (name, step) in enumerate(zip(MASS_COORDINATES, _COORDINATE_STEPS)):
        moved = replace(mech, **{name: base[i] + step})
        cols.append((mass_matrix_entries(moved, load_mass_kg, load_changer_coupled) - m0) / step)
    x = base + np.linalg.solve(np.column_stack(cols), np.asarray(entries, dtype=float) - m0)
    return dict(zip(MASS_COORDINATES, (float(v) for v in x)))


def with_values(params: BalanceParameters, values: Mapping[str, float], load_mass_kg: float,
                load_changer_coupled: bool) -> BalanceParameters:
    """
    A balance with mechanical parameters and mass-matrix entries replaced.

    Parameters
    ----------
    params : BalanceParameters
        The balance.
    values : mapping of str to float
        Mechanical parameters, any of :data:`MASS_MATRIX_NAMES` and
        :data:`~emfc_ros.core.ident.balance_names.PAN_FORCE_SCALE` (a factor on the
        load-changer characteristic; ``rest_position_m`` is ignored here).
    load_mass_kg : float
        Mass on the pan [kg].
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan.

    Returns
    -------
    BalanceParameters
        The modified copy.
    """
    skip = (REST_POSITION, PAN_FORCE_SCALE) + MASS_MATRIX_NAMES
    out = params.with_mechanics(**{k: float(v) for k, v in values.items() if k not in skip})
    if PAN_FORCE_SCALE in values:
        scale = float(values[PAN_FORCE_SCALE])
        out = replace(out, load_changer=LoadChanger(tuple(
            scale * c for c in params.load_changer.coeffs_N_per_A_pow)))
    if any(n in values for n in MASS_MATRIX_NAMES):
        now = mass_matrix_entries(out.mechanics, load_mass_kg, load_changer_coupled)
        wanted = [float(values.get(n, v)) for n, v in zip(MASS_MATRIX_NAMES, now)]
        out = out.with_mechanics(**coordinates_for(out.mechanics, load_mass_kg,
                                                   load_changer_coupled, wanted))
    return out


class BalanceGreyboxModel:
    """
    The recorded setpoints and the simulation of the balance model over them.

    Parameters
    ----------
    params : BalanceParameters
        The model's balance: characteristics, converters and the start values of the mechanics.
    sample_rate_Hz : float
        Sample rate of the recording [Hz].
    setpoints_V : ndarray, shape (n, 2)
        Coil and load-changer setpoints as applied [V], one row per sample.
    load_mass_kg : float
        Mass on the pan during the experiment [kg].
    load_changer_coupled : bool
        Whether the load changer's moving mass rode on the pan.
    hold : {'zoh', 'foh'}
        Hold of the setpoints in the simulation (as the DAC of the experiment).
    backend : {'auto', 'numba', 'numpy'}
        The simulator's kernel (:class:`~emfc_ros.core.sim.Simulator`).

    Attributes
    ----------
    n_simulations : int
        Full-record simulations run so far.
    """

    def __init__(self, params: BalanceParameters, sample_rate_Hz: float,
                 setpoints_V: np.ndarray, load_mass_kg: float,
                 load_changer_coupled: bool, hold: str = 'zoh', backend: str = 'auto',
                 initial_setpoints_V: Optional[Sequence[float]] = None) -> None:
        u = np.ascontiguousarray(setpoints_V, dtype=float)
        if u.ndim != 2 or u.shape[1] != 2 or u.shape[0] < 2:
            raise ValueError(f'setpoints_V must have shape (n >= 2, 2), got {u.shape}')
        start = (u[0] if initial_setpoints_V is None
                 else np.asarray(initial_setpoints_V, dtype=float))
        if start.shape != (2,) or not np.all(np.isfinite(start)):
            raise ValueError(f'initial_setpoints_V must be 2 finite voltages, got '
                             f'{initial_setpoints_V!r}')
        #: Setpoints the balance rests under before sample 0 [V] (the record's start).
        self.initial_setpoints_V = np.array(start, dtype=float)
        self.params = params
        self.sample_rate_Hz = float(sample_rate_Hz)
        self.setpoints_V = u
        self.load_mass_kg = float(load_mass_kg)
        self.load_changer_coupled = bool(load_changer_coupled)
        self.hold = hold
        self.backend = backend
        self.n_simulations = 0
        self._u_rows = np.ascontiguousarray(u.T)
        # the last few full-record simulations by parameter set: the fit evaluates the
        # Jacobian's columns in threads (the kernel releases the GIL), each asking for its
        # sections in turn
        self._cache: 'OrderedDict[tuple, np.ndarray]' = OrderedDict()
        self._lock = threading.Lock()
        self._sensitivity: Optional[LinearSensitivity] = None
        self._derivatives: Optional[np.ndarray] = None
        self._derivatives_key: Optional[tuple] = None
        self._input_derivatives: Optional[np.ndarray] = None
        self._input_derivatives_key: Optional[tuple] = None

    def balance(self, values: Mapping[str, float]) -> BalanceParameters:
        """
        The model's parameters with some mechanical parameters replaced.

        Parameters
        ----------
        values : mapping of str to float
            Mechanical parameter names and values.

        Returns
        -------
        BalanceParameters
            The modified copy; a ``rest_position_m`` entry is turned into the ``F_off_N`` that
            gives that rest position under the first recorded setpoints.
        """
        return self.start(values)[0]

    def start(self, values: Mapping[str, float]) -> Tuple[BalanceParameters, np.ndarray]:
        """
        The balance for some parameters and its state of rest under the first setpoints.

        Parameters
        ----------
        values : mapping of str to float
            As for :meth:`balance`.

        Returns
        -------
        params : BalanceParameters
            :meth:`balance`'s result.
        x0 : ndarray, shape (4,)
            :func:`rest_state` of it under the initial setpoints (from the same equilibrium
            solve when ``values`` give the rest position).
        """
        params = with_values(self.params, values, self.load_mass_kg, self.load_changer_coupled)
        if REST_POSITION in values:
            force, x0 = _offset_and_rest(params, self.initial_setpoints_V, self.load_mass_kg,
                                         self.load_changer_coupled,
                                         float(values[REST_POSITION]))
            return params.with_mechanics(F_off_N=force), x0
        return params, rest_state(params, self.initial_setpoints_V, self.load_mass_kg,
                                  self.load_changer_coupled)

    def simulate_setpoints(self, values: Mapping[str, float], setpoints_V: np.ndarray,
                           ) -> np.ndarray:
        """
        Simulate the position for setpoints, from rest (the record: under the initial ones).

        Parameters
        ----------
        values : mapping of str to float
            Mechanical parameters (others from :attr:`params`).
        setpoints_V : ndarray, shape (n, 2)
            Coil and load-changer setpoints [V].

        Returns
        -------
        ndarray, shape (n,)
            Lever-end position [m] as the sensor reports it (range clipping, no noise).
        """
        u = np.asarray(setpoints_V, dtype=float)
        if u is self.setpoints_V:
            params, x0 = self.start(values)
            before = self.initial_setpoints_V
        else:
            params = self.balance(values)
            x0 = rest_state(params, u[0], self.load_mass_kg, self.load_changer_coupled)
            before = u[0]
        sim = Simulator(params, self.sample_rate_Hz, 0, hold=self.hold, noise=False,
                        quantisation=False, reference_channels=False,
                        load_mass_kg=self.load_mass_kg,
                        load_changer_coupled=self.load_changer_coupled, x0=x0,
                        initial_setpoints_V=before, backend=self.backend)
        rows = self._u_rows if u is self.setpoints_V else np.ascontiguousarray(u.T)
        out = sim.step_block(rows)
        return out[sim.channel_names.index(_POSITION)]

    def simulate_record(self, values: Mapping[str, float]) -> np.ndarray:
        """
        Simulate the whole record (the last few parameter sets are cached; thread-safe).

        Parameters
        ----------
        values : mapping of str to float
            Mechanical parameters.

        Returns
        -------
        ndarray, shape (n,)
            Position [m].
        """
        key = tuple(sorted((k, float(v)) for k, v in values.items()))
        with self._lock:
            hit = self._cache.get(key)
            if hit is not None:
                self._cache.move_to_end(key)
                return hit
        out = self.simulate_setpoints(values, self.setpoints_V)
        with self._lock:
            self._cache[key] = out
            while len(self._cache) > _CACHED_RECORDS:
                self._cache.popitem(last=False)
            self.n_simulations += 1
        return out

    def offset(self, inputs: np.ndarray) -> Optional[int]:
        """
        First sample of a section's inputs in the recording.

        Parameters
        ----------
        inputs : ndarray
            Setpoints of a section.

        Returns
        -------
        int or None
            The index, or None when the array is not a view into the recorded setpoints.
        """
        base = self.setpoints_V
        if not (isinstance(inputs, np.ndarray) and inputs.ndim == 2 and inputs.shape[1] == 2
                and inputs.strides == base.strides and np.shares_memory(inputs, base)):
            return None
        delta = inputs.__array_interface__['data'][0] - base.__array_interface__['data'][0]
        if delta % base.strides[0]:
            return None
        first = delta // base.strides[0]
        if first < 0 or first + inputs.shape[0] > base.shape[0]:
            return None
        return int(first)

    def simulate(self, values: Mapping[str, float], inputs: np.ndarray) -> np.ndarray:
        """
        Simulate one data section: the callable given to :func:`fit_greybox`.

        Parameters
        ----------
        values : mapping of str to float
            Mechanical parameters.
        inputs : ndarray, shape (n, 2)
            Setpoints [V]: a view into the recording (then the slice of the full-record
            simulation is returned) or any other array (simulated on its own from rest).

        Returns
        -------
        ndarray, shape (n,)
            Position [m].
        """
        first = self.offset(inputs)
        if first is None:
            return self.simulate_setpoints(values, inputs)
        return self.simulate_record(values)[first:first + inputs.shape[0]]

    def output_derivatives(self, values: Mapping[str, float], names: Sequence[str],
                           inputs: np.ndarray) -> Optional[np.ndarray]:
        """
        Derivatives of a section's simulated position, from the linearised model.

        The ``output_derivatives`` of :func:`~emfc_ros.core.ident.greybox.fit_greybox`
        (:mod:`~emfc_ros.core.ident.linear_sensitivity`): the fit takes its Jacobian from them
        and checks them against the simulation.

        Parameters
        ----------
        values : mapping of str to float
            All parameters of the fit (mechanical, mass-matrix entries, rest position).
        names : sequence of str
            The free ones, in the Jacobian's column order.
        inputs : ndarray, shape (n, 2)
            Setpoints of a section: a view into the recording.

        Returns
        -------
        ndarray, shape (n, len(names)) or None
            ``d position / d parameter`` [m per unit]; None for inputs that are not a view
            into the recording or a first-order hold (the fit then differentiates the
            simulation).
        """
        first = self.offset(inputs)
        if first is None or self.hold != 'zoh':
            return None
        key = (tuple(sorted((k, float(v)) for k, v in values.items())), tuple(names))
        with self._lock:
            cached = self._derivatives if self._derivatives_key == key else None
        if cached is None:
            params, x0 = self.start(values)
            mech = [n for n in names if n != PAN_FORCE_SCALE]
            part = self._linear(params).derivatives(
                params, x0, mech, values,
                lambda v: with_values(self.params, v, self.load_mass_kg,
                                      self.load_changer_coupled), REST_POSITION)
            if len(mech) == len(names):
                cached = part
            else:
                # the pan force F = s F_file: dy/ds is the pan part of the response over s
                cached = np.zeros((part.shape[0], len(names)))
                for j, n in enumerate(mech):
                    cached[:, names.index(n)] = part[:, j]
                pan = self._linear(params).input_responses(params, x0)[:, 1]
                cached[:, list(names).index(PAN_FORCE_SCALE)] = pan / float(
                    values[PAN_FORCE_SCALE])
            with self._lock:
                self._derivatives, self._derivatives_key = cached, key
        return cached[first:first + inputs.shape[0]]

    def input_derivatives(self, values: Mapping[str, float], names: Sequence[str],
                          inputs: np.ndarray, outputs: np.ndarray) -> Optional[np.ndarray]:
        """
        Derivatives of a section's output error by inputs the fit takes as known.

        ``fit_greybox``'s ``systematic`` (:mod:`~emfc_ros.core.ident.systematic`): from the
        linearised model, at the fit's parameter values.

        Parameters
        ----------
        values : mapping of str to float
            All parameters of the fit.
        names : sequence of str
            Known inputs: ``position_scale`` (the measured position scaled by ``1 + beta``),
            ``coil_force_scale`` and ``pan_force_scale`` (an input force scaled by ``1 +
            beta``), or a fixed mechanical parameter by name (per unit of it, the fitted ones
            held: mass-matrix entries stay, their coordinates follow).
        inputs : ndarray, shape (n, 2)
            Setpoints of a section: a view into the recording.
        outputs : ndarray, shape (n,)
            The measured position of the section [m].

        Returns
        -------
        ndarray, shape (n, len(names)) or None
            ``d(y_hat - y) / d beta`` [m per unit]; None where the linearised model does not
            serve (inputs not a view into the recording, first-order hold).
        """
        first = self.offset(inputs)
        if first is None or self.hold != 'zoh':
            return None
        n = inputs.shape[0]
        model_names = tuple(m for m in names if m != 'position_scale')
        key = (tuple(sorted((k, float(v)) for k, v in values.items())), model_names)
        cached = self._input_derivatives if self._input_derivatives_key == key else None
        if cached is None:
            cached = self._record_input_derivatives(values, model_names)
            self._input_derivatives, self._input_derivatives_key = cached, key
        out = np.zeros((n, len(names)))
        for k, name in enumerate(names):
            if name == 'position_scale':
                out[:, k] = -np.asarray(outputs, dtype=float).reshape(n)
            else:
                out[:, k] = cached[first:first + n, model_names.index(name)]
        return out

    def _linear(self, params: BalanceParameters) -> LinearSensitivity:
        """The linearised model of the record (made once: its inputs are fixed)."""
        if self._sensitivity is None:
            self._sensitivity = LinearSensitivity(
                self.setpoints_V, self.sample_rate_Hz, self.load_mass_kg,
                self.load_changer_coupled, min_substeps(params, self.sample_rate_Hz),
                initial_setpoints_V=self.initial_setpoints_V)
        return self._sensitivity

    def _record_input_derivatives(self, values: Mapping[str, float],
                                  names: Sequence[str]) -> np.ndarray:
        """:meth:`input_derivatives` of the model's inputs over the whole record."""
        params, x0 = self.start(values)
        self._linear(params)
        out = np.zeros((self.setpoints_V.shape[0], len(names)))
        mech_names = [m for m in names if m in params.mechanics.__dataclass_fields__]
        unknown = [m for m in names if m not in mech_names
                   and m not in ('coil_force_scale', 'pan_force_scale')]
        if unknown:
            raise ValueError(f'unknown known inputs {unknown}')
        if mech_names:
            at = dict(values, **{m: float(getattr(params.mechanics, m)) for m in mech_names
                                 if m not in values})
            mech = self._sensitivity.derivatives(
                params, x0, mech_names, at,
                lambda v: with_values(self.params, v, self.load_mass_kg,
                                      self.load_changer_coupled), REST_POSITION)
            for j, m in enumerate(mech_names):
                out[:, names.index(m)] = mech[:, j]
        if 'coil_force_scale' in names or 'pan_force_scale' in names:
            forces = self._sensitivity.input_responses(params, x0)
            for j, m in enumerate(('coil_force_scale', 'pan_force_scale')):
                if m in names:
                    out[:, names.index(m)] = forces[:, j]
        return out

    def sections(self, position_m: np.ndarray, spans: Sequence[Tuple[str, int, int]],
                 weights: Optional[Mapping[str, float]] = None) -> List[DataSection]:
        """
        Data sections whose inputs are views into the recorded setpoints.

        Parameters
        ----------
        position_m : ndarray, shape (n,)
            Measured position of the whole record [m].
        spans : sequence of (name, first_sample_index, n_samples)
            The sections to fit.
        weights : mapping of str to float, optional
            Weight per section name (default 1).

        Returns
        -------
        list of DataSection
            One per span.
        """
        y = np.asarray(position_m, dtype=float)
        out = []
        for name, first, n in spans:
            w = float((weights or {}).get(name, 1.0))
            out.append(DataSection(name, self.setpoints_V[first:first + n],
                                   y[first:first + n], w))
        return out
