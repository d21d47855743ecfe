"""
The pan load that balances the open-loop lever at zero coil current.

The paper brought its balance to the operating point by loading the pan with mass pieces
rather than by a coil offset; this finds that mass for a parameter set.
"""

from __future__ import annotations

from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.sim.hold_point import hold_point


def balancing_load_mass_kg(params: BalanceParameters, load_changer_coupled: bool = False,
                           upper_kg: float = 1.0) -> float:
    """
    Mass on the pan for which the lever end rests at 0 with 0 V on the coil.

    Parameters
    ----------
    params : BalanceParameters
        The balance.
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan (its weight counts).
    upper_kg : float
        Largest mass searched [kg] (halved while the coil could not hold it).

    Returns
    -------
    float
        The mass [kg].

    Raises
    ------
    ValueError
        If no mass in [0, upper_kg] balances the lever (for example if the empty lever
        already needs a downward coil force).
    """
    def coil_hold_V(mass_kg: float) -> float:
        return float(hold_point(params, mass_kg, load_changer_coupled).setpoints_V[0])

    low = coil_hold_V(0.0)
    high = None
    while high is None:
        try:
            high = coil_hold_V(upper_kg)
        except ValueError:    # beyond the current limit: search a smaller range
            upper_kg *= 0.5
            if upper_kg < 1e-6:
                raise
    if low == 0.0:
        return 0.0
    if low * high > 0:
        raise ValueError(f'no pan load from 0 to {upper_kg} kg balances the lever at zero coil '
                         f'current (hold setpoints {low:.4g} V and {high:.4g} V)')
    from scipy.optimize import brentq   # here: importing scipy.optimize takes about 0.5 s
    return float(brentq(coil_hold_V, 0.0, upper_kg, xtol=1e-12))
