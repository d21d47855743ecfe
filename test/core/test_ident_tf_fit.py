"""
Rational transfer-function fit, order selection and modal parameters against analytic models.

Ground truth: the default balance model of emfc_ros.core.model and a two-mode system.
"""

import numpy as np
import pytest
from scipy import signal

from emfc_ros.core.ident import (fit_transfer_function, FrequencyResponseData,
                                 IdentificationError, select_order)
from emfc_ros.core.ident.tf_fit import estimated_weight_variance_factor
from emfc_ros.core.model import linearise, MechanicalParameters

F_HZ = np.logspace(0.0, 3.0, 400)


def frd_of(h, std, f=F_HZ):
    return FrequencyResponseData(f, h, np.ones(f.size), std, 1.0, 'test', 'N', 'm')


def balance_frd(seed, rel=0.01):
    """Coil-to-position FRF of the default balance with 1 % complex multiplicative noise."""
    h = linearise(MechanicalParameters()).frequency_response(F_HZ, 'coil').response_m_per_N
    rng = np.random.default_rng(seed)
    noisy = h * (1.0 + rel * (rng.standard_normal(h.size) + 1j * rng.standard_normal(h.size)))
    return frd_of(noisy, rel * np.sqrt(2.0) * np.abs(h))


def two_mode_tf():
    """Return (num, den) of 1 / (10 Hz, zeta 0.02) + 0.3 / (80 Hz, zeta 0.04) modes."""
    w1, w2 = 2 * np.pi * 10.0, 2 * np.pi * 80.0
    d1, d2 = [1.0, 2 * 0.02 * w1, w1 ** 2], [1.0, 2 * 0.04 * w2, w2 ** 2]
    num = np.polyadd(np.polymul([w1 ** 2], d2), np.polymul([0.3 * w2 ** 2], d1))
    return num, np.polymul(d1, d2)


def test_balance_modes_and_anti_resonance():
    lin = linearise(MechanicalParameters())
    poles = [r for r in lin.poles() if r.s_rad_per_s.imag > 0]
    zeros = [r for r in lin.zeros('coil') if r.s_rad_per_s.imag > 0]
    fit = fit_transfer_function(balance_frd(0), 2, 4)
    assert fit.is_stable and fit.refined and fit.unit == 'm/N'
    assert len(fit.modes) == 2 and len(fit.anti_resonances) == 1
    for mode, truth in zip(fit.modes, poles):
        np.testing.assert_allclose(mode.frequency_Hz, truth.frequency_Hz, rtol=0.005)
        np.testing.assert_allclose(mode.damping_ratio, truth.damping_ratio, rtol=0.10)
        # The reported uncertainty is consistent with the actual error (4 sigma).
        assert abs(mode.frequency_Hz - truth.frequency_Hz) < 4.0 * mode.frequency_std_Hz
    anti = fit.anti_resonances[0]
    np.testing.assert_allclose(anti.frequency_Hz, zeros[0].frequency_Hz, rtol=0.01)
    np.testing.assert_allclose(anti.damping_ratio, zeros[0].damping_ratio, rtol=0.10)
    np.testing.assert_allclose(fit.modes[0].frequency_Hz, 3.78, rtol=0.005)
    np.testing.assert_allclose(fit.modes[1].frequency_Hz, 410.0, rtol=0.005)
    np.testing.assert_allclose(anti.frequency_Hz, 353.8, rtol=0.01)
    # chi^2 per complex point near 1: the weighting uses the given std.
    assert 0.8 < fit.chi2 / F_HZ.size < 1.2


def test_modal_std_matches_monte_carlo_scatter():
    freqs, damps, f_std, d_std = [], [], [], []
    for seed in range(25):
        fit = fit_transfer_function(balance_frd(100 + seed), 2, 4)
        freqs.append([m.frequency_Hz for m in fit.modes + fit.anti_resonances])
        damps.append([m.damping_ratio for m in fit.modes + fit.anti_resonances])
        f_std.append([m.frequency_std_Hz for m in fit.modes + fit.anti_resonances])
        d_std.append([m.damping_std for m in fit.modes + fit.anti_resonances])
    ratio_f = np.std(freqs, axis=0, ddof=1) / np.mean(f_std, axis=0)
    ratio_d = np.std(damps, axis=0, ddof=1) / np.mean(d_std, axis=0)
    assert np.all((ratio_f > 0.6) & (ratio_f < 1.5)), ratio_f
    assert np.all((ratio_d > 0.6) & (ratio_d < 1.5)), ratio_d


def test_two_mode_system_exact_without_noise():
    num, den = two_mode_tf()
    f = np.logspace(0.0, 2.7, 200)
    h = signal.freqs(num, den, worN=2 * np.pi * f)[1]
    fit = fit_transfer_function(frd_of(h, np.full(f.size, np.nan), f), 2, 4)
    np.testing.assert_allclose(fit.denominator, den, rtol=1e-6)
    np.testing.assert_allclose(fit.numerator, num, rtol=1e-6)
    np.testing.assert_allclose([m.frequency_Hz for m in fit.modes], [10.0, 80.0], rtol=1e-6)
    np.testing.assert_allclose([m.damping_ratio for m in fit.modes], [0.02, 0.04], rtol=1e-6)
    np.testing.assert_allclose(fit.response(f), h, rtol=1e-6)
    # Without refinement the Sanathanan-Koerner result alone is exact as well.
    plain = fit_transfer_function(frd_of(h, np.full(f.size, np.nan), f), 2, 4, refine=False)
    np.testing.assert_allclose(plain.denominator, den, rtol=1e-6)
    lti = plain.to_lti()
    np.testing.assert_allclose(signal.freqs(lti.num, lti.den, worN=2 * np.pi * f)[1], h,
                               rtol=1e-6)


