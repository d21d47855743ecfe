"""
The device back-end interface: the configuration dataclasses and the Protocol.

A back-end is the host's view of one data-acquisition device (the FPGA of the paper): it is
configured with a sample rate, input channels (name, unit and the scaling between raw
converter codes and SI values), output channels (limits and a safe value) and a block size;
it is started and stopped; the host either streams setpoint blocks to it or configures the
device's own function generator; it returns measurement blocks as
:class:`emfc_ros.core.blocks.Block` with exact first sample indices, never spanning a gap;
and it counts every defect in :meth:`DeviceBackend.health`.

Back-ends are chosen by name in :mod:`emfc_ros.core.device.registry` (the only configuration
path); this module imports none of them.
"""

from __future__ import annotations

import dataclasses
import math
from typing import (Any, Dict, List, Mapping, Optional, Protocol, runtime_checkable, Sequence,
                    Tuple)

import numpy as np

from emfc_ros.core.blocks import Block
from emfc_ros.core.config import get_float, get_float_list, get_int, get_str_list, join
from emfc_ros.core.device.errors import DeviceConfigError
from emfc_ros.core.device.function_generator import GeneratorSpec
from emfc_ros.core.errors import ConfigError
from emfc_ros.core.model.balance_file import load_balance

#: Raw converter codes are signed 16-bit integers.
CODE_MIN = -32768
CODE_MAX = 32767
#: Longest channel name or unit in bytes (UTF-8), as the protocol carries them.
MAX_NAME_BYTES = 63
#: Most input and output channels of one device.
MAX_CHANNELS = 64
MAX_BLOCK_SIZE = 65535

#: Measured channels of the simulated balance, in the default order of the inputs.
DEFAULT_INPUTS = ('coil_current_A', 'load_changer_current_A', 'sensor_V', 'coil_setpoint_V',
                  'load_changer_setpoint_V', 'position_m')
#: The two outputs: coil and load-changer amplifier setpoints.
DEFAULT_OUTPUTS = ('coil_V', 'load_changer_V')


def _check_name(what: str, value: str) -> None:
    if not isinstance(value, str) or not value or len(value.encode('utf-8')) > MAX_NAME_BYTES:
        raise DeviceConfigError(f'{what} must be a non-empty string of at most '
                                f'{MAX_NAME_BYTES} UTF-8 bytes, got {value!r}')


def _check_finite(what: str, value: float) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)) or \
            not math.isfinite(value):
        raise DeviceConfigError(f'{what} must be a finite number, got {value!r}')


@dataclasses.dataclass(frozen=True)
class InputChannel:
    """
    One measured channel: ``value = code * scale + offset`` in SI units.

    Attributes
    ----------
    name : str
        Channel name, ending in its unit (for example ``'coil_current_A'``).
    unit : str
        SI unit of the scaled value.
    scale : float
        SI value per converter code, non-zero.
    offset : float
        SI value at code 0.
    """

    name: str
    unit: str
    scale: float
    offset: float = 0.0

    def __post_init__(self) -> None:
        _check_name('input channel name', self.name)
        _check_name(f'unit of {self.name}', self.unit)
        _check_finite(f'scale of {self.name}', self.scale)
        _check_finite(f'offset of {self.name}', self.offset)
        if self.scale == 0.0:
            raise DeviceConfigError(f'scale of {self.name} must not be 0')


@dataclasses.dataclass(frozen=True)
class OutputChannel:
    """
    One actuator output (a DAC channel).

    Attributes
    ----------
    name : str
        Channel name (for example ``'coil_V'``).
    min_V, max_V : float
        Limits; every output sample is clamped to them [V].
    safe_V : float
        Value driven when stopped, on underrun and when the watchdog trips [V].
    unit : str
        Unit of the values (``'V'``).
    scale, offset : float
        Code scaling for int16 setpoint frames (``value = code * scale + offset``).
    """

    name: str
    min_V: float = -10.0
    max_V: float = 10.0
    safe_V: float = 0.0
    unit: str = 'V'
    scale: float = 20.0 / 65536.0
    offset: float = 0.0

    def __post_init__(self) -> None:
        _check_name('output channel name', self.name)
        _check_name(f'unit of {self.name}', self.unit)
        for field in ('min_V', 'max_V', 'safe_V', 'scale', 'offset'):
            _check_finite(f'{field} of {self.name}', getattr(self, field))
        if not self.min_V <= self.safe_V <= self.max_V:
            raise DeviceConfigError(f'{self.name}: need min_V <= safe_V <= max_V, got '
                                    f'{self.min_V}, {self.safe_V}, {self.max_V}')
        if self.scale == 0.0:
            raise DeviceConfigError(f'scale of {self.name} must not be 0')
        # The DAC spans 65536 codes: limits outside that range would clamp nothing.
        span = 32768.0 * abs(self.scale)
        low, high = self.offset - span, self.offset + span
        if self.min_V < low - 1e-12 or self.max_V > high + 1e-12:
            raise DeviceConfigError(f'{self.name}: limits [{self.min_V}, {self.max_V}] V lie '
                                    f'outside the DAC range [{low:g}, {high:g}] V (scale '
                                    f'{self.scale:g} V per code, offset {self.offset:g} V)')


