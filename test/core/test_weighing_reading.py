"""Tests of the moving-average readings on synthetic force signals with known statistics."""

import math

import numpy as np
import pytest
from scipy import signal

from emfc_ros.core.weighing import (ReadingFilter, settled_reading, WeighingCalibration,
                                    WeighingError)

FS = 1000.0
S = -0.764525993883792
F0 = 0.1668
STEP_N = 0.1 / S  # force change of a 100 g load [N]


def _cal():
    return WeighingCalibration(S).zeroed(F0)


def _run(filt, force, first=0, block=None):
    readings = []
    if block is None:
        return filt.push(force, first)
    for start in range(0, force.size, block):
        readings += filt.push(force[start:start + block], first + start)
    return readings


def test_readings_are_the_moving_average_on_an_absolute_grid():
    rng = np.random.default_rng(3)
    force = F0 + 1e-6 * rng.standard_normal(5000)
    filt = ReadingFilter(FS, _cal())
    readings = _run(filt, force)
    # a reading closes at every sample n with (n + 1) % 100 == 0
    assert [r.sample_index for r in readings] == list(range(99, 5000, 100))
    for r in readings:
        n = min(r.sample_index + 1, 1000)
        window = force[r.sample_index + 1 - n:r.sample_index + 1]
        assert r.n_samples == n and r.window_full == (n == 1000)
        assert r.averaging_time_s == pytest.approx(n / FS)
        assert r.time_s == pytest.approx(r.sample_index / FS)
        np.testing.assert_allclose(r.mean_force_N, np.mean(window), rtol=1e-15)
        np.testing.assert_allclose(r.mass_kg, S * (np.mean(window) - F0), rtol=1e-9,
                                   atol=1e-15)


def test_white_noise_uncertainty_is_sigma_over_sqrt_n():
    sigma = 2e-6
    rng = np.random.default_rng(4)
    force = F0 + sigma * rng.standard_normal(int(120 * FS))
    readings = ReadingFilter(FS, _cal()).push(force, 0)
    full = [r for r in readings if r.window_full]
    expected_u_N = sigma / math.sqrt(1000)
    rms_u = math.sqrt(np.mean([r.force_u_N ** 2 for r in full]))
    assert rms_u == pytest.approx(expected_u_N, rel=0.1)
    # the mass uncertainty is |S| times the force uncertainty (calibration exact here)
    np.testing.assert_allclose([r.standard_uncertainty_kg for r in full],
                               [abs(S) * r.force_u_N for r in full], rtol=1e-12)
    # and the readings of disjoint windows scatter by that amount
    disjoint = [r.mass_kg for r in full[::10]]
    assert np.std(disjoint, ddof=1) == pytest.approx(abs(S) * expected_u_N, rel=0.2)


def test_correlated_noise_uncertainty_from_sub_block_means():
    # AR(1) noise, phi = 0.9: the variance of a long mean is (1 + phi) / (1 - phi) = 19 times
    # the white-noise value; the naive sigma / sqrt(N) would be 4.4 times too small.
    phi, sigma = 0.9, 2e-6
    rng = np.random.default_rng(5)
    innovations = sigma * math.sqrt(1 - phi ** 2) * rng.standard_normal(int(120 * FS))
    noise = signal.lfilter([1.0], [1.0, -phi], innovations)
    readings = ReadingFilter(FS, _cal()).push(F0 + noise, 0)
    full = [r for r in readings if r.window_full]
    expected_u_N = sigma / math.sqrt(1000) * math.sqrt((1 + phi) / (1 - phi))
    assert math.sqrt(np.mean([r.force_u_N ** 2 for r in full])) == pytest.approx(
        expected_u_N, rel=0.15)


def test_stable_only_after_a_full_window_and_the_step():
    rng = np.random.default_rng(6)
    force = F0 + 2e-7 * rng.standard_normal(int(5 * FS))
    force[2000:] += STEP_N  # 100 g at t = 2 s
    readings = ReadingFilter(FS, _cal(), stability_time_s=0.5,
                             stability_threshold_kg=1e-6).push(force, 0)
    stable = {r.sample_index: r.stable for r in readings}
    # first full window closes at 999; six full readings (0.5 s) are needed: 1499
    assert not any(stable[i] for i in range(99, 1499, 100))
    assert all(stable[i] for i in range(1499, 2000, 100))
    # the step enters the window at 2000; windows are all post-step from 2999, six of them
    # end at 3499
    assert not any(stable[i] for i in range(2099, 3499, 100))
    assert all(stable[i] for i in range(3499, 5000, 100))
    last = readings[-1]
    assert last.mass_kg == pytest.approx(0.1, abs=1e-7)


