"""
README commands run as a user types them, each in a process of its own.

Each test takes its command lines from README.md (``readme_lines``: a changed line is run as
changed, a removed one fails here) and runs them with the defaults they show: console
scripts from ``PATH`` (the activated virtual environment), ``ros2 run emfc_ros <node> ...``
resolved as ``ros2 run`` resolves it (``<prefix>/lib/emfc_ros/<node>`` through
``AMENT_PREFIX_PATH``: there is no ``ros2`` command line here), ``ros2 service call`` done with
rclpy as that command does it. Relative paths in a line (``config/...``) are the repository's:
the test runs the line in the repository or in a folder where ``config`` is the repository's
``config/``. What the lines produce is checked: streams over DDS, the bag read by an
independent reader (rosbags), files written. ``test/readme_commands.yaml`` names these tests
for their lines (``test/test_readme_commands.py``).
"""

import importlib
import json
from pathlib import Path
import re
import shlex
import shutil
import subprocess
import sys

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
import rclpy
from rosbags.highlevel import AnyReader
from std_msgs.msg import Float64MultiArray, String
import yaml

from emfc_ros.core.bag import read_metadata
from emfc_ros.core.stream_counts import CUSTOM_DATA_KEY, from_mapping, problems
from emfc_ros.nodes.convert import BLOCK_QOS, LATCHED_QOS, msg_to_block, msg_to_description
import readme_lines
import ros_harness
from ros_harness import scaled

REPO = Path(__file__).resolve().parents[2]
#: A fresh install compiles the numba kernels on the first start.
START_TIMEOUT_S = scaled(180.0)
TIMEOUT_S = scaled(60.0)
SHIPPED_TRAJECTORY_SAMPLES = 400000


def as_started(argv):
    """
    The process a typed line starts.

    ``ros2 run emfc_ros <node> ARGS`` becomes ``<prefix>/lib/emfc_ros/<node> ARGS`` (what
    ``ros2 run`` executes); any other line is started as typed (``PATH`` lookup).
    """
    if argv[:2] == ['ros2', 'run']:
        return [str(ros_harness.resolve_ros2run(argv[2], argv[3]))] + argv[4:]
    assert argv[0] != 'ros2', f'no stand-in for {argv}'
    return list(argv)


def run(argv, cwd, timeout_s=TIMEOUT_S, env=None):
    """Run a typed command to its end (``PATH`` of the activated environment)."""
    return subprocess.run(as_started(argv), capture_output=True, text=True, cwd=cwd,
                          timeout=timeout_s, env=ros_harness.child_environment(env))