@dataclasses.dataclass(frozen=True)
class DeviceConfig:
    """
    Everything a device needs before START.

    Attributes
    ----------
    sample_rate_Hz : float
        Sample clock of inputs and outputs [Hz].
    block_size : int
        Samples per channel per measurement block, 1..65535.
    inputs : tuple of InputChannel
        Measured channels, in block row order.
    outputs : tuple of OutputChannel
        Actuator outputs, in setpoint row order.
    watchdog_timeout_s : float
        The device drives the outputs to their safe values when no heartbeat (or other
        request) arrived for this long while running [s].
    """

    sample_rate_Hz: float
    block_size: int
    inputs: Tuple[InputChannel, ...]
    outputs: Tuple[OutputChannel, ...]
    watchdog_timeout_s: float = 0.5

    def __post_init__(self) -> None:
        _check_finite('sample_rate_Hz', self.sample_rate_Hz)
        if not 0.0 < self.sample_rate_Hz <= 1e7:
            raise DeviceConfigError(f'sample_rate_Hz must be in (0, 1e7], got '
                                    f'{self.sample_rate_Hz}')
        if isinstance(self.block_size, bool) or not isinstance(self.block_size, int) or \
                not 1 <= self.block_size <= MAX_BLOCK_SIZE:
            raise DeviceConfigError(f'block_size must be an integer in [1, {MAX_BLOCK_SIZE}], '
                                    f'got {self.block_size!r}')
        object.__setattr__(self, 'inputs', tuple(self.inputs))
        object.__setattr__(self, 'outputs', tuple(self.outputs))
        for what, chans in (('inputs', self.inputs), ('outputs', self.outputs)):
            if not 1 <= len(chans) <= MAX_CHANNELS:
                raise DeviceConfigError(f'{what}: need 1 to {MAX_CHANNELS} channels, got '
                                        f'{len(chans)}')
            names = [c.name for c in chans]
            if len(set(names)) != len(names):
                raise DeviceConfigError(f'{what}: channel names must be unique, got {names}')
        _check_finite('watchdog_timeout_s', self.watchdog_timeout_s)
        if not 0.0 < self.watchdog_timeout_s <= 3600.0:
            raise DeviceConfigError(f'watchdog_timeout_s must be in (0, 3600], got '
                                    f'{self.watchdog_timeout_s}')

    @property
    def input_names(self) -> Tuple[str, ...]:
        """
        Input channel names in block row order.

        Returns
        -------
        tuple of str
            The names.
        """
        return tuple(c.name for c in self.inputs)

    @property
    def safe_values_V(self) -> np.ndarray:
        """
        Safe value of every output.

        Returns
        -------
        numpy.ndarray
            Shape ``(outputs,)`` [V].
        """
        return np.array([c.safe_V for c in self.outputs])


def generator_range_V(spec: GeneratorSpec) -> Tuple[float, float]:
    """
    Lowest and highest value a generator spec outputs (before clamping).

    Parameters
    ----------
    spec : GeneratorSpec
        The spec (``'off'`` and ``'constant'`` output ``offset_V`` only).

    Returns
    -------
    (float, float)
        ``offset_V -/+ |gain * amplitude_V|`` [V].
    """
    swing = 0.0 if spec.waveform in ('off', 'constant') else abs(spec.gain * spec.amplitude_V)
    return spec.offset_V - swing, spec.offset_V + swing


