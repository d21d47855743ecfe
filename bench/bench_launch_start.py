"""
The hardware launch with the real ``ros2 launch``: runs without a start fault (issue 27).

Each run is the sequence of the launch file's docstring: ``emfc-device-emulator --port P
--load-mass-kg balance``, the README's recorder of the excitation and the measurements
(started before the launch in even runs, 2 s after it in odd ones), ``ros2 launch emfc_ros
hardware_experiment.launch.py device_port:=P ...`` with the default trajectory (40 s on the
device's clock), Ctrl-C once the generator is done and the recorder has the measured end. The
bag is then read: the device faults in its measurement description (``excitation_start_missing``
is a start fault; ``device_underrun``, ``excitation_late`` and the others are counted too),
whether the recorded excitation begins at sample 0, whether the measurements cover the whole
experiment.

Variants, interleaved run by run (the same-run baseline):

- ``shipped``: the launch file's defaults (start gate ``applier``, two excitation
  subscriptions, consumer pacing, ``excitation_lead_s`` 0.5 s since 2026-12-02, 0.3 s before);
- ``old_gate``: what the file did before issue 27 (``start_gate:=subscribers
  excitation_subscribers:=1 pacing:=wall excitation_lead_s:=0.1``);
- ``lead_<s>``: the shipped file with another ``excitation_lead_s`` (``--leads``).

    ./tools/bench.sh bench_launch_start                       # 10 runs of each variant
    ./tools/bench.sh bench_launch_start --runs 3 --leads 0.1 0.2 --variants shipped
    ./tools/bench.sh bench_launch_start --json bench/results/launch_start.json

Needs the real ROS 2 command line (``tools/setup_env.sh`` installs it from
``../shared/ros2-jazzy-cli``). Target: 10 of 10 shipped runs without a start fault.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from typing import Dict, List

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from emfc_ros.core.bag import read_streams  # noqa: E402

RECORDER = ['ros2', 'run', 'emfc_ros', 'recorder', '--ros-args', '-r', '__ns:=/emfc',
            '-p', 'output:=my_experiment', '-p', 'topics:=[excitation, excitation/description, '
            'measurements, measurements/description]']
PAN = ['load_mass_kg:=0.1274', 'load_changer_coupled:=false']
VARIANTS = {'shipped': [],
            'old_gate': ['start_gate:=subscribers', 'excitation_subscribers:=1',
                         'pacing:=wall', 'excitation_lead_s:=0.1']}
EXPERIMENT_S = 40.0


class Job:
    """A command in a process group of its own, stopped like Ctrl-C in its terminal."""

    def __init__(self, argv: List[str], log: Path, cwd: Path) -> None:
        self.log = log
        self._out = open(log, 'wb')
        self.proc = subprocess.Popen(argv, stdout=self._out, stderr=subprocess.STDOUT,
                                     cwd=cwd, start_new_session=True)

    def text(self) -> str:
        self._out.flush()
        return self.log.read_text(errors='replace')

    def stop(self, timeout_s: float = 30.0) -> int:
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(timeout=10)
        self._out.close()
        return self.proc.returncode


def one_run(k: int, args: List[str], folder: Path) -> Dict[str, object]:
    """One docstring sequence; what the bag says."""
    folder.mkdir(parents=True)
    port = 5600 + k % 300
    emulator = Job(['emfc-device-emulator', '--port', str(port), '--load-mass-kg', 'balance'],
                   folder / 'emulator.log', folder)
    jobs = [emulator]
    deadline = time.monotonic() + 30.0
    while 'listening on' not in emulator.text() and time.monotonic() < deadline:
        time.sleep(0.05)
    launch_argv = ['ros2', 'launch', 'emfc_ros', 'hardware_experiment.launch.py',
                   f'device_port:={port}', *PAN, *args]
    recorder_first = k % 2 == 0
    try:
        if recorder_first:
            jobs.append(Job(RECORDER, folder / 'recorder.log', folder))
            time.sleep(2.0)
        launch = Job(launch_argv, folder / 'launch.log', folder)
        jobs.append(launch)
        if not recorder_first:
            time.sleep(2.0)
            jobs.append(Job(RECORDER, folder / 'recorder.log', folder))
        t0 = time.monotonic()
        while 'experiment done' not in launch.text() and \
                time.monotonic() - t0 < EXPERIMENT_S + 90.0:
            time.sleep(0.2)
        done = 'experiment done' in launch.text()
        time.sleep(3.0)         # the measured end (settle) reaches the recorder
    finally:
        codes = [j.stop() for j in reversed(jobs)]
    out: Dict[str, object] = {'run': k, 'recorder_first': recorder_first, 'done': done,
                              'exit_codes': codes}
    try:
        streams = read_streams(folder / 'my_experiment')
    except Exception as exc:  # noqa: B902 a broken run is a result, not a crash
        out.update({'error': f'{type(exc).__name__}: {exc}', 'faults': ['unreadable bag']})
        return out
    meas = streams.get('/emfc/measurements')
    exc_stream = streams.get('/emfc/excitation')
    extra = meas.description.extra if meas is not None and meas.description else {}
    offset = extra.get('excitation_offset_samples')
    total = 400000
    out['faults'] = [f.get('kind') for f in extra.get('faults', [])]
    out['excitation_from_0'] = exc_stream is not None and exc_stream.first_sample_index == 0
    out['excitation_samples'] = exc_stream.n_samples if exc_stream is not None else 0
    out['measured_whole'] = bool(meas is not None and offset is not None and
                                 meas.first_sample_index + meas.n_samples >= offset + total)
    return out


def summary(results: List[Dict[str, object]]) -> Dict[str, object]:
    """Counts over the runs of one variant."""
    start = sum('excitation_start_missing' in r['faults'] for r in results)
    any_fault = sum(bool(r['faults']) for r in results)
    kinds: Dict[str, int] = {}
    for r in results:
        for kind in r['faults']:
            kinds[kind] = kinds.get(kind, 0) + 1
    return {'runs': len(results), 'start_faults': start, 'runs_with_a_fault': any_fault,
            'clean_runs': sum(not r['faults'] and r['done'] and r['excitation_from_0']
                              and r['measured_whole'] for r in results),
            'excitation_recorded_from_0': sum(bool(r['excitation_from_0']) for r in results),
            'fault_kinds': kinds}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--runs', type=int, default=10)
    parser.add_argument('--variants', nargs='*', default=['shipped', 'old_gate'])
    parser.add_argument('--leads', nargs='*', type=float, default=[],
                        help='extra shipped variants with this excitation_lead_s [s]')
    parser.add_argument('--json', type=Path)
    parser.add_argument('--keep', type=Path, help='keep the runs in this folder')
    args = parser.parse_args()
    if shutil.which('ros2') is None:
        print('bench_launch_start: the real ros2 command line is not installed '
              '(tools/setup_env.sh installs it from ../shared/ros2-jazzy-cli)', file=sys.stderr)
        return 2
    variants = {name: VARIANTS[name] for name in args.variants}
    for lead in args.leads:
        variants[f'lead_{lead:g}'] = [f'excitation_lead_s:={lead:g}']
    base = args.keep or Path(tempfile.mkdtemp(prefix='bench_launch_start_'))
    results: Dict[str, List[Dict[str, object]]] = {name: [] for name in variants}
    k = 0
    for run in range(args.runs):
        for name, extra in variants.items():
            result = one_run(k, extra, base / f'{name}_{run}')
            k += 1
            results[name].append(result)
            print(f'{name} run {run}: faults {result["faults"]}, excitation from 0: '
                  f'{result.get("excitation_from_0")}, whole measured: '
                  f'{result.get("measured_whole")}, exits {result["exit_codes"]}', flush=True)
    report = {name: summary(rs) for name, rs in results.items()}
    for name, s in report.items():
        print(f'{name}: {s["clean_runs"]} of {s["runs"]} clean, {s["start_faults"]} with a '
              f'start fault, faults {s["fault_kinds"]}, excitation recorded from 0 in '
              f'{s["excitation_recorded_from_0"]}')
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({'summary': report, 'runs': results}, indent=1))
    if not args.keep:
        shutil.rmtree(base, ignore_errors=True)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
