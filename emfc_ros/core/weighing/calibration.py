"""
Calibration of the weighing cell: compensation force [N] to mass [kg].

``mass_kg = sensitivity_kg_per_N * (force_N - zero_force_N) - tare_kg``

The coil force ``F_c`` (positive upward) holds the lever at zero position; a mass ``m`` on the
pan at ``l1`` from the pivot is balanced at the lever end ``l2 + l3`` by a DEcrease of the coil
force, ``m g l1 = -(l2 + l3) dF_c``, so the nominal sensitivity is negative:
``-(l2 + l3) / (l1 g)`` (-0.7645 kg/N with the defaults). The controller holds ``y = 0`` rather
than ``q1 = q2 = 0``, which makes the true span 0.054 % smaller than nominal (``docs/model.md``
section 4): adjustment with a reference weight removes that.

Every operation returns a new (immutable) calibration. Uncertainty model (standard
uncertainties, contributions treated as uncorrelated, which is slightly conservative):

``u_cal^2 = (S u_F0)^2 + (m_gross u_S,rel)^2 + u_tare^2``

with ``u_F0`` the standard uncertainty of the zero-force mean, ``u_S,rel`` the relative
standard uncertainty of the sensitivity from the adjustment,
``u_S,rel^2 = (u_Fref^2 + u_F0^2) / (F_ref - F0)^2 + (u_mref / m_ref)^2``, and ``u_tare`` the
tare mean's uncertainty ``|S| u_Ftare``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
import math
from typing import Optional

import numpy as np

from emfc_ros.core.model.parameters import MechanicalParameters
from emfc_ros.core.weighing.errors import WeighingError


#: Relative standard uncertainty of the sensitivity from the lever geometry (see
#: :meth:`WeighingCalibration.nominal`).
NOMINAL_SENSITIVITY_U_RELATIVE = 1.0e-3


def _finite(name: str, value: float) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise WeighingError(f'{name}: need a finite number, got {value!r}') from None
    if not math.isfinite(out):
        raise WeighingError(f'{name}: need a finite number, got {value!r}')
    return out


def _uncertainty(name: str, value: float) -> float:
    out = _finite(name, value)
    if out < 0.0:
        raise WeighingError(f'{name}: a standard uncertainty must be >= 0, got {value!r}')
    return out


def nominal_sensitivity_kg_per_N(mechanics: MechanicalParameters) -> float:
    """
    Nominal sensitivity ``-(l2 + l3) / (l1 g)`` from the lever geometry.

    Parameters
    ----------
    mechanics : MechanicalParameters
        Lever lengths ``l1_m``, ``l2_m``, ``l3_m`` [m] and gravity ``g_m_per_s2`` [m/s^2].

    Returns
    -------
    float
        Sensitivity [kg/N], negative: more mass on the pan, less coil force.
    """
    m = mechanics
    return -(m.l2_m + m.l3_m) / (m.l1_m * m.g_m_per_s2)


@dataclass(frozen=True)
class WeighingCalibration:
    """
    Linear map from compensation force to (net) mass, with its own uncertainty.

    Attributes
    ----------
    sensitivity_kg_per_N : float
        ``S`` [kg/N], non-zero (negative for the EMFC balance: see the module docstring).
    zero_force_N : float
        ``F0``, compensation force with the empty pan [N].
    tare_kg : float
        Tare subtracted from the gross mass [kg].
    zero_force_u_N : float
        Standard uncertainty of ``F0`` [N] (of the mean used by :meth:`zeroed`).
    sensitivity_u_relative : float
        Relative standard uncertainty of ``S`` [1] (from :meth:`adjusted`).
    tare_u_kg : float
        Standard uncertainty of the tare [kg].
    """

    sensitivity_kg_per_N: float
    zero_force_N: float = 0.0
    tare_kg: float = 0.0
    zero_force_u_N: float = 0.0
    sensitivity_u_relative: float = 0.0
    tare_u_kg: float = 0.0

    def __post_init__(self) -> None:
        sens = _finite('sensitivity_kg_per_N', self.sensitivity_kg_per_N)
        if sens == 0.0:
            raise WeighingError('sensitivity_kg_per_N: must be non-zero')
        object.__setattr__(self, 'sensitivity_kg_per_N', sens)
        for name in ('zero_force_N', 'tare_kg'):
            object.__setattr__(self, name, _finite(name, getattr(self, name)))
        for name in ('zero_force_u_N', 'sensitivity_u_relative', 'tare_u_kg'):
            object.__setattr__(self, name, _uncertainty(name, getattr(self, name)))

    @classmethod
    def nominal(cls, mechanics: MechanicalParameters, zero_force_N: float = 0.0,
                sensitivity_u_relative: Optional[float] = None) -> 'WeighingCalibration':
        """
        Calibration from the lever geometry, ``S = -(l2 + l3) / (l1 g)``.

        The geometry is not the span: the loop holds ``y = 0``, not ``q = 0``, and the joint
        flexes (0.054 % with the defaults), and real lever lengths have tolerances. Until an
        adjustment replaces it, the nominal sensitivity carries a relative standard
        uncertainty of :data:`NOMINAL_SENSITIVITY_U_RELATIVE` (0.1 %), so that a reading of
        an unadjusted balance states what it can be off by.

        Parameters
        ----------
        mechanics : MechanicalParameters
            The mechanics (lengths [m], gravity [m/s^2]).
        zero_force_N : float
            Compensation force of the empty pan [N] (e.g. from
            :func:`~emfc_ros.core.sim.hold_point.hold_point`); default 0 N.
        sensitivity_u_relative : float, optional
            Relative standard uncertainty of the nominal sensitivity; default
            :data:`NOMINAL_SENSITIVITY_U_RELATIVE`.

        Returns
        -------
        WeighingCalibration
            No tare; the zero force without uncertainty.
        """
        u = NOMINAL_SENSITIVITY_U_RELATIVE if sensitivity_u_relative is None \
            else sensitivity_u_relative
        return cls(nominal_sensitivity_kg_per_N(mechanics), zero_force_N,
                   sensitivity_u_relative=u)

    def gross_mass_kg(self, force_N):
        """
        Gross mass ``S (F - F0)`` (tare not subtracted), vectorised.

        Parameters
        ----------
        force_N : float or array_like
            Compensation force [N].

        Returns
        -------
        float or ndarray
            Gross mass [kg].
        """
        return self.sensitivity_kg_per_N * (np.asarray(force_N, dtype=float)
                                            - self.zero_force_N)

    def mass_kg(self, force_N):
        """
        Net mass ``S (F - F0) - tare`` [kg] of a compensation force [N], vectorised.

        Parameters
        ----------
        force_N : float or array_like
            Compensation force [N].

        Returns
        -------
        float or ndarray
            Net mass [kg]: :meth:`gross_mass_kg` less the tare.
        """
        return self.gross_mass_kg(force_N) - self.tare_kg

    def standard_uncertainty_kg(self, force_N):
        """
        The calibration's standard uncertainty contribution at a reading, vectorised.

        ``sqrt((S u_F0)^2 + (m_gross u_S,rel)^2 + u_tare^2)``; the reading's own noise is not
        included (see :mod:`emfc_ros.core.weighing.reading`).

        Parameters
        ----------
        force_N : float or array_like
            Compensation force of the reading [N].

        Returns
        -------
        float or ndarray
            Standard uncertainty [kg].
        """
        gross = self.gross_mass_kg(force_N)
        return np.sqrt((self.sensitivity_kg_per_N * self.zero_force_u_N) ** 2
                       + (gross * self.sensitivity_u_relative) ** 2 + self.tare_u_kg ** 2)

    def zeroed(self, mean_force_N: float, force_u_N: float = 0.0) -> 'WeighingCalibration':
        """
        Zero with the empty pan: the reading at ``mean_force_N`` becomes 0 kg.

        The tare is cleared (the pan is empty); the sensitivity is kept.

        Parameters
        ----------
        mean_force_N : float
            Mean compensation force of the empty pan [N].
        force_u_N : float
            Standard uncertainty of that mean [N].

        Returns
        -------
        WeighingCalibration
            The zeroed calibration.

        Raises
        ------
        WeighingError
            If an argument is not finite or the uncertainty is negative.
        """
        return replace(self, zero_force_N=_finite('mean_force_N', mean_force_N),
                       zero_force_u_N=_uncertainty('force_u_N', force_u_N),
                       tare_kg=0.0, tare_u_kg=0.0)

    def tared(self, mean_force_N: float, force_u_N: float = 0.0) -> 'WeighingCalibration':
        """
        Tare with a container on the pan: its net reading becomes 0 kg, gross is kept.

        Parameters
        ----------
        mean_force_N : float
            Mean compensation force with the container on the pan [N].
        force_u_N : float
            Standard uncertainty of that mean [N].

        Returns
        -------
        WeighingCalibration
            The calibration with ``tare_kg`` = gross mass of the container.

        Raises
        ------
        WeighingError
            If an argument is not finite or the uncertainty is negative.
        """
        force = _finite('mean_force_N', mean_force_N)
        u = _uncertainty('force_u_N', force_u_N)
        return replace(self, tare_kg=float(self.gross_mass_kg(force)),
                       tare_u_kg=abs(self.sensitivity_kg_per_N) * u)

    def adjusted(self, mean_force_N: float, reference_mass_kg: float, force_u_N: float = 0.0,
                 reference_mass_u_kg: float = 0.0) -> 'WeighingCalibration':
        """
        Adjust the span with a reference weight on the zeroed pan.

        ``S = m_ref / (F_ref - F0)`` so that the reading equals the reference; the zero is kept
        and the tare cleared (adjust on the zeroed, empty pan plus the reference weight).

        Parameters
        ----------
        mean_force_N : float
            Mean compensation force with the reference weight on the pan [N].
        reference_mass_kg : float
            Conventional mass of the reference weight [kg], > 0.
        force_u_N : float
            Standard uncertainty of the force mean [N].
        reference_mass_u_kg : float
            Standard uncertainty of the reference mass [kg].

        Returns
        -------
        WeighingCalibration
            The adjusted calibration.

        Raises
        ------
        WeighingError
            If an argument is not finite, the reference mass is not positive, the force
            equals the zero force, or the new sensitivity would change sign (the force moved
            the wrong way: reference not on the pan, or the balance was zeroed with a load).
        """
        force = _finite('mean_force_N', mean_force_N)
        ref = _finite('reference_mass_kg', reference_mass_kg)
        if ref <= 0.0:
            raise WeighingError(f'reference_mass_kg: the reference weight must be > 0 kg, '
                                f'got {reference_mass_kg!r}')
        u_force = _uncertainty('force_u_N', force_u_N)
        u_ref = _uncertainty('reference_mass_u_kg', reference_mass_u_kg)
        delta = force - self.zero_force_N
        if delta == 0.0:
            raise WeighingError(f'mean_force_N: {force!r} N equals the zero force, the '
                                f'reference weight changed nothing (is it on the pan?)')
        sens = ref / delta
        if (sens > 0.0) != (self.sensitivity_kg_per_N > 0.0):
            raise WeighingError(
                f'mean_force_N: the force moved by {delta:+.6g} N from the zero force, the '
                f'wrong direction for a sensitivity of sign {self.sensitivity_kg_per_N:+.3g} '
                f'kg/N (reference not on the pan, or zeroed with a load on it?)')
        u_rel = math.sqrt((u_force ** 2 + self.zero_force_u_N ** 2) / delta ** 2
                          + (u_ref / ref) ** 2)
        return replace(self, sensitivity_kg_per_N=sens, sensitivity_u_relative=u_rel,
                       tare_kg=0.0, tare_u_kg=0.0)
