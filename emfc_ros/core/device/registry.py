"""
The back-end registry: device back-ends by name, each with its typed options.

This is the only way a back-end is configured. The bridge node's parameters ``backend`` and
``<backend>.<option>`` (for example ``udp.device_host``), a run plan's bridge parameters and
a parsed YAML mapping all arrive here as one mapping (:func:`backend_from_mapping`):

- ``backend``: a key of :data:`BACKENDS`;
- the device configuration keys of :func:`~emfc_ros.core.device.backend.device_config_from_mapping`
  (sample rate, block size, channels, limits);
- one nested mapping per back-end, ``{name: {option: value}}``, read by the entry's
  :class:`Option` table (types, defaults, bounds); options of the other back-ends are
  ignored, so that one parameter table serves all of them;
- ``balance_file``: the balance the ``sim`` back-end simulates.

Adding a back-end is one more :class:`BackendEntry` here: the node declares its options as
parameters from :func:`parameter_table` and never branches on a back-end's name. The
back-ends themselves do not import this module.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Dict, Mapping, Optional, Tuple, Union

from emfc_ros.core.config import (get_bool, get_float, get_float_list, get_int, get_mapping,
                                  get_str, get_str_list, join, reject_unknown)
from emfc_ros.core.device import daqmx_backend
from emfc_ros.core.device.backend import (device_config_from_mapping, DEVICE_CONFIG_KEYS,
                                          DeviceBackend, DeviceConfig)
from emfc_ros.core.device.daqmx_backend import DaqmxBackend
from emfc_ros.core.device.errors import DeviceConfigError
from emfc_ros.core.device.replay_backend import ReplayBackend
from emfc_ros.core.device.sim_backend import SimBackend
from emfc_ros.core.device.udp_backend import UdpBackend
from emfc_ros.core.errors import ConfigError

#: A parameter value: what a ROS parameter or a YAML scalar (or list) holds.
Value = Union[bool, int, float, str, Tuple[str, ...], Tuple[float, ...]]


@dataclasses.dataclass(frozen=True)
class Option:
    """
    One typed option of a back-end (a node parameter ``<backend>.<key>``).

    Attributes
    ----------
    key : str
        The option's name, with its unit suffix where it has one.
    default : bool, int, float, str, or a tuple of str or of float
        The default; its type is the option's type (a tuple: a list of that type).
    description : str
        What it does, with its unit and range.
    minimum, maximum : float, optional
        Inclusive bounds of a number (``minimum`` exclusive with ``min_exclusive``).
    min_exclusive : bool
        Whether ``minimum`` itself is refused.
    choices : tuple of str
        The allowed values of a string option (empty: any).
    """

    key: str
    default: Value
    description: str
    minimum: Optional[float] = None
    maximum: Optional[float] = None
    min_exclusive: bool = False
    choices: Tuple[str, ...] = ()

    def read(self, cfg: Mapping[str, Any], path: str) -> Value:
        """
        The option's value in a mapping, checked, or its default.

        Parameters
        ----------
        cfg : Mapping
            The back-end's nested mapping.
        path : str
            Its dotted path, for messages.

        Returns
        -------
        bool, int, float or str
            The value, of the default's type.

        Raises
        ------
        ConfigError
            Naming ``<path>.<key>`` and what is allowed.
        """
        if isinstance(self.default, tuple):
            if self.default and isinstance(self.default[0], str):
                return tuple(get_str_list(cfg, self.key, path, default=list(self.default)))
            return tuple(float(v) for v in get_float_list(
                cfg, self.key, path, default=list(self.default), minimum=self.minimum,
                maximum=self.maximum))
        if isinstance(self.default, bool):
            return get_bool(cfg, self.key, path, default=self.default)
        if isinstance(self.default, int):
            return get_int(cfg, self.key, path, default=self.default,
                           minimum=None if self.minimum is None else int(self.minimum),
                           maximum=None if self.maximum is None else int(self.maximum))
        if isinstance(self.default, float):
            return get_float(cfg, self.key, path, default=self.default, minimum=self.minimum,
                             maximum=self.maximum, min_exclusive=self.min_exclusive)
        return get_str(cfg, self.key, path, default=self.default,
                       choices=self.choices or None)

    @property
    def limits(self) -> Optional[Tuple[float, float]]:
        """
        Inclusive ``(min, max)`` of a number with both bounds (a parameter descriptor's).

        Returns
        -------
        (float, float) or None
            The bounds, or None.
        """
        if isinstance(self.default, (bool, tuple)) or self.minimum is None or \
                self.maximum is None:
            return None
        if isinstance(self.default, int):
            return int(self.minimum), int(self.maximum)
        return float(self.minimum), float(self.maximum)


#: What an entry's factory gets: the back-end class, its options (key to value) and the
#: balance parameters (``balance_file``).
Factory = Callable[[type, Dict[str, Value], Any], DeviceBackend]


@dataclasses.dataclass(frozen=True)
class BackendEntry:
    """
    One back-end: its name, what it is, its options and how it is built.

    Attributes
    ----------
    name : str
        The configuration name (the ``backend`` parameter).
    cls : type
        The back-end class (it follows :class:`~emfc_ros.core.device.backend.DeviceBackend`).
    summary : str
        One line for the ``backend`` parameter's description.
    options : tuple of Option
        Its options (node parameters ``<name>.<key>``).
    factory : callable
        ``factory(cls, options, balance) -> DeviceBackend``: the options to the class's
        constructor.
    """

    name: str
    cls: type
    summary: str
    options: Tuple[Option, ...]
    factory: Factory

    def read_options(self, cfg: Mapping[str, Any], path: str) -> Dict[str, Value]:
        """
        The options in the back-end's nested mapping, checked, unknown keys refused.

        Parameters
        ----------
        cfg : Mapping
            The nested mapping (``{option: value}``).
        path : str
            Its dotted path.

        Returns
        -------
        dict
            Every option's value (defaults filled in).

        Raises
        ------
        ConfigError
            Naming the offending key.
        """
        reject_unknown(cfg, [o.key for o in self.options], path)
        return {o.key: o.read(cfg, path) for o in self.options}


def _address(host: Value, port: Value) -> Tuple[str, int]:
    return str(host), int(port)


def _make_udp(cls: type, options: Dict[str, Value], balance: Any) -> DeviceBackend:
    return cls(_address(options['device_host'], options['device_port']),
               bind_address=_address(options['bind_host'], options['bind_port']),
               heartbeat_period_s=float(options['heartbeat_period_s']),
               request_timeout_s=float(options['request_timeout_s']),
               retries=int(options['retries']),
               device_timeout_s=float(options['device_timeout_s']),
               reorder_window=int(options['reorder_window']),
               reorder_timeout_s=float(options['reorder_timeout_s']),
               setpoint_format=str(options['setpoint_format']),
               auto_reconnect=bool(options['auto_reconnect']),
               key_file=str(options['key_file']) or None)


def _make_sim(cls: type, options: Dict[str, Value], balance: Any) -> DeviceBackend:
    return cls(balance, int(options['seed']), simulator_options={
        'load_mass_kg': float(options['load_mass_kg']),
        'load_changer_coupled': bool(options['load_changer_coupled'])})


def _make_replay(cls: type, options: Dict[str, Value], balance: Any) -> DeviceBackend:
    return cls(str(options['bag']), topic=str(options['topic']), pacing=str(options['pacing']),
               speed=float(options['speed']), loop=bool(options['loop']))


def _make_daqmx(cls: type, options: Dict[str, Value], balance: Any) -> DeviceBackend:
    return cls(str(options['device']), options['ai_terminals'], options['ai_units_per_V'],
               options['ai_range_V'], str(options['ai_terminal_config']),
               options['ao_terminals'], grpc_address=str(options['grpc_address']),
               session_prefix=str(options['session_prefix']),
               read_period_s=float(options['read_period_s']),
               output_lead_s=float(options['output_lead_s']),
               input_buffer_s=float(options['input_buffer_s']),
               watchdog=str(options['watchdog']))


_PERIOD = dict(minimum=0.0, maximum=60.0, min_exclusive=True)
_DAQMX_SUMMARY = 'an NI-DAQmx device through the nidaqmx client (local driver or gRPC server)'

#: The back-ends by configuration name.
BACKENDS: Dict[str, BackendEntry] = {entry.name: entry for entry in (
    BackendEntry('sim', SimBackend, 'simulated balance in process', (
        Option('seed', 0, 'sim: noise seed, >= 0', minimum=0, maximum=2 ** 63 - 1),
        Option('load_mass_kg', 0.0, 'sim: mass on the pan [kg], 0 to 2', minimum=0.0,
               maximum=2.0),
        Option('load_changer_coupled', False, "sim: the load changer's moving mass rides on "
                                              'the pan'),
    ), _make_sim),
    BackendEntry('udp', UdpBackend, 'a device or the emulator over UDP', (
        Option('device_host', '127.0.0.1', 'IP address of the device'),
        Option('device_port', 5005, 'UDP port of the device, 1 to 65535', minimum=1,
               maximum=65535),
        Option('bind_host', '127.0.0.1', 'local IP address to bind'),
        Option('bind_port', 0, 'local UDP port, 0: any free one', minimum=0, maximum=65535),
        Option('heartbeat_period_s', 0.1, 'heartbeat period [s], (0, 60]', **_PERIOD),
        Option('request_timeout_s', 0.2, 'control request timeout before a retry [s], '
                                         '(0, 60]', **_PERIOD),
        Option('retries', 4, 'retries of a control request after the first attempt, 0 to '
                             '1000', minimum=0, maximum=1000),
        Option('device_timeout_s', 0.5, 'silence after which the device counts as lost (a '
                                        'latched fault) and is reconnected [s], (0, 60]',
               **_PERIOD),
        Option('reorder_window', 8, 'frames the reorder buffer spans before declaring a gap, '
                                    '1 to 1000', minimum=1, maximum=1000),
        Option('reorder_timeout_s', 0.2, 'longest wait for a missing frame [s], (0, 60]',
               **_PERIOD),
        Option('setpoint_format', 'float64', "setpoint frame format: 'float64' or 'int16'",
               choices=('float64', 'int16')),
        Option('auto_reconnect', True, 'reconfigure and restart a lost or rebooted device'),
        Option('key_file', '', 'pre-shared key file (hex text, at least 32 hex digits, mode '
                               '600) to authenticate every datagram with HMAC-SHA256; the '
                               'device needs the same key; empty: no authentication'),
    ), _make_udp),
    BackendEntry('replay', ReplayBackend, 'a recorded bag', (
        Option('bag', '', 'replay: the bag folder'),
        Option('topic', '', "replay: block topic to replay; empty: the bag's "
                            '*/measurements'),
        Option('pacing', 'receive_time', "replay: 'receive_time' (the original block "
                                         "timing), 'sample_clock' or 'fast'",
               choices=('receive_time', 'sample_clock', 'fast')),
        Option('speed', 1.0, 'replay: speed factor [1], (0, 1e6]', minimum=0.0,
               maximum=1e6, min_exclusive=True),
        Option('loop', False, 'replay: start over in a new epoch after the last block'),
    ), _make_replay),
    BackendEntry('daqmx', DaqmxBackend, _DAQMX_SUMMARY, (
        Option('device', 'Dev1', 'daqmx: NI-DAQmx device name'),
        Option('ai_terminals', daqmx_backend.default_terminals(),
               "daqmx: analog input of each input, in the inputs' order ('ai0')"),
        Option('ai_units_per_V', daqmx_backend.default_units_per_V(),
               "daqmx: SI units per volt at each input (signal conditioning), in the inputs' "
               'order'),
        Option('ai_range_V', daqmx_backend.default_ranges_V(),
               'daqmx: input range of each input, +/- [V]: 0.1, 0.2, 0.5, 1, 2, 5 or 10',
               minimum=0.1, maximum=10.0),
        Option('ai_terminal_config', 'DEFAULT', 'daqmx: analog input terminal '
                                                'configuration of every input',
               choices=daqmx_backend.TERMINAL_CONFIGS),
        Option('ao_terminals', tuple(t for _, t in daqmx_backend.DEFAULT_AO_WIRING),
               "daqmx: analog output of each output, in the outputs' order ('ao0')"),
        Option('grpc_address', '', 'daqmx: host:port of an NI gRPC Device Server; empty: '
                                   'the local NI-DAQmx driver'),
        Option('session_prefix', 'emfc', 'daqmx: prefix of the task and gRPC session names'),
        Option('read_period_s', 0.01, 'daqmx: inputs are read and outputs topped up in '
                                      'chunks of this length [s], (0, 1]', minimum=0.0,
               maximum=1.0, min_exclusive=True),
        Option('output_lead_s', 0.5, 'daqmx: outputs are written this far ahead of the '
                                     "device's position [s] (at least 2 read periods; the "
                                     "bridge's excitation_lead_s must exceed it by a "
                                     'block, a read and 50 ms), (0, 10]', minimum=0.0,
               maximum=10.0, min_exclusive=True),
        Option('input_buffer_s', 2.0, 'daqmx: input buffer [s], (0, 600]', minimum=0.0,
               maximum=600.0, min_exclusive=True),
        Option('watchdog', 'auto', 'daqmx: hardware watchdog timer with the safe values as '
                                   "expiration states: 'auto' (where the device has one), "
                                   "'on' (required) or 'off'",
               choices=daqmx_backend.WATCHDOG_MODES),
    ), _make_daqmx),
)}

#: Keys of the mapping besides the device configuration's and the back-ends' own.
OWN_KEYS = ('backend', 'balance_file')


def names() -> Tuple[str, ...]:
    """
    The registered back-end names, in registration order.

    Returns
    -------
    tuple of str
        The names.
    """
    return tuple(BACKENDS)


def entry(name: str) -> BackendEntry:
    """
    The registry entry of a back-end.

    Parameters
    ----------
    name : str
        A key of :data:`BACKENDS`.

    Returns
    -------
    BackendEntry
        The entry.

    Raises
    ------
    DeviceConfigError
        If the name is unknown (the message lists the known ones).
    """
    try:
        return BACKENDS[name]
    except KeyError:
        raise DeviceConfigError(f'backend must be one of {list(BACKENDS)}, got '
                                f'{name!r}') from None


def create_backend(name: str, **options: Any) -> DeviceBackend:
    """
    Build a back-end by name from its constructor's keyword arguments (tests, benchmarks).

    Configuration from parameters or files goes through :func:`backend_from_mapping`.

    Parameters
    ----------
    name : str
        A key of :data:`BACKENDS`.
    **options
        Keyword arguments of the back-end class's constructor.

    Returns
    -------
    DeviceBackend
        The back-end.

    Raises
    ------
    DeviceConfigError
        If the name is unknown.
    """
    return entry(name).cls(**options)


def parameter_table() -> Dict[str, Tuple[Value, str]]:
    """
    Every back-end's options as node parameters: ``'<backend>.<key>'`` to (default, text).

    Returns
    -------
    dict
        The parameter table entries (:func:`emfc_ros.nodes.params.declare_table`'s form).
    """
    return {f'{e.name}.{o.key}': (o.default, o.description)
            for e in BACKENDS.values() for o in e.options}


def parameter_limits() -> Dict[str, Tuple[float, float]]:
    """
    Inclusive limits of the numeric options with both bounds, by parameter name.

    Returns
    -------
    dict
        ``'<backend>.<key>'`` to ``(min, max)``.
    """
    return {f'{e.name}.{o.key}': o.limits for e in BACKENDS.values() for o in e.options
            if o.limits is not None}


def backend_summary() -> str:
    """
    The ``backend`` parameter's description: every name and what it is.

    Returns
    -------
    str
        One line.
    """
    return 'device back-end: ' + ', '.join(f"'{e.name}' ({e.summary})"
                                           for e in BACKENDS.values())


def backend_from_mapping(cfg: Mapping[str, Any], path: str = '', balance: Any = None
                         ) -> Tuple[DeviceBackend, DeviceConfig]:
    """
    Build the back-end named by ``backend`` and its device configuration from a mapping.

    Parameters
    ----------
    cfg : Mapping
        ``backend`` (default ``'sim'``), the device configuration keys, ``balance_file``
        and one nested mapping of options per back-end (module docstring).
    path : str
        The mapping's dotted path, for messages.
    balance : BalanceParameters, optional
        The balance (for the ``sim`` back-end and the default input scaling); read from
        ``balance_file`` (or the shipped default) when None.

    Returns
    -------
    backend : DeviceBackend
        The back-end (not yet configured).
    config : DeviceConfig
        What to pass to ``backend.configure``: the mapping's, or the configuration the
        back-end recorded (:attr:`DeviceBackend.recorded_config`, a replay).

    Raises
    ------
    ConfigError
        Naming the offending key and what is allowed.
    """
    reject_unknown(cfg, (*OWN_KEYS, *DEVICE_CONFIG_KEYS, *BACKENDS), path)
    name = get_str(cfg, 'backend', path, default='sim', choices=list(BACKENDS))
    chosen = BACKENDS[name]
    sub_path = join(path, name)
    options = chosen.read_options(get_mapping(cfg, name, path, default={}), sub_path)
    if balance is None:
        from emfc_ros.core.model.balance_file import load_balance
        balance_file = get_str(cfg, 'balance_file', path, default='')
        try:
            balance = load_balance(balance_file or None)
        except (OSError, ValueError) as exc:
            raise ConfigError(join(path, 'balance_file'), str(exc)) from None
    config = device_config_from_mapping(cfg, path, balance)
    try:
        backend = chosen.factory(chosen.cls, options, balance)
    except (ValueError, OSError) as exc:
        raise ConfigError(sub_path, str(exc)) from None
    recorded = backend.recorded_config
    return backend, recorded if recorded is not None else config
