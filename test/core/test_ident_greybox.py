"""
Grey-box fit of a mass-spring-damper with least squares, Gauss-Newton and pattern search.

Ground truth: the exact zero-order-hold response of the simulated system.
"""

import numpy as np
import pytest
from scipy import linalg, signal

from emfc_ros.core.ident import (DataSection, fit_greybox, fit_percent, IdentificationError,
                                 input_correlation_test, ParameterSpec, pattern_search,
                                 PatternSearchOptions, specs_from_mapping, whiteness_test)

FS_HZ = 1000.0
TRUTH = {'mass': 1.0, 'stiffness': (2 * np.pi * 5.0) ** 2, 'damping': 2 * 0.1 * 2 * np.pi * 5.0,
         'gain': 1000.0}
FREE = ('stiffness', 'damping', 'gain')


def simulate(p, u):
    """Exact zero-order-hold response of gain / (mass s^2 + damping s + stiffness)."""
    a = np.zeros((3, 3))
    a[0, 1] = 1.0
    a[1] = [-p['stiffness'] / p['mass'], -p['damping'] / p['mass'], p['gain'] / p['mass']]
    e = linalg.expm(a / FS_HZ)
    (a11, a12), (a21, a22) = e[:2, :2]
    b1, b2 = e[:2, 2]
    return signal.lfilter([0.0, b1, a12 * b2 - a22 * b1],
                          [1.0, -(a11 + a22), a11 * a22 - a12 * a21], u)


def inputs():
    rng = np.random.default_rng(0)
    prbs = np.repeat(rng.choice([-1.0, 1.0], 200), 10)
    steps = np.repeat([0.0, 1.0, -0.5, 0.5], 500)
    return prbs, steps


def sections(noise_rel=0.0, seed=1):
    rng = np.random.default_rng(seed)
    out = []
    for name, u in zip(('prbs', 'steps'), inputs()):
        y = simulate(TRUTH, u)
        out.append(DataSection(name, u, y + noise_rel * np.std(y) * rng.standard_normal(
            y.size)))
    return out


def specs(stiffness_upper=5000.0, mass=1.0):
    return [ParameterSpec('mass', mass, free=False, unit='kg'),
            ParameterSpec('stiffness', 700.0, 100.0, stiffness_upper, unit='N/m'),
            ParameterSpec('damping', 10.0, 0.1, 100.0, unit='N s/m'),
            ParameterSpec('gain', 600.0, 10.0, 1.0e4, unit='N/V')]


def test_simulation_matches_scipy_zoh():
    u = inputs()[0]
    num, den, _ = signal.cont2discrete(([TRUTH['gain']], [1.0, TRUTH['damping'],
                                                          TRUTH['stiffness']]),
                                       1.0 / FS_HZ, method='zoh')
    np.testing.assert_allclose(simulate(TRUTH, u), signal.lfilter(num.ravel(), den, u),
                               atol=1e-12)


@pytest.mark.parametrize('method, rtol', [('least_squares', 1e-4), ('gauss_newton', 1e-4),
                                          ('pattern_search', 1e-3)])
def test_noise_free_recovery(method, rtol):
    res = fit_greybox(simulate, sections(), specs(), method=method)
    for name in FREE:
        np.testing.assert_allclose(res.parameters[name], TRUTH[name], rtol=rtol)
    assert res.parameters['mass'] == 1.0 and res.standard_errors['mass'] == 0.0
    assert res.success and res.method == method
    assert [s.name for s in res.sections] == ['prbs', 'steps']
    assert all(s.fit_percent[0] > 99.9 for s in res.sections)
    assert res.optimizer_evaluations <= 2000 * 3 and res.time_s > 0.0
    assert res.free_names == FREE
    assert 'stiffness' in res.summary()


