"""
The cost of message authentication (HMAC-SHA256) on the device link at 300 kS/s.

Per run: the device emulator in its own process (``emfc-device-emulator``, four input
channels, 1000-sample blocks: 300 measurement frames of 8 kB per second at 300 kS/s) and, in
this process, the ``UdpBackend`` that configures it, reads every block and writes the
setpoints of the two outputs ``--lead-blocks`` ahead of the block it read (30 blocks, 0.1 s
at 300 kS/s, the bridge's ``excitation_lead_s``; float64: 300 setpoint frames of 16 kB per
second), as the daq_bridge does. The same run is done without a key (the baseline) and with
a key on both sides (``--key-file``), alternating, ``--repeats`` times each, after one
discarded warm-up run; all figures in one run of this script, so they compare like with
like on this shared machine.

Per run, for ``--seconds`` after the first block: the achieved rate (samples received per
second of stream), gaps and refused datagrams, and CPU per second of stream of the host
(this process: receiver, supervisor and the reading loop; ``getrusage``) and of the device
emulator (``/proc/<pid>/stat``). Also, once: the time to sign and to verify one 8 kB
measurement frame and one 16 kB setpoint frame (``timeit``, best of 5).

    python bench/bench_device_auth.py --seconds 20 --repeats 3
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import resource
import statistics
import subprocess
import sys
import tempfile
import time
import timeit
from typing import Dict, List, Optional

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from emfc_ros.core.device import protocol as proto  # noqa: E402
from emfc_ros.core.device.auth import load_key_file, Signer  # noqa: E402
from emfc_ros.core.device.backend import default_device_config  # noqa: E402
from emfc_ros.core.device.udp_backend import UdpBackend  # noqa: E402

TICKS = os.sysconf('SC_CLK_TCK')
INPUTS = ('coil_setpoint_V', 'coil_current_A', 'sensor_V', 'position_m')


def process_cpu_s(pid: int) -> float:
    """CPU time (user + system) of a process so far [s]."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICKS


