"""
What a plant front end needs besides the simulation: saturation counts.

Pure functions of the balance parameters and simulator output, used by the plant_simulator
node so that it stays thin (effort commands to setpoints:
:func:`emfc_ros.core.model.actuation.coil_setpoint_for_force_V`).
"""

from __future__ import annotations

from typing import Dict, Sequence

import numpy as np

from emfc_ros.core.model.parameters import BalanceParameters


def saturation_counts(outputs: np.ndarray, names: Sequence[str],
                      params: BalanceParameters) -> Dict[str, int]:
    """
    Count samples of a block at a converter, sensor or stop limit.

    Parameters
    ----------
    outputs : numpy.ndarray
        Simulator output block, rows named by ``names``.
    names : sequence of str
        Channel names (as :attr:`Simulator.channel_names`).
    params : BalanceParameters
        The balance (ranges and limits).

    Returns
    -------
    dict
        ``dac_saturated_samples``, ``sensor_saturated_samples``,
        ``current_limited_samples`` and ``at_stop_samples`` (the last only with the
        reference channel ``position_true_m``).
    """
    row = {name: i for i, name in enumerate(names)}
    conv = params.converters
    tol = 1e-9
    out = {
        'dac_saturated_samples': int(np.count_nonzero(
            np.abs(outputs[[row['coil_setpoint_V'], row['load_changer_setpoint_V']]])
            >= conv.dac_range_V * (1 - tol))),
        'current_limited_samples': int(
            np.count_nonzero(np.abs(outputs[row['coil_current_A']])
                             >= conv.coil_current_limit_A * (1 - 1e-3))
            + np.count_nonzero(np.abs(outputs[row['load_changer_current_A']])
                               >= conv.load_changer_current_limit_A * (1 - 1e-3))),
        'sensor_saturated_samples': int(np.count_nonzero(
            np.abs(outputs[row['position_m']]) >= conv.sensor_range_m * (1 - 1e-3))),
    }
    if 'position_true_m' in row:
        out['at_stop_samples'] = int(np.count_nonzero(
            np.abs(outputs[row['position_true_m']]) >= conv.stop_position_m))
    return out
