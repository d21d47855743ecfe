"""Multisine: spectrum on the chosen lines only, rms, crest factor and periodicity."""

import numpy as np
import pytest

from emfc_ros.core.errors import SignalError
from emfc_ros.core.signals import Multisine, select_lines


@pytest.mark.parametrize('phases', ['schroeder', 'random'])
def test_energy_only_on_chosen_lines(phases):
    period, n_periods = 1000, 3
    lines = [1, 2, 5, 17, 100, 333, 499]
    ms = Multisine(0.05, period, 10000.0, lines=lines, phases=phases, seed=3)
    x = ms.samples(np.arange(n_periods * period, dtype=np.int64))
    spectrum = np.abs(np.fft.rfft(x))
    on = np.array(lines) * n_periods
    off = np.setdiff1d(np.arange(spectrum.size), on)
    assert spectrum[off].max() < 1e-10 * spectrum[on].max()
    np.testing.assert_allclose(spectrum[on], spectrum[on][0], rtol=1e-9)  # equal amplitudes


def test_rms_and_crest_factor():
    ms = Multisine(0.2, 2048, 10000.0, f_min_Hz=10.0, f_max_Hz=2000.0)
    x = ms.samples(np.arange(2048, dtype=np.int64))
    np.testing.assert_allclose(np.sqrt(np.mean(x ** 2)), 0.2, rtol=1e-12)
    np.testing.assert_allclose(ms.crest_factor, np.max(np.abs(x)) / 0.2, rtol=1e-12)


def test_schroeder_crest_factor_below_random_phases():
    kwargs = dict(rms_V=1.0, period_samples=4096, sample_rate_Hz=10000.0, f_min_Hz=5.0,
                  f_max_Hz=2000.0)
    schroeder = Multisine(phases='schroeder', **kwargs).crest_factor
    random = np.median([Multisine(phases='random', seed=s, **kwargs).crest_factor
                        for s in range(7)])
    assert schroeder < 2.0 < random
    assert schroeder < 0.75 * random


def test_periodic_exactly_and_lines_from_band():
    ms = Multisine(1.0, 500, 1000.0, f_min_Hz=10.0, f_max_Hz=100.0, odd_only=True)
    np.testing.assert_array_equal(ms.lines, np.arange(5, 51, 2))
    np.testing.assert_allclose(ms.frequencies_Hz, ms.lines * 2.0)
    k = np.arange(10 ** 9, 10 ** 9 + 1500, dtype=np.int64)
    np.testing.assert_array_equal(ms.samples(k), ms.samples(k % 500))
    np.testing.assert_array_equal(ms.samples(k[:500]), ms.samples(k[500:1000]))


def test_select_lines_excludes_dc_and_nyquist():
    np.testing.assert_array_equal(select_lines(8, 8.0), [1, 2, 3])
    np.testing.assert_array_equal(select_lines(9, 9.0), [1, 2, 3, 4])


@pytest.mark.parametrize('kwargs', [dict(lines=[0, 1]), dict(lines=[500]), dict(lines=[2, 2]),
                                    dict(f_min_Hz=401.2, f_max_Hz=401.8),
                                    dict(lines=[1], f_min_Hz=1.0), dict(phases='flat'),
                                    dict(rms_V=0.0)])
def test_rejects_bad_parameters(kwargs):
    args = dict(rms_V=1.0, period_samples=1000, sample_rate_Hz=1000.0)
    args.update(kwargs)
    with pytest.raises(SignalError):
        Multisine(**args)
