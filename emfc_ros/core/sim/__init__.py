"""
Plant simulation: the block-wise RK4 kernel of the full nonlinear chain.

No ROS imports. See :mod:`emfc_ros.core.sim.kernel`.
"""

from emfc_ros.core.sim.kernel import BlockOutput, numba_available, PlantKernel

__all__ = ['BlockOutput', 'numba_available', 'PlantKernel']
