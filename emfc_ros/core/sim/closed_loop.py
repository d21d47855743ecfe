"""
The balance in closed loop: the position controller inside the simulator's sample loop.

As on the device's FPGA, the controller runs at its own sample rate (``rate_Hz``, 10 kHz by
default) inside the simulation, never through ROS topics. The simulator's rate is an integer
multiple ``M`` of it; at every controller sample the measured lever position (sensor, ADC and
inverse characteristic, noise included) is read, the controller
(:func:`emfc_ros.core.control.runtime.controller_step`) computes the coil force, the force is
turned into a coil setpoint (inverse motor coefficient at the measured position, inverse
amplifier) and applied ``delay_samples * M`` simulator samples later, held for ``M`` samples
(zero-order hold at the controller rate, then the 16-bit DAC). This is the loop
:func:`~emfc_ros.core.control.design.design_controller` designs for: controller, hold, delay,
plant.

The input of :meth:`ClosedLoopSimulator.step_block` stays ``(2, n)`` setpoints [V]: the coil row
is added to the controller's output (closed-loop excitation), the load-changer row drives the
load changer (load profiles). Two channels are appended to the simulator's:
``coil_current_precise_A`` (the compensation current through the precise current channel:
shunt, high-resolution ADC and its noise, see
:class:`~emfc_ros.core.control.loop_config.CurrentChannelConfig`) and ``force_command_N``
(the controller output applied at the sample).
"""

from __future__ import annotations

from typing import Callable, Optional, Tuple

import numpy as np

from emfc_ros.core.control.design import ControllerDesign, design_controller, plant_from_model
from emfc_ros.core.control.loop_config import CurrentChannelConfig, loop_timing, LoopConfig
from emfc_ros.core.control.robust import check_load_range
from emfc_ros.core.control.runtime import controller_step, initial_state, pack_controller
from emfc_ros.core.model.linear import linearise
from emfc_ros.core.model.load import loaded
from emfc_ros.core.sim import chain
from emfc_ros.core.sim.converters import lsb_V
from emfc_ros.core.sim.noise import standard_normals
from emfc_ros.core.sim.simulator import _jitted, Simulator

EXTRA_CHANNELS = ('coil_current_precise_A', 'force_command_N')
EXTRA_UNITS = ('A', 'N')
#: Added to the seed for the precise channel's noise stream (independent of the chain's).
CHANNEL_SEED_OFFSET = 0x2545F4914F6CDD1D
MM_PER_M = 1.0e3

_LOOP_JIT: Optional[Callable] = None


