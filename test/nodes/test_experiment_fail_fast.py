"""
``emfc-experiment`` fails fast and stops clean, run as users run it (a separate process).

A bad plan (a signal in an experiment file, an identification option) is refused with exit 2
and the key named before any node starts: no output folder, no bag. Ctrl-C during the
recording ends the run with exit 130 and one line saying what was kept; the bag is closed and
opens with the independent reader rosbags.
"""

import os
from pathlib import Path
import shutil
import signal
import subprocess
import sys

import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import get_typestore, Stores
import yaml

from emfc_ros.core.bag import read_metadata
from emfc_ros.core.paths import config_file
import ros_harness
from ros_harness import scaled

RUN_TIMEOUT_S = scaled(240.0)


def _runner() -> str:
    return shutil.which('emfc-experiment') or str(Path(sys.executable).parent /
                                                  'emfc-experiment')


def _default_plan_copy(folder: Path) -> Path:
    """The shipped default plan and its files, in a folder of the test."""
    for name in ('experiment_default.yaml', 'identification_trajectory.yaml',
                 'static_characteristics.yaml', 'balance_default.yaml'):
        (folder / name).write_text(config_file(name).read_text())
    return folder / 'experiment_default.yaml'


def _bad_signal(folder: Path) -> None:
    path = folder / 'static_characteristics.yaml'
    doc = yaml.safe_load(path.read_text())
    stairs = doc['/**']['ros__parameters']['experiment']['section'][
        'load_changer_staircase']['load_changer']['signals']['stairs']
    stairs['dwell_s'] = 'long'
    path.write_text(yaml.safe_dump(doc))


def _set_identification(change: dict):
    def apply(folder: Path) -> None:
        path = folder / 'experiment_default.yaml'
        doc = yaml.safe_load(path.read_text())
        doc['run']['identification'].update(change)
        path.write_text(yaml.safe_dump(doc))
    return apply


@pytest.mark.parametrize('change, key', [
    (_bad_signal, 'run.experiment_files[1] ({folder}/static_characteristics.yaml): experiment.'
                  'section.load_changer_staircase.load_changer.signals.stairs.dwell_s'),
    (_set_identification({'greybox': {'tolerence': 1e-6}}),
     'run.identification.greybox.tolerence: unknown key'),
    (_set_identification({'frf': {'frequency_max_Hz': 'high'}}),
     'run.identification.frf.frequency_max_Hz'),
    (_set_identification({'static': {'sections': ['coil_staircase']}}),
     'run.identification.static.sections[0]'),
])
def test_a_bad_plan_exits_2_naming_the_key_before_anything_runs(tmp_path, change, key):
    plan = _default_plan_copy(tmp_path)
    change(tmp_path)
    out = tmp_path / 'out'
    result = subprocess.run([_runner(), str(plan), '-o', str(out)], capture_output=True,
                            text=True, timeout=RUN_TIMEOUT_S,
                            env=ros_harness.child_environment(), cwd=tmp_path)
    assert result.returncode == 2, result.stdout[-2000:] + result.stderr[-2000:]
    assert key.format(folder=tmp_path) in result.stderr
    assert 'Traceback' not in result.stderr
    assert result.stdout == ''                  # no progress: nothing started
    assert not out.exists()                     # no output folder, no bag
    assert not (tmp_path / 'out').exists() and not list(tmp_path.glob('**/*.mcap'))


INTERRUPT_EXPERIMENT = """\
experiment:
  sample_rate_Hz: 10000.0
  sections: [hold]
  section:
    hold:
      duration_s: 120.0
      coil:
        signals:
          dither: {type: sine, amplitude_V: 0.001, frequency_Hz: 7.0}
"""
# The bridge's sim back-end: the device runs on the wall clock, as hardware does, so the
# recording lasts long enough to be interrupted.
INTERRUPT_PLAN = """\
run:
  name: interrupt
  target: bridge
  experiment_files: [experiment.yaml]
  timeout_s: 300.0
  bridge:
    backend: sim
    balance_file: balance_default.yaml
  identification: {enabled: false}
"""


