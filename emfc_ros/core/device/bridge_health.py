"""
What the daq_bridge reports on ``/diagnostics``: the level policy over its counters.

:func:`diagnostic_level` decides OK, WARN or ERROR and the one-line message from the values
a :class:`~emfc_ros.core.device.bridge_session.BridgeSession` reports; the node only turns
them into a ``DiagnosticStatus``.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence, Tuple

import numpy as np

#: Levels as ``diagnostic_msgs/DiagnosticStatus`` numbers them.
OK, WARN, ERROR = 0, 1, 2
#: Counters of stream defects: any makes the status WARN.
DEFECT_COUNTERS = ('gaps', 'duplicates', 'reordered', 'corrupt', 'late', 'heartbeat_misses',
                   'reconnects', 'excitation_gaps', 'excitation_duplicates',
                   'excitation_reordered', 'excitation_overlaps', 'excitation_malformed',
                   'published_gaps', 'malformed_blocks')
#: The bridge's own counters, reported 0 until they count.
COUNTERS = ('excitation_blocks', 'excitation_malformed', 'excitation_late_samples',
            'clamped_samples', 'watchdog_trips', 'emergency_stops', 'command_watchdog_trips',
            'command_malformed', 'published_blocks', 'published_samples', 'published_gaps',
            'published_missing_samples', 'dropped_out_of_order_blocks', 'malformed_blocks',
            'reader_errors', 'setpoint_samples_written', 'setpoint_late_samples',
            'setpoint_write_errors', 'epoch_changes', 'excitation_dropped_estop',
            'excitation_not_running')


def percentiles_us(values: Sequence[int]) -> Tuple[float, float]:
    """
    Median and 99th percentile of durations [ns], in microseconds.

    Parameters
    ----------
    values : sequence of int
        Durations [ns].

    Returns
    -------
    (float, float)
        Median and p99 [us]; NaN without values.
    """
    if not values:
        return float('nan'), float('nan')
    arr = np.fromiter(values, dtype=np.float64, count=len(values))
    return float(np.median(arr) / 1e3), float(np.percentile(arr, 99) / 1e3)


def diagnostic_level(values: Mapping[str, Any], intrusion_counters: Sequence[str],
                     fault_summary: str, n_faults: int) -> Tuple[int, str]:
    """
    The status level and message of the bridge's values (the worst condition wins).

    Parameters
    ----------
    values : Mapping
        :meth:`BridgeSession.diagnostic_values`.
    intrusion_counters : sequence of str
        The back-end's counters of refused datagrams.
    fault_summary : str
        The first latched fault, described.
    n_faults : int
        Latched faults.

    Returns
    -------
    level : int
        :data:`OK`, :data:`WARN` or :data:`ERROR`.
    message : str
        Why.
    """
    defects = sum(int(values.get(k, 0) or 0) for k in DEFECT_COUNTERS)
    intrusions = {k: int(values.get(k, 0) or 0) for k in intrusion_counters}
    level, message = OK, 'ok'
    if defects or values.get('clamped_samples'):
        level, message = WARN, 'stream defects or clamped setpoints'
    if any(intrusions.values()):
        level = WARN
        message = 'datagrams refused (not from the device, our session or our key): ' + \
            ', '.join(f'{k} {v}' for k, v in intrusions.items() if v)
    if values.get('watchdog_tripped'):
        level, message = WARN, 'excitation watchdog tripped: outputs safe'
    if values.get('emergency_stop'):
        level, message = ERROR, 'emergency stop latched: outputs safe'
    if n_faults:
        level = ERROR
        message = f'{n_faults} fault(s) latched until ~/reset or ~/start: {fault_summary}'
    if values.get('error') or values.get('state') == 'error':
        level, message = ERROR, values.get('error') or values.get('last_error', '')
    return level, message
