"""The measurement half of a batched USQUE step (paper Sec. 2.5, Eqs. (41)–(47); Sec. 3.3), shared by both
predictions: the ω-known rotation shortcut (:func:`lightcurve_gp.filters.step.usque_step`) and the rate-state
prediction that propagates every sigma point with its own ω (:mod:`lightcurve_gp.filters.rates`).

A prediction hands over the propagated centre ``q_0⁻`` (and ``ω_0⁻``), the prior mean ``x̂⁻`` and covariance ``P⁻``
of the error state about ``[0, ω_0⁻, b̂]`` and the sigma points ``χ_i⁻`` to update with — its own propagated ones,
or ones drawn again from ``(x̂⁻, P⁻)`` (the paper's variant, "computed again", Sec. 2.5: :func:`redrawn_sigma_points`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, NamedTuple

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import grp_to_quat, quat_right_matrix
from lightcurve_gp.filters.state import FilterState, StateLayout, StepRecord
from lightcurve_gp.filters.unscented import sqrt_psd_with_zero_rows, symmetrise
from lightcurve_gp.observation.base import ObservationModel, Variance

__all__ = ["RunConstants", "Prior", "SigmaInputs", "Gain", "measurement_update", "sigma_inputs",
           "update_with_predictions", "kalman_gain", "posterior", "redrawn_sigma_points", "adapted_noise", "sigma_set"]


@dataclass(frozen=True, eq=False)
class RunConstants:
    """Per-run constants of the recursion (weights, noises, layout, model, variant, rate dynamics)."""

    model: ObservationModel
    layout: StateLayout
    wm: Tensor
    wc: Tensor
    scale: float  # n + λ
    Q: Tensor  # (B, n, n)
    R: Tensor  # (B,)
    grp: tuple[float, float]  # (a, f)
    variance: Variance
    t_span_past: float
    adaptive_rate: float | None  # λ of the innovation rule; None: R fixed
    sigma_redraw: bool = False  # update with sigma points drawn again from (x̂⁻, P⁻)
    q_in_sigma: bool = True  # Q also added to P⁺ before the sigma points (Crassidis & Markley); else after only
    stepper: Callable[[Tensor, Tensor], tuple[Tensor, Tensor]] | None = None  # (q, ω) ↦ RK4 step, rate filter
    update_iterations: int = 1  # iterated posterior linearisation (filters.iterated) when > 1


class Prior(NamedTuple):
    """What a prediction hands to :func:`measurement_update`, for ``B`` filters."""

    q_m: Tensor  #: the propagated centre ``q_0⁻`` ``(B, 4)``
    omega_m: Tensor | None  #: its rate ``ω_0⁻`` ``(B, 3)`` (rad/s); ``None`` without ω in the state
    x_m: Tensor | None  #: prior mean ``(B, n)`` of the error state about ``[0, ω_0⁻, b̂]``; ``None``: zero
    P_m: Tensor  #: prior covariance ``(B, n, n)``
    chi: Tensor  #: sigma points of the update ``(B, 2n+1, n)``, about the same reference
    failed: Tensor  #: ``(B,)`` whether a square root fell back


def sigma_set(x: Tensor | None, offsets: Tensor) -> Tensor:
    """Sigma points ``[x, x + o_j, x − o_j]`` ``(B, 2n+1, n)`` from offsets ``(B, n, n)`` (row ``j`` = ``o_j``)."""
    B, _, n = offsets.shape
    centre = torch.zeros(B, 1, n, dtype=offsets.dtype, device=offsets.device) if x is None else x.unsqueeze(1)
    return torch.cat([centre, centre + offsets, centre - offsets], dim=1)


def redrawn_sigma_points(run: RunConstants, x_m: Tensor | None, P_m: Tensor) -> tuple[Tensor, Tensor]:
    """The paper's variant (Sec. 2.5, after Eq. (40): the sigma points "are computed again"): ``χ_i⁻ = x̂⁻ ± cols
    √((n+λ) P⁻)`` ``(B, 2n+1, n)``, and ``(B,)`` where the square root fell back."""
    s, failed = sqrt_psd_with_zero_rows(P_m)
    return sigma_set(x_m, math.sqrt(run.scale) * s.mT), failed


def measurement_update(run: RunConstants, state: FilterState, prior: Prior, *, y_k: Tensor,
                       observed_k: Tensor) -> tuple[FilterState, StepRecord]:
    """Steps 6–9 of :func:`lightcurve_gp.filters.usque.run_usque` for ``B`` filters: predicted observation, gain,
    update, reset and the ``m_past`` recursion.

    Args:
        run: the run's constants; state: the posterior at ``k − 1``; prior: the prediction at ``k``.
        y_k: observation ``ỹ_k (B,)`` with missing values filled by 0; observed_k: where it is finite ``(B,)``.
    """
    inputs = sigma_inputs(run, state, prior)
    y_sig, var_sig = run.model(q=inputs.q, m_past=inputs.m_past, variance=run.variance, **inputs.theta)
    return update_with_predictions(run, state, prior, inputs.R_qm, y_sig, var_sig, y_k=y_k, observed_k=observed_k)


class SigmaInputs(NamedTuple):
    """What the model is asked at the sigma points (step 6): attitudes ``q (B, 2n+1, 4)``, the running mean
    ``m_past (B, 2n+1)`` and, with ``θ`` in the state, ``{"theta": (B, 2n+1, p)}`` (else ``{}``); and the right
    product matrix ``R(q_0⁻) (B, 4, 4)`` the reset uses again."""

    q: Tensor
    m_past: Tensor
    theta: dict
    R_qm: Tensor


def sigma_inputs(run: RunConstants, state: FilterState, prior: Prior) -> SigmaInputs:
    """6. the sigma attitudes ``q_i⁻ = δq(χ_i⁻) ⊗ q_0⁻``, asked of the model in one call (one sigma-point set)."""
    chi = prior.chi
    B, S, _ = chi.shape
    R_qm = quat_right_matrix(prior.q_m)
    q_sig = torch.bmm(grp_to_quat(chi[..., :3], *run.grp), R_qm.mT)  # (B, 2n+1, 4)
    theta = {} if state.theta is None else {"theta": state.theta.unsqueeze(1) + chi[..., run.layout.parameter_slice]}
    return SigmaInputs(q_sig, state.m_past.unsqueeze(1).expand(B, S), theta, R_qm)


class Gain(NamedTuple):
    """The Kalman update of one step in the prior's error coordinates (all ``(B, ...)``): the posterior mean ``dx``
    (about ``[0, ω_0⁻, b̂]``, ``x̂⁻`` included) and covariance ``P``, the predicted observation ``y_hat``, its
    variance ``P_yy`` (with ``R_k`` and the model variance), the mean model variance ``m_var`` (NaN without one),
    the innovation ``nu``, where it updated ``upd`` and where the prediction was usable ``good``, and the noise
    ``R_k`` it used."""

    dx: Tensor
    P: Tensor
    y_hat: Tensor
    P_yy: Tensor
    m_var: Tensor
    nu: Tensor
    upd: Tensor
    good: Tensor
    R_k: Tensor


def update_with_predictions(run: RunConstants, state: FilterState, prior: Prior, R_qm: Tensor, y_sig: Tensor,
                            var_sig: Tensor | None, *, y_k: Tensor,
                            observed_k: Tensor) -> tuple[FilterState, StepRecord]:
    """Steps 6–9 given the model's predictions ``y_sig (B, 2n+1)`` and variances (or ``None``) at
    :func:`sigma_inputs` (``R_qm``: its :attr:`SigmaInputs.R_qm`): predicted observation, gain, update, reset and
    the ``m_past`` recursion."""
    gain = kalman_gain(run, state, prior, y_sig, var_sig, y_k=y_k, observed_k=observed_k)
    return posterior(run, state, prior, R_qm, gain, y_k=y_k, observed_k=observed_k)


def kalman_gain(run: RunConstants, state: FilterState, prior: Prior, y_sig: Tensor, var_sig: Tensor | None, *,
                y_k: Tensor, observed_k: Tensor) -> Gain:
    """Steps 6–7: the unscented predicted observation, its variance, the gain and the updated mean and covariance
    (:class:`Gain`) from the predictions ``y_sig (B, 2n+1)`` (and variances) at the prior's sigma points."""
    _, _, x_m, P_m, chi, _ = prior
    B = chi.shape[0]
    layout = run.layout
    zero = torch.zeros((), dtype=chi.dtype, device=chi.device)
    if state.offset is not None:
        y_sig = y_sig + (state.offset.unsqueeze(1) + chi[..., layout.offset_index])
    y_hat = y_sig @ run.wm
    dy = y_sig - y_hat.unsqueeze(1)
    R_k = run.R if state.noise_excess is None else torch.maximum(run.R, state.noise_excess)
    P_yy = (dy * dy) @ run.wc + R_k
    m_var = torch.full((B,), math.nan, dtype=chi.dtype, device=chi.device)
    if var_sig is not None:
        m_var = var_sig @ run.wm
        P_yy = P_yy + m_var
    # Pxy = Σ wc (χ_i⁻ − x̂⁻)(Y_i − ŷ)
    dchi = chi if x_m is None else chi - x_m.unsqueeze(1)
    P_xy = torch.bmm(dchi.mT, (dy * run.wc).unsqueeze(-1)).squeeze(-1)
    # 7. update where the observation exists and the prediction is usable
    good = ((P_xy.sum(-1) + y_hat + P_yy).abs() < math.inf) & (P_yy > 0)  # finite, usable
    upd = observed_k & good
    nu = y_k - y_hat
    K = P_xy / P_yy.unsqueeze(-1)
    # where() keeps inf/NaN of refused steps out of the state: the prior becomes the posterior
    dx = torch.where(upd.unsqueeze(-1), K * nu.unsqueeze(-1), zero)
    if x_m is not None:
        dx = dx + x_m
    P = torch.where(upd.view(B, 1, 1), symmetrise(P_m - P_yy.view(B, 1, 1) * (K.unsqueeze(-1) * K.unsqueeze(-2))),
                    P_m)
    return Gain(dx, P, y_hat, P_yy, m_var, nu, upd, good, R_k)


