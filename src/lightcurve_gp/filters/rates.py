"""The prediction of a USQUE whose state carries the body rate: ``[δp (3), ω (3), b (1)?]``.

With ω unknown the sigma points no longer share one kinematic increment: sigma point ``i`` is the attitude
``q_i = δq(χ_i) ⊗ q̂`` spinning at ``ω_i = ω̂ + χ_i[ω]``, and the torque-free Euler equations with the quaternion
kinematics (paper Sec. 2.3, Eqs. (14), (18)) move each by its own RK4 step — all ``B × (2n+1)`` of them in one
batched call (:func:`lightcurve_gp.attitude.dynamics.rk4_stepper`). The propagated attitudes are re-expressed as GRP
errors about the propagated centre ``q_0⁻`` and the rates as deviations from its rate ``ω_0⁻``; their weighted mean and
covariance are the prior (Crassidis & Markley 2003, Eqs. (30)–(36) of their filter with the gyro bias replaced by
the rate; paper Sec. 2.5, Eqs. (34)–(37)). The measurement update is shared with the ω-known filter
(:func:`lightcurve_gp.filters.update.measurement_update`).

A covariance with exactly zero variance on some components (``P0_ω = 0`` and no ω noise: ω effectively known) is
factorised on its other components alone
(:func:`~lightcurve_gp.filters.unscented.sqrt_psd_with_zero_rows`), so that filter is the ω-known one.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import grp_to_quat, quat_conj, quat_right_matrix, quat_to_grp
from lightcurve_gp.filters.state import FilterState
from lightcurve_gp.filters.unscented import sqrt_psd_with_zero_rows
from lightcurve_gp.filters.update import Prior, RunConstants, redrawn_sigma_points, sigma_set

__all__ = ["rate_prior", "propagate_sigma_points"]


def propagate_sigma_points(run: RunConstants, q_sig: Tensor, omega_sig: Tensor) -> tuple[Tensor, Tensor]:
    """One RK4 step of the torque-free motion of every sigma point: ``q (B, S, 4)``, ``ω (B, S, 3)`` (rad/s) →
    the same shapes one step later (``run.stepper``, one batched call)."""
    return run.stepper(q_sig, omega_sig)


def rate_prior(run: RunConstants, state: FilterState) -> Prior:
    """Steps 1–5 of :func:`lightcurve_gp.filters.usque.run_usque` with ω in the state, and the sigma points of the
    update.

    Returns the :class:`~lightcurve_gp.filters.update.Prior` about ``[0, ω_0⁻, b̂]``: the propagated centre
    ``q_0⁻ (B, 4)`` and ``ω_0⁻ (B, 3)``, ``x̂⁻ (B, n)``, ``P⁻ (B, n, n)`` and the sigma points ``(B, 2n+1, n)``
    (the propagated ones, or drawn again from ``(x̂⁻, P⁻)`` with ``run.sigma_redraw``).
    """
    a, f = run.grp
    w = run.layout.omega_slice
    s, failed = sqrt_psd_with_zero_rows(state.P + run.Q if run.q_in_sigma else state.P)
    chi = sigma_set(None, math.sqrt(run.scale) * s.mT)  # (B, 2n+1, n) about [0, ω̂, b̂]
    q_sig = torch.bmm(grp_to_quat(chi[..., :3], a, f), quat_right_matrix(state.q_hat).mT)
    q_next, omega_next = propagate_sigma_points(run, q_sig, state.omega.unsqueeze(1) + chi[..., w])
    q_m, omega_m = q_next[:, 0], omega_next[:, 0]
    # re-express about the propagated centre: δq_i = q_i⁻ ⊗ (q_0⁻)⁻¹, δω_i = ω_i⁻ − ω_0⁻
    dq = torch.bmm(q_next, quat_right_matrix(quat_conj(q_m)).mT)
    chi_m = torch.cat([quat_to_grp(dq, a, f), omega_next - omega_m.unsqueeze(1), chi[..., 6:]], dim=-1)
    x_m = chi_m.mT @ run.wm  # (B, n)
    d = chi_m - x_m.unsqueeze(1)
    P_m = torch.baddbmm(run.Q, d.mT * run.wc, d)
    P_m = 0.5 * (P_m + P_m.mT)
    if run.sigma_redraw:
        chi_m, failed_again = redrawn_sigma_points(run, x_m, P_m)
        failed = failed | failed_again
    return Prior(q_m, omega_m, x_m, P_m, chi_m, failed)
