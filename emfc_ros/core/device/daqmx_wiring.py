"""
How an EMFC balance is wired to an NI multifunction DAQ device (X Series), by default.

One table serves both sides: the ``daqmx`` back-end reads each measured channel from the
analog input named here and scales its volts to SI units (``value = volts * units_per_V``),
and the emulated NI-DAQmx device (:mod:`emfc_ros.core.device.daqmx_emulator`) puts the
simulated balance's signal on that terminal (``volts = value / units_per_V``). The two
outputs drive the amplifier inputs. ``docs/daqmx.md`` shows the wiring on the terminal block.

The setpoint channels (``coil_setpoint_V``, ``load_changer_setpoint_V``) are the outputs
looped back to two analog inputs: what was applied, measured on the same sample clock.
"""

from __future__ import annotations

import dataclasses
from typing import Dict, Tuple

from emfc_ros.core.device.backend import DEFAULT_OUTPUTS

#: The first device's name, as NI's tools name it.
DEFAULT_DEVICE = 'Dev1'
#: Input ranges of an X Series analog input, +/- [V].
AI_RANGES_V = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0)
#: Converter resolution of an X Series device's analog inputs and outputs [bits].
CONVERTER_BITS = 16


@dataclasses.dataclass(frozen=True)
class AiWire:
    """
    One measured channel on one analog input.

    Attributes
    ----------
    name : str
        The measured channel (the bridge's ``inputs`` name, ending in its unit).
    terminal : str
        The analog input, without the device (``'ai0'``).
    unit : str
        SI unit of the scaled value.
    units_per_V : float
        SI units per volt at the terminal (the signal conditioning's inverse gain).
    range_V : float
        The input range the back-end configures, +/- [V].
    signal : str
        What is connected, for a person.
    """

    name: str
    terminal: str
    unit: str
    units_per_V: float
    range_V: float
    signal: str


#: Coil and load-changer current monitors are 100 V/A (+/-0.1 A to +/-10 V, the default
#: balance's ``converters.current_monitor_V_per_A``); the position output of the sensor
#: electronics is 1e-5 m/V (+/-100 um to +/-10 V).
DEFAULT_AI_WIRING: Tuple[AiWire, ...] = (
    AiWire('coil_current_A', 'ai0', 'A', 0.01, 10.0, 'coil current monitor output'),
    AiWire('load_changer_current_A', 'ai1', 'A', 0.01, 10.0,
           'load-changer current monitor output'),
    AiWire('sensor_V', 'ai2', 'V', 1.0, 10.0, 'position sensor output'),
    AiWire('coil_setpoint_V', 'ai3', 'V', 1.0, 10.0, 'ao0 looped back (coil setpoint)'),
    AiWire('load_changer_setpoint_V', 'ai4', 'V', 1.0, 10.0,
           'ao1 looped back (load-changer setpoint)'),
    AiWire('position_m', 'ai5', 'm', 1e-5, 10.0,
           'linearised position output of the sensor electronics'),
)

#: The outputs: the coil amplifier's input on ao0, the load changer's on ao1.
DEFAULT_AO_WIRING: Tuple[Tuple[str, str], ...] = tuple(zip(DEFAULT_OUTPUTS, ('ao0', 'ao1')))


def ai_wiring_by_name() -> Dict[str, AiWire]:
    """
    The default analog-input wiring by measured channel name.

    Returns
    -------
    dict
        Name to :class:`AiWire`.
    """
    return {w.name: w for w in DEFAULT_AI_WIRING}


def range_for(limit_V: float) -> float:
    """
    The smallest X Series input range that holds +/- ``limit_V``.

    Parameters
    ----------
    limit_V : float
        The largest magnitude the input must measure [V].

    Returns
    -------
    float
        The range, +/- [V].

    Raises
    ------
    ValueError
        If ``limit_V`` exceeds the largest range (10 V) or is not positive.
    """
    if not 0.0 < limit_V <= AI_RANGES_V[-1] + 1e-12:
        raise ValueError(f'an analog input range of +/-{limit_V:g} V is not one of the '
                         f'device ranges {AI_RANGES_V} V')
    return next(r for r in AI_RANGES_V if r >= limit_V - 1e-12)


def resolution_V(range_V: float) -> float:
    """
    One converter step of a +/- ``range_V`` input or output [V].

    Parameters
    ----------
    range_V : float
        The range, +/- [V].

    Returns
    -------
    float
        ``2 * range_V / 2**16``.
    """
    return 2.0 * range_V / 2.0 ** CONVERTER_BITS