def posterior(run: RunConstants, state: FilterState, prior: Prior, R_qm: Tensor, gain: Gain, *, y_k: Tensor,
              observed_k: Tensor) -> tuple[FilterState, StepRecord]:
    """Steps 8–9 after :func:`kalman_gain`: the reset of the state to the posterior mean, the ``m_past``
    recursion, the adaptive noise's average, and the step's record."""
    dx, P, y_hat, P_yy, m_var, nu, upd, good, R_k = gain
    a, f = run.grp
    layout = run.layout
    # 8. reset q̂ ← δq(δp⁺) ⊗ q_0⁻ (the attitude error returns to zero); ω̂ ← ω_0⁻ + δω⁺; b̂ ← b̂ + δb⁺; θ̂ ← θ̂ + δθ⁺
    q_hat = torch.bmm(R_qm, grp_to_quat(dx[:, :3], a, f).unsqueeze(-1)).squeeze(-1)
    q_hat = q_hat / torch.linalg.vector_norm(q_hat, dim=-1, keepdim=True)
    offset = None if state.offset is None else state.offset + dx[:, layout.offset_index]
    theta_hat = None if state.theta is None else state.theta + dx[:, layout.parameter_slice]
    omega = None if prior.omega_m is None else prior.omega_m + dx[:, layout.omega_slice]
    # 9. fold the observation into m_past (the record keeps the m_past used for this prediction)
    tsp = run.t_span_past
    m_past = torch.where(observed_k, (tsp * state.m_past + y_k) / (tsp + 1.0), state.m_past)
    noise_excess = state.noise_excess
    if noise_excess is not None:
        noise_excess = torch.where(upd, adapted_noise(noise_excess, nu=nu, P_yy=P_yy, R_k=R_k, rate=run.adaptive_rate),
                                   noise_excess)
    record = StepRecord(y_hat, P_yy, m_var, nu, state.m_past, upd, prior.failed, observed_k & ~good)
    return FilterState(q_hat, offset, P, m_past, noise_excess, theta=theta_hat, omega=omega), record


def adapted_noise(average: Tensor, *, nu: Tensor, P_yy: Tensor, R_k: Tensor, rate: float) -> Tensor:
    """One step of the innovation-based measurement-noise estimate (covariance matching, Mehra 1972), all ``(B,)``.

    The innovation ``ν = ỹ − ŷ`` of a consistent filter has ``E ν² = Pyy``; its part not explained by the
    predicted spread and model variance, ``e = ν² − (Pyy − R_k)``, estimates the measurement noise. An observation
    model that is wrong along the true trajectory (an unmodelled surface: a glint, a lobe the GP never saw) shows
    up as an excess ``E e = R + bias²``, whatever the trajectory. The exponential average
    ``c ← (1 − λ) c + λ e`` (``λ = dt / τ``) is returned; the next step uses ``R̂ = max(R, c)`` — never below the
    configured noise, and only past innovations (no look-ahead).

    Args:
        average: the running average ``c`` before this step (mag²).
        nu: innovations (mag); P_yy: their predicted variance with ``R_k`` (mag²); R_k: the noise used (mag²).
        rate: ``λ`` in ``(0, 1]``.
    """
    excess = nu * nu - (P_yy - R_k)
    return average + rate * (excess - average)
