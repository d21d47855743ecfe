"""
The launch files as users run them: ``ros2 launch emfc_ros <file> [name:=value ...]``.

With the real ROS 2 Jazzy command line installed (``tools/setup_env.sh`` installs it from
``../shared/ros2-jazzy-cli``; CI has it) the job tests run every documented line with the
real ``ros2 launch`` in a process of its own, and the other documented commands of the
sequence (``ros2 run``, ``ros2 service call``, ``ros2 topic echo``) as typed. Without it they
evaluate the INSTALLED files (``<venv>/share/emfc_ros/launch``) with the test stand-in
``test/launch_stub`` (the Jazzy API subset they use, refusing the rest) and start each
``Node`` as the command ``ros2 launch`` would run; the output says which ran
(``launch_tool.which_tools``). The stand-in also evaluates every file with the declared
defaults and every documented argument line to check the nodes' parameters.

Each job is checked to its end: the whole default trajectory answered through the simulator
from sample 0 and the bag identified, the hardware experiment through the device emulator
with no start fault and identified, the recorded bag replayed to its ``done`` status, the
signal generator's stream recorded from its first block, the weighing example showing its
mass, two simulated balances side by side in two namespaces with their own clocks.
"""

import ast
import json
from pathlib import Path
import re
import shlex
import subprocess
import sys
import textwrap

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
import rclpy
from rosbags.highlevel import AnyReader
from std_msgs.msg import Bool, Float64MultiArray, String
from std_srvs.srv import Trigger
import yaml

from emfc_ros.core.bag import read_streams
from emfc_ros.core.config import unflatten
from emfc_ros.core.signals.spec import load_experiment_file
from emfc_ros.nodes import daq_bridge, plant_simulator, signal_generator, weighing
from emfc_ros.nodes.convert import (
    BLOCK_QOS, LATCHED_QOS, msg_to_block, msg_to_description)
import launch_tool
import readme_lines
import ros_harness
from ros_harness import scaled

REPO = Path(__file__).resolve().parents[2]
STUB = REPO / 'test' / 'launch_stub'
PACKAGE = 'emfc_ros'
#: Every launch file of the package (each has a job test below).
LAUNCH_FILES = tuple(sorted(p.name for p in (REPO / 'launch').glob('*.launch.py')))
JOB_TESTED = {'sim_experiment.launch.py', 'hardware_experiment.launch.py',
              'replay.launch.py', 'signal_generator.launch.py', 'weigh.launch.py'}
#: The files whose plant publishes simulated time (clock_topic remaps /clock for each node).
CLOCKED = {'sim_experiment.launch.py', 'weigh.launch.py'}
#: The declared parameters of each node executable, to check the launch files' types.
NODE_PARAMETERS = {'signal_generator': signal_generator.PARAMETERS,
                   'plant_simulator': plant_simulator.PARAMETERS,
                   'daq_bridge': daq_bridge.PARAMETERS,
                   'weighing': weighing.PARAMETERS}
#: The first plant start after an install compiles the simulator kernel (12-17 s measured).
START_TIMEOUT_S = scaled(180.0)
TIMEOUT_S = scaled(60.0)
DAC_LSB_V = 20.0 / 65536
SHIPPED_SAMPLES = 400000
#: How long a recorder may take to get the last clock ticks after the last block: a tick its
#: first transmission missed comes with the writer's periodic heartbeat (docs/recording.md).
LATE_TICKS_S = 10.0
#: A placeholder in documented argument values (``bag:=out/identification-.../bag``).
PLACEHOLDER = '...'

#: A short wall-paced experiment for the hardware lines with arguments (0.5 s; the README's
#: line runs the default, 40 s).
SHORT_EXPERIMENT = {
    'sample_rate_Hz': 10000.0,
    'sections': ['sine'],
    'section.sine.duration_s': 0.5,
    'section.sine.coil.signals.s.type': 'sine',
    'section.sine.coil.signals.s.amplitude_V': 0.2,
    'section.sine.coil.signals.s.frequency_Hz': 20.0,
}


@pytest.fixture(scope='module')
def stub():
    """``ros2launch_stub`` with the stand-in ``launch``/``launch_ros`` importable."""
    forget_launch_modules()
    sys.path.insert(0, str(STUB))
    import ros2launch_stub
    yield ros2launch_stub
    sys.path.remove(str(STUB))
    sys.meta_path[:] = [f for f in sys.meta_path
                        if type(f).__name__ != 'RefuseOtherModules']
    forget_launch_modules()


def forget_launch_modules():
    """Drop ``launch``, ``launch_ros`` and what imported them (the stand-in or the real)."""
    for name in list(sys.modules):
        if name.split('.')[0] in ('launch', 'launch_ros', 'ros2launch_stub') or \
                name == 'emfc_ros.launch_support':
            del sys.modules[name]


def installed(stub, file_name):
    """The installed launch file, found as ``ros2 launch emfc_ros <file>`` finds it."""
    path = stub.find_launch_file(PACKAGE, file_name)
    assert path == Path(sys.prefix, 'share', PACKAGE, 'launch', file_name), path
    return path


def documented_lines(stub, file_name):
    """
    Every ``ros2 launch emfc_ros <file> ...`` line of the docs and the docstring.

    The user docs (README.md and its guide pages) come first, then the other docs pages.

    Returns
    -------
    list of (str, list of str)
        Where the line is first found, and its launch arguments (each distinct list once).
    """
    docstring = ast.get_docstring(ast.parse(installed(stub, file_name).read_text()))
    guide = [str(p.relative_to(REPO)) for p in readme_lines.GUIDE_PAGES]
    sources = [(name, (REPO / name).read_text()) for name in guide]
    sources += [(f'docs/{p.name}', p.read_text()) for p in sorted((REPO / 'docs').glob('*.md'))
                if f'docs/{p.name}' not in guide]
    sources.append((f'{file_name} docstring', docstring))
    out = {}
    for where, text in sources:
        for line in text.splitlines():
            if re.search(rf'ros2 launch {PACKAGE} {re.escape(file_name)}(\s|$)', line):
                package, name, args = stub.split_ros2_launch(line)
                assert (package, name) == (PACKAGE, file_name)
                out.setdefault(tuple(args), where)
    return [(where, list(args)) for args, where in out.items()]


def fill_placeholders(args, **values):
    """Replace documented placeholder values (containing '...') with real ones."""
    out = []
    for arg in args:
        name, value = arg.split(':=', 1)
        if PLACEHOLDER in value:
            value = str(values[name])
        out.append(f'{name}:={value}')
    return out


def evaluate(stub, tmp_path, file_name, args):
    return stub.launch(installed(stub, file_name), args, tmp_path / 'launch_params')


def start(processes, launched):
    """Start every node process as ``ros2 launch`` does: its command and environment."""
    return {p.executable: processes.start(p.cmd, env=p.additional_env)
            for p in launched.processes}


