"""Block-wise RK4 plant kernel: block invariance, backend agreement and accuracy vs solve_ivp."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from emfc_ros.core.model import (BalanceParameters, equilibrium, lever_position_m,
                                 state_derivative)
from emfc_ros.core.sim import numba_available, PlantKernel

PARAMS = BalanceParameters()
FS_HZ = 10000.0
BACKENDS = ['numpy'] + (['numba'] if numba_available() else [])


def _rest_setpoints():
    op = equilibrium(PARAMS.mechanics)
    current = PARAMS.motor.current_A(op.F_c_N, 0.0)
    return op, PARAMS.coil_amplifier.voltage_V(current)


def _inputs(n=1000):
    op, u0 = _rest_setpoints()
    uc = np.full(n, u0)
    uc[100:] += 0.004
    uc[400:] -= 0.008
    uc[700:] += 0.004
    ul = np.zeros(n)
    ul[250:] = 0.2
    ul[600:] = -0.1
    return op, uc, ul


@pytest.mark.parametrize('backend', BACKENDS)
def test_blockwise_equals_one_shot_bit_for_bit(backend):
    op, uc, ul = _inputs(600)
    one = PlantKernel(PARAMS, FS_HZ, 2, x0=op.x, backend=backend)
    whole = one.run(uc, ul)
    split = PlantKernel(PARAMS, FS_HZ, 2, x0=op.x, backend=backend)
    parts = [split.run(uc[a:b], ul[a:b]) for a, b in [(0, 1), (1, 18), (18, 18), (18, 333),
                                                      (333, 600)]]
    for name in ('y_m', 'sensor_V', 'coil_current_A', 'load_changer_current_A',
                 'coil_force_N', 'pan_force_N'):
        joined = np.concatenate([getattr(p, name) for p in parts])
        assert np.array_equal(joined, getattr(whole, name)), name
    assert np.array_equal(split.state, one.state)
    assert np.array_equal(parts[-1].state_end, whole.state_end)


@pytest.mark.skipif(not numba_available(), reason='numba not installed')
def test_numba_and_numpy_backends_agree():
    op, uc, ul = _inputs(300)
    a = PlantKernel(PARAMS, FS_HZ, 1, x0=op.x, backend='numba').run(uc, ul)
    b = PlantKernel(PARAMS, FS_HZ, 1, x0=op.x, backend='numpy').run(uc, ul)
    np.testing.assert_allclose(a.y_m, b.y_m, rtol=1e-12, atol=1e-12 * np.abs(b.y_m).max())
    np.testing.assert_allclose(a.state_end, b.state_end, rtol=1e-12, atol=1e-15)


def _reference(op, uc, ul):
    """Piecewise solve_ivp (DOP853, rtol 1e-10) of the same chain, restarted at each step."""
    mech = PARAMS.mechanics
    n = uc.size
    edges = np.flatnonzero((np.diff(uc) != 0) | (np.diff(ul) != 0)) + 1
    edges = np.concatenate([[0], edges, [n]])
    x = op.x.copy()
    y = np.empty(n)
    for a, b in zip(edges[:-1], edges[1:]):
        i_c = PARAMS.coil_amplifier.current_A(uc[a])
        f_p = PARAMS.load_changer.force_N(PARAMS.load_changer_amplifier.current_A(ul[a]))

        def rhs(t, xx, i_c=i_c, f_p=f_p):
            f_c = PARAMS.motor.force_N(i_c, lever_position_m(xx, mech))
            return state_derivative(xx, f_c, f_p, mech)

        t = np.arange(a, b + 1) / FS_HZ
        sol = solve_ivp(rhs, (t[0], t[-1]), x, method='DOP853', rtol=1e-10, atol=1e-16,
                        t_eval=t)
        y[a:b] = [lever_position_m(v, mech) for v in sol.y.T[:-1]]
        x = sol.y[:, -1]
    return y, x


def test_kernel_matches_solve_ivp():
    op, uc, ul = _inputs(1000)
    ref, x_end = _reference(op, uc, ul)
    scale = np.abs(ref).max()
    assert scale > 1e-5  # the steps move the lever end by tens of micrometres
    errors = []
    for substeps in (1, 2):
        out = PlantKernel(PARAMS, FS_HZ, substeps, x0=op.x).run(uc, ul)
        errors.append(np.abs(out.y_m - ref).max() / scale)
    assert errors[0] < 1e-6
    assert errors[1] < errors[0] / 10.0  # fourth order: about 16 times smaller


@pytest.mark.parametrize('backend', BACKENDS)
def test_stays_at_rest_at_equilibrium_setpoint(backend):
    op, u0 = _rest_setpoints()
    out = PlantKernel(PARAMS, FS_HZ, 1, x0=op.x, backend=backend).run(
        np.full(500, u0), np.full(500, PARAMS.load_changer_amplifier.voltage_V(
            PARAMS.load_changer.current_A(0.0))))
    assert np.abs(out.y_m).max() < 1e-12
    assert np.abs(out.pan_force_N).max() < 1e-15


def test_outputs_follow_the_characteristics_and_current_limits():
    op, uc, ul = _inputs(200)
    uc = uc.copy()
    uc[150:] = 10.0  # full scale: 99.3 mA, just inside the 0.1 A limit
    ul = np.full(200, -10.0)
    k = PlantKernel(PARAMS, FS_HZ, 1, x0=op.x)
    out = k.run(uc, ul)
    np.testing.assert_allclose(out.sensor_V, PARAMS.sensor.voltage_V(out.y_m), rtol=1e-14)
    np.testing.assert_allclose(out.coil_force_N, PARAMS.motor.force_N(out.coil_current_A,
                                                                      out.y_m), rtol=1e-14)
    assert out.coil_current_A[-1] == pytest.approx(PARAMS.coil_amplifier.current_A(10.0))
    assert np.all(out.load_changer_current_A == -0.1)  # -100.7 mA clipped at the limit
    assert out.pan_force_N[0] == pytest.approx(PARAMS.load_changer.force_N(-0.1))


def test_kernel_rejects_bad_arguments():
    with pytest.raises(ValueError, match='sample_rate_Hz'):
        PlantKernel(PARAMS, 0.0)
    with pytest.raises(ValueError, match='substeps'):
        PlantKernel(PARAMS, FS_HZ, 0)
    with pytest.raises(ValueError, match='backend'):
        PlantKernel(PARAMS, FS_HZ, backend='fortran')
    k = PlantKernel(PARAMS, FS_HZ, backend='numpy')
    with pytest.raises(ValueError, match='equal length'):
        k.run(np.zeros(3), np.zeros(4))
    with pytest.raises(ValueError, match='finite'):
        k.run(np.array([np.nan]), np.zeros(1))
    with pytest.raises(ValueError, match='state'):
        k.state = [0.0, 0.0]
