"""
The weighing instrument in core (issue 15, items 3 and 4), on the simulated closed loop.

Seeds, loads and step times here were not used to tune anything. The balance runs with the
default in-loop controller at the plant_simulator node's default rates (10 kHz); the
pipeline reads the precise current channel (or the 16-bit monitor) and the position.
"""

import math

import numpy as np
import pytest

from emfc_ros.core.control.loop_config import LoopConfig
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.paths import config_file
from emfc_ros.core.sim.closed_loop import ClosedLoopSimulator
from emfc_ros.core.sim.resolution import simulator_resolution
from emfc_ros.core.sim.simulator import Simulator
from emfc_ros.core.weighing import WeighingCalibration, WeighingError
from emfc_ros.core.weighing.pipeline import WeighingPipeline

FS = 10000.0
MG = 1.0e-6
BLOCK = 1000


@pytest.fixture(scope='module')
def params():
    return BalanceParameters.load_yaml(str(config_file('balance_default.yaml')))


def simulate(params, seed, schedule, seconds, current='coil_current_precise_A'):
    """The closed loop under a load schedule [(time_s, kg)]; current, position, true load."""
    loop = ClosedLoopSimulator(Simulator(params, FS, seed=seed, reference_channels=False),
                               LoopConfig())
    n = int(round(seconds * FS))
    load = np.zeros(n)
    for t, m in schedule:
        load[int(round(t * FS)):] = m
    out = loop.step_loads(load)
    names = loop.channel_names
    res = simulator_resolution(params, current_channel=loop.current_channel)
    return (out[names.index(current)], out[names.index('position_m')], load,
            (res[current]['step'], res[current]['noise_rms']),
            math.hypot(res['position_m']['noise_rms'], res['position_m']['step'] / 12 ** 0.5))


def pipeline(params, resolution, position_noise, **kwargs):
    return WeighingPipeline(params.mechanics, params.motor.coeffs_N_per_A_per_mm_pow, FS,
                            WeighingCalibration.nominal(params.mechanics),
                            position_noise_m_rms=position_noise,
                            current_resolution=resolution, **kwargs)


def feed(pipe, current, position, start=0, stop=None, block=BLOCK):
    """Push whole blocks from ``start``; the readings and dynamic readings released."""
    stop = current.size if stop is None else stop
    readings, dynamic = [], []
    for a in range(start, stop, block):
        b = min(a + block, stop)
        r, d = pipe.push(current[a:b], position[a:b], a)
        readings += r
        dynamic += d
    return readings, dynamic


def calibrate(pipe, current, position):
    """Zero on the empty pan (0..2 s), adjust with the 100 g of 2..4 s; returns the end."""
    readings, _ = feed(pipe, current, position, 0, 20000)
    assert readings[-1].steady and not readings[-1].stable and not readings[-1].calibrated
    pipe.zero()
    readings, _ = feed(pipe, current, position, 20000, 40000)
    assert readings[-1].stable and abs(readings[-1].mass_kg - 0.1) < 0.1e-3
    pipe.adjust(0.1)
    return 40000


def test_before_the_first_zero_no_reading_is_stable(params):
    current, position, _, res, noise = simulate(params, 301, [(0.0, 0.0)], 3.0)
    pipe = pipeline(params, res, noise)
    readings, dynamic = feed(pipe, current, position, 0, 20000)
    assert readings and dynamic
    assert not any(r.stable or r.calibrated for r in readings)
    assert not any(d.settled or d.calibrated for d in dynamic)
    steady = [r for r in readings if r.steady]
    assert steady and all(-0.128 < r.mass_kg < -0.127 for r in steady)    # nominal, unzeroed
    with pytest.raises(WeighingError, match='not zeroed'):
        pipe.tare()
    with pytest.raises(WeighingError, match='not zeroed'):
        pipe.adjust(0.1)
    pipe.zero()
    readings, dynamic = feed(pipe, current, position, 20000)
    assert all(r.stable and r.calibrated and abs(r.mass_kg) < 0.1 * MG for r in readings)
    assert all(d.settled and abs(d.mass_kg) < 0.5 * MG for d in dynamic)


def test_zero_refuses_without_a_full_steady_window(params):
    current, position, _, res, noise = simulate(params, 302, [(0.0, 0.0), (1.6, 0.02)], 2.0)
    pipe = pipeline(params, res, noise)
    with pytest.raises(WeighingError, match='no reading yet'):
        pipe.zero()
    feed(pipe, current, position, 0, 5000)
    with pytest.raises(WeighingError, match='not full'):
        pipe.zero()
    feed(pipe, current, position, 5000, 17000)      # the step at 1.6 s is in the look-ahead
    assert not pipe.last_reading.steady
    with pytest.raises(WeighingError, match='not stable'):
        pipe.zero()


STEPS = [(0.0, 0.0), (2.0, 0.1), (4.0, 0.0),                      # zero, adjust
         (5.3, 0.0523), (6.93, 0.052302), (8.41, 0.052318), (9.87, 0.187), (11.2, 0.0047),
         (12.55, 0.0047015), (14.02, 0.0)]


