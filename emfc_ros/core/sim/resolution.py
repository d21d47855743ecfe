"""
The quantisation step and input noise of the simulated balance's measured channels.

Published in the measurement stream description as ``extra.resolution`` (the convention of
:mod:`emfc_ros.core.weighing.resolution`), so that a consumer (the weighing node) can budget
what averaging cannot remove, and knows the position noise its estimator must assume.
"""

from __future__ import annotations

import math
from typing import Dict, Optional

from emfc_ros.core.control.loop_config import CurrentChannelConfig
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.sim.converters import lsb_V


def simulator_resolution(params: BalanceParameters, noise: bool = True,
                         quantisation: bool = True,
                         current_channel: Optional[CurrentChannelConfig] = None
                         ) -> Dict[str, Dict[str, float]]:
    """
    ``{channel: {"step": q, "noise_rms": sigma}}`` of the simulator's measured channels.

    ``step`` is one converter code in the channel's unit (0 without quantisation), ``noise_rms``
    the independent noise per sample at the converter's input in that unit (0 without noise).
    The position's step uses the sensor's linear coefficient (the characteristic is within
    2 % of linear inside the range).

    Parameters
    ----------
    params : BalanceParameters
        The balance.
    noise, quantisation : bool
        Whether the simulator adds noise and quantises.
    current_channel : CurrentChannelConfig, optional
        The precise current channel of the closed loop (absent: no such channel).

    Returns
    -------
    dict
        Per channel name, step and noise [channel unit].
    """
    conv = params.converters
    adc = lsb_V(conv.adc_bits, conv.adc_range_V) if quantisation else 0.0
    sensor_gain = float(params.sensor.coeffs_V_per_m_pow[1])
    monitor = conv.current_monitor_V_per_A

    def entry(step: float, sigma: float) -> Dict[str, float]:
        return {'step': float(step), 'noise_rms': float(sigma) if noise else 0.0}

    table = {
        'position_m': entry(adc / sensor_gain, conv.sensor_noise_m_rms),
        'sensor_V': entry(adc, conv.sensor_noise_m_rms * sensor_gain),
        'coil_current_A': entry(adc / monitor, conv.coil_current_noise_A_rms),
        'load_changer_current_A': entry(adc / monitor, conv.load_changer_current_noise_A_rms),
    }
    if current_channel is not None:
        ch = current_channel
        step = lsb_V(ch.adc_bits, ch.adc_range_V) / ch.shunt_ohm if quantisation else 0.0
        # the amplifier's current noise flows through the shunt too: both dither the converter
        sigma = math.hypot(ch.noise_V_rms / ch.shunt_ohm, conv.coil_current_noise_A_rms)
        table['coil_current_precise_A'] = entry(step, sigma)
    return table