def _progress_lines(proc) -> int:
    return sum(' % ' in line and 'measured' in line for line in proc.output().splitlines())


def test_ctrl_c_while_recording_exits_130_with_one_line_and_a_closed_bag(tmp_path, processes):
    (tmp_path / 'experiment.yaml').write_text(INTERRUPT_EXPERIMENT)
    (tmp_path / 'plan.yaml').write_text(INTERRUPT_PLAN)
    (tmp_path / 'balance_default.yaml').write_text(config_file('balance_default.yaml')
                                                   .read_text())
    out = tmp_path / 'out'
    proc = processes.start([_runner(), 'plan.yaml', '-o', str(out)], cwd=tmp_path)
    # recording: the second progress line (a second of the device's data or more)
    assert ros_harness.wait_until(lambda: _progress_lines(proc) >= 2 or not proc.alive(),
                                  RUN_TIMEOUT_S), proc.output()[-3000:]
    assert proc.alive(), proc.output()[-3000:]
    os.kill(proc.pid, signal.SIGINT)
    proc.proc.wait(timeout=scaled(60))
    output = proc.output()
    assert proc.proc.returncode == 130, output[-3000:]
    assert 'Traceback' not in output and 'KeyboardInterrupt' not in output
    lines = [line for line in output.splitlines() if 'interrupted' in line]
    assert len(lines) == 1, output[-3000:]
    line = lines[0]
    # everything printed after the interrupt is that one line
    assert output.rstrip().splitlines()[-1] == line
    bag = out / 'bag'
    assert line.startswith('emfc-experiment: interrupted (Ctrl-C) at ')
    assert f'bag closed, {bag}' in line
    meta = read_metadata(bag)
    assert f'({meta["message_count"]} messages)' in line
    # the independent reader opens the bag and finds what the metadata says was recorded
    counts = {}
    indices = []
    with AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, _, raw in reader.messages():
            msg = reader.deserialize(raw, conn.msgtype)
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
            if conn.topic == '/emfc/excitation':
                indices.append((int(msg.data[0]), (msg.data.size - 3) // 2))
    assert sum(counts.values()) == meta['message_count']
    assert counts['/emfc/measurements'] >= 1 and counts['/emfc/excitation'] >= 2
    # the excitation recorded is the experiment's start, without a gap
    first, n = zip(*sorted(indices))
    assert first[0] == 0 and all(a + m == b for a, m, b in zip(first, n, first[1:]))
    done = int(line.split(' at ')[1].split(' of ')[0])
    assert 0 < done < 1_200_000
    assert not (out / 'summary.md').exists()     # the run did not pretend to finish


def test_the_interrupt_line_says_what_was_kept(tmp_path):
    from emfc_ros.cli.experiment import interrupted_line

    out = tmp_path / 'run'
    assert interrupted_line(out, {}) == (f'interrupted (Ctrl-C) before recording started; '
                                         f'nothing recorded ({out} holds the plan only)')
    bag = out / 'bag'
    bag.mkdir(parents=True)
    (bag / 'metadata.yaml').write_text(yaml.safe_dump(
        {'rosbag2_bagfile_information': {'message_count': 7}}))
    live = {'bag': str(bag), 'samples': 2500, 'total': 10000, 'sample_rate_Hz': 1000.0}
    assert interrupted_line(out, live) == (f'interrupted (Ctrl-C) at 2500 of 10000 samples '
                                           f'(2.50 s of 10.00 s); kept: bag closed, {bag} '
                                           '(7 messages)')
    line = interrupted_line(out, dict(live, recorded=True))
    assert line.startswith('interrupted (Ctrl-C) while identifying; kept: the complete '
                           f'recording, bag closed, {bag} (7 messages)')
    (bag / 'metadata.yaml').unlink()
    assert 'metadata unreadable' in interrupted_line(out, live)
