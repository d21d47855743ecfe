"""
The plant simulator: the full chain from setpoint voltages to measured channels, block by block.

``Simulator(params, sample_rate_Hz, seed).step_block(setpoints)`` turns a ``(2, n)`` array of
coil and load-changer setpoints [V] into a ``(channels, n)`` array of outputs named by
``channel_names`` / ``channel_units`` (see :mod:`emfc_ros.core.sim.channels` and
``docs/simulator.md``). The per-sample math is :func:`emfc_ros.core.sim.chain.chain_block`,
compiled with numba or interpreted. State, the last DAC values and the sample index carry from
block to block and the noise is a pure function of the sample index and the seed, so any split
into blocks reproduces one block bit for bit.
"""

from __future__ import annotations

import functools
from typing import Callable, Optional, Sequence, Tuple

import numpy as np

from emfc_ros.core.model.linear import linearise
from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.model.peripherals import PositionSensor
from emfc_ros.core.sim import chain
from emfc_ros.core.sim.channels import channel_names, channel_units
from emfc_ros.core.sim.converters import convert_V, lsb_V
from emfc_ros.core.sim.hold_point import hold_point
from emfc_ros.core.sim.kernel import numba_available, pack_mechanics
from emfc_ros.core.sim.noise import check_seed, noise_key

BACKENDS = ('auto', 'numba', 'numpy')
HOLDS = ('zoh', 'foh')

#: Largest RK4 step times the fastest mode's |eigenvalue| (stability limit 2.8, accuracy).
MAX_STEP_TIMES_RATE = 1.0

_JIT: Optional[Callable] = None


def _jitted() -> Callable:
    global _JIT
    if _JIT is None:
        import numba
        _JIT = numba.njit(cache=True, **chain.JIT_OPTIONS)(chain.chain_block)
    return _JIT


def fastest_rate_rad_per_s(params: BalanceParameters) -> float:
    """
    Largest eigenvalue magnitude of the linear mechanics, free or resting on a stop.

    Evaluated for the empty, uncoupled pan (the lightest, hence fastest, configuration).

    Parameters
    ----------
    params : BalanceParameters
        The parameters.

    Returns
    -------
    float
        ``max |lambda|`` [rad/s].
    """
    model = linearise(params.mechanics)
    mech = params.mechanics
    conv = params.converters
    c = np.array([mech.l2_m, mech.l3_m])
    feedback = np.concatenate([conv.stop_stiffness_N_per_m * c, conv.stop_damping_Ns_per_m * c])
    on_stop = model.A - np.outer(model.B[:, 0], feedback)
    return float(max(np.abs(np.linalg.eigvals(model.A)).max(),
                     np.abs(np.linalg.eigvals(on_stop)).max()))


def min_substeps(params: BalanceParameters, sample_rate_Hz: float) -> int:
    """
    Fewest RK4 steps per sample that keep ``h max|lambda| <= MAX_STEP_TIMES_RATE``.

    Parameters
    ----------
    params : BalanceParameters
        The parameters (the stop stiffness and damping set the fastest mode).
    sample_rate_Hz : float
        Sample rate [Hz].

    Returns
    -------
    int
        At least 1.
    """
    rate = fastest_rate_rad_per_s(params)
    return max(1, int(np.ceil(rate / (float(sample_rate_Hz) * MAX_STEP_TIMES_RATE))))


