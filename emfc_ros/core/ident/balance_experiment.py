"""
Simulated identification experiments on the balance: the recording the pipeline expects.

Used by the accuracy tests and benchmarks of :mod:`emfc_ros.core.ident.pipeline`, and handy for
trying a trajectory before running it on the real balance. The experiment is played through the
:class:`~emfc_ros.core.sim.Simulator` with the pan loaded by the balancing mass (the mass whose
weight the lever holds at ``y = 0`` with 0 V on the coil, as the paper loaded the pan with mass
pieces), so that 0 V on both amplifiers is the operating point.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, List, Mapping, Optional, Tuple

import numpy as np
from scipy import optimize

from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.signals.experiment import ChannelPlan, Experiment, Section
from emfc_ros.core.sim import hold_point, Simulator

#: Gains (``channel`` or ``section.channel`` keys) applied to the shipped trajectory
#: (config/identification_trajectory.yaml). Empty: its amplitudes (2.5 mV and 1.5 mV on the
#: coil) already keep the default balance, loaded with the balancing mass, inside the sensor
#: range (+/-100 um); they were set from this module's earlier gains 0.25, 0.3 and 0.75 on
#: 10 mV, 5 mV and 2 mV. See docs/identification_results.md for the peaks.
DEFAULT_TRAJECTORY_GAINS: dict = {}

#: Block size of the simulation [samples].
BLOCK_SAMPLES = 100000


@dataclass(frozen=True)
class SectionSpan:
    """
    One row of the section table as the signal generator publishes it.

    Attributes
    ----------
    name : str
        Section name.
    first_sample_index : int
        Index of its first sample in the recording.
    n_samples : int
        Its length in samples.
    """

    name: str
    first_sample_index: int
    n_samples: int


@dataclass
class SimulatedRecording:
    """
    A simulated experiment: channels on one clock, the section table and the configuration.

    Attributes
    ----------
    channels : dict of str to ndarray
        Every simulator output channel by name (units in the names).
    sample_rate_Hz : float
        Sample rate [Hz].
    sections : list of SectionSpan
        The section table.
    load_mass_kg : float
        Mass on the pan during the experiment [kg].
    load_changer_coupled : bool
        Whether the load changer's moving mass rode on the pan.
    gains : dict of str to float
        Channel gains applied to the experiment.
    """

    channels: Dict[str, np.ndarray]
    sample_rate_Hz: float
    sections: List[SectionSpan]
    load_mass_kg: float
    load_changer_coupled: bool
    gains: Dict[str, float] = field(default_factory=dict)


def balancing_mass_kg(params: BalanceParameters, load_changer_coupled: bool = True) -> float:
    """
    Mass on the pan that the balance holds at ``y = 0`` with 0 V on the coil.

    Parameters
    ----------
    params : BalanceParameters
        The balance.
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan (it then counts).

    Returns
    -------
    float
        The mass [kg] (about 0.1274 kg uncoupled, 0.1024 kg coupled, with the defaults).

    Raises
    ------
    ValueError
        If no mass in [0, 0.5] kg does it.
    """
    def coil_V(m: float) -> float:
        return float(hold_point(params, m, load_changer_coupled).setpoints_V[0])

    hi = 0.5
    try:
        if coil_V(0.0) * coil_V(hi) > 0.0:
            raise ValueError
    except ValueError:
        raise ValueError(f'no balancing mass between 0 and {hi} kg within the coil current '
                         f'limit') from None
    return float(optimize.brentq(coil_V, 0.0, hi, xtol=1e-12))


def scaled_experiment(experiment: Experiment, gains: Mapping[str, float],
                      sections: Optional[Mapping[str, int]] = None) -> Experiment:
    """
    Copy an experiment with every channel's gain multiplied and optionally shortened sections.

    Parameters
    ----------
    experiment : Experiment
        The experiment (e.g. from :func:`~emfc_ros.core.signals.load_experiment_file`).
    gains : mapping of str to float
        Factor per channel (key ``channel``) or per channel of one section (key
        ``section.channel``, which wins); absent channels keep their gain.
    sections : mapping of str to int, optional
        New lengths [samples] of some sections (the signals are cut, not re-timed).

    Returns
    -------
    Experiment
        The modified copy.
    """
    new = []
    lengths = dict(sections or {})
    for sec in experiment.sections:
        plans = {}
        for ch, plan in sec.channels.items():
            g = float(gains.get(f'{sec.name}.{ch}', gains.get(ch, 1.0)))
            plans[ch] = ChannelPlan(plan.signals, plan.gain * g, plan.offset_V * g)
        new.append(Section(sec.name, int(lengths.get(sec.name, sec.n_samples)), plans))
    return Experiment(new, experiment.sample_rate_Hz, experiment.channels, experiment.limits)


def simulate_experiment(params: BalanceParameters, experiment: Experiment, *, seed: int = 1,
                        load_mass_kg: Optional[float] = None, load_changer_coupled: bool = True,
                        noise: bool = True, quantisation: bool = True,
                        lead_in_s: float = 0.0) -> SimulatedRecording:
    """
    Play an experiment through the simulated balance.

    Parameters
    ----------
    params : BalanceParameters
        The balance (the truth).
    experiment : Experiment
        Setpoints of the ``coil`` and ``load_changer`` channels.
    seed : int
        Noise seed.
    load_mass_kg : float, optional
        Mass on the pan [kg]; default :func:`balancing_mass_kg`.
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan.
    noise, quantisation : bool
        Simulator realism switches.
    lead_in_s : float
        Time at rest (hold setpoints) recorded before the first section [s].

    Returns
    -------
    SimulatedRecording
        All channels, the section table (offset by the lead-in) and the configuration.
    """
    mass = balancing_mass_kg(params, load_changer_coupled) if load_mass_kg is None \
        else float(load_mass_kg)
    fs = experiment.sample_rate_Hz
    sim = Simulator(params, fs, seed, noise=noise, quantisation=quantisation,
                    load_mass_kg=mass, load_changer_coupled=load_changer_coupled)
    lead = int(round(lead_in_s * fs))
    rows = [experiment.channels.index(c) for c in ('coil', 'load_changer')]
    total = lead + experiment.total_samples
    out = np.empty((len(sim.channel_names), total))
    if lead:
        out[:, :lead] = sim.step_block(np.repeat(sim.hold_setpoints_V[:, None], lead, axis=1))
    for first in range(0, experiment.total_samples, BLOCK_SAMPLES):
        n = min(BLOCK_SAMPLES, experiment.total_samples - first)
        out[:, lead + first:lead + first + n] = sim.step_block(experiment.block(first, n)[rows])
    spans = [SectionSpan(s.name, lead + int(b), s.n_samples)
             for s, b in zip(experiment.sections, experiment.boundaries[:-1])]
    gains = {}
    for sec in experiment.sections:
        for ch, plan in sec.channels.items():
            gains.setdefault(ch, plan.gain)
    return SimulatedRecording(dict(zip(sim.channel_names, out)), fs, spans, mass,
                              load_changer_coupled, gains)


def section_table(recording: SimulatedRecording) -> List[Tuple[str, int, int]]:
    """
    Return the section table as plain ``(name, first_sample_index, n_samples)`` tuples.

    Parameters
    ----------
    recording : SimulatedRecording
        The recording.

    Returns
    -------
    list of tuple
        One row per section.
    """
    return [(s.name, s.first_sample_index, s.n_samples) for s in recording.sections]


_TIME_KEYS = ('duration_s', 'sweep_time_s', 'times_s')


def time_scaled_mapping(mapping: Mapping, factor: float) -> dict:
    """
    Copy an experiment mapping with every duration, sweep time and step time scaled.

    Shortens a trajectory for quick tests while keeping its frequency band: a chirp of
    ``5 Hz -> 2 kHz`` over 10 s becomes the same sweep over ``10 factor`` s.

    Parameters
    ----------
    mapping : Mapping
        The ``experiment`` mapping (e.g. from
        :func:`~emfc_ros.core.signals.find_experiment_mapping`).
    factor : float
        Time factor (> 0).

    Returns
    -------
    dict
        The scaled deep copy.
    """
    def walk(value):
        if isinstance(value, Mapping):
            out = {}
            for k, v in value.items():
                if k in _TIME_KEYS and isinstance(v, (int, float)):
                    out[k] = float(v) * factor
                elif k in _TIME_KEYS and isinstance(v, (list, tuple)):
                    out[k] = [float(t) * factor for t in v]
                else:
                    out[k] = walk(v)
            return out
        if isinstance(value, (list, tuple)):
            return [walk(v) for v in value]
        return value

    return walk(mapping)
