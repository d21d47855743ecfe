"""
Known discrete test systems shared by the identification tests (analytic ground truth).

Second-order sections from continuous modes by the bilinear transform with prewarping at the
mode, so the discrete resonance sits exactly at the continuous one.
"""

import numpy as np
from scipy import signal

FS_HZ = 1000.0


def mode(f0_Hz, zeta, fs_Hz=FS_HZ, gain=1.0):
    """Return (b, a) of ``gain w0^2 / (s^2 + 2 zeta w0 s + w0^2)`` discretised bilinearly."""
    w0 = 2.0 * fs_Hz * np.tan(np.pi * f0_Hz / fs_Hz)   # prewarped
    return signal.bilinear([gain * w0 ** 2], [1.0, 2.0 * zeta * w0, w0 ** 2], fs=fs_Hz)


def second_order(fs_Hz=FS_HZ):
    """Return the lightly damped 2nd-order system: 50 Hz, zeta 0.05, unit static gain."""
    return mode(50.0, 0.05, fs_Hz)


def two_mode(fs_Hz=FS_HZ):
    """Return the 4th-order system: modes at 40 Hz (zeta 0.03) and 180 Hz (0.05) in parallel."""
    b1, a1 = mode(40.0, 0.03, fs_Hz)
    b2, a2 = mode(180.0, 0.05, fs_Hz, gain=0.5)
    b = np.polyadd(np.polymul(b1, a2), np.polymul(b2, a1))
    return b, np.polymul(a1, a2)


def response(ba, frequency_Hz, fs_Hz=FS_HZ):
    """Exact complex response of (b, a) at the frequencies."""
    return signal.freqz(ba[0], ba[1], worN=np.asarray(frequency_Hz), fs=fs_Hz)[1]


def simulate(ba, u):
    """Zero-state response of (b, a) to u."""
    return signal.lfilter(ba[0], ba[1], u)


def test_modes_resonate_where_designed():
    """The prewarped bilinear modes peak (phase -90 deg) at their continuous frequencies."""
    for f0, zeta in ((50.0, 0.05), (180.0, 0.05)):
        h = response(mode(f0, zeta), [f0])[0]
        np.testing.assert_allclose(np.angle(h), -np.pi / 2.0, atol=1e-9)
        np.testing.assert_allclose(abs(h), 1.0 / (2.0 * zeta), rtol=1e-9)
