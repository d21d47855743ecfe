"""
Block-wise fixed-step RK4 plant kernel with a numba backend and a pure-Python/numpy fallback.

Both backends run the same function, :func:`emfc_ros.core.sim.rk4.rk4_block` (compiled by
``numba.njit(cache=True)`` or interpreted). The kernel owns the state between blocks and the
math has no notion of absolute time, so running a sequence of blocks gives bit for bit the
result of one block with the concatenated inputs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import numpy as np

from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.parameters import BalanceParameters, ConverterParameters
from emfc_ros.core.model.parameters import MechanicalParameters
from emfc_ros.core.records import same_clock_records
from emfc_ros.core.sim import rk4

BACKENDS = ('auto', 'numba', 'numpy')

_JIT: Optional[Callable] = None


def numba_available() -> bool:
    """
    Tell whether numba can be imported.

    Returns
    -------
    bool
        True if the numba backend is usable.
    """
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    return True


def resolved_backend(backend: str = 'auto') -> str:
    """
    The backend ``'auto'`` stands for here.

    Parameters
    ----------
    backend : {'auto', 'numba', 'numpy'}
        A backend name.

    Returns
    -------
    str
        ``'numba'`` or ``'numpy'`` (``'auto'``: numba when it imports).
    """
    if backend == 'auto':
        return 'numba' if numba_available() else 'numpy'
    return backend


def _jitted() -> Callable:
    global _JIT
    if _JIT is None:
        import numba
        _JIT = numba.njit(cache=True)(rk4.rk4_block)
    return _JIT


def pack_mechanics(mech: MechanicalParameters, conv: ConverterParameters) -> np.ndarray:
    """
    Pack the mechanics and current limits into the kernel's parameter vector.

    Parameters
    ----------
    mech : MechanicalParameters
        The (loaded) mechanics.
    conv : ConverterParameters
        Converters (for the amplifier current limits).

    Returns
    -------
    ndarray, shape (rk4.N_PAR,)
        The vector, indexed by the constants of :mod:`emfc_ros.core.sim.rk4`.
    """
    par = np.zeros(rk4.N_PAR)
    par[rk4.L1], par[rk4.L2], par[rk4.L3] = mech.l1_m, mech.l2_m, mech.l3_m
    par[rk4.MP], par[rk4.M1], par[rk4.R1], par[rk4.H1] = (mech.mp_kg, mech.m1_kg, mech.r1_m,
                                                          mech.h1_m)
    par[rk4.J1] = mech.J1_kgm2
    par[rk4.M2], par[rk4.R2], par[rk4.H2] = mech.m2_kg, mech.r2_m, mech.h2_m
    par[rk4.J2], par[rk4.M3] = mech.J2_kgm2, mech.m3_kg
    par[rk4.C1], par[rk4.D1] = mech.c1_Nm_per_rad, mech.d1_Nms_per_rad
    par[rk4.C2], par[rk4.D2] = mech.c2_Nm_per_rad, mech.d2_Nms_per_rad
    par[rk4.F_OFF], par[rk4.G] = mech.F_off_N, mech.g_m_per_s2
    par[rk4.I_COIL_MAX] = conv.coil_current_limit_A
    par[rk4.I_LC_MAX] = conv.load_changer_current_limit_A
    return par


@dataclass(frozen=True)
class BlockOutput:
    """
    Signals of one block, one value per sample at the sample instants.

    Attributes
    ----------
    y_m : ndarray
        Lever-end position [m].
    sensor_V : ndarray
        Position sensor voltage [V] (noise-free, unsaturated).
    coil_current_A, load_changer_current_A : ndarray
        Amplifier output currents [A] (clipped to the current limits).
    coil_force_N : ndarray
        Coil force at the lever end [N], positive upward.
    pan_force_N : ndarray
        Load-changer force on the pan [N], positive downward.
    state_end : ndarray, shape (4,)
        State ``[q1, q2, q1', q2']`` after the block [rad, rad/s].
    """

    y_m: np.ndarray
    sensor_V: np.ndarray
    coil_current_A: np.ndarray
    load_changer_current_A: np.ndarray
    coil_force_N: np.ndarray
    pan_force_N: np.ndarray
    state_end: np.ndarray


class PlantKernel:
    """
    The nonlinear plant (amplifiers, motor, mechanics, sensor, load changer) run block by block.

    Parameters
    ----------
    params : BalanceParameters
        The parameters.
    sample_rate_Hz : float
        Sample rate of the setpoints and outputs [Hz].
    substeps : int
        RK4 steps per sample (at 10 kHz one step resolves the 410 Hz mode to about 1e-4).
    load_mass_kg : float
        Mass on the pan [kg].
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan.
    x0 : sequence of float, optional
        Initial state [rad, rad/s]; default rest at ``q = 0``.
    backend : str
        ``'numba'``, ``'numpy'`` (interpreted, same math) or ``'auto'`` (numba if available).
    """

    def __init__(self, params: BalanceParameters, sample_rate_Hz: float, substeps: int = 1,
                 load_mass_kg: float = 0.0, load_changer_coupled: bool = False,
                 x0: Optional[Sequence[float]] = None, backend: str = 'auto') -> None:
        rate = float(sample_rate_Hz)
        if not (np.isfinite(rate) and rate > 0.0):
            raise ValueError(f'sample_rate_Hz must be a positive number, got {sample_rate_Hz!r}')
        if isinstance(substeps, bool) or not isinstance(substeps, (int, np.integer)) or \
                substeps < 1:
            raise ValueError(f'substeps must be an integer >= 1, got {substeps!r}')
        if backend not in BACKENDS:
            raise ValueError(f'backend must be one of {BACKENDS}, got {backend!r}')
        if backend == 'auto':
            backend = 'numba' if numba_available() else 'numpy'
        self._run = _jitted() if backend == 'numba' else rk4.rk4_block
        self.backend = backend
        self.dt_s = 1.0 / rate
        self.substeps = int(substeps)
        self.mechanics = loaded(params.mechanics, load_mass_kg, load_changer_coupled)
        self._par = pack_mechanics(self.mechanics, params.converters)
        self._amp_coil = np.array(params.coil_amplifier.coeffs_A_per_V_pow)
        self._amp_lc = np.array(params.load_changer_amplifier.coeffs_A_per_V_pow)
        self._motor = np.array(params.motor.coeffs_N_per_A_per_mm_pow)
        self._sensor = np.array(params.sensor.coeffs_V_per_m_pow)
        self._lc = np.array(params.load_changer.coeffs_N_per_A_pow)
        self._x = np.zeros(4)
        if x0 is not None:
            self.state = x0

    @property
    def state(self) -> np.ndarray:
        """Current state ``[q1, q2, q1', q2']`` [rad, rad/s] (a copy)."""
        return self._x.copy()

    @state.setter
    def state(self, x: Sequence[float]) -> None:
        arr = np.array(x, dtype=float).reshape(-1)
        if arr.shape != (4,) or not np.all(np.isfinite(arr)):
            raise ValueError(f'state must be 4 finite numbers, got {x!r}')
        self._x = arr

    def run(self, u_coil_V: Sequence[float], u_lc_V: Sequence[float]) -> BlockOutput:
        """
        Run one block of samples and advance the state.

        Parameters
        ----------
        u_coil_V, u_lc_V : sequence of float
            Setpoint voltages of the coil and load-changer amplifiers [V], one per sample,
            held over the sample period.

        Returns
        -------
        BlockOutput
            The signals at the sample instants and the state after the block.
        """
        uc, ul = same_clock_records(('u_coil_V', 'u_lc_V'), (u_coil_V, u_lc_V),
                                    allow_empty=True)
        out = np.empty((rk4.N_OUT, uc.size))
        self._run(self._x, uc, ul, self.dt_s, self.substeps, self._par, self._amp_coil,
                  self._amp_lc, self._motor, self._sensor, self._lc, out)
        return BlockOutput(out[rk4.OUT_Y], out[rk4.OUT_SENSOR], out[rk4.OUT_I_COIL],
                           out[rk4.OUT_I_LC], out[rk4.OUT_F_COIL], out[rk4.OUT_F_PAN],
                           self._x.copy())
