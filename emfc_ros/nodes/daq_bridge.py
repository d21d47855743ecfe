"""
The daq_bridge node: the only node that talks to the DAQ/FPGA device (or its stand-ins).

Same topics in and out as the plant simulator, so experiments, recorders and controllers
run unchanged on hardware. Topics (relative to the node namespace):

- ``excitation`` (``std_msgs/Float64MultiArray``, in): setpoint-voltage blocks [V], one row
  per device output (``coil``, ``load_changer``), block convention. Clamped to the output
  limits (counted) and streamed to the device ``excitation_lead_s`` ahead of its sample
  clock: excitation sample ``k`` of an epoch is applied at device sample ``k + offset``, the
  offset fixed when the epoch's first block arrives and published in the measurements
  description (``extra.excitation_offset_samples``). ``excitation/consumed``
  (``std_msgs/UInt64``, out): excitation samples the device has applied.
  ``excitation/ready`` (``std_msgs/String``, out, latched): JSON ``{node, ready, waiting}``,
  ready while the device runs with the excitation subscribed (a generator's start gate
  waits for it); otherwise what the bridge waits for.
- ``measurements`` (out): the device's input channels, one block per device frame, with the
  device's exact sample indices (never a block that spans a gap); latched
  ``measurements/description`` with names and units from the device configuration;
  ``measurements/position``, ``current`` and ``force`` (out): grouped by unit.
- ``joint_states`` (out), ``joint_commands`` and ``commands`` (in): the controller interface;
  an effort command [N] becomes a coil setpoint through the balance's motor and amplifier
  characteristics and is added to the coil output; zeroed after ``command_timeout_s``.
- ``/diagnostics`` (out): back-end health, excitation defects, clamping, watchdog, e-stop,
  arrival-to-publication latency.

Services (``std_srvs/Trigger``): ``~/start``, ``~/stop`` (acquisition), ``~/emergency_stop``
(outputs to their safe values at once, latched) and ``~/reset`` (release the e-stop). Nothing
that waits for the device runs on the executor: start, stop, the safe-output and generator
requests run in order in one worker thread (:class:`~emfc_ros.core.device.jobs.DeviceJobs`);
``~/start`` and ``~/stop`` answer at once that the request is under way, and ``~/status``
(``std_msgs/String``, latched JSON) says how it ended (``state``: ``starting``, ``running``,
``stopping``, ``stopped``, ``done`` (a replay published its last block) or ``error``, with
``error``, ``last_error``).
"""

from __future__ import annotations

import collections
import json
import math
import threading
import time
from typing import Any, Dict, List, Optional, Sequence, Tuple

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.exceptions import ParameterUninitializedException
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String, UInt64
from std_srvs.srv import Trigger

from emfc_ros.core.blocks import Block, Channel, Continuity, SequenceTracker, StreamDescription
from emfc_ros.core.device import protocol
from emfc_ros.core.device import registry
from emfc_ros.core.device.backend import (check_generator_range, DEFAULT_INPUTS,
                                          DEFAULT_OUTPUTS, DeviceBackend, DeviceConfig)
from emfc_ros.core.device.clock import device_index_at, earliest_start_ns
from emfc_ros.core.device.errors import DeviceConfigError, DeviceError, DeviceRefusedError
from emfc_ros.core.device.faults import describe, Fault, FaultMonitor
from emfc_ros.core.device.function_generator import GeneratorSpec, make_signal
from emfc_ros.core.device.jobs import DeviceJobs
from emfc_ros.core.errors import BlockError, ConfigError
from emfc_ros.core.excitation_queue import DROPPED, ExcitationQueue, JumpGuard
from emfc_ros.core.model.actuation import coil_setpoint_for_force_V
from emfc_ros.core.model.balance_file import load_balance
from emfc_ros.core.pan_load import declared_pan_load
from emfc_ros.core.start_gate import readiness_text
from emfc_ros.nodes.convert import (
    BLOCK_QOS, BlockMessageBuilder, CONTROL_QOS, description_to_msg, LATCHED_QOS, msg_to_block,
    node_diagnostics, steady_clock, subscribe_device_inputs, subscribe_excitation)
from emfc_ros.nodes.params import declare_table, refuse_unknown
from emfc_ros.nodes.spin import node_main

EXCITATION_MODES = ('stream', 'function_generator')
JOINT = 'lever'
STATE_QOS = QoSProfile(depth=1000)
LATENCY_WINDOW = 20000
GROUP_UNITS = {'position': ('m',), 'current': ('A',), 'force': ('N',)}
GROUP_EXTRA = {'position': ('sensor_V',)}

#: Parameters whose type is declared without a default (empty: derived).
_UNSET_STRINGS = Parameter.Type.STRING_ARRAY
_UNSET_DOUBLES = Parameter.Type.DOUBLE_ARRAY

PARAMETERS: Dict[str, Tuple[Any, str]] = {
    'backend': ('sim', registry.backend_summary()),
    'autostart': (True, 'configure and start the device when the node comes up'),
    'min_subscribers': (0, 'autostart: start the device (or the replay) and subscribe to the '
                           'excitation only once this many subscriptions to measurements have '
                           'matched [count], so that a listener started with the node loses '
                           'nothing'),
    'sample_rate_Hz': (10000.0, 'device sample clock [Hz], (0, 1e7]'),
    'block_size': (1000, 'samples per channel per measurement block [samples], 1 to 65535'),
    'inputs': (list(DEFAULT_INPUTS), 'measured channel names (the unit is the suffix)'),
    'input_units': (_UNSET_STRINGS, 'SI unit of each input; unset: the converter default'),
    'input_scales': (_UNSET_DOUBLES, 'SI value per converter code of each input [unit/code]; '
                                     'unset: the converter default'),
    'input_offsets': (_UNSET_DOUBLES, 'SI value at code 0 of each input [unit]; unset: 0'),
    'input_noise_rms': (_UNSET_DOUBLES, 'noise at the converter of each input, independent '
                                        'from sample to sample [unit rms], published with the '
                                        'code step in the description (extra.resolution) so '
                                        'that a consumer can budget the quantisation; unset '
                                        'or 0: unknown, no dither assumed'),
    'outputs': (list(DEFAULT_OUTPUTS), 'actuator output names: coil, load changer'),
    'output_min_V': ([-10.0, -10.0], 'lower limit of each output [V]; setpoints are clamped'),
    'output_max_V': ([10.0, 10.0], 'upper limit of each output [V]; setpoints are clamped'),
    'output_safe_V': ([0.0, 0.0], 'safe value of each output [V]: driven when stopped, on '
                                  'watchdog trip and emergency stop'),
    'device_watchdog_timeout_s': (0.5, "the device's own watchdog [s]: outputs safe when the "
                                       'host is silent this long'),
    'excitation_mode': ('stream', "'stream': excitation blocks in; 'function_generator': "
                                  'the on-device generator (funcgen.<output>.*); outputs '
                                  "with waveform 'off' still follow the excitation stream"),
    'excitation_lead_s': (0.1, 'setpoints are written this far ahead of the device clock '
                               '[s], 0 to 10'),
    'watchdog_timeout_s': (1.0, 'outputs go to their safe values when excitation stopped '
                                'arriving for this long [s], (0, 3600]'),
    'state_rate_Hz': (1000.0, 'rate of joint_states [Hz], 0 disables, at most '
                              'sample_rate_Hz'),
    'command_timeout_s': (0.1, 'effort command watchdog [s]: the command returns to 0 N after '
                               'this long without a new one, (0, 60]'),
    'publish_groups': (True, 'also publish measurements/position, current and force'),
    'balance_file': ('', 'balance parameter YAML (motor and amplifier characteristics for '
                         'effort commands, and the sim back-end); empty: the shipped default'),
    'diagnostics_period_s': (1.0, 'period of /diagnostics [s], 0.05 to 60'),
    'publisher_depth': (100, 'history depth of the block publishers [blocks], 1 to 100000: '
                             'a burst after a stall longer than this overruns slow readers'),
    'pan.load_mass_kg': (-1.0, 'mass on the pan during the experiment [kg], 0 to 100, '
                               'published in the measurement description for the '
                               'identification (emfc-identify reads it); negative: not '
                               'declared'),
    'pan.load_changer_coupled': ('', "'true' or 'false': whether the load changer's moving "
                                     'mass rides on the pan (published like '
                                     "pan.load_mass_kg); '': not declared"),
    # every back-end's options: '<backend>.<option>' (core/device/registry.py)
    **registry.parameter_table(),
}


