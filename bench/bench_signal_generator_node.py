"""
Sustained publish rate of the signal_generator node to a subscriber in another process.

The node runs as its own process (started like ``ros2 run emfc_ros signal_generator``),
paced to the wall clock, publishing two channels (a chirp on the coil, a PRBS on the load
changer). This process subscribes, checks every block's sample index (no gap, no
duplicate, no reordering) and measures the received rate and the node's CPU time.

Baseline, in the same run: a minimal rclpy publisher process that sends prebuilt messages
of the same size at the same pacing (the DDS and rclpy ceiling without signal generation).

First the target: 300 kS/s for 60 s (``--target-seconds``). Then a sweep of higher rates
with shorter runs, up to the first rate with a gap or a shortfall, to report the highest
rate with no gap.

    tools/bench.sh bench_signal_generator_node --json bench/results/signal_generator_node.json
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time

import numpy as np

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('ROS_DOMAIN_ID', str(100 + os.getpid() % 100))

TICKS = os.sysconf('SC_CLK_TCK')


def cpu_seconds(pid: int) -> float:
    """CPU time (user + system) of a process so far [s]."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


def experiment_yaml(rate: float, seconds: float) -> str:
    """Write the benchmark experiment: chirp on the coil, PRBS on the load changer."""
    doc = {'experiment': {
        'sample_rate_Hz': rate, 'sections': ['bench'],
        'section': {'bench': {
            'duration_s': seconds,
            'coil': {'signals': {'sweep': {
                'type': 'chirp', 'amplitude_V': 0.01, 'f_start_Hz': 1.0,
                'f_stop_Hz': rate / 4, 'sweep_time_s': seconds, 'method': 'logarithmic'}}},
            'load_changer': {'signals': {'prbs': {
                'type': 'prbs', 'order': 15, 'hold_samples': 1, 'low_V': -0.1,
                'high_V': 0.1}}}}}}}
    import yaml
    handle = tempfile.NamedTemporaryFile('w', suffix='.yaml', delete=False)
    yaml.safe_dump(doc, handle)
    handle.close()
    return handle.name


def raw_publisher(rate: float, block: int, seconds: float) -> int:
    """Baseline publisher: prebuilt 2-channel blocks, paced like the node."""
    import rclpy
    from std_msgs.msg import Float64MultiArray
    from std_srvs.srv import Trigger

    from emfc_ros.core.pacing import ClockPacer
    from emfc_ros.nodes.convert import BLOCK_QOS, BlockMessageBuilder

    rclpy.init()
    node = rclpy.create_node('signal_generator')
    pub = node.create_publisher(Float64MultiArray, 'excitation', BLOCK_QOS)
    state = {'start': None}

    def on_start(request, response):
        state['start'] = time.monotonic()
        response.success = True
        return response

    node.create_service(Trigger, '~/start', on_start)
    samples = np.random.default_rng(0).normal(size=(2, block))
    builder = BlockMessageBuilder()
    total = int(round(rate * seconds))
    index = 0
    deadline = time.monotonic() + seconds + 60
    while index < total and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.001)
        if state['start'] is None:
            continue
        pacer = state.setdefault('pacer', ClockPacer(rate, block, 2, state['start']))
        allowed = min(total, pacer.allowed_index(time.monotonic()))
        while index < allowed:
            n = min(block, total - index)
            pub.publish(builder.build(index, rate, 1, samples[:, :n]))
            index += n
    time.sleep(0.5)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def measure(kind: str, rate: float, block: int, seconds: float) -> dict:
    """Run one producer process at one rate and receive its stream here."""
    import rclpy
    from std_msgs.msg import Float64MultiArray
    from std_srvs.srv import Trigger

    from emfc_ros.core.blocks import SequenceTracker
    from emfc_ros.nodes.convert import BLOCK_QOS, msg_to_block

    # The node wrapper runs `python3` from PATH, as in an activated virtual environment.
    env = dict(os.environ, PYTHONUNBUFFERED='1',
               PATH=os.pathsep.join([str(Path(sys.executable).parent), os.environ['PATH']]))
    if kind == 'node':
        wrapper = Path(sys.prefix) / 'lib' / 'emfc_ros' / 'signal_generator'
        path = experiment_yaml(rate, seconds)
        argv = [str(wrapper), '--ros-args', '-p', f'experiment_file:={path}',
                '-p', f'block_size:={block}', '-p', 'pacing:=wall', '-p', 'autostart:=false',
                '--log-level', 'warn']
    else:
        argv = [sys.executable, __file__, '--role', 'raw-publisher', '--rate', str(rate),
                '--block', str(block), '--seconds', str(seconds)]
    proc = subprocess.Popen(argv, env=env)
    rclpy.init()
    node = rclpy.create_node('bench_subscriber')
    tracker = SequenceTracker()
    got = {'samples': 0, 'first_t': None, 'last_t': None}

    def on_block(msg):
        b = msg_to_block(msg)
        tracker.observe(b.first_sample_index, b.n_samples, b.epoch)
        now = time.monotonic()
        got['first_t'] = got['first_t'] or now
        got['last_t'] = now
        got['samples'] += b.n_samples

    node.create_subscription(Float64MultiArray, 'excitation', on_block, BLOCK_QOS)
    client = node.create_client(Trigger, 'signal_generator/start')
    total = int(round(rate * seconds))
    result = {'producer': kind, 'rate_S_per_s': rate, 'block_size': block,
              'seconds': seconds, 'expected_samples': total}
    try:
        t0 = time.monotonic()
        while (not client.service_is_ready() or node.count_publishers('excitation') < 1) \
                and time.monotonic() - t0 < 20:
            rclpy.spin_once(node, timeout_sec=0.05)
        cpu0 = cpu_seconds(proc.pid)
        future = client.call_async(Trigger.Request())
        t_start = time.monotonic()
        deadline = t_start + seconds * 1.5 + 10
        while got['samples'] < total and time.monotonic() < deadline and proc.poll() is None:
            rclpy.spin_once(node, timeout_sec=0.05)
        wall = time.monotonic() - t_start
        cpu = cpu_seconds(proc.pid) - cpu0 if proc.poll() is None else float('nan')
        span = (got['last_t'] - t_start) if got['last_t'] else float('nan')
        result.update(tracker.counters())
        result.update({
            'started': bool(future.done() and future.result().success),
            'received_samples': got['samples'],
            'wall_s': wall, 'received_rate_S_per_s': got['samples'] / span if span else 0.0,
            'producer_cpu_fraction_of_one_core': cpu / wall,
            'no_gap': tracker.gaps == 0 and tracker.duplicates == 0 and
            tracker.reordered == 0 and got['samples'] == total,
            # Sustained: everything arrived within 5 % of the stream's own duration.
            'sustained': got['samples'] == total and span <= seconds * 1.05 + 0.05,
        })
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        if proc.poll() is None:
            proc.send_signal(2)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=10)
    return result


