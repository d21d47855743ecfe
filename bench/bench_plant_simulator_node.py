"""
End-to-end rate of the plant_simulator node: excitation in, measurements out, over DDS.

Three processes: the signal_generator (wall-paced, two channels), the plant_simulator
(``time_mode: owner``, answering each excitation block at once) and this benchmark, which
subscribes to ``measurements`` and checks every block's sample index. Reported: samples
received, gaps, the rate, and the CPU of the plant process.

Baseline in the same run: the same generator with this process subscribed to
``excitation`` directly (what DDS and the subscriber sustain without the plant in between).
Configurations: the plant with everything on (grouped streams, joint states at 1 kHz) and
with only the ``measurements`` stream.

    tools/bench.sh bench_plant_simulator_node --seconds 60
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

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('ROS_DOMAIN_ID', str(100 + os.getpid() % 100))

TICKS = os.sysconf('SC_CLK_TCK')


def cpu_seconds(pid: int) -> float:
    """CPU time (user + system) of a process so far [s]."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


def experiment_file(rate: float, seconds: float, hold_V: float) -> str:
    """A small excitation around the hold point: sine on the coil, PRBS on the load changer."""
    import yaml
    doc = {'experiment': {
        'sample_rate_Hz': rate, 'sections': ['bench'],
        'section': {'bench': {
            'duration_s': seconds,
            'coil': {'offset_V': hold_V, 'signals': {'s': {
                'type': 'sine', 'amplitude_V': 0.002, 'frequency_Hz': 37.0}}},
            'load_changer': {'signals': {'p': {
                'type': 'prbs', 'order': 11, 'hold_samples': 30, 'low_V': -0.02,
                'high_V': 0.02}}}}}}}
    handle = tempfile.NamedTemporaryFile('w', suffix='.yaml', delete=False)
    yaml.safe_dump(doc, handle)
    handle.close()
    return handle.name


def _wrapper(name: str) -> str:
    return str(Path(sys.prefix) / 'lib' / 'emfc_ros' / name)