def _write_experiment(path, flat):
    path.write_text(yaml.safe_dump({'experiment': unflatten(flat)}))
    return path


# -- evaluation: every file, defaults and documented lines --------------------------------


def test_every_launch_file_has_a_job_test():
    assert set(LAUNCH_FILES) == JOB_TESTED


@pytest.mark.parametrize('file_name', LAUNCH_FILES)
def test_each_launch_file_is_installed_and_documented(stub, file_name):
    assert installed(stub, file_name).is_file()
    assert documented_lines(stub, file_name), f'no `ros2 launch {PACKAGE} {file_name}` line'


@pytest.mark.parametrize('file_name', LAUNCH_FILES)
def test_defaults_and_documented_lines_give_nodes_with_the_right_parameters(
        stub, tmp_path, file_name):
    lines = [('defaults', [])] + documented_lines(stub, file_name)
    if file_name == 'replay.launch.py':
        lines[0] = ('defaults', ['bag:=recorded_bag'])      # the one required argument
    for where, args in lines:
        launched = evaluate(stub, tmp_path, file_name, args)
        assert launched.context.warnings == [], (where, launched.context.warnings)
        assert launched.processes, where
        given = dict(a.split(':=', 1) for a in args)
        namespace = '/' + given.get('namespace', 'emfc')
        for proc in launched.processes:
            assert proc.namespace == namespace and proc.node_name == proc.executable, where
            assert proc.cmd[:6] == [str(ros_harness.resolve_ros2run(PACKAGE, proc.executable)),
                                    '--ros-args', '-r', f'__node:={proc.executable}',
                                    '-r', f'__ns:={namespace}'], (where, proc.cmd)
            # The instance's clock: /clock unless the line gives the namespace's own.
            if file_name in CLOCKED:
                clock = given.get('clock_topic', '/clock')
                assert proc.cmd[-2:] == ['-r', f'/clock:={clock}'], (where, proc.cmd)
            # Loopback-only discovery unless the line says otherwise (discovery_range).
            assert proc.additional_env == {
                'ROS_AUTOMATIC_DISCOVERY_RANGE': given.get('discovery_range', 'LOCALHOST')}
            declared = NODE_PARAMETERS[proc.executable]
            for entry in proc.parameters:
                if isinstance(entry, str):                  # a params file
                    assert Path(entry).is_file(), (where, entry)
                    continue
                for key, value in entry.items():
                    if key == 'use_sim_time':
                        assert value is True
                        continue
                    if key.startswith(('experiment.', 'balance.')):
                        continue                    # parameter groups the nodes read
                    assert key in declared, (where, proc.executable, key)
                    default = declared[key][0]
                    assert type(value) is type(default), (where, key, value, default)
                    if key.endswith('_file') and where == 'defaults':
                        assert Path(value).is_file(), (where, key, value)
                        assert Path(value).parent == Path(sys.prefix, 'share', PACKAGE,
                                                          'config'), value


@pytest.mark.parametrize('file_name', LAUNCH_FILES)
def test_every_launch_configuration_used_is_declared(stub, tmp_path, file_name):
    args = ['bag:=b'] if file_name == 'replay.launch.py' else []
    launched = evaluate(stub, tmp_path, file_name, args)
    declared = {a.name for a in launched.description.get_launch_arguments()}
    used = set(launched.context.configurations_used)
    assert used and used <= declared, used - declared
    assert set(launched.context.launch_configurations) == declared


def test_the_stand_in_behaves_like_ros2_launch(stub, tmp_path):
    replay = 'replay.launch.py'
    # A required argument that is missing is an error naming it.
    with pytest.raises(RuntimeError, match="missing required argument 'bag'"):
        evaluate(stub, tmp_path, replay, [])
    with pytest.raises(RuntimeError, match="malformed launch argument 'bag'"):
        evaluate(stub, tmp_path, replay, ['bag'])
    with pytest.raises(RuntimeError, match='malformed'):
        evaluate(stub, tmp_path, replay, ['topic:='])
    # The last of a repeated argument wins.
    plain = evaluate(stub, tmp_path, replay, ['bag:=b1'])
    twice = evaluate(stub, tmp_path, replay, ['bag:=b0', 'bag:=b1'])
    assert [p.parameters for p in twice.processes] == [p.parameters for p in plain.processes]
    assert plain.processes[0].parameters[0]['replay.bag'] == 'b1'
    # An argument the file does not declare ends the launch, naming it (our files check
    # ros2 launch's command line; the tool itself would set it and ignore it).
    with pytest.raises(RuntimeError, match='does not take the argument.s. not_declared '):
        evaluate(stub, tmp_path, replay, ['bag:=b0', 'not_declared:=7'])
    # ParameterValue(value_type=...) converts and refuses bad text.
    assert evaluate(stub, tmp_path, replay, ['bag:=b', 'speed:=2']).processes[0] \
        .parameters[0]['replay.speed'] == 2.0
    with pytest.raises(ValueError):
        evaluate(stub, tmp_path, replay, ['bag:=b', 'speed:=fast'])
    hardware = 'hardware_experiment.launch.py'
    for bad in ('device_port:=5555.5', 'device_port:=port', 'block_size:=1e3'):
        with pytest.raises(ValueError):
            evaluate(stub, tmp_path, hardware, [bad])
    # Without a type, values follow YAML rules as in the real Node.
    topic = evaluate(stub, tmp_path, replay, ['bag:=b', 'topic:=/a/measurements'])
    assert topic.processes[0].parameters[0]['replay.topic'] == '/a/measurements'
    # FindPackageShare: the install prefix's share/emfc_ros.
    sim = evaluate(stub, tmp_path, 'sim_experiment.launch.py', [])
    assert sim.context.launch_configurations['balance_file'] == str(
        Path(sys.prefix, 'share', PACKAGE, 'config', 'balance_default.yaml'))
    # A params file that is not a file: a warning, and the node starts without it.
    missing = evaluate(stub, tmp_path, hardware, ['bridge_params_file:=/nonexistent.yaml'])
    assert missing.context.warnings == ['Parameter file path is not a file: /nonexistent.yaml']
    assert '/nonexistent.yaml' not in missing.processes[0].cmd
    # choices: a value outside them is an error naming the valid ones; a bad declaration
    # fails at once.
    with pytest.raises(RuntimeError, match='Argument "discovery_range" provided value '
                                           '"subnet" is not valid. Valid options are'):
        evaluate(stub, tmp_path, hardware, ['discovery_range:=subnet'])
    from launch.actions import DeclareLaunchArgument
    with pytest.raises(RuntimeError, match='choices arg is empty'):
        DeclareLaunchArgument('a', default_value='x', choices=[])
    with pytest.raises(RuntimeError, match='is not in provided choices'):
        DeclareLaunchArgument('a', default_value='x', choices=['y'])
    assert DeclareLaunchArgument('a', default_value='x', description='A',
                                 choices=['x']).description == "A. Valid choices are: ['x']"


