"""
Linear and logarithmic chirps with an analytic, exactly continuous phase.

With ``t = k / fs`` and sweep time ``T`` the phase (in cycles) of one sweep is

* linear: ``Phi(t) = f0 t + (f1 - f0) t^2 / (2 T)``
* logarithmic: ``Phi(t) = f0 beta (exp(t / beta) - 1)`` with ``beta = T / ln(f1 / f0)``

so the instantaneous frequency ``dPhi/dt`` runs from ``f0`` to ``f1``. When the sweep repeats,
the phase continues: ``phase(t) = n Phi(T) + Phi(t mod T)`` with ``n = floor(t / T)``, so there
is no jump in the signal at the restart (only in its frequency). The output is
``amplitude_V * sin(2 pi phase + phase_rad)``, starting at 0 V for ``phase_rad = 0``.
"""

from __future__ import annotations

import math

import numpy as np

from emfc_ros.core.errors import SignalError
from emfc_ros.core.signals.base import as_index, check_finite, check_frequency, check_rate

TWO_PI = 2.0 * np.pi
METHODS = ('linear', 'logarithmic')
AFTER_SWEEP = ('repeat', 'zero')


class Chirp:
    """
    A frequency sweep from ``f_start_Hz`` to ``f_stop_Hz`` over ``sweep_time_s``.

    Parameters
    ----------
    amplitude_V : float
        Peak amplitude.
    f_start_Hz, f_stop_Hz : float
        Start and stop frequencies in (0, fs/2] (either order; equal gives a sine).
    sweep_time_s : float
        Duration of one sweep, > 0.
    sample_rate_Hz : float
        Sample rate.
    method : {'linear', 'logarithmic'}
        Frequency law.
    after_sweep : {'repeat', 'zero'}
        Sweep again with continuous phase, or output 0 V once ``t >= sweep_time_s``.
    phase_rad : float
        Phase offset at t = 0.
    """

    def __init__(self, amplitude_V: float, f_start_Hz: float, f_stop_Hz: float,
                 sweep_time_s: float, sample_rate_Hz: float = 10000.0,
                 method: str = 'logarithmic', after_sweep: str = 'repeat',
                 phase_rad: float = 0.0) -> None:
        self.sample_rate_Hz = check_rate(sample_rate_Hz)
        self.amplitude_V = check_finite('amplitude_V', amplitude_V)
        self.f_start_Hz = check_frequency('f_start_Hz', f_start_Hz, self.sample_rate_Hz,
                                          positive=True)
        self.f_stop_Hz = check_frequency('f_stop_Hz', f_stop_Hz, self.sample_rate_Hz,
                                         positive=True)
        self.sweep_time_s = check_finite('sweep_time_s', sweep_time_s)
        if self.sweep_time_s <= 0.0:
            raise SignalError(f'sweep_time_s must be > 0, got {sweep_time_s!r}')
        if method not in METHODS:
            raise SignalError(f'method must be one of {list(METHODS)}, got {method!r}')
        if after_sweep not in AFTER_SWEEP:
            raise SignalError(f'after_sweep must be one of {list(AFTER_SWEEP)}, '
                              f'got {after_sweep!r}')
        self.method = method
        self.after_sweep = after_sweep
        self.phase_rad = check_finite('phase_rad', phase_rad)
        f0, f1, T = self.f_start_Hz, self.f_stop_Hz, self.sweep_time_s
        self._log = method == 'logarithmic' and f0 != f1
        if self._log:
            self._beta_s = T / math.log(f1 / f0)
        else:
            self._rate_Hz_per_s = (f1 - f0) / T
        whole = float(self.phase_cycles(np.array([T]))[0]) if after_sweep == 'repeat' else 0.0
        self._cycles_per_sweep_frac = whole - math.floor(whole)

    def phase_cycles(self, tau_s: np.ndarray) -> np.ndarray:
        """
        Phase of one sweep, ``Phi(tau)``, in cycles.

        Parameters
        ----------
        tau_s : numpy.ndarray
            Time since the start of the sweep, in [0, sweep_time_s].

        Returns
        -------
        numpy.ndarray
            The phase in cycles (not reduced).
        """
        tau_s = np.asarray(tau_s, dtype=np.float64)
        if self._log:
            return self.f_start_Hz * self._beta_s * np.expm1(tau_s / self._beta_s)
        return tau_s * (self.f_start_Hz + 0.5 * self._rate_Hz_per_s * tau_s)

    def frequency_Hz(self, t_s: np.ndarray) -> np.ndarray:
        """
        Instantaneous frequency specified at time ``t`` since the start.

        Parameters
        ----------
        t_s : numpy.ndarray
            Times in s, >= 0.

        Returns
        -------
        numpy.ndarray
            Frequency in Hz (0 after the sweep when ``after_sweep == 'zero'``).
        """
        t_s = np.asarray(t_s, dtype=np.float64)
        n = np.floor(t_s / self.sweep_time_s)
        tau_s = t_s - n * self.sweep_time_s
        if self._log:
            f = self.f_start_Hz * np.exp(tau_s / self._beta_s)
        else:
            f = self.f_start_Hz + self._rate_Hz_per_s * tau_s
        if self.after_sweep == 'zero':
            f = np.where(n >= 1, 0.0, f)
        return f

    def samples(self, k: np.ndarray) -> np.ndarray:
        """
        Evaluate the chirp at local sample indices.

        Parameters
        ----------
        k : numpy.ndarray
            int64 sample indices >= 0.

        Returns
        -------
        numpy.ndarray
            float64 samples, same shape as ``k``.
        """
        k = as_index(k)
        t_s = k / self.sample_rate_Hz
        n = np.floor(t_s / self.sweep_time_s)
        tau_s = t_s - n * self.sweep_time_s
        cycles = self.phase_cycles(tau_s)
        if self.after_sweep == 'repeat':
            # n Phi(T) mod 1 from the fractional part of Phi(T): stays exact for large n
            extra = n * self._cycles_per_sweep_frac
            extra -= np.floor(extra)
            cycles += extra
        cycles -= np.floor(cycles)
        cycles *= TWO_PI
        cycles += self.phase_rad
        out = np.sin(cycles, out=cycles)
        out *= self.amplitude_V
        if self.after_sweep == 'zero':
            out[n >= 1] = 0.0
        return out

    def __repr__(self) -> str:
        return (f'Chirp(amplitude_V={self.amplitude_V!r}, f_start_Hz={self.f_start_Hz!r}, '
                f'f_stop_Hz={self.f_stop_Hz!r}, sweep_time_s={self.sweep_time_s!r}, '
                f'sample_rate_Hz={self.sample_rate_Hz!r}, method={self.method!r}, '
                f'after_sweep={self.after_sweep!r})')
