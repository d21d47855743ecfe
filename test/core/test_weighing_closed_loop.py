"""Weighing on the simulated closed loop: settled readings within 1 mg, the dynamic estimate."""

import numpy as np
import pytest

from emfc_ros.core.control.loop_config import LoopConfig
from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.paths import config_file
from emfc_ros.core.sim.closed_loop import ClosedLoopSimulator
from emfc_ros.core.sim.simulator import Simulator
from emfc_ros.core.weighing import (compensation_force_N, DynamicWeigher, settled_reading,
                                    WeighingCalibration)

FS_HZ = 20000
LOOP = LoopConfig()     # the default in-loop design: 10 kHz, 130 Hz, no notch
MG = 1.0e-6


class Balance:
    """The closed loop with helpers that return compensation force and position."""

    def __init__(self, seed: int) -> None:
        self.params = BalanceParameters.load_yaml(str(config_file('balance_default.yaml')))
        self.loop = ClosedLoopSimulator(
            Simulator(self.params, float(FS_HZ), seed=seed, reference_channels=False), LOOP)
        names = self.loop.channel_names
        self.rows = names.index('position_m'), names.index('coil_current_precise_A')

    def run(self, mass_kg: float, seconds: float):
        self.loop.set_load(mass_kg)
        out = self.loop.step_block(np.zeros((2, int(round(seconds * FS_HZ)))))
        y = out[self.rows[0]]
        force = compensation_force_N(out[self.rows[1]], y,
                                     self.params.motor.coeffs_N_per_A_per_mm_pow)
        return y, force


@pytest.fixture(scope='module')
def adjusted():
    """Zero with the empty pan, adjust with a 100 g reference weight (1 s averages)."""
    bal = Balance(seed=11)
    cal = WeighingCalibration.nominal(bal.params.mechanics)
    _, f = bal.run(0.0, 2.0)
    cal = cal.zeroed(settled_reading(f, FS_HZ, cal).mean_force_N)
    _, f = bal.run(0.1, 2.0)
    cal = cal.adjusted(settled_reading(f, FS_HZ, cal).mean_force_N, 0.1)
    return bal, cal


@pytest.mark.parametrize('mass_kg', [0.05, 0.02, 0.1])
def test_settled_reading_is_within_1_mg_after_adjustment(adjusted, mass_kg):
    bal, cal = adjusted
    _, f = bal.run(mass_kg, 2.0)
    reading = settled_reading(f, FS_HZ, cal, averaging_time_s=1.0)
    assert abs(reading.mass_kg - mass_kg) < 1.0 * MG
    assert 0.0 < reading.standard_uncertainty_kg < 0.5 * MG
    # the adjustment corrected the nominal lever-ratio sensitivity by a little, not nothing
    nominal = WeighingCalibration.nominal(bal.params.mechanics).sensitivity_kg_per_N
    assert 1e-5 < abs(cal.sensitivity_kg_per_N / nominal - 1.0) < 1e-2


def test_a_16_bit_dac_alone_would_step_about_50_mg(adjusted):
    """The coil DAC's step seen at the pan, the reason for the precise current channel."""
    bal, cal = adjusted
    p = bal.params
    conv = p.converters
    lsb_V = 2.0 * conv.dac_range_V / 2 ** conv.dac_bits
    step_N = p.coil_amplifier.coeffs_A_per_V_pow[1] * lsb_V * p.motor.coefficient_N_per_A(0.0)
    step_kg = abs(cal.sensitivity_kg_per_N) * step_N
    assert 40 * MG < step_kg < 60 * MG


def test_dynamic_estimate_is_within_1_mg_before_the_settled_average(adjusted):
    bal, cal = adjusted
    y0, f0 = bal.run(0.0, 0.5)
    weigher = DynamicWeigher(bal.params.mechanics, float(FS_HZ))
    weigher.update_block(y0, f0)
    y, f = bal.run(0.07, 1.5)
    m_dyn = weigher.mass_kg(weigher.update_block(y, f), cal)
    outside = np.nonzero(np.abs(m_dyn - 0.07) > 1.0 * MG)[0]
    t_dynamic_s = (outside[-1] + 1) / FS_HZ
    # the settled 1-s average cannot be right before a full second after the step
    assert t_dynamic_s < 0.6
    assert abs(np.mean(m_dyn[-FS_HZ // 2:]) - 0.07) < 0.3 * MG