#: Inclusive limits of the numeric parameters (descriptors; ``ros2 param describe``); an
#: open end at 0 is checked by the node.
LIMITS = {'sample_rate_Hz': (0.0, 1e7), 'block_size': (1, 65535),
          'device_watchdog_timeout_s': (0.0, 3600.0), 'excitation_lead_s': (0.0, 10.0),
          'watchdog_timeout_s': (0.0, 3600.0), 'command_timeout_s': (0.0, 60.0),
          'diagnostics_period_s': (0.05, 60.0), 'publisher_depth': (1, 100000),
          'min_subscribers': (0, 100), **registry.parameter_limits()}

#: Function-generator fields (``funcgen.<output>.<field>``) and their defaults.
FUNCGEN_FIELDS = {
    'waveform': ('off', "'off' (follow the excitation stream), 'sine', 'chirp', 'prbs', "
                        "'constant'"),
    'amplitude_V': (0.0, 'peak amplitude [V] (PRBS: +/- levels)'),
    'frequency_Hz': (0.0, 'sine frequency, chirp start frequency [Hz]'),
    'f_stop_Hz': (0.0, 'chirp stop frequency [Hz]'),
    'sweep_time_s': (1.0, 'chirp sweep duration [s]'),
    'method': ('logarithmic', "chirp law: 'linear' or 'logarithmic'"),
    'phase_rad': (0.0, 'phase at sample 0 [rad]'),
    'prbs_order': (10, 'PRBS register length, 2 to 31'),
    'prbs_hold_samples': (1, 'samples per PRBS bit [samples]'),
    'gain': (1.0, 'signal matching gain [1]'),
    'offset_V': (0.0, 'signal matching offset [V]'),
}
#: Autostart retries a device that does not answer this often [s].
RETRY_PERIOD_S = 5.0
#: Excitation that arrives while the device is starting is kept for the start (at most this
#: many samples per output): mapped before START is confirmed it would be lost at the start.
EARLY_EXCITATION_MAX_SAMPLES = 1_000_000
RUNTIME = ('watchdog_timeout_s', 'command_timeout_s', 'state_rate_Hz', 'excitation_lead_s')
#: Every other parameter of the table is fixed at start-up.
READ_ONLY = tuple(name for name in PARAMETERS if name not in RUNTIME)
#: Shown in the start-up log line (with every parameter set to a non-default value).
STARTUP_KEYS = ('backend', 'excitation_mode', 'sample_rate_Hz', 'block_size', 'autostart')
HELP_EXTRA = ('funcgen.<output>.<field> (one group per output, <output> without its _V '
              'suffix; settable at run time): ' + '; '.join(
                  f'{field} (default {default!r}): {text}'
                  for field, (default, text) in FUNCGEN_FIELDS.items())
              + '; prbs_order from 2 to 31.')


def funcgen_key(output: str) -> str:
    """
    The ``funcgen.<key>.*`` parameter group of an output channel.

    Parameters
    ----------
    output : str
        Output channel name, for example ``'coil_V'``.

    Returns
    -------
    str
        The name without its ``_V`` unit suffix (``'coil'``).
    """
    return output[:-2] if output.endswith('_V') and len(output) > 2 else output


def _percentiles_us(values: Sequence[int]) -> Tuple[float, float]:
    if not values:
        return float('nan'), float('nan')
    arr = np.fromiter(values, dtype=np.float64, count=len(values))
    return float(np.median(arr) / 1e3), float(np.percentile(arr, 99) / 1e3)