@pytest.mark.parametrize('file_name', LAUNCH_FILES)
def test_the_discovery_range_is_loopback_unless_chosen(stub, tmp_path, file_name):
    args = ['bag:=b'] if file_name == 'replay.launch.py' else []
    for value in ('LOCALHOST', 'SUBNET', 'OFF', 'SYSTEM_DEFAULT', None):
        line = args + ([f'discovery_range:={value}'] if value else [])
        launched = evaluate(stub, tmp_path, file_name, line)
        for proc in launched.processes:
            assert proc.additional_env == {
                'ROS_AUTOMATIC_DISCOVERY_RANGE': value or 'LOCALHOST'}, (file_name, value)
            # Only the range is set: ROS_STATIC_PEERS and ROS_DOMAIN_ID come from the shell.
            assert not {'ROS_STATIC_PEERS', 'ROS_DOMAIN_ID'} & set(proc.additional_env)


@pytest.mark.parametrize('source', [
    'from launch.actions import GroupAction',
    'from launch_ros.actions import ComposableNodeContainer',
    'from launch.substitutions import EnvironmentVariable',
    'from launch.conditions import IfCondition',
    'from launch_ros.actions import Node\n'
    "Node(package='emfc_ros', executable='recorder', respawn=True)",
    'from launch.actions import DeclareLaunchArgument\n'
    "DeclareLaunchArgument('a', default_value='x', condition=None)",
    'from launch.substitutions import LaunchConfiguration\n'
    "LaunchConfiguration('a', default='x')",
    'from launch_ros.parameter_descriptions import ParameterValue\n'
    'from typing import List\n'
    "ParameterValue('[1]', value_type=List[int])",
    'from launch_ros.actions import Node\n'
    "Node(package='emfc_ros', executable='recorder', parameters=[{'topics': ['a', 'b']}])",
])
def test_the_stand_in_refuses_what_it_does_not_implement(stub, source):
    import launch
    with pytest.raises(launch.UnsupportedByStub, match='test stand-in'):
        exec(compile(source, '<launch file>', 'exec'), {})


def test_an_undeclared_launch_configuration_fails_at_launch_time(stub, tmp_path):
    path = tmp_path / 'undeclared.launch.py'
    path.write_text(textwrap.dedent("""
        from launch import LaunchDescription
        from launch.substitutions import LaunchConfiguration
        from launch_ros.actions import Node


        def generate_launch_description():
            return LaunchDescription([Node(
                package='emfc_ros', executable='recorder', name='recorder',
                parameters=[{'output': LaunchConfiguration('output')}])])
    """))
    from launch.substitutions import SubstitutionFailure
    with pytest.raises(SubstitutionFailure, match="launch configuration 'output' does not"):
        stub.launch(path, [], tmp_path)
    # Given on the command line it works, as with the real tool.
    launched = stub.launch(path, ['output:=x'], tmp_path)
    assert launched.processes[0].parameters == [{'output': 'x'}]


# -- the jobs: ros2 launch (or the stand-in) and the documented commands as processes --------


@pytest.fixture(scope='module')
def tools(stub):
    """Which tools run the jobs; printed so that the test output says it."""
    line = launch_tool.which_tools()
    print(line)
    yield stub
    launch_tool.stop_ros2_daemon()


def start_launch(stub, file_name, args, log_dir, cwd=None):
    """``ros2 launch emfc_ros FILE ARGS``: the real tool, or the stand-in's processes."""
    line = ' '.join(['ros2 launch', PACKAGE, file_name, *args])
    print(f'{line}  ({launch_tool.which_tools()})')
    return launch_tool.start_launch(stub, PACKAGE, file_name, args, log_dir, cwd=cwd)


def typed(argv, log_dir, cwd=None, env=None):
    """Start a documented command line in a process of its own, the way it is typed."""
    return launch_tool.TypedProcess(launch_tool.as_started(argv), log_dir, env=env, cwd=cwd)


def run_to_end(argv, cwd, timeout_s=scaled(300.0)):
    """A documented command that ends by itself (``emfc-identify``), as typed."""
    return subprocess.run(launch_tool.as_started(argv), capture_output=True, text=True,
                          cwd=cwd, timeout=timeout_s, env=ros_harness.child_environment())


class Session:
    """An rclpy context and executor of the test's own, for observers."""

    def __init__(self):
        ros_harness.isolate_environment()
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context, domain_id=ros_harness.session_domain_id())
        from rclpy.executors import SingleThreadedExecutor
        self.executor = SingleThreadedExecutor(context=self.context)
        self.nodes = []

    def observer(self, **kwargs):
        observer = Observer(self.context, **kwargs)
        self.executor.add_node(observer.node)
        self.nodes.append(observer.node)
        return observer

    def spin_until(self, predicate, timeout_s):
        return ros_harness.spin_until(self.executor, predicate, timeout_s)

    def close(self):
        for node in self.nodes:
            self.executor.remove_node(node)
            node.destroy_node()
        self.executor.shutdown(timeout_sec=1.0)
        rclpy.try_shutdown(context=self.context)


class Observer:
    """
    Watches a namespace: generator status and done, bridge status, /diagnostics, blocks.

    It subscribes to no block stream unless asked (``measurements``, ``excitation``): a
    subscription counts for the start gates, as a recorder's does.
    """

    def __init__(self, context, measurements=False, excitation=False, name='launch_observer',
                 namespace='/emfc'):
        self.node = rclpy.create_node(name, namespace=namespace, context=context)
        self.status = None
        self.done = None
        self.bridge_status = None
        self.diagnostics = {}
        self.blocks = {'measurements': [], 'excitation': []}
        self.descriptions = {}
        self.node.create_subscription(
            String, 'signal_generator/status',
            lambda m: setattr(self, 'status', json.loads(m.data)), LATCHED_QOS)
        self.node.create_subscription(Bool, 'signal_generator/done',
                                      lambda m: setattr(self, 'done', m.data), LATCHED_QOS)
        self.node.create_subscription(
            String, 'daq_bridge/status',
            lambda m: setattr(self, 'bridge_status', json.loads(m.data)), LATCHED_QOS)
        self.node.create_subscription(
            String, 'measurements/description',
            lambda m: self.descriptions.__setitem__('measurements', msg_to_description(m)),
            LATCHED_QOS)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 100)
        self.namespace = namespace
        for topic, wanted in (('measurements', measurements), ('excitation', excitation)):
            if wanted:
                self.listen(topic)

    def listen(self, topic):
        """Subscribe to a block stream (a listener the start gates count)."""
        self.node.create_subscription(
            Float64MultiArray, topic,
            lambda m: self.blocks[topic].append(msg_to_block(m)), BLOCK_QOS)

    def _on_diag(self, msg):
        for status in msg.status:
            self.diagnostics[status.hardware_id] = (status.level, status.message,
                                                    {kv.key: kv.value for kv in status.values})

    def diag(self, part):
        """The latest diagnostics of this namespace's node whose name contains ``part``."""
        for fqn, value in self.diagnostics.items():
            if fqn.startswith(self.namespace.rstrip('/') + '/') and part in fqn.split('/')[-1]:
                return value
        return None

    def recorded(self, topic):
        """Messages of ``topic`` the namespace's recorder reports written."""
        diag = self.diag('recorder')
        return int(diag[2].get(f'messages {topic}', 0)) if diag else 0