@pytest.mark.parametrize('seed', [311, 312])
def test_every_stable_reading_is_right_for_its_stamp(params, seed):
    """Steps of 2 ug to 182 g at times no tuning saw: stable means right, within u."""
    current, position, load, res, noise = simulate(params, seed, STEPS, 15.5)
    pipe = pipeline(params, res, noise)
    start = calibrate(pipe, current, position)
    readings, dynamic = feed(pipe, current, position, start)
    stable = [r for r in readings if r.stable]
    # a stable reading in every stretch of constant load longer than 1.3 s (1 s window, the
    # loop's 0.1 s, the look-ahead)
    assert len(stable) >= 12
    for (t0, _), (t1, _) in zip(STEPS[3:], STEPS[4:]):
        if t1 - t0 > 1.3:
            assert any(t0 * FS < r.sample_index < t1 * FS for r in stable), (t0, t1)
    for r in stable:
        error = r.mass_kg - load[r.sample_index]
        assert abs(error) < 3.0 * r.standard_uncertainty_kg, (r.sample_index, error)
        assert abs(error) < 0.2 * MG
        # the whole window and the look-ahead saw one load (within the threshold)
        window = load[r.sample_index - r.n_samples + 1:r.sample_index + 1001]
        assert np.ptp(window) < 1.0 * MG
    # and a step bigger than the threshold shows in every reading whose window or look-ahead
    # holds it
    changes = np.nonzero(np.abs(np.diff(load)) > 1.5 * MG)[0] + 1
    for r in readings:
        span = (r.sample_index - r.n_samples + 1, r.sample_index + 1000)
        if any(span[0] <= c <= span[1] for c in changes if c > start):
            assert not r.steady, r.sample_index


@pytest.mark.parametrize('mass_kg', [0.005, 0.05])
def test_a_change_just_after_the_window_makes_the_reading_unsteady(params, mass_kg):
    """The reading closing at 3.0 s is released at 3.1 s: a change at 3.05 s is seen."""
    current, position, _, res, noise = simulate(
        params, 321, [(0.0, 0.0), (3.05, mass_kg)], 3.3)
    pipe = pipeline(params, res, noise)
    readings, _ = feed(pipe, current, position)
    by_index = {r.sample_index: r for r in readings}
    assert by_index[28999].steady                   # 2.9 s: look-ahead ends at 3.0 s
    assert not by_index[29999].steady               # 3.0 s: the change is in its look-ahead
    assert by_index[29999].mass_kg == pytest.approx(by_index[28999].mass_kg, abs=0.5 * MG)


def test_outputs_do_not_depend_on_the_block_split(params):
    current, position, _, res, noise = simulate(params, 331, [(0.0, 0.0), (1.37, 0.0412)],
                                                2.5)
    whole = pipeline(params, res, noise)
    a = whole.push(current, position, 0)
    split = pipeline(params, res, noise)
    cuts = np.unique(np.concatenate(([0, current.size],
                                     np.random.default_rng(5).integers(1, current.size, 25))))
    readings, dynamic = [], []
    for lo, hi in zip(cuts[:-1], cuts[1:]):
        r, d = split.push(current[lo:hi], position[lo:hi], int(lo))
        readings += r
        dynamic += d
    assert a == (readings, dynamic)
    assert len(readings) == 24 and len(dynamic) == 248


def test_a_gap_releases_what_waited_as_unsteady(params):
    current, position, _, res, noise = simulate(params, 332, [(0.0, 0.0)], 2.5)
    pipe = pipeline(params, res, noise)
    feed(pipe, current, position, 0, 15000)
    readings, dynamic = pipe.push(current[16000:17000], position[16000:17000], 16000)
    assert readings and all(not r.steady for r in readings)
    assert readings[0].sample_index == 14999 and dynamic
    assert pipe.gap_count == 1 and pipe.samples_lost == 1000
    later, _ = feed(pipe, current, position, 17000)
    assert later and later[0].n_samples < 10000           # the window restarted


def test_the_monitor_channel_states_its_quantisation_and_is_within_it(params):
    """The 16-bit current monitor: 3 uA codes, no dither; readings honest, not precise."""
    schedule = [(0.0, 0.0), (2.0, 0.1), (4.0, 0.0), (5.5, 0.0734829)]
    current, position, load, res, noise = simulate(params, 341, schedule, 8.0,
                                                   current='coil_current_A')
    assert res[0] == pytest.approx(3.0517578125e-06) and res[1] == 1e-7
    pipe = pipeline(params, res, noise)
    start = calibrate(pipe, current, position)
    readings, _ = feed(pipe, current, position, start)
    stable = [r for r in readings if r.stable]
    assert stable
    for r in stable:
        # half a code, rectangular: 1.53 uA * 21.69 N/A * 0.7645 kg/N / sqrt(3) = 14.6 mg
        assert r.resolution_u_kg == pytest.approx(14.6 * MG, rel=0.01)
        assert r.standard_uncertainty_kg >= r.resolution_u_kg
        assert abs(r.mass_kg - load[r.sample_index]) < 2.0 * r.standard_uncertainty_kg
    # the precise channel's share is nothing
    current, position, _, res, noise = simulate(params, 341, schedule[:1], 2.5)
    readings, _ = feed(pipeline(params, res, noise), current, position)
    assert readings[-1].resolution_u_kg == 0.0
    assert 0.0 < readings[-1].motion_u_kg < 0.01 * MG
