"""
Wall and CPU time of the main job (``emfc-experiment`` with a plan), by phase, and baselines.

Runs the job ``--repeats`` times as a user does (its own process; the numba cache as installed:
warm after ``tools/setup_env.sh``, which runs ``emfc-compile-kernels``), once more with an
empty numba cache (``NUMBA_CACHE_DIR`` pointing at a new folder: the first run after a plain
``pip install .`` that skipped ``emfc-compile-kernels``) unless ``--no-cold``, and prints the
phases of ``timing.json``, the process's wall time (interpreter start included) and its CPU
time (user + system of its threads; the plot workers are forked by a fork server the job does
not wait for, so their CPU time is not in it). Baselines measured in the same run:

* the numerical core alone generates and simulates the same excitation (no ROS, no bag);
* the bag of the first run identified in this process the way issue 12 did it
  (``greybox.method: least_squares``: finite-difference Jacobians, the central one of the
  covariance) against the current default (``gauss_newton`` with the linearised Jacobian), and
  its report written with the plots drawn in this process against drawn by the worker pool
  (:mod:`emfc_ros.core.report.background`); the ratios are printed.

    tools/bench.sh bench_experiment --repeats 3
    tools/bench.sh bench_experiment --plan config/experiment_quick.yaml --repeats 3
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from typing import Any, Dict, List, Optional

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('ROS_DOMAIN_ID', str(100 + os.getpid() % 100))

#: The issue's targets for the default plan [s].
TARGET_WARM_S = 5.0
TARGET_FIRST_S = 15.0


def core_baseline(plan_path: Optional[str]) -> dict:
    """Generate and simulate the plan's excitation with the core only."""
    from emfc_ros.core.model.parameters import BalanceParameters
    from emfc_ros.core.paths import config_file
    from emfc_ros.core.run_plan import load_plan
    from emfc_ros.core.signals import experiment_from_config
    from emfc_ros.core.sim.balancing import balancing_load_mass_kg
    from emfc_ros.core.sim.simulator import Simulator

    plan = load_plan(Path(plan_path) if plan_path else config_file('experiment_default.yaml'))
    t0 = time.perf_counter()
    experiment = experiment_from_config(plan.experiment)
    params = BalanceParameters.load_yaml(config_file('balance_default.yaml'))
    load = balancing_load_mass_kg(params, plan.simulator.load_changer_coupled)
    sim = Simulator(params, experiment.sample_rate_Hz, seed=plan.simulator.seed,
                    load_mass_kg=load,
                    load_changer_coupled=plan.simulator.load_changer_coupled)
    t1 = time.perf_counter()
    total = experiment.total_samples
    for first in range(0, total, plan.block_size):
        n = min(plan.block_size, total - first)
        sim.step_block(experiment.block(first, n))
    t2 = time.perf_counter()
    return {'set up': t1 - t0, 'generate and simulate': t2 - t1, 'total': t2 - t0,
            'samples': total}


def run_job(runner: str, plan: Optional[str], env: Dict[str, str]) -> Dict[str, Any]:
    """One run of the job in its own process: timing.json, wall and CPU time."""
    out = Path(tempfile.mkdtemp()) / 'run'
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    result = subprocess.run([runner] + ([plan] if plan else []) + ['-o', str(out)],
                            capture_output=True, text=True, timeout=1800, env=env)
    wall = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if result.returncode != 0:
        print(result.stdout[-2000:], result.stderr[-2000:])
        raise SystemExit(1)
    timing = json.loads((out / 'timing.json').read_text())
    timing['process wall (with interpreter start)'] = wall
    timing['job process CPU (user + system, its threads; not the plot workers)'] = (
        after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return {'timing': timing, 'out': out}


def worker_start_cpu() -> float:
    """CPU time of a plot worker's start: the fork server's imports (its preload), a warm-up."""
    code = ('import time\n'
            't = time.process_time()\n'
            'import emfc_ros.core.report.background\n'
            'import emfc_ros.core.ident.pipeline, emfc_ros.core.report.plots\n'
            'import matplotlib.pyplot\n'
            'from emfc_ros.core.report.background import _warm_up\n'
            '_warm_up()\n'
            'print(time.process_time() - t)\n')
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=300, check=True)
    return float(done.stdout.split()[-1])


