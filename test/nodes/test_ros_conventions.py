"""
ROS conventions of every node executable (issue 13 item 6).

- Parameter descriptors carry the limits (``FloatingPointRange``/``IntegerRange``) and
  ``read_only``, read back over the ``describe_parameters`` service as ``ros2 param describe``
  does; a set outside them is refused at once with a reason and the value stays.
- A start-up value outside the limits or of the wrong type: the node keeps running, logs an
  error naming the parameter (on ``/rosout``), keeps the default and reports the error.
- Node-specific services are private (``<node>/...``), the plant's ``~/reset`` included.
- One start-up line on ``/rosout`` and one shutdown line after SIGINT, from the node logger.
- ``--help`` on every executable prints purpose, parameters with defaults and limits, topics
  and services, and exits 0 without initialising rclpy.
"""

import importlib
from pathlib import Path
import subprocess
import sys

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import pytest
from rcl_interfaces.msg import Log
import rclpy
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

import ros_harness
from ros_harness import scaled

NODES = ('signal_generator', 'plant_simulator', 'position_controller', 'recorder',
         'identifier', 'weighing', 'daq_bridge')
CLASSES = {'signal_generator': 'SignalGeneratorNode', 'plant_simulator': 'PlantSimulatorNode',
           'position_controller': 'PositionControllerNode', 'recorder': 'RecorderNode',
           'identifier': 'IdentifierNode', 'weighing': 'WeighingNode',
           'daq_bridge': 'DaqBridgeNode'}
#: Start-up values that keep a node quiet (nothing published at a high rate, no bag).
QUIET = {'signal_generator': [('autostart', False)], 'recorder': [('autostart', False)],
         'daq_bridge': [('autostart', False)]}
TIMEOUT_S = scaled(30.0)
#: The plant's first start after an install compiles its kernel (12-17 s measured).
START_TIMEOUT_S = scaled(180.0)
ROSOUT_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)


def module(name):
    return importlib.import_module(f'emfc_ros.nodes.{name}')


def read_only_names(name):
    """The parameters the node's tables mark as fixed at start-up."""
    mod = module(name)
    fixed = set(getattr(mod, 'READ_ONLY', ()))
    fixed |= {n for n, entry in mod.PARAMETERS.items() if len(entry) == 3 and entry[2]}
    return fixed


def outside(low, high):
    """A value just outside ``[low, high]``, of the same type."""
    if isinstance(low, int) and isinstance(high, int):
        return high + 1 if high < 2 ** 63 - 1 else low - 1
    return float(high) + 1.0 + abs(float(high))


def call(executor, future):
    assert ros_harness.spin_until(executor, future.done, TIMEOUT_S)
    return future.result()


# -- descriptors, refused sets, private services (in process) -----------------------------

@pytest.mark.parametrize('name', NODES)
def test_descriptors_limits_and_private_services(name, executor, ros_context):
    mod = module(name)
    node = getattr(mod, CLASSES[name])(
        context=ros_context, namespace='/conv',
        parameter_overrides=[Parameter(k, value=v) for k, v in QUIET.get(name, [])])
    probe = rclpy.create_node('probe', namespace='/conv', context=ros_context)
    for n in (node, probe):
        executor.add_node(n)
    fqn = f'/conv/{name}'
    client = AsyncParameterClient(probe, fqn)
    assert ros_harness.spin_until(executor, client.services_are_ready, TIMEOUT_S)

    # Read back as `ros2 param describe` does: the limits and read_only are there.
    names = list(mod.PARAMETERS)
    descriptors = {d.name: d for d in call(executor,
                                           client.describe_parameters(names)).descriptors}
    assert set(descriptors) == set(names)
    limits = getattr(mod, 'LIMITS', {})
    fixed = read_only_names(name)
    assert limits, f'{name} declares no limits'
    for pname, d in descriptors.items():
        assert d.description == mod.PARAMETERS[pname][1]
        assert d.read_only == (pname in fixed), pname
        if pname in limits:
            low, high = limits[pname]
            ranges = d.integer_range if isinstance(mod.PARAMETERS[pname][0], int) \
                else d.floating_point_range
            assert len(ranges) == 1, pname
            assert (ranges[0].from_value, ranges[0].to_value) == (low, high), pname
        else:
            assert not d.integer_range and not d.floating_point_range, pname

    # Refused at once, with a reason; the value stays.
    for pname, (low, high) in limits.items():
        if pname in fixed:
            continue
        before = node.get_parameter(pname).value
        bad = outside(low, high)
        result = call(executor, client.set_parameters([Parameter(pname, value=bad)]))
        assert not result.results[0].successful, (pname, bad)
        assert pname in result.results[0].reason and 'out of range' in result.results[0].reason
        after = call(executor, client.get_parameters([pname])).values[0]
        assert node.get_parameter(pname).value == before
        assert after.double_value == before or after.integer_value == before
    for pname in sorted(fixed)[:3]:
        value = node.get_parameter(pname).value
        result = call(executor, client.set_parameters([Parameter(pname, value=value)]))
        assert not result.results[0].successful
        assert 'read-only' in result.results[0].reason and pname in result.results[0].reason

    # Every node-specific service is private: <namespace>/<node>/...
    services = [s for s, _ in probe.get_service_names_and_types_by_node(name, '/conv')]
    assert services
    assert all(s.startswith(fqn + '/') for s in services), services


