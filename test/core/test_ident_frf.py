"""
Welch FRF estimators (H1, H2, Hv), coherence and Bendat & Piersol uncertainty on known systems.

Ground truth: freqz of known discrete systems driven by noise, multisines and chirps.
"""

import numpy as np
import pytest
from scipy import signal
from test_ident_systems import FS_HZ, response, second_order, simulate, two_mode

from emfc_ros.core.ident import (cross_spectra, estimate_frf, FrequencyResponseData,
                                 IdentificationError, response_at)
from emfc_ros.core.ident.frf import effective_averages
from emfc_ros.core.signals import Chirp, Multisine

N = 2 ** 17
NPERSEG = 4096


def noise(seed, n=N):
    return np.random.default_rng(seed).standard_normal(n)


def test_cross_spectra_equal_scipy_csd():
    x = np.vstack((noise(1, 5000) + 2.0, noise(2, 5000)))
    spec = cross_spectra(x, FS_HZ, nperseg=300, noverlap=120, window='hamming',
                         detrend='linear')
    f, pxy = signal.csd(x[0], x[1], FS_HZ, nperseg=300, noverlap=120, window='hamming',
                        detrend='linear')
    np.testing.assert_allclose(spec.frequency_Hz, f)
    np.testing.assert_allclose(spec.matrix[:, 0, 1], pxy, rtol=1e-10, atol=1e-14)
    spec = cross_spectra(x, FS_HZ, nperseg=256)
    _, pxx = signal.welch(x[0], FS_HZ, nperseg=256)
    np.testing.assert_allclose(spec.matrix[:, 0, 0].real, pxx, rtol=1e-9)
    np.testing.assert_array_equal(spec.matrix[:, 1, 1].imag, 0.0)


def scipy_spectra(x, **kw):
    """The scipy recipe: csd for every pair, welch for every channel."""
    n_ch = len(x)
    mat = None
    for i in range(n_ch):
        for j in range(n_ch):
            if i == j:
                f, s = signal.welch(x[i], FS_HZ, **kw)
            else:
                f, s = signal.csd(x[i], x[j], FS_HZ, **kw)
            if mat is None:
                mat = np.empty((f.size, n_ch, n_ch), dtype=complex)
            mat[:, i, j] = s
    return f, mat


def assert_close_to_scipy(spec, f, mat):
    # Relative to the largest value of each spectrum (a bin where the two agree to 1e-15 in
    # absolute terms may hold a value 1e-10 of the largest one), and element-wise where the
    # value is not more than 1e6 times below the largest.
    np.testing.assert_allclose(spec.frequency_Hz, f)
    for i in range(mat.shape[1]):
        for j in range(mat.shape[2]):
            ref, ours = mat[:, i, j], spec.matrix[:, i, j]
            scale = np.max(np.abs(ref))
            assert np.max(np.abs(ours - ref)) <= 1e-12 * scale, (i, j)
            big = np.abs(ref) > 1e-6 * scale
            np.testing.assert_allclose(ours[big], ref[big], rtol=1e-9)


