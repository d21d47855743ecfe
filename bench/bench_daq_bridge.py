"""
Sustained rate, CPU and latency of the daq_bridge node on the udp and daqmx back-ends.

Three processes per run: the device (``emfc-device-emulator`` for udp, four input channels,
or ``emfc-daqmx-emulator`` for daqmx, NI's gRPC service on loopback; each its own process,
paced by its real-time sample clock), the daq_bridge node (its own process, ``backend: udp``
or ``daqmx``, only the ``measurements`` stream, no joint states) and this benchmark, which
subscribes to ``measurements`` and checks every block's sample index. The daqmx runs stream
2 AO and read 4 AI on one clock (the back-end always writes its outputs). The
bridge's publisher and this subscriber keep ``--depth`` blocks (1000: a second at 1000
blocks/s), so that the burst after a stall of the shared machine does not overrun them.

Per sample rate, for ``--seconds`` after the first block: samples received, published gaps,
back-end gaps, the achieved rate, the CPU of the bridge process (``/proc/<pid>/stat``) and
three latencies:

- ``arrival->publish``: inside the bridge, from the moment its reader thread got the block
  from the back-end (``read_block`` returned, the frame decoded and scaled) to the return of
  ``publish`` (the bridge's ``arrival_to_publish_*_us`` diagnostics, last 20000 blocks);
- ``age@publish``: how old the block's last sample was when the bridge had published it:
  ``t_publish - (t_START + end_index / rate)``, with ``t_START`` the bridge's monotonic time
  when the device's START answer arrived (the device sends a frame when its last sample is
  due, so this is transport plus bridge; it is low by about half a request round trip);
- ``age@subscriber``: the same age at this process's subscription callback (CLOCK_MONOTONIC is
  shared by the processes of one host; ``t_START`` comes in the description's
  ``extra.start_monotonic_ns``), so ``age@subscriber - age@publish`` is DDS delivery.

A rate is "sustained" when every block arrived here contiguous, the back-end declared no gap,
the achieved rate is within 1 % of the nominal one and the last block was less than 0.5 s old
(the bridge did not fall behind). The sweep runs the target (300 kS/s,
the paper's rate) first, then upward until a rate is not sustained.

Baseline in the same run: the back-end read directly in this process, no ROS (same
emulator set-up): the rate and the age at ``read_block`` return without the ROS layer. For
daqmx the baseline also streams setpoint blocks and measures the end-to-end latency from
writing an excitation block (at the earliest sample the back-end still accepts) to the return
of the measurement block that holds its first sample (``excitation->measurement``).

    python bench/bench_daq_bridge.py --seconds 60
    python bench/bench_daq_bridge.py --seconds 10 --rates 300000,600000,1000000
    python bench/bench_daq_bridge.py --seconds 10 --backends daqmx --rates 10000,100000,300000
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import time
from typing import Dict, List, Optional

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('ROS_DOMAIN_ID', str(140 + os.getpid() % 10))

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
TICKS = os.sysconf('SC_CLK_TCK')
INPUTS = ['coil_setpoint_V', 'coil_current_A', 'sensor_V', 'position_m']


def cpu_seconds(pid: int) -> float:
    """CPU time (user + system) of a process so far [s]."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


def _env() -> dict:
    return dict(os.environ, PYTHONUNBUFFERED='1',
                PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get('PYTHONPATH', '')]))


def start_emulator(kind: str = 'udp') -> tuple:
    """Start ``emfc-device-emulator --port 0`` (or ``emfc-daqmx-emulator``); read the port."""
    if kind == 'daqmx':
        args = [sys.executable, '-m', 'emfc_ros.cli.daqmx_emulator', '--listen',
                '127.0.0.1:0', '--seed', '0']
    else:
        args = [sys.executable, '-m', 'emfc_ros.cli.device_emulator', '--port', '0',
                '--channels', str(len(INPUTS)), '--seed', '0']
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, env=_env(), cwd=REPO)
    line = proc.stdout.readline().decode().strip()
    if not line.isdigit():
        stop(proc)
        raise RuntimeError(f'emulator did not print its port: {line!r}')
    return proc, int(line)


def stop(proc: subprocess.Popen, timeout_s: float = 10.0) -> None:
    """Interrupt a process we started, kill it if it does not end."""
    if proc.poll() is None:
        proc.send_signal(2)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout_s)


