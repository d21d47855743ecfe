"""
Model summary: poles, zeros and gains for a load configuration, and a printable table.

Print the table for the notes' three configurations with::

    python -m emfc_ros.core.model.summary [--config config/balance_default.yaml]
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import Iterable, List, Optional, Sequence, Tuple

import numpy as np

from emfc_ros.core.model.linear import linearise, LinearModel, Root
from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.parameters import BalanceParameters, MechanicalParameters

#: The configurations of the notes' table: label, load on the pan [kg], load changer coupled.
NOTES_CONFIGURATIONS = (
    ('empty pan', 0.0, False),
    ('load changer coupled (+25 g)', 0.0, True),
    ('100 g on the pan', 0.1, False),
)

#: Frequencies [Hz] at which the summary reports the coil-input magnitude.
SUMMARY_FREQUENCIES_HZ = (0.1, 1.0, 10.0, 100.0, 1000.0)


@dataclass(frozen=True)
class ModelSummary:
    """
    Poles, zeros and gains of the linear model for one load configuration.

    Attributes
    ----------
    label : str
        Name of the configuration.
    pan_mass_kg : float
        Total pan mass [kg].
    model : LinearModel
        The linear model (about rest at q = 0).
    poles : tuple of Root
        Poles (both inputs).
    coil_zeros, pan_zeros : tuple of Root
        Zeros of the coil-force and pan-force input to the lever-end position.
    static_gain_coil_m_per_N, static_gain_pan_m_per_N : float
        Static gains [m/N].
    static_force_ratio : float
        Coil force per pan force that keeps ``y = 0`` statically (``l1 / (l2 + l3)`` if the
        joint J were rigid).
    coil_magnitude_dB : tuple of float
        Coil-input magnitude [dB re 1 m/N] at ``SUMMARY_FREQUENCIES_HZ``.
    """

    label: str
    pan_mass_kg: float
    model: LinearModel
    poles: Tuple[Root, ...]
    coil_zeros: Tuple[Root, ...]
    pan_zeros: Tuple[Root, ...]
    static_gain_coil_m_per_N: float
    static_gain_pan_m_per_N: float
    static_force_ratio: float
    coil_magnitude_dB: Tuple[float, ...]


def summarize(p: MechanicalParameters, load_mass_kg: float = 0.0,
              load_changer_coupled: bool = False, label: str = '') -> ModelSummary:
    """
    Summarise the linear model of a load configuration.

    Parameters
    ----------
    p : MechanicalParameters
        The mechanics of the empty, uncoupled balance.
    load_mass_kg : float
        Mass on the pan [kg].
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan.
    label : str
        Name of the configuration.

    Returns
    -------
    ModelSummary
        The summary.
    """
    mech = loaded(p, load_mass_kg, load_changer_coupled)
    model = linearise(mech)
    g_coil = model.static_gain_m_per_N('coil')
    g_pan = model.static_gain_m_per_N('pan')
    mag = model.frequency_response(SUMMARY_FREQUENCIES_HZ, 'coil').magnitude_dB
    return ModelSummary(label, mech.mp_kg, model, model.poles(), model.zeros('coil'),
                        model.zeros('pan'), g_coil, g_pan, g_pan / g_coil,
                        tuple(float(v) for v in mag))


def _roots_text(roots: Iterable[Root], with_damping: bool) -> str:
    parts = []
    for r in roots:
        if r.is_real:
            parts.append(f'{r.signed_frequency_Hz:.1f} Hz (real)')
        elif r.s_rad_per_s.imag > 0.0:
            text = f'{r.frequency_Hz:.2f} Hz'
            if with_damping:
                text += f' (zeta {r.damping_ratio:.4f})'
            parts.append(text)
    return ', '.join(parts)


def format_summaries(summaries: Sequence[ModelSummary]) -> str:
    """
    Format summaries as a Markdown table plus gains.

    Parameters
    ----------
    summaries : sequence of ModelSummary
        The summaries.

    Returns
    -------
    str
        The text.
    """
    lines = ['| configuration | pan mass [kg] | poles | coil input: zeros | pan input: zeros |',
             '|---|---|---|---|---|']
    for s in summaries:
        lines.append(f'| {s.label} | {s.pan_mass_kg:.3f} | {_roots_text(s.poles, True)} | '
                     f'{_roots_text(s.coil_zeros, True)} | {_roots_text(s.pan_zeros, False)} |')
    lines.append('')
    freqs = ' / '.join(f'{f:g}' for f in SUMMARY_FREQUENCIES_HZ)
    for s in summaries:
        mags = ' / '.join(f'{m:.1f}' for m in s.coil_magnitude_dB)
        lines.append(f'- {s.label}: coil input magnitude at {freqs} Hz: {mags} dB re 1 m/N; '
                     f'static gains coil {20 * np.log10(abs(s.static_gain_coil_m_per_N)):.2f} '
                     f'dB, pan {20 * np.log10(abs(s.static_gain_pan_m_per_N)):.2f} dB; '
                     f'static force ratio {s.static_force_ratio:.5f}')
    return '\n'.join(lines)


def notes_summaries(params: Optional[BalanceParameters] = None) -> List[ModelSummary]:
    """
    Summaries for the notes' three configurations.

    Parameters
    ----------
    params : BalanceParameters, optional
        The parameters (default: the defaults).

    Returns
    -------
    list of ModelSummary
        Empty pan, load changer coupled, 100 g on the pan.
    """
    mech = (params or BalanceParameters()).mechanics
    return [summarize(mech, load, coupled, label)
            for label, load, coupled in NOTES_CONFIGURATIONS]


def main(argv: Optional[Sequence[str]] = None) -> int:
    """
    Print the summary table of the notes' configurations.

    Parameters
    ----------
    argv : sequence of str, optional
        Command-line arguments (``--config FILE``).

    Returns
    -------
    int
        Exit status.
    """
    parser = argparse.ArgumentParser(description='Poles, zeros and gains of the balance model.')
    parser.add_argument('--config', help='balance parameter YAML (default: built-in defaults)')
    args = parser.parse_args(argv)
    params = BalanceParameters.load_yaml(args.config) if args.config else BalanceParameters()
    print(format_summaries(notes_summaries(params)))
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
