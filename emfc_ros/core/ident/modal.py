"""
Modal parameters (frequency and damping of complex root pairs) with propagated uncertainty.

A pole pair is parametrised in the transfer-function fit as a quadratic factor
``s~^2 + a s~ + b`` of the scaled Laplace variable ``s~ = s / w_ref``; then
``f = w_ref sqrt(b) / (2 pi)`` and ``zeta = a / (2 sqrt(b))``, and the covariance of
``(a, b)`` maps to ``(f, zeta)`` through the analytic gradients. A zero pair is a root ``z`` of
the numerator polynomial ``N(s~) = sum_k n_k s~^k``; its first-order sensitivity is
``dz / dn_k = -z^k / N'(z)``, and ``f = w_ref |z| / (2 pi)``, ``zeta = -Re(z) / |z|``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Tuple

import numpy as np


@dataclass(frozen=True)
class Mode:
    """
    A complex root pair as natural frequency and damping ratio, with standard deviations.

    Attributes
    ----------
    frequency_Hz : float
        Natural frequency ``|s| / 2 pi`` [Hz].
    damping_ratio : float
        ``-Re(s) / |s|``.
    frequency_std_Hz : float
        Standard deviation of the frequency [Hz] (NaN when unknown).
    damping_std : float
        Standard deviation of the damping ratio.
    """

    frequency_Hz: float
    damping_ratio: float
    frequency_std_Hz: float = float('nan')
    damping_std: float = float('nan')

    @property
    def s_rad_per_s(self) -> complex:
        """The root with positive imaginary part [rad/s]."""
        w = 2.0 * np.pi * self.frequency_Hz
        z = self.damping_ratio
        return complex(-z * w, w * np.sqrt(max(1.0 - z * z, 0.0)))

    def __str__(self) -> str:
        return (f'{self.frequency_Hz:.5g} +/- {self.frequency_std_Hz:.2g} Hz, zeta '
                f'{self.damping_ratio:.4g} +/- {self.damping_std:.2g}')


def quadratic_mode(a: float, b: float, covariance: np.ndarray,
                   reference_rad_per_s: float) -> Mode:
    """
    Mode of the factor ``s~^2 + a s~ + b`` (``s~ = s / w_ref``) with propagated covariance.

    Parameters
    ----------
    a, b : float
        Factor coefficients (``a^2 < 4 b`` for a complex pair).
    covariance : ndarray, shape (2, 2)
        Covariance of ``(a, b)``.
    reference_rad_per_s : float
        ``w_ref`` [rad/s].

    Returns
    -------
    Mode
        Frequency and damping with standard deviations.
    """
    rb = np.sqrt(b)
    f = reference_rad_per_s * rb / (2.0 * np.pi)
    zeta = a / (2.0 * rb)
    g_f = np.array([0.0, reference_rad_per_s / (4.0 * np.pi * rb)])
    g_z = np.array([1.0 / (2.0 * rb), -a / (4.0 * b * rb)])
    cov = np.asarray(covariance, dtype=float)
    return Mode(float(f), float(zeta), float(np.sqrt(max(g_f @ cov @ g_f, 0.0))),
                float(np.sqrt(max(g_z @ cov @ g_z, 0.0))))


def root_modes(coefficients: np.ndarray, covariance: np.ndarray,
               reference_rad_per_s: float) -> Tuple[Mode, ...]:
    """
    Modes of the complex root pairs of a polynomial with coefficient covariance.

    Parameters
    ----------
    coefficients : ndarray
        ``n_0 .. n_m`` of ``N(s~) = sum_k n_k s~^k`` (ascending powers, scaled variable).
    covariance : ndarray, shape (m + 1, m + 1)
        Covariance of the coefficients.
    reference_rad_per_s : float
        ``w_ref`` [rad/s].

    Returns
    -------
    tuple of Mode
        One per root with positive imaginary part, sorted by frequency.
    """
    c = np.asarray(coefficients, dtype=float)
    cov = np.asarray(covariance, dtype=float)
    if c.size < 3:
        return ()
    roots = np.roots(c[::-1])
    dpoly = np.polyder(c[::-1])
    modes = []
    for z in roots:
        if z.imag <= 1e-12 * abs(z):
            continue
        g = -(z ** np.arange(c.size)) / np.polyval(dpoly, z)      # dz / dn_k
        x, y, r = z.real, z.imag, abs(z)
        g_f = (reference_rad_per_s / (2.0 * np.pi)) * (x * g.real + y * g.imag) / r
        g_z = (-(y * y) * g.real + x * y * g.imag) / r ** 3
        modes.append(Mode(float(reference_rad_per_s * r / (2.0 * np.pi)), float(-x / r),
                          float(np.sqrt(max(g_f @ cov @ g_f, 0.0))),
                          float(np.sqrt(max(g_z @ cov @ g_z, 0.0)))))
    return tuple(sorted(modes, key=lambda m: m.frequency_Hz))
