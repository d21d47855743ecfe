"""
BLAS limited to one thread inside the small-matrix steps, restored afterwards.

The thread count is read back from the BLAS libraries themselves (threadpoolctl), inside the
decorated functions of the identification core, not from our own bookkeeping.
"""

import threading

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from emfc_ros.core import blas_threads
from emfc_ros.core.ident import FrequencyResponseData, tf_fit


@pytest.fixture
def two_threads():
    """BLAS on two threads for the test (a one-core machine would not show a change)."""
    assert blas_threads.available(), 'threadpoolctl found no BLAS library'
    with threadpool_limits(2, user_api='blas'):
        assert blas_threads.blas_threads() == 2
        yield


def test_block_limits_and_restores(two_threads):
    with blas_threads.single_blas_thread():
        assert blas_threads.blas_threads() == 1
        with blas_threads.single_blas_thread():
            assert blas_threads.blas_threads() == 1
        assert blas_threads.blas_threads() == 1     # the inner exit keeps the outer limit
    assert blas_threads.blas_threads() == 2


def test_restored_after_an_exception(two_threads):
    with pytest.raises(ZeroDivisionError):
        with blas_threads.single_blas_thread():
            1 / 0
    assert blas_threads.blas_threads() == 2


def test_overlapping_blocks_in_threads_restore_once_all_left(two_threads):
    first_in, second_in, first_out = threading.Event(), threading.Event(), threading.Event()
    seen = {}

    def first():
        with blas_threads.single_blas_thread():
            first_in.set()
            second_in.wait(5.0)
        first_out.set()

    def second():
        first_in.wait(5.0)
        with blas_threads.single_blas_thread():
            second_in.set()
            first_out.wait(5.0)
            seen['after_first_left'] = blas_threads.blas_threads()
        seen['after_both_left'] = blas_threads.blas_threads()

    threads = [threading.Thread(target=first), threading.Thread(target=second)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10.0)
    assert seen == {'after_first_left': 1, 'after_both_left': 2}


def test_decorated_core_function_runs_on_one_thread(two_threads, monkeypatch):
    seen = []
    original = tf_fit._solve_real

    def spy(rows, rhs):
        seen.append(blas_threads.blas_threads())
        return original(rows, rhs)

    monkeypatch.setattr(tf_fit, '_solve_real', spy)
    f = np.logspace(0.0, 2.0, 60)
    s = 2j * np.pi * f
    h = 1.0 / (s ** 2 + 2.0 * s + 400.0)
    frd = FrequencyResponseData(f, h, np.ones(f.size), 1e-3 * np.abs(h), 10.0, 'test')
    fit = tf_fit.fit_transfer_function(frd, 0, 2)
    assert seen and set(seen) == {1}
    np.testing.assert_allclose(fit.denominator / fit.denominator[0], [1.0, 2.0, 400.0],
                               rtol=1e-6)
    assert blas_threads.blas_threads() == 2


def test_switched_off_leaves_threads_alone(two_threads):
    previous = blas_threads.set_limiting(False)
    try:
        with blas_threads.single_blas_thread():
            assert blas_threads.blas_threads() == 2
    finally:
        blas_threads.set_limiting(previous)
    assert previous is True