def test_plant_reset_is_private_and_float_parameters_take_integers(executor, ros_context):
    from emfc_ros.nodes.plant_simulator import PlantSimulatorNode
    plant = PlantSimulatorNode(context=ros_context, namespace='/emfc')
    probe = rclpy.create_node('probe', namespace='/emfc', context=ros_context)
    for n in (plant, probe):
        executor.add_node(n)
    reset = probe.create_client(Trigger, '/emfc/plant_simulator/reset')
    assert ros_harness.spin_until(executor, reset.service_is_ready, TIMEOUT_S)
    response = call(executor, reset.call_async(Trigger.Request()))
    assert response.success, response.message
    assert '/emfc/reset' not in dict(probe.get_service_names_and_types())

    client = AsyncParameterClient(probe, '/emfc/plant_simulator')
    assert ros_harness.spin_until(executor, client.services_are_ready, TIMEOUT_S)
    # `ros2 param set /emfc/plant_simulator load_mass_kg 1` sends an integer.
    result = call(executor, client.set_parameters([Parameter('load_mass_kg', value=1)]))
    assert result.results[0].successful, result.results[0].reason
    assert plant.get_parameter('load_mass_kg').value == 1.0
    assert plant.get_parameter('load_mass_kg').type_ == Parameter.Type.DOUBLE
    result = call(executor, client.set_parameters([Parameter('load_mass_kg', value=3)]))
    assert not result.results[0].successful and 'out of range' in result.results[0].reason
    result = call(executor, client.set_parameters([Parameter('load_mass_kg', value='heavy')]))
    assert not result.results[0].successful
    assert plant.get_parameter('load_mass_kg').value == 1.0


# -- start-up and shutdown, refused start-up values (processes) ----------------------------

class RosoutProbe:
    """Collects /rosout and /diagnostics."""

    def __init__(self, context):
        self.node = rclpy.create_node('rosout_probe', context=context)
        self.logs = []
        self.diagnostics = {}
        self.node.create_subscription(Log, '/rosout', self.logs.append, ROSOUT_QOS)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 100)

    def _on_diag(self, msg):
        for status in msg.status:
            self.diagnostics[status.name] = status

    def lines(self, logger, level=None):
        return [m.msg for m in self.logs
                if m.name == logger and (level is None or m.level == level)]

    def status_of(self, node_name):
        return [s for name, s in self.diagnostics.items() if node_name in name]


def test_startup_line_on_rosout_and_shutdown_line_after_sigint(executor, ros_context,
                                                               processes):
    probe = RosoutProbe(ros_context)
    executor.add_node(probe.node)
    procs = {}
    for name in NODES:
        args = ['--ros-args', '-r', '__ns:=/conv']
        for k, v in QUIET.get(name, []):
            args += ['-p', f'{k}:={str(v).lower()}']
        if name == 'plant_simulator':
            args += ['-p', 'load_mass_kg:=0.1']      # shown in the line: set at start-up
        procs[name] = processes.start(ros_harness.node_executable(name) + args)

    def started(name):
        return any(line.startswith(f'started as /conv/{name}')
                   for line in probe.lines(f'conv.{name}'))

    assert ros_harness.spin_until(executor, lambda: all(started(n) for n in NODES),
                                  START_TIMEOUT_S), \
        {n: p.output()[-2000:] for n, p in procs.items() if not started(n)}
    plant_line = [m for m in probe.lines('conv.plant_simulator', Log.INFO)
                  if m.startswith('started as')]
    assert len(plant_line) == 1
    assert "time_mode='owner'" in plant_line[0] and 'load_mass_kg=0.1' in plant_line[0]
    generator_line = [m for m in probe.lines('conv.signal_generator')
                      if m.startswith('started as')][0]
    assert "pacing='wall'" in generator_line and 'autostart=False' in generator_line

    for name, proc in procs.items():
        assert proc.stop() == 0, proc.output()
        out = proc.output()
        assert f'[conv.{name}.shutdown]: shutting down: interrupted' in out, out[-2000:]
        # Nothing printed around the ROS logger: every line is a ROS log line.
        stray = [line for line in out.splitlines()
                 if line.strip() and not line.startswith(('[INFO]', '[WARN]', '[ERROR]'))]
        assert not stray, stray