@pytest.mark.parametrize('n, nperseg, noverlap, window, detrend, chunk_bytes', [
    (10007, 1001, 333, 'hann', 'constant', None),        # odd lengths, step 668 odd
    (10007, 1001, 333, 'hann', 'constant', 1),           # one segment per chunk
    (9999, 512, 500, 'hamming', 'linear', None),         # step 12 does not divide 512
    (9999, 512, 0, 'blackman', False, 20000),            # no overlap, no detrend, chunk 9
    (4097, 4097, 0, 'hann', 'constant', None),           # one segment, the whole record
    (10001, 1000, 750, 'hann', 'constant', 70000),       # means from 4 blocks per segment
    (10001, 1000, 0, 'hamming', 'constant', None),       # means from 1 block per segment
    (5000, 777, 600, ('tukey', 0.3), 'linear', 30000),   # overlap > half
    (6000, 256, None, 'custom', False, None),            # a window array
])
def test_cross_spectra_equal_scipy_on_awkward_settings(monkeypatch, n, nperseg, noverlap,
                                                       window, detrend, chunk_bytes):
    from emfc_ros.core.ident import welch
    if chunk_bytes is not None:
        monkeypatch.setattr(welch, 'CHUNK_BYTES', chunk_bytes)
    rng = np.random.default_rng(n + nperseg)
    # Three channels with offsets and a trend, one a filtered copy of another.
    t = np.arange(n) / FS_HZ
    x0 = rng.standard_normal(n) + 5.0 + 3.0 * t
    x1 = signal.lfilter([0.2, 0.3], [1.0, -0.5], x0) + 0.1 * rng.standard_normal(n)
    x2 = rng.standard_normal(n) - 2.0
    if isinstance(window, str) and window == 'custom':
        window = rng.uniform(0.5, 1.0, nperseg)
    kw = dict(nperseg=nperseg, noverlap=noverlap, window=window, detrend=detrend)
    spec = cross_spectra((x0, x1, x2), FS_HZ, **kw)
    f, mat = scipy_spectra((x0, x1, x2), **kw)
    assert_close_to_scipy(spec, f, mat)
    assert spec.n_segments == (n - spec.noverlap) // (nperseg - spec.noverlap)
    np.testing.assert_array_equal(np.diagonal(spec.matrix, axis1=1, axis2=2).imag, 0.0)
    # The stacked (C, N) array gives the same numbers as the sequence of records.
    np.testing.assert_array_equal(cross_spectra(np.vstack((x0, x1, x2)), FS_HZ, **kw).matrix,
                                  spec.matrix)


def test_estimate_frf_equal_scipy_recipe():
    u = noise(21, 200003)
    y = signal.lfilter(*signal.butter(4, 0.1), u) + 0.01 * noise(22, u.size)
    _, pxy = signal.csd(u, y, FS_HZ, nperseg=4096)
    _, pxx = signal.welch(u, FS_HZ, nperseg=4096)
    _, pyy = signal.welch(y, FS_HZ, nperseg=4096)
    frd = estimate_frf(u, y, FS_HZ, nperseg=4096)
    np.testing.assert_allclose(frd.response, (pxy / pxx)[1:], rtol=1e-12)
    np.testing.assert_allclose(frd.coherence, (np.abs(pxy) ** 2 / (pxx * pyy))[1:], rtol=1e-12)


def test_non_finite_samples_anywhere_are_refused_naming_the_record():
    # 1000 samples, segments of 300 every 150: the last segment ends at sample 900.
    kw = dict(nperseg=300, noverlap=150)
    for name, index, value in (('input', 950, np.nan), ('output', 10, np.inf),
                               ('output', 999, -np.inf), ('input', 450, np.nan)):
        u, y = noise(31, 1000), noise(32, 1000)
        (u if name == 'input' else y)[index] = value
        with pytest.raises(IdentificationError, match=f'{name} holds non-finite'):
            estimate_frf(u, y, FS_HZ, **kw)
    with pytest.raises(IdentificationError, match='too large'):
        estimate_frf(1e200 * noise(33, 1000), noise(34, 1000), FS_HZ, **kw)


def test_cross_spectra_refuses_bad_channels():
    with pytest.raises(IdentificationError, match='shape'):
        cross_spectra(np.ones(100), FS_HZ)
    with pytest.raises(IdentificationError, match='equally long'):
        cross_spectra((np.ones(100), np.ones(99)), FS_HZ)
    with pytest.raises(IdentificationError, match='detrend'):
        cross_spectra((np.ones(100), np.ones(100)), FS_HZ, detrend='quadratic')


def test_effective_averages_of_hann_at_half_overlap():
    # Welch (1967): Hann at 50 % overlap has rho = 1/6, so n_eff = K / (1 + 2 (1 - 1/K) / 36).
    win = signal.get_window('hann', 1024)
    k = 40
    np.testing.assert_allclose(effective_averages(win, 512, k),
                               k / (1.0 + 2.0 * (1.0 - 1.0 / k) * (1.0 / 6.0) ** 2), rtol=2e-3)
    assert effective_averages(win, 1024, k) == k


