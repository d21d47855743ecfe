"""
Dynamic weighing: estimate the pan force before the loop has settled.

Model. The linearised two-beam mechanics (:func:`emfc_ros.core.model.linear.linearise`,
state ``x = [q1, q2, q1', q2']``, inputs ``[F_c, F_p]``: coil force up at the lever end and
pan force down at the pan, output the lever-end position ``y``) is discretised with a
zero-order hold at the estimator's sample rate (:func:`scipy.signal.cont2discrete`) and
augmented with the unknown pan force as a random walk:

``x[n+1] = Phi x[n] + Gamma_c dF_c[n] + Gamma_p w[n]``,  ``w[n+1] = w[n] + eta[n]``,
``y[n] = C x[n] + v[n]``

with ``var(eta) = q^2 / fs`` (``q`` = ``force_random_walk_N_per_sqrt_s``), ``var(v) =
position_noise_m_rms^2`` and optionally white coil-force noise through ``Gamma_c``. Signals are
deviations from the model's operating point (``F_c0``, ``F_p0``, ``y0``). The known input is
the compensation force ``F_c`` computed from the measured current (sample ``n`` is taken to act
over ``[t_n, t_n+1)``); the measurement is the lever-end position. The steady-state gain comes
from :func:`scipy.linalg.solve_discrete_are` in scaled coordinates, polished by Newton (Hewer)
steps (:mod:`.riccati`: the raw solver is 20 % off on this badly scaled model); the filter is
the "current estimate" form
(``w_hat[n]`` uses ``y[n]``).

Output. The pan-force estimate ``F_p = F_p0 + w_hat`` [N] (positive down, in addition to the
weight of the masses of the model: a load of ``m`` kg on the pan reads about ``m g``). To use
the SAME :class:`~emfc_ros.core.weighing.calibration.WeighingCalibration` (zero, tare,
adjustment) as the static readings, it is expressed as the equivalent compensation force

``F_eq = F_c0 - r w_hat``,  ``r = G_pan(0) / G_coil(0)`` (0.13326 with the defaults),

the coil force that would hold the lever at ``y = 0`` against the estimated pan force. At
rest ``F_eq = F_c - (y - y0) / G_coil(0)``, which equals the compensation force when the loop
holds ``y = y0``, so the static calibration applies unchanged.

Change-adaptive filter (the default, ``adaptive=True``). A steady-state filter has one
bandwidth: a small ``q`` is quiet but slow after a load step, a large one quick but noisy. The
adaptive filter runs the time-varying Kalman filter instead (the covariance follows the
Riccati recursion every sample, in scaled coordinates) with a small ``q`` (default 1e-6
N/sqrt(s)), and watches its innovations: when the normalised innovation squared, summed over
the last ``change_window_s`` (2 ms), exceeds ``window + change_threshold_sigma *
sqrt(2 window)`` (its mean plus 12 standard deviations under the model) times the running mean
of the normalised innovation squared over the last second (1 when the assumed position noise
is right: the test adapts to a noise assumed somewhat wrong), a change is declared
and the covariance of the force is inflated to ``(max_step_kg g)^2`` (the states' by 100
times their steady-state variance). The filter then forgets the old force and converges on
the new one as fast as the data allow (the covariance shrinks like a growing least-squares
fit), and returns to the quiet steady state by itself. It runs the linear model of the load on
the pan (a grid of ``model_step_kg``, switched when the estimate leaves the model's band), so
that the load's inertia is no model error while the lever moves. On the simulated balance in
closed loop (10 kHz, 2.7 nm position noise) every step of 1 to 200 g is within 1 mg after at
most 0.046 s, against 0.10 to 0.19 s for the steady-state filter with ``q = 1e-5`` and about
1.03 s for the 1-s moving average (``bench/bench_weighing.py``, ``docs/weighing.md``).

Tuning of the steady-state filter (``adaptive=False``). ``q`` sets the estimator bandwidth:
larger ``q`` follows a load step sooner but passes more position noise (amplified by the
inverse of the pan-to-position response, which falls as 1/f^2 above the 3.8 Hz pivot
resonance) and more model error into the estimate; smaller ``q``
averages longer. The lever is very sensitive (about 106 nm of lever travel per mg on the pan in
the static open-loop gain) and the position noise is small, so the useful ``q`` is tiny. With
``q = 1e-5 N/sqrt(s)``, 2 nm rms position noise at 10 kHz and a PID+lead loop at
50 Hz crossover, the estimate is within 1 mg (9.8e-6 N) of a 100 g step after about 0.16 s
with about 0.05 mg rms noise (also when the plant carries the 100 g in its inertia and the
estimator does not), whereas the 1-s moving average of the compensation force needs about
1.09 s. Measured on that loop: ``q = 2e-5`` gives 0.13 s and 0.09 mg, ``5e-6`` 0.20 s and
0.03 mg, ``1e-6`` 0.35 s and 0.006 mg, ``1e-7`` 0.85 s; above about ``5e-5`` the noise peaks
reach 1 mg (0.18 mg rms) and the settled flag flickers. Scaling ``q`` and the position noise
together keeps the same gain (the estimate noise then scales with the position noise).

Settled flag. ``settled[n]`` is True when (a) at least ``settle_window_s`` (20 ms) have passed
since the start, the last reset and the last declared change, (b) the spread (max - min) of
the estimate over the last ``settle_window_s`` is below ``settle_threshold_kg * g`` (1 mg),
and (c) ``settle_sigma`` (3) times the filter's own standard deviation of the force estimate
is below that threshold: the estimate has stopped moving, and the filter does not expect it
to move by more than the threshold (the residual error it still has to remove is within
3 standard deviations). Tested on unseen steps: after the flag rises, the estimate stays
within the threshold of where it was until the load changes again.

Any split of the input into blocks gives the same output bit for bit (the filter state and the
settle window are carried between blocks).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Union

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from scipy import signal

from emfc_ros.core.model.linear import linearise, LinearModel
from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.parameters import MechanicalParameters
from emfc_ros.core.records import same_clock_records
from emfc_ros.core.weighing import kalman_loop
from emfc_ros.core.weighing.calibration import WeighingCalibration
from emfc_ros.core.weighing.errors import WeighingError
from emfc_ros.core.weighing.riccati import filter_riccati

#: Default random-walk intensity of the pan force [N/sqrt(s)] (see the module docstring).
DEFAULT_FORCE_RANDOM_WALK_N_PER_SQRT_S = 1.0e-6
#: Scaled-state variance added on a declared change (the force's comes from max_step_kg).
STATE_INFLATION = 100.0
#: The load estimate must be known to this standard deviation before the model follows it [kg].
MODEL_SWITCH_SIGMA_KG = 1.0e-3
BACKENDS = ('auto', 'numba', 'numpy')
_JIT = None


_ADAPTIVE_JIT = None


def _jitted():
    global _JIT
    if _JIT is None:
        import numba
        _JIT = numba.njit(cache=True)(kalman_loop.kalman_block)
    return _JIT


def _adaptive_jitted():
    global _ADAPTIVE_JIT
    if _ADAPTIVE_JIT is None:
        import numba
        _ADAPTIVE_JIT = numba.njit(cache=True)(kalman_loop.adaptive_block)
    return _ADAPTIVE_JIT


def _numba_available() -> bool:
    try:
        import numba  # noqa: F401
    except ImportError:
        return False
    return True


@dataclass(frozen=True)
class DynamicEstimate:
    """
    The estimator's outputs for one block.

    Attributes
    ----------
    pan_force_N : ndarray
        Pan-force estimate per sample [N], positive down.
    equivalent_force_N : ndarray
        Equivalent compensation force per sample [N] (feed it to a ``WeighingCalibration``).
    innovation_m : ndarray
        Measured minus predicted lever-end position per sample [m].
    settled : ndarray of bool
        Settled flag per sample.
    pan_force_u_N : ndarray
        The filter's standard deviation of the pan-force estimate per sample [N].
    change : ndarray of bool
        True at the samples where a load change was declared (adaptive filter).
    """

    pan_force_N: np.ndarray
    equivalent_force_N: np.ndarray
    innovation_m: np.ndarray
    settled: np.ndarray
    pan_force_u_N: np.ndarray
    change: np.ndarray


def _steady_state(phi_a: np.ndarray, c_a: np.ndarray, noise: np.ndarray, r: float):
    try:
        p_prior = filter_riccati(phi_a, c_a, noise, r)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise WeighingError(f'no steady-state Kalman gain for these noise levels: '
                            f'{exc}') from None
    return p_prior, p_prior @ c_a / (float(c_a @ p_prior @ c_a) + r)


def _positive(name: str, value: float) -> float:
    out = float(value)
    if not (math.isfinite(out) and out > 0.0):
        raise WeighingError(f'{name}: must be finite and > 0, got {value!r}')
    return out


class DynamicWeigher:
    """
    Steady-state Kalman filter estimating the pan force (see the module docstring).

    Parameters
    ----------
    model_or_mechanics : LinearModel or MechanicalParameters
        A linear model (``linearise(...)``) or the mechanics to linearise about ``q = 0``.
    sample_rate_Hz : float
        Estimator sample rate [Hz] (the rate of the position and current samples).
    position_noise_m_rms : float
        Position measurement noise per sample [m rms], > 0 (simulator default 2e-9 m).
    force_random_walk_N_per_sqrt_s : float
        Random-walk intensity of the pan force [N/sqrt(s)], > 0.
    coil_force_noise_N_rms : float
        White noise of the compensation force input per sample [N rms], >= 0 (difference
        between the force computed from the measured current and the force acting).
    settle_window_s : float
        Window of the settled test [s].
    settle_threshold_kg : float
        Largest spread of the estimate over that window, as a mass [kg] (force / g).
    initial_pan_force_N : float, optional
        Initial pan-force estimate [N]; default the operating point's ``F_p0``.
    backend : str
        ``'auto'`` (numba if available), ``'numba'`` or ``'numpy'`` (interpreted).
    adaptive : bool
        Run the change-adaptive time-varying filter (default) instead of the steady-state one.
    change_window_s : float
        Window of the innovation test of the adaptive filter [s].
    change_threshold_sigma : float
        Threshold of that test, in standard deviations of the windowed sum above its mean.
    max_step_kg : float
        Largest load change expected [kg]: sets the force covariance after a change.
    settle_sigma : float
        Standard deviations of the estimate that must fit in the settle threshold.
    reference_random_walk_N_per_sqrt_s : float
        ``q`` of the quick steady-state reference filter of the adaptive mode [N/sqrt(s)]:
        the mean of its difference to the estimate over ``settle_window_s`` is how far the
        estimate still has to move (settled flag, condition d).
    load_aware : bool
        Adaptive mode, built on the empty balance: run the model of the load on the pan (on a
        grid of ``model_step_kg``, up to ``max_step_kg``), switching when the estimate,
        known to 1 g, leaves the model's band by 0.6 steps.
    model_step_kg : float
        Grid of the load models [kg].
    """

    def __init__(self, model_or_mechanics: Union[LinearModel, MechanicalParameters],
                 sample_rate_Hz: float, position_noise_m_rms: float = 2.0e-9,
                 force_random_walk_N_per_sqrt_s: float = DEFAULT_FORCE_RANDOM_WALK_N_PER_SQRT_S,
                 coil_force_noise_N_rms: float = 0.0, settle_window_s: float = 0.02,
                 settle_threshold_kg: float = 1.0e-6, initial_pan_force_N=None,
                 backend: str = 'auto', adaptive: bool = True, change_window_s: float = 0.002,
                 change_threshold_sigma: float = 12.0, max_step_kg: float = 0.5,
                 settle_sigma: float = 3.0,
                 reference_random_walk_N_per_sqrt_s: float = 1.0e-4, load_aware: bool = True,
                 model_step_kg: float = 0.01) -> None:
        if isinstance(model_or_mechanics, LinearModel):
            model = model_or_mechanics
        elif isinstance(model_or_mechanics, MechanicalParameters):
            model = linearise(model_or_mechanics)
        else:
            raise WeighingError('model_or_mechanics: need a LinearModel or '
                                f'MechanicalParameters, got {type(model_or_mechanics).__name__}')
        if backend not in BACKENDS:
            raise WeighingError(f'backend: must be one of {BACKENDS}, got {backend!r}')
        if backend == 'auto':
            backend = 'numba' if _numba_available() else 'numpy'
        self.backend = backend
        self.adaptive = bool(adaptive)
        self._run = _jitted() if backend == 'numba' else kalman_loop.kalman_block
        self._run_adaptive = (_adaptive_jitted() if backend == 'numba'
                              else kalman_loop.adaptive_block)
        self.model = model
        self._fs = _positive('sample_rate_Hz', sample_rate_Hz)
        sigma_y = _positive('position_noise_m_rms', position_noise_m_rms)
        q = _positive('force_random_walk_N_per_sqrt_s', force_random_walk_N_per_sqrt_s)
        sigma_c = float(coil_force_noise_N_rms)
        if not (math.isfinite(sigma_c) and sigma_c >= 0.0):
            raise WeighingError(f'coil_force_noise_N_rms: must be finite and >= 0, got '
                                f'{coil_force_noise_N_rms!r}')
        op = model.operating_point
        self.coil_force_N0 = float(op.F_c_N)
        self.pan_force_N0 = float(op.F_p_N)
        self.position_m0 = float(op.y_m)
        self.g_m_per_s2 = float(op.mechanics.g_m_per_s2)
        self.force_ratio = (model.static_gain_m_per_N('pan')
                            / model.static_gain_m_per_N('coil'))
        self.coil_gain_m_per_N = model.static_gain_m_per_N('coil')

        n = model.A.shape[0]
        phi, gam, _, _, _ = signal.cont2discrete(
            (model.A, model.B, model.C, model.D), 1.0 / self._fs, method='zoh')
        phi_a = np.zeros((n + 1, n + 1))
        phi_a[:n, :n] = phi
        phi_a[:n, n] = gam[:, 1]
        phi_a[n, n] = 1.0
        gam_c = np.zeros(n + 1)
        gam_c[:n] = gam[:, 0]
        c_a = np.zeros(n + 1)
        c_a[:n] = model.C[0]
        noise = np.zeros((n + 1, n + 1))
        noise[n, n] = q * q / self._fs
        noise += sigma_c ** 2 * np.outer(gam_c, gam_c)
        p_prior, gain = _steady_state(phi_a, c_a, noise, sigma_y ** 2)
        q_ref = _positive('reference_random_walk_N_per_sqrt_s',
                          reference_random_walk_N_per_sqrt_s)
        noise_ref = noise.copy()
        noise_ref[n, n] = q_ref * q_ref / self._fs
        self._reference_gain = _steady_state(phi_a, c_a, noise_ref, sigma_y ** 2)[1]
        self.transition = phi_a
        self.coil_input = gam_c
        self.output_row = c_a
        self.gain = gain
        #: Steady-state covariance of the filtered state (a posteriori).
        self.covariance = p_prior - np.outer(gain, c_a @ p_prior)
        self._window = int(round(_positive('settle_window_s', settle_window_s) * self._fs))
        if self._window < 2:
            raise WeighingError(f'settle_window_s: {settle_window_s!r} s is fewer than 2 '
                                'samples')
        self._threshold_N = _positive('settle_threshold_kg', settle_threshold_kg) * \
            self.g_m_per_s2
        self._initial = (self.pan_force_N0 if initial_pan_force_N is None
                         else float(initial_pan_force_N))
        self._settle_sigma = _positive('settle_sigma', settle_sigma)
        # the adaptive filter, in coordinates scaled by the steady-state standard deviations
        self._r = sigma_y ** 2
        self._q = q
        self._sigma_c = sigma_c
        self._change_window = int(round(_positive('change_window_s', change_window_s) * self._fs))
        if self._change_window < 2:
            raise WeighingError(f'change_window_s: {change_window_s!r} s is fewer than 2 '
                                'samples')
        self._change_threshold = self._change_window + _positive(
            'change_threshold_sigma', change_threshold_sigma) * math.sqrt(
            2.0 * self._change_window)
        self._nis_alpha = 1.0 / self._fs        # a running mean over 1 s
        self._step_N = _positive('max_step_kg', max_step_kg) * self.g_m_per_s2
        # load-aware models: the load's inertia is what the empty model lacks while the lever
        # moves; the pan-force state means the same load force in every loaded model (their
        # operating points cancel the built-in weight), so a switch keeps the state
        self._model_step_kg = _positive('model_step_kg', model_step_kg)
        self._load_aware = bool(load_aware) and self.adaptive and op.F_p_N == 0.0
        self._base_mechanics = op.mechanics
        self._models = {0: self._filter_model(phi_a, gam_c, c_a, p_prior, gain)}
        self._max_model = int(round(float(max_step_kg) / self._model_step_kg))
        #: Load models the adaptive filter has switched to since the construction.
        self.model_switches = 0
        #: Load changes declared by the adaptive filter since the construction.
        self.changes = 0
        self.reset()

    def _filter_model(self, phi_a, gam_c, c_a, p_prior, gain) -> dict:
        """The adaptive filter's matrices in coordinates scaled by one model's steady state."""
        posterior = p_prior - np.outer(gain, c_a @ p_prior)
        scale = np.sqrt(np.maximum(np.diag(posterior), 0.0))
        scale[scale == 0.0] = 1.0
        inflation = np.full(scale.size, STATE_INFLATION)
        inflation[-1] = (self._step_N / scale[-1]) ** 2
        return {'scale': scale, 'phi': phi_a * scale[None, :] / scale[:, None],
                'gamma': gam_c / scale, 'c': c_a * scale,
                'q_w': self._q ** 2 / self._fs / scale[-1] ** 2,
                'prior': p_prior / np.outer(scale, scale), 'inflation': inflation}

    def _model(self, k: int) -> dict:
        """The filter model of the load ``k * model_step_kg`` (built once, then cached)."""
        if k not in self._models:
            model = linearise(loaded(self._base_mechanics, k * self._model_step_kg))
            n = model.A.shape[0]
            phi, gam, _, _, _ = signal.cont2discrete(
                (model.A, model.B, model.C, model.D), 1.0 / self._fs, method='zoh')
            phi_a = np.zeros((n + 1, n + 1))
            phi_a[:n, :n] = phi
            phi_a[:n, n] = gam[:, 1]
            phi_a[n, n] = 1.0
            gam_c = np.zeros(n + 1)
            gam_c[:n] = gam[:, 0]
            c_a = np.zeros(n + 1)
            c_a[:n] = model.C[0]
            noise = np.zeros((n + 1, n + 1))
            noise[n, n] = self._q ** 2 / self._fs
            noise += self._sigma_c ** 2 * np.outer(gam_c, gam_c)
            p_prior, gain = _steady_state(phi_a, c_a, noise, self._r)
            self._models[k] = self._filter_model(phi_a, gam_c, c_a, p_prior, gain)
        return self._models[k]

    def _band(self, k: int, scale_w: float):
        """The scaled force band of model ``k``; outside it (known to 1 g) the model switches."""
        if not self._load_aware:
            return -math.inf, math.inf, -1.0
        step_N = self._model_step_kg * self.g_m_per_s2
        low = (k - 0.6) * step_N / scale_w if k > 0 else -math.inf
        high = (k + 0.6) * step_N / scale_w if k < self._max_model else math.inf
        return low, high, (MODEL_SWITCH_SIGMA_KG * self.g_m_per_s2 / scale_w) ** 2

    def _switch_model(self) -> None:
        """Move the adaptive filter to the model of its current load estimate."""
        old = self._model(self._model_k)
        physical = self._state_z * old['scale']
        load_kg = (physical[-1] + self.pan_force_N0) / self.g_m_per_s2
        k = int(min(max(round(load_kg / self._model_step_kg), 0), self._max_model))
        new = self._model(k)
        self._model_k = k
        self._state_z = physical / new['scale']
        self._p_z = new['prior'] + np.diag(new['inflation'])
        self.model_switches += 1

    @property
    def model_load_kg(self) -> float:
        """The load of the model the adaptive filter runs now [kg]."""
        return self._model_k * self._model_step_kg

    @property
    def sample_rate_Hz(self) -> float:
        """Sample rate [Hz]."""
        return self._fs

    @property
    def pan_force_u_N(self) -> float:
        """Model-based steady-state standard deviation of the pan-force estimate [N]."""
        return float(math.sqrt(max(self.covariance[-1, -1], 0.0)))

    def reset(self, pan_force_N=None) -> None:
        """
        Restart from rest at the operating point with a given pan-force estimate.

        Parameters
        ----------
        pan_force_N : float, optional
            Initial pan-force estimate [N]; default the constructor's.
        """
        start = self._initial if pan_force_N is None else float(pan_force_N)
        self._state = np.zeros(self.transition.shape[0])
        self._state[-1] = start - self.pan_force_N0
        self._tail = np.zeros(0)
        self._model_k = 0
        empty = self._models[0]
        self._state_z = self._state / empty['scale']
        self._p_z = empty['prior'].copy()
        self._ring = np.zeros(self._change_window)
        self._counters = np.array([0.0, 0.0, 0.0, 0.0, 1.0])
        self._reference_state = self._state.copy()
        self._lag_tail = np.zeros(0)
        self._fresh = True

    def update_block(self, position_m, coil_force_N) -> np.ndarray:
        """
        Process one block and return the pan-force estimate per sample.

        Parameters
        ----------
        position_m : array_like, shape (k,)
            Measured lever-end position [m].
        coil_force_N : array_like, shape (k,)
            Compensation force ``k(y) I`` from the measured current [N], positive up.

        Returns
        -------
        ndarray, shape (k,)
            Pan-force estimate [N], positive down.
        """
        return self.update_block_detailed(position_m, coil_force_N).pan_force_N

    def update_block_detailed(self, position_m, coil_force_N) -> DynamicEstimate:
        """
        Process one block and return all outputs.

        Parameters
        ----------
        position_m : array_like, shape (k,)
            Measured lever-end position [m].
        coil_force_N : array_like, shape (k,)
            Compensation force from the measured current [N], positive up.

        Returns
        -------
        DynamicEstimate
            Pan force, equivalent compensation force, innovation and settled flag.

        Raises
        ------
        WeighingError
            If the arrays are not 1-D of equal length or hold non-finite values.
        """
        y, f = same_clock_records(('position_m', 'coil_force_N'), (position_m, coil_force_N),
                                  WeighingError, allow_empty=True)
        w = np.empty(y.size)
        e = np.empty(y.size)
        if self.adaptive:
            var = np.empty(y.size)
            since = np.empty(y.size)
            before = self._counters[2]
            dy = y - self.position_m0
            df = f - self.coil_force_N0
            pos = 0
            while pos < y.size:
                m = self._model(self._model_k)
                low, high, switch_var = self._band(self._model_k, m['scale'][-1])
                done = self._run_adaptive(
                    m['phi'], m['gamma'], m['c'], self._r, m['q_w'], self._state_z, self._p_z,
                    dy[pos:], df[pos:], self._change_window, self._change_threshold,
                    m['inflation'], self._ring, self._counters, w[pos:], var[pos:], e[pos:],
                    since[pos:], self._nis_alpha, low, high, switch_var)
                w[pos:pos + done] *= m['scale'][-1]
                var[pos:pos + done] *= m['scale'][-1] ** 2
                pos += done
                if pos < y.size:
                    self._switch_model()
            self.changes += int(self._counters[2] - before)
            u = np.sqrt(np.maximum(var, 0.0))
            change = since == 1.0
            if self._fresh and change.size:
                change[0] = False           # the start, not a declared change
            since_ok = since >= self._window
        else:
            self._run(self.transition, self.coil_input, self.output_row, self.gain, self._state,
                      y - self.position_m0, f - self.coil_force_N0, w, e)
            u = np.full(y.size, self.pan_force_u_N)
            change = np.zeros(y.size, dtype=bool)
            since_ok = np.ones(y.size, dtype=bool)
        # the quick reference filter: how far the estimate still has to go
        reference = np.empty(y.size)
        self._run(self.transition, self.coil_input, self.output_row, self._reference_gain,
                  self._reference_state, y - self.position_m0, f - self.coil_force_N0,
                  reference, np.empty(y.size))
        lag = np.abs(self._lag_mean(reference - w))
        since_ok &= lag < 0.5 * self._threshold_N
        self._fresh = self._fresh and y.size == 0
        pan = w + self.pan_force_N0
        settled = self._settled(pan) & since_ok & (self._settle_sigma * u < self._threshold_N)
        return DynamicEstimate(pan, self.equivalent_force_N(pan), e, settled, u, change)

    def _lag_mean(self, lag: np.ndarray) -> np.ndarray:
        # mean of (reference - estimate) over the settle window ending at each sample; inf
        # until a full window exists since the reset
        # (each window summed on its own: the same values in the same order whatever the
        # block split, so the result is bit for bit the same)
        series = np.concatenate((self._lag_tail, lag))
        out = np.full(lag.size, np.inf)
        if series.size >= self._window:
            means = sliding_window_view(series, self._window).mean(axis=1)
            out[self._window - 1 - self._lag_tail.size:] = means
        self._lag_tail = series[max(0, series.size - (self._window - 1)):]
        return out

    def _settled(self, pan: np.ndarray) -> np.ndarray:
        # The tail holds up to window - 1 estimates since the reset, so the first full window
        # ends at block index window - 1 - tail.size >= 0.
        series = np.concatenate((self._tail, pan))
        settled = np.zeros(pan.size, dtype=bool)
        if series.size >= self._window:
            view = sliding_window_view(series, self._window)
            spread = view.max(axis=1) - view.min(axis=1)
            settled[self._window - 1 - self._tail.size:] = spread < self._threshold_N
        self._tail = series[max(0, series.size - (self._window - 1)):]
        return settled

    def equivalent_force_N(self, pan_force_N):
        """
        Equivalent compensation force ``F_c0 - r (F_p - F_p0)``, vectorised.

        Parameters
        ----------
        pan_force_N : float or array_like
            Pan-force estimate [N].

        Returns
        -------
        float or ndarray
            Compensation force [N] that would hold ``y = y0`` against that pan force.
        """
        return self.coil_force_N0 - self.force_ratio * (np.asarray(pan_force_N, dtype=float)
                                                        - self.pan_force_N0)

    def mass_u_kg(self, pan_force_u_N, calibration: WeighingCalibration):
        """
        A standard deviation of the pan-force estimate as a mass, through a calibration.

        Parameters
        ----------
        pan_force_u_N : float or array_like
            Standard deviation of the pan-force estimate [N].
        calibration : WeighingCalibration
            The calibration of the compensation force readings.

        Returns
        -------
        float or ndarray
            Standard deviation [kg] (``|S r| u``).
        """
        return abs(calibration.sensitivity_kg_per_N * self.force_ratio) * np.asarray(
            pan_force_u_N, dtype=float)

    def mass_kg(self, pan_force_N, calibration: WeighingCalibration):
        """
        Mass reading of a pan-force estimate through a (static) calibration.

        Parameters
        ----------
        pan_force_N : float or array_like
            Pan-force estimate [N].
        calibration : WeighingCalibration
            The calibration of the compensation force readings.

        Returns
        -------
        float or ndarray
            Net mass [kg].
        """
        return calibration.mass_kg(self.equivalent_force_N(pan_force_N))