def read_bag(bag):
    """The bag's block streams and its simulated clock, read by independent readers."""
    streams = read_streams(bag)
    with AnyReader([Path(bag)]) as reader:
        clocks = [c for c in reader.connections if c.msgtype == 'rosgraph_msgs/msg/Clock']
        ticks = {c.topic: [] for c in clocks}
        for conn, stamp, raw in reader.messages(connections=clocks):
            msg = reader.deserialize(raw, conn.msgtype)
            ticks[conn.topic].append((stamp, msg.clock.sec * 10 ** 9 + msg.clock.nanosec))
        custom = dict(reader.custom_data) if hasattr(reader, 'custom_data') else {}
    return streams, ticks, custom


def check_sim_bag(bag, ns, experiment, clock_topic='/clock'):
    """The whole trajectory from sample 0, exact, once; simulated time monotonic, no loss."""
    streams, ticks, _ = read_bag(bag)
    total = experiment.total_samples
    meas = streams[f'{ns}/measurements']
    assert (meas.first_sample_index, meas.n_samples) == (0, total)
    assert meas.gaps == [] and meas.duplicates == 0
    assert list(meas.block_first_index) == list(range(0, total, 1000))
    names = meas.channel_names
    expected = experiment.block(0, total)
    np.testing.assert_allclose(meas.samples[names.index('coil_setpoint_V')], expected[0],
                               atol=DAC_LSB_V)
    np.testing.assert_allclose(meas.samples[names.index('load_changer_setpoint_V')],
                               expected[1], atol=DAC_LSB_V)
    exc = streams[f'{ns}/excitation']
    assert exc.first_sample_index == 0 and exc.n_samples == total and exc.duplicates == 0
    # Simulated time: one tick per block on this instance's clock only, none lost from the
    # recorder's first (a recorder discovers each topic's publisher on its own poll, so it
    # may subscribe to the clock a few blocks into the run: the blocks themselves are held
    # for it, the ticks are not), to the end; the messages are stamped with it in order.
    assert list(ticks) == [clock_topic], list(ticks)
    sim_ns = [t for _, t in ticks[clock_topic]]
    tick_ns = 1000 * 10 ** 9 // int(experiment.sample_rate_Hz)
    assert sim_ns == list(range(sim_ns[0], total * 10 ** 9 // int(experiment.sample_rate_Hz)
                                + 1, tick_ns)), (sim_ns[:3], len(sim_ns))
    print(f'{clock_topic}: recorded from tick {sim_ns[0] // tick_ns} of {total // 1000}')
    stamps = [s for s, _ in ticks[clock_topic]]
    assert all(b >= a for a, b in zip(stamps, stamps[1:]))
    assert all(b >= a for a, b in zip(meas.block_receive_time_ns, meas.block_receive_time_ns[1:]))
    return streams


SIM_RECORDER = 'ros2 run emfc_ros recorder --ros-args -r __ns:=/emfc -p use_sim_time:=true'