@pytest.mark.parametrize('system', [second_order, two_mode])
def test_h1_noise_free_is_exact_with_unit_coherence(system):
    ba = system()
    u = noise(3)
    frd = estimate_frf(u, simulate(ba, u), FS_HZ, nperseg=NPERSEG, input_unit='N',
                       output_unit='m')
    band = (frd.frequency_Hz > 5.0) & (frd.frequency_Hz < 400.0)
    truth = response(ba, frd.frequency_Hz[band])
    # Leakage of the 0.25 Hz-wide Hann window is the only error left (largest at the peaks).
    rel = np.abs(frd.response[band] / truth - 1.0)
    assert np.median(rel) < 2e-3 and np.max(rel) < 0.05
    assert np.median(frd.coherence[band]) > 0.999
    assert frd.unit == 'm/N' and frd.estimator == 'H1'


def test_h1_error_consistent_with_reported_std():
    ba = two_mode()
    u = noise(4)
    y = simulate(ba, u) + 0.3 * noise(5)
    frd = estimate_frf(u, y, FS_HZ, nperseg=NPERSEG).band(5.0, 400.0)
    err = np.abs(frd.response - response(ba, frd.frequency_Hz))
    z2 = (err / frd.std) ** 2
    # Complex circular error: E[z^2] = 1 and P(|e| < 2 std) = 1 - exp(-4) = 0.98.
    assert 0.75 < np.mean(z2) < 1.35
    assert np.mean(err < 2.0 * frd.std) > 0.93
    # Magnitude / phase std and bounds are consistent with the complex std.
    lo, hi, plo, phi = frd.confidence_bounds(0.95)
    assert np.all(lo <= frd.magnitude) and np.all(hi >= frd.magnitude)
    np.testing.assert_allclose(hi - frd.magnitude, 1.959964 * frd.std / np.sqrt(2.0),
                               rtol=1e-5)


def test_coherence_drops_with_output_noise():
    ba = second_order()
    u = noise(6)
    y = simulate(ba, u)
    clean = estimate_frf(u, y, FS_HZ, nperseg=NPERSEG).band(5.0, 400.0)
    noisy = estimate_frf(u, y + 0.5 * noise(7), FS_HZ, nperseg=NPERSEG).band(5.0, 400.0)
    assert np.min(clean.coherence) > 0.99
    # Where the response is small the output noise dominates: coherence falls well below 1.
    snr = np.abs(response(ba, noisy.frequency_Hz)) ** 2 / 0.25
    expected = snr / (1.0 + snr)
    mid = (noisy.frequency_Hz > 60.0) & (noisy.frequency_Hz < 120.0)
    np.testing.assert_allclose(np.median(noisy.coherence[mid]), np.median(expected[mid]),
                               rtol=0.15)
    assert np.median(noisy.coherence) < 0.9


def test_input_noise_biases_h1_low_h2_high_hv_between():
    ba = second_order()
    u = noise(8)
    y = simulate(ba, u) + 0.3 * noise(9)
    u_meas = u + 0.5 * noise(10)
    est = {e: estimate_frf(u_meas, y, FS_HZ, nperseg=NPERSEG, estimator=e).band(5.0, 150.0)
           for e in ('H1', 'H2', 'Hv')}
    truth = np.abs(response(ba, est['H1'].frequency_Hz))
    ratio = {e: np.median(est[e].magnitude / truth) for e in est}
    # H1 = H Suu / (Suu + Snn) = 0.8 H for input noise variance 0.25.
    np.testing.assert_allclose(ratio['H1'], 0.8, rtol=0.03)
    assert ratio['H2'] > 1.02
    assert ratio['H1'] < ratio['Hv'] < ratio['H2']
    assert np.all(est['H1'].magnitude <= est['Hv'].magnitude * (1 + 1e-12))
    assert np.all(est['Hv'].magnitude <= est['H2'].magnitude * (1 + 1e-12))