def loop_block(x, prev, u, first, noise_key, par, sensor_table, out, coef, cstate, ring_V,
               ring_N, ratio, delay, setpoint_m, run_chain):
    """
    Simulate a block in closed loop, one simulator sample at a time.

    Parameters
    ----------
    x, prev, first, noise_key, par, sensor_table
        As :func:`emfc_ros.core.sim.chain.chain_block`.
    u : ndarray, shape (2, n)
        Excitation [V]: added to the controller's coil setpoint; the load-changer setpoint.
    out : ndarray, shape (chain.N_OUT + 2, n)
        The chain's rows (reference rows included), then the true coil current [A] and the
        applied force command [N].
    coef, cstate : ndarray
        Controller coefficients and state (updated).
    ring_V, ring_N : ndarray
        Coil setpoint [V] and force [N] for sample ``i`` at ``i % len(ring)`` (updated).
    ratio : int
        Simulator samples per controller sample.
    delay : int
        Delay of the controller output [simulator samples], >= 1.
    setpoint_m : float
        Position setpoint [m].
    run_chain : callable
        The chain (compiled or not).

    Returns
    -------
    bool
        False if ``u`` holds a value that is not finite (nothing simulated).
    """
    n_total = u.shape[1]
    for j in range(n_total):
        if not (np.isfinite(u[0, j]) and np.isfinite(u[1, j])):
            return False
    size = ring_V.shape[0]
    # The chain runs from one controller sample to the next in one call: the setpoints of
    # those samples were all written by earlier controller samples (delay >= 1), and a block
    # of the chain equals its samples one by one bit for bit.
    u_run = np.empty((2, ratio))
    out_run = np.empty((chain.N_OUT, ratio))
    i_max = par[chain.rk4.I_COIL_MAX]
    amp_coil = chain.characteristic(par, chain.AMP_COIL)
    motor = chain.characteristic(par, chain.MOTOR)
    c0 = amp_coil[0]
    c1 = amp_coil[1]
    j = 0
    while j < n_total:
        idx0 = first + j
        length = min((ratio - idx0 % ratio) % ratio + 1, n_total - j)
        if length != ratio:     # the block's edges
            u1 = np.empty((2, length))
            out1 = np.empty((chain.N_OUT, length))
        else:
            u1 = u_run
            out1 = out_run
        for k in range(length):
            slot = (idx0 + k) % size
            u1[0, k] = ring_V[slot] + u[0, j + k]
            u1[1, k] = u[1, j + k]
        run_chain(x, prev, u1, idx0, noise_key, par, sensor_table, out1)
        for k in range(length):
            for r in range(chain.N_OUT):
                out[r, j + k] = out1[r, k]
            y_true = out1[chain.OUT_POS_TRUE, k]
            k_true = 0.0
            for m in range(len(motor) - 1, -1, -1):
                k_true = k_true * (y_true * MM_PER_M) + motor[m]
            out[chain.N_OUT, j + k] = out1[chain.OUT_F_COIL_TRUE, k] / k_true
            out[chain.N_OUT + 1, j + k] = ring_N[(idx0 + k) % size]
        idx = idx0 + length - 1
        j += length
        if idx % ratio == 0:
            y_meas = out1[chain.OUT_POS, length - 1]
            force = controller_step(coef, cstate, setpoint_m - y_meas)
            k_meas = 0.0
            for m in range(len(motor) - 1, -1, -1):
                k_meas = k_meas * (y_meas * MM_PER_M) + motor[m]
            current = min(max(force / k_meas, -i_max), i_max)
            # invert the amplifier I(U) (ascending powers) by Newton from the linear term
            volt = (current - c0) / c1
            for _ in range(4):
                value = 0.0
                slope = 0.0
                for m in range(len(amp_coil) - 1, -1, -1):
                    slope = slope * volt + value
                    value = value * volt + amp_coil[m]
                volt = volt - (value - current) / slope
            for i in range(ratio):
                ring_V[(idx + delay + i) % size] = volt
                ring_N[(idx + delay + i) % size] = force
    return True


def _loop_jitted() -> Callable:
    global _LOOP_JIT
    if _LOOP_JIT is None:
        import numba
        _LOOP_JIT = numba.njit(cache=True)(loop_block)
    return _LOOP_JIT


def design_for(simulator: Simulator, config: LoopConfig) -> ControllerDesign:
    """
    Design the controller of a loop configuration and check it over the weighing range.

    The design is made on the linear model at ``design_load_mass_kg``, then checked at loads
    from 0 to ``max_load_kg`` (margins and exact closed-loop poles,
    :func:`~emfc_ros.core.control.robust.check_load_range`).

    Parameters
    ----------
    simulator : Simulator
        The simulator (its parameters give the model).
    config : LoopConfig
        The loop.

    Returns
    -------
    ControllerDesign
        Controller and margins (at the design load).

    Raises
    ------
    ValueError
        If the design fails, or the loop is unstable or short of margins at some load of
        the range (the message names the loads and the limits).
    """
    coupled = simulator.load_changer_coupled
    model = linearise(loaded(simulator.params.mechanics, config.design_load_mass_kg, coupled))
    design = design_controller(plant_from_model(model), config.rate_Hz, config.crossover_Hz,
                               config.phase_margin_deg, delay_samples=config.delay_samples,
                               notch_Hz=config.notch_Hz, notch_quality=config.notch_quality)
    check_load_range(simulator.params.mechanics, design.controller, config.delay_samples,
                     config.max_load_kg, coupled)
    return design


