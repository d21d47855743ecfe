"""The worker that runs device requests off the executor: order, no duplicates, shutdown."""

import threading

import pytest

from emfc_ros.core.device.jobs import DeviceJobs, outcome


def test_jobs_run_in_the_order_asked_and_a_waiting_job_is_not_queued_twice():
    jobs = DeviceJobs('test-jobs')
    gate = threading.Event()
    done = []
    try:
        first = jobs.submit('start', lambda: (gate.wait(5.0), done.append('start'))[1])
        assert jobs.pending('start') and jobs.pending()
        safe = jobs.submit('safe_outputs', done.append, 'safe')
        again = jobs.submit('safe_outputs', done.append, 'safe again')
        assert again is safe                         # still waiting: the same job
        restore = jobs.submit('restore', done.append, 'restore')
        assert not safe.done()
        gate.set()
        restore.result(5.0)
        assert done == ['start', 'safe', 'restore']
        assert first.done() and not jobs.pending()
        # A job that raises: the exception is in its future, the worker goes on.
        failed = jobs.submit('stop', lambda: 1 / 0)
        with pytest.raises(ZeroDivisionError):
            failed.result(5.0)
        assert outcome(failed)[0] is False and 'ZeroDivisionError' in outcome(failed)[1]
        good = jobs.submit('y', lambda: (True, 'ok'))
        assert good.result(5.0) == (True, 'ok') and outcome(good) == (True, 'ok')
    finally:
        gate.set()
        assert jobs.close(5.0)


def test_close_cancels_what_waits_and_refuses_new_jobs():
    jobs = DeviceJobs('test-jobs')
    gate, started = threading.Event(), threading.Event()
    running = jobs.submit('start', lambda: (started.set(), gate.wait(5.0))[1])
    assert started.wait(5.0)
    waiting = jobs.submit('stop', lambda: 'never')
    closer = threading.Thread(target=jobs.close, args=(5.0,))
    closer.start()
    gate.set()
    closer.join(5.0)
    assert running.result(5.0) is True
    assert waiting.cancelled()
    assert jobs.submit('late', lambda: 'never').cancelled()
    assert outcome(waiting) == (False, 'cancelled')