class DaqBridgeNode(Node):
    """
    Bridge between ROS topics and a device back-end (sim, udp or replay).

    Parameters
    ----------
    **kwargs
        Passed to :class:`rclpy.node.Node` (for example ``parameter_overrides``).
    """

    def __init__(self, **kwargs) -> None:
        super().__init__('daq_bridge', allow_undeclared_parameters=True,
                         automatically_declare_parameters_from_overrides=True, **kwargs)
        refused = declare_table(self, PARAMETERS, LIMITS, READ_ONLY)
        funcgen = {f'funcgen.{funcgen_key(str(out))}.{field}': entry
                   for out in self._param('outputs') or []
                   for field, entry in FUNCGEN_FIELDS.items()}
        refused += declare_table(self, funcgen, {
            name: (2, 31) for name in funcgen if name.endswith('.prbs_order')})
        refused += refuse_unknown(self, [*PARAMETERS, *funcgen])
        self._runtime: Dict[str, float] = {}
        for name in RUNTIME:
            try:
                self._runtime[name] = float(self._param(name))
            except (TypeError, ValueError):     # refused with a reason by _build
                self._runtime[name] = float(PARAMETERS[name][0])
        self._lock = threading.RLock()
        self._start_lock = threading.Lock()
        #: Excitation blocks received while the device was starting: (block, samples, clipped).
        self._early: List[Tuple[Block, np.ndarray, int]] = []
        # Everything that waits for the device runs here, in order, never on the executor.
        self._jobs = DeviceJobs('daq-bridge-device')
        # (kind, device index, message, exact) found off the executor thread, latched by it
        self._worker_faults: List[Tuple[str, Optional[int], str, bool]] = []
        self._retry_at: Optional[float] = None
        self._start_refused = False
        self._autostart_active = False
        self._error = ''
        self._last_error = ''
        self._state = 'idle'
        self._backend: Optional[DeviceBackend] = None
        self._config: Optional[DeviceConfig] = None
        self._pan: Dict[str, Any] = {}
        self._specs: List[GeneratorSpec] = []
        self._balance: Any = None
        self._counts: Dict[str, int] = collections.Counter()
        self._latency_ns: collections.deque = collections.deque(maxlen=LATENCY_WINDOW)
        self._age_ns: collections.deque = collections.deque(maxlen=LATENCY_WINDOW)
        self._reader: Optional[threading.Thread] = None
        self._reader_stop = threading.Event()
        self._sim_timer = None
        self._reset_stream_state()
        self._estop = False
        self._tripped = False
        self._monitor = FaultMonitor()
        self._safe_failed = ''
        self._command_N = 0.0
        self._command_time = -math.inf
        self._last_position_m = 0.0
        self._builders: Dict[str, BlockMessageBuilder] = {}
        self._groups: Dict[str, List[int]] = {}
        self._pub: Dict[str, Any] = {}
        self._pub_desc: Dict[str, Any] = {}
        try:
            if refused:     # no device started with values nobody asked for
                raise ValueError('; '.join(refused))
            self._build()
        except (ConfigError, DeviceConfigError, DeviceError, ValueError, OSError,
                TypeError) as exc:
            self._error = f'configuration refused: {exc}'
            self._state = 'error'
            self.get_logger().error(self._error)
        self._make_publishers()
        self._pub_status = self.create_publisher(String, '~/status', LATCHED_QOS)
        self._pub_ready = self.create_publisher(String, 'excitation/ready', LATCHED_QOS)
        self._readiness = ''
        self._holding = False
        self._wanted = 0
        self._pub_ack = self.create_publisher(UInt64, 'excitation/consumed', CONTROL_QOS)
        self._pub_state = self.create_publisher(JointState, 'joint_states', STATE_QOS)
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        wanted = int(self._param('min_subscribers'))     # declare_table: 0 to 100
        hold = self._backend is not None and bool(self._param('autostart')) and wanted > 0
        # Holding for listeners, the excitation is subscribed only once started, so that a
        # generator waiting for its consumer (min_subscribers) waits for the listeners too.
        subscribe_device_inputs(self, None if hold else self._on_excitation,
                                self._on_joint_command, self._on_array_command)
        self.create_service(Trigger, '~/start', self._srv_start)
        self.create_service(Trigger, '~/stop', self._srv_stop)
        self.create_service(Trigger, '~/emergency_stop', self._srv_estop)
        self.create_service(Trigger, '~/reset', self._srv_reset)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        period = float(self._param('diagnostics_period_s'))
        self.create_timer(min(60.0, max(0.05, period)), self._publish_diagnostics,
                          clock=steady_clock())
        self.create_timer(0.01, self._watchdog_tick, clock=steady_clock())
        self._sim_timer = None
        if self._backend is not None and self._backend.host_paced:
            # Created once: the worker thread that starts and stops never creates timers.
            block = self._config.block_size
            period = min(0.02, max(0.001, 0.5 * block / self._rate))
            self._sim_timer = self.create_timer(period, self._sim_tick, clock=steady_clock())
        self._holding = hold
        self._wanted = wanted
        self._publish_status()
        if self._backend is not None and self._param('autostart'):
            self._autostart_active = True
            if hold:
                self.get_logger().info(f'waiting for {wanted} subscription(s) to measurements '
                                       'before starting')
            else:
                self._request_start('autostart')
            self.create_timer(0.05, self._autostart_tick, clock=steady_clock())

    # -- starting and stopping, off the executor ------------------------------------------

    def _request_start(self, why: str) -> str:
        """Queue a start in the worker thread; say what happens."""
        if self._state == 'running':
            return 'already running'
        self._set_state('starting')
        self._jobs.submit('start', self._start_job, why)
        return ('start requested: configuring and starting the device in the background; '
                '~/status says when it runs (state running) or why not (state error)')

    def _start_job(self, why: str) -> Tuple[bool, str]:
        self._start_refused = False
        ok, message = self._start()
        if ok:
            self._retry_at = None
            self.get_logger().info(f'{why}: {message}')
        elif why == 'autostart' and self._autostart_active and self._start_refused:
            self._retry_at = None
            self.get_logger().error(f'{message}; not retried (the device refused the '
                                    'configuration: fix the parameters, for example inputs '
                                    'for a device with fewer analog inputs, and restart the '
                                    'node or call ~/start)')
        elif why == 'autostart' and self._autostart_active:
            self._retry_at = time.monotonic() + RETRY_PERIOD_S
            self.get_logger().error(f'{message}; retrying every {RETRY_PERIOD_S} s',
                                    throttle_duration_sec=30.0)
        else:
            self.get_logger().error(message)
        return ok, message

    def _autostart_tick(self) -> None:
        """Autostart: once listeners matched (min_subscribers), and retries of a silent device."""
        if not self._autostart_active:
            return
        if self._holding:
            matched = self._pub['measurements'].get_subscription_count()
            if matched < self._wanted:
                return
            self._end_hold()
            if self._state in ('running', 'starting'):     # started through ~/start
                return
            self.get_logger().info(f'{matched} subscription(s) to measurements matched: '
                                   'starting')
            self._request_start('autostart')
            return
        due = self._retry_at
        if due is not None and time.monotonic() >= due and not self._jobs.pending('start'):
            self._retry_at = None
            if self._state != 'running':
                self._request_start('autostart')

    def _end_hold(self) -> None:
        """Stop waiting for listeners (min_subscribers) and subscribe to the excitation."""
        if self._holding:
            self._holding = False
            subscribe_excitation(self, self._on_excitation)

    def _cancel_retry(self) -> None:
        self._autostart_active = False
        self._retry_at = None

    def _set_state(self, state: str) -> None:
        self._state = state
        self._publish_status()

    def status_values(self) -> Dict[str, Any]:
        """
        What ``~/status`` says: the state and why.

        Returns
        -------
        dict
            ``state``, ``error``, ``last_error``, ``stream_epoch``, ``faults`` (count),
            ``device_busy`` (a request to the device under way).
        """
        return {'state': self._state, 'error': self._error, 'last_error': self._last_error,
                'stream_epoch': self._epoch if self._epoch is not None else -1,
                'faults': len(self._monitor.faults), 'device_busy': self._jobs.pending()}

    def _publish_status(self) -> None:
        try:
            self._pub_status.publish(String(data=json.dumps(self.status_values())))
            self._announce_readiness()
        except Exception:   # noqa: B902 during shutdown the publisher may be gone
            if self.context.ok():
                raise

    def _readiness_values(self) -> Tuple[bool, str]:
        """Whether excitation arriving now is applied, and if not what the bridge waits for."""
        if self._backend is not None and not self._backend.applies_excitation:
            return False, f'applies no excitation ({self._backend.name} back-end)'
        if self._holding:
            pub = self._pub.get('measurements')
            matched = pub.get_subscription_count() if pub is not None else 0
            return False, (f'waits for {self._wanted} subscription(s) to '
                           f'{pub.topic_name if pub is not None else "measurements"} before '
                           f'starting the device (a recorder; {matched} matched)')
        if self._state == 'running':
            return True, ''
        if self._state == 'error' or self._error:
            return False, f'refuses: {self._last_error or self._error}'
        return False, {'starting': 'waits for the device to start',
                       'stopping': 'waits for the device to stop'}.get(
            self._state, f'waits for a start (state {self._state}: call ~/start)')

    def _announce_readiness(self) -> None:
        """Publish excitation/ready when what it says changes."""
        pub = getattr(self, '_pub_ready', None)
        if pub is None:
            return
        ready, waiting = self._readiness_values()
        text = readiness_text(self.get_fully_qualified_name(), ready, waiting)
        if text != self._readiness:
            self._readiness = text
            pub.publish(String(data=text))

    # -- configuration ---------------------------------------------------------------------

    def _param(self, name: str):
        try:
            return self.get_parameter(name).value
        except ParameterUninitializedException:
            return None

    def _device_mapping(self) -> Dict[str, Any]:
        cfg: Dict[str, Any] = {'watchdog_timeout_s': self._param('device_watchdog_timeout_s')}
        for key in ('sample_rate_Hz', 'block_size', 'inputs', 'input_units', 'input_scales',
                    'input_offsets', 'outputs', 'output_min_V', 'output_max_V',
                    'output_safe_V'):
            value = self._param(key)
            if value is None:
                continue
            if not isinstance(value, (str, bool, int, float)):
                value = list(value)
            cfg[key] = value
        return cfg

    def _backend_mapping(self) -> Dict[str, Any]:
        """The registry's mapping (core/device/registry.py) from the node's parameters."""
        cfg: Dict[str, Any] = {'backend': str(self._param('backend')), **self._device_mapping()}
        for entry in registry.BACKENDS.values():
            cfg[entry.name] = {o.key: self._param(f'{entry.name}.{o.key}')
                               for o in entry.options}
        return cfg

    def _build(self) -> None:
        """Build the back-end, the device configuration and the generator specs."""
        mode = str(self._param('excitation_mode'))
        if mode not in EXCITATION_MODES:
            raise ConfigError('excitation_mode', f'must be one of {list(EXCITATION_MODES)}, '
                                                 f'got {mode!r}')
        for key, low, high in (('watchdog_timeout_s', 0.0, 3600.0),
                               ('command_timeout_s', 0.0, 60.0),
                               ('excitation_lead_s', -1e-12, 10.0)):
            value = float(self._param(key))
            if not low < value <= high:
                raise ConfigError(key, f'must be in ({low}, {high}], got {value}')
        balance = str(self._param('balance_file'))
        self._balance = load_balance(balance or None)
        backend, config = registry.backend_from_mapping(self._backend_mapping(),
                                                        balance=self._balance)
        self._pan = declared_pan_load(float(self._param('pan.load_mass_kg')),
                                      str(self._param('pan.load_changer_coupled')))
        rate = float(self._param('state_rate_Hz'))
        if not 0.0 <= rate <= config.sample_rate_Hz:
            raise ConfigError('state_rate_Hz', f'must be in [0, {config.sample_rate_Hz}] Hz, '
                                               f'got {rate}')
        self._specs = self._generator_specs(config) if mode == 'function_generator' else \
            [GeneratorSpec()] * len(config.outputs)
        noise = self._param('input_noise_rms')
        noise = [0.0] * len(config.inputs) if noise is None else [float(v) for v in noise]
        if len(noise) != len(config.inputs) or not all(
                math.isfinite(v) and v >= 0.0 for v in noise):
            raise ConfigError('input_noise_rms', f'need {len(config.inputs)} values >= 0 (one '
                                                 f'per input), got {noise}')
        self._resolution = {c.name: {'step': abs(float(c.scale)), 'noise_rms': v}
                            for c, v in zip(config.inputs, noise)}
        if backend.recorded_resolution is not None:
            # the recorded values are not codes: what the recording said, or nothing
            self._resolution = backend.recorded_resolution
        self._backend = backend
        self._config = config
        self._mode = mode
        self._rate = config.sample_rate_Hz
        self._safe = config.safe_values_V
        self._lo = np.array([c.min_V for c in config.outputs])[:, None]
        self._hi = np.array([c.max_V for c in config.outputs])[:, None]
        self._row = {n: i for i, n in enumerate(config.input_names)}
        units = [c.unit for c in config.inputs]
        for group, wanted in GROUP_UNITS.items():
            rows = [i for i, (n, u) in enumerate(zip(config.input_names, units))
                    if u in wanted or n in GROUP_EXTRA.get(group, ())]
            if rows:
                self._groups[group] = rows

    def _generator_specs(self, config: DeviceConfig,
                         overrides: Optional[Dict[str, Any]] = None) -> List[GeneratorSpec]:
        specs = []
        for out in config.outputs:
            key = funcgen_key(out.name)
            fields = {}
            for field, (default, _) in FUNCGEN_FIELDS.items():
                name = f'funcgen.{key}.{field}'
                if overrides and name in overrides:
                    value = overrides[name]
                elif self.has_parameter(name):
                    value = self._param(name)
                else:
                    value = default
                if isinstance(default, float) and isinstance(value, int) and \
                        not isinstance(value, bool):
                    value = float(value)
                fields[field] = value
            try:
                spec = GeneratorSpec(**fields)
                make_signal(spec, config.sample_rate_Hz)
                check_generator_range([spec], DeviceConfig(
                    config.sample_rate_Hz, config.block_size, config.inputs, (out,),
                    config.watchdog_timeout_s))
            except (DeviceConfigError, TypeError) as exc:
                raise ConfigError(f'funcgen.{key}', str(exc)) from None
            specs.append(spec)
        return specs

    def _on_set_parameters(self, params: List[Parameter]) -> SetParametersResult:
        funcgen: Dict[str, Any] = {}
        for p in params:
            if p.name.startswith('funcgen.'):
                funcgen[p.name] = p.value
                continue
            if p.name not in RUNTIME:
                if p.name in PARAMETERS:
                    return SetParametersResult(
                        successful=False, reason=f'{p.name} is fixed at start-up; restart the '
                                                 'node with the new value')
                continue
            if p.type_ not in (Parameter.Type.DOUBLE, Parameter.Type.INTEGER):
                return SetParametersResult(successful=False,
                                           reason=f'{p.name} must be a number, got {p.value!r}')
            value = float(p.value)
            rate = self._rate if self._config is not None else 1e7
            limits = {'watchdog_timeout_s': (0.0, 3600.0, False),
                      'command_timeout_s': (0.0, 60.0, False),
                      'state_rate_Hz': (0.0, rate, True),
                      'excitation_lead_s': (0.0, 10.0, True)}[p.name]
            low, high, closed = limits
            if not (low <= value if closed else low < value) or not value <= high or \
                    not math.isfinite(value):
                bracket = '[' if closed else '('
                return SetParametersResult(
                    successful=False, reason=f'{p.name} must be in {bracket}{low}, {high}], '
                                             f'got {p.value!r}')
        if funcgen and self._config is not None:
            try:
                specs = self._generator_specs(self._config, funcgen)
            except ConfigError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
            if self._mode == 'function_generator':
                self._specs = specs
                if self._state == 'running' and not (self._estop or self._tripped):
                    # Checked like the device checks it; sent by the worker thread (a
                    # refusal then is a generator_unconfirmed fault).
                    self._jobs.submit('set_generator', self._set_generator)
        for p in params:
            if p.name in RUNTIME:
                self._runtime[p.name] = float(p.value)
        return SetParametersResult(successful=True)

    # -- life cycle --------------------------------------------------------------------------

    def _reset_stream_state(self) -> None:
        self._epoch: Optional[int] = None
        self._expected: Optional[int] = None
        self._last_end: Optional[int] = None
        self._last_arrival = 0.0
        self._t_start = time.monotonic()
        self._anchor_ns = time.monotonic_ns()
        self._start_time_ns = 0
        self._write_index: Optional[int] = None
        self._offset: Optional[int] = None
        #: The device's clock restarted under a running excitation stream (a remap follows).
        self._device_restarted = False
        self._exc_tracker = SequenceTracker()
        self._jump_guard = JumpGuard()
        self._exc_received_end = 0
        self._queue = ExcitationQueue(self._safe if self._config is not None else [0.0])
        self._acked = -1
        self._last_excitation = None
        # device index after the last excitation sample written to the device (its setpoints
        # play out until then: the excitation watchdog counts from there too)
        self._exc_written_end: Optional[int] = None

    def _start(self) -> Tuple[bool, str]:
        with self._start_lock:          # a retry in its thread and a ~/start call
            return self._start_locked()

    def _start_locked(self) -> Tuple[bool, str]:
        if self._backend is None:
            return False, self._error or 'no back-end'
        if self._state == 'running':
            return True, 'already running'
        try:
            self._backend.configure(self._config)
            specs = self._safe_specs() if self._estop else self._specs
            if self._estop or self._mode == 'function_generator':
                self._backend.set_function_generator(specs)
            # The START request waits for the device: not with the lock the executor's
            # callbacks take (no block of the new epoch is read before the state is reset).
            epoch = self._backend.start()
            with self._lock:
                self._reset_stream_state()
                self._tripped = False
                self._t_start = time.monotonic()
                self._anchor_ns = time.monotonic_ns()
                self._start_time_ns = self.get_clock().now().nanoseconds
                self._epoch = epoch
                self._monitor.reset(self._health(), epoch)
                if self._estop:             # the e-stop is still latched: still a fault
                    self._monitor.add('emergency_stop', 0, None,
                                      'emergency stop latched: outputs at their safe values')
        except (DeviceError, DeviceConfigError) as exc:
            # The device answered no (or the configuration cannot work): trying again in
            # 5 s gives the same answer, so autostart stops and says so.
            self._start_refused = isinstance(exc, DeviceConfigError) or (
                isinstance(exc, DeviceRefusedError)
                and exc.status in (protocol.BAD_REQUEST, protocol.UNSUPPORTED))
            self._last_error = f'start failed: {exc}'
            with self._lock:
                self._counts['excitation_not_running'] += len(self._early)
                self._early = []
                self._set_state('error')
            return False, self._last_error
        self._error = ''
        self._reader_stop.clear()
        with self._lock:        # the excitation kept during the start first, in order
            self._set_state('running')
            early, self._early = self._early, []
            for block, samples, clipped in early:
                self._take_excitation(block, samples, clipped)
        self._publish_descriptions()
        if not self._backend.host_paced:        # host-paced: the timer reads
            self._reader = threading.Thread(target=self._read_loop, daemon=True,
                                            name='daq-bridge-reader')
            self._reader.start()
        return True, f'started: epoch {epoch}'

    def _stop(self) -> Tuple[bool, str]:
        """Stop the acquisition (the worker thread, or destroy_node): waits for the device."""
        if self._state not in ('running', 'stopping', 'done'):
            return True, 'not running'
        self._reader_stop.set()
        if self._reader is not None:
            self._reader.join(5.0)
            self._reader = None
        try:
            self._backend.stop()
        except DeviceError as exc:
            self._last_error = f'stop: {exc}'
            self._set_state('stopped')
            return False, self._last_error
        self._set_state('stopped')
        return True, 'stopped: outputs at their safe values'

    def _request_stop(self) -> str:
        """Queue a stop in the worker thread; say what happens."""
        if self._state not in ('running', 'starting', 'stopping', 'done'):
            return 'not running'
        if self._state == 'running':
            self._set_state('stopping')
        self._jobs.submit('stop', self._stop)
        return ('stop requested: stopping the device in the background (its outputs go to '
                'their safe values); ~/status says when it has (state stopped)')

    def destroy_node(self) -> None:
        """Stop the acquisition and release the back-end, then destroy the node."""
        try:
            self._cancel_retry()
            if not self._jobs.close(timeout_s=10.0):
                self.get_logger().warning('a device request still runs at shutdown')
            self._stop()
        finally:
            if self._backend is not None:
                try:
                    self._backend.close()
                except (DeviceError, OSError):
                    pass
            super().destroy_node()

    # -- measurement path --------------------------------------------------------------------

    def _read_loop(self) -> None:
        backend = self._backend
        while not self._reader_stop.is_set():
            try:
                block = backend.read_block(timeout_s=0.05)
            except Exception as exc:       # noqa: B902 a back-end failure must not kill us
                self._counts['reader_errors'] += 1
                self._last_error = f'read_block: {exc}'
                self._reader_stop.wait(0.1)
                continue
            if block is None:
                if backend.finished:
                    self._replay_done(backend)
                    return
                continue
            try:
                self._handle_block(block, time.monotonic_ns())
            except Exception as exc:       # noqa: B902 e.g. publishing during shutdown
                if not self.context.ok():
                    return
                self._counts['reader_errors'] += 1
                self._last_error = f'publishing a block: {exc}'

    def _replay_done(self, backend: DeviceBackend) -> None:
        """A finite source (a replay) published its last block: state done, said once."""
        with self._lock:
            if self._state != 'running':
                return
            self._set_state('done')
        self.get_logger().info(f'{backend.name} done: every block published (~/start '
                               'starts again in a new epoch)')

    def _sim_tick(self) -> None:
        if self._state != 'running':
            return
        block = self._config.block_size
        due = int((time.monotonic() - self._t_start) * self._rate)
        for _ in range(64):
            end = self._last_end or 0
            if end + block > due:
                return
            got = self._backend.read_block(0.0)
            if got is None:
                return
            self._handle_block(got, time.monotonic_ns())

    def _handle_block(self, block: Block, arrival_ns: int) -> None:
        cfg = self._config
        if block.samples.ndim != 2 or block.samples.shape[0] != len(cfg.inputs) or \
                block.n_samples < 1:
            self._counts['malformed_blocks'] += 1
            self._last_error = f'device block of shape {block.samples.shape} dropped'
            return
        with self._lock:
            if block.epoch != self._epoch:
                self._epoch = block.epoch
                self._expected = None
                self._last_end = None
                self._write_index = None
                self._exc_written_end = None
                self._offset = None            # the device index restarted: remap
                self._device_restarted = self._exc_received_end > 0
                self._queue = ExcitationQueue(self._safe)
                self._anchor_ns = arrival_ns - int(block.end_index * 1e9 / self._rate)
                self._counts['epoch_changes'] += 1
                new_epoch = True
            else:
                new_epoch = False
                # The device clock's start is known no earlier than the earliest arrival says:
                # a first block that arrived late (a stall) must not leave the estimate of the
                # device index behind for the run (setpoints written late by that much).
                self._anchor_ns = earliest_start_ns(self._anchor_ns, arrival_ns,
                                                    block.end_index, self._rate)
            if self._expected is not None:
                if block.first_sample_index < self._expected:
                    self._counts['dropped_out_of_order_blocks'] += 1
                    return
                if block.first_sample_index > self._expected:
                    self._counts['published_gaps'] += 1
                    self._counts['published_missing_samples'] += \
                        block.first_sample_index - self._expected
            self._expected = block.end_index
            self._last_end = block.end_index
            self._last_arrival = arrival_ns * 1e-9
        if new_epoch:
            self._publish_descriptions()
        samples = block.samples
        for topic, pub in self._pub.items():
            rows = samples if topic == 'measurements' else samples[self._groups[topic[13:]]]
            builder = self._builders.setdefault(topic, BlockMessageBuilder())
            pub.publish(builder.build(block.first_sample_index, self._rate, block.epoch, rows))
        done = time.monotonic_ns()
        self._latency_ns.append(done - arrival_ns)
        self._age_ns.append(done - self._anchor_ns - int(block.end_index * 1e9 / self._rate))
        self._counts['published_blocks'] += 1
        self._counts['published_samples'] += block.n_samples
        self._write_setpoints(block.end_index)
        self._acknowledge(block.end_index)
        self._publish_states(block)

    # -- setpoint path -----------------------------------------------------------------------

    def _lead_samples(self) -> int:
        lead = int(math.ceil(self._runtime['excitation_lead_s'] * self._rate))
        return max(lead, 1)

    def _device_index_now(self) -> int:
        """The device's sample index now, from the epoch's START-anchored monotonic clock."""
        return device_index_at(time.monotonic_ns(), self._anchor_ns, self._rate)

    def _command_V(self) -> float:
        if self._command_N == 0.0:
            return 0.0
        if time.monotonic() - self._command_time > self._runtime['command_timeout_s']:
            self._command_N = 0.0
            self._counts['command_watchdog_trips'] += 1
            return 0.0
        return coil_setpoint_for_force_V(self._balance, self._command_N, self._last_position_m)

    def _write_setpoints(self, device_end: int) -> None:
        """Write setpoints for the device samples up to ``device_end + lead``."""
        with self._lock:
            command = self._command_V()
            halted = self._estop or self._tripped
            if self._offset is None and command == 0.0 and not halted:
                return                          # nothing to stream: the device holds safe
            target = device_end + self._lead_samples()
            w = self._write_index if self._write_index is not None else device_end
            if w < device_end:
                self._counts['setpoint_late_samples'] += device_end - w
                w = device_end
            n = target - w
            if n <= 0:
                return
            out = np.repeat(self._safe[:, None], n, axis=1)
            q = self._queue
            if self._offset is not None and not halted:
                if q.queued and q.head_index < w:
                    late = min(w - q.head_index, q.queued)
                    self._late_fault(q.head_index, late)
                    q.pop(late)
                    self._counts['excitation_late_samples'] += late
                lead = max(0, q.head_index - w)
                if lead < n:
                    samples, real = q.pop(n - lead)
                    out[:, lead:] = samples
                    if real:
                        self._exc_written_end = w + lead + real
            if command and not halted:
                out[0] += command
                clipped = int(np.count_nonzero((out < self._lo) | (out > self._hi)))
                if clipped:
                    self._counts['clamped_samples'] += clipped
                    np.clip(out, self._lo, self._hi, out=out)
            self._write_index = target
        try:
            self._backend.write_setpoints(w, out)
            self._counts['setpoint_samples_written'] += n
        except (DeviceError, DeviceConfigError) as exc:
            self._counts['setpoint_write_errors'] += 1
            self._last_error = f'write_setpoints: {exc}'

    def _late_fault(self, device_index: int, samples: int) -> None:
        """Excitation that came after its device samples were written: a fault (lock held)."""
        if self._monitor.has('excitation_late') or \
                any(f[0] == 'excitation_late' for f in self._worker_faults):
            return
        lead_s = self._runtime['excitation_lead_s']
        self._worker_faults.append((
            'excitation_late', int(device_index),
            f'{samples} excitation samples arrived after their device samples had been '
            f'written (from device sample {device_index}): the generator, or the link to it, '
            f'was more than excitation_lead_s ({lead_s:g} s) behind the device, or a '
            "consumer-paced generator's window is shorter than that lead; the outputs were at "
            'their safe values there', True))

    def _acknowledge(self, device_end: int) -> None:
        with self._lock:
            if self._offset is None:
                return
            consumed = min(device_end - self._offset, self._exc_received_end)
        if consumed > self._acked and consumed >= 0:
            self._acked = consumed
            self._pub_ack.publish(UInt64(data=int(consumed)))

    def _on_excitation(self, msg: Float64MultiArray) -> None:
        if self._config is None:
            self._reject(self._error or 'not configured')
            return
        try:
            block = msg_to_block(msg, expected_channels=len(self._config.outputs))
            if abs(block.sample_rate_Hz - self._rate) > 1e-9 * self._rate:
                raise BlockError(f'excitation at {block.sample_rate_Hz} Hz, the device runs '
                                 f'at {self._rate} Hz')
            if block.n_samples == 0:
                raise BlockError('excitation block has no samples')
            if not np.all(np.isfinite(block.samples)):
                raise BlockError('excitation block holds NaN or infinite values')
        except BlockError as exc:
            self._reject(str(exc))
            return
        samples = np.array(block.samples, dtype=np.float64)
        clipped = int(np.count_nonzero((samples < self._lo) | (samples > self._hi)))
        if clipped:
            np.clip(samples, self._lo, self._hi, out=samples)
        with self._lock:
            if self._state != 'running':
                self._hold_excitation(block, samples, clipped)
                return
        self._take_excitation(block, samples, clipped)

    def _hold_excitation(self, block: Block, samples: np.ndarray, clipped: int) -> None:
        """Excitation before the device runs: kept for the start, or dropped and counted."""
        held = sum(b.n_samples for b, _, _ in self._early)
        if self._state == 'starting' and held + block.n_samples <= EARLY_EXCITATION_MAX_SAMPLES:
            self._early.append((block, samples, clipped))
            return
        self._counts['excitation_not_running'] += 1
        self._last_error = (f'excitation block at sample {block.first_sample_index} dropped: the '
                            f'device is not running (state {self._state})')
        self.get_logger().warning(self._last_error, throttle_duration_sec=5.0)

    def _take_excitation(self, block: Block, samples: np.ndarray, clipped: int) -> None:
        """Queue an excitation block for the device (the device runs)."""
        remap = False
        with self._lock:
            try:
                self._jump_guard.check(self._exc_tracker, block)
            except BlockError as exc:
                self._reject(str(exc))
                return
            kind = self._exc_tracker.observe(block.first_sample_index, block.n_samples,
                                             block.epoch)
            if kind in DROPPED:
                # Counted by the tracker. A block we already have: its sender did not hear
                # our acknowledgement, so say again how far we are.
                acked = self._acked
                if acked > 0 and self._offset is not None:
                    self._pub_ack.publish(UInt64(data=int(acked)))
                return
            self._counts['excitation_blocks'] += 1
            self._counts['clamped_samples'] += clipped
            self._last_excitation = time.monotonic()
            if self._tripped:
                self._tripped = False
                self._jobs.submit('restore_generator', self._restore_generator)
                if kind not in (Continuity.FIRST, Continuity.RESTART):
                    # The same stream goes on after a gap the outputs spent at their safe
                    # values: the samples between were not applied.
                    self._latch([self._monitor.add(
                        'excitation_watchdog', self._counts.get('watchdog_trip_device_index'),
                        None, 'the excitation stopped for longer than watchdog_timeout_s '
                        'and then went on: the outputs were at their safe values in between '
                        'and the rest is applied with a new offset')])
            if self._estop:
                self._counts['excitation_dropped_estop'] += 1
                return                          # latched: nothing is queued until ~/reset
            if kind in (Continuity.FIRST, Continuity.RESTART) or self._offset is None:
                start = self._device_index_now() + self._lead_samples()
                if self._write_index is not None:
                    start = max(start, self._write_index)
                self._offset = start - block.first_sample_index
                restarted, self._device_restarted = self._device_restarted, False
                if block.first_sample_index > 0 and \
                        (kind in (Continuity.FIRST, Continuity.RESTART) or restarted):
                    # The device applies this epoch's excitation from here on: what came
                    # before it was not applied (or in an earlier device epoch). A remap
                    # after safe outputs (watchdog, e-stop) is that fault's, not this one.
                    # Recorded at the device index sample 0 would have had, spanning the
                    # samples never applied: experiment samples 0 to first - 1.
                    self._latch([self._monitor.add(
                        'excitation_start_missing', self._offset, block.first_sample_index,
                        f'the excitation is applied from its sample '
                        f'{block.first_sample_index} on (device sample {start}): its samples '
                        f'0 to {block.first_sample_index - 1} never reached the device in this '
                        'device epoch, so the recorded excitation before them was not applied',
                        True)])
                self._queue = ExcitationQueue(self._safe)
                self._acked = -1
                remap = True
            self._exc_received_end = block.end_index
            self._queue.push(Block(block.first_sample_index + self._offset, self._rate, 0,
                                   samples))
        if remap:
            self._publish_descriptions()

    def _reject(self, reason: str) -> None:
        self._counts['excitation_malformed'] += 1
        self._last_error = reason
        self.get_logger().warning(f'excitation block dropped: {reason}',
                                  throttle_duration_sec=5.0)

    # -- safety --------------------------------------------------------------------------------

    def _safe_specs(self) -> List[GeneratorSpec]:
        return [GeneratorSpec('constant', offset_V=float(v)) for v in self._safe]

    def _restore_generator(self) -> None:
        """The generator back to its configuration (worker thread)."""
        if self._state != 'running':
            return
        try:
            self._backend.set_function_generator(self._specs)
        except (DeviceError, DeviceConfigError) as exc:
            self._worker_fault('generator_unconfirmed', f'the device did not confirm the '
                               f'function generator restored after a safe-output hold ({exc}): '
                               'its outputs may still be at their safe values')

    def _set_generator(self) -> None:
        """A run-time change of the generator (worker thread): the latest specs."""
        if self._state != 'running' or self._estop or self._tripped:
            return
        try:
            self._backend.set_function_generator(self._specs)
        except (DeviceError, DeviceConfigError) as exc:
            self._worker_fault('generator_unconfirmed', f'the device did not confirm the '
                               f'changed function generator ({exc}): it may still output the '
                               'previous one')

    def _worker_fault(self, kind: str, message: str) -> None:
        """A fault the worker saw: latched by the executor's next watchdog tick."""
        self._last_error = message
        with self._lock:
            self._worker_faults.append((kind, self._device_index_now(), message, False))

    def _drive_safe(self, why: str) -> str:
        """
        Outputs to their safe values now: safe setpoints at once, the device's generator.

        The generator request (with its retries, seconds when the device is gone) runs in the
        worker thread, so the executor never waits for the device; a refusal is latched as a
        ``safe_outputs_unconfirmed`` fault and stops the device (STOP also drives the
        outputs safe), in the worker too.
        """
        with self._lock:
            self._queue = ExcitationQueue(self._safe)
            self._offset = None
            self._command_N = 0.0
        index = self._device_index_now()
        self._counts[f'{why}_device_index'] = index
        self._jobs.submit('safe_outputs', self._confirm_safe, why)
        return f'outputs to {self._safe.tolist()} V from about device sample {index}'

    def _confirm_safe(self, why: str) -> None:
        if self._state != 'running':
            return                          # stopped meanwhile: STOP drove them safe
        try:
            self._backend.set_function_generator(self._safe_specs())
        except (DeviceError, DeviceConfigError) as exc:
            self._safe_failed = f'{why}: the device did not confirm the safe outputs ({exc})'
            return
        self._counts['safe_outputs_confirmed'] += 1

    def _health(self) -> Dict[str, Any]:
        try:
            return self._backend.health() if self._backend is not None else {}
        except (DeviceError, OSError):
            return {}

    def _latch(self, faults: Sequence[Fault]) -> None:
        """Report newly latched faults: log, description, diagnostics."""
        if not faults:
            return
        self._counts['faults'] += len(faults)
        for line in describe(faults).splitlines():
            self.get_logger().error(f'fault: {line}')
        self._publish_descriptions()
        self._publish_diagnostics()
        self._publish_status()

    def published_counts(self) -> Dict[str, Dict[str, int]]:
        """
        Messages published per stream (for an in-process supervisor's accounting).

        Returns
        -------
        dict
            Relative topic name to ``published`` [count] (joint states in wall time are never
            decimated).
        """
        counts = {topic: {'published': int(self._counts['published_blocks'])}
                  for topic in self._pub}
        counts['joint_states'] = {'published': int(self._counts['published_states'])}
        return counts

    def faults(self) -> Tuple[Fault, ...]:
        """
        The latched faults of this run (for in-process supervisors).

        Returns
        -------
        tuple of Fault
            Oldest first; empty when the run is clean.
        """
        return self._monitor.faults

    def _watchdog_tick(self) -> None:
        if self._state != 'running':
            return
        with self._lock:
            found, self._worker_faults = self._worker_faults, []
        if found:
            self._latch([self._monitor.add(kind, index, None, message, exact)
                         for kind, index, message, exact in found])
        if self._safe_failed:
            message, self._safe_failed = self._safe_failed, ''
            self._last_error = message
            self._latch([self._monitor.add('safe_outputs_unconfirmed',
                                           self._device_index_now(), None, message)])
            self._request_stop()            # STOP drives the outputs safe (worker thread)
            return
        new = self._monitor.observe(self._health(), self._device_index_now(),
                                    self._last_end or 0,
                                    float(self._backend.silence_timeout_s))
        self._latch(new)
        if self._tripped or self._estop:
            return
        last = self._last_excitation
        if last is None or not any(not s.active for s in self._specs):
            return
        # From the last excitation block's arrival; once everything that arrived has been
        # written to the device, from when the device has played it, if that is later: a
        # short stream written whole well ahead is not cut before its end (it was, without a
        # fault, when lead plus stream reached the timeout). Excitation still queued in the
        # bridge is cut at the trip, a fault (below).
        with self._lock:
            drained = self._queue.queued == 0
        written = self._exc_written_end
        if drained and written is not None and self._anchor_ns is not None:
            last = max(last, (self._anchor_ns + written * 1e9 / self._rate) * 1e-9)
        if time.monotonic() - last > self._runtime['watchdog_timeout_s']:
            self._tripped = True
            self._counts['watchdog_trips'] += 1
            with self._lock:
                pending = self._queue.queued
                head = self._queue.head_index
            message = self._drive_safe('watchdog_trip')
            self.get_logger().warning(f'excitation watchdog tripped: {message}')
            if pending:
                self._latch([self._monitor.add(
                    'excitation_watchdog', head, pending,
                    f'the excitation watchdog tripped with {pending} excitation samples '
                    'still queued: they were not applied')])

    def _srv_estop(self, request: Trigger.Request, response: Trigger.Response):
        if self._backend is None:
            response.success, response.message = False, self._error
            return response
        self._estop = True
        self._counts['emergency_stops'] += 1
        response.message = 'emergency stop latched until ~/reset: ' + \
            self._drive_safe('emergency_stop')
        response.success = True
        self.get_logger().warning(response.message)
        if self._state == 'running':
            self._latch([self._monitor.add('emergency_stop',
                                           self._counts['emergency_stop_device_index'], None,
                                           'emergency stop: outputs at their safe values')])
        return response

    def _srv_reset(self, request: Trigger.Request, response: Trigger.Response):
        faults = self._monitor.faults
        if faults:
            # Acknowledged: the next data are clean again (the bag keeps the record).
            self._monitor.reset(self._health(), self._epoch or 0)
            self._publish_descriptions()
            self.get_logger().info(f'{len(faults)} fault(s) acknowledged by ~/reset')
        if not self._estop and not self._tripped:
            response.success = True
            response.message = f'{len(faults)} fault(s) acknowledged' if faults else \
                'nothing to reset'
            return response
        self._estop = False
        self._tripped = False
        self._last_excitation = None
        if self._state == 'running':
            self._jobs.submit('restore_generator', self._restore_generator)
        response.success = True
        response.message = ('emergency stop released: outputs follow the excitation again '
                            '(the generator is restored in the background)')
        return response

    def _srv_start(self, request: Trigger.Request, response: Trigger.Response):
        # Answers at once: the device's answer (or its silence, seconds of retries) is
        # waited for in the worker thread; ~/status says how the start ended.
        if self._backend is None:
            response.success, response.message = False, self._error or 'no back-end'
            return response
        self._end_hold()                    # an explicit start does not wait for listeners
        response.success, response.message = True, self._request_start('~/start')
        return response

    def _srv_stop(self, request: Trigger.Request, response: Trigger.Response):
        self._cancel_retry()
        response.success, response.message = True, self._request_stop()
        return response

    # -- controller interface ------------------------------------------------------------------

    def _on_joint_command(self, msg: JointState) -> None:
        if JOINT in msg.name and len(msg.effort) == len(msg.name):
            self._set_command(float(msg.effort[msg.name.index(JOINT)]))
        else:
            self._counts['command_malformed'] += 1
            self._last_error = f'joint_commands needs an effort for joint {JOINT!r}'

    def _on_array_command(self, msg: Float64MultiArray) -> None:
        if len(msg.data) == 1:
            self._set_command(float(msg.data[0]))
        else:
            self._counts['command_malformed'] += 1
            self._last_error = f'commands needs exactly 1 value (effort [N]), got {len(msg.data)}'

    def _set_command(self, effort_N: float) -> None:
        if not math.isfinite(effort_N):
            self._counts['command_malformed'] += 1
            self._last_error = f'effort command {effort_N!r} is not finite'
            return
        with self._lock:
            self._command_N = effort_N
            self._command_time = time.monotonic()

    def _publish_states(self, block: Block) -> None:
        rate = self._runtime['state_rate_Hz']
        if rate <= 0.0:
            return
        step = max(1, int(round(self._rate / rate)))
        s = block.samples
        n = block.n_samples
        if 'position_m' in self._row:
            position = s[self._row['position_m']]
        elif 'sensor_V' in self._row:
            position = np.asarray(self._balance.sensor.position_m(s[self._row['sensor_V']]))
        else:
            position = np.full(n, np.nan)
        self._last_position_m = float(position[-1]) if np.isfinite(position[-1]) else 0.0
        velocity = np.gradient(position) * self._rate if n > 1 else np.zeros(n)
        if 'coil_force_N' in self._row:
            effort = s[self._row['coil_force_N']]
        elif 'coil_current_A' in self._row:
            effort = np.asarray(self._balance.motor.force_N(s[self._row['coil_current_A']],
                                                            position))
        else:
            effort = np.full(n, np.nan)
        # first index of the block is a multiple of nothing in particular: keep the grid
        start = (-block.first_sample_index) % step
        for i in range(start, n, step):
            ns = self._start_time_ns + int(round((block.first_sample_index + i) * 1e9
                                                 / self._rate))
            msg = JointState()
            msg.header.stamp = Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)
            msg.name = [JOINT]
            msg.position = [float(position[i])]
            msg.velocity = [float(velocity[i])]
            msg.effort = [float(effort[i])]
            self._pub_state.publish(msg)
            self._counts['published_states'] += 1

    # -- descriptions and diagnostics ----------------------------------------------------------

    def _make_publishers(self) -> None:
        qos = BLOCK_QOS
        depth = self._param('publisher_depth')
        if isinstance(depth, int) and not isinstance(depth, bool) and 1 <= depth <= 100000:
            qos = QoSProfile(history=BLOCK_QOS.history, depth=depth,
                             reliability=BLOCK_QOS.reliability,
                             durability=BLOCK_QOS.durability)
        elif not self._error:
            self._error = f'configuration refused: publisher_depth must be an integer from 1 ' \
                          f'to 100000, got {depth!r}'
            self._state = 'error'
        self._pub['measurements'] = self.create_publisher(Float64MultiArray, 'measurements',
                                                          qos)
        self._pub_desc['measurements'] = self.create_publisher(
            String, 'measurements/description', LATCHED_QOS)
        if self._param('publish_groups') and self._config is not None:
            for group in self._groups:
                topic = f'measurements/{group}'
                self._pub[topic] = self.create_publisher(Float64MultiArray, topic, qos)
                self._pub_desc[topic] = self.create_publisher(String, f'{topic}/description',
                                                              LATCHED_QOS)

    def _publish_descriptions(self) -> None:
        if self._config is None:
            return
        cfg = self._config
        channels = tuple(Channel(c.name, c.unit, f'device input {i}: code * {c.scale:g} + '
                                                 f'{c.offset:g} {c.unit}')
                         for i, c in enumerate(cfg.inputs))
        extra = {'backend': self._backend.name, 'excitation_mode': self._mode,
                 'start_monotonic_ns': int(self._anchor_ns),
                 'excitation_epoch': self._exc_tracker.epoch,
                 'excitation_offset_samples': self._offset,
                 'outputs': [{'name': c.name, 'min_V': c.min_V, 'max_V': c.max_V,
                              'safe_V': c.safe_V} for c in cfg.outputs],
                 'faults': [f.to_dict() for f in self._monitor.faults],
                 'resolution': self._resolution}
        extra.update(self._pan)
        extra.update(self._backend.description_extra())
        epoch = self._epoch or 0
        for topic, pub in self._pub_desc.items():
            rows = range(len(channels)) if topic == 'measurements' else \
                self._groups[topic[13:]]
            pub.publish(description_to_msg(StreamDescription(
                topic.rsplit('/', 1)[-1], self._rate, cfg.block_size,
                tuple(channels[i] for i in rows), epoch=epoch,
                start_time_ns=self._start_time_ns, source=self.get_fully_qualified_name(),
                extra=extra)))

    def diagnostic_values(self) -> Dict[str, Any]:
        """
        Everything /diagnostics reports, as one mapping.

        Returns
        -------
        dict
            Counter and state names (units in the names) to values.
        """
        values: Dict[str, Any] = {'state': self._state,
                                  'backend': str(self._param('backend')),
                                  'excitation_mode': str(self._param('excitation_mode'))}
        if self._backend is not None:
            try:
                values.update(self._backend.health())
            except (DeviceError, OSError) as exc:
                values['health_error'] = str(exc)
        tracker = self._exc_tracker.counters()
        values.update({f'excitation_{k}': v for k, v in tracker.items() if k != 'blocks'})
        q = self._queue.counters()
        values.update({'excitation_underrun_samples': q['underrun_samples'],
                       'excitation_gap_filled_samples': q['gap_filled_samples'],
                       'excitation_queued_samples': q['queued_samples']})
        for key in ('excitation_blocks', 'excitation_malformed', 'excitation_late_samples',
                    'clamped_samples', 'watchdog_trips', 'emergency_stops',
                    'command_watchdog_trips', 'command_malformed', 'published_blocks',
                    'published_samples', 'published_gaps', 'published_missing_samples',
                    'dropped_out_of_order_blocks', 'malformed_blocks', 'reader_errors',
                    'setpoint_samples_written', 'setpoint_late_samples',
                    'setpoint_write_errors', 'epoch_changes', 'excitation_dropped_estop',
                    'excitation_not_running'):
            values[key] = self._counts.get(key, 0)
        for key in ('watchdog_trip_device_index', 'emergency_stop_device_index'):
            if key in self._counts:
                values[key] = self._counts[key]
        lat = list(self._latency_ns)
        age = list(self._age_ns)
        med, p99 = _percentiles_us(lat)
        age_med, age_p99 = _percentiles_us(age)
        values['faults'] = describe(self._monitor.faults) or 'none'
        values.update({'watchdog_tripped': int(self._tripped),
                       'emergency_stop': int(self._estop),
                       'sample_rate_Hz': self._rate if self._config is not None else 0.0,
                       'stream_epoch': self._epoch if self._epoch is not None else -1,
                       'device_next_index': self._last_end or 0,
                       'excitation_offset_samples': self._offset
                       if self._offset is not None else '',
                       'command_N': self._command_N,
                       'latency_blocks': len(lat),
                       'arrival_to_publish_median_us': f'{med:.1f}',
                       'arrival_to_publish_p99_us': f'{p99:.1f}',
                       'sample_age_at_publish_median_us': f'{age_med:.1f}',
                       'sample_age_at_publish_p99_us': f'{age_p99:.1f}',
                       'last_error': self._last_error, 'error': self._error})
        return values

    def _publish_diagnostics(self) -> None:
        values = self.diagnostic_values()
        defects = sum(int(values.get(k, 0) or 0) for k in (
            'gaps', 'duplicates', 'reordered', 'corrupt', 'late', 'heartbeat_misses',
            'reconnects', 'excitation_gaps', 'excitation_duplicates',
            'excitation_reordered', 'excitation_overlaps', 'excitation_malformed',
            'published_gaps', 'malformed_blocks'))
        names = self._backend.intrusion_counters if self._backend is not None else ()
        intrusions = {k: int(values.get(k, 0) or 0) for k in names}
        level = DiagnosticStatus.OK
        message = 'ok'
        if defects or values['clamped_samples']:
            level, message = DiagnosticStatus.WARN, 'stream defects or clamped setpoints'
        if any(intrusions.values()):
            level = DiagnosticStatus.WARN
            message = 'datagrams refused (not from the device, our session or our key): ' + \
                ', '.join(f'{k} {v}' for k, v in intrusions.items() if v)
        if self._tripped:
            level, message = DiagnosticStatus.WARN, 'excitation watchdog tripped: outputs safe'
        if self._estop:
            level, message = DiagnosticStatus.ERROR, 'emergency stop latched: outputs safe'
        faults = self._monitor.faults
        if faults:
            level = DiagnosticStatus.ERROR
            message = f'{len(faults)} fault(s) latched until ~/reset or ~/start: ' + \
                describe(faults[:1])
        if self._error or self._state == 'error':
            level, message = DiagnosticStatus.ERROR, self._error or self._last_error
        self._pub_diag.publish(node_diagnostics(self, 'device', level, message, values))


main = node_main(DaqBridgeNode, 'daq_bridge')


if __name__ == '__main__':
    raise SystemExit(main())