def test_gap_resets_the_window_and_is_counted():
    rng = np.random.default_rng(7)
    force = F0 + 1e-6 * rng.standard_normal(4000)
    filt = ReadingFilter(FS, _cal())
    before = filt.push(force[:1500], 0)
    assert before[-1].window_full and filt.gap_count == 0
    after = filt.push(force[1750:], 1750)  # 250 samples lost
    assert filt.gap_count == 1 and filt.samples_lost == 250
    first = after[0]
    assert first.sample_index == 1799 and first.n_samples == 50
    assert not first.window_full and not first.stable and first.gap_count == 1
    np.testing.assert_allclose(first.mean_force_N, np.mean(force[1750:1800]), rtol=1e-15)
    refilled = [r for r in after if r.window_full]
    assert refilled[0].sample_index == 2799
    # a repeated block (index going backwards) is a gap too, with nothing lost
    filt.push(force[:100], 0)
    assert filt.gap_count == 2 and filt.samples_lost == 250


def test_block_split_invariance():
    rng = np.random.default_rng(8)
    force = F0 + 1e-6 * rng.standard_normal(7000)
    force[3000:] += STEP_N
    whole = ReadingFilter(FS, _cal(), averaging_time_s=0.7,
                          reading_period_s=0.05).push(force, 10)
    split = ReadingFilter(FS, _cal(), averaging_time_s=0.7, reading_period_s=0.05)
    cuts = np.sort(rng.choice(np.arange(1, 7000), 60, replace=False))
    pieces = []
    for a, b in zip(np.r_[0, cuts], np.r_[cuts, 7000]):
        pieces += split.push(force[a:b], 10 + a)
    assert pieces == whole
    # readings close at 49, 99, ..., 6999 (samples 10 to 7009)
    assert len(whole) == 140 and whole[0].sample_index == 49 and whole[0].n_samples == 40


def test_calibration_can_change_between_blocks():
    force = np.full(3000, F0 + STEP_N)
    filt = ReadingFilter(FS, _cal())
    filt.push(force[:1500], 0)
    filt.calibration = _cal().tared(F0 + STEP_N)
    readings = filt.push(force[1500:], 1500)
    assert readings[-1].mass_kg == pytest.approx(0.0, abs=1e-15)
    assert readings[-1].stable


def test_settled_reading():
    rng = np.random.default_rng(9)
    force = F0 + STEP_N + 1e-6 * rng.standard_normal(3000)
    r = settled_reading(force, FS, _cal(), averaging_time_s=1.0)
    np.testing.assert_allclose(r.mean_force_N, np.mean(force[-1000:]), rtol=1e-15)
    assert r.n_samples == 1000 and r.sample_index == 2999 and r.stable
    assert r.mass_kg == pytest.approx(0.1, abs=5 * abs(S) * 1e-6 / math.sqrt(1000))
    drifting = force + np.linspace(0.0, 1e-4, 3000)  # 76 mg over 3 s
    assert not settled_reading(drifting, FS, _cal()).stable
    with pytest.raises(WeighingError, match='fewer than the 1000'):
        settled_reading(force[:999], FS, _cal())


@pytest.mark.parametrize('kwargs, match', [
    ({'averaging_time_s': 0.0}, 'averaging_time_s'),
    ({'averaging_time_s': 0.01}, 'fewer than 20 samples'),
    ({'reading_period_s': -1.0}, 'reading_period_s'),
    ({'n_sub_blocks': 1}, 'n_sub_blocks'),
    ({'stability_threshold_kg': 0.0}, 'stability_threshold_kg'),
    ({'stability_time_s': float('nan')}, 'stability_time_s'),
])
def test_filter_argument_errors(kwargs, match):
    with pytest.raises(WeighingError, match=match):
        ReadingFilter(FS, _cal(), **kwargs)


def test_push_errors():
    filt = ReadingFilter(FS, _cal())
    with pytest.raises(WeighingError, match='non-finite'):
        filt.push(np.array([F0, np.nan]), 0)
    with pytest.raises(WeighingError, match='1-D'):
        filt.push(np.zeros((2, 2)), 0)
    with pytest.raises(WeighingError, match='calibration'):
        filt.calibration = 1.0
