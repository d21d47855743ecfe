"""The in-loop controller: runtime equals the design, anti-windup, the simulated closed loop."""

import math

import numpy as np
import pytest
from scipy import signal

from emfc_ros.core.control import design_controller, plant_from_model
from emfc_ros.core.control.loop_config import (current_channel_config, loop_config,
                                               LoopConfig)
from emfc_ros.core.control.runtime import (INTEGRAL, pack_controller, pid_terms,
                                           RuntimeController)
from emfc_ros.core.errors import ConfigError
from emfc_ros.core.model.linear import linearise
from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.paths import config_file
from emfc_ros.core.sim.closed_loop import ClosedLoopSimulator
from emfc_ros.core.sim.hold_point import hold_point
from emfc_ros.core.sim.simulator import Simulator

FS_SIM_HZ = 20000.0
LOOP = LoopConfig(rate_Hz=10000.0, crossover_Hz=130.0, phase_margin_deg=40.0,
                  delay_samples=1.5)


@pytest.fixture(scope='module')
def params():
    return BalanceParameters.load_yaml(str(config_file('balance_default.yaml')))


@pytest.fixture(scope='module')
def design(params):
    model = linearise(loaded(params.mechanics, 0.0, False))
    return design_controller(plant_from_model(model), 10000.0, 100.0, 40.0, delay_samples=1.5,
                             notch_Hz=410.0)


def _loop(params, seed=3, **kwargs):
    sim = Simulator(params, FS_SIM_HZ, seed=seed, **kwargs)
    return ClosedLoopSimulator(sim, LOOP)


def test_runtime_controller_is_the_designed_transfer_function(design):
    errors = np.random.default_rng(0).normal(scale=1e-6, size=3000)
    got = RuntimeController(design.controller).update_block(errors)
    want = signal.lfilter(design.controller.numerator, design.controller.denominator, errors)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.max(np.abs(want)))


def test_pid_split_rebuilds_the_stage(design):
    b, a = design.controller.stages[0]
    ki, pole, kd = pid_terms(b, a)
    z = np.exp(2j * np.pi * np.array([1.0, 30.0, 300.0, 3000.0]) / 10000.0)
    pid = 1.0 + ki * (z + 1.0) / (z - 1.0) + kd * (z - 1.0) / (z - pole)
    np.testing.assert_allclose(pid, np.polyval(b, z) / np.polyval(a, z), rtol=1e-10)
    with pytest.raises(ValueError, match='integrator'):
        pid_terms(np.array([1.0, 0.5, 0.1]), np.array([1.0, -0.5, 0.0]))


def test_bumpless_start_holds_the_initial_output(design):
    rc = RuntimeController(design.controller, initial_output_N=0.1667)
    np.testing.assert_allclose(rc.update_block(np.zeros(50)), 0.1667, rtol=1e-12)


def test_anti_windup_stops_the_integral_at_the_limit(design):
    rc = RuntimeController(design.controller, output_limits_N=(-0.5, 0.5))
    out = rc.update_block(np.full(2000, 1e-2))      # a large error: saturates at once
    assert np.all(out[10:] == 0.5)
    frozen = rc.state[INTEGRAL]
    rc.update_block(np.full(2000, 1e-2))
    assert rc.state[INTEGRAL] == frozen
    # without the clamp the integral keeps growing
    free = RuntimeController(design.controller)
    free.update_block(np.full(4000, 1e-2))
    assert free.state[INTEGRAL] > 10.0 * abs(frozen)
    # leaving saturation takes a few samples, not the time to unwind a wound-up integral
    back = rc.update_block(np.full(300, -1e-6))
    assert np.all(np.abs(back[-100:]) < 0.5)
    assert rc.saturated_samples >= 3990
    with pytest.raises(ValueError, match='not finite'):
        rc.update(float('nan'))


def test_pack_refuses_bad_limits_and_controllers(design):
    with pytest.raises(ValueError, match='lower < upper'):
        pack_controller(design.controller, (1.0, -1.0))


def test_config_errors_name_the_key():
    assert loop_config({}) is None
    assert loop_config({'enabled': False}) is None
    cfg = loop_config({'crossover_Hz': 80, 'notch_Hz': 410.0})
    assert cfg.crossover_Hz == 80.0 and cfg.notch_Hz == 410.0
    with pytest.raises(ConfigError, match='control.phase_margin_deg'):
        loop_config({'phase_margin_deg': 95.0})
    with pytest.raises(ConfigError, match='control.gain'):
        loop_config({'gain': 1.0})
    with pytest.raises(ConfigError, match='current_channel.adc_bits'):
        current_channel_config({'adc_bits': 4})


