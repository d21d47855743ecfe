"""
Experiments: named sections in sequence, each driving the setpoint channels.

Within a section every channel sums its signals (sorted by name, for determinism), applies
``gain * sum + offset_V`` (signal matching) and clamps to the channel's limits. A signal sees
the local index ``k - section_start``. A channel absent from a section, and every channel past
the end of the experiment, outputs its safe value: 0 V clamped to its limits.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Dict, Mapping, Optional, Sequence, Tuple

import numpy as np

from emfc_ros.core.errors import BlockError, SignalError
from emfc_ros.core.signals.base import check_rate, Signal

#: Setpoint voltages of the two power amplifiers, V.
DEFAULT_CHANNELS = ('coil', 'load_changer')
DEFAULT_LIMITS_V = (-10.0, 10.0)


@dataclass(frozen=True)
class ChannelLimits:
    """
    Clamping range of a channel.

    Attributes
    ----------
    min_V, max_V : float
        Inclusive bounds, ``min_V <= max_V``.
    """

    min_V: float = DEFAULT_LIMITS_V[0]
    max_V: float = DEFAULT_LIMITS_V[1]

    def __post_init__(self) -> None:
        if not (math.isfinite(self.min_V) and math.isfinite(self.max_V)) or \
                self.min_V > self.max_V:
            raise SignalError(f'limits need finite min_V <= max_V, got [{self.min_V!r}, '
                              f'{self.max_V!r}]')

    @property
    def safe_V(self) -> float:
        """0 V clamped to the limits."""
        return min(max(0.0, self.min_V), self.max_V)


@dataclass(frozen=True)
class ChannelPlan:
    """
    What one channel does during one section.

    Attributes
    ----------
    signals : Mapping[str, Signal]
        Named signals, summed in sorted-name order.
    gain : float
        Dimensionless factor applied to the sum.
    offset_V : float
        Added after the gain.
    """

    signals: Mapping[str, Signal] = field(default_factory=dict)
    gain: float = 1.0
    offset_V: float = 0.0

    def evaluate(self, k: np.ndarray) -> np.ndarray:
        """
        ``gain * sum(signals) + offset_V`` at local indices (not clamped).

        Parameters
        ----------
        k : numpy.ndarray
            int64 local sample indices >= 0.

        Returns
        -------
        numpy.ndarray
            float64 samples.
        """
        names = sorted(self.signals)
        if not names:
            out = np.zeros(k.shape)
        else:
            out = np.array(self.signals[names[0]].samples(k), dtype=np.float64, copy=True)
            for name in names[1:]:
                out += self.signals[name].samples(k)
        out *= self.gain
        out += self.offset_V
        return out


@dataclass(frozen=True)
class Section:
    """
    A named stretch of the experiment.

    Attributes
    ----------
    name : str
        Section name.
    n_samples : int
        Length in samples (>= 1).
    channels : Mapping[str, ChannelPlan]
        Plans of the channels that are driven; others output their safe value.
    """

    name: str
    n_samples: int
    channels: Mapping[str, ChannelPlan] = field(default_factory=dict)

    @classmethod
    def from_duration(cls, name: str, duration_s: float, sample_rate_Hz: float,
                      channels: Mapping[str, ChannelPlan]) -> 'Section':
        """
        Build a section of ``round(duration_s * sample_rate_Hz)`` samples.

        Parameters
        ----------
        name : str
            Section name.
        duration_s : float
            Duration.
        sample_rate_Hz : float
            Sample rate.
        channels : Mapping[str, ChannelPlan]
            Channel plans.

        Returns
        -------
        Section
            The section.
        """
        return cls(name, int(round(duration_s * sample_rate_Hz)), dict(channels))


class Experiment:
    """
    Sections in sequence on a set of channels.

    Parameters
    ----------
    sections : sequence of Section
        The sections, played in order.
    sample_rate_Hz : float
        Sample rate; every signal must have been built for it.
    channels : sequence of str
        Channel names; rows of :meth:`block` follow this order.
    limits : Mapping[str, ChannelLimits], optional
        Per-channel clamping; absent channels get -10..10 V.
    """

    def __init__(self, sections: Sequence[Section], sample_rate_Hz: float,
                 channels: Sequence[str] = DEFAULT_CHANNELS,
                 limits: Optional[Mapping[str, ChannelLimits]] = None) -> None:
        self.sample_rate_Hz = check_rate(sample_rate_Hz)
        self.channels: Tuple[str, ...] = tuple(channels)
        if not self.channels or len(set(self.channels)) != len(self.channels):
            raise SignalError(f'channels must be distinct and non-empty, got {channels!r}')
        limits = dict(limits or {})
        for name in limits:
            if name not in self.channels:
                raise SignalError(f'limits for unknown channel {name!r}')
        self.limits: Dict[str, ChannelLimits] = {
            name: limits.get(name, ChannelLimits()) for name in self.channels}
        self.sections: Tuple[Section, ...] = tuple(sections)
        if not self.sections:
            raise SignalError('an experiment needs at least one section')
        names = [s.name for s in self.sections]
        if len(set(names)) != len(names):
            raise SignalError(f'section names must be distinct, got {names}')
        for section in self.sections:
            if section.n_samples < 1:
                raise SignalError(f'section {section.name!r} has {section.n_samples} samples')
            for channel, plan in section.channels.items():
                if channel not in self.channels:
                    raise SignalError(f'section {section.name!r} drives unknown channel '
                                      f'{channel!r}; channels are {list(self.channels)}')
                for sig_name, sig in plan.signals.items():
                    rate = float(sig.sample_rate_Hz)
                    if abs(rate - self.sample_rate_Hz) > 1e-9 * self.sample_rate_Hz:
                        raise SignalError(f'signal {section.name}.{channel}.{sig_name} is '
                                          f'built for {rate!r} Hz, the experiment runs at '
                                          f'{self.sample_rate_Hz!r} Hz')
        lengths = np.array([s.n_samples for s in self.sections], dtype=np.int64)
        self.boundaries = np.concatenate(([0], np.cumsum(lengths))).astype(np.int64)
        self.total_samples = int(self.boundaries[-1])
        self.safe_V = np.array([self.limits[c].safe_V for c in self.channels])
        self._min_V = np.array([self.limits[c].min_V for c in self.channels])[:, None]
        self._max_V = np.array([self.limits[c].max_V for c in self.channels])[:, None]

    @property
    def n_channels(self) -> int:
        """Number of channels."""
        return len(self.channels)

    @property
    def duration_s(self) -> float:
        """Total duration in s."""
        return self.total_samples / self.sample_rate_Hz

    def section_start(self, index: int) -> int:
        """
        First sample of a section.

        Parameters
        ----------
        index : int
            Section index.

        Returns
        -------
        int
            Its first global sample index.
        """
        return int(self.boundaries[index])

    def section_index_at(self, k: int) -> int:
        """
        Find the index of the section holding global sample ``k``.

        Parameters
        ----------
        k : int
            Global sample index >= 0.

        Returns
        -------
        int
            The section index, or -1 past the end.
        """
        if k < 0:
            raise BlockError(f'sample index must be >= 0, got {k}')
        if k >= self.total_samples:
            return -1
        return int(np.searchsorted(self.boundaries, k, side='right')) - 1

    def section_at(self, k: int) -> Optional[Section]:
        """
        Find the section holding global sample ``k``.

        Parameters
        ----------
        k : int
            Global sample index >= 0.

        Returns
        -------
        Section or None
            The section, or None past the end.
        """
        index = self.section_index_at(k)
        return None if index < 0 else self.sections[index]

    def block(self, first_sample_index: int, n: int) -> np.ndarray:
        """
        Generate samples ``first_sample_index .. first_sample_index + n - 1`` of all channels.

        Parameters
        ----------
        first_sample_index : int
            Global index of the first sample, >= 0.
        n : int
            Number of samples, >= 0.

        Returns
        -------
        numpy.ndarray
            float64 array of shape (n_channels, n), channel-major; past the end each channel
            holds its safe value.

        Raises
        ------
        BlockError
            If the index or count is negative.
        """
        first = int(first_sample_index)
        n = int(n)
        if first < 0 or n < 0:
            raise BlockError(f'block needs first_sample_index >= 0 and n >= 0, got '
                             f'{first_sample_index}, {n}')
        out = np.empty((len(self.channels), n))
        stop = first + n
        pos = first
        if pos < self.total_samples:
            index = int(np.searchsorted(self.boundaries, pos, side='right')) - 1
            while pos < stop and index < len(self.sections):
                start = int(self.boundaries[index])
                end = min(stop, int(self.boundaries[index + 1]))
                self._fill(self.sections[index], out[:, pos - first:end - first],
                           np.arange(pos - start, end - start, dtype=np.int64))
                pos = end
                index += 1
        if pos < stop:
            out[:, pos - first:] = self.safe_V[:, None]
        return out

    def _fill(self, section: Section, view: np.ndarray, k_local: np.ndarray) -> None:
        for row, channel in enumerate(self.channels):
            plan = section.channels.get(channel)
            if plan is None:
                view[row] = self.safe_V[row]
                continue
            values = plan.evaluate(k_local)
            np.maximum(values, self._min_V[row, 0], out=values)
            np.minimum(values, self._max_V[row, 0], out=view[row])

    def __repr__(self) -> str:
        names = ', '.join(s.name for s in self.sections)
        return (f'Experiment({len(self.sections)} sections [{names}], '
                f'{self.total_samples} samples at {self.sample_rate_Hz!r} Hz, '
                f'channels={list(self.channels)})')
