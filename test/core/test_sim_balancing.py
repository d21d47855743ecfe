"""The balancing pan load."""

import numpy as np
import pytest

from emfc_ros.core.model.parameters import BalanceParameters
from emfc_ros.core.paths import config_file
from emfc_ros.core.sim.balancing import balancing_load_mass_kg
from emfc_ros.core.sim.hold_point import hold_point


@pytest.fixture(scope='module')
def params():
    return BalanceParameters.load_yaml(config_file('balance_default.yaml'))


@pytest.mark.parametrize('coupled', [False, True])
def test_balancing_mass_needs_no_coil_current(params, coupled):
    mass = balancing_load_mass_kg(params, coupled)
    assert 0.05 < mass < 0.2
    np.testing.assert_allclose(hold_point(params, mass, coupled).setpoints_V, 0.0, atol=1e-9)


def test_coupled_load_changer_counts_as_pan_mass(params):
    free = balancing_load_mass_kg(params, False)
    coupled = balancing_load_mass_kg(params, True)
    np.testing.assert_allclose(free - coupled, params.mechanics.load_changer_mass_kg,
                               rtol=1e-6)


def test_unreachable_balance_is_refused(params):
    with pytest.raises(ValueError, match='no pan load'):
        balancing_load_mass_kg(params, False, upper_kg=0.01)