class ClosedLoopSimulator:
    """
    The simulated balance with the position controller in its sample loop.

    Parameters
    ----------
    simulator : Simulator
        The open-loop simulator (its rate must be an integer multiple of the controller's;
        reference channels are used internally whether it publishes them or not).
    config : LoopConfig
        The loop: controller rate, design targets, delay, setpoint.
    current_channel : CurrentChannelConfig, optional
        The precise current channel (default values when None).
    design : ControllerDesign, optional
        A controller designed elsewhere (must be at ``config.rate_Hz``); default: designed
        from ``config`` on the simulator's model.

    Attributes
    ----------
    design : ControllerDesign
        The controller and the margins the design predicts.
    ratio : int
        Simulator samples per controller sample.
    delay_sim_samples : int
        Delay of the controller output [simulator samples].
    channel_names, channel_units : tuple of str
        Output rows of :meth:`step_block`.

    Raises
    ------
    ValueError
        If the rates are not integer multiples, the delay is not a whole number of simulator
        samples >= 1, or the design fails (the message says which).
    """

    def __init__(self, simulator: Simulator, config: LoopConfig,
                 current_channel: Optional[CurrentChannelConfig] = None,
                 design: Optional[ControllerDesign] = None) -> None:
        self.sim = simulator
        self.config = config
        self.current_channel = current_channel or CurrentChannelConfig()
        self.ratio, self.delay_sim_samples = loop_timing(config, simulator.sample_rate_Hz)
        self.design = design if design is not None else design_for(simulator, config)
        if abs(self.design.controller.sample_rate_Hz - config.rate_Hz) > 1e-9 * config.rate_Hz:
            raise ValueError('design: the controller runs at '
                             f'{self.design.controller.sample_rate_Hz} Hz, not at the '
                             f'configured {config.rate_Hz} Hz')
        conv = simulator.params.converters
        force_limit = conv.coil_current_limit_A * simulator.params.motor.coefficient_N_per_A(0.0)
        self.output_limits_N = (-float(force_limit), float(force_limit))
        self._coef = pack_controller(self.design.controller, self.output_limits_N)
        names = simulator.channel_names
        self._public_rows = list(range(len(names)))
        self.channel_names = tuple(names) + EXTRA_CHANNELS
        self.channel_units = tuple(simulator.channel_units) + EXTRA_UNITS
        self._run = _loop_jitted() if simulator.backend == 'numba' else loop_block
        self._chain = _jitted() if simulator.backend == 'numba' else chain.chain_block
        self._channel_seed = (simulator.seed + CHANNEL_SEED_OFFSET) % 2 ** 64
        self.reset()

    # -- the simulator's interface ---------------------------------------------------------

    @property
    def params(self):
        """The balance parameters."""
        return self.sim.params

    @property
    def sample_rate_Hz(self) -> float:
        """Simulator sample rate [Hz]."""
        return self.sim.sample_rate_Hz

    @property
    def sample_index(self) -> int:
        """Index of the next sample."""
        return self.sim.sample_index

    @property
    def load_mass_kg(self) -> float:
        """Mass on the pan [kg]."""
        return self.sim.load_mass_kg

    @property
    def load_changer_coupled(self) -> bool:
        """Whether the load changer's moving mass rides on the pan."""
        return self.sim.load_changer_coupled

    @property
    def hold_setpoints_V(self) -> np.ndarray:
        """Open-loop setpoints [V] that hold the lever at 0 for the current load (a copy)."""
        return self.sim.hold_setpoints_V

    @property
    def state(self) -> np.ndarray:
        """Mechanical state ``[q1, q2, q1', q2']`` [rad, rad/s] (a copy)."""
        return self.sim.state

    def set_load(self, load_mass_kg: float, load_changer_coupled: bool = False) -> None:
        """
        Change the mass on the pan (a load step); the loop and the state continue.

        Parameters
        ----------
        load_mass_kg : float
            Mass on the pan [kg].
        load_changer_coupled : bool
            Load changer's moving mass on the pan.
        """
        self.sim.set_load(load_mass_kg, load_changer_coupled)

    def reset(self) -> None:
        """Return to the start: initial state, the controller holding the initial force."""
        self.sim.reset()
        hold_V = float(self.sim.last_setpoints_V[0])
        params = self.sim.params
        force = float(params.motor.force_N(params.coil_amplifier.current_A(hold_V), 0.0))
        self._cstate = initial_state(self._coef, force)
        size = self.delay_sim_samples + self.ratio + 1
        self._ring_V = np.full(size, hold_V)
        self._ring_N = np.full(size, force)

    @property
    def controller_state(self) -> np.ndarray:
        """The controller's state (a copy; layout of :mod:`emfc_ros.core.control.runtime`)."""
        return self._cstate.copy()

    def step_block(self, setpoints: np.ndarray) -> np.ndarray:
        """
        Simulate a block in closed loop.

        Parameters
        ----------
        setpoints : ndarray, shape (2, n)
            Coil excitation added to the controller's setpoint, and the load-changer setpoint
            [V].

        Returns
        -------
        ndarray, shape (len(channel_names), n)
            Outputs, rows as :attr:`channel_names`.

        Raises
        ------
        ValueError
            If the array is not ``(2, n)`` or holds values that are not finite (nothing is
            simulated then).
        """
        u = np.ascontiguousarray(setpoints, dtype=float)
        if u.ndim != 2 or u.shape[0] != 2:
            raise ValueError(f'setpoints must have shape (2, n) (coil, load_changer), got '
                             f'shape {u.shape}')
        sim = self.sim
        n = u.shape[1]
        full = np.empty((chain.N_OUT + 2, n))
        first = sim.sample_index
        args = (sim._x, sim._prev, u, first, sim._noise_key, sim._par, sim._table, full,
                self._coef, self._cstate, self._ring_V, self._ring_N,
                self.ratio, self.delay_sim_samples, float(self.config.position_setpoint_m),
                self._chain)
        if sim.backend == 'numba':
            ok = self._run(*args)
        else:
            with np.errstate(over='ignore'):
                ok = self._run(*args)
        if not ok:
            raise ValueError('setpoints must be finite')
        sim._index += n
        out = np.empty((len(self.channel_names), n))
        out[:len(self._public_rows)] = full[self._public_rows]
        out[-2] = self._precise_current_A(full[chain.N_OUT], first, sim.quantisation)
        out[-1] = full[chain.N_OUT + 1]
        return out

    def step_loads(self, load_mass_kg, setpoints: Optional[np.ndarray] = None) -> np.ndarray:
        """
        Simulate a block with the mass on the pan given per sample (load steps at samples).

        Parameters
        ----------
        load_mass_kg : array_like, shape (n,)
            Mass on the pan at each sample [kg]; where it changes, :meth:`set_load` is applied
            from that sample on (the load-changer coupling is kept).
        setpoints : ndarray, shape (2, n), optional
            Excitation (default zeros).

        Returns
        -------
        ndarray, shape (len(channel_names), n)
            Outputs, as :meth:`step_block`.
        """
        load = np.asarray(load_mass_kg, dtype=float)
        if load.ndim != 1:
            raise ValueError(f'load_mass_kg must be 1-D, got shape {load.shape}')
        u = np.zeros((2, load.size)) if setpoints is None else np.asarray(setpoints, dtype=float)
        if u.shape != (2, load.size):
            raise ValueError(f'setpoints must have shape (2, {load.size}), got {u.shape}')
        edges = np.concatenate(([0], np.nonzero(np.diff(load))[0] + 1, [load.size]))
        parts = []
        for a, b in zip(edges[:-1], edges[1:]):
            if b > a:
                if load[a] != self.load_mass_kg:
                    self.set_load(float(load[a]), self.load_changer_coupled)
                parts.append(self.step_block(u[:, a:b]))
        return np.concatenate(parts, axis=1) if parts else self.step_block(u)

    def _precise_current_A(self, current_A: np.ndarray, first: int,
                           quantise: bool) -> np.ndarray:
        ch = self.current_channel
        volts = current_A * ch.shunt_ohm
        if self.sim.noise and ch.noise_V_rms > 0.0 and current_A.size:
            volts = volts + ch.noise_V_rms * standard_normals(self._channel_seed, first,
                                                              current_A.size)[0]
        if quantise:
            lsb = lsb_V(ch.adc_bits, ch.adc_range_V)
            codes = np.clip(np.floor(volts / lsb + 0.5), -2.0 ** (ch.adc_bits - 1),
                            2.0 ** (ch.adc_bits - 1) - 1.0)
            volts = codes * lsb
        else:
            volts = np.clip(volts, -ch.adc_range_V, ch.adc_range_V)
        return volts / ch.shunt_ohm


def precise_current_resolution_A(channel: CurrentChannelConfig) -> Tuple[float, float]:
    """
    One code and the rms noise of the precise current channel, in current [A].

    Parameters
    ----------
    channel : CurrentChannelConfig
        The channel.

    Returns
    -------
    (float, float)
        ``(lsb_A, noise_A_rms)``.
    """
    return (lsb_V(channel.adc_bits, channel.adc_range_V) / channel.shunt_ohm,
            channel.noise_V_rms / channel.shunt_ohm)
