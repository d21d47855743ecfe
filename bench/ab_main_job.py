"""
What each part of the main job costs on its critical path (the job without that part).

Each variant is ``emfc-experiment`` with the shipped plan in a process of its own, as a user
runs it (``console_main``), the variants interleaved round by round so that a slow spell of a
shared VM hits all alike. The variants leave out, in the child process only:

- ``no_greybox_figures``: the 15 figures of the grey-box fit (Bode diagrams with the model,
  time series, residual analyses, pole-zero map); the coherence and static figures stay;
- ``probe_in_line``: the frequency-domain fit's probe for a second optimum (four restarts)
  run in the job's own process before the time-domain fit, as before issue 14's seventh
  round, instead of in a plot worker during it (the same-run baseline of that change);
- ``no_systematic``: the grey-box's type B propagation left out (issue 28: every known input
  treated as exact), the same-run baseline of its cost (target: shipped <= 1.1 of it);
- ``file_ratio``: the load changer's force scale not fitted (``greybox.free`` as before
  issue 28 made the force constants' ratio a default), the same-run baseline of that change.

A variant is a measurement of where the time goes, never a way to run the job
(``no_greybox_figures`` leaves its report incomplete). Printed per variant: the process wall time
(median, range) and, for every run, the machine's busy CPU time over the run from
``/proc/stat`` (every process, the plot workers included; the machine should be otherwise
idle)::

    tools/bench.sh ab_main_job --rounds 5
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from typing import Dict, List, Tuple

VARIANTS = ('shipped', 'no_greybox_figures', 'probe_in_line', 'no_systematic', 'file_ratio')

CHILD = r"""
import sys


def main():
    variant, out = sys.argv[1], sys.argv[2]
    if variant == 'probe_in_line':
        from emfc_ros.core.report import background

        def refuse(*args, **kwargs):
            raise RuntimeError('probe in line (bench variant)')

        background.PlotPool.submit_task = refuse
    elif variant == 'no_systematic':
        from emfc_ros.core.ident import balance_fit
        balance_fit.components = lambda *args, **kwargs: []
    elif variant == 'file_ratio':
        import dataclasses

        from emfc_ros.core.ident import balance_fit
        fit_balance = balance_fit.fit_balance

        def without_scale(setting, channels, sections, frf_jobs, modes, anti, gcfg, *args,
                          **kwargs):
            free = tuple(n for n in gcfg.free if n != 'load_changer_force_scale')
            return fit_balance(setting, channels, sections, frf_jobs, modes, anti,
                               dataclasses.replace(gcfg, free=free), *args, **kwargs)

        balance_fit.fit_balance = without_scale
    elif variant == 'no_greybox_figures':
        from emfc_ros.core.report import background, writer
        step_jobs, report_jobs = background.step_jobs, background.report_jobs

        def no_step_jobs(step, result, out):
            return [] if step.startswith('greybox_') else step_jobs(step, result, out)

        def no_report_jobs(*args, **kwargs):
            return [j for j in report_jobs(*args, **kwargs)
                    if j.kind in ('coherence', 'static')]

        background.step_jobs = no_step_jobs
        writer.report_jobs = background.report_jobs = no_report_jobs
    sys.argv = ['emfc-experiment', '-o', out]
    from emfc_ros.cli.experiment import console_main
    console_main()


# the plot workers' fork server imports this file as its main module: it must not run the job
if __name__ == '__main__':
    main()
"""


def busy_cpu_s() -> float:
    """Busy CPU time of the whole machine since boot [s] (``/proc/stat``)."""
    with open('/proc/stat') as fh:
        fields = [int(v) for v in fh.readline().split()[1:]]
    user, nice, system, _idle, _iowait, irq, softirq, steal = fields[:8]
    return (user + nice + system + irq + softirq + steal) / os.sysconf('SC_CLK_TCK')


def run(variant: str, workdir: Path) -> Tuple[float, float, int]:
    """One run of a variant: (wall [s], busy CPU of the machine [s], exit code)."""
    out = workdir / f'{variant}-{time.monotonic_ns()}'
    script = workdir / 'child.py'
    if not script.exists():
        script.write_text(CHILD)
    cpu, wall = busy_cpu_s(), time.perf_counter()
    done = subprocess.run([sys.executable, str(script), variant, str(out)],
                          capture_output=True, text=True, timeout=600)
    wall, cpu = time.perf_counter() - wall, busy_cpu_s() - cpu
    if done.returncode != 0:
        print(f'{variant}: exit {done.returncode}\n{done.stderr[-2000:]}', file=sys.stderr)
    shutil.rmtree(out, ignore_errors=True)
    return wall, cpu, done.returncode


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0].strip())
    parser.add_argument('--rounds', type=int, default=5, help='runs of each variant')
    parser.add_argument('--variants', nargs='*', choices=VARIANTS[1:], default=VARIANTS[1:],
                        help='the variants to compare with shipped (default all)')
    args = parser.parse_args(argv)
    variants = ('shipped',) + tuple(args.variants)
    workdir = Path(tempfile.mkdtemp(prefix='ab_main_job-'))
    results: Dict[str, List[Tuple[float, float, int]]] = {v: [] for v in variants}
    try:
        run('shipped', workdir)             # numba's cache and the page cache warm
        for k in range(args.rounds):
            order = variants if k % 2 == 0 else variants[::-1]
            for variant in order:
                results[variant].append(run(variant, workdir))
                wall, cpu, rc = results[variant][-1]
                print(f'round {k + 1} {variant:20s} wall {wall:5.2f} s  machine CPU '
                      f'{cpu:5.2f} s  exit {rc}', flush=True)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    print(f'\n{os.cpu_count()} processors, {args.rounds} rounds, interleaved')
    failed = 0
    for variant, rows in results.items():
        walls = [w for w, _, _ in rows]
        cpus = [c for _, c, _ in rows]
        failed += sum(1 for _, _, rc in rows if rc != 0)
        print(f'{variant:20s} wall median {statistics.median(walls):5.2f} s '
              f'({min(walls):.2f}-{max(walls):.2f}), machine CPU median '
              f'{statistics.median(cpus):5.2f} s ({min(cpus):.2f}-{max(cpus):.2f})')
    base = statistics.median(w for w, _, _ in results['shipped'])
    for variant in variants[1:]:
        other = statistics.median(w for w, _, _ in results[variant])
        print(f'{variant}: {base - other:+.2f} s of the shipped median wall '
              f'({other / base:.2f} of it)')
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