@pytest.mark.parametrize('method', ['least_squares', 'gauss_newton', 'pattern_search'])
def test_noisy_fit_standard_errors_cover_truth(method):
    res = fit_greybox(simulate, sections(0.05, seed=2), specs(), method=method)
    for name in FREE:
        se = res.standard_errors[name]
        assert 0.0 < se < 0.05 * TRUTH[name]
        assert abs(res.parameters[name] - TRUTH[name]) < 3.0 * se, name
    np.testing.assert_allclose(np.diag(res.correlation), 1.0)
    for sec in res.sections:
        # Fit = 100 (1 - noise / signal) for white noise of 5 % of the output std.
        np.testing.assert_allclose(sec.fit_percent[0], 95.0, atol=0.5)
        assert sec.whiteness_fraction >= 0.9 and sec.input_correlation_fraction >= 0.9


def test_standard_error_coverage_over_repeats():
    hits = []
    for seed in range(20):
        res = fit_greybox(simulate, sections(0.05, seed=10 + seed), specs())
        hits.append([abs(res.parameters[n] - TRUTH[n]) < 2.0 * res.standard_errors[n]
                     for n in FREE])
    coverage = np.mean(hits, axis=0)
    assert np.all(coverage >= 0.8), coverage


@pytest.mark.parametrize('method', ['least_squares', 'gauss_newton', 'pattern_search'])
def test_bounds_respected_and_fixed_stay_fixed(method):
    seen = []

    def recording(p, u):
        seen.append(dict(p))
        return simulate(p, u)

    res = fit_greybox(recording, sections(), specs(stiffness_upper=900.0), method=method)
    assert all(100.0 <= p['stiffness'] <= 900.0 for p in seen)
    assert all(0.1 <= p['damping'] <= 100.0 and 10.0 <= p['gain'] <= 1.0e4 for p in seen)
    assert all(p['mass'] == 1.0 for p in seen)
    # The truth (987 N/m) is outside: the estimate sits on the bound.
    np.testing.assert_allclose(res.parameters['stiffness'], 900.0, rtol=1e-6)


def derivatives(scale_column=None, factor=1.0):
    """Output derivatives by central differences of ``simulate`` (optionally one column off)."""
    def output_derivatives(p, names, u):
        columns = []
        for name in names:
            h = 1e-6 * abs(p[name])
            up, down = dict(p, **{name: p[name] + h}), dict(p, **{name: p[name] - h})
            d = (simulate(up, u) - simulate(down, u)) / (2.0 * h)
            columns.append(d * (factor if name == scale_column else 1.0))
        return np.column_stack(columns)
    return output_derivatives


def test_gauss_newton_takes_checked_output_derivatives_for_the_covariance():
    data = sections(0.05, seed=4)
    exact = fit_greybox(simulate, data, specs(), method='gauss_newton')
    assert exact.jacobian_method.startswith('central differences')
    given = fit_greybox(simulate, data, specs(), method='gauss_newton',
                        output_derivatives=derivatives())
    assert given.jacobian_method.startswith('output derivatives')
    assert given.derivative_check < 1e-3
    for name in FREE:
        se = exact.standard_errors[name]
        assert abs(given.parameters[name] - exact.parameters[name]) < 0.01 * se
        np.testing.assert_allclose(given.standard_errors[name], se, rtol=1e-3)


def test_wrong_output_derivatives_are_caught_and_replaced():
    data = sections(0.05, seed=4)
    exact = fit_greybox(simulate, data, specs(), method='gauss_newton')
    wrong = fit_greybox(simulate, data, specs(), method='gauss_newton',
                        output_derivatives=derivatives('damping', 1.3))
    # the check sees the damping column 30 % off and computes the central differences
    assert wrong.derivative_check > 0.01
    assert wrong.jacobian_method.startswith('central differences')
    for name in FREE:
        se = exact.standard_errors[name]
        assert abs(wrong.parameters[name] - exact.parameters[name]) < 0.05 * se
        np.testing.assert_allclose(wrong.standard_errors[name], se, rtol=1e-3)


def test_wrong_fixed_parameter_shows_in_residual_tests():
    good = fit_greybox(simulate, sections(0.05, seed=3), specs())
    wrong = [ParameterSpec('damping', 2.0 * TRUTH['damping'], free=False) if s.name ==
             'damping' else s for s in specs()]
    bad = fit_greybox(simulate, sections(0.05, seed=3), wrong)
    assert bad.cost > 2.0 * good.cost
    assert bad.sections[0].whiteness_fraction < 0.5 < good.sections[0].whiteness_fraction
    assert bad.sections[0].fit_percent[0] < good.sections[0].fit_percent[0] - 1.0