def test_order_selection_picks_the_true_order():
    sel = select_order(balance_frd(1), [(0, 2), (1, 3), (2, 4), (3, 5), (2, 6)])
    assert (sel.chosen.numerator_order, sel.chosen.denominator_order) == (2, 4)
    assert len(sel.table) == 5 and sel.criterion == 'bic'
    chi2 = {(r['numerator_order'], r['denominator_order']): r['chi2'] for r in sel.table}
    assert chi2[(1, 3)] > 100.0 * chi2[(2, 4)]
    aic = select_order(balance_frd(1), [(1, 3), (2, 4)], criterion='aic')
    assert aic.chosen.denominator_order == 4


def test_unstable_fit_is_stabilised():
    # Data of a system with a right-half-plane pole pair: the fit must still be stable.
    w = 2 * np.pi * 20.0
    den = [1.0, -2 * 0.05 * w, w ** 2]
    h = signal.freqs([w ** 2], den, worN=2 * np.pi * F_HZ)[1]
    data = frd_of(h, np.full(F_HZ.size, np.nan))
    # Sanathanan-Koerner finds the unstable pair; reflection keeps |p| and flips Re(p).
    plain = fit_transfer_function(data, 0, 2, refine=False)
    assert plain.is_stable
    np.testing.assert_allclose([plain.modes[0].frequency_Hz, plain.modes[0].damping_ratio],
                               [20.0, 0.05], rtol=1e-6)
    # The bounded refinement keeps every pole in the left half plane.
    fit = fit_transfer_function(data, 0, 2)
    assert fit.is_stable and all(p.s_rad_per_s.real <= 0.0 for p in fit.poles)


def test_tf_fit_errors():
    frd = balance_frd(2)
    with pytest.raises(IdentificationError, match='proper'):
        fit_transfer_function(frd, 3, 2)
    with pytest.raises(IdentificationError, match='too few'):
        fit_transfer_function(frd.select(slice(0, 3)), 2, 4)
    with pytest.raises(IdentificationError, match='criterion'):
        select_order(frd, [(2, 4)], criterion='mdl')


def test_estimated_weight_factor_is_the_sample_ml_inflation():
    assert estimated_weight_variance_factor(12.0) == pytest.approx(1.25)
    assert estimated_weight_variance_factor(float('inf')) == 1.0
    assert estimated_weight_variance_factor(1e9) == pytest.approx(1.0, abs=1e-8)
    assert estimated_weight_variance_factor(3.0) == pytest.approx(3.0)   # nu <= 4: at nu 5


def _frd_with_estimated_std(seed, h, rel, dof):
    """A noisy FRF whose std is estimated from ``dof`` complex degrees of freedom."""
    rng = np.random.default_rng(seed)
    sigma = rel * np.sqrt(2.0) * np.abs(h)
    noisy = h + sigma / np.sqrt(2.0) * (rng.standard_normal(h.size)
                                        + 1j * rng.standard_normal(h.size))
    std = sigma * np.sqrt(rng.chisquare(2 * dof, h.size) / (2 * dof))
    return FrequencyResponseData(F_HZ, noisy, np.ones(F_HZ.size), std, float(dof), 'LPM',
                                 'N', 'm', details={'dof': dof})


def test_modes_std_covers_the_scatter_when_the_weights_are_estimated():
    num, den = two_mode_tf()
    h = signal.freqs(num, den, worN=2 * np.pi * F_HZ)[1]
    natural_Hz = np.array([10.0, 80.0])
    z = []
    for seed in range(150):
        fit = fit_transfer_function(_frd_with_estimated_std(700 + seed, h, 0.02, dof=6), 2, 4)
        z.append([(m.frequency_Hz - f) / m.frequency_std_Hz
                  for m, f in zip(fit.modes, natural_Hz)])
    spread = np.std(z, axis=0, ddof=1)
    # With the (nu - 2) / (nu - 4) = 1.25 variance factor the z scatter is about 1
    # (about 1.12 without it); 150 repetitions give about 6 % sampling error.
    assert np.all((spread > 0.85) & (spread < 1.15)), spread
    # The same data with the std declared known (no dof): 1.25 times smaller variances.
    frd = _frd_with_estimated_std(700, h, 0.02, dof=6)
    known = FrequencyResponseData(frd.frequency_Hz, frd.response, frd.coherence, frd.std,
                                  frd.n_averages, 'test', 'N', 'm')
    a, b = fit_transfer_function(frd, 2, 4), fit_transfer_function(known, 2, 4)
    np.testing.assert_allclose(a.covariance, 1.25 * b.covariance, rtol=1e-9)
