"""Simulator: channels, equilibrium, block invariance, converters, stops, noise and load."""

from hypothesis import given, HealthCheck, settings, strategies as st
import numpy as np
import pytest

from emfc_ros.core.model import BalanceParameters
from emfc_ros.core.sim import (channel_names, convert_V, lsb_V, min_substeps, numba_available,
                               Simulator, standard_normals)

PARAMS = BalanceParameters()
CONV = PARAMS.converters
FS_HZ = 10000.0
BACKENDS = ['numpy'] + (['numba'] if numba_available() else [])
LSB_V = 20.0 / 65536.0


def _row(sim, out, name):
    return out[sim.channel_names.index(name)]


def _held(sim, n):
    return np.tile(sim.hold_setpoints_V[:, None], (1, n))


def _excitation(sim, n, seed=1):
    rng = np.random.default_rng(seed)
    u = _held(sim, n)
    u[0] += np.repeat(rng.normal(0.0, 2e-3, n // 10 + 1), 10)[:n]
    u[1] += np.repeat(rng.normal(0.0, 0.05, n // 25 + 1), 25)[:n]
    return u


def test_channel_names_and_units():
    sim = Simulator(PARAMS, FS_HZ)
    assert sim.channel_names == (
        'coil_setpoint_V', 'load_changer_setpoint_V', 'coil_current_A', 'load_changer_current_A',
        'sensor_V', 'position_m', 'coil_force_N', 'load_changer_force_N', 'position_true_m',
        'pan_force_N', 'coil_force_true_N')
    assert sim.channel_units == ('V', 'V', 'A', 'A', 'V', 'm', 'N', 'N', 'm', 'N', 'N')
    assert all(n.endswith('_' + u) for n, u in zip(sim.channel_names, sim.channel_units))
    short = Simulator(PARAMS, FS_HZ, reference_channels=False)
    assert short.channel_names == channel_names(False) == sim.channel_names[:8]
    assert short.step_block(_held(short, 5)).shape == (8, 5)


@pytest.mark.parametrize('backend', BACKENDS)
def test_equilibrium_holds_with_zero_excitation(backend):
    sim = Simulator(PARAMS, FS_HZ, noise=False, quantisation=False, backend=backend)
    x0 = sim.state
    n = 10000 if backend == 'numba' else 300   # 1 s compiled, 30 ms interpreted
    out = sim.step_block(_held(sim, n))
    assert np.abs(_row(sim, out, 'position_true_m')).max() < 1e-12
    assert np.abs(_row(sim, out, 'position_m')).max() < 1e-12
    assert np.abs(sim.state - x0).max() < 1e-12
    assert sim.sample_index == n


@pytest.mark.parametrize('backend', BACKENDS)
@pytest.mark.parametrize('hold', ['zoh', 'foh'])
@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(cuts=st.lists(st.integers(0, 240), min_size=0, max_size=6),
       seed=st.integers(0, 2 ** 64 - 1))
def test_blockwise_equals_one_shot_bit_for_bit(backend, hold, cuts, seed):
    n = 240
    kwargs = dict(seed=seed, hold=hold, backend=backend)
    one = Simulator(PARAMS, FS_HZ, **kwargs)
    u = _excitation(one, n)
    whole = one.step_block(u)
    split = Simulator(PARAMS, FS_HZ, **kwargs)
    edges = [0] + sorted(cuts) + [n]
    parts = [split.step_block(u[:, a:b]) for a, b in zip(edges[:-1], edges[1:])]
    assert np.array_equal(np.concatenate(parts, axis=1), whole)
    assert np.array_equal(split.state, one.state)
    assert split.sample_index == one.sample_index == n


@pytest.mark.skipif(not numba_available(), reason='numba not installed')
def test_blockwise_equals_one_shot_for_long_runs():
    n = 100000
    one = Simulator(PARAMS, 20000.0, seed=7)
    u = _excitation(one, n)
    whole = one.step_block(u)
    split = Simulator(PARAMS, 20000.0, seed=7)
    edges = [0, 1000, 1001, 16383, 65537, 99000, n]
    parts = [split.step_block(u[:, a:b]) for a, b in zip(edges[:-1], edges[1:])]
    assert np.array_equal(np.concatenate(parts, axis=1), whole)


@pytest.mark.skipif(not numba_available(), reason='numba not installed')
@pytest.mark.parametrize('hold', ['zoh', 'foh'])
def test_numba_and_numpy_backends_agree(hold):
    a = Simulator(PARAMS, FS_HZ, seed=3, hold=hold, quantisation=False, backend='numba')
    b = Simulator(PARAMS, FS_HZ, seed=3, hold=hold, quantisation=False, backend='numpy')
    u = _excitation(a, 300)
    oa, ob = a.step_block(u), b.step_block(u)
    scale = np.abs(ob).max(axis=1, keepdims=True)
    assert np.all(np.abs(oa - ob) <= 1e-10 * scale + 1e-300)


def test_reset_repeats_the_run():
    sim = Simulator(PARAMS, FS_HZ, seed=11)
    u = _excitation(sim, 500)
    first = sim.step_block(u)
    sim.set_load(0.01)
    sim.step_block(u)
    sim.reset()
    assert sim.sample_index == 0 and sim.load_mass_kg == 0.0
    assert np.array_equal(sim.step_block(u), first)


def test_dac_quantisation_and_saturation():
    assert lsb_V(16, 10.0) == LSB_V
    sim = Simulator(PARAMS, FS_HZ, noise=False)
    u = _held(sim, 6)
    u[0] = [0.0, 1.2345678, -3.0e-4, 12.0, -12.0, 9.9999]
    u[1] = [LSB_V * 0.49, LSB_V * 0.51, -LSB_V * 1.5001, 10.0, -10.0, 1e9]
    out = sim.step_block(u)
    applied = out[:2]
    codes = applied / LSB_V
    assert np.array_equal(codes, np.round(codes))
    assert np.all(np.abs(applied - u.clip(-10.0, 10.0 - LSB_V)) <= LSB_V / 2)
    assert applied[0, 3] == 32767 * LSB_V and applied[0, 4] == -10.0
    assert list(applied[1, :3]) == [0.0, LSB_V, -2 * LSB_V]
    assert applied[1, 5] == 32767 * LSB_V
    np.testing.assert_array_equal(applied, convert_V(u, 16, 10.0))
    off = Simulator(PARAMS, FS_HZ, noise=False, quantisation=False).step_block(u)
    np.testing.assert_array_equal(off[:2], u.clip(-10.0, 10.0))


def test_adc_quantisation_of_measured_channels():
    sim = Simulator(PARAMS, FS_HZ, noise=False)
    out = sim.step_block(_excitation(sim, 400))
    for name, scale in (('sensor_V', 1.0), ('coil_current_A', 100.0),
                        ('load_changer_current_A', 100.0)):
        codes = _row(sim, out, name) * scale / LSB_V
        assert np.allclose(codes, np.round(codes), rtol=0, atol=1e-6), name
    # position_m is the inverse sensor characteristic of the quantised voltage
    np.testing.assert_allclose(_row(sim, out, 'position_m'),
                               PARAMS.sensor.position_m(_row(sim, out, 'sensor_V')),
                               rtol=1e-12, atol=1e-20)
    err = _row(sim, out, 'position_m') - _row(sim, out, 'position_true_m')
    assert np.abs(err).max() < 4e-9    # half an LSB is 3.05 nm at 5e4 V/m
    np.testing.assert_allclose(
        _row(sim, out, 'coil_force_N'),
        PARAMS.motor.force_N(_row(sim, out, 'coil_current_A'), _row(sim, out, 'position_m')),
        rtol=1e-14)
    i_lc = _row(sim, out, 'load_changer_current_A')
    np.testing.assert_allclose(_row(sim, out, 'load_changer_force_N'),
                               PARAMS.load_changer.force_N(i_lc), rtol=1e-14)


def test_amplifier_current_saturation():
    sim = Simulator(PARAMS, FS_HZ, noise=False, quantisation=False)
    u = _held(sim, 3)
    u[1] = [-10.0, 10.0, 0.0]   # -100.7 mA (clipped), +99.3 mA, 7.6 uA
    out = sim.step_block(u)
    i_lc = _row(sim, out, 'load_changer_current_A')
    assert i_lc[0] == -0.1
    assert i_lc[1] == pytest.approx(PARAMS.load_changer_amplifier.current_A(10.0), rel=1e-14)
    assert _row(sim, out, 'pan_force_N')[0] == pytest.approx(PARAMS.load_changer.force_N(-0.1))


def test_sensor_saturates_at_its_range():
    mech = PARAMS.mechanics
    y = 130e-6
    q = y / (mech.l2_m + mech.l3_m)
    sim = Simulator(PARAMS, FS_HZ, noise=False, quantisation=False, x0=[q, q, 0.0, 0.0])
    out = sim.step_block(_held(sim, 1))
    assert _row(sim, out, 'position_true_m')[0] == pytest.approx(y, rel=1e-6)
    assert _row(sim, out, 'position_m')[0] == pytest.approx(CONV.sensor_range_m, rel=1e-12)
    assert _row(sim, out, 'sensor_V')[0] == pytest.approx(
        PARAMS.sensor.voltage_V(CONV.sensor_range_m), rel=1e-14)


@pytest.mark.parametrize('setpoint_V, sign', [(10.0, 1.0), (-10.0, -1.0)])
def test_mechanical_stop_limits_travel(setpoint_V, sign):
    sim = Simulator(PARAMS, FS_HZ, noise=False)
    u = _held(sim, 5000)
    u[0] = setpoint_V      # about +/-2.2 N at the lever end, 180 times the hold force change
    y = sign * _row(sim, sim.step_block(u), 'position_true_m')
    stop = CONV.stop_position_m
    assert y.max() > stop                       # it reaches the stop ...
    assert y.max() < stop + 40e-6               # ... bounces into it a little ...
    settled = y[-1000:]                         # ... and rests on it: 2.2 N / 1e6 N/m
    assert np.all(settled > stop) and np.all(settled < stop + 3e-6)
    # the sensor saturates meanwhile
    assert np.abs(_row(sim, sim.step_block(u[:, :1]), 'position_m')).max() <= \
        CONV.sensor_range_m * 1.001


def test_noise_is_seeded_and_has_the_configured_rms():
    n = 40000
    kwargs = dict(quantisation=False)
    a = Simulator(PARAMS, 20000.0, seed=5, **kwargs)
    u = _held(a, n)
    oa = a.step_block(u)
    ob = Simulator(PARAMS, 20000.0, seed=5, **kwargs).step_block(u)
    oc = Simulator(PARAMS, 20000.0, seed=6, **kwargs).step_block(u)
    assert np.array_equal(oa, ob)
    assert not np.array_equal(oa[2], oc[2])
    sensor = _row(a, oa, 'position_m') - _row(a, oa, 'position_true_m')
    assert np.std(sensor) == pytest.approx(CONV.sensor_noise_m_rms, rel=0.05)
    i_true = PARAMS.coil_amplifier.current_A(_row(a, oa, 'coil_setpoint_V'))
    coil = _row(a, oa, 'coil_current_A') - i_true
    assert np.std(coil) == pytest.approx(CONV.coil_current_noise_A_rms, rel=0.05)
    lc = _row(a, oa, 'load_changer_current_A') - PARAMS.load_changer_amplifier.current_A(0.0)
    assert np.std(lc) == pytest.approx(CONV.load_changer_current_noise_A_rms, rel=0.05)
    # the three streams are independent
    assert abs(np.corrcoef(sensor, coil)[0, 1]) < 0.03
    assert abs(np.corrcoef(coil, lc)[0, 1]) < 0.03
    off = Simulator(PARAMS, 20000.0, seed=5, noise=False, quantisation=False).step_block(u)
    assert np.abs(_row(a, off, 'position_m') - _row(a, off, 'position_true_m')).max() < 1e-18


def test_noise_is_a_pure_function_of_the_sample_index():
    whole = standard_normals(42, 0, 5000)
    assert np.array_equal(standard_normals(42, 1234, 100), whole[:, 1234:1334])
    assert not np.array_equal(standard_normals(43, 0, 10), whole[:, :10])
    # standard normal: mean 0, variance 1, Gaussian kurtosis, independent rows
    big = standard_normals(1, 10 ** 6, 200000)
    assert np.abs(big.mean(axis=1)).max() < 0.01
    assert np.abs(big.std(axis=1) - 1.0).max() < 0.01
    assert np.abs((big ** 4).mean(axis=1) - 3.0).max() < 0.1
    assert np.abs(np.corrcoef(big)[np.triu_indices(3, 1)]).max() < 0.01


@pytest.mark.parametrize('backend', BACKENDS)
def test_kernel_noise_is_the_documented_generator(backend):
    """The kernel adds standard_normals(seed, index) times the rms, for any first index."""
    sim = Simulator(PARAMS, FS_HZ, seed=99, quantisation=False, backend=backend)
    u = _held(sim, 150)
    sim.step_block(u[:, :50])
    out = sim.step_block(u[:, 50:])
    z = standard_normals(99, 50, 100)
    sensor = _row(sim, out, 'position_m') - _row(sim, out, 'position_true_m')
    np.testing.assert_allclose(sensor, z[0] * CONV.sensor_noise_m_rms, rtol=1e-6, atol=1e-19)
    coil = _row(sim, out, 'coil_current_A') - PARAMS.coil_amplifier.current_A(
        _row(sim, out, 'coil_setpoint_V'))
    np.testing.assert_allclose(coil, z[1] * CONV.coil_current_noise_A_rms, rtol=1e-6,
                               atol=1e-17)
    lc = _row(sim, out, 'load_changer_current_A') - PARAMS.load_changer_amplifier.current_A(0.0)
    np.testing.assert_allclose(lc, z[2] * CONV.load_changer_current_noise_A_rms, rtol=1e-6,
                               atol=1e-17)


def test_first_order_hold_delays_by_one_sample():
    zoh = Simulator(PARAMS, FS_HZ, noise=False, hold='zoh')
    foh = Simulator(PARAMS, FS_HZ, noise=False, hold='foh')
    u = _excitation(zoh, 300)
    oz, of = zoh.step_block(u), foh.step_block(u)
    for name in ('coil_current_A', 'load_changer_current_A'):
        assert np.array_equal(_row(foh, of, name)[1:], _row(zoh, oz, name)[:-1])
    np.testing.assert_array_equal(_row(foh, of, 'coil_setpoint_V'),
                                  _row(zoh, oz, 'coil_setpoint_V'))
    assert np.array_equal(foh.last_setpoints_V, oz[:2, -1])


def test_set_load_moves_the_hold_point_and_keeps_the_state():
    sim = Simulator(PARAMS, FS_HZ, noise=False, quantisation=False)
    sim.step_block(_held(sim, 10))
    x = sim.state
    empty = sim.hold_setpoints_V
    sim.set_load(0.1)
    assert np.array_equal(sim.state, x)
    loaded = sim.hold_setpoints_V
    # 100 g on the pan needs about 0.98 N * 0.1333 / 21.69 N/A = 6 mA less coil current
    assert (empty[0] - loaded[0]) * 0.010 == pytest.approx(0.1 * 9.81 * 0.13326 / 21.692,
                                                           rel=0.01)
    out = sim.step_block(np.tile(empty[:, None], (1, 200)))
    assert _row(sim, out, 'position_true_m')[-1] > 20e-6   # the weight tips the balance
    with pytest.raises(ValueError, match='load_mass_kg'):
        sim.set_load(-1.0)


def test_substeps_are_checked_and_chosen():
    assert min_substeps(PARAMS, 10000.0) == 1
    assert min_substeps(PARAMS, 1000.0) > 1
    assert Simulator(PARAMS, 1000.0).substeps == min_substeps(PARAMS, 1000.0)
    with pytest.raises(ValueError, match='substeps'):
        Simulator(PARAMS, 1000.0, substeps=1)
    with pytest.raises(ValueError, match='substeps'):
        Simulator(PARAMS, FS_HZ, substeps=0)


def test_bad_arguments_are_refused():
    with pytest.raises(ValueError, match='sample_rate_Hz'):
        Simulator(PARAMS, -1.0)
    with pytest.raises(ValueError, match='seed'):
        Simulator(PARAMS, FS_HZ, seed=-1)
    with pytest.raises(ValueError, match='hold'):
        Simulator(PARAMS, FS_HZ, hold='cubic')
    with pytest.raises(ValueError, match='backend'):
        Simulator(PARAMS, FS_HZ, backend='fortran')
    with pytest.raises(ValueError, match='state'):
        Simulator(PARAMS, FS_HZ, x0=[0.0])
    sim = Simulator(PARAMS, FS_HZ)
    with pytest.raises(ValueError, match=r'shape \(2, n\)'):
        sim.step_block(np.zeros((3, 4)))
    with pytest.raises(ValueError, match='finite'):
        sim.step_block(np.array([[np.nan], [0.0]]))
    assert sim.step_block(np.zeros((2, 0))).shape == (11, 0)
    assert sim.sample_index == 0
