"""
The device's own function generator: sine, chirp or PRBS per output channel, gain and offset.

Like the FPGA generator of the paper (section 2.3.2), it runs on the device's sample clock:
output channel ``j`` at device sample index ``k`` (counted from START) is
``gain * waveform(k) + offset_V``, then clamped to the channel's limits by the device. The
waveforms are those of :mod:`emfc_ros.core.signals`, so any split into blocks gives the same
samples.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Optional, Sequence

import numpy as np

from emfc_ros.core.device.errors import DeviceConfigError
from emfc_ros.core.errors import SignalError
from emfc_ros.core.signals import Chirp, Prbs, Signal, Sine

#: Waveform names in protocol code order (code = index).
WAVEFORMS = ('off', 'sine', 'chirp', 'prbs', 'constant')
#: Chirp frequency laws in protocol code order.
CHIRP_METHODS = ('linear', 'logarithmic')
#: Largest |gain * amplitude_V| and |offset_V| a generator accepts [V]: ten times the usual
#: +/-10 V output range, to refuse values that can only be typing errors.
MAX_GENERATOR_V = 100.0


@dataclasses.dataclass(frozen=True)
class GeneratorSpec:
    """
    What the function generator drives on one output channel.

    Attributes
    ----------
    waveform : str
        ``'off'`` (the channel follows the host's setpoint stream), ``'sine'``, ``'chirp'``,
        ``'prbs'`` or ``'constant'`` (just ``offset_V``).
    amplitude_V : float
        Peak amplitude (PRBS: levels ``-amplitude_V`` and ``+amplitude_V``) [V].
    frequency_Hz : float
        Sine frequency, or chirp start frequency [Hz].
    f_stop_Hz : float
        Chirp stop frequency [Hz].
    sweep_time_s : float
        Duration of one chirp sweep [s] (sweeps repeat with continuous phase).
    method : str
        Chirp law, ``'linear'`` or ``'logarithmic'``.
    phase_rad : float
        Phase at sample 0 (sine, chirp) [rad].
    prbs_order : int
        PRBS register length, 2..31.
    prbs_hold_samples : int
        Samples per PRBS bit, >= 1.
    gain : float
        Signal matching gain (dimensionless).
    offset_V : float
        Signal matching offset [V].
    """

    waveform: str = 'off'
    amplitude_V: float = 0.0
    frequency_Hz: float = 0.0
    f_stop_Hz: float = 0.0
    sweep_time_s: float = 1.0
    method: str = 'logarithmic'
    phase_rad: float = 0.0
    prbs_order: int = 10
    prbs_hold_samples: int = 1
    gain: float = 1.0
    offset_V: float = 0.0

    def __post_init__(self) -> None:
        if self.waveform not in WAVEFORMS:
            raise DeviceConfigError(f'waveform must be one of {WAVEFORMS}, got '
                                    f'{self.waveform!r}')
        if self.method not in CHIRP_METHODS:
            raise DeviceConfigError(f'method must be one of {CHIRP_METHODS}, got '
                                    f'{self.method!r}')
        for name in ('amplitude_V', 'frequency_Hz', 'f_stop_Hz', 'sweep_time_s', 'phase_rad',
                     'gain', 'offset_V'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                    not math.isfinite(value):
                raise DeviceConfigError(f'{name} must be a finite number, got {value!r}')
        if abs(self.gain * self.amplitude_V) > MAX_GENERATOR_V or \
                abs(self.offset_V) > MAX_GENERATOR_V:
            raise DeviceConfigError(
                f'gain * amplitude_V ({self.gain * self.amplitude_V:g} V) and offset_V '
                f'({self.offset_V:g} V) must be within +/-{MAX_GENERATOR_V:g} V (a sanity '
                'bound; the outputs are clamped to their limits anyway)')

    @property
    def active(self) -> bool:
        """
        Whether the generator drives the channel.

        Returns
        -------
        bool
            False for ``'off'`` (the channel follows the setpoint stream).
        """
        return self.waveform != 'off'


def make_signal(spec: GeneratorSpec, sample_rate_Hz: float) -> Optional[Signal]:
    """
    Build the waveform of a generator spec (before gain and offset).

    Parameters
    ----------
    spec : GeneratorSpec
        The spec.
    sample_rate_Hz : float
        The device's sample rate [Hz].

    Returns
    -------
    Signal or None
        The waveform; None for ``'off'`` and ``'constant'``.

    Raises
    ------
    DeviceConfigError
        If the signal cannot be built (frequency above Nyquist, bad PRBS order...).
    """
    try:
        if spec.waveform == 'sine':
            return Sine(spec.amplitude_V, spec.frequency_Hz, spec.phase_rad, sample_rate_Hz)
        if spec.waveform == 'chirp':
            return Chirp(spec.amplitude_V, spec.frequency_Hz, spec.f_stop_Hz,
                         spec.sweep_time_s, sample_rate_Hz, method=spec.method,
                         phase_rad=spec.phase_rad)
        if spec.waveform == 'prbs':
            return Prbs(spec.prbs_order, spec.prbs_hold_samples, -spec.amplitude_V,
                        spec.amplitude_V, sample_rate_Hz)
    except (SignalError, TypeError, ValueError) as exc:
        raise DeviceConfigError(f'function generator ({spec.waveform}): {exc}') from exc
    return None


class FunctionGenerator:
    """
    One generator spec per output channel, evaluated on the device's sample clock.

    Parameters
    ----------
    specs : sequence of GeneratorSpec
        One per output channel.
    sample_rate_Hz : float
        The device's sample rate [Hz].
    """

    def __init__(self, specs: Sequence[GeneratorSpec], sample_rate_Hz: float) -> None:
        self.specs = tuple(specs)
        self.sample_rate_Hz = float(sample_rate_Hz)
        self._signals = [make_signal(s, self.sample_rate_Hz) for s in self.specs]

    def active(self, channel: int) -> bool:
        """
        Whether the generator drives an output channel.

        Parameters
        ----------
        channel : int
            Output channel index.

        Returns
        -------
        bool
            True unless the channel's waveform is ``'off'``.
        """
        return self.specs[channel].active

    def samples(self, channel: int, first_sample_index: int, n: int) -> np.ndarray:
        """
        Generator output of one channel for ``n`` samples.

        Parameters
        ----------
        channel : int
            Output channel index.
        first_sample_index : int
            Device sample index of the first sample.
        n : int
            Samples.

        Returns
        -------
        numpy.ndarray
            ``gain * waveform(k) + offset_V`` [V], shape ``(n,)``.
        """
        spec = self.specs[channel]
        signal = self._signals[channel]
        if signal is None:
            return np.full(n, spec.offset_V)
        k = np.arange(first_sample_index, first_sample_index + n, dtype=np.int64)
        return spec.gain * signal.samples(k) + spec.offset_V
