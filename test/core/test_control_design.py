"""Tests of the loop-shaping controller design against independent closed-loop computations."""

import math

import numpy as np
import pytest
from scipy import linalg, signal

from emfc_ros.core.control import design_controller, DiscreteController, plant_from_model
from emfc_ros.core.model.linear import linearise
from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.paths import config_file

FS_HZ = 10.0e3
DELAY = 1.5


@pytest.fixture(scope='module')
def model():
    params = BalanceParameters.load_yaml(str(config_file('balance_default.yaml')))
    return linearise(loaded(params.mechanics, 0.0, False))


@pytest.fixture(scope='module')
def design(model):
    return design_controller(plant_from_model(model), FS_HZ, 50.0, 40.0, delay_samples=DELAY)


def _scaled(controller: DiscreteController, factor: float) -> DiscreteController:
    return DiscreteController(controller.sample_rate_Hz, controller.gain * factor,
                              controller.stages, controller.stage_names)


def _closed_loop_poles(model, controller: DiscreteController) -> np.ndarray:
    """Exact sampled-data closed loop: ZOH plant, 1.5 samples of delay, u = -C(z) y."""
    T = 1.0 / controller.sample_rate_Hz
    A, b, C = model.A, model.B[:, [0]], model.C
    n = A.shape[0]

    def phi_gamma(tau):
        m = np.zeros((n + 1, n + 1))
        m[:n, :n] = A
        m[:n, n:] = b
        e = linalg.expm(m * tau)
        return e[:n, :n], e[:n, n:]

    # In [kT, kT + T/2) the plant sees u[k-2], in [kT + T/2, (k+1)T) it sees u[k-1].
    phi_half, gam_half = phi_gamma(T / 2.0)
    phi = phi_half @ phi_half
    gam_u2 = phi_half @ gam_half
    gam_u1 = gam_half
    Ac, Bc, Cc, Dc = signal.tf2ss(controller.numerator, controller.denominator)
    nc = Ac.shape[0]
    size = n + 2 + nc
    M = np.zeros((size, size))
    iu1, iu2, ic = n, n + 1, n + 2
    M[:n, :n] = phi
    M[:n, [iu1]] = gam_u1
    M[:n, [iu2]] = gam_u2
    M[iu1, :n] = -(Dc @ C)[0]
    M[iu1, ic:] = Cc[0]
    M[iu2, iu1] = 1.0
    M[ic:, :n] = -Bc @ C
    M[ic:, ic:] = Ac
    return linalg.eigvals(M)


def _is_stable(model, controller) -> bool:
    return bool(np.max(np.abs(_closed_loop_poles(model, controller))) < 1.0)


def _own_loop(model, controller, f):
    """L from the combined polynomials, the plant and the hold and delay, computed here."""
    _, c = signal.freqz(controller.numerator, controller.denominator, worN=f,
                        fs=controller.sample_rate_Hz)
    p = model.frequency_response(f, 'coil').response_m_per_N
    w = 2.0 * np.pi * f / controller.sample_rate_Hz
    hold = np.sinc(f / controller.sample_rate_Hz) * np.exp(-1j * w / 2.0)
    return c * p * hold * np.exp(-1j * w * DELAY)


def test_meets_requested_crossover_and_phase_margin(design):
    assert abs(design.phase_margin_deg - 40.0) < 1.0
    assert abs(design.crossover_Hz - 50.0) < 0.02 * 50.0
    assert len(design.gain_crossovers_Hz) == 1
    assert design.controller.stage_names == ('pid', 'lead')
    assert design.controller.gain > 0.0


def test_closed_loop_is_stable_and_conditionally_stable(model, design):
    assert _is_stable(model, design.controller)
    lower, upper = design.lower_gain_margin, design.upper_gain_margin
    assert lower is not None and 0.0 < lower < 1.0
    assert upper is not None and upper > 1.0
    # The exact sampled-data loop loses stability just past both reported margins.
    assert _is_stable(model, _scaled(design.controller, lower * 1.02))
    assert not _is_stable(model, _scaled(design.controller, lower * 0.98))
    assert _is_stable(model, _scaled(design.controller, upper * 0.98))
    assert not _is_stable(model, _scaled(design.controller, upper * 1.02))