def own_cpu_s() -> float:
    """CPU time of this process, all threads [s]."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def start_emulator(key_file: Optional[Path]) -> tuple:
    """``emfc-device-emulator --port 0`` (with the key file), and the port it prints."""
    args = [sys.executable, '-m', 'emfc_ros.cli.device_emulator', '--port', '0', '--channels',
            str(len(INPUTS)), '--seed', '0']
    if key_file is not None:
        args += ['--key-file', str(key_file)]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO),
                                                       os.environ.get('PYTHONPATH', '')]))
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env,
                            cwd=REPO)
    line = proc.stdout.readline().decode().strip()
    if not line.isdigit():
        proc.kill()
        raise RuntimeError(f'emulator did not print its port: {line!r}')
    return proc, int(line)


def one_run(rate: float, block: int, seconds: float, key_file: Optional[Path],
            lead_blocks: int = 30) -> dict:
    """Stream for ``seconds``; return rate, defects and CPU per second of stream."""
    proc, port = start_emulator(key_file)
    backend = UdpBackend(('127.0.0.1', port), key_file=key_file)
    try:
        config = default_device_config(rate, block, INPUTS, watchdog_timeout_s=1.0)
        backend.configure(config)
        backend.start()
        setpoints = np.zeros((2, block))
        first = backend.read_block(10.0)
        if first is None:
            raise RuntimeError('no block from the emulator')
        lead = lead_blocks * block
        backend.write_setpoints(first.end_index,
                                np.zeros((2, lead)))       # the lead, then one block per block
        t0, host0, dev0 = time.monotonic(), own_cpu_s(), process_cpu_s(proc.pid)
        start_index, end_index = first.end_index, first.end_index
        while time.monotonic() - t0 < seconds:
            got = backend.read_block(1.0)
            if got is None:
                continue
            end_index = got.end_index
            backend.write_setpoints(got.end_index + lead - block, setpoints)
        wall = time.monotonic() - t0
        host, dev = own_cpu_s() - host0, process_cpu_s(proc.pid) - dev0
        stream_s = (end_index - start_index) / rate
        health = backend.health()
        status = backend.status().counters
    finally:
        backend.close()
        proc.terminate()
        proc.wait(10)
    return {'authenticated': key_file is not None, 'wall_s': wall, 'stream_s': stream_s,
            'received_kSps': (end_index - start_index) / wall / 1e3,
            'gaps': health['gaps'], 'underrun_samples': status['underrun_samples'],
            'device_late_blocks': status['late_blocks'],
            'refused_host': sum(health[k] for k in ('unauthenticated', 'replayed',
                                                    'wrong_session', 'corrupt')),
            'refused_device': status['unauthenticated_datagrams'] +
            status['replayed_datagrams'],
            'host_cpu_per_stream_s': host / stream_s, 'device_cpu_per_stream_s': dev / stream_s}


def crypto_costs(block: int) -> Dict[str, float]:
    """Sign and verify one measurement and one setpoint frame [us], best of 5."""
    key = bytes(range(32))
    signer = Signer(key)
    frames = {'measurement_8kB': proto.Frame(proto.STREAM_MEASUREMENT, 1, 1, 0,
                                             np.zeros((len(INPUTS), block), np.int16), 5),
              'setpoint_16kB': proto.Frame(proto.STREAM_SETPOINT, 1, 1, 0,
                                           np.zeros((2, block)), 5)}
    out = {}
    for name, frame in frames.items():
        for label, sign in (('plain', None), ('hmac', signer)):
            data = proto.encode_frame(frame, sign)
            k = key if sign else None
            n = 2000
            enc = min(timeit.repeat(lambda: proto.encode_frame(frame, sign), number=n,
                                    repeat=5)) / n
            dec = min(timeit.repeat(lambda: proto.decode_frame(data, k), number=n,
                                    repeat=5)) / n
            out[f'{name}_{label}_encode_us'] = enc * 1e6
            out[f'{name}_{label}_decode_us'] = dec * 1e6
    return out


def main(argv: Optional[List[str]] = None) -> int:
    """Run the benchmark, print the table, store the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--seconds', type=float, default=20.0, help='per run [s]')
    parser.add_argument('--repeats', type=int, default=3, help='runs with and without a key')
    parser.add_argument('--rate', type=float, default=300000.0, help='sample rate [Hz]')
    parser.add_argument('--block-size', type=int, default=1000, help='samples per block')
    parser.add_argument('--lead-blocks', type=int, default=30,
                        help='setpoints are written this many blocks ahead')
    parser.add_argument('--json', default=str(REPO / 'bench' / 'results' / 'device_auth.json'))
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        key_file = Path(tmp) / 'device.key'
        key_file.write_text(os.urandom(32).hex())
        key_file.chmod(0o600)
        load_key_file(key_file)
        # A first, discarded run: the emulator builds its simulator for this rate.
        one_run(args.rate, args.block_size, min(3.0, args.seconds), None, args.lead_blocks)
        runs = []
        for i in range(args.repeats):
            for key in (None, key_file):
                run = one_run(args.rate, args.block_size, args.seconds, key, args.lead_blocks)
                runs.append(run)
                print(f'run {i + 1} {"hmac " if key else "plain"}: '
                      f'{run["received_kSps"]:.1f} kS/s, gaps {run["gaps"]}, host CPU '
                      f'{100 * run["host_cpu_per_stream_s"]:.1f} %, device CPU '
                      f'{100 * run["device_cpu_per_stream_s"]:.1f} %', flush=True)
    costs = crypto_costs(args.block_size)
    summary = {}
    for auth in (False, True):
        mine = [r for r in runs if r['authenticated'] == auth]
        summary['hmac' if auth else 'plain'] = {
            key: statistics.median(r[key] for r in mine)
            for key in ('received_kSps', 'host_cpu_per_stream_s', 'device_cpu_per_stream_s')}
        summary['hmac' if auth else 'plain'].update(
            gaps=sum(r['gaps'] for r in mine), underrun_samples=sum(
                r['underrun_samples'] for r in mine),
            device_late_blocks=sum(r['device_late_blocks'] for r in mine),
            refused=sum(r['refused_host'] + r['refused_device'] for r in mine))
    print(f'\n{args.rate / 1e3:.0f} kS/s, {len(INPUTS)} channels, blocks of '
          f'{args.block_size}, {args.seconds:g} s x {args.repeats} per case (median):')
    print('| link | received [kS/s] | host CPU [% of a core] | device CPU [% of a core] | '
          'gaps | refused |')
    print('|---|---|---|---|---|---|')
    for name, s in summary.items():
        print(f'| {name} | {s["received_kSps"]:.1f} | {100 * s["host_cpu_per_stream_s"]:.1f} | '
              f'{100 * s["device_cpu_per_stream_s"]:.1f} | {s["gaps"]} | {s["refused"]} |')
    print('\nper frame [us]: ' + ', '.join(f'{k} {v:.1f}' for k, v in costs.items()))
    doc = {'rate_Hz': args.rate, 'block_size': args.block_size, 'channels': len(INPUTS),
           'seconds': args.seconds, 'repeats': args.repeats, 'runs': runs,
           'summary': summary, 'per_frame_us': costs,
           'load_average': os.getloadavg()}
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(doc, indent=2))
    return 0


if __name__ == '__main__':
    sys.exit(main())
