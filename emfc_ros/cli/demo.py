"""
emfc-demo: play an experiment through the signal_generator node and check the stream (no plant).

Brings up the signal_generator node and a monitor node in one process (a multi-threaded
executor, real DDS between them), plays the shipped four-section identification
trajectory as fast as the monitor consumes it, checks that every sample arrived once and in
order, and writes what the generator produced to an output folder: the samples (NPY and
CSV), a per-section summary (Markdown and JSON) and a plot (PNG). The main job, an
experiment on the simulated balance or a device that is recorded and identified, is
``emfc-experiment``.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys
import time
from typing import List, Optional

import numpy as np


def _summary_rows(samples: np.ndarray, description) -> List[dict]:
    rate = description.sample_rate_Hz
    rows = []
    for section in description.extra.get('sections', []):
        first = section['first_sample_index']
        stop = first + section['n_samples']
        row = {'section': section['name'], 'start_s': first / rate,
               'duration_s': section['n_samples'] / rate}
        for c, channel in enumerate(description.channels):
            x = samples[c, first:stop]
            row[f'{channel.name}_rms_V'] = float(np.sqrt(np.mean(x ** 2)))
            row[f'{channel.name}_min_V'] = float(x.min())
            row[f'{channel.name}_max_V'] = float(x.max())
        rows.append(row)
    return rows


def _write_outputs(out: Path, samples: np.ndarray, description, tracker_counts: dict,
                   wall_s: float) -> None:
    out.mkdir(parents=True, exist_ok=True)
    rate = description.sample_rate_Hz
    names = [f'{c.name}_{c.unit}' for c in description.channels]
    np.save(out / 'excitation.npy', samples)
    t = np.arange(samples.shape[1]) / rate
    np.savetxt(out / 'excitation.csv', np.column_stack([np.arange(samples.shape[1]), t,
                                                        samples.T]),
               delimiter=',', header='sample_index,time_s,' + ','.join(names), comments='',
               fmt=['%d', '%.9g'] + ['%.12g'] * samples.shape[0])
    rows = _summary_rows(samples, description)
    doc = {'sample_rate_Hz': rate, 'total_samples': int(samples.shape[1]),
           'channels': names, 'stream_checks': tracker_counts, 'wall_time_s': wall_s,
           'sections': rows}
    (out / 'summary.json').write_text(json.dumps(doc, indent=2))
    lines = ['# Excitation produced by signal_generator', '',
             f'{samples.shape[1]} samples at {rate:g} Hz on {len(names)} channels, received '
             f'over DDS in {wall_s:.2f} s; gaps {tracker_counts["gaps"]}, duplicates '
             f'{tracker_counts["duplicates"]}, reordered {tracker_counts["reordered"]}.', '',
             '| section | start [s] | duration [s] | ' + ' | '.join(
                 f'{n} rms [V] | {n} min [V] | {n} max [V]'
                 for n in (c.name for c in description.channels)) + ' |',
             '|---' * (3 + 3 * len(names)) + '|']
    for row in rows:
        cells = [row['section'], f'{row["start_s"]:g}', f'{row["duration_s"]:g}']
        for c in description.channels:
            cells += [f'{row[f"{c.name}_{k}_V"]:.4g}' for k in ('rms', 'min', 'max')]
        lines.append('| ' + ' | '.join(cells) + ' |')
    (out / 'summary.md').write_text('\n'.join(lines) + '\n')
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        return
    fig, axes = plt.subplots(len(names), 1, sharex=True, figsize=(10, 2.2 * len(names)))
    for ax, name, x in zip(np.atleast_1d(axes), names, samples):
        # Min/max envelope per bin, so that fast sweeps are not aliased by decimation.
        step = max(1, x.size // 4000)
        n = x.size // step * step
        bins = x[:n].reshape(-1, step)
        ax.fill_between(t[:n:step], bins.min(axis=1), bins.max(axis=1), lw=0.4, step='post')
        ax.set_ylabel(name)
        for section in description.extra.get('sections', []):
            ax.axvline(section['first_sample_index'] / rate, color='k', lw=0.5, ls=':')
    np.atleast_1d(axes)[-1].set_xlabel('time [s]')
    fig.suptitle('excitation (setpoint voltages) per section')
    fig.tight_layout()
    fig.savefig(out / 'excitation.png', dpi=110)
    plt.close(fig)


def run(out: Path, experiment_file: Optional[str], timeout_s: float) -> int:
    """
    Run the generator and the monitor until the experiment is received.

    Parameters
    ----------
    out : pathlib.Path
        Output folder.
    experiment_file : str or None
        Experiment YAML; the shipped identification trajectory when None.
    timeout_s : float
        Upper bound on the whole run [s].

    Returns
    -------
    int
        0 on success, 1 if the stream was incomplete or defective.
    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from std_msgs.msg import Float64MultiArray, String, UInt64
    from std_srvs.srv import Trigger

    from emfc_ros.core.blocks import Continuity, SequenceTracker
    from emfc_ros.core.json_text import load_json_text
    from emfc_ros.core.start_gate import readiness_text
    from emfc_ros.nodes.convert import (
        BLOCK_QOS, CONTROL_QOS, LATCHED_QOS, msg_to_block, msg_to_description)
    from emfc_ros.nodes.signal_generator import SignalGeneratorNode

    rclpy.init()
    overrides = [Parameter('pacing', value='consumer'), Parameter('autostart', value=False)]
    if experiment_file:
        overrides.append(Parameter('experiment_file', value=str(experiment_file)))
    generator = SignalGeneratorNode(parameter_overrides=overrides)
    monitor = rclpy.create_node('demo_monitor')
    state = {'description': None, 'chunks': [], 'received': 0, 'bad': 0, 'section': ''}
    tracker = SequenceTracker()
    ack = monitor.create_publisher(UInt64, 'excitation/consumed', CONTROL_QOS)
    # The monitor is the consumer: it announces itself ready, as the plant and the bridge
    # do, for the generator's start gate.
    monitor.create_publisher(String, 'excitation/ready', LATCHED_QOS).publish(
        String(data=readiness_text(monitor.get_fully_qualified_name(), True)))

    def on_description(msg: String) -> None:
        state['description'] = msg_to_description(msg)

    def on_block(msg: Float64MultiArray) -> None:
        block = msg_to_block(msg)
        kind = tracker.observe(block.first_sample_index, block.n_samples, block.epoch)
        if kind in (Continuity.FIRST, Continuity.CONTIGUOUS):
            state['chunks'].append(np.array(block.samples))
            state['received'] = block.end_index
        else:
            state['bad'] += 1
        ack.publish(UInt64(data=block.end_index))

    def on_status(msg: String) -> None:
        try:
            status = load_json_text(msg.data, 'signal generator status')
            state['section'] = str(status.get('section', '')) if isinstance(status, dict) \
                else ''
        except ValueError:
            state['malformed'] = state.get('malformed', 0) + 1

    monitor.create_subscription(String, 'excitation/description', on_description, LATCHED_QOS)
    monitor.create_subscription(String, 'signal_generator/status', on_status, LATCHED_QOS)
    start_client = monitor.create_client(Trigger, 'signal_generator/start')
    monitor.create_subscription(Float64MultiArray, 'excitation', on_block, BLOCK_QOS)
    executor = SingleThreadedExecutor()   # see emfc_ros/cli/experiment.py
    executor.add_node(generator)
    executor.add_node(monitor)
    t0 = time.monotonic()
    code = 1
    try:
        while (generator.count_subscribers('excitation') < 1
               or not start_client.service_is_ready()) and time.monotonic() - t0 < 10:
            executor.spin_once(timeout_sec=0.05)
        future = start_client.call_async(Trigger.Request())
        while not future.done() and time.monotonic() - t0 < 20:
            executor.spin_once(timeout_sec=0.05)
        if not future.done() or not future.result().success:
            print('signal_generator did not start: '
                  f'{future.result().message if future.done() else "no answer"}',
                  file=sys.stderr)
            return 1
        print(f'signal_generator: {future.result().message}', flush=True)
        t_start = time.monotonic()
        last_print = 0.0
        while time.monotonic() - t0 < timeout_s:
            executor.spin_once(timeout_sec=0.05)
            desc = state['description']
            total = desc.total_samples if desc is not None else -1
            now = time.monotonic()
            if desc is not None and now - last_print > 0.5:
                last_print = now
                section = state['section'] or 'done'
                print(f'  {100.0 * state["received"] / total:5.1f} %  sample '
                      f'{state["received"]}/{total}  section {section}', flush=True)
            if desc is not None and state['received'] >= total > 0:
                break
        wall = time.monotonic() - t_start
        desc = state['description']
        if desc is None or state['received'] < desc.total_samples:
            print(f'incomplete: received {state["received"]} samples in {timeout_s} s',
                  file=sys.stderr)
        else:
            samples = np.concatenate(state['chunks'], axis=1)
            _write_outputs(out, samples, desc, tracker.counters(), wall)
            rate_kS = samples.shape[1] / wall / 1e3
            print(f'received {samples.shape[1]} samples x {samples.shape[0]} channels in '
                  f'{wall:.2f} s ({rate_kS:.0f} kS/s per channel); defects: '
                  f'{tracker.counters()}')
            print((out / 'summary.md').read_text())
            print(f'wrote {out}/excitation.npy, excitation.csv, summary.md, summary.json, '
                  'excitation.png')
            code = 0 if state['bad'] == 0 else 1
    finally:
        executor.shutdown()
        generator.destroy_node()
        monitor.destroy_node()
        rclpy.try_shutdown()
    return code


def main(argv: Optional[List[str]] = None) -> int:
    """
    Entry point of ``emfc-demo``.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (``sys.argv[1:]`` when None).

    Returns
    -------
    int
        Exit code.
    """
    parser = argparse.ArgumentParser(prog='emfc-demo', description=__doc__.split('\n\n')[0])
    parser.add_argument('-o', '--out', default='out/demo', help='output folder')
    parser.add_argument('--experiment', default=None,
                        help='experiment YAML (default: the shipped identification trajectory)')
    parser.add_argument('--timeout', type=float, default=120.0, help='upper bound [s]')
    args = parser.parse_args(argv)
    return run(Path(args.out), args.experiment, args.timeout)


if __name__ == '__main__':
    raise SystemExit(main())
