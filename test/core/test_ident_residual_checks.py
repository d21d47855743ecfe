"""
Residual checks that mean something (issue 28 item 4).

The cross-correlation test's p-value uses the null covariance of its lags for the actual
input (Bartlett) and the fitted parameters' estimation error; the coherence check names the
frequency of a dynamic the model lacks. Calibrated here against synthetic records whose
truth is known (independent white residuals under steps, chirps and PRBS; a regression
whose parameter was estimated elsewhere), and checked on the balance: a right model does
not warn, an unmodelled mode is named at its frequency.
"""

import numpy as np
import pytest

from emfc_ros.core.ident.metrics import input_correlation_test, whiteness_test
from emfc_ros.core.ident.offnominal import draw_balance, record_draw, TEST_SEEDS, \
    with_extra_mode
from emfc_ros.core.ident.pipeline import identify
from emfc_ros.core.ident.residual_coherence import residual_coherence

N = 20000
FS = 10000.0


def inputs(rng):
    """A step staircase, a chirp and a PRBS of N samples."""
    t = np.arange(N) / FS
    return {'steps': np.repeat(rng.standard_normal(20), N // 20),
            'chirp': np.sin(2 * np.pi * (1.0 + 100.0 * t) * t),
            'prbs': np.repeat(rng.choice([-1.0, 1.0], N // 5), 5)}


def test_a_white_residual_independent_of_the_input_passes_at_the_nominal_rate():
    rng = np.random.default_rng(28401)
    p = {name: [] for name in inputs(rng)}
    white = []
    for _ in range(200):
        e = rng.standard_normal(N)
        white.append(whiteness_test(e).p_value)
        for name, u in inputs(rng).items():
            test = input_correlation_test(e, u)
            p[name].append(test.p_value)
    assert np.mean(np.array(white) < 0.01) <= 0.03
    assert 0.01 <= np.mean(np.array(white) < 0.1) <= 0.2
    for name, values in p.items():
        values = np.array(values)
        assert np.mean(values < 0.01) <= 0.04, name
        assert np.mean(values < 0.1) <= 0.2, name


def test_a_dependence_on_the_input_is_found():
    rng = np.random.default_rng(28402)
    found = []
    for _ in range(20):
        u = inputs(rng)['prbs']
        e = rng.standard_normal(N) + 0.1 * np.roll(u, 3)
        found.append(input_correlation_test(e, u).p_value < 1e-4)
    assert all(found)


def test_a_parameter_estimated_elsewhere_is_not_taken_for_a_model_error():
    """A gain from a short noisy record, tested on a long quiet staircase (y = theta x)."""
    rng = np.random.default_rng(28403)
    with_terms, without, old_rule = [], [], []
    for _ in range(200):
        x_a = rng.standard_normal(500)
        theta_hat = 1.0 + rng.standard_normal() / np.sqrt(x_a @ x_a)     # its scatter
        variance = 1.0 / (x_a @ x_a)
        x_b = np.repeat(rng.standard_normal(20), N // 20)
        residual = x_b * 1.0 + 0.05 * rng.standard_normal(N) - theta_hat * x_b
        # the residual's derivative by theta, and theta's variance
        terms = (-x_b[:, None], np.array([[variance]]))
        with_terms.append(input_correlation_test(residual, x_b, parameter_terms=terms).p_value)
        plain = input_correlation_test(residual, x_b)
        without.append(plain.p_value)
        old_rule.append(plain.fraction_inside < 0.8)    # the rule before issue 28
    assert np.mean(np.array(without) < 0.01) > 0.5
    assert np.mean(old_rule) > 0.5
    assert np.mean(np.array(with_terms) < 0.01) <= 0.04


def test_the_coherence_check_is_calibrated_and_names_a_resonance():
    from scipy import signal
    rng = np.random.default_rng(28404)
    p = []
    for _ in range(100):
        e = rng.standard_normal(4 * N)
        p.append(residual_coherence(e, {'u': rng.standard_normal(4 * N),
                                        'v': np.repeat(rng.standard_normal(80), N // 20)},
                                    FS, (1.0, 2000.0)).p_value)
    assert np.mean(np.array(p) < 0.01) <= 0.04
    # a lightly damped 150 Hz response to the input, small beside the noise
    w = 2 * np.pi * 150.0
    b, a = signal.bilinear([w * w], [1.0, 2 * 0.02 * w, w * w], FS)
    u = rng.standard_normal(4 * N)
    response = signal.lfilter(b, a, u)
    e = rng.standard_normal(4 * N) + 0.1 * response / np.std(response)
    peak = residual_coherence(e, {'coil': u}, FS, (1.0, 2000.0))
    assert peak.p_value < 1e-6
    assert abs(peak.frequency_Hz - 150.0) < 15.0 and peak.input == 'coil'


@pytest.mark.slow
def test_on_the_balance_a_right_model_passes_and_an_extra_mode_is_named():
    seed = TEST_SEEDS[3]
    rec = record_draw(draw_balance(seed), seed, draw_seed=seed)
    right = identify(rec.recording, rec.section_table, rec.options())
    assert right.success, right.failures
    assert not [w for w in right.warnings if 'residual' in w], right.warnings
    p_values = [s.input_correlation_p_value for s in right.greybox.fit.sections]
    assert all(np.isfinite(p_values)), p_values
    # a mode at 150 Hz adding a quarter of the coil response at its peak
    broken = with_extra_mode(rec, 150.0, 0.02, 0.01)
    res = identify(broken.recording, broken.section_table, broken.options())
    named = [w for w in res.warnings if 'coherent with the coil input' in w]
    assert named, res.warnings
    peaks = [s.coherence for s in res.greybox.fit.sections
             if s.coherence is not None and s.coherence.p_value < 1e-6]
    assert peaks and all(abs(pk.frequency_Hz - 150.0) < 25.0 for pk in peaks), peaks
    row = res.to_dict()['greybox']['sections'][0]
    assert row['coherence']['input'] == 'coil' and row['coherence']['p_value'] < 1e-6