def identification_baseline(bag: Path) -> Dict[str, float]:
    """The same bag identified and reported the issue-12 way and the current way."""
    from emfc_ros.core.ident.from_bag import identify_bag
    from emfc_ros.core.report import write_report
    from emfc_ros.core.report.background import PlotPool

    out: Dict[str, float] = {}
    results = {}
    for method in ('least_squares', 'gauss_newton'):
        wall, cpu = time.perf_counter(), time.process_time()
        results[method], _ = identify_bag(bag, {'greybox': {'method': method}},
                                          namespace='/emfc')
        out[f'identify, {method} [s]'] = time.perf_counter() - wall
        out[f'identify, {method}, CPU [s]'] = time.process_time() - cpu
        out[f'identify, {method}, simulations'] = results[method].greybox.fit.n_evaluations
    folder = Path(tempfile.mkdtemp())
    wall = time.perf_counter()
    write_report(results['gauss_newton'], folder / 'in_process')
    out['report, plots in this process [s]'] = time.perf_counter() - wall
    with PlotPool() as pool:
        time.sleep(3.0)                 # the workers' start-up, as during the identification
        wall = time.perf_counter()
        write_report(results['gauss_newton'], folder / 'pool', pool=pool)
        out['report, plots by the worker pool, after their start-up [s]'] = \
            time.perf_counter() - wall
    from emfc_ros.core.report.background import draw, report_jobs
    jobs = report_jobs(results['gauss_newton'], folder / 'figures')
    (folder / 'figures').mkdir()
    cpu = time.process_time()
    for job in jobs:
        draw(job)
    out['figures drawn one after the other, CPU [s]'] = time.process_time() - cpu
    out['figures'] = len(jobs)
    out['plot workers: imports and warm-up (fork server and one worker), CPU [s]'] = \
        worker_start_cpu()
    shutil.rmtree(folder, ignore_errors=True)
    for name in ('c1_Nm_per_rad', 'd1_Nms_per_rad', 'c2_Nm_per_rad', 'd2_Nms_per_rad'):
        a = results['least_squares'].greybox.fit
        b = results['gauss_newton'].greybox.fit
        out[f'{name}: difference / standard error'] = abs(
            a.parameters[name] - b.parameters[name]) / a.standard_errors[name]
        out[f'{name}: standard error ratio'] = (b.standard_errors[name]
                                                / a.standard_errors[name])
    return out