def test_timers_run_on_wall_time_under_use_sim_time_without_a_clock(executor, ros_context,
                                                                    processes):
    """Diagnostics and watchdogs run on the steady clock: no /clock, still 1 Hz (issue 13)."""
    counts = {}

    def on_diag(msg):
        for status in msg.status:
            counts[status.name] = counts.get(status.name, 0) + 1

    node = rclpy.create_node('diag_counter', context=ros_context)
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 100)
    executor.add_node(node)
    for name in NODES:
        args = ['--ros-args', '-r', '__ns:=/simtime', '-p', 'use_sim_time:=true']
        for k, v in QUIET.get(name, []):
            args += ['-p', f'{k}:={str(v).lower()}']
        processes.start(ros_harness.node_executable(name) + args)

    def ticking(name):
        return sum(c for n, c in counts.items() if n.startswith(name)) >= 3

    assert ros_harness.spin_until(executor, lambda: all(ticking(n) for n in NODES),
                                  START_TIMEOUT_S), counts


@pytest.mark.parametrize('name, value, needle', [
    ('weighing', 'reference_mass_kg:=-1.0', 'reference_mass_kg'),
    ('signal_generator', 'block_size:=0', 'block_size'),
    ('position_controller', 'command_is_total:=maybe', 'command_is_total'),
])
def test_refused_startup_value_keeps_node_running(name, value, needle, executor, ros_context,
                                                  processes):
    probe = RosoutProbe(ros_context)
    executor.add_node(probe.node)
    proc = processes.start(ros_harness.node_executable(name) + [
        '--ros-args', '-r', '__ns:=/conv', '-p', value])

    def refused():
        return [m for m in probe.lines(f'conv.{name}', Log.ERROR)
                if needle in m and 'start-up value' in m]

    assert ros_harness.spin_until(executor, refused, START_TIMEOUT_S), proc.output()
    assert 'refused' in refused()[0] and 'keeps its default' in refused()[0]
    assert ros_harness.spin_until(
        executor, lambda: any(s.level == DiagnosticStatus.ERROR and needle in s.message
                              for s in probe.status_of(name)), TIMEOUT_S), \
        [(s.name, s.message) for s in probe.diagnostics.values()]
    client = AsyncParameterClient(probe.node, f'/conv/{name}')
    assert ros_harness.spin_until(executor, client.services_are_ready, TIMEOUT_S)
    # the node is another process: the answer to a first request may be lost
    answered = ros_harness.call_until_answered(
        executor, lambda: client.get_parameters([needle]), TIMEOUT_S)
    assert answered is not None, proc.output()
    got = answered.result().values[0]
    default = module(name).PARAMETERS[needle][0]
    assert parameter_value_to_python(got) == default
    assert proc.alive()
    assert proc.stop() == 0, proc.output()


@pytest.mark.parametrize('name', ['plant_simulator', 'daq_bridge', 'signal_generator', 'recorder',
                                  'weighing', 'identifier', 'position_controller'])
def test_an_unknown_parameter_name_is_refused_not_ignored(name, executor, ros_context,
                                                          processes):
    probe = RosoutProbe(ros_context)
    executor.add_node(probe.node)
    proc = processes.start(ros_harness.node_executable(name) + [
        '--ros-args', '-r', '__ns:=/conv', '-p', 'smaple_rate_Hz:=20000.0'])

    def refused():
        return [m for m in probe.lines(f'conv.{name}', Log.ERROR)
                if 'smaple_rate_Hz' in m and 'unknown' in m]

    assert ros_harness.spin_until(executor, refused, START_TIMEOUT_S), proc.output()
    assert ros_harness.spin_until(
        executor, lambda: any(s.level == DiagnosticStatus.ERROR and 'smaple_rate_Hz' in s.message
                              for s in probe.status_of(name)), TIMEOUT_S), \
        [(s.name, s.message) for s in probe.diagnostics.values()]
    assert proc.alive()
    assert proc.stop() == 0, proc.output()


