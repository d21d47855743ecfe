"""
emfc-model-summary: operating point, poles, zeros and static gains of the balance model as YAML.

``emfc-model-summary [--config FILE] [--load-mass-kg M] [--load-changer-coupled]`` prints:

* ``configuration``: the parameter source, load, coupling and total pan mass;
* ``operating_point``: the hold point (lever end at 0 m, load changer at 0 V): angles, forces,
  currents and setpoints;
* ``poles`` and ``zeros`` (coil and pan input to the lever-end position): frequency [Hz],
  damping ratio and the root in rad/s, one entry per complex pair; real roots carry their signed
  frequency (negative: left half plane). The linear model is the notes' one, about ``q = 0``
  (:func:`emfc_ros.core.model.summary.summarize`);
* ``static_gains``: lever-end position per force [m/N] and end to end, setpoint voltage to
  sensor voltage [V/V] through amplifier, motor or load changer, mechanics and sensor (the
  small-signal slopes at the hold point, with the motor coefficient's position dependence).

Errors (unreadable or invalid configuration, bad arguments) go to stderr with exit code 2.
"""

from __future__ import annotations

import argparse
import sys
from typing import List, Optional, Sequence

import numpy as np
from numpy.polynomial import polynomial as npoly
import yaml

from emfc_ros.core.model.linear import Root
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.model.summary import summarize
from emfc_ros.core.sim.hold_point import hold_point


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog='emfc-model-summary',
        description='Print the operating point, poles, zeros and static gains of the balance '
                    'model as YAML.')
    parser.add_argument('--config', help='balance parameter YAML (default: built-in defaults)')
    parser.add_argument('--load-mass-kg', type=float, default=0.0,
                        help='mass on the pan [kg] (default 0)')
    parser.add_argument('--load-changer-coupled', action='store_true',
                        help="the load changer's moving mass rides on the pan")
    return parser


def _roots(roots: Sequence[Root]) -> List[dict]:
    out = []
    for r in roots:
        s = r.s_rad_per_s
        if r.is_real:
            out.append({'frequency_Hz': r.signed_frequency_Hz, 'real': True,
                        's_rad_per_s': [float(s.real), 0.0]})
        elif s.imag > 0.0:
            out.append({'frequency_Hz': r.frequency_Hz, 'damping_ratio': r.damping_ratio,
                        's_rad_per_s': [float(s.real), float(s.imag)]})
    return out


def _slope(coeffs: Sequence[float], x: float) -> float:
    return float(npoly.polyval(x, npoly.polyder(np.asarray(coeffs, dtype=float))))


def model_summary(params: BalanceParameters, load_mass_kg: float = 0.0,
                  load_changer_coupled: bool = False, source: str = 'built-in defaults') -> dict:
    """
    Collect the summary as plain data.

    Parameters
    ----------
    params : BalanceParameters
        The parameters.
    load_mass_kg : float
        Mass on the pan [kg].
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan.
    source : str
        Where the parameters came from (printed).

    Returns
    -------
    dict
        Nested plain dictionaries and lists (floats, bools, strings).
    """
    s = summarize(params.mechanics, load_mass_kg, load_changer_coupled)
    hp = hold_point(params, load_mass_kg, load_changer_coupled)
    op = hp.operating_point
    mm_per_m = 1.0e3
    i_coil, i_lc = (float(v) for v in hp.currents_A)
    u_coil, u_lc = (float(v) for v in hp.setpoints_V)
    k0 = float(params.motor.coefficient_N_per_A(0.0))
    dk_dy = _slope(params.motor.coeffs_N_per_A_per_mm_pow, 0.0) * mm_per_m   # N/(A m)
    sensor_slope = _slope(params.sensor.coeffs_V_per_m_pow, 0.0)
    # y = G_c (k(y) I_c) + G_p F_p: the motor's position dependence is a feedback stiffness
    loop = 1.0 - s.static_gain_coil_m_per_N * dk_dy * i_coil
    coil_y_per_V = (s.static_gain_coil_m_per_N * k0
                    * _slope(params.coil_amplifier.coeffs_A_per_V_pow, u_coil) / loop)
    lc_y_per_V = (s.static_gain_pan_m_per_N
                  * _slope(params.load_changer.coeffs_N_per_A_pow, i_lc)
                  * _slope(params.load_changer_amplifier.coeffs_A_per_V_pow, u_lc) / loop)
    return {
        'configuration': {
            'parameters': source,
            'load_mass_kg': float(load_mass_kg),
            'load_changer_coupled': bool(load_changer_coupled),
            'pan_mass_kg': float(s.pan_mass_kg),
        },
        'operating_point': {
            'description': 'hold point: lever end at 0 m, load changer setpoint 0 V',
            'q1_rad': float(op.q_rad[0]),
            'q2_rad': float(op.q_rad[1]),
            'position_m': float(op.y_m),
            'coil_force_N': float(op.F_c_N),
            'pan_force_N': float(op.F_p_N),
            'coil_current_A': i_coil,
            'load_changer_current_A': i_lc,
            'coil_setpoint_V': u_coil,
            'load_changer_setpoint_V': u_lc,
        },
        'poles': _roots(s.poles),
        'zeros': {'coil': _roots(s.coil_zeros), 'pan': _roots(s.pan_zeros)},
        'static_gains': {
            'coil_m_per_N': float(s.static_gain_coil_m_per_N),
            'pan_m_per_N': float(s.static_gain_pan_m_per_N),
            'coil_dB_re_1_m_per_N': float(20.0 * np.log10(abs(s.static_gain_coil_m_per_N))),
            'pan_dB_re_1_m_per_N': float(20.0 * np.log10(abs(s.static_gain_pan_m_per_N))),
            'pan_to_coil_force_ratio': float(s.static_force_ratio),
            'coil_setpoint_to_sensor_V_per_V': float(sensor_slope * coil_y_per_V),
            'load_changer_setpoint_to_sensor_V_per_V': float(sensor_slope * lc_y_per_V),
        },
    }


def main(argv: Optional[List[str]] = None) -> int:
    """
    Run the command.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (default: ``sys.argv[1:]``).

    Returns
    -------
    int
        0 on success, 2 on a usage, configuration or file error.
    """
    try:
        args = _parser().parse_args(argv)
    except SystemExit as exc:          # argparse already printed the message
        return int(exc.code or 0)
    try:
        params = BalanceParameters.load_yaml(args.config) if args.config else BalanceParameters()
        data = model_summary(params, args.load_mass_kg, args.load_changer_coupled,
                             args.config or 'built-in defaults')
    except (ValueError, OSError, RuntimeError) as exc:
        print(f'emfc-model-summary: error: {exc}', file=sys.stderr)
        return 2
    sys.stdout.write(yaml.safe_dump(data, sort_keys=False, default_flow_style=False))
    return 0


if __name__ == '__main__':
    sys.exit(main())
