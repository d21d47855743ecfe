"""
Grey-box covariance under coloured noise: the sandwich estimators against Monte Carlo truth.

A linear model ``y = theta * u(t)`` with AR(1) noise (``rho = 0.98``, strongly coloured) has the
exact covariance ``(u^T u)^-1 u^T Sigma u (u^T u)^-1`` of the least-squares estimate; the white
formula ``s^2 (u^T u)^-1`` is several times too small. The fits run through
:func:`fit_greybox` like the balance's.
"""

import numpy as np
from scipy import linalg, signal

from emfc_ros.core.ident.covariance import line_score_covariance, score_covariance
from emfc_ros.core.ident.greybox import DataSection, fit_greybox, ParameterSpec
from emfc_ros.core.ident.noise_model import noise_spectrum, whitening_weights

N = 4000
RHO = 0.98
T = np.arange(N) / N
U = np.sin(2 * np.pi * 3 * T) + 0.5 * np.sign(np.sin(2 * np.pi * 1.3 * T))


def ar1(rng, n=N, rho=RHO, sigma=1e-3):
    return signal.lfilter([1.0], [1.0, -rho], rng.normal(0.0, sigma, n))


def exact_std(u=U, rho=RHO, sigma=1e-3):
    k = np.arange(u.size)
    cov = sigma ** 2 / (1 - rho ** 2) * rho ** np.abs(k[:, None] - k[None, :])
    return float(np.sqrt(u @ cov @ u) / (u @ u))


def fit(y, covariance='sandwich', weights=None, transient=None):
    def simulate(values, inputs):
        return values['theta'] * inputs

    return fit_greybox(simulate, [DataSection('s', U, y)],
                       [ParameterSpec('theta', 1.0, 0.0, 10.0, True, 1.0)],
                       covariance=covariance,
                       noise_weights=None if weights is None else [weights],
                       transients=None if transient is None else [transient])


def test_score_covariance_is_the_white_formula_for_white_residuals():
    rng = np.random.default_rng(3)
    jac = rng.normal(size=(2000, 2))
    r = rng.normal(0.0, 0.5, 2000)
    got = score_covariance(jac, r, [2000], smoothing_lines=1)
    # identical in expectation; the raw periodogram version equals sum J_t^2 r_t^2 averaged
    expected = 0.25 * jac.T @ jac
    np.testing.assert_allclose(got, expected, atol=0.1 * np.max(np.diag(expected)))


def test_sandwich_matches_the_exact_covariance_of_coloured_noise():
    rng = np.random.default_rng(7)
    truth = exact_std()
    sandwich, white, estimates = [], [], []
    for _ in range(40):
        y = 2.0 * U + ar1(rng)
        res = fit(y)
        sandwich.append(res.standard_errors['theta'])
        estimates.append(res.parameters['theta'])
        white.append(fit(y, covariance='white').standard_errors['theta'])
    scatter = float(np.std(estimates))
    # the Monte Carlo scatter agrees with the exact value (40 repetitions: +/- 25 %)
    np.testing.assert_allclose(scatter, truth, rtol=0.3)
    # the sandwich is right on average within 25 %, the white formula is far too small
    np.testing.assert_allclose(np.mean(sandwich), truth, rtol=0.25)
    assert np.mean(white) < 0.5 * truth


def test_noise_weighted_fit_is_efficient_and_its_covariance_covers():
    rng = np.random.default_rng(11)
    f = np.fft.rfftfreq(N)
    # AR(1) spectrum shape |1 / (1 - rho e^-jw)|^2
    shape = 1.0 / np.abs(1.0 - RHO * np.exp(-2j * np.pi * f)) ** 2
    # the AR(1) noise's transient term in a finite record: (z - rho)^-1 z times the state at
    # the start minus the state at the end
    zk = np.exp(2j * np.pi * f)
    transient = (zk / (zk - RHO))[:, None]
    z, errs = [], []
    for _ in range(40):
        y = 2.0 * U + ar1(rng)
        w = whitening_weights(y - 2.0 * U, [shape])
        res = fit(y, weights=w, transient=transient)
        errs.append(res.parameters['theta'] - 2.0)
        z.append((res.parameters['theta'] - 2.0) / res.standard_errors['theta'])
    # weighting by the noise spectrum is no worse than plain least squares
    assert np.std(errs) < 1.1 * exact_std()
    # and its reported uncertainty covers the error
    assert 0.7 < np.std(z) < 1.4
    assert np.mean(np.abs(z) < 1.96) > 0.85


def test_noise_spectrum_recovers_a_known_spectrum_shape():
    rng = np.random.default_rng(5)
    e = ar1(rng, n=20000) + rng.normal(0.0, 2e-3, 20000)
    f = np.fft.rfftfreq(e.size)
    shape = 1.0 / np.abs(1.0 - RHO * np.exp(-2j * np.pi * f)) ** 2
    phi = noise_spectrum(e, [shape])
    truth = 1e-6 * shape + 4e-6
    ratio = phi / truth
    assert 0.8 < np.median(ratio) < 1.25
    assert np.all(phi > 0.0)


def test_line_score_covariance_counts_neighbouring_lines():
    rng = np.random.default_rng(9)
    jac = rng.normal(size=(400, 1))
    r = rng.normal(size=400)
    independent = line_score_covariance(jac, r, [400], max_lag_lines=0)
    half = 200
    score = jac[:half, 0] * r[:half] + jac[half:, 0] * r[half:]
    np.testing.assert_allclose(independent[0, 0], score @ score)
    assert linalg.norm(line_score_covariance(jac, r, [400], max_lag_lines=8)) > 0.0
