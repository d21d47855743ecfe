"""The LPM on sparse excitations (odd multisines): detection, exactness, calibrated std."""

import numpy as np
import pytest
from scipy import signal

from emfc_ros.core.ident.errors import IdentificationError
from emfc_ros.core.ident.local_polynomial import (detect_excitation, excited_lines,
                                                  local_polynomial_frf)
from emfc_ros.core.signals.multisine import Multisine

FS = 1000.0
N = 20000                      # 20 s: 0.05 Hz lines
PERIOD = 2000                  # 2 s periods: excited lines every 10 DFT lines (odd: every 20)


def _system():
    wn, z = 2 * np.pi * 50.0, 0.02
    return signal.cont2discrete(([wn ** 2], [1, 2 * z * wn, wn ** 2]), 1 / FS, 'zoh')


def _multisine(seed=4, odd_only=True):
    ms = Multisine(1.0, PERIOD, FS, f_min_Hz=2.0, f_max_Hz=400.0, odd_only=odd_only,
                   phases='random', seed=seed)
    return np.asarray(ms.samples(np.arange(N)), dtype=float)


def _response(u, sysd, seed=None, noise=0.0, x0=1.0):
    # a non-zero initial state: the transient the LPM's T polynomial must absorb
    zi = signal.lfiltic(sysd[0].ravel(), sysd[1], [x0, -x0])
    y, _ = signal.lfilter(sysd[0].ravel(), sysd[1], u, zi=zi)
    if noise:
        y = y + noise * np.random.default_rng(seed).standard_normal(u.size)
    return y


def test_sparse_inputs_are_told_from_broadband_ones():
    rng = np.random.default_rng(3)
    chirp = signal.chirp(np.arange(N) / FS, 2.0, N / FS, 400.0, method='logarithmic')
    steps = np.repeat([0.0, 0.2, -0.2, 0.0], N // 4)
    for broadband in (rng.standard_normal(N), chirp, steps):
        assert excited_lines(np.fft.rfft(broadband), 6) is None
    lines = excited_lines(np.fft.rfft(_multisine()), 6)
    assert lines is not None
    spacing = np.diff(lines)
    assert np.all(spacing == 20)                 # odd harmonics of 0.5 Hz, 0.05 Hz lines
    np.testing.assert_allclose(lines[0] * FS / N, 2.5)


def test_lpm_on_an_odd_multisine_is_exact_at_the_excited_lines():
    sysd = _system()
    u = _multisine()
    y = _response(u, sysd)
    frd, = local_polynomial_frf([u], y, FS, frequency_min_Hz=5, frequency_max_Hz=300)
    assert frd.details['sparse_excitation']
    df = np.diff(frd.frequency_Hz)
    np.testing.assert_allclose(df, 1.0)          # only the excited lines
    _, truth = signal.freqz(sysd[0].ravel(), sysd[1], worN=frd.frequency_Hz, fs=FS)
    np.testing.assert_allclose(frd.response, truth, rtol=2e-3)


def test_lpm_std_on_a_multisine_covers_its_error():
    sysd = _system()
    u = _multisine()
    ratios = []
    for seed in range(6):
        y = _response(u, sysd, seed=100 + seed, noise=0.02)
        frd, = local_polynomial_frf([u], y, FS, frequency_min_Hz=5, frequency_max_Hz=300)
        _, truth = signal.freqz(sysd[0].ravel(), sysd[1], worN=frd.frequency_Hz, fs=FS)
        ratios.append(np.abs(frd.response - truth) ** 2 / frd.std ** 2)
    assert 0.6 < float(np.mean(ratios)) < 1.6


def test_a_dense_multisine_keeps_the_ordinary_lpm():
    # a 10 s period excites every 2nd DFT line of the 20 s record: a window holds several
    # excited lines, on which the ordinary LPM's G polynomial rests
    ms = Multisine(1.0, N // 2, FS, f_min_Hz=2.0, f_max_Hz=400.0, phases='random', seed=5)
    u = np.asarray(ms.samples(np.arange(N)), dtype=float)
    sysd = _system()
    y = _response(u, sysd)
    frd, = local_polynomial_frf([u], y, FS, frequency_min_Hz=5, frequency_max_Hz=300)
    assert not frd.details['sparse_excitation']
    excited = np.abs(frd.details['input_amplitude']) > 1e-3 * np.max(frd.details[
        'input_amplitude'])
    _, truth = signal.freqz(sysd[0].ravel(), sysd[1], worN=frd.frequency_Hz, fs=FS)
    np.testing.assert_allclose(frd.response[excited], truth[excited], rtol=5e-3)


def test_two_inputs_a_multisine_and_noise():
    rng = np.random.default_rng(6)
    u1 = _multisine()
    u2 = rng.standard_normal(N)
    y = signal.lfilter([0.5, 0.2], [1.0, -0.3], u1) + signal.lfilter([-1.0], [1.0, 0.5], u2)
    a, b = local_polynomial_frf([u1, u2], y, FS, frequency_min_Hz=5, frequency_max_Hz=300)
    assert a.details['sparse_excitation'] and not b.details['sparse_excitation']
    wa = np.exp(-2j * np.pi * a.frequency_Hz / FS)
    wb = np.exp(-2j * np.pi * b.frequency_Hz / FS)
    np.testing.assert_allclose(a.response, (0.5 + 0.2 * wa) / (1 - 0.3 * wa), rtol=1e-3)
    np.testing.assert_allclose(b.response, -1.0 / (1 + 0.5 * wb), rtol=1e-3)


def test_an_excitation_detected_once_serves_every_band():
    sysd = _system()
    u = _multisine()
    y = _response(u, sysd, seed=7, noise=0.02)
    once = detect_excitation([u])
    assert once[0] is not None
    for band in ((5.0, 40.0), (99.5, 100.5), (150.0, 300.0)):
        a, = local_polynomial_frf([u], y, FS, frequency_min_Hz=band[0],
                                  frequency_max_Hz=band[1])
        b, = local_polynomial_frf([u], y, FS, frequency_min_Hz=band[0],
                                  frequency_max_Hz=band[1], excitation=once)
        np.testing.assert_array_equal(a.frequency_Hz, b.frequency_Hz)
        np.testing.assert_allclose(a.response, b.response, rtol=1e-12)
    # broadband declared: the ordinary LPM (every 13th line), not the excited lines
    c, = local_polynomial_frf([u], y, FS, frequency_min_Hz=5.0, frequency_max_Hz=40.0,
                              excitation=[None])
    assert not c.details['sparse_excitation'] and np.allclose(np.diff(c.frequency_Hz), 0.65)
    with pytest.raises(IdentificationError, match='excitation names 2 inputs'):
        local_polynomial_frf([u], y, FS, excitation=[None, None])
