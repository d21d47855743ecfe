"""
Derivatives of the simulated position with respect to the mechanics, from the linearised model.

The grey-box fit (:mod:`~emfc_ros.core.ident.balance_greybox`) simulates the nonlinear balance,
but over the shipped experiment the lever moves by tens of micrometres about its rest: the
response is linear to about 1e-4 (the motor coefficient changes by 5.5e-4 per millimetre, the
beams' angles stay below 1e-3 rad). The Jacobian of the fit, a finite difference of two full
simulations per parameter (16 simulations for 8 parameters), is therefore taken from the
linearised model instead, at the cost of about two simulations:

* the linear model about the rest under the initial setpoints (``x' = A x + B dF``, ``y = y0 +
  C x``, :func:`~emfc_ros.core.model.linear.jacobians`, with the coil force's dependence on the
  position, ``dF_c = k'(y0) I_c0 dy``, in ``A``), discretised as the simulator integrates it:
  one RK4 step per substep with the force held over the sample (``Phi = I + hA + (hA)^2/2 +
  (hA)^3/6 + (hA)^4/24``, ``Gamma = h (I + hA/2 + (hA)^2/6 + (hA)^3/24) B``, composed over the
  substeps), so that it differs from the simulation by the nonlinearity only;
* in modal form, ``y[n] - y0 = sum_ij r_ij s_ij[n]`` with ``s_ij[n + 1] = lambda_i s_ij[n] +
  dF_j[n]`` (``r_ij`` the residues of input ``j`` in mode ``i``), whose derivative is
  ``sum_ij (dr_ij s_ij + r_ij dlambda_i t_ij)`` with ``t_ij = ds_ij / dlambda_i`` the same
  recursion driven by ``s_ij``: eight first-order complex filters over the record, whatever
  the number of parameters; ``dr`` and ``dlambda`` are central differences of 4 x 4 matrices;
* the rest position (the fit's stand-in for the offset force) shifts the whole response.

The input forces are those of the recorded setpoints through the amplifiers (clipped to their
current limits) and the load changer, as the simulator computes them. The fit checks this
Jacobian against the simulation itself along two directions and uses the finite-difference one
when they disagree (:func:`~emfc_ros.core.ident.greybox.fit_greybox`, ``output_derivatives``).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Dict, List, Mapping, Optional, Sequence, Tuple

import numpy as np

from emfc_ros.core.ident.modal_filter import modal_pair
from emfc_ros.core.model.linear import jacobians
from emfc_ros.core.model.load import loaded
from emfc_ros.core.model.parameters import BalanceParameters, MechanicalParameters

#: Central-difference step of the 4 x 4 quantities, relative to each parameter's magnitude
#: (they are smooth and free of simulation noise).
STEP = 1.0e-6


def rk4_map(a: np.ndarray, b: np.ndarray, h: float, substeps: int = 1
            ) -> Tuple[np.ndarray, np.ndarray]:
    """
    The RK4 map of ``x' = A x + B w`` over one sample, ``w`` held constant.

    Parameters
    ----------
    a : ndarray, shape (n, n)
        State matrix [1/s].
    b : ndarray, shape (n, m)
        Input matrix.
    h : float
        Sample period [s].
    substeps : int
        RK4 steps per sample.

    Returns
    -------
    phi : ndarray, shape (n, n)
        ``x[k + 1] = phi x[k] + gamma w[k]``.
    gamma : ndarray, shape (n, m)
        The input's part.
    """
    step = h / substeps
    ha = step * a
    eye = np.eye(a.shape[0])
    ha2 = ha @ ha
    ha3 = ha2 @ ha
    phi1 = eye + ha + ha2 / 2.0 + ha3 / 6.0 + ha3 @ ha / 24.0
    gamma1 = step * (eye + ha / 2.0 + ha2 / 6.0 + ha3 / 24.0) @ b
    phi, gamma = phi1, gamma1
    for _ in range(substeps - 1):
        phi, gamma = phi1 @ phi, phi1 @ gamma + gamma1
    return phi, gamma


class LinearSensitivity:
    """
    Position and its derivatives with respect to mechanical parameters, linearised.

    Parameters
    ----------
    setpoints_V : ndarray, shape (n, 2)
        Coil and load-changer setpoints as applied [V] (the record).
    sample_rate_Hz : float
        Sample rate [Hz].
    load_mass_kg : float
        Mass on the pan [kg].
    load_changer_coupled : bool
        Whether the load changer's moving mass rides on the pan.
    substeps : int
        RK4 steps per sample of the simulation.
    initial_setpoints_V : (float, float), optional
        The setpoints the balance rested under before sample 0 (the linearisation's rest and
        the inputs' reference); default the first setpoints.
    """

    def __init__(self, setpoints_V: np.ndarray, sample_rate_Hz: float, load_mass_kg: float,
                 load_changer_coupled: bool, substeps: int = 1,
                 initial_setpoints_V: Optional[Sequence[float]] = None) -> None:
        self.setpoints_V = np.asarray(setpoints_V, dtype=float)
        self.initial_setpoints_V = (self.setpoints_V[0] if initial_setpoints_V is None
                                    else np.asarray(initial_setpoints_V, dtype=float))
        self.sample_rate_Hz = float(sample_rate_Hz)
        self.load_mass_kg = float(load_mass_kg)
        self.load_changer_coupled = bool(load_changer_coupled)
        self.substeps = int(substeps)
        self._inputs_key: Optional[tuple] = None
        self._currents: Optional[Tuple[np.ndarray, np.ndarray]] = None

    def _input_currents(self, params: BalanceParameters
                        ) -> Tuple[np.ndarray, np.ndarray, float, float]:
        """
        Coil current [A] and pan force [N] per sample, and under the initial setpoints.

        Fixed characteristics: cached.
        """
        conv = params.converters
        key = (params.coil_amplifier, params.load_changer_amplifier, params.load_changer,
               conv.dac_range_V, conv.coil_current_limit_A, conv.load_changer_current_limit_A)
        if key != self._inputs_key:
            u = np.clip(np.vstack((self.initial_setpoints_V[None, :], self.setpoints_V)),
                        -conv.dac_range_V, conv.dac_range_V)
            i_coil = np.clip(params.coil_amplifier.current_A(u[:, 0]),
                             -conv.coil_current_limit_A, conv.coil_current_limit_A)
            i_lc = np.clip(params.load_changer_amplifier.current_A(u[:, 1]),
                           -conv.load_changer_current_limit_A,
                           conv.load_changer_current_limit_A)
            i_coil = np.asarray(i_coil, dtype=float)
            f_pan = np.asarray(params.load_changer.force_N(i_lc), dtype=float)
            self._currents = (i_coil[1:], f_pan[1:], float(i_coil[0]), float(f_pan[0]))
            self._inputs_key = key
        return self._currents

    def modal(self, params: BalanceParameters, x0: np.ndarray,
              mechanics: MechanicalParameters) -> Tuple[np.ndarray, np.ndarray]:
        """
        Eigenvalues and residues of the discretised linear model.

        Parameters
        ----------
        params : BalanceParameters
            The balance (characteristics; its mechanics are replaced by ``mechanics``).
        x0 : ndarray, shape (4,)
            Rest state about which to linearise [rad, rad/s].
        mechanics : MechanicalParameters
            The (empty, uncoupled) mechanics to linearise.

        Returns
        -------
        lam : ndarray, shape (4,)
            Eigenvalues of the one-sample map.
        res : ndarray, shape (4, 2)
            Residues ``(C v_i)(w_i Gamma_j)`` [m/N per sample], coil force scaled by ``k(y0)``
            so that the input is the coil current deviation [A].
        """
        _, _, i_ref, f_ref = self._input_currents(params)
        mech = loaded(mechanics, self.load_mass_kg, self.load_changer_coupled)
        y0 = float(mech.l2_m * np.sin(x0[0]) + mech.l3_m * np.sin(x0[1]))
        k0 = float(params.motor.coefficient_N_per_A(y0))
        dk = 1.0e-9
        slope = float(params.motor.coefficient_N_per_A(y0 + dk)
                      - params.motor.coefficient_N_per_A(y0 - dk)) / (2.0 * dk)
        a, b, c, _ = jacobians(mech, np.asarray(x0, dtype=float),
                               np.array([k0 * i_ref, f_ref]))
        # the coil force follows the position at every RK4 stage: F_c = k(y) I_c
        a = a + np.outer(b[:, 0], slope * i_ref * c[0])
        phi, gamma = rk4_map(a, b, 1.0 / self.sample_rate_Hz, self.substeps)
        lam, v = np.linalg.eig(phi)
        w = np.linalg.inv(v)
        res = (c[0] @ v)[:, None] * (w @ gamma)
        res[:, 0] *= k0
        return lam, res

    def derivatives(self, params: BalanceParameters, x0: np.ndarray, names: Sequence[str],
                    values: Mapping[str, float],
                    with_values: Callable[[Dict[str, float]], BalanceParameters],
                    rest_name: Optional[str] = None) -> np.ndarray:
        """
        Derivatives of the position over the record with respect to parameters.

        Parameters
        ----------
        params : BalanceParameters
            The balance at ``values``.
        x0 : ndarray, shape (4,)
            Its rest state under the initial setpoints.
        names : sequence of str
            Parameters to differentiate by: names ``with_values`` understands (mechanical
            parameters, mass-matrix entries) and ``rest_name``.
        values : mapping of str to float
            The current values of ``names``.
        with_values : callable
            ``with_values(values) -> BalanceParameters`` (mechanics replaced).
        rest_name : str, optional
            The parameter that is the rest position of the lever end [m]: it shifts the
            response.

        Returns
        -------
        ndarray, shape (n, len(names))
            ``dy / dtheta`` [m per unit of each parameter].
        """
        drive = self._drive(params)
        n = drive.shape[0]
        lam, res = self.modal(params, x0, params.mechanics)
        keep, weight = _one_of_each_pair(lam)
        d_lam = np.zeros((len(keep), len(names)), dtype=complex)
        d_res = np.zeros((len(keep), 2, len(names)), dtype=complex)
        out = np.zeros((n, len(names)))
        for k, name in enumerate(names):
            if name == rest_name:
                out[:, k] = 1.0
                continue
            v0 = float(values[name])
            h = STEP * (abs(v0) or 1.0)
            ends = []
            for sign in (1.0, -1.0):
                moved = with_values(dict(values, **{name: v0 + sign * h})).mechanics
                # the offset force as at the current values (it is solved for the rest
                # position; its effect on the linearisation is of second order)
                moved = replace(moved, F_off_N=params.mechanics.F_off_N)
                lam_s, res_s = self.modal(params, x0, moved)
                order = [int(np.argmin(np.abs(lam_s - lam[i]))) for i in keep]
                ends.append((lam_s[order], res_s[order]))
            d_lam[:, k] = (ends[0][0] - ends[1][0]) / (2.0 * h)
            d_res[:, :, k] = (ends[0][1] - ends[1][1]) / (2.0 * h)
        # s_ij[m + 1] = lam_i s_ij[m] + drive_j[m];  t_ij = d s_ij / d lam_i. The real part of
        # sum a z is sum (Re a Re z - Im a Im z): one real product of the complex signals
        # viewed as interleaved real and imaginary columns.
        signals = np.empty((n, 4 * len(keep)), dtype=complex)
        coeff = np.empty((2 * signals.shape[1], len(names)))
        col = 0
        for m, i in enumerate(keep):
            for j in range(2):
                signals[:, col], signals[:, col + 1] = modal_pair(lam[i], drive[:, j])
                for a in (weight[m] * d_res[m, j], weight[m] * res[i, j] * d_lam[m]):
                    coeff[2 * col] = a.real
                    coeff[2 * col + 1] = -a.imag
                    col += 1
        out += signals.view(np.float64) @ coeff
        return out

    def input_responses(self, params: BalanceParameters, x0: np.ndarray) -> np.ndarray:
        """
        The linearised position response to each input's deviation from its initial value.

        ``y_j[n] = sum_i Re(r_ij s_ij[n])`` (the terms of :meth:`derivatives`' response): the
        part of the position the coil current (``j = 0``) and the pan force (``j = 1``) drive.
        A force scale ``1 + e`` on input ``j`` changes the position by ``e y_j`` to first
        order (the rest under the initial setpoints stays where the fitted rest position puts
        it: the offset force is solved for it).

        Parameters
        ----------
        params : BalanceParameters
            The balance.
        x0 : ndarray, shape (4,)
            Its rest state under the initial setpoints.

        Returns
        -------
        ndarray, shape (n, 2)
            Coil part and pan part of the position [m].
        """
        drive = self._drive(params)
        lam, res = self.modal(params, x0, params.mechanics)
        out = np.zeros(drive.shape)
        for i, weight in zip(*_one_of_each_pair(lam)):
            for j in range(2):
                s, _ = modal_pair(lam[i], drive[:, j])
                out[:, j] += weight * (res[i, j] * s).real
        return out

    def _drive(self, params: BalanceParameters) -> np.ndarray:
        """Coil current [A] and pan force [N] minus their initial values, shape (n, 2)."""
        i_coil, f_pan, i_ref, f_ref = self._input_currents(params)
        return np.column_stack((i_coil - i_ref, f_pan - f_ref))


def _one_of_each_pair(lam: np.ndarray) -> Tuple[List[int], np.ndarray]:
    """Modes to sum: one of each conjugate pair (weight 2), real ones (weight 1)."""
    keep = [i for i in range(lam.size) if lam[i].imag >= -1e-15 * abs(lam[i])]
    return keep, np.array([2.0 if lam[i].imag > 1e-15 * abs(lam[i]) else 1.0 for i in keep])
