"""
Compensation force of the voice coil from the measured current and lever-end position.

The coil force at the lever end is ``F_c = k(y) I`` with the position-dependent motor
coefficient ``k(y) = sum_j k[j] (y / 1 mm)**j`` [N/A] (paper Table 1, ``docs/model.md``
section 5). Positive upward; adding mass to the pan lowers it (see ``docs/weighing.md``).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.polynomial import polynomial as npoly

from emfc_ros.core.weighing.errors import WeighingError

_MM_PER_M = 1.0e3


def compensation_force_N(coil_current_A, position_m,
                         motor_coeffs_N_per_A_per_mm_pow: Sequence[float]) -> np.ndarray:
    """
    Coil force ``k(y) I`` with the position-dependent motor coefficient (vectorised).

    Parameters
    ----------
    coil_current_A : float or array_like
        Measured coil current [A].
    position_m : float or array_like
        Lever-end position at the same samples [m] (broadcast against the current).
    motor_coeffs_N_per_A_per_mm_pow : sequence of float
        ``k[j]`` in N/(A mm**j), ascending powers of the position in millimetres (default
        balance: 21.692, 0.012, -5.273e-3).

    Returns
    -------
    ndarray
        Compensation force at the lever end [N], positive upward, broadcast shape of the
        inputs (0-d for scalars).

    Raises
    ------
    WeighingError
        If the coefficient list is empty or not finite.
    """
    k = np.asarray(motor_coeffs_N_per_A_per_mm_pow, dtype=float)
    if k.ndim != 1 or k.size == 0 or not np.all(np.isfinite(k)):
        raise WeighingError('motor_coeffs_N_per_A_per_mm_pow: need a non-empty 1-D sequence '
                            f'of finite numbers, got {motor_coeffs_N_per_A_per_mm_pow!r}')
    current = np.asarray(coil_current_A, dtype=float)
    y_mm = np.asarray(position_m, dtype=float) * _MM_PER_M
    return npoly.polyval(y_mm, k) * current