def test_margins_agree_with_own_grid(model, design):
    f = np.linspace(0.05, 4990.0, 400000)
    L = _own_loop(model, design.controller, f)
    mag = np.abs(L)
    i = np.nonzero(np.diff(np.sign(mag - 1.0)))[0]
    assert len(i) == 1
    fc = f[i[0]]
    pm = 180.0 + np.degrees(np.angle(L[i[0]]))
    assert fc == pytest.approx(design.crossover_Hz, rel=2e-3)
    assert pm == pytest.approx(design.phase_margin_deg, abs=0.2)
    j = np.nonzero(np.diff(np.sign(L.imag)) != 0)[0]
    factors = [1.0 / mag[k] for k in j if L.real[k] < 0.0]
    own_lower = max(k for k in factors if k < 1.0)
    own_upper = min(k for k in factors if k > 1.0)
    assert own_lower == pytest.approx(design.lower_gain_margin, rel=1e-2)
    assert own_upper == pytest.approx(design.upper_gain_margin, rel=1e-2)
    S = 1.0 / (1.0 + L)
    assert np.max(np.abs(S)) == pytest.approx(design.sensitivity_peak, rel=1e-3)
    T = np.abs(L * S)
    bw = f[np.argmax(T < 1.0 / math.sqrt(2.0))]
    assert bw == pytest.approx(design.bandwidth_Hz, rel=2e-3)
    assert design.bandwidth_Hz > design.crossover_Hz


def test_controller_transfer_function_matches_its_response(design):
    c = design.controller
    f = np.array([1.0, 50.0, 410.0, 3000.0])
    _, h = signal.freqz(c.numerator, c.denominator, worN=f, fs=FS_HZ)
    np.testing.assert_allclose(c.frequency_response(f), h, rtol=1e-8)
    d = c.to_dlti()
    assert d.dt == pytest.approx(1.0 / FS_HZ)
    assert np.any(np.isclose(d.poles, 1.0))   # the integrator


def test_notch_at_resonance_cuts_loop_gain(model, design):
    notched = design_controller(plant_from_model(model), FS_HZ, 50.0, 40.0,
                                delay_samples=DELAY, notch_Hz=410.0)
    assert notched.controller.stage_names == ('pid', 'lead', 'notch')
    assert abs(notched.phase_margin_deg - 40.0) < 1.0
    assert abs(notched.crossover_Hz - 50.0) < 1.0
    assert _is_stable(model, notched.controller)
    f = np.array([410.0])
    plain = abs(_own_loop(model, design.controller, f)[0])
    cut = abs(_own_loop(model, notched.controller, f)[0])
    assert 20.0 * math.log10(plain / cut) >= 20.0


def test_high_crossover_other_margins(model):
    d = design_controller(plant_from_model(model), FS_HZ, 120.0, 40.0, notch_Hz=410.0)
    assert d.crossover_Hz == pytest.approx(120.0, rel=1e-3)
    assert d.phase_margin_deg == pytest.approx(40.0, abs=1e-3)
    assert _is_stable(model, d.controller)


@pytest.mark.parametrize('kwargs, name', [
    ({'crossover_Hz': 6000.0}, 'crossover_Hz'),
    ({'crossover_Hz': 5000.0}, 'crossover_Hz'),
    ({'crossover_Hz': -1.0}, 'crossover_Hz'),
    ({'phase_margin_deg': 0.0}, 'phase_margin_deg'),
    ({'phase_margin_deg': 90.0}, 'phase_margin_deg'),
    ({'phase_margin_deg': -10.0}, 'phase_margin_deg'),
    ({'delay_samples': -1.0}, 'delay_samples'),
    ({'notch_Hz': 5000.0}, 'notch_Hz'),
    ({'sample_rate_Hz': 0.0}, 'sample_rate_Hz'),
])
def test_bad_inputs_raise_naming_the_argument(model, kwargs, name):
    args = dict(sample_rate_Hz=FS_HZ, crossover_Hz=50.0, phase_margin_deg=40.0)
    args.update(kwargs)
    with pytest.raises(ValueError, match=name):
        design_controller(plant_from_model(model), **args)
