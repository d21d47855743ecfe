"""The simulator's fixed-step RK4 against scipy's solve_ivp at tight tolerance, both holds."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from emfc_ros.core.model import BalanceParameters, lever_position_m, state_derivative
from emfc_ros.core.sim import Simulator

PARAMS = BalanceParameters()
FS_HZ = 10000.0


def _inputs(sim, n=600):
    u = np.tile(sim.hold_setpoints_V[:, None], (1, n))
    u[0, 100:] += 0.004
    u[0, 300:] -= 0.008
    u[0, 450:] += 0.003 * np.sin(np.arange(n - 450) * 0.3)
    u[1, 200:] = 0.2
    u[1, 400:] = -0.1
    return u


def _reference(sim, u, hold):
    """solve_ivp (DOP853, rtol 1e-11) sample by sample, the setpoint held or ramped."""
    mech = sim.mechanics
    x = sim.state
    prev = sim.last_setpoints_V
    y = np.empty(u.shape[1])
    dt = 1.0 / FS_HZ
    for n in range(u.shape[1]):
        y[n] = lever_position_m(x, mech)
        start = prev if hold == 'foh' else u[:, n]

        def rhs(t, xx, start=start, end=u[:, n]):
            v = start + (t / dt) * (end - start)
            i_c = PARAMS.coil_amplifier.current_A(v[0])
            f_p = PARAMS.load_changer.force_N(PARAMS.load_changer_amplifier.current_A(v[1]))
            f_c = PARAMS.motor.force_N(i_c, lever_position_m(xx, mech))
            return state_derivative(xx, f_c, f_p, mech)

        x = solve_ivp(rhs, (0.0, dt), x, method='DOP853', rtol=1e-11, atol=1e-18).y[:, -1]
        prev = u[:, n]
    return y


@pytest.mark.parametrize('hold', ['zoh', 'foh'])
def test_rk4_matches_solve_ivp(hold):
    errors = []
    for substeps in (1, 2):
        sim = Simulator(PARAMS, FS_HZ, noise=False, quantisation=False, hold=hold,
                        substeps=substeps)
        u = _inputs(sim)
        if substeps == 1:
            ref = _reference(sim, u, hold)
        out = sim.step_block(u)[sim.channel_names.index('position_true_m')]
        scale = np.abs(ref).max()
        assert scale > 1e-5
        errors.append(np.abs(out - ref).max() / scale)
    assert errors[0] < 1e-6, errors
    assert errors[1] < errors[0] / 8.0, errors      # fourth order