def test_pattern_search_budget_and_exit_reason():
    opts = PatternSearchOptions(max_function_evaluations=40)
    res = fit_greybox(simulate, sections(), specs(), method='pattern_search', options=opts)
    assert not res.success and 'maximum' in res.exit_reason
    assert res.optimizer_evaluations <= 40


def test_pattern_search_polls_like_matlab():
    # MATLAB's example: x0 = [2.1, 1.7], mesh 1, poll order [1 0], [0 1], [-1 0], [0 -1].
    points = []

    def f(x):
        points.append(tuple(np.round(x, 12)))
        return (x[0] - 1.0) ** 2 + (x[1] - 0.0) ** 2

    res = pattern_search(f, [2.1, 1.7])
    # (1.1, 1.7) improves: the poll stops there (opportunistic) and the mesh doubles to 2.
    assert points[:5] == [(2.1, 1.7), (3.1, 1.7), (2.1, 2.7), (1.1, 1.7), (3.1, 1.7)]
    np.testing.assert_allclose(res.x, [1.0, 0.0], atol=1e-6)
    assert res.exit_flag in (1, 2, 3) and res.success
    assert res.n_evaluations <= 2000 * 2 and res.n_iterations <= 100 * 2


def test_pattern_search_projects_onto_bounds():
    res = pattern_search(lambda x: float(np.sum((x - 3.0) ** 2)), [0.0, 0.0],
                         lower=[-1.0, -1.0], upper=[2.0, 2.5])
    np.testing.assert_allclose(res.x, [2.0, 2.5], atol=1e-6)
    with pytest.raises(IdentificationError, match='outside'):
        pattern_search(lambda x: 0.0, [5.0], lower=[0.0], upper=[1.0])


def test_metrics():
    y = np.sin(np.linspace(0.0, 20.0, 1000))
    assert fit_percent(y, y) == 100.0
    np.testing.assert_allclose(fit_percent(y, np.full_like(y, y.mean())), 0.0, atol=1e-12)
    np.testing.assert_allclose(fit_percent(y, y + 0.1 * (y - y.mean())), 90.0)
    rng = np.random.default_rng(4)
    white = rng.standard_normal(5000)
    assert whiteness_test(white).fraction_inside >= 0.9
    coloured = signal.lfilter([1.0], [1.0, -0.95], white)
    assert whiteness_test(coloured).fraction_inside < 0.1
    np.testing.assert_allclose(whiteness_test(white, confidence=0.99).bound,
                               2.5758293 / np.sqrt(5000), rtol=1e-6)
    u = rng.standard_normal(5000)
    assert input_correlation_test(white, u).fraction_inside >= 0.9
    assert input_correlation_test(white + 0.5 * np.roll(u, 3), u).fraction_inside < 1.0


def test_greybox_errors():
    with pytest.raises(IdentificationError, match='method'):
        fit_greybox(simulate, sections(), specs(), method='simplex')
    with pytest.raises(IdentificationError, match='unique'):
        fit_greybox(simulate, sections(), specs() + [ParameterSpec('mass', 1.0)])
    with pytest.raises(IdentificationError, match='outside'):
        fit_greybox(simulate, sections(), [ParameterSpec('stiffness', 1.0, 2.0, 3.0)])
    with pytest.raises(IdentificationError, match='shape'):
        fit_greybox(lambda p, u: u[:10], sections(), specs())


def test_specs_from_mapping():
    specs_ = specs_from_mapping({'mass': 1.0, 'stiffness': 700.0, 'damping': -2.0},
                                free=('stiffness', 'damping'))
    by_name = {s.name: s for s in specs_}
    assert not by_name['mass'].free and by_name['stiffness'].free
    assert (by_name['stiffness'].lower, by_name['stiffness'].upper) == (70.0, 7000.0)
    assert (by_name['damping'].lower, by_name['damping'].upper) == (-20.0, -0.2)
    assert by_name['stiffness'].resolved_scale() == 700.0
    with pytest.raises(IdentificationError, match='gain'):
        specs_from_mapping({'mass': 1.0}, free=('gain',))