def test_multisine_and_chirp_excitation():
    ba = two_mode()
    ms = Multisine(1.0, 1000, FS_HZ, f_min_Hz=2.0, f_max_Hz=450.0, phases='random', seed=1)
    u = ms.samples(np.arange(40000))
    y = simulate(ba, u) + 0.01 * noise(11, u.size)
    frd = estimate_frf(u[2000:], y[2000:], FS_HZ, nperseg=1000, window='boxcar',
                       noverlap=0).band(5.0, 400.0)
    err = np.abs(frd.response - response(ba, frd.frequency_Hz))
    assert np.mean(err < 3.0 * frd.std) > 0.95
    assert np.mean(err < 0.5 * frd.std) < 0.5    # the std is not grossly pessimistic
    # A single chirp, complete transient (zero after the sweep): the single-frequency DFT
    # ratio is exact at any frequency. Welch H1 on a sweep has a deterministic leakage error
    # (largest at the resonances) that the coherence-based std does not describe.
    chirp = Chirp(1.0, 1.0, 450.0, 20.0, FS_HZ, method='logarithmic', after_sweep='zero')
    u = chirp.samples(np.arange(int(24 * FS_HZ)))
    y = simulate(ba, u)
    f = np.array([7.3, 40.0, 123.4, 180.0, 333.3])
    dft = response_at(u, y, FS_HZ, f, method='dft')
    np.testing.assert_allclose(dft.response, response(ba, f), rtol=1e-7)
    h1 = estimate_frf(u, y, FS_HZ, nperseg=2048).band(5.0, 400.0)
    rel = np.abs(h1.response / response(ba, h1.frequency_Hz) - 1.0)
    assert np.median(rel) < 5e-3 and np.max(rel) < 0.1


def test_response_at_sine_fit_exact_and_std():
    ba = second_order()
    f = np.array([13.7, 47.3, 111.1])
    t = np.arange(30000) / FS_HZ
    u = np.sum(np.cos(2 * np.pi * f[:, None] * t + np.array([[0.3], [1.0], [2.0]])), axis=0)
    y = simulate(ba, u)
    keep = slice(5000, None)
    frd = response_at(u[keep], y[keep], FS_HZ, f, input_unit='V', output_unit='m')
    np.testing.assert_allclose(frd.response, response(ba, f), rtol=1e-8)
    noisy = response_at(u[keep], y[keep] + 0.1 * noise(12, y[keep].size), FS_HZ, f)
    err = np.abs(noisy.response - response(ba, f))
    assert np.all(err < 4.0 * noisy.std) and np.all(noisy.std > 0.0)
    # std of a sine amplitude in white noise: sigma sqrt(2 / N) per component.
    np.testing.assert_allclose(noisy.std * np.abs(frd.details['input_amplitude']),
                               0.1 * np.sqrt(4.0 / y[keep].size), rtol=0.05)


def test_errors_name_the_problem():
    with pytest.raises(IdentificationError, match='equal length'):
        estimate_frf(np.ones(100), np.ones(99), FS_HZ)
    with pytest.raises(IdentificationError, match='estimator'):
        estimate_frf(noise(1, 100), noise(2, 100), FS_HZ, estimator='H3')
    with pytest.raises(IdentificationError, match='nperseg'):
        estimate_frf(noise(1, 100), noise(2, 100), FS_HZ, nperseg=200)
    with pytest.raises(IdentificationError, match='NaN'):
        estimate_frf(np.full(100, np.nan), noise(2, 100), FS_HZ)
    with pytest.raises(IdentificationError, match='Nyquist'):
        response_at(noise(1, 100), noise(2, 100), FS_HZ, [600.0])
    assert isinstance(IdentificationError('x'), ValueError)
    frd = estimate_frf(noise(1, 1000), noise(2, 1000), FS_HZ)
    assert isinstance(frd, FrequencyResponseData)
