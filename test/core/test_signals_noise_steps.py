"""Noise (seeded, chunked), steps, staircases and constants."""

import numpy as np
import pytest

from emfc_ros.core.errors import SignalError
from emfc_ros.core.signals import Constant, GaussianNoise, staircase, Steps, UniformNoise
from emfc_ros.core.signals.noise import CHUNK_SAMPLES


def test_noise_seeded_reproducible_and_seed_dependent():
    k = np.arange(10000, dtype=np.int64)
    a = GaussianNoise(0.0, 1.0, 7, 1000.0).samples(k)
    np.testing.assert_array_equal(a, GaussianNoise(0.0, 1.0, 7, 1000.0).samples(k))
    assert not np.array_equal(a, GaussianNoise(0.0, 1.0, 8, 1000.0).samples(k))
    u = UniformNoise(-1.0, 1.0, 7, 1000.0).samples(k)
    np.testing.assert_array_equal(u, UniformNoise(-1.0, 1.0, 7, 1000.0).samples(k))


def test_noise_chunk_is_seedsequence_of_seed_and_chunk():
    noise = UniformNoise(0.0, 2.0, 11, 1000.0)
    k = np.arange(3 * CHUNK_SAMPLES, 4 * CHUNK_SAMPLES, dtype=np.int64)
    rng = np.random.default_rng(np.random.SeedSequence([11, 3]))
    np.testing.assert_array_equal(noise.samples(k), rng.uniform(0.0, 2.0, CHUNK_SAMPLES))


def test_noise_random_access_equals_sequential():
    noise = GaussianNoise(0.5, 2.0, 3, 1000.0)
    whole = noise.samples(np.arange(50000, dtype=np.int64))
    k = np.random.default_rng(0).integers(0, 50000, 3000)
    np.testing.assert_array_equal(GaussianNoise(0.5, 2.0, 3, 1000.0).samples(k), whole[k])


def test_uniform_moments_within_statistical_bounds():
    n, low, high = 400000, -0.3, 0.5
    x = UniformNoise(low, high, 1, 1000.0).samples(np.arange(n, dtype=np.int64))
    assert x.min() >= low and x.max() < high
    var = (high - low) ** 2 / 12
    assert abs(x.mean() - (low + high) / 2) < 5 * np.sqrt(var / n)
    # the variance estimate of a uniform has relative sd sqrt(0.8 / n)
    assert abs(x.var() / var - 1) < 5 * np.sqrt(0.8 / n)


def test_gaussian_moments_within_statistical_bounds():
    n, mean, std = 400000, 0.1, 0.02
    x = GaussianNoise(mean, std, 2, 1000.0).samples(np.arange(n, dtype=np.int64))
    assert abs(x.mean() - mean) < 5 * std / np.sqrt(n)
    assert abs(x.std() / std - 1) < 5 * np.sqrt(0.5 / n)
    # white: lag-1 correlation within noise
    r1 = np.corrcoef(x[:-1], x[1:])[0, 1]
    assert abs(r1) < 5 / np.sqrt(n)


def test_noise_rejects_bad_parameters():
    with pytest.raises(SignalError):
        UniformNoise(1.0, 0.0, 0, 1000.0)
    with pytest.raises(SignalError):
        GaussianNoise(0.0, -1.0, 0, 1000.0)
    with pytest.raises(SignalError):
        GaussianNoise(0.0, 1.0, -1, 1000.0)


def test_steps_levels_and_switch_samples():
    steps = Steps([0.5, 1.0, 2.5], [0.2, -0.2, 0.0], 10.0)
    x = steps.samples(np.arange(30, dtype=np.int64))
    expected = np.zeros(30)
    expected[5:10] = 0.2
    expected[10:25] = -0.2
    np.testing.assert_array_equal(x, expected)


def test_staircase_up_and_down():
    stairs = staircase(-1.0, 0.5, 3, 0.2, 10.0, start_time_s=0.1, up_and_down=True)
    np.testing.assert_allclose(stairs.levels_V, [-1.0, -0.5, 0.0, -0.5, -1.0])
    x = stairs.samples(np.arange(12, dtype=np.int64))
    np.testing.assert_array_equal(x, [0.0, -1.0, -1.0, -0.5, -0.5, 0.0, 0.0, -0.5, -0.5,
                                      -1.0, -1.0, -1.0])


def test_constant():
    np.testing.assert_array_equal(Constant(0.25, 10.0).samples(np.arange(4)), [0.25] * 4)


@pytest.mark.parametrize('times,levels', [([0.0, 1.0], [1.0]), ([1.0, 0.5], [0.0, 1.0]),
                                          ([0.0, 0.01], [0.0, 1.0]), ([-1.0], [1.0]),
                                          ([], [])])
def test_steps_reject_bad_lists(times, levels):
    with pytest.raises(SignalError):
        Steps(times, levels, 10.0)
