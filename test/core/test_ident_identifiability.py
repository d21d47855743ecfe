"""Fisher-information analysis and the choice of the free set."""

import numpy as np

from emfc_ros.core.ident.identifiability import (analyse, choose_free,
                                                 relative_jacobian_columns)


def _jacobian(names, columns):
    return np.column_stack([columns[n] for n in names])


def test_well_conditioned_set_keeps_every_parameter():
    rng = np.random.default_rng(1)
    cols = {n: rng.normal(size=500) for n in ('a', 'b', 'c')}
    choice = choose_free(lambda names: _jacobian(names, cols), ['a', 'b', 'c'],
                         {'a': 1.0, 'b': 1.0, 'c': 1.0}, may_fix=['a', 'b', 'c'])
    assert choice.free == ('a', 'b', 'c')
    assert choice.fixed == {}
    assert choice.analysis.rank == 3
    # 500 unit-variance residuals: every direction known to about 1/sqrt(500)
    assert np.all(choice.analysis.relative_uncertainty < 0.1)


def test_parameters_that_enter_only_as_a_sum_are_not_separable():
    # y depends on a + b only: the direction (1, -1)/sqrt(2) is not determined at all
    rng = np.random.default_rng(2)
    u = rng.normal(size=400)
    cols = {'a': u, 'b': u.copy(), 'c': rng.normal(size=400)}
    ana = analyse(_jacobian(['a', 'b', 'c'], cols), ['a', 'b', 'c'], [1.0, 1.0, 1.0])
    assert ana.rank == 2
    assert ana.condition_number > 1e12
    worst = int(np.argmax(ana.relative_uncertainty))
    np.testing.assert_allclose(np.abs(ana.directions[worst]), [2 ** -0.5, 2 ** -0.5, 0.0],
                               atol=1e-8)
    text = ana.combination(worst)
    assert 'da/a' in text and 'db/b' in text and 'dc/c' not in text
    choice = choose_free(lambda names: _jacobian(names, cols), ['a', 'b', 'c'],
                         {'a': 1.0, 'b': 1.0, 'c': 1.0}, may_fix=['b'])
    assert choice.free == ('a', 'c')
    assert set(choice.fixed) == {'b'}
    assert 'not separable' in choice.fixed['b']
    assert choice.initial_analysis.rank == 2 and choice.analysis.rank == 2


def test_only_allowed_parameters_are_fixed():
    u = np.linspace(-1.0, 1.0, 300)
    cols = {'a': u, 'b': 2.0 * u}
    choice = choose_free(lambda names: _jacobian(names, cols), ['a', 'b'], {'a': 1.0, 'b': 1.0},
                         may_fix=[])
    assert choice.free == ('a', 'b')
    assert choice.fixed == {}


def test_relative_jacobian_columns_match_the_analytic_derivative():
    x = np.linspace(0.0, 1.0, 50)

    def residual(v):
        return v['k'] * np.exp(-v['d'] * x)

    values = {'k': 2.0, 'd': 0.5}
    jac = relative_jacobian_columns(residual, values, ['k', 'd'])
    np.testing.assert_allclose(jac[:, 0], np.exp(-0.5 * x), rtol=1e-7)
    np.testing.assert_allclose(jac[:, 1], -2.0 * x * np.exp(-0.5 * x), rtol=1e-6, atol=1e-9)
    d = analyse(jac, ['k', 'd'], [2.0, 0.5]).to_dict()
    assert d['names'] == ['k', 'd'] and len(d['directions']) == 2