def pack_parameters(params: BalanceParameters, load_mass_kg: float,
                    load_changer_coupled: bool, sample_rate_Hz: float, *, noise: bool = True,
                    quantisation: bool = True, hold: str = 'zoh',
                    substeps: int = 1) -> np.ndarray:
    """
    Pack mechanics, converters, noise levels, switches and characteristics for the chain.

    Parameters
    ----------
    params : BalanceParameters
        The parameters.
    load_mass_kg : float
        Mass on the pan [kg].
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan.
    sample_rate_Hz : float
        Sample rate [Hz].
    noise, quantisation, hold, substeps
        As :class:`Simulator`'s.

    Returns
    -------
    ndarray
        The vector, indexed by the constants of :mod:`emfc_ros.core.sim.chain`, with the
        characteristics' coefficients from ``chain.N_PAR`` on.
    """
    conv = params.converters
    lists = [np.asarray(c, dtype=float).reshape(-1) for c in (
        params.coil_amplifier.coeffs_A_per_V_pow,
        params.load_changer_amplifier.coeffs_A_per_V_pow,
        params.motor.coeffs_N_per_A_per_mm_pow, params.sensor.coeffs_V_per_m_pow,
        params.load_changer.coeffs_N_per_A_pow)]
    par = np.zeros(chain.N_PAR + sum(len(c) for c in lists))
    par[chain.COEFFS:chain.N_PAR] = [len(c) for c in lists]
    par[chain.N_PAR:] = np.concatenate(lists)
    par[:chain.rk4.N_PAR] = pack_mechanics(
        loaded(params.mechanics, load_mass_kg, load_changer_coupled), conv)
    par[chain.DAC_LSB] = lsb_V(conv.dac_bits, conv.dac_range_V)
    par[chain.DAC_LO] = -2.0 ** (conv.dac_bits - 1)
    par[chain.DAC_HI] = 2.0 ** (conv.dac_bits - 1) - 1.0
    par[chain.DAC_RANGE] = conv.dac_range_V
    par[chain.ADC_LSB] = lsb_V(conv.adc_bits, conv.adc_range_V)
    par[chain.ADC_LO] = -2.0 ** (conv.adc_bits - 1)
    par[chain.ADC_HI] = 2.0 ** (conv.adc_bits - 1) - 1.0
    par[chain.ADC_RANGE] = conv.adc_range_V
    par[chain.SENSOR_RANGE] = conv.sensor_range_m
    par[chain.STOP_POS] = conv.stop_position_m
    par[chain.STOP_K] = conv.stop_stiffness_N_per_m
    par[chain.STOP_D] = conv.stop_damping_Ns_per_m
    par[chain.MONITOR] = conv.current_monitor_V_per_A
    par[chain.NOISE_Y] = conv.sensor_noise_m_rms
    par[chain.NOISE_IC] = conv.coil_current_noise_A_rms
    par[chain.NOISE_ILC] = conv.load_changer_current_noise_A_rms
    par[chain.DT] = 1.0 / float(sample_rate_Hz)
    par[chain.USE_NOISE] = float(bool(noise))
    par[chain.QUANTISE] = float(bool(quantisation))
    par[chain.FOH] = float(hold == 'foh')
    par[chain.SUBSTEPS] = int(substeps)
    return par


def sensor_table(params: BalanceParameters) -> np.ndarray:
    """
    Inverse sensor characteristic at every ADC code (the kernel's lookup table).

    Computed once per sensor characteristic and ADC (the last few are kept: a fit builds a
    simulator per parameter set with the same sensor); callers must not modify it.

    Parameters
    ----------
    params : BalanceParameters
        The parameters (sensor characteristic, ADC bits and range).

    Returns
    -------
    ndarray, shape (2**adc_bits,)
        Position [m] for the codes ``-2**(bits-1) .. 2**(bits-1) - 1``.
    """
    conv = params.converters
    return _sensor_table(tuple(float(c) for c in params.sensor.coeffs_V_per_m_pow),
                         int(conv.adc_bits), float(conv.adc_range_V), float(conv.sensor_range_m))


@functools.lru_cache(maxsize=8)
def _sensor_table(coeffs: Tuple[float, ...], adc_bits: int, adc_range_V: float,
                  sensor_range_m: float) -> np.ndarray:
    sensor = PositionSensor(coeffs)
    codes = np.arange(-2 ** (adc_bits - 1), 2 ** (adc_bits - 1), dtype=float)
    # the kernel only sees voltages of the clipped position: stay inside the monotonic range
    ends = sensor.voltage_V(np.array([-sensor_range_m, sensor_range_m]))
    volts = np.clip(codes * lsb_V(adc_bits, adc_range_V), ends.min(), ends.max())
    # shared by the simulators of the same sensor; nothing writes to it (kept writeable: numba
    # types a read-only array differently, which would compile the kernel a second time)
    return np.asarray(sensor.position_m(volts), dtype=float)