def measure(config: str, rate: float, block: int, seconds: float, hold_V: float) -> dict:
    """Run generator (and plant) processes and receive the stream here."""
    import rclpy
    from std_msgs.msg import Float64MultiArray
    from std_srvs.srv import Trigger

    from emfc_ros.core.blocks import SequenceTracker
    from emfc_ros.nodes.convert import BLOCK_QOS, msg_to_block

    env = dict(os.environ, PYTHONUNBUFFERED='1',
               PATH=os.pathsep.join([str(Path(sys.executable).parent), os.environ['PATH']]))
    path = experiment_file(rate, seconds, hold_V)
    procs = {'generator': subprocess.Popen(
        [_wrapper('signal_generator'), '--ros-args', '-p', f'experiment_file:={path}',
         '-p', f'block_size:={block}', '-p', 'pacing:=wall', '-p', 'autostart:=false',
         '-p', 'min_subscribers:=1', '--log-level', 'warn'], env=env)}
    topic = 'excitation'
    if config != 'no plant (baseline)':
        everything = config == 'plant, all streams'
        procs['plant'] = subprocess.Popen(
            [_wrapper('plant_simulator'), '--ros-args', '-p', 'time_mode:=owner',
             '-p', f'sample_rate_Hz:={rate}',
             '-p', f'publish_groups:={"true" if everything else "false"}',
             '-p', f'state_rate_Hz:={1000.0 if everything else 0.0}',
             '--log-level', 'warn'], env=env)
        topic = 'measurements'
    rclpy.init()
    node = rclpy.create_node('bench_subscriber')
    tracker = SequenceTracker()
    got = {'samples': 0, 'last_t': None, 'first_index': None}

    def on_block(msg):
        b = msg_to_block(msg)
        if got['first_index'] is None:
            got['first_index'] = b.first_sample_index
        tracker.observe(b.first_sample_index, b.n_samples, b.epoch)
        got['last_t'] = time.monotonic()
        got['samples'] += b.n_samples

    node.create_subscription(Float64MultiArray, topic, on_block, BLOCK_QOS)
    client = node.create_client(Trigger, 'signal_generator/start')
    total = int(round(rate * seconds))
    result = {'configuration': config, 'rate_S_per_s': rate, 'block_size': block,
              'seconds': seconds, 'expected_samples': total}
    try:
        t0 = time.monotonic()
        ready = False
        while not ready and time.monotonic() - t0 < 30:
            rclpy.spin_once(node, timeout_sec=0.05)
            ready = client.service_is_ready() and node.count_publishers(topic) >= 1
            if 'plant' in procs:
                ready = ready and node.count_subscribers('excitation') >= 1
        cpu0 = {k: cpu_seconds(p.pid) for k, p in procs.items()}
        client.call_async(Trigger.Request())
        t_start = time.monotonic()
        deadline = t_start + seconds * 1.5 + 15
        while got['samples'] < total and time.monotonic() < deadline:
            rclpy.spin_once(node, timeout_sec=0.05)
        wall = time.monotonic() - t_start
        span = (got['last_t'] - t_start) if got['last_t'] else float('nan')
        result.update(tracker.counters())
        result.update({
            'received_samples': got['samples'], 'wall_s': wall,
            'first_sample_index': got['first_index'],
            'received_rate_S_per_s': got['samples'] / span if span else 0.0,
            'cpu_fraction_of_one_core': {
                k: (cpu_seconds(p.pid) - cpu0[k]) / wall if p.poll() is None else None
                for k, p in procs.items()},
            'no_gap': tracker.gaps == 0 and tracker.duplicates == 0 and tracker.reordered == 0
            and got['samples'] == total and got['first_index'] == 0,
            'sustained': got['samples'] == total and span <= seconds * 1.05 + 0.1,
        })
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(2)
        for p in procs.values():
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=10)
    return result


def main(argv=None) -> int:
    """Run the benchmark and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--rate', type=float, default=300000.0, help='sample rate [S/s]')
    parser.add_argument('--block', type=int, default=1000, help='samples per block')
    parser.add_argument('--seconds', type=float, default=60.0, help='duration per run [s]')
    parser.add_argument('--json', default='bench/results/plant_simulator_node.json')
    args = parser.parse_args(argv)
    from emfc_ros.core.model.parameters import BalanceParameters
    from emfc_ros.core.paths import config_file
    from emfc_ros.core.sim.simulator import Simulator
    hold_V = float(Simulator(BalanceParameters.load_yaml(config_file('balance_default.yaml')),
                             args.rate).hold_setpoints_V[0])
    runs = [measure(c, args.rate, args.block, args.seconds, hold_V)
            for c in ('no plant (baseline)', 'plant, measurements only', 'plant, all streams')]
    print(f'{"configuration":>26} {"kS/s":>6} {"s":>4} {"received":>10} {"gaps":>5} '
          f'{"dup":>4} {"recv kS/s":>9} {"plant CPU %":>11} {"gen CPU %":>9} {"ok":>3}')
    for r in runs:
        cpu = r['cpu_fraction_of_one_core']
        plant = f'{100 * cpu["plant"]:.1f}' if cpu.get('plant') is not None else '-'
        gen = f'{100 * cpu["generator"]:.1f}' if cpu.get('generator') is not None else '-'
        print(f'{r["configuration"]:>26} {r["rate_S_per_s"] / 1e3:6.0f} {r["seconds"]:4.0f} '
              f'{r["received_samples"]:10d} {r["gaps"]:5d} {r["duplicates"]:4d} '
              f'{r["received_rate_S_per_s"] / 1e3:9.1f} {plant:>11} {gen:>9} '
              f'{"yes" if r["no_gap"] and r["sustained"] else "NO":>3}')
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({'runs': runs}, indent=2))
    print(f'wrote {out}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
