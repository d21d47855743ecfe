"""
emfc-experiment: run an identification experiment, record it, identify the balance.

With no arguments: the shipped ``config/experiment_default.yaml`` (the paper's four-section
identification trajectory plus the static-characteristic staircases, on the simulated
balance, in simulated time). The nodes (signal_generator, plant_simulator, recorder) are
composed in this process on one executor and talk over real DDS; the run
writes one output folder: ``bag/`` (MCAP rosbag2), ``experiment.yaml`` (the excitation as
played), ``run.yaml`` (the plan), the identification results and plots, ``timing.json`` and
``summary.md``.

With ``target: bridge`` (``config/experiment_bridge_emulator.yaml``) the daq_bridge node
takes the plant simulator's place: the same experiment on a device (udp back-end; the
runner can start the device emulator itself, on loopback) or the bridge's simulated device,
in wall time on the device's sample clock, the signal generator paced by the device.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
from pathlib import Path
import signal
import sys
import threading
import time
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple

import yaml

from emfc_ros.core.errors import ConfigError, EmfcError
from emfc_ros.core.heap import COMMAND_HEAP
from emfc_ros.core.paths import config_file
from emfc_ros.core.run_plan import load_plan, runner_state_wall_rate_Hz, RunPlan
from emfc_ros.core.stream_counts import CUSTOM_DATA_KEY, markdown, problems

DEFAULT_PLAN = 'experiment_default.yaml'
#: Longest wait for the daq_bridge to start or stop the device (its worker thread) [s].
START_WAIT_S = 30.0
#: Closing the recording: the bag must have stopped growing this long once every counted
#: stream is complete [s].
QUIET_S = 0.1
#: After a device fault, how long the run goes on gathering the faults of the same event
#: before it stops [s]: a host stall shows as late excitation at once and as the device's
#: watchdog trip with the next heartbeat reply (0.1 s); a clean-clone CI run stopped on the
#: first and its bag lacked the second, the root cause.
FAULT_GATHER_S = 0.5
#: Excitation blocks the generator keeps in flight to the simulated plant, per executor. The
#: recorder stamps a message with its node's simulated time when it takes it, and rclpy's
#: time source keeps only the newest /clock message (depth 1). The events executor runs the
#: callbacks in arrival order: with 8 blocks in flight the plant answered all 8 before the
#: recorder took its /clock, and the bag stamped blocks up to 0.7 s late (measured). One
#: block in flight stamps each block with its own time (the experiment phase took 0.75 s
#: against 0.6 s with 8); the wait-set executor takes one message per subscription and
#: cycle, which kept its 8-block window within one block.
SIMULATOR_WINDOW_BLOCKS = {'events': 1, 'single_threaded': 8}
#: Longest wait at the end of a run for the warm-up thread (:func:`warm_up`) [s]. It has ended
#: long before in a run that got to its experiment; it may still be compiling a kernel (an
#: empty numba cache, 15 s and more) when a run fails early or Ctrl-C stops it, and the
#: command does not wait for that (it leaves with os._exit, which ends the thread).
WARM_UP_JOIN_S = 5.0


class Phases:
    """Wall time per phase of the run."""

    def __init__(self) -> None:
        self.seconds: Dict[str, float] = {}
        self._name: Optional[str] = None
        self._t0 = 0.0

    def start(self, name: str) -> None:
        """Close the running phase and start ``name``."""
        self.stop()
        self._name, self._t0 = name, time.monotonic()

    def stop(self) -> None:
        """Close the running phase."""
        if self._name is not None:
            self.seconds[self._name] = time.monotonic() - self._t0
            self._name = None


class RunInterrupted(KeyboardInterrupt):
    """
    Ctrl-C (SIGINT) stopped the run.

    Not an :class:`~emfc_ros.core.errors.EmfcError`: an interrupt, not an error, so that no
    ``except Exception`` (the bag reader's, the warm-up's) swallows it.
    """


class CtrlC:
    """
    SIGINT handling of the runner: stop at a clean point, close the bag, say what was kept.

    While the runner polls (``deferred``: its spin loops check :meth:`check` every 20 ms) the
    handler only records the request, so that no node is cut off in the middle of a callback;
    otherwise (setting up nodes, reading the bag, identifying) it raises
    :class:`RunInterrupted` at once. A second Ctrl-C during the clean-up is ignored (the
    clean-up is short and bounded: the recorder closes its bag).
    """

    def __init__(self) -> None:
        self.requested = False
        self.deferred = False
        self._previous: Any = None

    def install(self) -> None:
        """Take over SIGINT (main thread only)."""
        self._previous = signal.signal(signal.SIGINT, self._handler)

    def restore(self) -> None:
        """Give SIGINT back to the handler before :meth:`install`."""
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
            self._previous = None

    def _handler(self, signum: int, frame: Any) -> None:
        if self.requested:
            return
        self.requested = True
        if not self.deferred:
            raise RunInterrupted()

    def check(self) -> None:
        """Raise :class:`RunInterrupted` if Ctrl-C was pressed."""
        if self.requested:
            raise RunInterrupted()


def _progress(text: str) -> None:
    print(text, flush=True)


def _plan_document(plan: RunPlan, load_kg: float, executor: Optional[str] = None) -> dict:
    executor = executor or plan.executor
    doc = dataclasses.asdict(plan)
    doc['executor_used'] = executor
    doc['experiment'] = '(see experiment.yaml)'
    doc['source'] = str(plan.source) if plan.source else None
    if plan.target == 'simulator':
        doc['simulator']['balance_file'] = str(plan.simulator.balance_file or '')
        doc['simulator']['load_mass_kg_used'] = load_kg
        doc['simulator']['max_state_wall_rate_Hz_used'] = runner_state_wall_rate_Hz(
            plan.simulator, plan.experiment['sample_rate_Hz'], plan.block_size, executor)
        doc.pop('bridge')
    else:
        doc.pop('simulator')
        bridge = doc['bridge']
        bridge['balance_file'] = str(plan.bridge.balance_file or '')
        bridge['parameters_file'] = str(plan.bridge.parameters_file or '')
        bridge['load_mass_kg_used'] = load_kg
    doc['recording']['topics'] = list(plan.recording.topics)
    return {'run': doc}


def check_bridge_parameters(plan: RunPlan) -> None:
    """
    Refuse daq_bridge parameters the node does not know (the node would ignore them).

    Parameters
    ----------
    plan : RunPlan
        The plan (target ``'bridge'``; other targets pass).

    Raises
    ------
    ConfigError
        Naming ``run.bridge.parameters.<name>`` and the known names.
    """
    if plan.bridge is None:
        return
    from emfc_ros.nodes.daq_bridge import FUNCGEN_FIELDS, funcgen_key, PARAMETERS

    outputs = plan.bridge.parameters.get('outputs') or ['coil_V', 'load_changer_V']
    known = set(PARAMETERS) | {f'funcgen.{funcgen_key(str(o))}.{f}' for o in outputs
                               for f in FUNCGEN_FIELDS}
    for name in plan.bridge.parameters:
        if name not in known:
            raise ConfigError(f'run.bridge.parameters.{name}',
                              f'not a daq_bridge parameter; known: {sorted(known)}')


def bridge_parameters(plan: RunPlan, balance_path: Path, load_kg: float,
                      device_address: Optional[Tuple[str, int]] = None) -> Dict[str, Any]:
    """
    The daq_bridge node's parameters for a run.

    Parameters
    ----------
    plan : RunPlan
        The plan (target ``'bridge'``).
    balance_path : pathlib.Path
        Balance parameters file.
    load_kg : float
        Mass on the pan [kg] (the sim back-end's device).
    device_address : tuple, optional
        ``(host, port)`` of the emulator the runner started.

    Returns
    -------
    dict
        Parameter name to value.
    """
    bridge = plan.bridge
    params = dict(bridge.parameters)
    params.update({'backend': bridge.backend, 'autostart': False,
                   'balance_file': str(balance_path)})
    if bridge.backend == 'sim':
        params.update({'sim.load_mass_kg': float(load_kg),
                       'sim.load_changer_coupled': bool(bridge.load_changer_coupled)})
    if device_address is not None and plan.bridge.backend == 'daqmx':
        params['daqmx.grpc_address'] = f'{device_address[0]}:{int(device_address[1])}'
    elif device_address is not None:
        params.update({'udp.device_host': device_address[0],
                       'udp.device_port': int(device_address[1])})
    return params


def bag_custom_data(plan: RunPlan, load_kg: float, coupled: bool) -> dict:
    """
    What the bag must carry so that ``emfc-identify BAG`` reproduces the run's identification.

    Parameters
    ----------
    plan : RunPlan
        The plan.
    load_kg : float
        Mass on the pan [kg] (declared by the plan, or the balancing mass pieces).
    coupled : bool
        Whether the load changer's moving mass rides on the pan.

    Returns
    -------
    dict
        ``emfc_ros.identification_options`` (the plan's ``identification`` mapping without
        ``enabled``) and ``emfc_ros.plant_configuration`` (pan load, coupling, source).
    """
    device = 'bridge' if plan.target == 'bridge' else 'simulator'
    declared = getattr(plan, device).load_mass_kg
    source = (f'run plan run.{device}.load_mass_kg' if declared is not None else
              f'run plan run.{device}.load_mass_kg: balance (the mass pieces that hold the '
              f'lever at 0 with 0 V on the coil, from the balance file)')
    return {'emfc_ros.identification_options': {
                k: v for k, v in plan.identification.items() if k != 'enabled'},
            'emfc_ros.plant_configuration': {
                'load_mass_kg': float(load_kg), 'load_changer_coupled': bool(coupled),
                'source': source}}


def stream_counts(plan: RunPlan, total: int, rate: float, publishers: Sequence[Any],
                  written: Mapping[str, int]) -> List[Any]:
    """
    The message accounting of a run, per recorded topic.

    Parameters
    ----------
    plan : RunPlan
        The plan.
    total : int
        Samples in the experiment.
    rate : float
        Sample rate [Hz].
    publishers : sequence
        The run's nodes with ``published_counts()`` (device node, signal generator).
    written : Mapping
        Messages the recorder wrote per topic.

    Returns
    -------
    list of emfc_ros.core.stream_counts.StreamCount
        One per recorded topic, in topic order; ``due`` where the experiment defines it
        (every block stream of the generator, and on the simulator the plant's streams, its
        ``/clock`` and its joint states).
    """
    from emfc_ros.core.stream_counts import states_due, StreamCount

    ns = plan.namespace
    published: Dict[str, dict] = {}
    for node in publishers:
        for topic, entry in node.published_counts().items():
            published[topic if topic.startswith('/') else f'{ns}/{topic}'] = entry
    sizes = [min(plan.block_size, total - i) for i in range(0, total, plan.block_size)]
    due = {f'{ns}/excitation': len(sizes)}
    if plan.target == 'simulator':
        # Owner mode: one answer (block and /clock tick) per excitation block, and the joint
        # states of the answered samples; on the bridge the device streams without an end.
        due.update({topic: len(sizes) for topic in published
                    if topic == '/clock' or topic.startswith(f'{ns}/measurements')})
        due[f'{ns}/joint_states'] = states_due(sizes, rate, plan.simulator.state_rate_Hz)
    out = []
    for topic in sorted(written):
        entry = published.get(topic, {})
        out.append(StreamCount(topic, int(written[topic]), entry.get('published'),
                               int(entry.get('repeated', 0)), int(entry.get('decimated', 0)),
                               due.get(topic) if entry else None))
    return out


def interpreted_warning(params: Any, rate: float, total: int, load_kg: float,
                        coupled: bool) -> str:
    """
    Without numba: how long the simulated experiment will take, measured on a short block.

    Parameters
    ----------
    params : BalanceParameters
        The simulated balance.
    rate : float
        Sample rate [Hz].
    total : int
        Samples of the experiment.
    load_kg : float
        Pan load [kg].
    coupled : bool
        Load changer coupled.

    Returns
    -------
    str
        The warning; empty with numba (the compiled kernel).
    """
    import numpy as np

    from emfc_ros.core.sim.kernel import numba_available
    from emfc_ros.core.sim.simulator import Simulator

    if numba_available():
        return ''
    probe = 1000
    sim = Simulator(params, rate, load_mass_kg=load_kg, load_changer_coupled=coupled,
                    backend='numpy')
    start = time.perf_counter()
    sim.step_block(np.zeros((2, probe)))
    per_second = probe / max(time.perf_counter() - start, 1e-9)
    return (f'the simulator runs interpreted (numba is not installed, about {per_second:.0f} '
            f'samples/s): the experiment ({total} samples) takes about '
            f'{total / per_second / 60.0:.1f} min and the identification several minutes more '
            f'(pip install numba: about 1 s each)')


class ExperimentFault(EmfcError, RuntimeError):
    """The device did not apply the excitation as commanded (a latched fault)."""


def fault_message(faults, offset: Optional[int], total: int, rate: float, bag: Path) -> str:
    """
    What failed, in the experiment's samples, and what was kept.

    Parameters
    ----------
    faults : sequence of Fault
        The daq_bridge's latched faults.
    offset : int or None
        Device index of experiment sample 0.
    total : int
        Samples in the experiment.
    rate : float
        Sample rate [Hz].
    bag : pathlib.Path
        The bag (closed on the way out, with the faults in its custom data).

    Returns
    -------
    str
        The message.
    """
    from emfc_ros.core.device.faults import describe
    lines = describe(faults, None if offset is None else int(offset), total, rate)
    return ('the device did not apply the excitation as commanded, the experiment failed:\n  '
            + lines.replace('\n', '\n  ') + f'\n  the bag {bag} keeps what was recorded up '
            'to here, with the faults in its custom data (emfc_ros.faults)')


def make_executor(kind: str) -> Tuple[Any, str]:
    """
    The runner's executor (``run.executor``).

    ``'events'``: rclpy's EventsExecutor (``rclpy.experimental``, in Jazzy since rclpy 7.1.4),
    which waits for DDS events in C++ and runs the callbacks in arrival order; the
    wait-set SingleThreadedExecutor rebuilds its wait set (every node's subscriptions,
    services, timers and QoS event handlers) for each callback, which took half of the
    experiment phase of the shipped plan (490 blocks: 1.1-2.2 s against 0.5-0.9 s in
    interleaved runs, ``docs/benchmarks.md``, main job, fifth round). Without it (an older
    rclpy) the wait-set executor is used and the runner says so.

    Parameters
    ----------
    kind : str
        ``'events'`` or ``'single_threaded'``.

    Returns
    -------
    executor : rclpy.executors.Executor
        The executor (``add_node``, ``spin_once``, ``shutdown``).
    kind : str
        The kind it is (``'single_threaded'`` after a fallback).
    """
    from rclpy.executors import SingleThreadedExecutor

    if kind == 'events':
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:
            _progress('  rclpy has no EventsExecutor (rclpy < 7.1.4): the wait-set '
                      'SingleThreadedExecutor runs the nodes (run.executor: single_threaded)')
        else:
            return EventsExecutor(), 'events'
    return SingleThreadedExecutor(), 'single_threaded'


def record(plan: RunPlan, out: Path, phases: Phases, ctrl_c: Optional[CtrlC] = None,
           live: Optional[dict] = None) -> dict:
    """
    Bring up the nodes, play the experiment, record it; return what happened.

    Parameters
    ----------
    plan : RunPlan
        The plan.
    out : pathlib.Path
        The output folder (created).
    phases : Phases
        Timing of the phases.
    ctrl_c : CtrlC, optional
        Ctrl-C handling: checked in every wait; the bag is closed on the way out.
    live : dict, optional
        Filled while running (``bag`` once recording, ``samples``, ``total``,
        ``sample_rate_Hz``), for the report of an interrupted run.

    Returns
    -------
    dict
        Samples, blocks, bag path, the pan load used, recorded message counts; for the
        bridge target also the excitation offset on the device clock.

    Raises
    ------
    RuntimeError
        If a node refuses to start, the device does not answer or the experiment does not
        finish in ``plan.timeout_s``.
    RunInterrupted
        On Ctrl-C (the bag is closed before it propagates).
    """
    import rclpy
    from rclpy.logging import LoggingSeverity
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions
    from std_msgs.msg import Float64MultiArray, String
    from std_srvs.srv import Trigger

    from emfc_ros.core.blocks import SequenceTracker, StreamDescription
    from emfc_ros.core.json_text import load_json_text
    from emfc_ros.core.model.parameters import BalanceParameters
    from emfc_ros.core.signals import experiment_from_config
    from emfc_ros.core.sim.balancing import balancing_load_mass_kg
    from emfc_ros.nodes.convert import BLOCK_QOS, LATCHED_QOS, msg_to_block
    from emfc_ros.nodes.recorder import RecorderNode
    from emfc_ros.nodes.signal_generator import SignalGeneratorNode

    phases.start('set up nodes')
    ctrl_c = ctrl_c or CtrlC()
    live = {} if live is None else live
    on_bridge = plan.target == 'bridge'
    experiment = experiment_from_config(plan.experiment)
    experiment_path = out / 'experiment.yaml'
    experiment_path.write_text(yaml.safe_dump({'experiment': plan.experiment},
                                              sort_keys=False))
    device = plan.bridge if on_bridge else plan.simulator
    balance_path = device.balance_file or config_file('balance_default.yaml')
    params = BalanceParameters.load_yaml(balance_path)
    coupled = device.load_changer_coupled
    load_kg = device.load_mass_kg
    if load_kg is None:
        load_kg = balancing_load_mass_kg(params, coupled)
    (out / 'run.yaml').write_text(yaml.safe_dump(_plan_document(plan, load_kg),
                                                 sort_keys=False))
    total = experiment.total_samples
    rate = experiment.sample_rate_Hz
    bag = out / 'bag'
    ns = plan.namespace
    live.update({'total': total, 'sample_rate_Hz': rate, 'samples': 0})
    if not on_bridge:
        warning = interpreted_warning(params, rate, total, load_kg, coupled)
        if warning:
            _progress(f'  {warning}')

    emulator = None
    # SIGINT stays with the runner (CtrlC), so that the context lives on to close the bag.
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    nodes = []
    recorder = None
    executor = None
    try:
        executor, executor_kind = make_executor(plan.executor)
        if executor_kind != plan.executor:
            (out / 'run.yaml').write_text(yaml.safe_dump(
                _plan_document(plan, load_kg, executor_kind), sort_keys=False))
        if on_bridge:
            from emfc_ros.nodes.daq_bridge import DaqBridgeNode
            address = None
            if plan.bridge.start_emulator:
                emulator = _start_emulator(plan, params, load_kg, coupled, balance_path)
                address = emulator.address
                what, detail = _emulator_label(plan)
                _progress(f'  {what} on {address[0]}:{address[1]}{detail}')
            values = bridge_parameters(plan, balance_path, load_kg, address)
            doc = _plan_document(plan, load_kg, executor_kind)
            doc['run']['bridge']['parameters'] = values     # as given to the node
            (out / 'run.yaml').write_text(yaml.safe_dump(doc, sort_keys=False))
            device_node = DaqBridgeNode(namespace=ns, parameter_overrides=[
                Parameter(k, value=v) for k, v in values.items()])
            device_name = 'daq_bridge'
        else:
            from emfc_ros.nodes.plant_simulator import PlantSimulatorNode
            device_node = PlantSimulatorNode(namespace=ns, parameter_overrides=[
                Parameter('time_mode', value='owner'),
                Parameter('sample_rate_Hz', value=float(rate)),
                Parameter('balance_file', value=str(balance_path)),
                Parameter('load_mass_kg', value=float(load_kg)),
                Parameter('load_changer_coupled', value=bool(coupled)),
                Parameter('seed', value=int(plan.simulator.seed)),
                Parameter('noise', value=bool(plan.simulator.noise)),
                Parameter('quantisation', value=bool(plan.simulator.quantisation)),
                Parameter('state_rate_Hz', value=float(plan.simulator.state_rate_Hz)),
                Parameter('max_state_wall_rate_Hz', value=runner_state_wall_rate_Hz(
                    plan.simulator, rate, plan.block_size, executor_kind)),
                Parameter('publish_groups', value=False)])
            device_name = 'plant_simulator'
        nodes.append(device_node)
        # The simulator owns time: the recorder and the generator take it from /clock, so
        # the bag's stamps and duration are simulated time, and /clock is recorded for
        # `ros2 bag play --clock`. On the bridge the device runs in real time: wall clock.
        sim_time = not on_bridge
        topics = list(plan.recording.topics)
        if sim_time and '/clock' not in topics:
            topics.append('/clock')
        recorder = RecorderNode(namespace=ns, parameter_overrides=[
            Parameter('use_sim_time', value=sim_time),
            Parameter('output', value=str(bag)),
            Parameter('topics', value=topics),
            Parameter('flush_period_s', value=float(plan.recording.flush_period_s)),
            Parameter('max_bag_size_B', value=int(plan.recording.max_bag_size_B)),
            Parameter('max_bag_duration_s', value=float(plan.recording.max_bag_duration_s)),
            Parameter('discovery_period_s', value=0.1),
            Parameter('autostart', value=False),
            Parameter('experiment_description', value=experiment_path.read_text()),
            Parameter('custom_data', value=yaml.safe_dump(
                bag_custom_data(plan, load_kg, coupled), sort_keys=False))])
        nodes.append(recorder)
        pacing = plan.bridge.pacing if on_bridge else 'consumer'
        generator = SignalGeneratorNode(namespace=ns, parameter_overrides=[
            Parameter('use_sim_time', value=sim_time),
            Parameter('experiment_file', value=str(experiment_path)),
            Parameter('pacing', value=pacing),
            Parameter('block_size', value=int(plan.block_size)),
            Parameter('window_blocks', value=plan.bridge.window_blocks if on_bridge else
                      SIMULATOR_WINDOW_BLOCKS[executor_kind]),
            Parameter('lead_blocks', value=plan.bridge.lead_blocks if on_bridge else 2),
            # The launch files' rule: sample 0 waits for the device node ready on
            # excitation/ready and for its and the recorder's subscriptions.
            Parameter('start_gate', value='applier'),
            Parameter('min_subscribers', value=2),
            Parameter('autostart', value=False)])
        nodes.append(generator)
        runner = rclpy.create_node('experiment_runner', namespace=ns)
        nodes.append(runner)

        seen = {'samples': 0, 'blocks': 0, 'end': 0, 'epochs': set(), 'status': {},
                'offset': None, 'malformed': 0}

        def malformed(what: str, exc: Exception) -> None:
            """A description or status that did not parse: counted, said once, ignored."""
            seen['malformed'] += 1
            if seen['malformed'] == 1:
                _progress(f'  warning: malformed {what} ignored: {exc}')
        tracker = SequenceTracker()

        def on_measurements(msg: Float64MultiArray) -> None:
            block = msg_to_block(msg)
            tracker.observe(block.first_sample_index, block.n_samples, block.epoch)
            seen['samples'] += block.n_samples
            seen['blocks'] += 1
            seen['end'] = max(seen['end'], block.first_sample_index + block.n_samples)
            seen['epochs'].add(block.epoch)

        def on_description(msg: String) -> None:
            try:
                extra = StreamDescription.from_json(msg.data).extra
            except ValueError as exc:           # BlockError: malformed, too deep, too large
                malformed('measurement description', exc)
                return
            seen['offset'] = extra.get('excitation_offset_samples')

        def on_status(msg: String) -> None:
            try:
                status = load_json_text(msg.data, 'signal generator status')
                if not isinstance(status, dict):
                    raise ValueError(f'expected a JSON object, got {type(status).__name__}')
            except ValueError as exc:
                malformed('signal generator status', exc)
                return
            seen['status'].update(status)

        runner.create_subscription(Float64MultiArray, 'measurements', on_measurements,
                                   BLOCK_QOS)
        runner.create_subscription(String, 'measurements/description', on_description,
                                   LATCHED_QOS)
        runner.create_subscription(String, 'signal_generator/status', on_status, LATCHED_QOS)
        clients = {name: runner.create_client(Trigger, name) for name in (
            'signal_generator/start', 'recorder/start', 'recorder/stop', 'daq_bridge/start',
            'daq_bridge/stop')}
        # One thread: on an idle virtual machine every hand-over between the threads of a
        # MultiThreadedExecutor waits for a sleeping CPU (measured here: a topic round trip
        # of 138 ms median against 0.47 ms single-threaded). The recorder writes to disk in
        # its own thread (the bridge reads the device in its own), so nothing here blocks
        # the executor.
        for node in nodes:
            executor.add_node(node)

        def spin_until(predicate, timeout_s: float) -> bool:
            deadline = time.monotonic() + timeout_s
            while not predicate():
                ctrl_c.check()
                if time.monotonic() > deadline:
                    return False
                executor.spin_once(timeout_sec=0.02)
            return True

        def call(name: str, timeout_s: float = 10.0) -> Trigger.Response:
            client = clients[name]
            if not spin_until(client.service_is_ready, timeout_s):
                raise RuntimeError(f'service {ns}/{name} did not appear in {timeout_s} s')
            future = client.call_async(Trigger.Request())
            if not spin_until(future.done, timeout_s):
                raise RuntimeError(f'service {ns}/{name} did not answer in {timeout_s} s')
            return future.result()

        COMMAND_HEAP.settled()          # the imports and the nodes stay to the end
        phases.start('discovery')
        # From here every wait polls Ctrl-C: a request stops the run at a clean point.
        ctrl_c.check()
        ctrl_c.deferred = True
        # The recorder subscribes once recording: start it first, then wait until it and
        # the device node are subscribed to the excitation and the measurements.
        answer = call('recorder/start')
        if not answer.success:
            raise RuntimeError(f'recorder refused to start: {answer.message}')
        live['bag'] = str(bag)
        wanted = {f'{ns}/{t}' if not t.startswith('/') else t
                  for t in ('excitation', 'measurements')}

        def discovered() -> bool:
            return (wanted <= set(recorder.recorded_topics())
                    and generator.count_subscribers('excitation') >= 2
                    and device_node.count_subscribers('measurements') >= 2)

        if not spin_until(discovered, 30.0):
            raise RuntimeError('the nodes did not discover each other in 30 s: recorder '
                               f'topics {recorder.recorded_topics()}, excitation subscribers '
                               f'{generator.count_subscribers("excitation")}, measurement '
                               f'subscribers {device_node.count_subscribers("measurements")}')
        if on_bridge:
            # Start the acquisition while recording, so the bag holds the device stream
            # from its sample 0; a device that does not answer stops the run here.
            answer = call('daq_bridge/start')
            if not answer.success:
                raise RuntimeError(f'{device_name} could not start the device '
                                   f'({plan.bridge.backend} back-end): {answer.message}')
            # The bridge starts the device in its worker thread (the executor never waits
            # for the device); its status says when that ended.
            if not spin_until(lambda: device_node.status_values()['state']
                              in ('running', 'error'), START_WAIT_S):
                raise RuntimeError(f'{device_name} did not start the device in '
                                   f'{START_WAIT_S:g} s: {device_node.status_values()}')
            state = device_node.status_values()
            if state['state'] != 'running':
                raise RuntimeError(f'{device_name} could not start the device '
                                   f'({plan.bridge.backend} back-end): '
                                   f'{state["last_error"] or state["error"]}')
            _progress(f'  {device_name}: started, stream epoch {state["stream_epoch"]}')

        phases.start('experiment')
        answer = call('signal_generator/start')
        if not answer.success:
            raise RuntimeError(f'signal_generator refused to start: {answer.message}')
        t0 = time.monotonic()
        settle = int(round(plan.bridge.settle_s * rate)) if on_bridge else 0

        def measured() -> int:
            """Experiment samples measured so far (on the excitation's clock)."""
            if not on_bridge:
                return seen['samples']
            if seen['offset'] is None:
                return 0
            return max(0, seen['end'] - int(seen['offset']))

        last = 0.0
        clock = 'measured' if on_bridge else 'simulated'
        while measured() < total + settle:
            live['samples'] = min(measured(), total)
            ctrl_c.check()
            if time.monotonic() - t0 > plan.timeout_s:
                raise RuntimeError(f'experiment not finished after {plan.timeout_s} s: '
                                   f'{min(measured(), total)} of {total} samples measured')
            if on_bridge and device_node.faults():
                # The faults of one event come within a heartbeat or two; the recorder keeps
                # each in the bag once a description with it is in.
                until = time.monotonic() + FAULT_GATHER_S
                spin_until(lambda: time.monotonic() >= until, FAULT_GATHER_S + 1.0)
                spin_until(lambda: recorder.recorded_faults() >= len(device_node.faults()),
                           5.0)
                raise ExperimentFault(fault_message(device_node.faults(), seen['offset'],
                                                    total, rate, bag))
            if on_bridge and len(seen['epochs']) > 1:
                raise RuntimeError(f'the device stream restarted during the experiment '
                                   f'(epochs {sorted(seen["epochs"])}): the device was lost '
                                   'and reconnected; run the experiment again')
            executor.spin_once(timeout_sec=0.02)
            now = time.monotonic()
            if now - last >= 1.0:
                last = now
                done = min(measured(), total)
                _progress(f'  {100.0 * done / total:5.1f} %  section '
                          f'{seen["status"].get("section") or "-":<32} {clock} '
                          f'{done / rate:6.2f} s of {total / rate:.2f} s, wall '
                          f'{now - t0:5.1f} s')
        live['samples'] = total
        _progress(f'  100.0 %  {total} samples measured in {time.monotonic() - t0:.1f} s '
                  f'({clock} {total / rate:.1f} s)')

        phases.start('close recording')
        if on_bridge:
            # Outputs to their safe values and no more blocks: the stream has an end.
            answer = call('daq_bridge/stop')
            if answer.success:
                spin_until(lambda: device_node.status_values()['state']
                           not in ('running', 'stopping'), START_WAIT_S)
            state = device_node.status_values()
            if not answer.success or state['state'] != 'stopped':
                _progress(f'  {device_name}: stop: {answer.message} (state {state["state"]}, '
                          f'{state["last_error"]})')
        measurement_topic = f'{ns}/measurements'
        # Everything the runner received has been published; wait (bounded) until the
        # recorder has written as many measurement blocks, then close the bag.
        spin_until(lambda: recorder.written_messages().get(measurement_topic, 0)
                   >= seen['blocks'], 30.0)
        # Other topics trail the blocks. Every stream whose publisher counts its messages
        # (joint states, /clock, the excitation) is waited for until the recorder has them
        # all; the uncounted ones (diagnostics, status) until the bag has stopped growing for
        # QUIET_S (at most 10 s in all). All publishers are in this process: what they sent
        # arrives within milliseconds.
        counted = {}
        for node in (device_node, generator):
            for topic, entry in node.published_counts().items():
                counted[topic if topic.startswith('/') else f'{ns}/{topic}'] = int(
                    entry.get('published', 0))
        quiet = {'count': -1, 'since': time.monotonic()}

        def settled() -> bool:
            written = recorder.written_messages()
            count = sum(written.values())
            if count != quiet['count']:
                quiet['count'], quiet['since'] = count, time.monotonic()
            if any(written.get(topic, 0) < n for topic, n in counted.items()
                   if topic in recorded):
                return False
            return time.monotonic() - quiet['since'] > QUIET_S

        recorded = set(recorder.recorded_topics())
        spin_until(settled, 10.0)
        # Nothing more is taken, and what was taken is written: the counts are what the
        # closed bag holds (a /diagnostics message arriving between the count and the close
        # made it hold one more than they said).
        recorder.end_subscriptions()
        spin_until(lambda: recorder.queued_messages() == 0, 10.0)
        written = recorder.written_messages()
        # No silent loss: what each stream owed, published, left out and recorded, in the
        # bag's custom data (added to the open bag) and in summary.md.
        counts = stream_counts(plan, total, rate, (device_node, generator), written)
        recorder.set_parameters([Parameter('custom_data', value=yaml.safe_dump(
            {CUSTOM_DATA_KEY: {c.topic: c.as_dict() for c in counts}}, sort_keys=False))])
        answer = call('recorder/stop', timeout_s=60.0)
        if not answer.success:
            raise RuntimeError(f'recorder did not close the bag: {answer.message}')
        info = {'total_samples': total, 'sample_rate_Hz': rate, 'bag': str(bag),
                'load_mass_kg': load_kg, 'load_changer_coupled': coupled,
                'measurement_blocks_received': seen['blocks'],
                'malformed_descriptions_or_status': seen['malformed'],
                'measurement_stream': tracker.counters(),
                'written_messages': written, 'stream_counts': counts}
        if on_bridge:
            info['excitation_offset_samples'] = int(seen['offset'])
            info['device'] = _device_summary(plan, emulator)
        return info
    finally:
        ctrl_c.deferred = True          # the clean-up runs to its end
        if ctrl_c.requested and recorder is not None:
            # The runner's one line reports the bag; the recorder's own log line would repeat it.
            recorder.get_logger().set_level(LoggingSeverity.WARN)
        if executor is not None:
            executor.shutdown()         # no callback runs while the nodes go
        for node in nodes:
            node.destroy_node()         # the recorder closes its bag here
        rclpy.try_shutdown()
        if emulator is not None:
            emulator.stop()


def _start_emulator(plan: RunPlan, params: Any, load_kg: float, coupled: bool,
                    balance_path: Path) -> Any:
    """Start the device emulator (loopback only), loaded like the plan."""
    if plan.bridge.backend == 'daqmx':
        from emfc_ros.cli.daqmx_process import DaqmxEmulatorProcess
        emu = plan.bridge.emulator
        return DaqmxEmulatorProcess(emu.host, emu.port, seed=emu.seed, load_mass_kg=load_kg,
                                    load_changer_coupled=coupled, noise=emu.noise,
                                    balance_file=balance_path)
    from emfc_ros.core.device.auth import KeyFileError, load_key_file
    from emfc_ros.core.device.emulator import DeviceEmulator

    emu = plan.bridge.emulator
    # The bridge's key file, if any: the emulator speaks with the same key.
    key_file = str(plan.bridge.parameters.get('udp.key_file') or '')
    try:
        emulator = DeviceEmulator(emu.host, emu.port, params=params, seed=emu.seed,
                                  max_inputs=emu.channels, simulator_options={
                                      'load_mass_kg': float(load_kg),
                                      'load_changer_coupled': bool(coupled),
                                      'noise': emu.noise, 'quantisation': emu.quantisation},
                                  key=load_key_file(key_file) if key_file else None)
        emulator.start()
    except KeyFileError as exc:
        raise RuntimeError(f'cannot start the device emulator: {exc}') from None
    except OSError as exc:
        raise RuntimeError(f'cannot start the device emulator on {emu.host}:{emu.port}: '
                           f'{exc}') from exc
    return emulator


def _emulator_label(plan: RunPlan) -> Tuple[str, str]:
    """What the runner's emulator is, and what to say after its address."""
    if plan.bridge.backend == 'daqmx':
        from emfc_ros.cli.daqmx_process import DaqmxEmulatorProcess
        return DaqmxEmulatorProcess.what, ''
    return 'device emulator (in this process)', \
        f', {plan.bridge.emulator.channels} analog inputs'


def _device_summary(plan: RunPlan, emulator: Any) -> str:
    bridge = plan.bridge
    if emulator is not None and bridge.backend == 'daqmx':
        return (f'daq_bridge, daqmx back-end, {_emulator_label(plan)[0]} started by the '
                f'runner on {emulator.host}:{emulator.port}')
    if emulator is not None:
        return (f'daq_bridge, udp back-end, device emulator started by the runner on '
                f'{emulator.host}:{emulator.port}')
    if bridge.backend == 'daqmx':
        where = bridge.parameters.get('daqmx.grpc_address') or 'the local NI-DAQmx driver'
        return (f'daq_bridge, daqmx back-end, device '
                f'{bridge.parameters.get("daqmx.device", "Dev1")} via {where}')
    if bridge.backend == 'udp':
        return (f'daq_bridge, udp back-end, device at '
                f'{bridge.parameters.get("udp.device_host", "127.0.0.1")}:'
                f'{bridge.parameters.get("udp.device_port", 5005)}')
    return f'daq_bridge, {bridge.backend} back-end'


def identify(plan: RunPlan, info: dict, out: Path, phases: Phases,
             pool: Optional[Any] = None) -> List[str]:
    """
    Read the bag back and run the identification; return summary lines.

    Parameters
    ----------
    plan : RunPlan
        The plan.
    info : dict
        What :func:`record` returned.
    out : pathlib.Path
        The output folder.
    phases : Phases
        Timing of the phases.
    pool : PlotPool, optional
        Workers drawing the report's plots (:mod:`emfc_ros.core.report.background`).

    Returns
    -------
    list of str
        Markdown lines for the summary.
    """
    import numpy as np

    from emfc_ros.core.bag import read_streams

    phases.start('read bag')
    streams = read_streams(info['bag'])
    ns = plan.namespace
    measurements = streams[f'{ns}/measurements']
    excitation = streams[f'{ns}/excitation']
    offset = info.get('excitation_offset_samples', 0)
    lines = [f'Read back {measurements.n_samples} samples x {len(measurements.channel_names)} '
             f'channels of `{ns}/measurements` from the bag (first sample index '
             f'{measurements.first_sample_index}, gaps {len(measurements.gaps)}).', '']
    if plan.target == 'bridge':
        lines += [f'Device: {info["device"]}. Excitation sample 0 was applied at device '
                  f'sample {offset} (`excitation_offset_samples`); the identification uses '
                  f'device samples {offset} to {offset + excitation.n_samples}.', '']
    start = offset - measurements.first_sample_index
    if 'coil_setpoint_V' in measurements.channel_names and start >= 0 and \
            start + excitation.n_samples <= measurements.n_samples:
        applied = measurements.channel('coil_setpoint_V')[start:start + excitation.n_samples]
        lines.append('Largest difference between the excitation and the setpoint the DAC '
                     f'applied: {float(np.max(np.abs(applied - excitation.channel("coil")))):.3g}'
                     ' V (coil).')
        lines.append('')
    if not plan.identification.get('enabled', True):
        lines.append('Identification disabled in the plan (`identification.enabled: false`).')
        return lines
    try:
        from emfc_ros.core.ident import pipeline  # noqa: F401
    except ImportError:
        lines.append('**Identification not run:** this version has no identification '
                     'pipeline yet (issue 6); the run stops after recording. The bag holds '
                     'everything needed to identify later.')
        return lines
    return lines + _run_pipeline(plan, info, streams, out, phases, pool)


def _run_pipeline(plan: RunPlan, info: dict, streams: dict, out: Path,
                  phases: Phases, pool: Optional[Any] = None) -> List[str]:
    from emfc_ros.core.ident.errors import IdentificationError
    from emfc_ros.core.ident.from_bag import identify_bag

    phases.start('identify')
    COMMAND_HEAP.settled()              # the identification's imports (the warm-up thread's)
    folder = out / 'identification'

    def step_done(step: str, partial: Any) -> None:
        if pool is not None:            # its plots are drawn while the next step runs
            pool.submit_step(step, partial, folder)

    # The options and the pan load come from the bag (the recorder stored them), exactly as
    # `emfc-identify BAG` takes them, so that both give the same result.
    try:
        result, _ = identify_bag(Path(info['bag']), None, namespace=plan.namespace,
                                 progress=_pipeline_progress, streams=streams,
                                 on_step=step_done,
                                 executor=pool.tasks if pool is not None else None)
    except IdentificationError as exc:
        info['identification_error'] = str(exc)
        return [f'**Identification failed:** {exc}. The bag is complete; identify it again '
                f'with `emfc-identify` once the cause is fixed.']
    phases.start('report')
    from emfc_ros.core.report import write_report
    write_report(result, folder, pool=pool)
    if not result.success:
        info['identification_error'] = '; '.join(result.failures)
    return [f'Identification results, plots and summary: `{folder}/` (`results.yaml`, '
            '`summary.md`).', ''] + (folder / 'summary.md').read_text().splitlines()


def warm_up(plan: RunPlan, identify: bool) -> threading.Thread:
    """
    Import and load, in a background thread, what the run needs after setting up its nodes.

    scipy.optimize (the balancing load and the plant's hold point, then the identification),
    the simulator's compiled kernel (numba's cache, about 0.5 s to load), the identification
    modules and the grey-box fit's kernel. The main thread meanwhile imports rclpy, creates
    the nodes and waits for discovery; whatever the thread has not finished when the main
    thread gets there, the main thread waits for (the import system's and numba's locks), so
    the run does the same work in the same order either way. A failure here is ignored: the
    same import or load fails again where the run needs it, and is reported there.

    Parameters
    ----------
    plan : RunPlan
        The plan (its target and whether it identifies).
    identify : bool
        Whether this run identifies (``--no-identify`` not given).

    Returns
    -------
    threading.Thread
        The started daemon thread.
    """
    def load() -> None:
        try:
            import scipy.optimize  # noqa: F401
            from emfc_ros.core import kernels
            if plan.target == 'simulator':
                kernels.prepare(['simulator chain'])
            if identify and plan.identification.get('enabled', True):
                import emfc_ros.core.bag  # noqa: F401
                import emfc_ros.core.ident.from_bag  # noqa: F401
                import emfc_ros.core.ident.pipeline  # noqa: F401
                import emfc_ros.core.report  # noqa: F401
                kernels.prepare(['modal filter (grey-box Jacobian)'])
        except Exception:               # noqa: B902 (reported where the run needs it)
            pass

    thread = threading.Thread(target=load, name='warm-up', daemon=True)
    thread.start()
    return thread


def plot_pool(plan: RunPlan) -> Optional[Any]:
    """
    Worker processes for the report's plots, started before identifying (None: no plots).

    Parameters
    ----------
    plan : RunPlan
        The plan (identification enabled?).

    Returns
    -------
    PlotPool or None
        None when identification is disabled or matplotlib is not installed (the report then
        says so).
    """
    import importlib.util

    if not plan.identification.get('enabled', True) or \
            importlib.util.find_spec('matplotlib') is None:
        return None
    from emfc_ros.core.report.background import PlotPool
    return PlotPool()


def _pipeline_progress(step: str, fraction: float, message: str) -> None:
    _progress(f'  identify: {step:<20} {100 * fraction:5.1f} %  {message}')


def interrupted_line(out: Path, live: Mapping[str, Any]) -> str:
    """
    The one line that says what an interrupted run kept.

    Parameters
    ----------
    out : pathlib.Path
        The output folder.
    live : Mapping
        What :func:`record` filled in (``bag``, ``samples``, ``total``, ``sample_rate_Hz``,
        ``recorded`` once the recording was complete).

    Returns
    -------
    str
        For example ``interrupted (Ctrl-C) at 12000 of 490000 samples (1.20 s of 49.00 s);
        kept: bag closed, out/x/bag (130 messages)``.
    """
    bag = live.get('bag')
    if not bag:
        return (f'interrupted (Ctrl-C) before recording started; nothing recorded ({out} '
                'holds the plan only)')
    from emfc_ros.core.bag import read_metadata
    from emfc_ros.core.bag.errors import BagFormatError
    try:
        count = f'{int(read_metadata(Path(bag)).get("message_count", 0))} messages'
    except BagFormatError as exc:
        count = f'metadata unreadable: {exc}'
    if live.get('recorded'):
        return (f'interrupted (Ctrl-C) while identifying; kept: the complete recording, bag '
                f'closed, {bag} ({count}); identify it with emfc-identify {bag}')
    rate = float(live.get('sample_rate_Hz') or 1.0)
    done, total = int(live.get('samples', 0)), int(live.get('total', 0))
    return (f'interrupted (Ctrl-C) at {done} of {total} samples ({done / rate:.2f} s of '
            f'{total / rate:.2f} s); kept: bag closed, {bag} ({count})')


def main(argv: Optional[List[str]] = None) -> int:
    """
    Entry point of ``emfc-experiment``.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (``sys.argv[1:]`` when None).

    Returns
    -------
    int
        0 on success, 1 if the run failed, 2 for a bad plan (nothing started, no output
        folder), 130 after Ctrl-C (the bag closed and kept).
    """
    parser = argparse.ArgumentParser(prog='emfc-experiment',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('plan', nargs='?', default=None,
                        help=f'run plan YAML (default: the shipped {DEFAULT_PLAN})')
    parser.add_argument('-o', '--out', default=None,
                        help='output folder (default: out/<name>-<date>-<time>)')
    parser.add_argument('--no-identify', action='store_true',
                        help='stop after recording')
    args = parser.parse_args(argv)
    ctrl_c = CtrlC()
    ctrl_c.install()
    try:
        return _run(args, ctrl_c)
    except KeyboardInterrupt:
        # Ctrl-C before the run started (checking the plan): nothing was made.
        print('emfc-experiment: interrupted (Ctrl-C) before the run started; nothing '
              'recorded', file=sys.stderr, flush=True)
        return 130
    finally:
        ctrl_c.restore()


def _run(args: argparse.Namespace, ctrl_c: CtrlC) -> int:
    """Check the whole plan, then record and identify; the exit code."""
    try:
        # The whole plan, before any node starts or any folder is made: run plan, every
        # experiment file and signal, the identification options (emfc_ros.core.plan_check).
        plan = load_plan(Path(args.plan) if args.plan else config_file(DEFAULT_PLAN))
        check_bridge_parameters(plan)
    except (ConfigError, FileNotFoundError) as exc:
        print(f'emfc-experiment: {exc}', file=sys.stderr)
        return 2
    out = Path(args.out) if args.out else Path('out') / (
        f'{plan.name}-{time.strftime("%Y%m%d-%H%M%S")}')
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        print(f'emfc-experiment: output folder {out} exists and is not empty', file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    phases = Phases()
    t0 = time.monotonic()
    live: Dict[str, Any] = {}
    print(f'emfc-experiment: {plan.name} on the {plan.target}, output {out}', flush=True)
    # The plot workers start now, in the background: their fork server imports matplotlib
    # and the identification's modules on the other core while this process imports ROS and
    # sets up the nodes; the workers are forked from it, ready before the first plot.
    pool = None if args.no_identify else plot_pool(plan)
    warming = warm_up(plan, not args.no_identify)
    try:
        info = record(plan, out, phases, ctrl_c, live)
        live['recorded'] = True
        ctrl_c.check()                  # pressed while the nodes were shut down
        ctrl_c.deferred = False         # identifying: Ctrl-C stops at once
        lines = [] if args.no_identify else identify(plan, info, out, phases, pool)
    except KeyboardInterrupt:
        ctrl_c.requested = ctrl_c.deferred = True       # a second Ctrl-C is ignored now
        phases.stop()
        (out / 'timing.json').write_text(json.dumps(phases.seconds, indent=2))
        print(f'emfc-experiment: {interrupted_line(out, live)}', file=sys.stderr, flush=True)
        return 130
    except (RuntimeError, ConfigError, OSError, ValueError) as exc:
        phases.stop()
        print(f'emfc-experiment: failed: {exc}', file=sys.stderr)
        (out / 'timing.json').write_text(json.dumps(phases.seconds, indent=2))
        return 1
    finally:
        if pool is not None:
            pool.close()
        warming.join(WARM_UP_JOIN_S)    # not left importing while the interpreter ends
    phases.stop()
    wall = time.monotonic() - t0
    timing = dict(phases.seconds, total=wall)
    (out / 'timing.json').write_text(json.dumps(timing, indent=2))
    summary = [f'# {plan.name}', '',
               f'Target: {plan.target}, namespace `{plan.namespace}`, '
               f'{info["total_samples"]} samples at {info["sample_rate_Hz"]:g} Hz '
               f'({info["total_samples"] / info["sample_rate_Hz"]:.1f} s '
               f'{"on the device clock" if plan.target == "bridge" else "simulated"}), pan '
               f'load {1e3 * info["load_mass_kg"]:.2f} g, load changer '
               f'{"coupled" if info["load_changer_coupled"] else "not coupled"}.', '',
               f'Bag: `{info["bag"]}`; measurement stream as received live: '
               f'{info["measurement_stream"]}.', '',
               '| phase | wall time [s] |', '|---|---|']
    summary += [f'| {name} | {seconds:.2f} |' for name, seconds in timing.items()]
    summary += ['', '## Messages per stream', '',
                f"Also in the bag's custom data `{CUSTOM_DATA_KEY}`.", '']
    summary += markdown(info['stream_counts'])
    summary += [''] + lines
    (out / 'summary.md').write_text('\n'.join(summary) + '\n')
    print('\n'.join(summary))
    lost = problems(info['stream_counts'])
    if lost:
        print('emfc-experiment: warning: messages lost or unaccounted for: '
              + '; '.join(lost) + f' (summary.md, bag custom data {CUSTOM_DATA_KEY})',
              file=sys.stderr)
    if 'identification_error' in info:
        print(f'emfc-experiment: identification failed: {info["identification_error"]} '
              f'(bag and report kept in {out})', file=sys.stderr)
        return 1
    return 0


def console_main() -> None:
    """
    The ``emfc-experiment`` command: :func:`main`, then the process ends at once.

    Everything the run writes is closed by then (the bag by its recorder, every other file as
    it is written, the plot workers stopped); the interpreter's own teardown of the loaded
    libraries (numba's LLVM, scipy, the DDS middleware) took 0.4-0.6 s after the last line
    was printed (measured against :func:`os._exit`), so the command flushes its output and
    leaves with :func:`os._exit`. The process's garbage collector is set for a short
    command (:mod:`emfc_ros.core.heap`). Called as a function (:func:`main`) nothing of this
    applies.
    """
    COMMAND_HEAP.start()                # the collector off for the imports
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == '__main__':
    console_main()
