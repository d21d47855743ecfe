"""
Period averaging of multisine experiments, its noise estimate, the ETFE and two-input FRFs.

Ground truth: freqz of known discrete systems; Monte Carlo repeats for the noise estimate.
"""

import warnings

import numpy as np
import pytest
from test_ident_systems import FS_HZ, response, second_order, simulate, two_mode

from emfc_ros.core.ident import (average_periods, estimate_two_input_frf, etfe,
                                 IdentificationError)
from emfc_ros.core.signals import Multisine


def multisine_record(period, periods, seed=0):
    ms = Multisine(1.0, period, FS_HZ, f_min_Hz=2.0, f_max_Hz=400.0, phases='random',
                   seed=seed)
    return ms, ms.samples(np.arange(period * periods))


@pytest.mark.parametrize('system', [second_order, two_mode])
def test_period_average_is_exact_without_noise(system):
    ba = system()
    ms, u = multisine_record(1000, 8)
    frd = average_periods(u, simulate(ba, u), FS_HZ, 1000, transient_periods=3,
                          lines=ms.lines, input_unit='N', output_unit='m')
    np.testing.assert_allclose(frd.frequency_Hz, ms.frequencies_Hz)
    np.testing.assert_allclose(frd.response, response(ba, ms.frequencies_Hz), rtol=1e-9)
    assert frd.n_averages == 5 and frd.estimator == 'periodic'
    assert np.all(frd.std < 1e-9 * np.abs(frd.response))
    # Automatic line detection finds the same lines; the ETFE over whole periods agrees.
    auto = average_periods(u, simulate(ba, u), FS_HZ, 1000, transient_periods=3)
    np.testing.assert_array_equal(auto.details['lines'], ms.lines)
    y = simulate(ba, u)
    whole = etfe(u[3000:], y[3000:], FS_HZ)
    np.testing.assert_allclose(whole.frequency_Hz, ms.frequencies_Hz)
    np.testing.assert_allclose(whole.response, response(ba, ms.frequencies_Hz), rtol=1e-9)


def test_period_std_matches_monte_carlo_scatter():
    ba = two_mode()
    period, periods, repeats = 200, 18, 60
    ms, u = multisine_record(period, periods, seed=2)
    y0 = simulate(ba, u)
    rng = np.random.default_rng(3)
    estimates, stds = [], []
    for _ in range(repeats):
        # Coloured output noise and white input noise.
        ny = np.convolve(rng.standard_normal(u.size), [1.0, 0.8, 0.3], mode='same')
        frd = average_periods(u + 0.02 * rng.standard_normal(u.size), y0 + 0.05 * ny, FS_HZ,
                              period, transient_periods=8, lines=ms.lines)
        estimates.append(frd.response)
        stds.append(frd.std)
    estimates, stds = np.array(estimates), np.array(stds)
    empirical_var = np.mean(np.abs(estimates - estimates.mean(axis=0)) ** 2, axis=0) * (
        repeats / (repeats - 1))
    predicted_var = np.mean(stds ** 2, axis=0)
    ratio = np.sqrt(np.mean(empirical_var) / np.mean(predicted_var))
    assert 0.7 < ratio < 1.3
    # Line by line too, in the median.
    assert 0.7 < np.median(np.sqrt(empirical_var / predicted_var)) < 1.3
    # Bias is negligible: the mean over repeats is within its standard error.
    err = np.abs(estimates.mean(axis=0) - response(ba, ms.frequencies_Hz))
    assert np.mean(err < 3.0 * np.sqrt(predicted_var / repeats)) > 0.95


def test_period_average_errors():
    ms, u = multisine_record(100, 3)
    with pytest.raises(IdentificationError, match='at least 2 periods'):
        average_periods(u, u, FS_HZ, 100, transient_periods=2)
    with pytest.raises(IdentificationError, match='period_samples'):
        average_periods(u, u, FS_HZ, 100.5)
    with pytest.raises(IdentificationError, match='lines'):
        average_periods(u, u, FS_HZ, 100, lines=[60])


def test_two_input_recovers_two_systems():
    ba1, ba2 = second_order(), two_mode()
    rng = np.random.default_rng(5)
    n = 2 ** 17
    u1, u2 = rng.standard_normal(n), rng.standard_normal(n)
    y = simulate(ba1, u1) + simulate(ba2, u2) + 0.05 * rng.standard_normal(n)
    res = estimate_two_input_frf((u1, u2), y, FS_HZ, nperseg=4096, input_units=('N', 'N'),
                                 output_unit='m')
    for frd, ba in zip(res.responses, (ba1, ba2)):
        sub = frd.band(5.0, 400.0)
        truth = response(ba, sub.frequency_Hz)
        err = np.abs(sub.response - truth)
        assert np.max(err) < 0.06 * np.max(np.abs(truth))  # leakage at the peaks
        assert np.median(err) < 2e-3 * np.max(np.abs(truth))
        assert np.mean(err < 3.0 * sub.std) > 0.95
        assert frd.unit == 'm/N'
    assert np.median(res.multiple_coherence) > 0.9
    assert np.median(res.input_correlation) < 0.05
    assert np.max(res.condition_number) < 10.0


def test_two_input_refuses_correlated_inputs():
    rng = np.random.default_rng(6)
    u1 = rng.standard_normal(20000)
    y = simulate(second_order(), u1)
    with pytest.raises(IdentificationError, match='correlated'):
        estimate_two_input_frf((u1, 2.0 * u1), y, FS_HZ, nperseg=1024)
    with pytest.raises(IdentificationError, match='correlated'):
        estimate_two_input_frf((u1, 2.0 * u1 + 1e-6 * rng.standard_normal(20000)), y, FS_HZ,
                               nperseg=1024)
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        estimate_two_input_frf((u1, 2.0 * u1 + rng.standard_normal(20000)), y, FS_HZ,
                               nperseg=1024)