def with_config(folder):
    """A working folder where ``config/`` is the repository's, as in the checkout."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / 'config').symlink_to(REPO / 'config')
    return folder


def service_call(executor, node, argv, timeout_s=TIMEOUT_S):
    """``ros2 service call NAME TYPE`` as the command does it: a client, one request."""
    assert argv[:3] == ['ros2', 'service', 'call'] and len(argv) == 5, argv
    package, kind, name = argv[4].split('/')
    srv = getattr(importlib.import_module(f'{package}.{kind}'), name)
    client = node.create_client(srv, argv[3])
    assert ros_harness.spin_until(executor, client.service_is_ready, timeout_s), argv
    future = client.call_async(srv.Request())
    assert ros_harness.spin_until(executor, future.done, timeout_s), argv
    node.destroy_client(client)
    return future.result()


class Observer:
    """Blocks, descriptions and statuses of one namespace, and /diagnostics."""

    def __init__(self, context, namespace, streams=('excitation',), name='readme_observer'):
        self.node = rclpy.create_node(name, namespace=namespace, context=context)
        self.blocks = {s: [] for s in streams}
        self.descriptions = {}
        self.status = {}
        self.diagnostics = {}
        for stream in streams:
            self.node.create_subscription(
                Float64MultiArray, stream,
                lambda m, s=stream: self.blocks[s].append(msg_to_block(m)), BLOCK_QOS)
            self.node.create_subscription(
                String, f'{stream}/description',
                lambda m, s=stream: self.descriptions.__setitem__(s, msg_to_description(m)),
                LATCHED_QOS)
        for node_name in ('signal_generator', 'recorder'):
            self.node.create_subscription(
                String, f'{node_name}/status',
                lambda m, n=node_name: self.status.__setitem__(n, json.loads(m.data)),
                LATCHED_QOS)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 50)

    def _on_diag(self, msg):
        for status in msg.status:
            self.diagnostics[status.name.split(':')[0].strip()] = (
                status.level, status.message, {kv.key: kv.value for kv in status.values})

    def diag(self, part):
        found = [v for k, v in self.diagnostics.items() if part in k]
        return found[-1] if found else None


def contiguous(blocks):
    firsts = [b.first_sample_index for b in blocks]
    return all(b - a == blk.n_samples for a, b, blk in zip(firsts, firsts[1:], blocks))


# -- the signal generator as installed ------------------------------------------------------


@pytest.mark.parametrize('prefix', [
    'emfc-signal-generator --ros-args -p pacing:=wall',             # Install, 1.
    'ros2 run emfc_ros signal_generator --ros-args -p pacing:=wall',  # Install, 3.
])
def test_the_install_lines_start_the_generator_on_the_shipped_trajectory(
        prefix, tmp_path, processes, executor, ros_context):
    argv = readme_lines.readme_argv(prefix)
    # `export AMENT_PREFIX_PATH=$VIRTUAL_ENV` and LOCALHOST discovery, as the block says.
    env = ros_harness.child_environment()
    assert env['AMENT_PREFIX_PATH'].split(':')[0] == sys.prefix
    assert env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
    program = Path(shutil.which(as_started(argv)[0], path=env['PATH']))
    assert program.parent in (Path(sys.prefix, 'bin'), Path(sys.prefix, 'lib', 'emfc_ros'))
    observer = Observer(ros_context, '/')
    executor.add_node(observer.node)
    generator = processes.start(as_started(argv), cwd=tmp_path)
    assert ros_harness.spin_until(
        executor, lambda: len(observer.blocks['excitation']) >= 5
        and observer.status.get('signal_generator', {}).get('state') == 'running',
        START_TIMEOUT_S), generator.output()
    # No experiment given: the shipped identification trajectory, 1000-sample blocks at
    # wall pace (no consumer needed), on the node's default topics.
    description = observer.descriptions['excitation']
    assert description.total_samples == SHIPPED_TRAJECTORY_SAMPLES
    assert [s['name'] for s in description.extra['sections']] == [
        'coil_chirp', 'load_changer_chirp', 'coil_chirp_load_changer_steps',
        'load_changer_chirp_coil_steps']
    blocks = observer.blocks['excitation']
    assert all(b.n_samples == 1000 for b in blocks) and contiguous(blocks)
    status = observer.status['signal_generator']
    assert status['error'] == '' and not status.get('waiting')
    assert generator.stop() == 0, generator.output()


# -- signal generator in /emfc, the service call, the recorder, the bag tools ---------------


@pytest.mark.slow(seconds=45)
def test_generator_service_call_recorder_and_bag_tools_as_typed(tmp_path, processes, executor,
                                                                ros_context):
    """
    The signal_generator block: the node armed (autostart:=false), a recorder, ~/start.

    The recorder started between the two lines records the whole shipped trajectory from
    sample 0 (40 s at the wall clock's pace); the bag tools then read it.
    """
    observer = Observer(ros_context, '/emfc')
    executor.add_node(observer.node)
    # ros2 run emfc_ros signal_generator --ros-args -r __ns:=/emfc --params-file config/...
    generator_argv = readme_lines.readme_argv(
        'ros2 run emfc_ros signal_generator --ros-args -r __ns:=/emfc --params-file')
    assert 'autostart:=false' in generator_argv
    generator = processes.start(as_started(generator_argv), cwd=REPO)
    assert ros_harness.spin_until(
        executor, lambda: observer.status.get('signal_generator', {}).get('state') == 'armed'
        and 'excitation' in observer.descriptions, START_TIMEOUT_S), generator.output()
    assert observer.descriptions['excitation'].total_samples == SHIPPED_TRAJECTORY_SAMPLES
    assert observer.descriptions['excitation'].source == '/emfc/signal_generator'
    assert observer.blocks['excitation'] == []          # armed: nothing sent yet

    # The recorder section's line, in the user's folder (output:=my_experiment).
    recorder_argv = readme_lines.readme_argv(
        'ros2 run emfc_ros recorder --ros-args -r __ns:=/emfc -p output:=my_experiment')
    recorder = processes.start(as_started(recorder_argv), cwd=tmp_path)
    assert ros_harness.spin_until(
        executor, lambda: '/emfc/excitation' in observer.status.get('recorder', {}).get(
            'topics', []), START_TIMEOUT_S), recorder.output()

    # `ros2 service call /emfc/signal_generator/start std_srvs/srv/Trigger` runs the armed
    # experiment, epoch 1, from sample 0; its end is `done`.
    call = readme_lines.readme_argv('ros2 service call /emfc/signal_generator/start')
    answer = service_call(executor, observer.node, call)
    assert answer.success and answer.message == 'running epoch 1', answer.message
    assert ros_harness.spin_until(
        executor, lambda: observer.status['signal_generator'].get('state') == 'done',
        TIMEOUT_S + 45.0), generator.output()
    assert generator.stop() == 0, generator.output()
    ros_harness.spin_until(executor, lambda: False, 1.5)     # the last blocks reach the bag
    assert recorder.stop() == 0, recorder.output()           # Ctrl-C closes the bag
    assert 'closed' in recorder.output() and ' 0 dropped' in recorder.output()

    bag = tmp_path / 'my_experiment'
    with AnyReader([bag]) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        blocks = [c for c in reader.connections if c.topic == '/emfc/excitation']
        headers = [tuple(int(v) for v in reader.deserialize(raw, c.msgtype).data[:3:2])
                   for c, _, raw in reader.messages(connections=blocks)]
    assert headers == [(first, 1) for first in range(0, SHIPPED_TRAJECTORY_SAMPLES, 1000)]
    assert counts['/emfc/excitation/description'] >= 1       # latched

    # emfc-bag-info my_experiment: the counts the independent reader found.
    info = run(readme_lines.readme_argv('emfc-bag-info my_experiment'), cwd=tmp_path)
    assert info.returncode == 0, info.stderr
    listed = dict(re.findall(r'Topic: (\S+) \| Type: \S+ \| Count: (\d+)', info.stdout))
    assert {t: int(n) for t, n in listed.items()} == counts, info.stdout
    # emfc-bag-repair BAG on the closed bag: intact, left as it is.
    repair = run(['emfc-bag-repair', 'my_experiment'], cwd=tmp_path)
    assert repair.returncode == 0, repair.stderr
    assert re.search(r'_0\.mcap: ok, \d+ messages', repair.stdout), repair.stdout
    with AnyReader([bag]) as reader:
        assert {c.topic: c.msgcount for c in reader.connections} == counts


# -- the device emulator and the bridge ------------------------------------------------------


def _bridge_blocks(executor, observer, bridge, n=10):
    assert ros_harness.spin_until(
        executor, lambda: len(observer.blocks['measurements']) >= n
        and observer.diag('daq_bridge') is not None, START_TIMEOUT_S), bridge.output()
    return observer.blocks['measurements']


def test_device_emulator_and_bridge_lines_as_typed(tmp_path, processes, executor, ros_context):
    observer = Observer(ros_context, '/emfc', streams=('measurements',))
    executor.add_node(observer.node)
    emulator_argv = readme_lines.readme_argv('emfc-device-emulator --port 5555')
    emulator = processes.start(as_started(emulator_argv), cwd=tmp_path)
    assert ros_harness.wait_until(lambda: 'listening on' in emulator.output(), TIMEOUT_S), \
        emulator.output()
    assert emulator.output().splitlines()[0] == '5555'
    bridge_argv = readme_lines.readme_argv(
            'ros2 run emfc_ros daq_bridge --ros-args -r __ns:=/emfc --params-file '
            'config/daq_bridge_udp.yaml -p udp.device_port:=5555')
    params = yaml.safe_load((REPO / 'config' / 'daq_bridge_udp.yaml').read_text())
    inputs = params['/**']['ros__parameters']['inputs']
    bridge = processes.start(as_started(bridge_argv), cwd=REPO)
    blocks = _bridge_blocks(executor, observer, bridge)
    # The device's stream from the udp back-end (autostart in the params file), its
    # channels, contiguous on the device's sample clock.
    assert contiguous(blocks) and all(b.n_samples == 1000 for b in blocks)
    assert list(observer.descriptions['measurements'].channel_names) == inputs
    level, message, values = observer.diag('daq_bridge')
    assert values['backend'] == 'udp' and values['state'] == 'running', values
    assert level != DiagnosticStatus.ERROR, message
    assert bridge.stop() == 0, bridge.output()
    assert emulator.stop() == 0, emulator.output()


def test_the_daq_bridge_page_lines_as_typed(tmp_path, processes, executor, ros_context):
    """
    docs/daq_bridge.md's first block: the emulator and both ``ros2 run`` bridge lines.

    With the emulator's default (six analog inputs) the bridge's default inputs and those of
    ``config/daq_bridge_udp.yaml`` are served (a 4-input default made the first bridge line
    retry every 5 s for ever with no measurement).
    """
    argvs = readme_lines.fenced_argvs((REPO / 'docs' / 'daq_bridge.md').read_text())
    emulator_argv = next(a for a in argvs if a[0] == 'emfc-device-emulator')
    bridges = [a for a in argvs if a[:4] == ['ros2', 'run', 'emfc_ros', 'daq_bridge']][:2]
    assert emulator_argv == ['emfc-device-emulator', '--port', '5555', '&']
    assert len(bridges) == 2 and '--params-file' in bridges[1], bridges
    emulator = processes.start(as_started(emulator_argv[:-1]), cwd=tmp_path)
    assert ros_harness.wait_until(lambda: 'listening on' in emulator.output(), TIMEOUT_S)
    for k, argv in enumerate(bridges):
        observer = Observer(ros_context, '/emfc', streams=('measurements',),
                            name=f'bridge_page_{k}')
        executor.add_node(observer.node)
        bridge = processes.start(as_started(argv), cwd=REPO)
        blocks = _bridge_blocks(executor, observer, bridge)
        assert contiguous(blocks) and all(b.n_samples == 1000 for b in blocks)
        assert len(observer.descriptions['measurements'].channel_names) == 6
        level, message, values = observer.diag('daq_bridge')
        assert values['state'] == 'running' and level != DiagnosticStatus.ERROR, message
        assert bridge.stop() == 0, bridge.output()
        executor.remove_node(observer.node)
        observer.node.destroy_node()
        ros_harness.spin_until(executor, lambda: False, 0.5)
    assert emulator.stop() == 0, emulator.output()


def test_the_table_emulator_lines_open_and_close_the_loop(
        tmp_path, processes, executor, ros_context):
    """``emfc-device-emulator`` (table) and ``... --control-crossover-Hz 130`` (prose)."""
    positions = {}
    for k, argv in enumerate([readme_lines.readme_argv('emfc-device-emulator'),
                              readme_lines.readme_argv('emfc-device-emulator',
                                                       '--control-crossover-Hz')]):
        observer = Observer(ros_context, '/emfc', streams=('measurements',),
                            name=f'emulator_observer_{k}')
        executor.add_node(observer.node)
        emulator = processes.start(as_started(argv), cwd=tmp_path)
        assert ros_harness.wait_until(lambda: 'listening on 127.0.0.1' in emulator.output(),
                                      TIMEOUT_S), emulator.output()
        port = int(emulator.output().splitlines()[0])       # default --port 0: any free one
        # The README's bridge line with this device's port.
        typed = readme_lines.readme_argv(
            'ros2 run emfc_ros daq_bridge --ros-args -r __ns:=/emfc --params-file '
            'config/daq_bridge_udp.yaml -p udp.device_port:=5555')
        bridge_argv = [f'udp.device_port:={port}' if a.startswith('udp.device_port:=') else a
                       for a in typed]
        bridge = processes.start(as_started(bridge_argv), cwd=REPO)
        blocks = _bridge_blocks(executor, observer, bridge, n=20)
        names = observer.descriptions['measurements'].channel_names
        position = np.concatenate([b.samples[names.index('position_m')]
                                   for b in blocks[-10:]])
        positions[' '.join(argv)] = float(np.mean(np.abs(position)))
        assert bridge.stop() == 0, bridge.output()
        assert emulator.stop() == 0, emulator.output()
        executor.remove_node(observer.node)
        observer.node.destroy_node()
    open_loop, closed_loop = positions.values()
    # Empty pan, 0 V on the coil: open loop the soft lever rests on a stop (more than 50 um
    # away); the device's position controller holds it at 0 (within 2 um).
    assert open_loop > 50e-6, positions
    assert closed_loop < 2e-6, positions


# -- offline commands ------------------------------------------------------------------------


def test_emfc_demo_as_typed(tmp_path):
    result = run(readme_lines.readme_argv('emfc-demo'), cwd=tmp_path, timeout_s=scaled(300))
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    out = tmp_path / 'out' / 'demo'
    for name in ('excitation.npy', 'excitation.csv', 'summary.md', 'summary.json'):
        assert (out / name).is_file(), name
    samples = np.load(out / 'excitation.npy')
    assert SHIPPED_TRAJECTORY_SAMPLES in samples.shape and 2 in samples.shape
    assert 'gaps 0, duplicates 0, reordered 0' in (out / 'summary.md').read_text()


def test_generate_model_summary_and_simulate_as_typed(tmp_path):
    folder = with_config(tmp_path / 'checkout')
    # emfc-generate config/identification_trajectory.yaml -o excitation.csv
    generate = run(readme_lines.readme_argv('emfc-generate config/'), cwd=folder)
    assert generate.returncode == 0, generate.stderr
    excitation = np.loadtxt(folder / 'excitation.csv', delimiter=',', skiprows=1)
    assert excitation.shape == (SHIPPED_TRAJECTORY_SAMPLES, 4)
    # emfc-generate CONFIG -o OUT.csv is the same command: CONFIG and OUT are the user's.
    assert readme_lines.readme_command('emfc-generate CONFIG -o OUT.csv')
    # emfc-model-summary [--config FILE]: both forms, the same numbers for the shipped file.
    plain = run(['emfc-model-summary'], cwd=folder)
    given = run(['emfc-model-summary', '--config', 'config/balance_default.yaml'], cwd=folder)
    assert readme_lines.readme_command('emfc-model-summary [--config FILE]')
    assert plain.returncode == 0 and given.returncode == 0, plain.stderr + given.stderr
    summary, from_file = yaml.safe_load(plain.stdout), yaml.safe_load(given.stdout)
    assert summary['configuration']['parameters'] == 'built-in defaults'
    assert from_file['configuration']['parameters'] == 'config/balance_default.yaml'
    for doc in (summary, from_file):
        doc.pop('configuration')
    assert summary == from_file and summary
    # emfc-simulate EXCITATION -o OUT with the excitation just written.
    assert readme_lines.readme_command('emfc-simulate EXCITATION -o OUT')
    simulate = run(['emfc-simulate', 'excitation.csv', '-o', 'response.npy'], cwd=folder,
                   timeout_s=scaled(300))
    assert simulate.returncode == 0, simulate.stderr
    response = np.load(folder / 'response.npy')
    assert SHIPPED_TRAJECTORY_SAMPLES in response.shape


def test_another_plan_as_typed(tmp_path):
    """``emfc-experiment my_plan.yaml -o out/run1``: a user's short plan, counts that add up."""
    (tmp_path / 'chirp.yaml').write_text(yaml.safe_dump({'experiment': {
        'sample_rate_Hz': 10000.0, 'sections': ['chirp'], 'section': {'chirp': {
            'duration_s': 3.0, 'coil': {'signals': {'c': {
                'type': 'chirp', 'amplitude_V': 0.002, 'f_start_Hz': 5.0,
                'f_stop_Hz': 500.0, 'method': 'logarithmic'}}}}}}}))
    (tmp_path / 'my_plan.yaml').write_text(yaml.safe_dump({'run': {
        'name': 'my_plan', 'experiment_files': ['chirp.yaml'],
        'simulator': {'state_rate_Hz': 100.0},
        'identification': {'enabled': False}}}))
    result = run(readme_lines.readme_argv('emfc-experiment my_plan.yaml'), cwd=tmp_path,
                 timeout_s=scaled(600))
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    out = tmp_path / 'out' / 'run1'
    assert (out / 'bag' / 'metadata.yaml').is_file() and (out / 'summary.md').is_file()
    custom = read_metadata(out / 'bag')['custom_data']
    counts = {c.topic: c for c in from_mapping(yaml.safe_load(custom[CUSTOM_DATA_KEY]))}
    assert problems(counts.values()) == []
    # 30 blocks of 1000 samples; 100 Hz states: 10 per block, limited in wall time
    states = counts['/emfc/joint_states']
    assert states.due == 300 and states.published + states.decimated == 300
    with AnyReader([out / 'bag']) as reader:
        recorded = {c.topic: c.msgcount for c in reader.connections}
    assert {t: c.recorded for t, c in counts.items()} == recorded
    assert counts['/emfc/measurements'].published == recorded['/emfc/measurements'] == 30


def test_a_benchmark_as_typed():
    """``./tools/bench.sh <name> [args]`` as docs/benchmarks.md types it for bench_signals."""
    assert readme_lines.readme_command('./tools/bench.sh <name>')
    lines = re.findall(r'`(\./tools/bench\.sh bench_signals)`',
                       (REPO / 'docs' / 'benchmarks.md').read_text())
    assert lines, 'docs/benchmarks.md shows `./tools/bench.sh bench_signals`'
    readme_lines.check_tools_venv()
    results = REPO / 'bench' / 'results' / 'signals.json'
    kept = results.read_bytes() if results.is_file() else None   # a user's earlier figures
    try:
        result = run(shlex.split(lines[0]), cwd=REPO, timeout_s=scaled(600),
                     env={'EMFC_VENV': sys.prefix})
        assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
        assert 'setup_env:' not in result.stderr, result.stderr      # the venv was current
        figures = json.loads(results.read_text())
        assert figures and f'wrote {results}' in result.stdout
    finally:
        if kept is not None:
            results.write_bytes(kept)
        elif results.is_file():
            results.unlink()


def test_the_test_tool_with_pytest_args_as_typed():
    """``./tools/test.sh [pytest args]`` with a small test file as the argument."""
    assert readme_lines.readme_command('./tools/test.sh [pytest args]')
    readme_lines.check_tools_venv()
    result = run(['./tools/test.sh', 'test/test_core_purity.py'], cwd=REPO, timeout_s=scaled(600),
                 env={'EMFC_VENV': sys.prefix})
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    assert 'setup_env:' not in result.stderr, result.stderr
    assert re.search(r'\b\d+ passed\b', result.stdout) and 'failed' not in result.stdout
    # The tool says how it isolated DDS: the session's domain id, loopback only.
    assert f'ROS_DOMAIN_ID={ros_harness.session_domain_id()}' in result.stderr