def check_generator_range(specs: Sequence[GeneratorSpec], config: 'DeviceConfig') -> None:
    """
    Refuse generator specs whose output would leave their channel's limits.

    The device would clamp such an output (what was asked for would not be applied), and a
    value beyond the limits is almost always a typing error: the bound is each output's
    ``[min_V, max_V]`` (inside the DAC range), not a fixed number of volts.

    Parameters
    ----------
    specs : sequence of GeneratorSpec
        One per output channel.
    config : DeviceConfig
        The configuration with the outputs' limits.

    Raises
    ------
    DeviceConfigError
        Naming the channel, the generator's range and the limits.
    """
    for spec, out in zip(specs, config.outputs):
        if not spec.active:
            continue
        low, high = generator_range_V(spec)
        if low < out.min_V - 1e-9 or high > out.max_V + 1e-9:
            raise DeviceConfigError(
                f'function generator of {out.name}: its output spans [{low:g}, {high:g}] V '
                f'(offset_V -/+ |gain * amplitude_V|), beyond the output limits '
                f'[{out.min_V:g}, {out.max_V:g}] V')


def to_codes(values: np.ndarray, scale: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """
    Convert SI values to raw int16 converter codes (nearest code, saturating).

    Parameters
    ----------
    values : numpy.ndarray
        Shape ``(channels, n)``.
    scale, offset : numpy.ndarray
        Per channel, shape ``(channels,)``.

    Returns
    -------
    numpy.ndarray
        int16 codes, shape ``(channels, n)``.
    """
    codes = np.rint((np.asarray(values, dtype=np.float64) - offset[:, None]) / scale[:, None])
    return np.clip(np.nan_to_num(codes), CODE_MIN, CODE_MAX).astype(np.int16)


def from_codes(codes: np.ndarray, scale: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """
    Convert raw converter codes to SI values.

    Parameters
    ----------
    codes : numpy.ndarray
        Integer codes, shape ``(channels, n)``.
    scale, offset : numpy.ndarray
        Per channel, shape ``(channels,)``.

    Returns
    -------
    numpy.ndarray
        float64 values ``code * scale + offset``.
    """
    return codes.astype(np.float64) * scale[:, None] + offset[:, None]


def input_scaling(config: DeviceConfig) -> Tuple[np.ndarray, np.ndarray]:
    """
    Scale and offset vectors of a configuration's inputs.

    Parameters
    ----------
    config : DeviceConfig
        The configuration.

    Returns
    -------
    scale, offset : numpy.ndarray
        Shape ``(inputs,)`` each.
    """
    return (np.array([c.scale for c in config.inputs]),
            np.array([c.offset for c in config.inputs]))


def default_input_channel(name: str, params: Any = None) -> InputChannel:
    """
    The scaling of a simulated-balance channel that matches its converter.

    Voltages and currents use the ADC or DAC step (currents through the current monitor), so
    their codes are exact; positions use the sensor range over 32768 codes, forces 4 N.

    Parameters
    ----------
    name : str
        A simulator channel name (its suffix gives the unit).
    params : BalanceParameters, optional
        Converter parameters; the shipped defaults when None.

    Returns
    -------
    InputChannel
        The channel.

    Raises
    ------
    DeviceConfigError
        If the unit suffix is not one of ``_V``, ``_A``, ``_m``, ``_N``.
    """
    if params is None:
        params = load_balance()
    conv = params.converters
    adc_lsb_V = 2.0 * conv.adc_range_V / 2.0 ** conv.adc_bits
    dac_lsb_V = 2.0 * conv.dac_range_V / 2.0 ** conv.dac_bits
    unit = name.rsplit('_', 1)[-1]
    if unit == 'V':
        scale = dac_lsb_V if 'setpoint' in name else adc_lsb_V
    elif unit == 'A':
        scale = adc_lsb_V / conv.current_monitor_V_per_A
    elif unit == 'm':
        scale = conv.sensor_range_m / 32768.0
    elif unit == 'N':
        scale = 4.0 / 32768.0
    else:
        raise DeviceConfigError(f'channel {name!r}: unit suffix {unit!r} is not V, A, m or N')
    return InputChannel(name, unit, scale, 0.0)


def default_device_config(sample_rate_Hz: float = 10000.0, block_size: int = 1000,
                          inputs: Sequence[str] = DEFAULT_INPUTS, params: Any = None, *,
                          limits_V: Tuple[float, float] = (-10.0, 10.0),
                          safe_V: Sequence[float] = (0.0, 0.0),
                          watchdog_timeout_s: float = 0.5) -> DeviceConfig:
    """
    A configuration for the simulated balance (or a device wired like it).

    Parameters
    ----------
    sample_rate_Hz : float
        Sample rate [Hz].
    block_size : int
        Samples per block.
    inputs : sequence of str
        Simulator channel names to measure.
    params : BalanceParameters, optional
        For the converter scaling; the shipped defaults when None.
    limits_V : (float, float)
        Output limits of both outputs [V].
    safe_V : sequence of float
        Safe values of coil and load-changer outputs [V].
    watchdog_timeout_s : float
        Device watchdog timeout [s].

    Returns
    -------
    DeviceConfig
        The configuration.
    """
    ins = tuple(default_input_channel(n, params) for n in inputs)
    outs = tuple(OutputChannel(n, limits_V[0], limits_V[1], float(s))
                 for n, s in zip(DEFAULT_OUTPUTS, safe_V))
    return DeviceConfig(float(sample_rate_Hz), int(block_size), ins, outs,
                        float(watchdog_timeout_s))


@runtime_checkable
class DeviceBackend(Protocol):
    """
    What the bridge needs from a device back-end.

    Sample indices count from 0 at START on the device's sample clock; the epoch increments at
    every START (and at every reconnect of a network back-end).

    Attributes
    ----------
    name : str
        The registry name (:mod:`emfc_ros.core.device.registry`), published in the
        measurement description.
    host_paced : bool
        True: the back-end makes a block only when asked (:meth:`read_block` does not wait),
        so the host reads it on its own clock at the sample rate; False: blocks arrive on the
        device's clock and a reader thread waits for them.
    applies_excitation : bool
        Whether setpoints written are applied to a balance (False: a recording).
    silence_timeout_s : float
        No block for this long while running counts as the device lost [s].
    recorded_config : DeviceConfig or None
        The configuration the back-end's data were taken with (a recording), used instead
        of the configured one; None: the configured one.
    recorded_resolution : dict or None
        The recorded channels' resolution (``extra.resolution`` of a description); None:
        the converter steps of the configuration.
    finished : bool
        True once a finite source has returned its last block.
    intrusion_counters : tuple of str
        Health counters of datagrams refused as not from the device, the session or the key
        (a warning, not a stream defect).
    """

    name: str
    host_paced: bool
    applies_excitation: bool
    silence_timeout_s: float
    recorded_config: Optional['DeviceConfig']
    recorded_resolution: Optional[Dict[str, Any]]
    finished: bool
    intrusion_counters: Tuple[str, ...]

    def description_extra(self) -> Dict[str, Any]:
        """
        What the back-end adds to the measurement description's ``extra``.

        Returns
        -------
        dict
            Keys and values to merge into ``extra`` (JSON-able).
        """
        ...  # pragma: no cover

    def configure(self, config: DeviceConfig) -> None:
        """
        Send the configuration (device idle or stopped).

        Parameters
        ----------
        config : DeviceConfig
            Sample rate, block size, inputs and outputs, watchdog timeout.
        """
        ...  # pragma: no cover

    def start(self) -> int:
        """
        Start sampling at index 0; returns the new epoch.

        Returns
        -------
        int
            The stream epoch of the blocks from now on.
        """
        ...  # pragma: no cover

    def stop(self) -> None:
        """Stop sampling; the outputs go to their safe values."""
        ...  # pragma: no cover

    def write_setpoints(self, first_sample_index: int, samples_V: np.ndarray) -> None:
        """
        Queue setpoints ``(outputs, n)`` [V] for device samples from the given index.

        Parameters
        ----------
        first_sample_index : int
            Device sample index of ``samples_V[:, 0]``, >= 0.
        samples_V : numpy.ndarray, shape (outputs, n)
            Setpoints per output [V], finite.
        """
        ...  # pragma: no cover

    def set_function_generator(self, specs: Sequence[GeneratorSpec]) -> None:
        """
        Configure the on-device generator, one spec per output ('off': stream).

        Parameters
        ----------
        specs : sequence of GeneratorSpec
            One per output, in the outputs' order.
        """
        ...  # pragma: no cover

    def read_block(self, timeout_s: float = 1.0) -> Optional[Block]:
        """
        Next measurement block in SI units, or None if none arrived in time.

        Parameters
        ----------
        timeout_s : float
            Longest wait [s] (host-paced back-ends do not wait).

        Returns
        -------
        Block or None
            The block, a row per input of the configuration in use (``recorded_config``
            for a recording).
        """
        ...  # pragma: no cover

    def health(self) -> Dict[str, int]:
        """
        Health counters (see ``docs/device_protocol.md``).

        Returns
        -------
        dict of str to int
            Counter name to value.
        """
        ...  # pragma: no cover

    def take_faults(self) -> List[Tuple[str, Optional[int], str, bool]]:
        """
        Faults the back-end found itself since the last call, each once (kind, index...).

        Returns
        -------
        list of tuple
            ``(kind, device_index, message, exact)`` each: a kind of
            :data:`emfc_ros.core.device.faults.KINDS`, the first device sample affected (or None),
            what the back-end said, whether the index is exact.
        """
        ...  # pragma: no cover

    def close(self) -> None:
        """Release sockets and threads (stops the device if running)."""
        ...  # pragma: no cover


#: Keys of :func:`device_config_from_mapping`.
DEVICE_CONFIG_KEYS = ('sample_rate_Hz', 'block_size', 'watchdog_timeout_s', 'inputs',
                      'input_units', 'input_scales', 'input_offsets', 'outputs',
                      'output_min_V', 'output_max_V', 'output_safe_V')


def _per_channel(cfg: Mapping[str, Any], key: str, path: str, n: int,
                 default: Sequence[float]) -> list:
    values = get_float_list(cfg, key, path, default=list(default))
    if len(values) != n:
        raise ConfigError(join(path, key), f'expected {n} values (one per channel), got '
                                           f'{len(values)}')
    return values


def device_config_from_mapping(cfg: Mapping[str, Any], path: str = '',
                               params: Any = None) -> DeviceConfig:
    """
    Build a device configuration from a mapping (parsed YAML or ROS parameters).

    Keys (all optional): ``sample_rate_Hz`` (10000), ``block_size`` (1000),
    ``watchdog_timeout_s`` (0.5), ``inputs`` (channel names, :data:`DEFAULT_INPUTS`),
    ``input_units``, ``input_scales``, ``input_offsets`` (per input; default the converter
    scaling of :func:`default_input_channel`), ``outputs`` (:data:`DEFAULT_OUTPUTS`),
    ``output_min_V`` (-10), ``output_max_V`` (10), ``output_safe_V`` (0), per output. Parallel
    lists keep the form valid for ROS parameters.

    Parameters
    ----------
    cfg : Mapping
        The mapping.
    path : str
        Its dotted path, for messages.
    params : BalanceParameters, optional
        For the default scaling.

    Returns
    -------
    DeviceConfig
        The configuration.

    Raises
    ------
    ConfigError
        Naming the offending key and what is allowed.
    """
    rate = get_float(cfg, 'sample_rate_Hz', path, default=10000.0, minimum=0.0,
                     maximum=1e7, min_exclusive=True)
    block = get_int(cfg, 'block_size', path, default=1000, minimum=1, maximum=MAX_BLOCK_SIZE)
    watchdog = get_float(cfg, 'watchdog_timeout_s', path, default=0.5, minimum=0.0,
                         maximum=3600.0, min_exclusive=True)
    names = get_str_list(cfg, 'inputs', path, default=list(DEFAULT_INPUTS), min_length=1)
    try:
        defaults = [default_input_channel(n, params) for n in names] \
            if not all(k in cfg for k in ('input_units', 'input_scales')) else []
    except DeviceConfigError as exc:
        raise ConfigError(join(path, 'inputs'), str(exc)) from None
    n_in = len(names)
    units = get_str_list(cfg, 'input_units', path,
                         default=[c.unit for c in defaults] if defaults else None)
    if len(units) != n_in:
        raise ConfigError(join(path, 'input_units'), f'expected {n_in} units, got {len(units)}')
    scales = _per_channel(cfg, 'input_scales', path, n_in, [c.scale for c in defaults])
    offsets = _per_channel(cfg, 'input_offsets', path, n_in, [0.0] * n_in)
    outs = get_str_list(cfg, 'outputs', path, default=list(DEFAULT_OUTPUTS), min_length=1)
    n_out = len(outs)
    lo = _per_channel(cfg, 'output_min_V', path, n_out, [-10.0] * n_out)
    hi = _per_channel(cfg, 'output_max_V', path, n_out, [10.0] * n_out)
    safe = _per_channel(cfg, 'output_safe_V', path, n_out, [0.0] * n_out)
    try:
        inputs = tuple(InputChannel(*a) for a in zip(names, units, scales, offsets))
        outputs = tuple(OutputChannel(*a) for a in zip(outs, lo, hi, safe))
        return DeviceConfig(rate, block, inputs, outputs, watchdog)
    except DeviceConfigError as exc:
        raise ConfigError(path or 'device', str(exc)) from None
