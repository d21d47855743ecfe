"""
emfc-weigh: the balance as a weighing instrument, in one command.

``emfc-weigh`` brings up the simulated balance in closed loop (the ``plant_simulator`` node
with the in-loop controller, owning time, driven by zero excitation at ``--speed`` simulated
seconds per wall second) and the ``weighing`` node, composed in this process over real DDS,
zeroes the balance on its first steady reading, and prints every reading as it comes:
sample time, mass, standard uncertainty, stable flag, and the dynamic estimate of the same
sample. ``--load`` puts masses on the simulated pan at times of the sample clock; ``--tare-at``
and ``--adjust-at`` act like a user at the balance. ``--target bridge`` weighs a device
through the ``daq_bridge`` node instead (``--device HOST:PORT``, or ``--start-emulator`` for
the device emulator on loopback, running the same in-loop controller).

    emfc-weigh --load 0:0,2:0.1,4:0,6:0.0734829 --adjust-at 2:0.1 --duration 8

Exit codes: 0 done (``--duration`` reached), 1 the balance could not weigh (the reason is
printed: a configuration the weighing node refuses, no readings), 2 bad arguments, 130 Ctrl-C
(one line, the nodes shut down).
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import time
from typing import Any, Dict, List, Optional

from emfc_ros.core.weighing.errors import WeighingError
from emfc_ros.core.weighing.profiles import parse_load_schedule
from emfc_ros.core.weighing.session import (ActionQueue, event_line, ExcitationPacer,
                                            parse_actions, precise_current_window,
                                            reading_line)

PROG = 'emfc-weigh'
SAMPLE_RATE_HZ = 10000.0        # the plant_simulator's and the daq_bridge's default
BLOCK = 1000
#: Wall time allowed until the first reading (the first start after an install compiles the
#: numerical kernels, about 15 to 60 s on a loaded machine).
START_TIMEOUT_S = 180.0
#: Wall time a reading waits for the dynamic reading of its sample before it is printed [s].
DYNAMIC_WAIT_S = 0.5
#: Samples per reading (reading_period_s 0.1 s at 10 kHz) and how many readings the
#: simulation may run ahead of the printed ones (the look-ahead needs one).
BLOCK_PER_READING = 1000
READINGS_AHEAD = 2
#: Until the first reading is printed the simulation may run this many readings ahead: the
#: weighing node ignores blocks that reach it before the plant's (latched) description, and
#: with only READINGS_AHEAD readings allowed the first reading's look-ahead would then never
#: be simulated (seen under load: no reading in 180 s). Zero, tare and adjust act on steady
#: readings (a full 1-s window), so the first 0.5 s run ahead harms none of them.
READINGS_AHEAD_AT_START = 5


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, description='Weigh with the EMFC balance in closed loop (simulated, or a '
                               'device through the daq_bridge) and print the readings.')
    parser.add_argument('--target', choices=('sim', 'bridge'), default='sim',
                        help="'sim' (default): the simulated balance; 'bridge': a device "
                             'through the daq_bridge')
    parser.add_argument('--load', default='',
                        help="masses on the pan over the sample clock: 'time_s:mass_kg,...', "
                             'e.g. 0:0,2:0.0734829 (sim, or bridge with --start-emulator)')
    parser.add_argument('--duration', type=float, default=0.0,
                        help='stop after this much sample time [s] (default 0: until Ctrl-C)')
    parser.add_argument('--zero-at', action='append', default=None, metavar='T',
                        help='zero on the first steady reading from T s on (default: 0; '
                             'repeatable)')
    parser.add_argument('--no-zero', action='store_true', help='do not zero at the start')
    parser.add_argument('--tare-at', action='append', default=[], metavar='T',
                        help='tare on the first steady reading from T s on (repeatable)')
    parser.add_argument('--adjust-at', action='append', default=[], metavar='T:KG',
                        help='adjust with a reference mass of KG kg on the first steady '
                             'reading from T s on (repeatable)')
    parser.add_argument('--speed', type=float, default=1.0,
                        help='sim: simulated seconds per wall second (default 1: real time; '
                             '0: as fast as the simulator runs)')
    parser.add_argument('--seed', type=int, default=0, help='noise seed of the simulation')
    parser.add_argument('--device', default='', metavar='HOST:PORT',
                        help='bridge: the device (udp protocol, docs/device_protocol.md)')
    parser.add_argument('--start-emulator', action='store_true',
                        help='bridge: start the device emulator (in-loop controller) on '
                             'loopback and weigh through it')
    parser.add_argument('--namespace', default='/emfc', help='ROS namespace of the nodes')
    parser.add_argument('--quiet-dynamic', action='store_true',
                        help='do not print the dynamic estimate')
    return parser


class _CtrlC:
    """Records SIGINT; the loop polls it and shuts down cleanly."""

    def __init__(self) -> None:
        self.requested = False
        self._previous: Any = None

    def install(self) -> None:
        self._previous = signal.signal(signal.SIGINT, self._handler)

    def restore(self) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)

    def _handler(self, signum: int, frame: Any) -> None:
        self.requested = True


def main(argv: Optional[List[str]] = None) -> int:
    """
    Entry point of ``emfc-weigh``.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (``sys.argv[1:]`` when None).

    Returns
    -------
    int
        0 done, 1 the balance could not weigh, 2 bad arguments, 130 Ctrl-C.
    """
    parser = _parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:
        return int(exc.code or 0)
    try:
        options = _check(args)
    except WeighingError as exc:
        print(f'{PROG}: error: {exc}', file=sys.stderr)
        return 2
    ctrl_c = _CtrlC()
    ctrl_c.install()
    try:
        return _Session(args, options, ctrl_c).run()
    finally:
        ctrl_c.restore()


def _check(args: argparse.Namespace) -> Dict[str, Any]:
    """Every argument checked before anything starts."""
    schedule = parse_load_schedule(args.load)
    if args.target == 'bridge' and schedule and not args.start_emulator:
        raise WeighingError('--load: on a device, put the masses on the pan yourself (the '
                            'schedule drives the simulated balance: --target sim, or the '
                            'emulator: --start-emulator)')
    if args.target == 'bridge' and not (args.device or args.start_emulator):
        raise WeighingError('--target bridge needs --device HOST:PORT or --start-emulator')
    if args.target == 'sim' and (args.device or args.start_emulator):
        raise WeighingError('--device and --start-emulator belong to --target bridge')
    device = None
    if args.device:
        host, _, port = args.device.rpartition(':')
        try:
            device = (host or '127.0.0.1', int(port))
        except ValueError:
            raise WeighingError(f'--device: {args.device!r} must be HOST:PORT') from None
        if not 1 <= device[1] <= 65535:
            raise WeighingError(f'--device: port {device[1]} must be in [1, 65535]')
    if not (math.isfinite(args.duration) and args.duration >= 0.0):
        raise WeighingError(f'--duration: {args.duration!r} must be >= 0 s (0: until Ctrl-C)')
    if not 0 <= args.seed < 2 ** 63:
        raise WeighingError(f'--seed: {args.seed} must be in [0, 2^63)')
    zero_at = [] if args.no_zero else (args.zero_at or ['0'])
    actions = parse_actions(zero_at, args.tare_at, args.adjust_at)
    ExcitationPacer(SAMPLE_RATE_HZ, BLOCK, args.speed)          # checks --speed
    return {'schedule': schedule, 'device': device, 'actions': actions}


class _Session:
    """The composed nodes, the user's client node and the loop that prints."""

    def __init__(self, args: argparse.Namespace, options: Dict[str, Any],
                 ctrl_c: _CtrlC) -> None:
        self.args = args
        self.options = options
        self.ctrl_c = ctrl_c
        self.actions = ActionQueue(options['actions'])
        self.readings: List[Any] = []
        self.dynamic: Dict[int, Dict[str, str]] = {}
        self.acked = 0
        self.sent = 0
        self.rate = SAMPLE_RATE_HZ
        self.last_time_s: Optional[float] = None
        self.load_changes_seen = 0
        self.future = None
        self.future_action = None
        self.count = 0
        self.emulator = None
        self._first_seen: Dict[int, float] = {}
        self._timed: List[Any] = []
        self.handled_index = -1             # the last reading printed and acted on

    # -- set-up ----------------------------------------------------------------------------

    def _nodes(self):
        from rclpy.parameter import Parameter
        from emfc_ros.nodes.weighing import WeighingNode
        ns = self.args.namespace
        nodes = []
        if self.args.target == 'sim':
            from emfc_ros.nodes.plant_simulator import PlantSimulatorNode
            load = ','.join(f'{t!r}:{m!r}' for t, m in self.options['schedule'])
            nodes.append(PlantSimulatorNode(namespace=ns, parameter_overrides=[
                Parameter('time_mode', value='owner'),
                Parameter('control.enabled', value=True),
                Parameter('load_schedule', value=load),
                Parameter('seed', value=int(self.args.seed)),
                Parameter('state_rate_Hz', value=0.0),
                Parameter('publish_groups', value=False)]))
        else:
            from emfc_ros.nodes.daq_bridge import DaqBridgeNode
            host, port = self.options['device'] or self._start_emulator()
            nodes.append(DaqBridgeNode(namespace=ns, parameter_overrides=[
                Parameter(k, value=v) for k, v in self._bridge_parameters(host, port).items()]))
        nodes.append(WeighingNode(namespace=ns))
        return nodes

    def _emulator_options(self) -> Dict[str, Any]:
        from emfc_ros.core.control.loop_config import LoopConfig
        return {'control': LoopConfig(), 'load_schedule': self.options['schedule']}

    def _start_emulator(self):
        from emfc_ros.core.device.emulator import DeviceEmulator
        self.emulator = DeviceEmulator('127.0.0.1', 0, seed=int(self.args.seed),
                                       simulator_options=self._emulator_options())
        port = self.emulator.start()
        print(event_line(None, f'device emulator on 127.0.0.1:{port} (in-loop controller)'),
              flush=True)
        return '127.0.0.1', port

    def _bridge_parameters(self, host: str, port: int) -> Dict[str, Any]:
        from emfc_ros.core.control.loop_config import CurrentChannelConfig, LoopConfig
        from emfc_ros.core.device.backend import default_input_channel
        from emfc_ros.core.model.balance_file import load_balance
        from emfc_ros.core.sim.hold_point import hold_point
        from emfc_ros.core.sim.resolution import simulator_resolution
        params = load_balance()
        currents = [hold_point(params, m).currents_A[0] for m in (0.0, LoopConfig().max_load_kg)]
        offset, scale = precise_current_window(currents)
        position = default_input_channel('position_m', params)
        out = {'backend': 'udp', 'udp.device_host': host, 'udp.device_port': int(port),
               'inputs': ['coil_current_precise_A', 'position_m'],
               'input_units': ['A', 'm'], 'input_scales': [scale, position.scale],
               'input_offsets': [offset, 0.0], 'state_rate_Hz': 0.0,
               'publish_groups': False}
        if self.emulator is not None:
            # the emulator's converter noise is known: the quantisation budget may count on it
            res = simulator_resolution(params, current_channel=CurrentChannelConfig())
            out['input_noise_rms'] = [res['coil_current_precise_A']['noise_rms'],
                                      res['position_m']['noise_rms']]
        return out

    def _client(self, context_node):
        from diagnostic_msgs.msg import DiagnosticArray
        from std_msgs.msg import Float64MultiArray, String, UInt64
        from std_srvs.srv import Trigger
        from emfc_ros.nodes.convert import BLOCK_QOS, CONTROL_QOS, LATCHED_QOS
        from emfc_ros.nodes.weighing import DYNAMIC_QOS, READING_QOS
        node = context_node
        self.pub = node.create_publisher(Float64MultiArray, 'excitation', BLOCK_QOS)
        node.create_subscription(UInt64, 'excitation/consumed',
                                 lambda m: setattr(self, 'acked', max(self.acked, m.data)),
                                 CONTROL_QOS)
        node.create_subscription(DiagnosticArray, 'weighing/reading', self.readings.append,
                                 READING_QOS)
        node.create_subscription(DiagnosticArray, 'weighing/dynamic', self._on_dynamic,
                                 DYNAMIC_QOS)
        node.create_subscription(String, 'measurements/description', self._on_description,
                                 LATCHED_QOS)
        self.services = {name: node.create_client(Trigger, f'weighing/{name}')
                         for name in ('zero', 'tare', 'adjust')}

    def _on_dynamic(self, msg) -> None:
        values = {kv.key: kv.value for kv in msg.status[0].values}
        self.dynamic[int(values['sample_index'])] = values
        if len(self.dynamic) > 2000:
            for key in sorted(self.dynamic)[:1000]:
                del self.dynamic[key]

    def _on_description(self, msg) -> None:
        from emfc_ros.core.blocks import StreamDescription
        try:
            description = StreamDescription.from_json(msg.data)
        except ValueError:
            return
        self.rate = description.sample_rate_Hz
        changes = description.extra.get('load_changes') or []
        for index, mass in changes[self.load_changes_seen:]:
            self._event_at(index, f'{mass * 1e3:g} g on the pan (sample {index}, from the '
                                  'plant description)')
        self.load_changes_seen = max(self.load_changes_seen, len(changes))

    def _event_at(self, index: int, text: str) -> None:
        """An event of a sample: printed before the first reading that reaches it."""
        self._timed.append((int(index), text))
        self._timed.sort()

    def _flush_events(self, before_index: float) -> None:
        while self._timed and self._timed[0][0] <= before_index:
            index, text = self._timed.pop(0)
            print(event_line(index / self.rate, text), flush=True)

    # -- the loop --------------------------------------------------------------------------

    def run(self) -> int:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.logging import LoggingSeverity
        from rclpy.signals import SignalHandlerOptions
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        nodes = []
        try:
            print(event_line(None, f'{PROG}: {self._what()}; starting the nodes (the first '
                                   'start after an install compiles the kernels)'), flush=True)
            for name in ('plant_simulator', 'weighing', 'daq_bridge'):
                # warnings and errors only: the readings and events are the output
                rclpy.logging.set_logger_level(
                    f'{self.args.namespace.strip("/").replace("/", ".")}.{name}'.lstrip('.'),
                    LoggingSeverity.WARN)
                rclpy.logging.set_logger_level(name, LoggingSeverity.WARN)
            nodes = self._nodes()
            self.weighing = nodes[-1]
            client = rclpy.create_node('emfc_weigh', namespace=self.args.namespace)
            nodes.append(client)
            self._client(client)
            executor = SingleThreadedExecutor()
            for node in nodes:
                executor.add_node(node)
            return self._loop(executor)
        except KeyboardInterrupt:
            self.ctrl_c.requested = True
            return self._interrupted()
        finally:
            signal.signal(signal.SIGINT, signal.SIG_IGN)     # the clean-up is short
            for node in nodes:
                node.destroy_node()
            rclpy.try_shutdown()
            if self.emulator is not None:
                self.emulator.stop()

    def _what(self) -> str:
        if self.args.target == 'sim':
            speed = 'as fast as it runs' if self.args.speed == 0 else \
                f'{self.args.speed:g} x real time'
            return f'simulated balance in closed loop, {speed}'
        where = ' (emulator)' if self.args.start_emulator else f' at {self.args.device}'
        return 'a device through the daq_bridge' + where

    def _interrupted(self) -> int:
        at = f'{self.last_time_s:.3f} s of sample time' if self.last_time_s is not None \
            else 'the start'
        print(f'{PROG}: interrupted (Ctrl-C) at {at} after {self.count} readings; nodes shut '
              'down', file=sys.stderr, flush=True)
        return 130

    def _loop(self, executor) -> int:
        started = time.monotonic()
        pacer = ExcitationPacer(SAMPLE_RATE_HZ, BLOCK, self.args.speed)
        duration = self.args.duration
        last_error = ''
        while True:
            executor.spin_once(timeout_sec=0.005)
            if self.ctrl_c.requested:
                return self._interrupted()
            refused = self.weighing._config_error or self.weighing._stream_error
            if refused:
                print(f'{PROG}: the weighing node refuses: {refused}', file=sys.stderr,
                      flush=True)
                return 1
            if self.args.target == 'sim':
                self._drive(pacer, duration)
            self._emulator_events()
            while self.readings:
                msg = self.readings[0]
                status = msg.status[0]
                if status.level == status.ERROR:
                    self.readings.pop(0)
                    if status.message != last_error:
                        print(event_line(None, f'weighing: {status.message}'), flush=True)
                        last_error = status.message
                    continue
                values = {kv.key: kv.value for kv in status.values}
                # the dynamic reading of the same sample comes on its own topic: wait for it
                # a little (it is released earlier on the sample clock, but may be queued)
                waited = time.monotonic() - self._first_seen.setdefault(id(msg),
                                                                        time.monotonic())
                if not self.args.quiet_dynamic and waited < DYNAMIC_WAIT_S and \
                        int(values['sample_index']) not in self.dynamic:
                    break
                self.readings.pop(0)
                self._first_seen.pop(id(msg), None)
                self._print(values)
                if duration and self.last_time_s >= duration - 1e-9:
                    self._flush_events(self.handled_index)
                    print(event_line(self.last_time_s, f'{duration:g} s weighed: done '
                                                       f'({self.count} readings)'), flush=True)
                    return 0
            self._act()
            if self.count == 0 and time.monotonic() - started > START_TIMEOUT_S:
                print(f'{PROG}: no reading after {START_TIMEOUT_S:g} s: '
                      f'{last_error or "no measurements"}', file=sys.stderr, flush=True)
                return 1

    def _drive(self, pacer: ExcitationPacer, duration: float) -> None:
        """Zero excitation blocks to the simulator, which owns time and simulates on them."""
        import numpy as np
        from emfc_ros.nodes.convert import block_to_msg
        if self.pub.get_subscription_count() < 1:
            return
        # a reading is released one reading period after its last sample: simulate past the
        # end for the last ones
        end = math.inf if not duration else int(round((duration + 0.25) * SAMPLE_RATE_HZ))
        if self.future is not None:
            return      # an action waits for its answer: the balance does not run ahead
        # the simulator never runs more than two readings ahead of what is printed and acted
        # on, so that zero, tare and adjust act on the reading they were asked for
        ahead = self.handled_index + 1 + READINGS_AHEAD * BLOCK_PER_READING
        if self.count == 0:
            ahead = max(ahead, READINGS_AHEAD_AT_START * BLOCK_PER_READING)
        allowed = min(pacer.allowed_index(time.monotonic(), self.acked), end, ahead)
        while self.sent < allowed:
            self.pub.publish(block_to_msg(self.sent, SAMPLE_RATE_HZ, 1, np.zeros((2, BLOCK))))
            self.sent += BLOCK

    def _emulator_events(self) -> None:
        if self.emulator is None:
            return
        changes = self.emulator.device.load_changes
        for _, index, mass in changes[self.load_changes_seen:]:
            self._event_at(index, f'{mass * 1e3:g} g on the pan (sample {index}, the emulator)')
        self.load_changes_seen = max(self.load_changes_seen, len(changes))

    def _print(self, values: Dict[str, str]) -> None:
        index = int(values['sample_index'])
        self._flush_events(index)
        self.handled_index = index
        self.last_time_s = (index + 1) / self.rate
        self.count += 1
        dynamic = None if self.args.quiet_dynamic else self.dynamic.get(index)
        print(reading_line(values, self.rate, dynamic), flush=True)
        action = self.actions.due(self.last_time_s, values.get('steady') == 'true')
        if action is not None:
            self._request(action)

    def _request(self, action) -> None:
        from rclpy.parameter import Parameter
        from std_srvs.srv import Trigger
        if action.kind == 'adjust':
            self.weighing.set_parameters([Parameter('reference_mass_kg',
                                                    value=float(action.mass_kg))])
        client = self.services[action.kind]
        if not client.service_is_ready():
            self.actions.finished(False, 'service not ready yet')
            return
        self.future = client.call_async(Trigger.Request())
        self.future_action = action

    def _act(self) -> None:
        if self.future is None or not self.future.done():
            return
        answer = self.future.result()
        action, self.future = self.future_action, None
        given_up = self.actions.finished(answer.success, answer.message)
        if answer.success:
            print(event_line(self.last_time_s, f'{action.describe()}: done: {answer.message}'),
                  flush=True)
        elif given_up:
            print(event_line(self.last_time_s, given_up), flush=True)


if __name__ == '__main__':
    sys.exit(main())