def test_rates_and_delay_must_fit_the_simulator(params):
    sim = Simulator(params, 10000.0, seed=0)
    with pytest.raises(ValueError, match='whole number'):
        ClosedLoopSimulator(sim, LOOP)          # 1.5 samples of 10 kHz
    with pytest.raises(ValueError, match='divide'):
        ClosedLoopSimulator(Simulator(params, 15000.0, seed=0), LOOP)


def test_a_100_g_step_stays_in_the_sensor_range_and_returns_to_zero(params):
    cl = _loop(params)
    names = cl.channel_names
    cl.step_block(np.zeros((2, 2000)))
    cl.set_load(0.1)
    out = cl.step_block(np.zeros((2, int(FS_SIM_HZ))))
    y = out[names.index('position_true_m')]
    assert np.max(np.abs(y)) < params.converters.sensor_range_m
    assert np.max(np.abs(y)) > 5e-6                 # the step did move the lever
    assert abs(np.mean(y[-4000:])) < 2e-9
    # the compensation current is the one that holds 100 g, which differs from the empty
    # pan's by the lever ratio's share of 0.981 N
    i = out[names.index('coil_current_precise_A')]
    held = hold_point(params, 0.1).currents_A[0]
    empty = hold_point(params, 0.0).currents_A[0]
    m = params.mechanics
    ratio = 0.1 * m.g_m_per_s2 * m.l1_m / (m.l2_m + m.l3_m) / params.motor.coefficient_N_per_A(0)
    np.testing.assert_allclose(empty - held, ratio, rtol=1e-3)
    np.testing.assert_allclose(np.mean(i[-4000:]), held, rtol=0, atol=1e-3 * ratio)


def test_block_wise_equals_one_shot(params):
    one = _loop(params, seed=5)
    u = np.zeros((2, 3000))
    u[0, 1000:] = 0.01
    whole = one.step_block(u)
    parts = _loop(params, seed=5)
    split = np.concatenate([parts.step_block(u[:, a:b]) for a, b in
                            ((0, 1), (1, 777), (777, 778), (778, 2000), (2000, 3000))], axis=1)
    np.testing.assert_array_equal(whole, split)
    with pytest.raises(ValueError, match='finite'):
        parts.step_block(np.full((2, 3), np.nan))
    assert parts.sample_index == 3000


def test_interpreted_loop_matches_the_compiled_one(params):
    compiled = _loop(params, seed=2, backend='numba')
    plain = _loop(params, seed=2, backend='numpy')
    u = np.zeros((2, 120))
    u[0, 20:] = 0.05
    a = compiled.step_block(u)
    b = plain.step_block(u)
    row = compiled.channel_names.index('position_true_m')
    np.testing.assert_allclose(a[row], b[row], rtol=1e-9, atol=1e-15)


def test_margin_measured_in_the_simulated_loop_matches_the_design(params):
    """Inject a multisine at the plant input; L = -u_controller / u_plant at each line."""
    cl = _loop(params, seed=4)
    names = cl.channel_names
    period = 4000                      # 0.2 s at 20 kHz: lines every 5 Hz
    lines = np.arange(10, 61)          # 50 .. 300 Hz
    t = np.arange(period) / FS_SIM_HZ
    phases = np.random.default_rng(1).uniform(0, 2 * np.pi, lines.size)
    x = sum(np.cos(2 * np.pi * k * 5.0 * t + p) for k, p in zip(lines, phases))
    x *= 0.03 / np.max(np.abs(x))      # 30 mV peak at the coil setpoint
    cl.step_block(np.vstack([np.tile(x, 3), np.zeros(3 * period)]))    # transient
    out = cl.step_block(np.vstack([np.tile(x, 8), np.zeros(8 * period)]))
    total = out[names.index('coil_setpoint_V')]
    control = total - np.tile(x, 8)
    spec = lambda v: np.fft.rfft(v.reshape(8, period).mean(axis=0))[lines]  # noqa: E731
    loop = -spec(control) / spec(total)
    f = lines * 5.0
    mag = np.log(np.abs(loop))
    i = int(np.nonzero(np.sign(mag[:-1]) != np.sign(mag[1:]))[0][0])
    w = mag[i] / (mag[i] - mag[i + 1])
    crossover = f[i] + w * (f[i + 1] - f[i])
    phase = np.unwrap(np.angle(loop))
    margin = 180.0 + math.degrees(phase[i] + w * (phase[i + 1] - phase[i]))
    margin = (margin + 180.0) % 360.0 - 180.0
    design = cl.design
    assert abs(crossover - design.crossover_Hz) < 0.05 * design.crossover_Hz
    assert abs(margin - design.phase_margin_deg) < 3.0