def test_refused_startup_value_blocks_the_start_until_replaced(executor, ros_context):
    from emfc_ros.nodes.signal_generator import SignalGeneratorNode
    node = SignalGeneratorNode(context=ros_context, namespace='/conv', parameter_overrides=[
        Parameter('block_size', value=0), Parameter('autostart', value=True)])
    probe = rclpy.create_node('probe', namespace='/conv', context=ros_context)
    for n in (node, probe):
        executor.add_node(n)
    assert node.get_parameter('block_size').value == 1000
    arm = probe.create_client(Trigger, '/conv/signal_generator/arm')
    assert ros_harness.spin_until(executor, arm.service_is_ready, TIMEOUT_S)
    response = call(executor, arm.call_async(Trigger.Request()))
    assert not response.success and 'block_size' in response.message
    assert 'start-up value 0 refused' in response.message
    client = AsyncParameterClient(probe, '/conv/signal_generator')
    assert ros_harness.spin_until(executor, client.services_are_ready, TIMEOUT_S)
    result = call(executor, client.set_parameters([Parameter('block_size', value=-3)]))
    assert not result.results[0].successful
    response = call(executor, arm.call_async(Trigger.Request()))
    assert not response.success and 'block_size' in response.message
    result = call(executor, client.set_parameters([Parameter('block_size', value=500)]))
    assert result.results[0].successful
    response = call(executor, arm.call_async(Trigger.Request()))
    assert response.success, response.message


# -- --help ---------------------------------------------------------------------------------

def console_script(name):
    return str(Path(sys.executable).parent / ('emfc-' + name.replace('_', '-')))


@pytest.mark.parametrize('name', NODES)
def test_help_on_every_executable(name):
    mod = module(name)
    limits = getattr(mod, 'LIMITS', {})
    fixed = read_only_names(name)
    purpose = mod.__doc__.strip().splitlines()[0]
    for argv in (ros_harness.node_executable(name) + ['--help'], [console_script(name), '-h']):
        result = subprocess.run(argv, capture_output=True, text=True, timeout=scaled(120),
                                env=ros_harness.child_environment())
        assert result.returncode == 0, result.stderr
        out = result.stdout
        assert out.startswith(f'usage: {name} ') and purpose in out
        assert 'Topics' in out and 'Service' in out
        assert result.stderr == ''          # no node: nothing logged
        lines = out.splitlines()
        for pname, entry in mod.PARAMETERS.items():
            head = [line for line in lines if line.startswith(f'  {pname}: ')]
            assert len(head) == 1, pname
            if not isinstance(entry[0], Parameter.Type):
                assert f'default {entry[0]!r}' in head[0]
            if pname in limits:
                assert f'from {limits[pname][0]} to {limits[pname][1]}' in head[0]
            assert ('read-only' in head[0]) == (pname in fixed)
        words = ' '.join(out.split())
        for pname, entry in mod.PARAMETERS.items():
            assert ' '.join(entry[1].split()) in words, pname


HELP_WITHOUT_INIT = """
import importlib, sys
import rclpy

def refuse(*args, **kwargs):
    raise RuntimeError('rclpy.init called')

rclpy.init = refuse
for name in sys.argv[1:]:
    main = importlib.import_module('emfc_ros.nodes.' + name).main
    assert main(['--help']) == 0
    try:
        main(['--ros-args', '-p', 'x:=1'])
    except RuntimeError as exc:
        assert 'rclpy.init called' in str(exc)
    else:
        raise AssertionError('the guard did not catch a start')
print('HELP WITHOUT INIT', len(sys.argv) - 1)
"""


def test_help_does_not_initialise_rclpy():
    result = subprocess.run([sys.executable, '-c', HELP_WITHOUT_INIT, *NODES],
                            capture_output=True, text=True, timeout=scaled(120),
                            env=ros_harness.child_environment())
    assert result.returncode == 0, result.stderr
    assert f'HELP WITHOUT INIT {len(NODES)}' in result.stdout


def test_help_flags_before_ros_args_only():
    from emfc_ros.nodes.spin import wants_help
    assert wants_help(['--help']) and wants_help(['-h'])
    assert wants_help(['-h', '--ros-args', '-p', 'seed:=1'])
    assert not wants_help([])
    assert not wants_help(['--ros-args', '--help'])         # ROS's own
    assert not wants_help(['--ros-args', '-p', 'x:=-h'])