def percentiles_us(values_ns: List[int]) -> Dict[str, float]:
    """Median and 99th percentile [us]."""
    if not values_ns:
        return {'median_us': float('nan'), 'p99_us': float('nan')}
    arr = np.asarray(values_ns, dtype=np.float64) / 1e3
    return {'median_us': round(float(np.median(arr)), 1),
            'p99_us': round(float(np.percentile(arr, 99)), 1)}


def baseline(rate: float, block: int, seconds: float, kind: str = 'udp') -> dict:
    """The back-end read directly, no ROS: rate, gaps and sample age at read return."""
    from emfc_ros.core.device import create_backend, default_device_config
    emulator, port = start_emulator(kind)
    if kind == 'daqmx':
        backend = create_backend('daqmx', grpc_address=f'127.0.0.1:{port}')
    else:
        backend = create_backend('udp', device_address=('127.0.0.1', port))
    written: Dict[int, int] = {}        # first sample of an excitation block -> write time
    latencies: List[int] = []
    try:
        backend.configure(default_device_config(rate, block, INPUTS))
        backend.start()
        anchor = time.monotonic_ns()
        ages: List[int] = []
        samples = 0
        expected = None
        holes = 0
        first_t = None
        next_write = None
        cpu0 = time.process_time()
        while True:
            got = backend.read_block(timeout_s=1.0)
            now = time.monotonic_ns()
            if got is None:
                break
            if first_t is None:
                first_t = now
                cpu0 = time.process_time()
            elif now - first_t > seconds * 1e9:
                break
            ages.append(now - anchor - int(got.end_index * 1e9 / rate))
            if expected is not None and got.first_sample_index != expected:
                holes += 1
            expected = got.end_index
            samples += got.n_samples
            if kind == 'daqmx':
                for k in [k for k in written if got.first_sample_index <= k < got.end_index]:
                    latencies.append(now - written.pop(k))
                # the next excitation block at the earliest sample still accepted
                horizon = backend._ao_end + block
                start = horizon if next_write is None else max(next_write, horizon)
                written[start] = time.monotonic_ns()
                backend.write_setpoints(start, np.zeros((2, block)))
                next_write = start + block
        elapsed = (time.monotonic_ns() - first_t) * 1e-9 if first_t else 0.0
        cpu = time.process_time() - cpu0
        health = backend.health()
    finally:
        backend.close()
        stop(emulator)
    achieved = samples / elapsed if elapsed else 0.0
    faults = backend.take_faults() if kind == 'daqmx' else []
    ok = holes == 0 and health['gaps'] == 0 and achieved >= 0.99 * rate and not faults
    out = {'path': f'{kind} back-end, no ROS (baseline)', 'backend': kind, 'rate_Hz': rate,
           'seconds': elapsed, 'samples': samples, 'achieved_rate_Hz': round(achieved, 1),
           'gaps': holes, 'backend_gaps': health['gaps'], 'sustained': ok,
           'cpu_percent': round(100.0 * cpu / elapsed, 1) if elapsed else float('nan'),
           'age_at_read': percentiles_us(ages)}
    if kind == 'daqmx':
        out.update({'excitation_to_measurement': percentiles_us(latencies),
                    'faults': [f[2] for f in faults],
                    'daqmx_errors': health.get('daqmx_errors', 0)})
    return out


