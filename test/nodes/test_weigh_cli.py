"""
``emfc-weigh`` as users type it (issue 15, item 1), each run a separate process.

The README's weighing line runs as typed (parsed from the README); the output is read as a
user reads it: before the first zero every reading says ``uncalibrated``; every ``stable``
reading after it is within twice its stated uncertainty of the mass the schedule put on the
pan; the plant's description announces each load change at its sample. Ctrl-C ends a run with
exit code 130 and one line; the bridge path weighs through the device emulator; bad
arguments give exit code 2 and a line naming them.
"""

from pathlib import Path
import re
import shlex
import shutil
import sys

import pytest

import ros_harness
from ros_harness import scaled

REPO = Path(__file__).resolve().parents[2]
#: The first start after an install compiles the numba kernels.
TIMEOUT_S = scaled(240.0)
READING = re.compile(r'^t\s+([\d.]+) s\s+mass\s+([+-][\d.]+) g\s+u\s+([\d.]+) mg\s+'
                     r'(stable|unstable|uncalibrated)\b')


def command() -> str:
    return shutil.which('emfc-weigh') or str(Path(sys.executable).parent / 'emfc-weigh')


def readme_line() -> str:
    """The README's one weighing line (in the section on weighing)."""
    text = (REPO / 'README.md').read_text()
    start = text.index('## Weighing in one line')
    block = re.search(r'```bash\n(.*?)```', text[start:], re.S).group(1)
    lines = [line.strip() for line in block.splitlines() if line.strip().startswith('emfc-weigh')]
    assert len(lines) == 1, lines
    return lines[0]


def run(processes, argv, timeout_s=TIMEOUT_S):
    proc = processes.start([command()] + argv)
    assert ros_harness.wait_until(lambda: not proc.alive(), timeout_s), proc.output()
    return proc.proc.returncode, proc.output()


def readings(output):
    """``(time_s, mass_kg, u_kg, flag)`` of every printed reading, in order."""
    out = []
    for line in output.splitlines():
        m = READING.match(line)
        if m:
            out.append((float(m.group(1)), float(m.group(2)) * 1e-3,
                        float(m.group(3)) * 1e-6, m.group(4)))
    return out


def schedule_mass(schedule, t):
    """The mass the schedule puts on the pan at sample time t [s]."""
    mass = 0.0
    for start, kg in schedule:
        if t >= start:
            mass = kg
    return mass


def event_time(output, text):
    for line in output.splitlines():
        if line.startswith('#') and text in line:
            return float(line.split()[1])
    raise AssertionError(f'no event {text!r} in\n{output}')


@pytest.mark.slow
def test_the_readme_weighing_line_runs_as_typed(processes):
    words = shlex.split(readme_line())
    assert words[0] == 'emfc-weigh'
    load = words[words.index('--load') + 1]
    schedule = [tuple(float(v) for v in item.split(':')) for item in load.split(',')]
    code, output = run(processes, words[1:])
    assert code == 0, output
    got = readings(output)
    duration = float(words[words.index('--duration') + 1])
    assert got[-1][0] == pytest.approx(duration)
    assert output.rstrip().splitlines()[-1].endswith(f'done ({len(got)} readings)')
    zero_t = event_time(output, 'zero (from 0 s): done')
    adjust_t = event_time(output, 'adjust with 100 g (from 2 s): done')
    assert zero_t < 2.0 < adjust_t
    # before the first zero: uncalibrated, never stable
    assert all(flag == 'uncalibrated' for t, _, _, flag in got if t <= zero_t)
    stable = [(t, m, u) for t, m, u, flag in got if flag == 'stable']
    assert len(stable) > 20
    for t, mass, u in stable:
        assert t > zero_t
        true = schedule_mass(schedule, t)
        assert abs(mass - true) <= 2.0 * u + 1e-8, (t, mass, true, u)     # printed to 10 ug
    # after the adjustment: the unseen 73.4829 g within a fraction of a milligram
    last = [(t, m, u) for t, m, u in stable if t > adjust_t and schedule_mass(schedule, t) ==
            pytest.approx(0.0734829)]
    assert last and all(abs(m - 0.0734829) < 0.3e-6 and u < 0.5e-6 for _, m, u in last)
    # every load change announced at its sample by the plant's description
    for start, kg in schedule:
        assert event_time(output, f'{kg * 1e3:g} g on the pan (sample '
                                  f'{int(round(start * 10000))}, from the plant') == \
            pytest.approx(start)


@pytest.mark.slow
def test_ctrl_c_ends_a_run_with_one_line_and_130(processes):
    proc = processes.start([command()])          # the defaults: real time, until Ctrl-C
    assert ros_harness.wait_until(lambda: len(readings(proc.output())) >= 3, TIMEOUT_S), \
        proc.output()
    count = len(proc.output().splitlines())
    assert proc.stop() == 130, proc.output()
    after = proc.output().splitlines()[count:]
    tail = [line for line in after if not READING.match(line) and not line.startswith('#')]
    assert len(tail) == 1 and tail[0].startswith('emfc-weigh: interrupted (Ctrl-C) at '), after


@pytest.mark.slow
def test_weighing_through_the_bridge_and_the_device_emulator(processes):
    schedule = [(0.0, 0.0), (1.5, 0.1), (3.0, 0.05)]
    code, output = run(processes, ['--target', 'bridge', '--start-emulator',
                                   '--load', '0:0,1.5:0.1,3:0.05', '--adjust-at', '1.5:0.1',
                                   '--duration', '4.5'])
    assert code == 0, output
    assert '# device emulator on 127.0.0.1:' in output
    event_time(output, 'adjust with 100 g (from 1.5 s): done')
    stable = [(t, m, u) for t, m, u, flag in readings(output) if flag == 'stable']
    for t, mass, u in stable:
        assert abs(mass - schedule_mass(schedule, t)) <= 2.0 * u + 1e-8, (t, mass, u)
    fifty = [m for t, m, u in stable if t > 4.1]
    assert fifty and all(abs(m - 0.05) < 0.3e-6 for m in fifty)
    for start, kg in schedule[1:]:
        event_time(output, f'{kg * 1e3:g} g on the pan (sample {int(start * 10000)}, the '
                           'emulator)')


@pytest.mark.parametrize('argv, text', [
    (['--load', '0:0,1:-3'], "load schedule entry 2 '1:-3': mass must be from 0 to 2 kg"),
    (['--load', '2:0.1,1:0'], 'times must increase'),
    (['--adjust-at', '2'], "--adjust-at: '2' must be time_s:mass_kg"),
    (['--target', 'bridge'], '--target bridge needs --device HOST:PORT or --start-emulator'),
    (['--target', 'bridge', '--device', 'localhost:5555', '--load', '0:0.1'],
     '--load: on a device, put the masses on the pan yourself'),
    (['--speed', '-1'], '--speed'),
    (['--duration', 'nan'], '--duration'),
])
def test_bad_arguments_exit_2_naming_them(processes, argv, text):
    code, output = run(processes, argv, timeout_s=scaled(60.0))
    assert code == 2, output
    assert output.startswith('emfc-weigh: error: ') and text in output, output
    assert len(output.strip().splitlines()) == 1
