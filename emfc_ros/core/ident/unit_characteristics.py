"""
The unit's own amplifier curves for the grey-box: from the staircases, checked against the file.

The static step fits each amplifier's curve ``I(U)`` from its staircase (the current monitor
against the setpoint, :mod:`~emfc_ros.core.ident.static_fit`). A unit's amplifiers differ
from the type's curve in the balance file by a few percent; the grey-box simulates the
balance from the setpoints through these curves, so it takes the identified ones
(``greybox.amplifiers_from_static``, default on) and says for each characteristic where it
came from and how far the file's is from it (:func:`unit_amplifiers`). An identified curve is
used only where it holds: monotonic over its staircase and the staircase spanning the
setpoints the grey-box sections apply; otherwise the file's, with a warning.
"""

from __future__ import annotations

from dataclasses import replace
import math
from typing import Any, Dict, List, Mapping, Tuple

import numpy as np

from emfc_ros.core.errors import ConfigError
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.model.peripherals import Amplifier, check_monotonic

#: Amplifier, its setpoint channel and its stated gain and DAC-gain uncertainty keys.
CHANNELS = {'coil_amplifier': ('coil_setpoint_V', 'coil_amplifier_gain_relative',
                               'coil_dac_gain_relative'),
            'load_changer_amplifier': ('load_changer_setpoint_V',
                                       'load_changer_amplifier_gain_relative',
                                       'load_changer_dac_gain_relative')}


def unit_amplifiers(balance: BalanceParameters, fits: Mapping[str, Any],
                    points: Mapping[str, Tuple[np.ndarray, np.ndarray]],
                    setpoint_spans_V: Mapping[str, float]
                    ) -> Tuple[BalanceParameters, Dict[str, float], Dict[str, str], List[str]]:
    """
    The balance with the identified amplifier curves, and what was done for each.

    Parameters
    ----------
    balance : BalanceParameters
        The configured balance (the file's curves, the stated uncertainties).
    fits : mapping of str to PolynomialFit
        The static step's fits by characteristic (``coil_amplifier``,
        ``load_changer_amplifier``; others are ignored).
    points : mapping of str to (ndarray, ndarray)
        The plateaus each fit used (setpoints [V], currents [A]).
    setpoint_spans_V : mapping of str to float
        Per amplifier the largest absolute setpoint the grey-box sections apply [V].

    Returns
    -------
    balance : BalanceParameters
        With each usable identified curve in place of the file's.
    gain_errors : dict of str to float
        Per amplifier taken from its staircase: the relative standard error of the
        identified gain (``dI/dU`` at 0 V).
    sources : dict of str to str
        Per amplifier: identified or from the file, and the comparison of the two gains.
    warnings : list of str
        Why an identified curve was not used.
    """
    out, errors, sources, warnings = balance, {}, {}, []
    stated = balance.uncertainties
    for part, (channel, gain_key, dac_key) in CHANNELS.items():
        fit = fits.get(part)
        if fit is None:
            continue
        coeffs = [float(c) for c in fit.coefficients]
        gain, se = coeffs[1], float(fit.standard_errors[1])
        file_gain = float(getattr(balance, part).coeffs_A_per_V_pow[1])
        diff = gain / file_gain - 1.0
        spread = math.hypot(se / abs(gain), float(getattr(stated, gain_key)),
                            float(getattr(stated, dac_key)),
                            float(stated.current_monitor_gain_relative))
        compare = (f"the file's gain {file_gain:.6g} A/V is {100 * -diff / (1 + diff):+.2f} % "
                   f'from it ({abs(diff) / spread:.1f} combined standard uncertainties of '
                   f'the difference)')
        u = np.asarray(points[part][0], dtype=float)
        reach = float(np.max(np.abs(u))) if u.size else 0.0
        need = float(setpoint_spans_V.get(channel, 0.0))
        try:
            check_monotonic(coeffs, float(np.min(u)), float(np.max(u)), part)
        except ConfigError as exc:
            warnings.append(f'greybox: the {part} curve from its staircase is not used: '
                            f"{exc.problem}; the file's is")
            sources[part] = f'file (the staircase curve is not monotonic); {compare}'
            continue
        if need > reach * 1.0001:
            warnings.append(f'greybox: the {part} curve from its staircase is not used: the '
                            f'staircase spans +/-{reach:.3g} V, the fitted sections apply up '
                            f"to {need:.3g} V; the file's is")
            sources[part] = f'file (the staircase spans less than the fit needs); {compare}'
            continue
        out = replace(out, **{part: Amplifier(tuple(coeffs))})
        errors[part] = se / abs(gain)
        sources[part] = (f'identified (static staircase, {len(u)} plateaus; gain {gain:.6g} '
                         f'+/- {se:.2g} A/V); {compare}')
    return out, errors, sources, warnings