def through_bridge(rate: float, block: int, seconds: float, depth: int,
                   kind: str = 'udp') -> dict:
    """Emulator -> bridge process -> this process, over DDS."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile
    from std_msgs.msg import Float64MultiArray, String

    from emfc_ros.nodes.convert import BLOCK_QOS, LATCHED_QOS, msg_to_description

    emulator, port = start_emulator(kind)
    ns = f'/bench{os.getpid()}'
    device = ['-p', 'backend:=udp', '-p', f'udp.device_port:={port}'] if kind == 'udp' else \
        ['-p', 'backend:=daqmx', '-p', f'daqmx.grpc_address:=127.0.0.1:{port}']
    args = [sys.executable, '-m', 'emfc_ros.nodes.daq_bridge', '--ros-args', '-r',
            f'__ns:={ns}', *device,
            '-p', f'sample_rate_Hz:={rate}', '-p', f'block_size:={block}',
            '-p', f'inputs:=[{",".join(INPUTS)}]', '-p', 'publish_groups:=false',
            '-p', 'state_rate_Hz:=0.0', '-p', 'diagnostics_period_s:=1.0',
            '-p', f'publisher_depth:={depth}',
            '--log-level', 'warn']
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('bench_subscriber', context=context, namespace=ns)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    state = {'anchor': None, 'diag': {}, 'blocks': [], 'first_t': None}

    def on_block(msg):
        now = time.monotonic_ns()
        data = msg.data
        n = msg.layout.dim[1].size
        state['blocks'].append((int(data[0]), int(data[2]), n, now))
        if state['first_t'] is None:
            state['first_t'] = now

    def on_description(msg):
        state['anchor'] = msg_to_description(msg).extra.get('start_monotonic_ns')

    def on_diag(msg):
        for status in msg.status:
            if status.hardware_id == f'{ns}/daq_bridge':
                state['diag'] = {kv.key: kv.value for kv in status.values}

    qos = QoSProfile(history=BLOCK_QOS.history, depth=depth,
                     reliability=BLOCK_QOS.reliability, durability=BLOCK_QOS.durability)
    node.create_subscription(Float64MultiArray, 'measurements', on_block, qos)
    node.create_subscription(String, 'measurements/description', on_description, LATCHED_QOS)
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 10)
    bridge = subprocess.Popen(args, env=_env(), cwd=REPO)
    result: dict = {'path': f'{kind}: emulator -> daq_bridge -> subscriber (DDS)',
                    'backend': kind, 'rate_Hz': rate}
    window: list = []
    try:
        deadline = time.monotonic() + 30.0
        while state['first_t'] is None and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        if state['first_t'] is None:
            raise RuntimeError('no block from the bridge within 30 s')
        warm = time.monotonic() + 2.0             # discovery backlog, emulator catch-up
        while time.monotonic() < warm:
            executor.spin_once(timeout_sec=0.05)
        state['blocks'].clear()
        state['first_t'] = time.monotonic_ns()
        cpu0 = cpu_seconds(bridge.pid)
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            executor.spin_once(timeout_sec=0.05)
        cpu = cpu_seconds(bridge.pid) - cpu0
        elapsed = (time.monotonic_ns() - state['first_t']) * 1e-9
        window = list(state['blocks'])            # not what arrives while we wait below
        # the diagnostics that cover the window
        state['diag'] = {}
        deadline = time.monotonic() + 5.0
        while not state['diag'] and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
    finally:
        stop(bridge)
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
        rclpy.try_shutdown(context=context)
        stop(emulator)
    blocks = window
    holes = sum(1 for a, b in zip(blocks, blocks[1:])
                if a[1] == b[1] and b[0] != a[0] + a[2])
    epochs = len({b[1] for b in blocks})
    samples = sum(b[2] for b in blocks)
    achieved = samples / elapsed if elapsed else 0.0
    anchor = state['anchor']
    ages = [t - anchor - int((f + n) * 1e9 / rate) for f, _, n, t in blocks] if anchor else []
    diag = state['diag']
    backend_gaps = int(diag.get('gaps', -1))
    final_age_ms = ages[-1] / 1e6 if ages else float('nan')
    ok = bool(blocks) and holes == 0 and epochs == 1 and backend_gaps == 0 and \
        int(diag.get('blocks_overflowed', 0)) == 0 and achieved >= 0.99 * rate and \
        final_age_ms < 500.0 and str(diag.get('faults', 'none')) in ('none', '0', '')
    result.update({
        'seconds': round(elapsed, 2), 'samples': samples, 'blocks': len(blocks),
        'achieved_rate_Hz': round(achieved, 1), 'gaps': holes, 'epochs': epochs,
        'backend_gaps': backend_gaps, 'sustained': ok,
        'bridge_cpu_percent': round(100.0 * cpu / elapsed, 1) if elapsed else float('nan'),
        'arrival_to_publish': {
            'median_us': float(diag.get('arrival_to_publish_median_us', 'nan')),
            'p99_us': float(diag.get('arrival_to_publish_p99_us', 'nan'))},
        'age_at_publish': {
            'median_us': float(diag.get('sample_age_at_publish_median_us', 'nan')),
            'p99_us': float(diag.get('sample_age_at_publish_p99_us', 'nan'))},
        'age_at_subscriber': percentiles_us(ages), 'final_age_ms': round(final_age_ms, 2),
        'bridge_diagnostics': {k: diag.get(k) for k in (
            'frames_received', 'corrupt', 'duplicates', 'reordered', 'late',
            'heartbeat_misses', 'reconnects', 'published_blocks', 'latency_blocks',
            'faults', 'daqmx_errors')}})
    return result


def _fmt(x: Optional[dict], key: str) -> str:
    if not x or key not in x:
        return '-'
    v = x[key]
    return f'{v["median_us"]:.0f}/{v["p99_us"]:.0f}'


def main(argv: Optional[List[str]] = None) -> int:
    """Run the sweep, print the table, write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=60.0,
                        help='measured seconds per rate (default 60)')
    parser.add_argument('--rates', default='300000,600000,1000000,1500000,2000000',
                        help='sample rates to try in order [Hz]; the sweep stops at the '
                             'first rate that is not sustained')
    parser.add_argument('--block-size', type=int, default=1000, help='samples per block')
    parser.add_argument('--depth', type=int, default=1000,
                        help='history depth of the bridge publisher and of this subscriber '
                             '[blocks] (the bridge default is 100)')
    parser.add_argument('--backends', default='udp,daqmx',
                        help='back-ends to sweep, in order (default udp,daqmx)')
    parser.add_argument('--json', default=str(REPO / 'bench' / 'results' / 'daq_bridge.json'))
    args = parser.parse_args(argv)
    rates = [float(r) for r in args.rates.split(',') if r]
    runs = []
    best = {}
    for kind in [k for k in args.backends.split(',') if k]:
        best[kind] = {'bridge': 0.0, 'baseline': 0.0}
        for rate in rates:
            base = baseline(rate, args.block_size, args.seconds, kind)
            runs.append(base)
            print(json.dumps(base), flush=True)
            ros = through_bridge(rate, args.block_size, args.seconds, args.depth, kind)
            runs.append(ros)
            print(json.dumps(ros), flush=True)
            if base['sustained']:
                best[kind]['baseline'] = max(best[kind]['baseline'], rate)
            if ros['sustained']:
                best[kind]['bridge'] = max(best[kind]['bridge'], rate)
            if not ros['sustained']:
                break
    header = (f'{"path":44} {"rate kS/s":>9} {"got kS/s":>9} {"gaps":>4} {"ok":>3} '
              f'{"CPU %":>6} {"arr->pub us":>12} {"age@pub us":>11} {"age@sub us":>11}')
    print()
    print(header)
    print('-' * len(header))
    for r in runs:
        cpu = r.get('bridge_cpu_percent', r.get('cpu_percent'))
        age_pub = _fmt(r, 'age_at_publish') if 'age_at_publish' in r else \
            _fmt(r, 'age_at_read')
        print(f'{r["path"][:44]:44} {r["rate_Hz"] / 1e3:9.0f} {r["achieved_rate_Hz"] / 1e3:9.1f} '
              f'{r["gaps"] + max(0, r["backend_gaps"]):4d} {"yes" if r["sustained"] else "no":>3} '
              f'{cpu:6.1f} {_fmt(r, "arrival_to_publish"):>12} {age_pub:>11} '
              f'{_fmt(r, "age_at_subscriber"):>11}')
    for kind, b in best.items():
        print(f'\n{kind}: highest sustained rate: bridge {b["bridge"] / 1e3:.0f} kS/s, '
              f'baseline {b["baseline"] / 1e3:.0f} kS/s ({len(INPUTS)} channels, blocks of '
              f'{args.block_size}, {args.seconds:.0f} s per rate); latencies are median/p99')
    for r in runs:
        if 'excitation_to_measurement' in r:
            print(f'{r["path"]} at {r["rate_Hz"] / 1e3:.0f} kS/s: excitation->measurement '
                  f'{_fmt(r, "excitation_to_measurement")} us')
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({'channels': INPUTS, 'block_size': args.block_size,
                               'history_depth_blocks': args.depth,
                               'seconds_per_rate': args.seconds,
                               'highest_sustained_rate_Hz': best, 'runs': runs}, indent=2))
    print(f'wrote {out}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
