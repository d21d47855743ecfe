"""
Ground truth: the nonlinear simulator's frequency responses against the analytic linear model.

A periodic multisine (integer number of periods, transient discarded, noise and quantisation
off) drives the coil or the load changer; the FRF is the ratio of the DFT of the true lever-end
position to the DFT of the applied force at the excited lines. The simulator holds each force
over a sample (zero-order hold), so the sampled FRF is the continuous one times the hold's
``(1 - exp(-j w T)) / (j w T)`` (aliases are 80 dB down at 2 kHz).
"""

import numpy as np
import pytest

from emfc_ros.core.model import BalanceParameters, equilibrium, linearise
from emfc_ros.core.signals import Multisine
from emfc_ros.core.sim import numba_available, Simulator

pytestmark = pytest.mark.skipif(not numba_available(), reason='needs the compiled kernel')

PARAMS = BalanceParameters()
FS_HZ = 20000.0
PERIOD = 2 ** 15          # 1.64 s, lines 0.61 Hz apart
PERIODS = 6               # the first five (8.2 s, ten time constants of the 3.8 Hz mode) settle
RESOLUTION_HZ = FS_HZ / PERIOD
LINES = np.unique(np.round(np.logspace(np.log10(1.0 / RESOLUTION_HZ),
                                       np.log10(2000.0 / RESOLUTION_HZ), 80)).astype(int))


def _run(sim, path, rms_V, lines=LINES, period=PERIOD, periods=PERIODS):
    ms = Multisine(rms_V, period, sim.sample_rate_Hz, lines=lines)
    k = np.arange(period * periods)
    u = np.tile(sim.hold_setpoints_V[:, None], (1, k.size))
    u[0 if path == 'coil' else 1] += ms.samples(k)
    out = sim.step_block(u)
    spectra = {name: np.fft.rfft(out[sim.channel_names.index(name), -period:])[lines]
               for name in ('position_true_m', 'coil_force_true_N', 'pan_force_N')}
    return spectra, out


def _hold_factor(f_Hz, fs_Hz):
    wt = 2.0 * np.pi * np.asarray(f_Hz) / fs_Hz
    return (1.0 - np.exp(-1j * wt)) / (1j * wt)


def _compare(measured, model, f_Hz, exclude_Hz=None):
    keep = np.ones(f_Hz.shape, bool)
    if exclude_Hz is not None:
        keep &= np.abs(f_Hz / exclude_Hz - 1.0) > 0.02
    ratio = measured[keep] / model[keep]
    return np.abs(20.0 * np.log10(np.abs(ratio))).max(), np.abs(np.degrees(np.angle(ratio))).max()


def test_coil_path_matches_the_linear_model():
    sim = Simulator(PARAMS, FS_HZ, noise=False, quantisation=False)
    s, out = _run(sim, 'coil', 3e-4)
    assert np.abs(out[sim.channel_names.index('position_true_m')]).max() < 30e-6
    f = LINES * RESOLUTION_HZ
    model = linearise(PARAMS.mechanics)
    expected = model.frequency_response(f, 'coil').response_m_per_N * _hold_factor(f, FS_HZ)
    anti = [z.frequency_Hz for z in model.zeros('coil') if not z.is_real][0]
    db, deg = _compare(s['position_true_m'] / s['coil_force_true_N'], expected, f, anti)
    assert f.min() < 1.3 and f.max() > 1990.0 and f.size > 60
    assert db < 0.5 and deg < 3.0, (db, deg)


def test_load_changer_path_matches_the_linear_model_with_its_moving_mass():
    sim = Simulator(PARAMS, FS_HZ, noise=False, quantisation=False, load_changer_coupled=True)
    s, out = _run(sim, 'load_changer', 0.02)
    f = LINES * RESOLUTION_HZ
    pan_force = out[sim.channel_names.index('pan_force_N')]
    op = equilibrium(PARAMS.mechanics, 0.0, True, F_p_N=float(pan_force.mean()))
    model = linearise(op.mechanics, op)
    hold = _hold_factor(f, FS_HZ)
    g_pan = model.frequency_response(f, 'pan').response_m_per_N * hold
    g_coil = model.frequency_response(f, 'coil').response_m_per_N * hold
    # The coil holds the balance meanwhile and its force k(y) I follows y (0.8 % of the
    # plant's stiffness): subtract that measured input's share before dividing.
    y = s['position_true_m'] - g_coil * s['coil_force_true_N']
    db, deg = _compare(y / s['pan_force_N'], g_pan, f)
    assert db < 0.5 and deg < 3.0, (db, deg)
    # the moving mass matters: the uncoupled model is off by dB around the resonance
    uncoupled = linearise(PARAMS.mechanics).frequency_response(f, 'pan').response_m_per_N * hold
    assert _compare(y / s['pan_force_N'], uncoupled, f)[0] > 3.0


def test_set_load_moves_the_resonance():
    fs, period = 10000.0, 2 ** 13
    res = fs / period
    lines = np.arange(int(300 / res), int(450 / res))
    sim = Simulator(PARAMS, fs, noise=False, quantisation=False)
    s_empty, _ = _run(sim, 'coil', 5e-3, lines, period, 3)
    sim.set_load(0.1)
    s_loaded, _ = _run(sim, 'coil', 5e-3, lines, period, 3)
    f = lines * res
    for spectra, expected_Hz in ((s_empty, 410.0), (s_loaded, 362.5)):
        h = np.abs(spectra['position_true_m'] / spectra['coil_force_true_N'])
        assert f[np.argmax(h)] == pytest.approx(expected_Hz, abs=2.5)
