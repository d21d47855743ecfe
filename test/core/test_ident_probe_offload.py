"""
The grey-box's probe for a second optimum run in another process (issue 14, item 5).

``identify(..., executor=...)`` starts the time-domain fit while the probe runs elsewhere; the
result must be the one the probe in line gives, whatever the other process does: the same
numbers when it finds nothing, the in-line result again when it finds a better optimum, its
failure in the verdict, and the probe run in line when the process pool cannot take it or
fails.
"""

from concurrent.futures import Future, ProcessPoolExecutor
import multiprocessing
from pathlib import Path

import numpy as np
import pytest
import yaml

from emfc_ros.core.ident import balance_fit
from emfc_ros.core.ident.balance_experiment import (section_table, simulate_experiment,
                                                    time_scaled_mapping)
from emfc_ros.core.ident.pipeline import identify
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.signals import experiment_from_config, find_experiment_mapping

TRAJECTORY = Path(__file__).resolve().parents[2] / 'config' / 'identification_trajectory.yaml'
DRAWN = ('c1_Nm_per_rad', 'd1_Nms_per_rad', 'c2_Nm_per_rad', 'd2_Nms_per_rad', 'mp_kg',
         'm1_kg', 'J1c_kgm2', 'm2_kg', 'J2c_kgm2', 'm3_kg')


def _timeless(value):
    """A result's plain data without its wall times (they differ from run to run)."""
    if isinstance(value, dict):
        return {k: _timeless(v) for k, v in value.items() if k not in ('time_s', 'timings_s')}
    if isinstance(value, (list, tuple)):
        return [_timeless(v) for v in value]
    return value


@pytest.fixture(scope='module')
def case():
    """An off-nominal balance (+/-5 %, drawn with a seed no other test uses), 0.3x trajectory."""
    rng = np.random.default_rng(80417)
    nominal = BalanceParameters()
    truth = nominal.with_mechanics(**{k: getattr(nominal.mechanics, k) * rng.uniform(0.95, 1.05)
                                      for k in DRAWN})
    doc = yaml.safe_load(TRAJECTORY.read_text())
    exp = experiment_from_config(time_scaled_mapping(find_experiment_mapping(doc), 0.3))
    recording = simulate_experiment(truth, exp, seed=80418)
    options = {'load_mass_kg': recording.load_mass_kg, 'load_changer_coupled': True}
    return recording, options


@pytest.fixture(scope='module')
def in_line(case):
    recording, options = case
    return identify(recording, section_table(recording), options)


class Claims:
    """
    An executor whose probe claims an outcome (a better optimum, a failure).

    The probe finds a better optimum or two equal ones only on data made for it; this stands
    in for such a probe and returns at once what it is told, to check what the fit does then.
    """

    def __init__(self, better: bool = False, failures=()):
        self.better, self.failures, self.calls = better, list(failures), 0

    def submit(self, fn, *args):
        self.calls += 1
        future = Future()
        _model, _frfs, fit = args[:3]
        future.set_result((fit if self.better else None, list(self.failures)))
        return future


class Refuses:
    """An executor that cannot take work (a pool shut down)."""

    def submit(self, fn, *args):
        raise RuntimeError('cannot schedule new futures after shutdown')


class Fails:
    """An executor whose task failed in the other process."""

    def submit(self, fn, *args):
        future = Future()
        future.set_exception(EOFError('the worker died'))
        return future


def test_a_probe_in_a_worker_process_gives_the_in_line_result(case, in_line):
    recording, options = case
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context('spawn')) as pool:
        result = identify(recording, section_table(recording), options, executor=pool)
    assert in_line.success, in_line.failures
    assert result.greybox is not None
    assert _timeless(result.to_dict()) == _timeless(in_line.to_dict())


@pytest.mark.parametrize('executor', [Refuses(), Fails()], ids=['refuses', 'fails'])
def test_the_probe_runs_in_line_when_the_other_process_cannot(case, in_line, executor):
    recording, options = case
    result = identify(recording, section_table(recording), options, executor=executor)
    assert _timeless(result.to_dict()) == _timeless(in_line.to_dict())


def test_a_better_optimum_found_elsewhere_runs_the_fit_again_in_line(case, in_line):
    recording, options = case
    claims = Claims(better=True)
    result = identify(recording, section_table(recording), options, executor=claims)
    assert claims.calls == 1            # the second run is in line: no second submission
    assert _timeless(result.to_dict()) == _timeless(in_line.to_dict())


def test_the_probes_failure_reaches_the_verdict_where_the_in_line_probe_puts_it(case):
    recording, options = case
    failure = 'greybox: the data fit two parameter sets equally well (c2 1 or 2)'
    result = identify(recording, section_table(recording), options,
                      executor=Claims(failures=[failure]))
    assert not result.success
    assert failure in result.failures
    # the probe in line ends the frequency-domain stage: its failure comes before any failure
    # of the time-domain fit and its checks
    assert result.failures.index(failure) == 0
    assert result.greybox is not None   # the fit is still there to look at


def test_probe_elsewhere_is_the_in_line_probe(case):
    # the task the worker runs reports what the in-line probe reports: nothing better here
    recording, options = case
    captured = {}

    class Capture:
        def submit(self, fn, *args):
            captured['fn'], captured['args'] = fn, args
            raise RuntimeError('run it in line')

    identify(recording, section_table(recording), options, executor=Capture())
    assert captured['fn'] is balance_fit.probe_elsewhere
    better, failures = balance_fit.probe_elsewhere(*captured['args'])
    assert better is None and failures == []