def main(argv=None) -> int:
    """Run the benchmark and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--role', default='bench', choices=['bench', 'raw-publisher'])
    parser.add_argument('--rate', type=float, default=300000.0)
    parser.add_argument('--block', type=int, default=1000)
    parser.add_argument('--seconds', type=float, default=60.0)
    parser.add_argument('--target-seconds', type=float, default=60.0,
                        help='duration of the run at the target rate [s]')
    parser.add_argument('--sweep-seconds', type=float, default=10.0,
                        help='duration of each run of the upward sweep [s]')
    parser.add_argument('--sweep', default='600000,1200000,2400000,4800000',
                        help='rates of the sweep [S/s], comma separated')
    parser.add_argument('--json', default='bench/results/signal_generator_node.json')
    args = parser.parse_args(argv)
    if args.role == 'raw-publisher':
        try:
            return raw_publisher(args.rate, args.block, args.seconds)
        except KeyboardInterrupt:   # the benchmark ends us with SIGINT when it has all
            return 0

    runs = []
    for kind in ('raw', 'node'):
        runs.append(measure(kind, args.rate, args.block, args.target_seconds))
    for rate in [float(r) for r in args.sweep.split(',') if r]:
        pair = [measure(kind, rate, args.block, args.sweep_seconds) for kind in ('raw', 'node')]
        runs += pair
        if not (pair[1]['no_gap'] and pair[1]['sustained']):
            break
    best = {kind: max([r['rate_S_per_s'] for r in runs if r['producer'] == kind
                       and r['no_gap'] and r['sustained']], default=0.0)
            for kind in ('raw', 'node')}
    print(f'{"producer":>8} {"rate kS/s":>10} {"s":>5} {"received":>10} {"gaps":>5} '
          f'{"dup":>4} {"reord":>5} {"recv kS/s":>10} {"CPU %":>6} {"ok":>3}')
    for r in runs:
        print(f'{r["producer"]:>8} {r["rate_S_per_s"] / 1e3:10.0f} {r["seconds"]:5.0f} '
              f'{r["received_samples"]:10d} {r["gaps"]:5d} {r["duplicates"]:4d} '
              f'{r["reordered"]:5d} {r["received_rate_S_per_s"] / 1e3:10.1f} '
              f'{100 * r["producer_cpu_fraction_of_one_core"]:6.1f} '
              f'{"yes" if r["no_gap"] and r["sustained"] else "NO":>3}')
    print(f'highest rate with no gap and sustained, 2 channels, {args.block}-sample blocks: '
          f'node {best["node"] / 1e3:.0f} kS/s, raw publisher baseline '
          f'{best["raw"] / 1e3:.0f} kS/s (sweep stops at the first failing rate)')
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({'runs': runs, 'highest_no_gap_S_per_s': best,
                               'target_S_per_s': 300000.0}, indent=2))
    print(f'wrote {out}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
