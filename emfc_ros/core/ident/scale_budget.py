"""
Systematic (type B) uncertainty of the FRFs, the transfer-function gains and the static fits.

These results are ratios of measured signals, each read through a characteristic the
identification takes as known, so each carries the stated uncertainties of those
characteristics (:class:`~emfc_ros.core.model.uncertainties.StatedUncertainties`) as a
relative uncertainty of its scale, input by input (GUM, independent inputs in quadrature):

* an FRF, lever-end position per force [m/N]: the position through the sensor characteristic
  and its ADC (``sensor_gain_relative``, ``adc_gain_relative``), the force through the
  measured current (``current_monitor_gain_relative``) and the force constant of its actuator
  (``motor_coefficient_relative`` for the coil, ``load_changer_force_relative`` for the pan
  input); where the recording holds the force itself (``coil_force_N``,
  ``load_changer_force_N``: the simulator's, or a force measurement) the FRF takes it and
  only the position's part remains (no stated uncertainty covers such a channel). A scale
  moves the magnitude, not the phase;
* a transfer-function fit of it: the same relative uncertainty on its gain (the numerator);
  a scale moves no pole and no zero, so the modes' frequencies and damping ratios have no
  part from these inputs;
* an amplifier curve ``I = sum_k c_k U^k``: the current through its monitor
  (``current_monitor_gain_relative``) and the setpoint through the DAC that drives the
  amplifier (``coil_dac_gain_relative``, ``load_changer_dac_gain_relative``): ``c_k`` moves by
  ``k`` times the DAC's relative error;
* the load changer's curve ``F = sum_k c_k I^k``: the current through its monitor, ``c_k``
  moving by ``k`` times its relative error (the force is the recording's reference channel,
  taken as exact: no stated uncertainty covers it).
"""

from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Dict, Tuple

from emfc_ros.core.model.uncertainties import StatedUncertainties

#: The stated inputs behind the measured position.
POSITION_INPUTS = ('sensor_gain_relative', 'adc_gain_relative')
#: The stated inputs behind a force computed from its measured current, by the FRF's input.
FORCE_INPUTS: Dict[str, Tuple[str, ...]] = {
    'coil': ('motor_coefficient_relative', 'current_monitor_gain_relative'),
    'pan': ('load_changer_force_relative', 'current_monitor_gain_relative'),
}
#: Per static fit: the stated input of its y scale and of its x scale (None: exact).
STATIC_INPUTS: Dict[str, Tuple[str, str]] = {
    'coil_amplifier': ('current_monitor_gain_relative', 'coil_dac_gain_relative'),
    'load_changer_amplifier': ('current_monitor_gain_relative',
                               'load_changer_dac_gain_relative'),
    'load_changer': ('', 'current_monitor_gain_relative'),
}


@dataclass(frozen=True)
class ScaleBudget:
    """
    The relative systematic standard uncertainty of one result's scale, input by input.

    Attributes
    ----------
    parts : tuple of (str, float)
        Each stated input (a key of the ``uncertainties`` section) and its contribution, a
        relative standard uncertainty (k = 1), largest first; inputs stated as 0 left out.
    """

    parts: Tuple[Tuple[str, float], ...] = ()

    @property
    def relative(self) -> float:
        """
        The combined relative standard uncertainty (root sum of squares of the parts).

        Returns
        -------
        float
            A fraction of the value (0.02 = 2 %).
        """
        return math.sqrt(sum(u * u for _, u in self.parts))

    @property
    def dominant(self) -> str:
        """
        The input contributing most ('' without any).

        Returns
        -------
        str
            A key of the ``uncertainties`` section.
        """
        return self.parts[0][0] if self.parts else ''

    def as_dict(self) -> Dict[str, float]:
        """
        The parts as a mapping, largest first (for results.yaml).

        Returns
        -------
        dict of str to float
            Input to its relative contribution.
        """
        return {name: float(u) for name, u in self.parts}


def _budget(parts: Dict[str, float]) -> ScaleBudget:
    kept = [(name, abs(float(u))) for name, u in parts.items() if u != 0.0]
    return ScaleBudget(tuple(sorted(kept, key=lambda p: -p[1])))


def frf_budget(stated: StatedUncertainties, input_name: str,
               force_recorded: bool = False) -> ScaleBudget:
    """
    The systematic part of an FRF's magnitude (and of its transfer-function gain).

    Parameters
    ----------
    stated : StatedUncertainties
        The balance file's ``uncertainties``.
    input_name : str
        The FRF's input, ``'coil'`` or ``'pan'``.
    force_recorded : bool
        The recording holds the input's force itself (no current and force constant in the
        FRF's force).

    Returns
    -------
    ScaleBudget
        Relative to the magnitude.

    Raises
    ------
    KeyError
        For another input.
    """
    names = POSITION_INPUTS + (() if force_recorded else FORCE_INPUTS[input_name])
    return _budget({name: getattr(stated, name) for name in names})


def static_budget(stated: StatedUncertainties, key: str, power: int) -> ScaleBudget:
    """
    The systematic part of one coefficient of a static fit.

    Parameters
    ----------
    stated : StatedUncertainties
        The balance file's ``uncertainties``.
    key : str
        The fit (:data:`STATIC_INPUTS`).
    power : int
        The coefficient's power of x (0: the offset).

    Returns
    -------
    ScaleBudget
        Relative to the coefficient: the y scale's uncertainty, and ``power`` times the x
        scale's (an x read ``1 + e`` too large makes ``c_k`` ``(1 + e)^-k`` too small).

    Raises
    ------
    KeyError
        For another fit.
    """
    y_name, x_name = STATIC_INPUTS[key]         # two different inputs (or none for y)
    parts: Dict[str, float] = {}
    if y_name:
        parts[y_name] = getattr(stated, y_name)
    if power:
        parts[x_name] = power * getattr(stated, x_name)
    return _budget(parts)