class Simulator:
    """
    The EMFC balance simulated sample by sample, run block by block.

    Parameters
    ----------
    params : BalanceParameters
        Mechanics, characteristics, converters, stops and noise levels.
    sample_rate_Hz : float
        Sample rate of setpoints and outputs [Hz].
    seed : int
        Noise seed in [0, 2**64).
    substeps : int, optional
        RK4 steps per sample; default the fewest that resolve the fastest mode (the stop
        contact, about 1.3 kHz with the defaults): 1 at 10 kHz and above. A value below that
        is refused.
    hold : {'zoh', 'foh'}
        Zero-order hold, or first-order hold (ramp from the previous DAC value to the current
        one over the sample period: one sample of delay).
    noise : bool
        Add sensor and amplifier current noise.
    quantisation : bool
        Quantise DAC and ADC (saturation applies either way).
    reference_channels : bool
        Append ``position_true_m``, ``pan_force_N`` and ``coil_force_true_N``.
    load_mass_kg : float
        Mass on the pan [kg] at the start.
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan at the start.
    x0 : sequence of float, optional
        Initial state ``[q1, q2, q1', q2']`` [rad, rad/s]; default the hold point (rest with the
        lever end at 0, see :attr:`hold_setpoints_V`).
    initial_setpoints_V : sequence of float, optional
        DAC values before the first sample (first-order hold) [V]; default the hold setpoints.
    backend : {'auto', 'numba', 'numpy'}
        Compiled kernel, interpreted fallback (same math, slow), or numba when available.

    Attributes
    ----------
    channel_names, channel_units : tuple of str
        Output rows of :meth:`step_block` and their SI units.
    mechanics : MechanicalParameters
        The loaded mechanics of the current load.
    noise, quantisation, hold
        As the parameters; they may be changed between blocks.
    """

    def __init__(self, params: BalanceParameters, sample_rate_Hz: float, seed: int = 0, *,
                 substeps: Optional[int] = None, hold: str = 'zoh', noise: bool = True,
                 quantisation: bool = True, reference_channels: bool = True,
                 load_mass_kg: float = 0.0, load_changer_coupled: bool = False,
                 x0: Optional[Sequence[float]] = None,
                 initial_setpoints_V: Optional[Sequence[float]] = None,
                 backend: str = 'auto') -> None:
        rate = float(sample_rate_Hz)
        if not (np.isfinite(rate) and rate > 0.0):
            raise ValueError(f'sample_rate_Hz must be a positive number, got {sample_rate_Hz!r}')
        if hold not in HOLDS:
            raise ValueError(f'hold must be one of {HOLDS}, got {hold!r}')
        if backend not in BACKENDS:
            raise ValueError(f'backend must be one of {BACKENDS}, got {backend!r}')
        if backend == 'auto':
            backend = 'numba' if numba_available() else 'numpy'
        self.params = params
        self.sample_rate_Hz = rate
        self.seed = check_seed(seed)
        self._noise_key = noise_key(self.seed)
        needed = min_substeps(params, rate)
        if substeps is None:
            substeps = needed
        if isinstance(substeps, bool) or not isinstance(substeps, (int, np.integer)) or \
                substeps < 1:
            raise ValueError(f'substeps must be an integer >= 1, got {substeps!r}')
        if substeps < needed:
            raise ValueError(f'substeps: {substeps} RK4 steps per sample at {rate:g} Hz cannot '
                             f'resolve the fastest mode (the mechanical stop contact); use '
                             f'substeps >= {needed}')
        self.substeps = int(substeps)
        self._hold = hold
        self._noise = bool(noise)
        self._quantisation = bool(quantisation)
        self.reference_channels = bool(reference_channels)
        self.backend = backend
        self._run = _jitted() if backend == 'numba' else chain.chain_block
        self._table = sensor_table(params)
        self.channel_names = channel_names(self.reference_channels)
        self.channel_units = channel_units(self.reference_channels)
        self._initial_load = (float(load_mass_kg), bool(load_changer_coupled))
        self.set_load(load_mass_kg, load_changer_coupled)
        if x0 is None or initial_setpoints_V is None:
            hp = hold_point(params, load_mass_kg, load_changer_coupled)
            x0 = hp.x if x0 is None else x0
            initial_setpoints_V = (hp.setpoints_V if initial_setpoints_V is None
                                   else initial_setpoints_V)
        self._x0 = self._check_state(x0)
        prev = initial_setpoints_V
        prev = np.array(prev, dtype=float).reshape(-1)
        if prev.shape != (2,) or not np.all(np.isfinite(prev)):
            raise ValueError(f'initial_setpoints_V must be 2 finite voltages, got '
                             f'{initial_setpoints_V!r}')
        # the DAC values: what the converter holds before the first sample
        self._prev0 = np.array([self._dac(v) for v in prev])
        self.reset()
        # compile the kernel (or load it from numba's cache) now, not on the first block
        self.step_block(np.zeros((2, 0)))

    @property
    def noise(self) -> bool:
        """Whether sensor and amplifier current noise is added."""
        return self._noise

    @noise.setter
    def noise(self, on: bool) -> None:
        self._noise = bool(on)
        self._par[chain.USE_NOISE] = float(self._noise)

    @property
    def quantisation(self) -> bool:
        """Whether DAC and ADC are quantised (saturation applies either way)."""
        return self._quantisation

    @quantisation.setter
    def quantisation(self, on: bool) -> None:
        self._quantisation = bool(on)
        self._par[chain.QUANTISE] = float(self._quantisation)

    @property
    def hold(self) -> str:
        """The hold of the DAC values, ``'zoh'`` or ``'foh'``."""
        return self._hold

    @hold.setter
    def hold(self, hold: str) -> None:
        if hold not in HOLDS:
            raise ValueError(f'hold must be one of {HOLDS}, got {hold!r}')
        self._hold = hold
        self._par[chain.FOH] = float(hold == 'foh')

    def _dac(self, v: float) -> float:
        conv = self.params.converters
        return float(convert_V(v, conv.dac_bits, conv.dac_range_V, self.quantisation))

    @staticmethod
    def _check_state(x: Sequence[float]) -> np.ndarray:
        arr = np.array(x, dtype=float).reshape(-1)
        if arr.shape != (4,) or not np.all(np.isfinite(arr)):
            raise ValueError(f'state must be 4 finite numbers [rad, rad, rad/s, rad/s], '
                             f'got {x!r}')
        return arr

    @property
    def state(self) -> np.ndarray:
        """State ``[q1, q2, q1', q2']`` [rad, rad/s] before the next sample (a copy)."""
        return self._x.copy()

    @state.setter
    def state(self, x: Sequence[float]) -> None:
        self._x = self._check_state(x)

    @property
    def sample_index(self) -> int:
        """Index of the next sample (samples simulated since the start or the last reset)."""
        return self._index

    @property
    def last_setpoints_V(self) -> np.ndarray:
        """DAC values of the last sample [V] (the first-order hold's ramp start; a copy)."""
        return self._prev.copy()

    @property
    def hold_setpoints_V(self) -> np.ndarray:
        """Setpoints [V] that hold the lever end at 0 for the current load (load changer 0 V)."""
        if self._hold_V is None:
            self._hold_V = hold_point(self.params, self.load_mass_kg,
                                      self.load_changer_coupled).setpoints_V
        return self._hold_V.copy()

    def set_load(self, load_mass_kg: float, load_changer_coupled: bool = False) -> None:
        """
        Change the mass on the pan and the load-changer coupling; the state continues.

        Parameters
        ----------
        load_mass_kg : float
            Mass on the pan [kg], >= 0 (its weight acts from the next sample).
        load_changer_coupled : bool
            Whether the load changer's moving mass rides on the pan.

        Raises
        ------
        ValueError
            If the mass is negative or not finite.
        """
        self._par = pack_parameters(self.params, load_mass_kg, load_changer_coupled,
                                    self.sample_rate_Hz, noise=self._noise,
                                    quantisation=self._quantisation, hold=self._hold,
                                    substeps=self.substeps)
        self.load_mass_kg = float(load_mass_kg)
        self.load_changer_coupled = bool(load_changer_coupled)
        self.mechanics = loaded(self.params.mechanics, self.load_mass_kg,
                                self.load_changer_coupled)
        self._hold_V: Optional[np.ndarray] = None

    def reset(self) -> None:
        """Return to the initial state, DAC values, load and sample index 0."""
        self.set_load(*self._initial_load)
        self._x = self._x0.copy()
        self._prev = self._prev0.copy()
        self._index = 0

    def step_block(self, setpoints: np.ndarray) -> np.ndarray:
        """
        Simulate one block of samples.

        Parameters
        ----------
        setpoints : ndarray, shape (2, n)
            Coil and load-changer setpoints [V], one column per sample (clamped by the DAC).

        Returns
        -------
        ndarray, shape (len(channel_names), n)
            The output channels at the sample instants, rows as :attr:`channel_names`.

        Raises
        ------
        ValueError
            If the array does not have 2 rows or holds non-finite values.
        """
        u = np.ascontiguousarray(setpoints, dtype=float)
        if u.ndim != 2 or u.shape[0] != 2:
            raise ValueError(f'setpoints must have shape (2, n) (coil, load_changer), got '
                             f'shape {u.shape}')
        n = u.shape[1]
        out = np.empty((len(self.channel_names), n))
        # the kernel refuses non-finite setpoints before it changes anything (cheaper than a
        # numpy check for small blocks)
        if self.backend == 'numba':
            ok = self._run(self._x, self._prev, u, self._index, self._noise_key, self._par,
                           self._table, out)
        else:   # plain Python floats index faster when interpreted
            with np.errstate(over='ignore'):   # the interpreted noise hash wraps around 2**64
                ok = self._run(self._x, self._prev, u, self._index, self._noise_key,
                               self._par.tolist(), self._table, out)
        if not ok:
            raise ValueError('setpoints must be finite')
        self._index += n
        return out
