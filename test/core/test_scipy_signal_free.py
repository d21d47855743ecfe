"""
The job's path without scipy.signal: our replacements against scipy.signal itself.

The experiment runner does not import scipy.signal (nor scipy.stats behind it): about a second
of its start-up. Each replacement must equal what scipy.signal computes, and the modules on
the runner's path must not import it.
"""

import subprocess
import sys

import numpy as np
import pytest
from scipy import signal, special, stats

from emfc_ros.core.ident.frf import window_samples
from emfc_ros.core.ident.metrics import correlation_at_lags
from emfc_ros.core.ident.modal_filter import modal_pair
from emfc_ros.core.report.exports import ss_to_tf, tf_to_ss
from ros_harness import scaled


@pytest.mark.parametrize('n', [1, 2, 7, 256, 4096])
def test_the_hann_window_is_scipys(n):
    np.testing.assert_allclose(window_samples('hann', n), signal.get_window('hann', n),
                               rtol=0, atol=1e-15)


def test_other_windows_come_from_scipy():
    np.testing.assert_array_equal(window_samples(('tukey', 0.25), 64),
                                  signal.get_window(('tukey', 0.25), 64))


@pytest.mark.parametrize('n, max_lag', [(1000, 25), (1000, 999), (5, 4), (1, 0), (40000, 50)])
def test_the_correlation_at_lags_is_scipys(n, max_lag):
    rng = np.random.default_rng(n * 31 + max_lag)
    a, b = rng.normal(size=n), rng.normal(size=n)
    ref = signal.correlate(a, b, mode='full', method='direct')[n - 1 - max_lag:n + max_lag]
    np.testing.assert_allclose(correlation_at_lags(a, b, max_lag), ref, rtol=0,
                               atol=1e-12 * np.max(np.abs(ref)))


@pytest.mark.parametrize('lam', [0.5 + 0.3j, 0.9999 * np.exp(0.002j), -0.2 + 0j])
def test_the_modal_pair_is_two_lfilters(lam):
    x = np.random.default_rng(5).normal(size=5000)
    s, t = modal_pair(lam, x)
    s_ref = signal.lfilter([0.0, 1.0], [1.0, -lam], x.astype(complex))
    t_ref = signal.lfilter([0.0, 1.0], [1.0, -lam], s_ref)
    np.testing.assert_allclose(s, s_ref, rtol=1e-13, atol=1e-13 * np.max(np.abs(s_ref)))
    np.testing.assert_allclose(t, t_ref, rtol=1e-13, atol=1e-13 * np.max(np.abs(t_ref)))


@pytest.mark.parametrize('nn, nd', [(1, 1), (1, 3), (3, 5), (5, 5)])
def test_tf_to_ss_is_tf2ss(nn, nd):
    rng = np.random.default_rng(nn * 10 + nd)
    num, den = rng.normal(size=nn), np.r_[2.5, rng.normal(size=nd - 1)]
    for got, ref in zip(tf_to_ss(num, den), signal.tf2ss(num, den)):
        assert np.shape(got) == np.shape(ref)
        np.testing.assert_allclose(got, ref, rtol=1e-15, atol=1e-15)


def test_an_improper_transfer_function_is_refused():
    with pytest.raises(ValueError, match='improper'):
        tf_to_ss([1.0, 2.0, 3.0], [1.0, 1.0])


@pytest.mark.parametrize('input', [0, 1])
def test_ss_to_tf_is_ss2tf(input):
    rng = np.random.default_rng(7 + input)
    a, b = rng.normal(size=(4, 4)), rng.normal(size=(4, 2))
    c, d = rng.normal(size=(1, 4)), np.array([[0.0, 0.3]])
    num, den = ss_to_tf(a, b, c, d, input=input)
    num_ref, den_ref = signal.ss2tf(a, b, c, d, input=input)
    np.testing.assert_allclose(num, num_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(den, den_ref, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize('dof', [1, 3, 12, 1000])
def test_the_coverage_factor_is_students_t(dof):
    assert special.stdtrit(dof, 0.975) == pytest.approx(stats.t.ppf(0.975, dof), rel=1e-12)


def test_the_runners_path_imports_neither_scipy_signal_nor_stats():
    code = ('import sys\n'
            'import emfc_ros.cli.experiment, emfc_ros.nodes.plant_simulator\n'
            'import emfc_ros.nodes.recorder, emfc_ros.nodes.signal_generator\n'
            'import emfc_ros.core.ident.pipeline, emfc_ros.core.ident.from_bag\n'
            'import emfc_ros.core.report.writer, emfc_ros.core.report.exports\n'
            "print(sorted(m for m in ('scipy.signal', 'scipy.stats') if m in sys.modules))\n")
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=scaled(120))
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == '[]', out.stdout


def test_the_correlation_at_lags_refuses_what_it_cannot_compute():
    from emfc_ros.core.ident.errors import IdentificationError
    with pytest.raises(IdentificationError, match='lengths differ'):
        correlation_at_lags(np.ones(10), np.ones(9), 2)
    with pytest.raises(IdentificationError, match='max_lag 10 is not in 0..9'):
        correlation_at_lags(np.ones(10), np.ones(10), 10)
