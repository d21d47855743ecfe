"""
Recorder throughput over DDS, against rosbags' Writer writing the same messages directly.

A publisher process sends, paced to the wall clock, a measurement stream (``C`` channels at
``R`` samples per second in 1000-sample blocks) and a 2-channel excitation stream on the same
clock, with their latched descriptions. The recorder node runs as its own process (as
``ros2 run emfc_ros recorder`` would), is stopped with SIGINT (which closes the bag) and the
bag is read back with :func:`emfc_ros.core.bag.read_streams`: lossless means every sample of
both streams is in the bag, in order, with no gap. Reported: MB/s and messages/s of the
recording, the recorder's CPU time, dropped messages and the bag size.

Baselines, in the same run, on the same serialized messages (no DDS): rosbags'
``Writer(version=9, storage_plugin=MCAP)`` writing them directly, and this package's
``BagWriter`` (the recorder's writer without DDS and thread), interleaved, best of
``--repeats``; the writer-only ratio (ours / rosbags, messages per second) is printed. Our
writer also fsyncs when it closes a file (crash safety), rosbags' does not; both times
include closing.

    unshare -n -- bash -c 'ip link set lo up && .venv/bin/python bench/bench_recorder.py'
    .venv/bin/python bench/bench_recorder.py --writers-only --channels 8   # no DDS
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.setdefault('ROS_DOMAIN_ID', str(100 + os.getpid() % 100))

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
BLOCK = 1000
MEASUREMENT = '/bench/measurements'
EXCITATION = '/bench/excitation'

PUBLISHER = """
import json, sys, time
import numpy as np
import rclpy
from std_msgs.msg import Float64MultiArray, String
from emfc_ros.core.blocks import Channel, StreamDescription
from emfc_ros.nodes.convert import (BLOCK_QOS, BlockMessageBuilder, description_to_msg,
                                    LATCHED_QOS)
rate, channels, seconds, block = float(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3]), \
    int(sys.argv[4])
rclpy.init()
node = rclpy.create_node('bench_publisher')
streams = []
for topic, n in ((sys.argv[5], channels), (sys.argv[6], 2)):
    pub = node.create_publisher(Float64MultiArray, topic, BLOCK_QOS)
    desc = node.create_publisher(String, topic + '/description', LATCHED_QOS)
    desc.publish(description_to_msg(StreamDescription(
        stream=topic.rsplit('/', 1)[-1], sample_rate_Hz=rate, block_size=block,
        channels=tuple(Channel(f'c{i}', 'V') for i in range(n)), epoch=1)))
    streams.append((pub, desc, BlockMessageBuilder(), n))
deadline = time.monotonic() + 30.0
while any(p.get_subscription_count() < 1 or d.get_subscription_count() < 1
          for p, d, _, _ in streams):
    if time.monotonic() > deadline:
        print(json.dumps({'error': 'recorder did not subscribe within 30 s'}))
        sys.exit(1)
    rclpy.spin_once(node, timeout_sec=0.01)
