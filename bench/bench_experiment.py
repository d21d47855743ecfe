"""
Wall time of the main job (``emfc-experiment`` with the shipped plan), broken down by phase.

Baseline in the same run: the same excitation generated and simulated by the numerical core
alone (no ROS, no bag), which is the floor the ROS plumbing adds to.

    tools/bench.sh bench_experiment --repeats 2
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import shutil
import subprocess
import sys
import tempfile
import time

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('ROS_DOMAIN_ID', str(100 + os.getpid() % 100))


def core_baseline() -> dict:
    """Generate and simulate the default plan's excitation with the core only."""
    from emfc_ros.core.model.parameters import BalanceParameters
    from emfc_ros.core.paths import config_file
    from emfc_ros.core.run_plan import load_plan
    from emfc_ros.core.signals import experiment_from_config
    from emfc_ros.core.sim.balancing import balancing_load_mass_kg
    from emfc_ros.core.sim.simulator import Simulator

    plan = load_plan(config_file('experiment_default.yaml'))
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


def main(argv=None) -> int:
    """Run the main job and the baseline, print the breakdown."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--repeats', type=int, default=2)
    parser.add_argument('--json', default='bench/results/experiment.json')
    args = parser.parse_args(argv)
    runner = shutil.which('emfc-experiment') or str(
        Path(sys.executable).parent / 'emfc-experiment')
    runs = []
    for i in range(args.repeats):
        out = Path(tempfile.mkdtemp()) / 'run'
        t0 = time.monotonic()
        result = subprocess.run([runner, '-o', str(out)], capture_output=True, text=True,
                                timeout=1800)
        wall = time.monotonic() - t0
        if result.returncode != 0:
            print(result.stdout[-2000:], result.stderr[-2000:])
            return 1
        timing = json.loads((out / 'timing.json').read_text())
        timing['process wall (with interpreter start)'] = wall
        runs.append(timing)
        shutil.rmtree(out.parent, ignore_errors=True)
    baseline = core_baseline()
    phases = list(runs[0])
    print(f'{"phase":<40}' + ''.join(f'{"run " + str(i + 1) + " [s]":>12}'
                                     for i in range(len(runs))))
    for phase in phases:
        print(f'{phase:<40}' + ''.join(f'{r.get(phase, float("nan")):12.2f}' for r in runs))
    print(f'baseline, core only ({baseline["samples"]} samples): set up '
          f'{baseline["set up"]:.2f} s, generate and simulate '
          f'{baseline["generate and simulate"]:.2f} s, total {baseline["total"]:.2f} s')
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({'runs': runs, 'core_baseline': baseline}, indent=2))
    print(f'wrote {out}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
