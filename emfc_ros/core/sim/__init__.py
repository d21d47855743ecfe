"""
Plant simulation: the block-wise simulator of the full chain and its RK4 kernels.

No ROS imports. :class:`Simulator` (``simulator.py``) runs setpoint voltages through DAC, hold,
amplifiers, motor and load changer, the nonlinear two-beam mechanics with mechanical stops, the
position sensor and the ADC (``chain.py``, compiled with numba or interpreted), with seeded noise
(``noise.py``). :class:`PlantKernel` (``kernel.py``, ``rk4.py``) is the bare mechanics kernel.
See ``docs/simulator.md``.
"""

from emfc_ros.core.sim.channels import channel_names, channel_units
from emfc_ros.core.sim.converters import convert_V, lsb_V
from emfc_ros.core.sim.hold_point import hold_point, HoldPoint
from emfc_ros.core.sim.kernel import BlockOutput, numba_available, PlantKernel
from emfc_ros.core.sim.noise import noise_key, standard_normals
from emfc_ros.core.sim.simulator import min_substeps, Simulator

__all__ = ['BlockOutput', 'channel_names', 'channel_units', 'convert_V', 'hold_point',
           'HoldPoint', 'lsb_V', 'min_substeps', 'noise_key', 'numba_available',
           'PlantKernel', 'Simulator', 'standard_normals']