time.sleep(0.5)  # let the latched descriptions reach the recorder
total = int(rate * seconds) // block * block
base = np.arange(block, dtype=np.float64)
sent = 0
bytes_sent = 0
start = time.monotonic()
while sent < total:
    due = min(total, int((time.monotonic() - start) * rate) // block * block + block)
    while sent < due:
        for pub, _, builder, n in streams:
            x = np.broadcast_to(base + sent, (n, block))
            msg = builder.build(sent, rate, 1, x)
            pub.publish(msg)
            bytes_sent += 8 * len(msg.data)
        sent += block
    time.sleep(0.0005)
elapsed = time.monotonic() - start
print(json.dumps({'samples': sent, 'blocks': 2 * sent // block, 'seconds': elapsed,
                  'data_bytes': bytes_sent}))
node.destroy_node()
rclpy.try_shutdown()
"""


def _wait4(proc: subprocess.Popen, timeout_s: float):
    """Wait for a child by its pid with a bound; return (status, rusage)."""
    deadline = time.monotonic() + timeout_s
    while True:
        pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
        if pid == proc.pid:
            proc.returncode = os.waitstatus_to_exitcode(status)
            return status, usage
        if time.monotonic() > deadline:
            os.kill(proc.pid, signal.SIGKILL)
            pid, status, usage = os.wait4(proc.pid, 0)
            proc.returncode = os.waitstatus_to_exitcode(status)
            return status, usage
        time.sleep(0.02)


def record_over_dds(rate: float, channels: int, seconds: float, work: Path) -> dict:
    """Run publisher and recorder processes; read the bag back; return the figures."""
    from emfc_ros.core.bag import read_streams

    bag = work / f'rec_{int(rate)}_{channels}'
    env = dict(os.environ, PYTHONUNBUFFERED='1', ROS_LOG_DIR=str(work / 'roslog'))
    log = open(work / f'recorder_{channels}.log', 'w+')
    recorder = subprocess.Popen(
        [sys.executable, '-m', 'emfc_ros.nodes.recorder', '--ros-args',
         '-p', f'output:={bag}', '-p', 'discovery_period_s:=0.1',
         '-p', f'topics:=[{MEASUREMENT},{MEASUREMENT}/description,{EXCITATION},'
               f'{EXCITATION}/description]'],
        cwd=REPO, env=env, stdout=log, stderr=subprocess.STDOUT)
    publisher = subprocess.run(
        [sys.executable, '-c', PUBLISHER, str(rate), str(channels), str(seconds), str(BLOCK),
         MEASUREMENT, EXCITATION], cwd=REPO, env=env, capture_output=True, text=True,
        timeout=seconds + 120)
    t_stop = time.monotonic()
    # Let the last messages arrive: the recorder's queue drains in well under a second.
    time.sleep(1.0)
    os.kill(recorder.pid, signal.SIGINT)
    _, usage = _wait4(recorder, 60.0)
    close_s = time.monotonic() - t_stop - 1.0
    log.seek(0)
    output = log.read()
    log.close()
    if publisher.returncode != 0:
        raise RuntimeError(f'publisher failed: {publisher.stdout} {publisher.stderr}')
    sent = json.loads(publisher.stdout.strip().splitlines()[-1])
    match = re.search(r'closed .*: (\d+) messages in (\d+) files, (\d+) dropped', output)
    streams = read_streams(bag, on_gap='nan')
    meas, exc = streams[MEASUREMENT], streams[EXCITATION]
    lossless = all(s.gaps == [] and s.first_sample_index == 0
                   and s.n_samples == sent['samples'] for s in (meas, exc))
    exact = bool(meas.samples[-1, -1] == sent['samples'] - 1) if meas.n_samples else False
    bag_bytes = sum(p.stat().st_size for p in bag.glob('*.mcap'))
    messages = 2 * sent['samples'] // BLOCK
    return {
        'mode': 'recorder over DDS', 'rate_S_per_s': rate, 'channels': channels,
        'seconds': sent['seconds'], 'messages': messages,
        'received_samples': [meas.n_samples, exc.n_samples],
        'gaps': [list(map(list, meas.gaps))[:10], list(map(list, exc.gaps))[:10]],
        'first_sample_index': [meas.first_sample_index, exc.first_sample_index],
        'last_sample_exact': exact,
        'lossless': lossless and exact,
        'dropped': int(match.group(3)) if match else None,
        'files': int(match.group(2)) if match else None,
        'MB_per_s': sent['data_bytes'] / sent['seconds'] / 1e6,
        'messages_per_s': messages / sent['seconds'],
        'recorder_cpu_s': usage.ru_utime + usage.ru_stime,
        'recorder_cpu_fraction': (usage.ru_utime + usage.ru_stime) / (sent['seconds'] + 2),
        'recorder_max_rss_MB': usage.ru_maxrss / 1024,
        'close_s': close_s, 'bag_MB': bag_bytes / 1e6,
    }


def serialized_messages(rate: float, channels: int, seconds: float):
    """The same blocks as the publisher sends, serialised with rclpy (CDR)."""
    import numpy as np
    from rclpy.serialization import serialize_message

    from emfc_ros.nodes.convert import BlockMessageBuilder

    total = int(rate * seconds) // BLOCK * BLOCK
    builders = [BlockMessageBuilder(), BlockMessageBuilder()]
    base = np.arange(BLOCK, dtype=np.float64)
    out = []
    for first in range(0, total, BLOCK):
        for k, n in enumerate((channels, 2)):
            msg = builders[k].build(first, rate, 1, np.broadcast_to(base + first, (n, BLOCK)))
            out.append((k, int(first / rate * 1e9), serialize_message(msg)))
    return out


def write_directly(kind: str, messages, work: Path, rate: float, channels: int,
                   durable: bool = True) -> dict:
    """
    Baseline: write the serialized messages with rosbags' Writer or our BagWriter.

    ``durable``: the time includes putting the data on disk: our writer fsyncs when it closes
    a file (as the recorder does), and rosbags' files are fsynced after its close (it never
    fsyncs itself). Without it, our writer runs with ``fsync=False`` and neither waits for
    the disk (the data may still be in the page cache when the clock stops).
    """
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import get_typestore, Stores

    from emfc_ros.core.bag import BagWriter

    path = work / f'{kind}_{int(rate)}_{channels}'
    msgtype = 'std_msgs/msg/Float64MultiArray'
    data_bytes = sum(len(raw) for _, _, raw in messages)
    start = time.perf_counter()
    cpu0 = time.process_time()
    if kind == 'rosbags':
        typestore = get_typestore(Stores.ROS2_JAZZY)
        with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            conns = [writer.add_connection(t, msgtype, typestore=typestore)
                     for t in (MEASUREMENT, EXCITATION)]
            for k, t, raw in messages:
                writer.write(conns[k], t, raw)
        if durable:
            for file in sorted(path.iterdir()):
                fd = os.open(file, os.O_RDONLY)
                try:
                    os.fsync(fd)
                finally:
                    os.close(fd)
    else:
        writer = BagWriter(path, fsync=durable)
        writer.open()
        conns = [writer.add_connection(t, msgtype) for t in (MEASUREMENT, EXCITATION)]
        for k, t, raw in messages:
            writer.write(conns[k], t, raw)
        writer.close()
    elapsed = time.perf_counter() - start
    cpu = time.process_time() - cpu0
    return {'mode': f'{kind} direct{", fsync" if durable else ""}', 'rate_S_per_s': rate,
            'channels': channels, 'durable': durable,
            'seconds': elapsed, 'messages': len(messages), 'lossless': True,
            'MB_per_s': data_bytes / elapsed / 1e6, 'messages_per_s': len(messages) / elapsed,
            'writer_cpu_s': cpu,
            'bag_MB': sum(p.stat().st_size for p in path.glob('*.mcap')) / 1e6}


def writer_ratio(messages, work: Path, rate: float, channels: int, repeats: int,
                 durable: bool) -> dict:
    """Both writers on the same messages, interleaved, best of ``repeats``; their ratio."""
    best = {}
    for rep in range(repeats):
        for kind in ('rosbags', 'BagWriter'):
            run = write_directly(kind, messages, work / f'{rep}', rate, channels, durable)
            shutil.rmtree(work / f'{rep}', ignore_errors=True)
            if kind not in best or run['messages_per_s'] > best[kind]['messages_per_s']:
                best[kind] = run
    ours, theirs = best['BagWriter'], best['rosbags']
    return {'channels': channels, 'rate_S_per_s': rate, 'repeats': repeats,
            'durable': durable,
            'rosbags_messages_per_s': theirs['messages_per_s'],
            'ours_messages_per_s': ours['messages_per_s'],
            'ratio': ours['messages_per_s'] / theirs['messages_per_s'],
            'cpu_ratio': theirs['writer_cpu_s'] / ours['writer_cpu_s'],
            'runs': [theirs, ours]}


def main(argv=None) -> int:
    """Run the benchmark, print the table and write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=5.0, help='publishing time [s]')
    parser.add_argument('--rate', type=float, default=300000.0, help='sample rate [S/s]')
    parser.add_argument('--channels', type=int, nargs='+', default=[4, 8],
                        help='measurement channels per run')
    parser.add_argument('--direct-seconds', type=float, default=5.0,
                        help='stream time of the messages the writers write directly [s]')
    parser.add_argument('--repeats', type=int, default=3,
                        help='direct writes per writer (interleaved, best kept)')
    parser.add_argument('--writers-only', action='store_true',
                        help='only the direct writes (no DDS, no recorder process)')
    parser.add_argument('--json', default=str(REPO / 'bench' / 'results' / 'recorder.json'))
    args = parser.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix='bench_recorder_'))
    runs = []
    ratios = []
    try:
        for channels in args.channels:
            if not args.writers_only:
                runs.append(record_over_dds(args.rate, channels, args.seconds, work))
            messages = serialized_messages(args.rate, channels, args.direct_seconds)
            for durable in (False, True):
                ratio = writer_ratio(messages, work, args.rate, channels, args.repeats,
                                     durable)
                runs.extend(ratio.pop('runs'))
                ratios.append(ratio)
            del messages
    finally:
        if os.environ.get('EMFC_BENCH_KEEP'):
            print(f'kept {work}')
        else:
            shutil.rmtree(work, ignore_errors=True)
    print(f'{"mode":>24} {"kS/s":>6} {"ch":>3} {"s":>6} {"msgs":>6} {"msg/s":>8} '
          f'{"MB/s":>7} {"lossless":>8} {"dropped":>7} {"CPU s":>6} {"bag MB":>7}')
    for r in runs:
        cpu = r.get('recorder_cpu_s', r.get('writer_cpu_s', 0.0))
        dropped = r.get('dropped', '-')
        print(f'{r["mode"]:>24} {r["rate_S_per_s"] / 1e3:6.0f} {r["channels"]:3d} '
              f'{r["seconds"]:6.2f} {r["messages"]:6d} {r["messages_per_s"]:8.0f} '
              f'{r["MB_per_s"]:7.1f} {str(r["lossless"]):>8} {str(dropped):>7} {cpu:6.2f} '
              f'{r["bag_MB"]:7.1f}')
    for r in ratios:
        what = 'on disk (fsync)' if r['durable'] else 'page cache'
        print(f'writer only, {r["channels"]} + 2 channels, {what}, best of {r["repeats"]}: '
              f'BagWriter {r["ours_messages_per_s"]:.0f} msg/s, rosbags Writer '
              f'{r["rosbags_messages_per_s"]:.0f} msg/s, ratio {r["ratio"]:.2f} '
              f'(target >= 0.5: {"met" if r["ratio"] >= 0.5 else "NOT met"}); CPU time '
              f'rosbags / ours {r["cpu_ratio"]:.2f}')
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({'block_samples': BLOCK, 'runs': runs, 'writer_ratios': ratios,
                               'command': 'bench/bench_recorder.py ' + ' '.join(
                                   argv if argv is not None else sys.argv[1:])}, indent=2))
    print(f'wrote {out}')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
