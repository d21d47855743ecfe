"""
The simulator kernel's fast paths.

The libm fallback of the small-angle sine and cosine, and the check of the setpoints inside the
kernel.
"""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from emfc_ros.core.model import BalanceParameters, lever_position_m, state_derivative
from emfc_ros.core.sim import numba_available, Simulator
from emfc_ros.core.sim.chain import SMALL_ANGLE_RAD

PARAMS = BalanceParameters()
FS_HZ = 10000.0
BACKENDS = ['numpy'] + (['numba'] if numba_available() else [])
# |q1| + |q2| = 1.2 SMALL_ANGLE_RAD (the RK4 steps take the libm path) with the lever end near 0,
# inside the stops
X_LARGE = [0.4 * SMALL_ANGLE_RAD, -0.8 * SMALL_ANGLE_RAD, 0.0, 0.0]


def _reference(sim, u, n):
    """solve_ivp (DOP853, rtol 1e-11) sample by sample, zero-order hold, no stops."""
    mech = sim.mechanics
    x = sim.state
    y = np.empty(n)
    for k in range(n):
        y[k] = lever_position_m(x, mech)
        i_c = PARAMS.coil_amplifier.current_A(u[0, k])
        f_p = PARAMS.load_changer.force_N(PARAMS.load_changer_amplifier.current_A(u[1, k]))

        def rhs(t, xx, i_c=i_c, f_p=f_p):
            return state_derivative(xx, PARAMS.motor.force_N(i_c, lever_position_m(xx, mech)),
                                    f_p, mech)

        x = solve_ivp(rhs, (0.0, 1.0 / FS_HZ), x, method='DOP853', rtol=1e-11,
                      atol=1e-18).y[:, -1]
    return y


@pytest.mark.parametrize('backend', BACKENDS)
def test_large_angles_take_the_libm_path_accurately(backend):
    # the internal mode rings strongly: 8 RK4 steps per sample keep RK4's own error below 1e-6
    sim = Simulator(PARAMS, FS_HZ, noise=False, quantisation=False, x0=X_LARGE, substeps=8,
                    backend=backend)
    n = 60 if backend == 'numpy' else 200
    u = np.tile(sim.hold_setpoints_V[:, None], (1, n))
    ref = _reference(sim, u, n)
    out = sim.step_block(u)[sim.channel_names.index('position_true_m')]
    assert 1e-7 < np.abs(ref).max() < PARAMS.converters.stop_position_m
    assert np.abs(out - ref).max() <= 1e-6 * np.abs(ref).max()


@pytest.mark.skipif(not numba_available(), reason='numba not installed')
def test_backends_agree_across_the_small_angle_threshold():
    kwargs = dict(noise=False, quantisation=False, x0=X_LARGE)
    a = Simulator(PARAMS, FS_HZ, backend='numba', **kwargs)
    b = Simulator(PARAMS, FS_HZ, backend='numpy', **kwargs)
    u = np.tile(a.hold_setpoints_V[:, None], (1, 300))
    oa, ob = a.step_block(u), b.step_block(u)
    scale = np.abs(ob).max(axis=1, keepdims=True)
    assert np.all(np.abs(oa - ob) <= 1e-10 * scale + 1e-300)


@pytest.mark.parametrize('backend', BACKENDS)
@pytest.mark.parametrize('bad', [np.nan, np.inf, -np.inf])
def test_non_finite_setpoints_change_nothing(backend, bad):
    sim = Simulator(PARAMS, FS_HZ, seed=4, backend=backend)
    u = np.tile(sim.hold_setpoints_V[:, None], (1, 40))
    sim.step_block(u[:, :10])
    state, last, index = sim.state, sim.last_setpoints_V, sim.sample_index
    bad_u = u.copy()
    bad_u[1, 25] = bad
    with pytest.raises(ValueError, match='finite'):
        sim.step_block(bad_u)
    assert np.array_equal(sim.state, state) and sim.sample_index == index
    assert np.array_equal(sim.last_setpoints_V, last)
    again = Simulator(PARAMS, FS_HZ, seed=4, backend=backend)
    whole = again.step_block(u)
    assert np.array_equal(sim.step_block(u[:, 10:]), whole[:, 10:])