def _sim_experiment(stub, folder, order):
    """
    The guide's sim_experiment line and its recorder line, in the given start order.

    Both are docs/nodes.md's.

    Returns what was seen and the bag; the launch and the recorder are stopped (Ctrl-C).
    """
    where, args = documented_lines(stub, 'sim_experiment.launch.py')[0]
    assert where == 'docs/nodes.md'
    experiment = load_experiment_file(Path(sys.prefix, 'share', PACKAGE, 'config',
                                           'identification_trajectory.yaml'))
    n_blocks = -(-experiment.total_samples // 1000)
    session = Session()
    observer = session.observer(name='sim_observer')
    logs = folder / 'logs'
    recorder_line = readme_lines.readme_argv(SIM_RECORDER)
    assert 'output:=my_experiment' in recorder_line
    started = []
    try:
        for what in (('launch', 'recorder') if order == 'launch first' else
                     ('recorder', 'launch')):
            if what == 'launch':
                started.append(start_launch(stub, 'sim_experiment.launch.py', args, logs))
            else:
                started.append(typed(recorder_line, logs, cwd=folder))
            # the second a few seconds later, as a user types it
            session.spin_until(lambda: False, 2.0)
        launch, recorder = started if order == 'launch first' else started[::-1]

        def output():
            return f'--- launch\n{launch.output()}\n--- recorder\n{recorder.output()}'
        # Stopped once the recorder has every block and every clock tick: a small message
        # that its first transmission missed reaches it at the writer's next periodic
        # heartbeat, seconds later (docs/recording.md, Stopping a recording).
        finished = session.spin_until(
            lambda: observer.done is True
            and observer.recorded('/emfc/measurements') >= n_blocks, START_TIMEOUT_S)
        session.spin_until(lambda: observer.recorded('/clock') >= n_blocks, LATE_TICKS_S)
        session.spin_until(lambda: int(
            (observer.diag('plant_simulator') or (0, '', {}))[2].get('blocks_out', 0))
            >= n_blocks, TIMEOUT_S)
        result = {'finished': finished, 'status': observer.status, 'done': observer.done,
                  'plant': observer.diag('plant_simulator'), 'output': output(),
                  'experiment': experiment, 'bag': folder / 'my_experiment',
                  'alive': launch.alive()}
        result['recorder_exit'] = recorder.stop()
        result['launch_exit'] = launch.stop()
        result['output'] = output()
        return result
    finally:
        for p in started:
            p.stop()
        session.close()


@pytest.fixture(scope='module')
def sim_runs(tools, tmp_path_factory):
    """The README's sim_experiment sequence twice: launch first, then recorder first."""
    return {order: _sim_experiment(tools, tmp_path_factory.mktemp('sim_experiment'), order)
            for order in ('launch first', 'recorder first')}


@pytest.mark.slow
@pytest.mark.parametrize('order', ['launch first', 'recorder first'])
def test_sim_experiment_records_the_whole_trajectory_in_any_start_order(sim_runs, order,
                                                                        tmp_path):
    run = sim_runs[order]
    assert run['finished'], f"{run['status']}\n{run['output']}"
    total = run['experiment'].total_samples
    assert run['status']['state'] == 'done' and run['done'] is True
    assert run['status']['acknowledged_sample_index'] == total
    assert run['status']['error'] == '' and run['status']['resends'] == 0, run['status']
    assert run['alive'], run['output']
    assert run['launch_exit'] == 0 and run['recorder_exit'] == 0, run['output']
    # The generator waited for the plant, not for the recorder's subscription alone.
    assert 'sample 0 waits for' in run['output'] or 'start gate (applier) open' in \
        run['output'], run['output']
    check_sim_bag(run['bag'], '/emfc', run['experiment'])
    # The plant owns time: every 20 blocks it waited for the recorder's acknowledgements.
    plant = run['plant'][2]
    assert int(plant['blocks_out']) == total // 1000
    assert int(plant['ack_waits']) == total // 1000 // 20, plant
    # The bag identified as recorded: emfc-identify BAG (the README's offline line).
    if order == 'launch first':
        result = run_to_end(['emfc-identify', str(run['bag']), '-o', str(tmp_path / 'ident')],
                            cwd=tmp_path)
        assert result.returncode == 0, result.stdout + result.stderr
        assert 'Identification succeeded' in (tmp_path / 'ident' / 'summary.md').read_text()


TWO_INSTANCES = """
from launch import LaunchDescription
from launch.actions import GroupAction, IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import PathJoinSubstitution
from launch_ros.actions import PushROSNamespace
from launch_ros.substitutions import FindPackageShare


def generate_launch_description():
    sim = PathJoinSubstitution([FindPackageShare('emfc_ros'), 'launch',
                                'sim_experiment.launch.py'])
    return LaunchDescription([
        GroupAction([PushROSNamespace(name), IncludeLaunchDescription(
            PythonLaunchDescriptionSource(sim),
            launch_arguments={'clock_topic': 'clock', 'seed': seed}.items())])
        for name, seed in (('a', '1'), ('b', '2'))])
"""


def _simulator_doc_lines():
    """The launch and recorder lines of docs/simulator.md, section 9 (instance ``a``)."""
    text = (REPO / 'docs' / 'simulator.md').read_text()
    section = text[text.index('## 9. Two simulated balances'):]
    argvs = readme_lines.fenced_argvs(section)
    launch_line = next(a for a in argvs if a[:2] == ['ros2', 'launch'])
    recorder_line = next(a for a in argvs if a[:2] == ['ros2', 'run'])
    return launch_line, recorder_line


def _for_instance(words, name):
    """A documented line of instance ``a`` for instance ``name`` (namespace, clock, bag)."""
    swap = {'namespace:=a': f'namespace:={name}', '__ns:=/a': f'__ns:=/{name}',
            '/clock:=/a/clock': f'/clock:=/{name}/clock', 'output:=bag_a': f'output:=bag_{name}'}
    return [swap.get(w, w) for w in words]


@pytest.mark.slow
@pytest.mark.parametrize('variant', ['user launch file', 'documented lines'])
def test_two_simulated_balances_side_by_side_keep_their_own_time(tools, tmp_path, variant):
    """
    Two sim_experiment instances on one domain, each with its clock in its namespace.

    ``user launch file``: a user's file including sim_experiment twice under
    ``PushROSNamespace('a')`` and ``('b')`` with ``clock_topic: clock`` (with the stand-in,
    which has no includes: two launches with ``namespace:=a/emfc`` and ``b/emfc``), and a
    recorder per instance following its clock. ``documented lines``: docs/simulator.md,
    section 9, as typed for ``a``, and for ``b`` with its names (and another seed).
    """
    experiment = load_experiment_file(Path(sys.prefix, 'share', PACKAGE, 'config',
                                           'identification_trajectory.yaml'))
    n_blocks = experiment.total_samples // 1000
    session = Session()
    logs = tmp_path / 'logs'
    if variant == 'user launch file':
        names = ('/a/emfc', '/b/emfc')
        recorders = [['ros2', 'run', 'emfc_ros', 'recorder', '--ros-args', '-r', f'__ns:={ns}',
                      '-r', f'/clock:={ns}/clock', '-p', 'use_sim_time:=true', '-p',
                      f'output:=bag_{ns.split("/")[1]}', '-p', 'topics:=[excitation, '
                      'excitation/description, measurements, measurements/description, clock]']
                     for ns in names]
    else:
        names = ('/a', '/b')
        launch_line, recorder_line = _simulator_doc_lines()
        recorders = [_for_instance(recorder_line, n[1:]) for n in names]
    observers = {ns: session.observer(name='two_observer', namespace=ns) for ns in names}
    started = []
    try:
        started += [typed(r, logs, cwd=tmp_path) for r in recorders]
        if variant == 'user launch file' and launch_tool.real_cli():
            user_file = tmp_path / 'two_balances.launch.py'
            user_file.write_text(TWO_INSTANCES)
            print(f'ros2 launch {user_file}  ({launch_tool.which_tools()})')
            started.append(launch_tool.LaunchProcess([str(user_file)], logs, cwd=tmp_path))
        elif variant == 'user launch file':
            for ns, seed in zip(names, ('1', '2')):
                started.append(start_launch(tools, 'sim_experiment.launch.py', [
                    f'namespace:={ns[1:]}', 'clock_topic:=clock', f'seed:={seed}'], logs))
        else:
            assert launch_line[:4] == ['ros2', 'launch', PACKAGE, 'sim_experiment.launch.py']
            for k, ns in enumerate(names):
                args = _for_instance(launch_line, ns[1:])[4:] + ([] if k == 0 else ['seed:=2'])
                started.append(start_launch(tools, 'sim_experiment.launch.py', args, logs))

        def output():
            return '\n'.join(p.output() for p in started)
        assert session.spin_until(lambda: all(
            o.done is True and o.recorded(f'{ns}/measurements') >= n_blocks
            for ns, o in observers.items()), START_TIMEOUT_S), output()
        session.spin_until(lambda: all(o.recorded(f'{ns}/clock') >= n_blocks
                                       for ns, o in observers.items()), LATE_TICKS_S)
        for ns, o in observers.items():
            assert o.status['state'] == 'done' and o.status['error'] == '', (ns, o.status)
        for p in started:
            assert p.stop() == 0, output()
    finally:
        for p in started:
            p.stop()
        session.close()
    records = []
    for ns in names:
        bag = tmp_path / f'bag_{ns.split("/")[1]}'
        streams = check_sim_bag(bag, ns, experiment, clock_topic=f'{ns}/clock')
        assert set(streams) == {f'{ns}/measurements', f'{ns}/excitation'}
        _, _, custom = read_bag(bag)
        assert 'emfc_ros.lost_messages' not in custom, custom
        records.append(streams[f'{ns}/measurements'].samples)
    # Two balances, two noise seeds: the records differ, each its own.
    assert not np.array_equal(*records)


def test_two_plants_on_one_clock_topic_refuse_to_simulate(executor, ros_context):
    """The default /clock for two simulated balances: each names the other and stops."""
    from emfc_ros.nodes.plant_simulator import PlantSimulatorNode
    plants = [PlantSimulatorNode(namespace=ns, context=ros_context) for ns in ('/p1', '/p2')]
    readiness = {}
    probe = rclpy.create_node('clock_probe', context=ros_context)
    for ns in ('/p1', '/p2'):
        probe.create_subscription(
            String, f'{ns}/excitation/ready',
            lambda m, ns=ns: readiness.__setitem__(ns, json.loads(m.data)), LATCHED_QOS)
    for node in plants + [probe]:
        executor.add_node(node)
    assert ros_harness.spin_until(executor, lambda: all(
        r.get('ready') is False and 'also publishes /clock' in r.get('waiting', '')
        for r in readiness.values()) and len(readiness) == 2, TIMEOUT_S), readiness
    assert '/p2/plant_simulator also publishes /clock' in readiness['/p1']['waiting']
    assert 'clock_topic:=clock' in readiness['/p1']['waiting']


def _documented_emulator(stub, file_name):
    """The emulator line of a launch file's docstring (``emfc-device-emulator ... &``)."""
    docstring = ast.get_docstring(ast.parse(installed(stub, file_name).read_text()))
    lines = [line for line in docstring.splitlines() if line.strip().startswith(
        'emfc-device-emulator')]
    assert len(lines) == 1, lines
    words = shlex.split(lines[0], comments=True)
    return [w for w in words if w != '&']


RECORDER_LINE = ('ros2 run emfc_ros recorder --ros-args -r __ns:=/emfc '
                 '-p output:=my_experiment -p topics:=[excitation, excitation/description, '
                 'measurements, measurements/description]')


@pytest.mark.slow(seconds=50)
def test_hardware_experiment_applies_the_whole_trajectory_and_is_identified(tools, tmp_path):
    """
    The docstring's sequence: the emulator, the launch line, the recorder, emfc-identify.

    The recorder is the README's (recorder section), with the topics the docstring lists
    for identification; it is started first, the launch a few seconds later. The whole
    default trajectory (40 s on the device's clock) must be applied from sample 0 with no
    device fault, and ``emfc-identify BAG`` identify the bag with the pan load it carries.
    """
    where, args = [(w, a) for w, a in documented_lines(tools, 'hardware_experiment.launch.py')
                   if w.endswith('docstring')][0]
    experiment = load_experiment_file(Path(sys.prefix, 'share', PACKAGE, 'config',
                                           'identification_trajectory.yaml'))
    total = experiment.total_samples
    session = Session()
    observer = session.observer(name='hardware_observer')
    logs = tmp_path / 'logs'
    started = []
    try:
        emulator = typed(_documented_emulator(tools, 'hardware_experiment.launch.py'), logs,
                         cwd=tmp_path)
        started.append(emulator)
        assert ros_harness.wait_until(lambda: 'listening on' in emulator.output(), TIMEOUT_S)
        recorder = typed(readme_lines.readme_argv(RECORDER_LINE), logs, cwd=tmp_path)
        started.append(recorder)
        session.spin_until(lambda: False, 2.0)
        launch = start_launch(tools, 'hardware_experiment.launch.py', args, logs)
        started.append(launch)

        def end():
            desc = observer.descriptions.get('measurements')
            offset = desc.extra.get('excitation_offset_samples') if desc else None
            return None if offset is None else int(offset) + total

        def output():
            return '\n'.join(f'--- {p.argv}\n{p.output()}' for p in started)
        assert session.spin_until(
            lambda: observer.done is True and end() is not None
            and observer.recorded('/emfc/measurements') * 1000 >= end() + 2000,
            START_TIMEOUT_S + total / 10000.0), output()
        assert observer.status['state'] == 'done' and observer.status['error'] == ''
        assert session.spin_until(lambda: observer.diag('daq_bridge'), TIMEOUT_S)
        level, message, values = observer.diag('daq_bridge')
        for key in ('excitation_late_samples', 'published_gaps', 'published_missing_samples',
                    'excitation_gap_filled_samples', 'reader_errors', 'setpoint_write_errors',
                    'excitation_malformed'):
            assert values[key] == '0', (key, values)
        assert recorder.stop() == 0 and launch.stop() == 0, output()
        assert emulator.stop() == 0, output()
    finally:
        for p in started:
            p.stop()
        session.close()
    bag = tmp_path / 'my_experiment'
    streams = read_streams(bag)
    meas, exc = streams['/emfc/measurements'], streams['/emfc/excitation']
    desc = meas.description
    assert desc.extra['faults'] == [], desc.extra['faults']
    offset = int(desc.extra['excitation_offset_samples'])
    assert meas.first_sample_index == 0 and meas.gaps == [] and meas.duplicates == 0
    assert exc.first_sample_index == 0 and exc.n_samples == total
    coil = meas.samples[meas.channel_names.index('coil_setpoint_V'), offset:offset + total]
    np.testing.assert_allclose(coil, experiment.block(0, total)[0], atol=DAC_LSB_V)
    result = run_to_end(['emfc-identify', 'my_experiment', '-o', 'ident'], cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert 'Identification succeeded' in (tmp_path / 'ident' / 'summary.md').read_text()


@pytest.mark.slow
def test_hardware_experiment_lines_start_at_sample_0(tools, tmp_path):
    """
    The other documented hardware lines (docs/nodes.md, docs/daq_bridge.md), from sample 0.

    Each with a 0.5 s experiment added (``experiment_file:=``, the last value wins),
    against the README's ``emfc-device-emulator --port 5555``; this test's listener
    records both streams.
    """
    lines = [(w, a) for w, a in documented_lines(tools, 'hardware_experiment.launch.py')
             if not w.endswith('docstring')]
    assert ('docs/nodes.md', []) in lines and len(lines) >= 2, lines
    short_file = _write_experiment(tmp_path / 'short.yaml', SHORT_EXPERIMENT)
    excitation = load_experiment_file(short_file)
    total = excitation.total_samples
    session = Session()
    observer = session.observer(name='hardware_lines', measurements=True, excitation=True)
    logs = tmp_path / 'logs'
    emulator = typed(readme_lines.readme_argv('emfc-device-emulator --port 5555'), logs,
                     cwd=tmp_path)
    started = []
    try:
        assert ros_harness.wait_until(lambda: 'listening on' in emulator.output(), TIMEOUT_S)
        for where, args in lines:
            observer.blocks['measurements'].clear()
            observer.descriptions.clear()
            observer.done = observer.status = None
            launch = start_launch(tools, 'hardware_experiment.launch.py',
                                  args + [f'experiment_file:={short_file}'], logs)
            started.append(launch)

            def excitation_measured():
                desc = observer.descriptions.get('measurements')
                if desc is None or desc.extra.get('excitation_offset_samples') in (None, ''):
                    return False
                end = int(desc.extra['excitation_offset_samples']) + total
                return bool(observer.blocks['measurements']) and \
                    observer.blocks['measurements'][-1].first_sample_index >= end

            assert session.spin_until(
                lambda: observer.done is True and excitation_measured(),
                START_TIMEOUT_S), (where, observer.status, launch.output())
            assert observer.status['state'] == 'done' and observer.status['error'] == ''
            blocks = observer.blocks['measurements']
            firsts = [b.first_sample_index for b in blocks]
            # The device's indices from its start (the bridge waited for this listener).
            assert firsts == list(range(0, 1000 * len(firsts), 1000))
            desc = observer.descriptions['measurements']
            assert desc.extra['faults'] == [], (where, desc.extra['faults'])
            offset = int(desc.extra['excitation_offset_samples'])
            got = np.concatenate([np.asarray(b.samples) for b in blocks], axis=1)
            coil = got[desc.channel_names.index('coil_setpoint_V'), offset:]
            np.testing.assert_allclose(coil[:total], excitation.block(0, total)[0],
                                       atol=DAC_LSB_V)
            assert launch.stop() == 0, launch.output()
            # the stopped bridge's last blocks are taken now, not as the next run's
            session.spin_until(lambda: False, 0.5)
    finally:
        for p in started:
            p.stop()
        emulator.stop()
        session.close()


@pytest.mark.slow
def test_replay_gives_back_the_recorded_measurements_to_its_done_status(tools, sim_runs,
                                                                        tmp_path):
    run = sim_runs['launch first']
    assert run['finished'], run['output']
    recorded = read_streams(run['bag'])['/emfc/measurements']
    span_s = (recorded.block_receive_time_ns[-1] - recorded.block_receive_time_ns[0]) * 1e-9
    session = Session()
    started = []
    try:
        for k, (where, args) in enumerate(documented_lines(tools, 'replay.launch.py')):
            args = fill_placeholders(args, bag=run['bag'])
            # The bag lasts as long as the simulated experiment: replay it 10 times faster.
            observer = session.observer(name=f'replay_observer_{k}')
            launch = start_launch(tools, 'replay.launch.py', args + ['speed:=10'],
                                  tmp_path / 'logs')
            started.append(launch)
            # Nobody listens yet: the bridge waits (min_subscribers, default 1) ...
            assert session.spin_until(lambda: observer.diag('daq_bridge'), START_TIMEOUT_S), \
                launch.output()
            session.spin_until(lambda: False, 1.0)
            level, message, values = observer.diag('daq_bridge')
            assert values['state'] == 'idle' and values['published_blocks'] == '0', values
            # ... replays the whole bag to the listener that comes, then says it is done.
            observer.listen('measurements')

            def replayed():
                return len(observer.blocks['measurements']) >= len(
                    recorded.block_first_index) and (observer.bridge_status or {}).get(
                    'state') == 'done'
            assert session.spin_until(replayed, START_TIMEOUT_S + span_s), (
                where, observer.bridge_status, launch.output())
            blocks = observer.blocks['measurements']
            assert [b.first_sample_index for b in blocks] == list(recorded.block_first_index)
            got = np.concatenate([np.asarray(b.samples) for b in blocks], axis=1)
            np.testing.assert_array_equal(got, recorded.samples)
            assert observer.descriptions['measurements'].extra['backend'] == 'replay'
            assert 'replay done' in launch.output()
            assert launch.stop() == 0, launch.output()
            session.executor.remove_node(observer.node)
            session.nodes.remove(observer.node)
            observer.node.destroy_node()        # the next line's bridge waits for a new one
    finally:
        for p in started:
            p.stop()
        session.close()


@pytest.mark.slow(seconds=50)
def test_signal_generator_launch_is_recorded_from_its_first_block(tools, tmp_path):
    """
    The generator's launch lines, recorded from sample 0 by a recorder started first.

    Each documented line with the README's recorder started BEFORE the launch: the bag has
    the stream from sample 0 (the file's ``min_subscribers:=1``). The first line runs the
    whole default trajectory (40 s at the wall clock's pace), the others a few blocks.
    """
    session = Session()
    observer = session.observer(name='generator_observer')
    logs = tmp_path / 'logs'
    started = []
    try:
        for k, (where, args) in enumerate(documented_lines(tools, 'signal_generator.launch.py')):
            folder = tmp_path / f'line{k}'
            folder.mkdir()
            observer.done = observer.status = None
            recorder = typed(readme_lines.readme_argv(RECORDER_LINE), logs, cwd=folder)
            started.append(recorder)
            assert session.spin_until(lambda: observer.diag('recorder'), START_TIMEOUT_S)
            launch = start_launch(tools, 'signal_generator.launch.py', args, logs)
            started.append(launch)
            whole = k == 0
            assert session.spin_until(
                lambda: (observer.done is True and observer.recorded('/emfc/excitation') >= 400)
                if whole else observer.recorded('/emfc/excitation') >= 5
                and observer.status is not None,
                START_TIMEOUT_S + 45.0), (where, launch.output(), recorder.output())
            assert observer.status['error'] == ''
            assert launch.stop() == 0, launch.output()
            session.spin_until(lambda: False, 1.0)          # the last blocks reach the bag
            assert recorder.stop() == 0, recorder.output()
            exc = read_streams(folder / 'my_experiment')['/emfc/excitation']
            size = dict(a.split(':=', 1) for a in args).get('block_size', '1000')
            assert exc.first_sample_index == 0 and exc.gaps == [] and exc.duplicates == 0
            assert all(b == i * int(size) for i, b in enumerate(exc.block_first_index))
            if whole:
                assert exc.n_samples == SHIPPED_SAMPLES
            observer.diagnostics.clear()
    finally:
        for p in started:
            p.stop()
        session.close()


def _echoed_readings(text):
    """(mass_kg, standard uncertainty [kg], stable) of every reading echo printed."""
    out = []
    for doc in text.split('\n---'):
        mass = re.search(r"key: mass_kg\s+value: '?([-+0-9.eE]+)'?", doc)
        u = re.search(r"key: standard_uncertainty_kg\s+value: '?([-+0-9.eE]+)'?", doc)
        stable = re.search(r"key: stable\s+value: '?(true|false)'?", doc)
        if mass and u and stable:
            out.append((float(mass.group(1)), float(u.group(1)), stable.group(1) == 'true'))
    return out


def _zero(session, node, argv):
    """Call the zero service as the documented line does (as typed with the real tool)."""
    if launch_tool.real_cli():
        result = subprocess.run(argv, capture_output=True, text=True, timeout=scaled(60),
                                env=ros_harness.child_environment())
        return 'success=True' in result.stdout, result.stdout + result.stderr
    client = node.create_client(Trigger, argv[3])
    assert session.spin_until(client.service_is_ready, TIMEOUT_S)
    future = client.call_async(Trigger.Request())
    assert session.spin_until(future.done, TIMEOUT_S)
    return future.result().success, future.result().message


@pytest.mark.slow(seconds=30)
def test_weigh_launch_shows_the_scheduled_mass(tools, tmp_path):
    """
    The weighing example shows its mass.

    docs/weighing.md, section 8, as typed: the launch line, the zero once a reading of the
    empty pan is steady, ``ros2 topic echo`` of the readings showing the mass put on at 20 s.
    """
    lines = documented_lines(tools, 'weigh.launch.py')
    doc = (REPO / 'docs' / 'weighing.md').read_text()
    block = doc[doc.index('ros2 launch emfc_ros weigh.launch.py'):].split('```')[0]
    zero_argv, echo_argv = (shlex.split(line) for line in block.splitlines()[1:3])
    assert zero_argv[:3] == ['ros2', 'service', 'call'] and echo_argv[:3] == [
        'ros2', 'topic', 'echo'], block
    session = Session()
    node = rclpy.create_node('weigh_observer', namespace='/emfc', context=session.context)
    session.executor.add_node(node)
    session.nodes.append(node)
    readings, descriptions = [], []
    node.create_subscription(DiagnosticArray, 'weighing/reading', lambda m: readings.append(
        {kv.key: kv.value for kv in m.status[0].values} | {'level': m.status[0].level}), 100)
    node.create_subscription(String, 'measurements/description',
                             lambda m: descriptions.append(msg_to_description(m)),
                             LATCHED_QOS)
    started = []
    try:
        for where, args in lines:
            launch = start_launch(tools, 'weigh.launch.py', args, tmp_path / 'logs')
            started.append(launch)
            schedule = [tuple(float(v) for v in item.split(':')) for item in
                        dict(a.split(':=', 1) for a in args)['load'].split(',') if item]
            echo = typed(echo_argv, tmp_path / 'logs') if launch_tool.real_cli() else None
            if echo is not None:
                started.append(echo)

            def steady():
                return [r for r in readings if r.get('steady') == 'true']
            assert session.spin_until(lambda: steady() and descriptions, START_TIMEOUT_S), \
                (where, launch.output())
            rate = descriptions[-1].sample_rate_Hz

            def time_of(r):
                return (int(r['sample_index']) + 1) / rate
            first_mass = min(t for t, kg in schedule if kg > 0)
            assert time_of(steady()[0]) < first_mass, 'the empty pan must be steady first'
            assert all(r['stable'] == 'false' and r['calibrated'] == 'false'
                       for r in readings if r['level'] != DiagnosticStatus.ERROR)
            ok, message = _zero(session, node, zero_argv)
            assert ok, message
            last_change = max(t for t, _ in schedule)
            assert session.spin_until(
                lambda: any(r['stable'] == 'true' and time_of(r) > last_change + 1.1
                            for r in readings), START_TIMEOUT_S), launch.output()
            for r in readings:
                if r['level'] == DiagnosticStatus.ERROR or r['stable'] != 'true':
                    continue
                true = max((kg for t, kg in schedule if t <= time_of(r)), default=0.0)
                assert abs(float(r['mass_kg']) - true) <= 2.0 * float(
                    r['standard_uncertainty_kg']), (r, true)
            changes = descriptions[-1].extra['load_changes']
            for t, kg in schedule:
                assert [int(round(t * rate)), kg] in changes, changes
            if echo is not None:
                session.spin_until(lambda: False, 2.0)
                # Ctrl-C: ros2 (ros2cli) exits with the signal's number, 2, by design
                assert echo.stop() in (0, 2), echo.output()
                shown = [(m, u) for m, u, stable in _echoed_readings(echo.output()) if stable]
                assert shown, echo.output()[-2000:]
                mass, u = shown[-1]
                assert abs(mass - schedule[-1][1]) <= 2.0 * u, echo.output()[-2000:]
            assert launch.stop() == 0, launch.output()
            readings.clear()
            descriptions.clear()
    finally:
        for p in started:
            p.stop()
        session.close()


@pytest.mark.parametrize('file_name', LAUNCH_FILES)
def test_the_real_ros2_launch_shows_and_checks_the_arguments(tools, tmp_path, file_name):
    """
    The real tool lists every argument, and an undeclared one ends the launch.

    ``ros2 launch emfc_ros FILE --show-args`` lists every argument with its description, and
    an argument the file does not declare ends the launch before any node starts.

    With the stand-in (no real tool) the same declarations are checked by evaluation.
    """
    declared = {a.name: a for a in evaluate(tools, tmp_path, file_name, ['bag:=b'] if
                                            file_name == 'replay.launch.py' else [])
                .description.get_launch_arguments()}
    assert {'namespace', 'discovery_range'} <= set(declared)
    assert all(a.description and a.description != 'no description given'
               for a in declared.values()), file_name
    if not launch_tool.real_cli():
        with pytest.raises(RuntimeError, match='does not take the argument.s. use_sim_time'):
            evaluate(tools, tmp_path, file_name, ['bag:=b', 'use_sim_time:=false'] if
                     file_name == 'replay.launch.py' else ['use_sim_time:=false'])
        return
    shown = subprocess.run(['ros2', 'launch', PACKAGE, file_name, '--show-args'],
                           capture_output=True, text=True, timeout=scaled(120),
                           env=ros_harness.child_environment())
    assert shown.returncode == 0, shown.stderr
    for name in declared:
        assert f"'{name}':" in shown.stdout, (name, shown.stdout)
    extra = ['bag:=b'] if file_name == 'replay.launch.py' else []
    launch = launch_tool.LaunchProcess([PACKAGE, file_name, *extra, 'use_sim_time:=false'],
                                       tmp_path / 'logs')
    code = launch.wait(120.0)
    output = launch.output()
    launch.stop()
    assert code not in (None, 0), output
    assert 'does not take the argument(s) use_sim_time' in output, output
    assert 'process started' not in output, output


def test_the_stand_in_is_not_installed():
    """The installed package never depends on the test stand-in (nor imports it)."""
    result = subprocess.run(
        [sys.executable, '-c', 'import importlib.util as u; s = u.find_spec("launch_ros"); '
         'print(s.origin if s else "")'], capture_output=True, text=True, cwd='/',
        timeout=scaled(60))
    assert result.returncode == 0, result.stderr
    assert 'launch_stub' not in result.stdout
    # The real launch_ros only where the real command line is installed.
    assert bool(result.stdout.strip()) == launch_tool.installed_cli(), result.stdout