def main(argv=None) -> int:
    """Run the main job and the baselines, print the breakdown."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--plan', default=None, help='run plan (default the shipped one)')
    parser.add_argument('--no-cold', action='store_true',
                        help='skip the run with an empty numba cache')
    parser.add_argument('--no-baseline', action='store_true',
                        help='skip the in-process identification baselines')
    parser.add_argument('--json', default='bench/results/experiment.json')
    args = parser.parse_args(argv)
    runner = shutil.which('emfc-experiment') or str(
        Path(sys.executable).parent / 'emfc-experiment')
    env = dict(os.environ)
    runs: List[Dict[str, Any]] = []
    labels = []
    first_bag = None
    for i in range(args.repeats):
        job = run_job(runner, args.plan, env)
        runs.append(job['timing'])
        labels.append(f'warm {i + 1}')
        if first_bag is None:
            first_bag = Path(tempfile.mkdtemp()) / 'bag'
            shutil.copytree(job['out'] / 'bag', first_bag)
        shutil.rmtree(job['out'].parent, ignore_errors=True)
    if not args.no_cold:
        cache = tempfile.mkdtemp(prefix='numba-cache-')
        job = run_job(runner, args.plan, dict(env, NUMBA_CACHE_DIR=cache))
        runs.append(job['timing'])
        labels.append('empty cache')
        shutil.rmtree(job['out'].parent, ignore_errors=True)
        shutil.rmtree(cache, ignore_errors=True)
    baseline = core_baseline(args.plan)
    phases = list(dict.fromkeys(k for r in runs for k in r))
    print(f'plan: {args.plan or "config/experiment_default.yaml"}')
    print(f'{"phase":<56}' + ''.join(f'{label + " [s]":>18}' for label in labels))
    for phase in phases:
        print(f'{phase:<56}' + ''.join(f'{r.get(phase, float("nan")):18.2f}' for r in runs))
    print(f'baseline, core only ({baseline["samples"]} samples): set up '
          f'{baseline["set up"]:.2f} s, generate and simulate '
          f'{baseline["generate and simulate"]:.2f} s, total {baseline["total"]:.2f} s')
    warm = [r['process wall (with interpreter start)'] for r, label in zip(runs, labels)
            if label.startswith('warm')]
    median = sorted(warm)[len(warm) // 2]
    within = sum(1 for w in warm if w <= TARGET_WARM_S)
    verdict = 'met' if median <= TARGET_WARM_S else 'not met'
    print(f'warm runs, process wall: best {min(warm):.2f} s, median {median:.2f} s (target '
          f'{TARGET_WARM_S:g} s for the default plan: {verdict} by the median, {within} of '
          f'{len(warm)} runs within it)')
    if not args.no_cold:
        cold = runs[-1]['process wall (with interpreter start)']
        print(f'empty numba cache (no emfc-compile-kernels after the install): {cold:.2f} s '
              f'(target {TARGET_FIRST_S:g} s: {"met" if cold <= TARGET_FIRST_S else "not met"};'
              f' after tools/setup_env.sh, which compiles at install, the first run is a warm '
              f'run)')
    ident = {}
    if not args.no_baseline and first_bag is not None:
        ident = identification_baseline(first_bag)
        print('same bag, in this process (baseline: the issue-12 way):')
        for key, value in ident.items():
            print(f'  {key:<62} {value:10.3f}')
        print(f'  ratio identify least_squares / gauss_newton: wall '
              f'{ident["identify, least_squares [s]"] / ident["identify, gauss_newton [s]"]:.2f}'
              f', CPU {ident["identify, least_squares, CPU [s]"]:.2f} / '
              f'{ident["identify, gauss_newton, CPU [s]"]:.2f} s')
        print(f'  ratio report in process / worker pool: '
              f'{ident["report, plots in this process [s]"] / ident["report, plots by the worker pool, after their start-up [s]"]:.2f}')  # noqa: E501
        # What the machine must do for one warm run, whatever the schedule: the job's process,
        # the plot workers' start and the figures; on this many processors no run is shorter.
        cpus = len(os.sched_getaffinity(0))
        job_cpu = sorted(r['job process CPU (user + system, its threads; not the plot workers)']
                         for r, label in zip(runs, labels) if label.startswith('warm'))
        job_cpu_s = job_cpu[len(job_cpu) // 2]
        budget = (job_cpu_s + ident['plot workers: imports and warm-up (fork server and one '
                                    'worker), CPU [s]']
                  + ident['figures drawn one after the other, CPU [s]'])
        print(f'CPU budget of a warm run: job process {job_cpu_s:.2f} s (median) + plot '
              f'workers\' start {ident["plot workers: imports and warm-up (fork server and one worker), CPU [s]"]:.2f} s '  # noqa: E501
              f'+ {ident["figures"]:.0f} figures {ident["figures drawn one after the other, CPU [s]"]:.2f} s '  # noqa: E501
              f'= {budget:.2f} s of CPU; on {cpus} processors no schedule takes less than '
              f'{budget / cpus:.2f} s (target {TARGET_WARM_S:g} s)')
    if first_bag is not None:
        shutil.rmtree(first_bag.parent, ignore_errors=True)
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({'plan': args.plan, 'labels': labels, 'runs': runs,
                               'core_baseline': baseline, 'identification': ident},
                              indent=2))
    print(f'wrote {out}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
