"""Sine and chirp: analytic values, instantaneous frequency and phase continuity."""

from fractions import Fraction
import math

import numpy as np
import pytest
from scipy import signal as sps

from emfc_ros.core.errors import SignalError
from emfc_ros.core.signals import Chirp, Sine


def zero_crossing_frequency(x, fs):
    """Estimate the frequency from interpolated zero-crossing intervals (half periods)."""
    negative = np.signbit(x)
    i = np.flatnonzero(negative[1:] != negative[:-1])
    t = (i + x[i] / (x[i] - x[i + 1])) / fs
    return 0.5 * (t[1:] + t[:-1]), 0.5 / np.diff(t)


def test_sine_matches_formula():
    fs = 1000.0
    sine = Sine(2.5, 12.3, 0.7, fs)
    k = np.arange(5000, dtype=np.int64)
    np.testing.assert_allclose(sine.samples(k), 2.5 * np.sin(2 * np.pi * 12.3 * k / fs + 0.7),
                               rtol=0, atol=1e-12)


def test_sine_exact_at_huge_index():
    fs, f = 10000.0, 123.4567
    sine = Sine(1.0, f, 0.0, fs)
    k = np.array([10 ** 10 + 3, 2 ** 33 + 5], dtype=np.int64)  # 11.6 and 9.9 days
    expected = []
    for kk in k:
        cycles = Fraction(int(kk)) * Fraction(f) / Fraction(fs)
        expected.append(math.sin(2 * math.pi * float(cycles - math.floor(cycles))))
    np.testing.assert_allclose(sine.samples(k), expected, rtol=0, atol=1e-6)


def test_sine_rejects_above_nyquist():
    with pytest.raises(SignalError, match='Nyquist'):
        Sine(1.0, 600.0, 0.0, 1000.0)


@pytest.mark.parametrize('method', ['linear', 'logarithmic'])
def test_chirp_instantaneous_frequency_within_0p1_percent(method):
    # the shipped trajectory's sweep (5 Hz -> 2 kHz in 10 s), sampled finely enough that
    # linear interpolation of the zero crossings is accurate to far below 0.1 %
    fs, sweep_s = 100000.0, 10.0
    chirp = Chirp(1.0, 5.0, 2000.0, sweep_s, fs, method=method, after_sweep='zero')
    x = chirp.samples(np.arange(int(fs * sweep_s), dtype=np.int64))
    t_mid, f_est = zero_crossing_frequency(x, fs)
    keep = t_mid < sweep_s - 1e-3
    assert keep.sum() > 6000
    np.testing.assert_allclose(f_est[keep], chirp.frequency_Hz(t_mid[keep]), rtol=1e-3)
    # the estimates cover the band up to the stop frequency
    assert f_est[keep][0] < 60.0 and f_est[keep][-1] > 1990.0


@pytest.mark.parametrize('method', ['linear', 'logarithmic'])
def test_chirp_matches_scipy_first_sweep(method):
    fs = 10000.0
    chirp = Chirp(0.3, 5.0, 2000.0, 2.0, fs, method=method)
    k = np.arange(20000, dtype=np.int64)
    ref = 0.3 * sps.chirp(k / fs, 5.0, 2.0, 2000.0, method=method, phi=-90.0)
    np.testing.assert_allclose(chirp.samples(k), ref, rtol=0, atol=1e-9)


@pytest.mark.parametrize('method', ['linear', 'logarithmic'])
def test_chirp_phase_continuous_across_repeats(method):
    fs, amp, f0, f1, sweep = 10000.0, 1.0, 3.0, 50.0, 0.123456
    chirp = Chirp(amp, f0, f1, sweep, fs, method=method, after_sweep='repeat')
    k = np.arange(int(5.2 * sweep * fs), dtype=np.int64)
    x = chirp.samples(k)
    # independent analytic phase: n Phi(T) + Phi(t mod T)
    t = k / fs
    n = np.floor(t / sweep)
    tau = t - n * sweep
    if method == 'linear':
        phi = lambda s: f0 * s + (f1 - f0) * s ** 2 / (2 * sweep)  # noqa: E731
    else:
        beta = sweep / np.log(f1 / f0)
        phi = lambda s: f0 * beta * (np.exp(s / beta) - 1)  # noqa: E731
    assert abs(phi(sweep) % 1 - 0.5) < 0.45  # a restart at phase 0 would jump
    np.testing.assert_allclose(x, amp * np.sin(2 * np.pi * (n * phi(sweep) + phi(tau))),
                               rtol=0, atol=1e-9)
    # no jump: every step is bounded by the largest slope 2 pi A f_max / fs
    assert np.max(np.abs(np.diff(x))) <= 2 * np.pi * amp * f1 / fs * 1.001


def test_chirp_zero_after_sweep():
    fs = 1000.0
    chirp = Chirp(1.0, 5.0, 100.0, 0.5, fs, after_sweep='zero')
    x = chirp.samples(np.arange(1000, dtype=np.int64))
    assert np.all(x[500:] == 0.0)
    assert np.any(x[400:500] != 0.0)


def test_chirp_exact_far_into_repeats():
    fs = 10000.0
    chirp = Chirp(1.0, 5.0, 2000.0, 10.0, fs)
    n_sweeps = 1000
    k = np.arange(10, 20, dtype=np.int64) + n_sweeps * 100000
    phi_t = Fraction(5.0) * Fraction(10.0) + Fraction(2000.0 - 5.0) * Fraction(10.0) / 2
    base = float((phi_t * n_sweeps) % 1)
    tau = (k - n_sweeps * 100000) / fs
    ref = np.sin(2 * np.pi * (base + tau * (5.0 + 0.5 * 199.5 * tau)))
    np.testing.assert_allclose(Chirp(1.0, 5.0, 2000.0, 10.0, fs, method='linear').samples(k),
                               ref, rtol=0, atol=1e-8)
    assert np.all(np.isfinite(chirp.samples(k)))


@pytest.mark.parametrize('kwargs', [dict(method='cubic'), dict(after_sweep='hold'),
                                    dict(sweep_time_s=0.0), dict(f_start_Hz=0.0),
                                    dict(f_stop_Hz=6000.0)])
def test_chirp_rejects_bad_parameters(kwargs):
    args = dict(amplitude_V=1.0, f_start_Hz=5.0, f_stop_Hz=100.0, sweep_time_s=1.0,
                sample_rate_Hz=10000.0)
    args.update(kwargs)
    with pytest.raises(SignalError):
        Chirp(**args)
