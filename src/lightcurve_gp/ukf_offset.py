"""USQUE with a magnitude offset in the state: joint attitude and reflectance estimation.

The light curve of the paper's object is diffuse-dominated, so its magnitude at reflectance ρ is the magnitude at a
reference ``ρ0`` shifted by a constant (paper eq. mApp with ``c_d ∝ ρ``)::

    m(q; ρ) = m(q; ρ0) − 2.5 log10(ρ / ρ0)

An unknown ρ is therefore an unknown offset ``b`` on a reference light curve. This filter augments USQUE's GRP
attitude error ``δp`` (3) with ``b`` (1, mag, a random walk) and predicts

    y = h(q, m_past) + b

with any :class:`~lightcurve_gp.observation.base.ObservationModel` ``h`` of the reference curve: the renderer with
``ρ0`` (a conventional UKF that estimates ρ) or a GP trained on ρ-normalised magnitudes (the GPUKF with an offset).
Steps are those of :func:`lightcurve_gp.ukf.run_usque` on the 4-dimensional state ``x = [δp, b]``; the attitude part
is reset to zero after every update while ``b`` carries its estimate (Crassidis & Markley 2003, with the bias-state
pattern of their gyro-bias filter, here a measurement bias). The offset's estimate maps back to a reflectance by
:func:`offset_to_rho`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from .rotations import grp_to_quat, quat_to_grp
from .ukf import (FilterHistory, UsqueParams, _as_cov, _left_matrix, _right_matrix, _right_matrix_conj, _sqrt_psd,
                  _symmetrise, _warn_fallbacks, unscented_weights)

__all__ = ["OffsetFilterHistory", "offset_to_rho", "rho_to_offset", "initial_offset", "run_usque_offset"]


def rho_to_offset(rho: float | Tensor, rho_reference: float) -> float | Tensor:
    """Magnitude offset ``b = −2.5 log10(ρ / ρ0)`` of a diffuse-dominated light curve (mag)."""
    if isinstance(rho, Tensor):
        return -2.5 * torch.log10(rho / rho_reference)
    if not rho > 0 or not rho_reference > 0:
        raise ValueError(f"rho and rho_reference must be positive, got {rho!r} and {rho_reference!r}")
    return -2.5 * math.log10(rho / rho_reference)


def offset_to_rho(offset: Tensor, rho_reference: float) -> Tensor:
    """Inverse of :func:`rho_to_offset`: ``ρ = ρ0 · 10^(−b / 2.5)`` for offsets ``(...)`` in mag."""
    return rho_reference * torch.pow(10.0, -offset / 2.5)


def initial_offset(model, q_est0: Tensor, y0: Tensor, m_past0: Tensor) -> Tensor:
    """Offset prior mean from the first observation: ``b0 = ỹ_0 − h(q̂_0, m_past0)`` ``(B,)`` (mag).

    A non-finite ``ỹ_0`` or prediction gives ``b0 = 0`` for that filter (the prior std then carries it).
    """
    with torch.no_grad():
        pred, _ = model(q=q_est0, m_past=m_past0.expand(q_est0.shape[:-1]), with_variance=False)
    b0 = y0.to(pred) - pred
    return torch.where(torch.isfinite(b0), b0, torch.zeros_like(b0))


@dataclass
class OffsetFilterHistory(FilterHistory):
    """:class:`~lightcurve_gp.ukf.FilterHistory` (``P`` is the attitude block) plus the offset state.

    Attributes:
        offset: posterior offset estimates ``b_k`` ``(B, T+1)`` (mag); ``k = 0`` is the prior mean.
        offset_var: posterior offset variances ``(B, T+1)`` (mag²).
        P_full: posterior covariances of ``[δp, b]`` ``(B, T+1, 4, 4)``.
    """

    offset: Tensor
    offset_var: Tensor
    P_full: Tensor


def _check_offset_inputs(q_est0: Tensor, P0: Tensor, b0: Tensor, observations: Tensor, m_past0: Tensor,
                         increments: Tensor) -> tuple[int, int]:
    if q_est0.ndim != 2 or q_est0.shape[-1] != 4:
        raise ValueError(f"q_est0 must have shape (B, 4), got {tuple(q_est0.shape)}")
    B = q_est0.shape[0]
    if observations.ndim != 2 or observations.shape[0] != B:
        raise ValueError(f"observations must have shape (B={B}, T+1), got {tuple(observations.shape)}")
    T = observations.shape[1] - 1
    if P0.shape not in ((4, 4), (B, 4, 4)):
        raise ValueError(f"P0 must have shape (4, 4) or (B={B}, 4, 4) for the state [dp, b], got {tuple(P0.shape)}")
    if b0.shape not in ((B,), ()):
        raise ValueError(f"b0 must have shape (B={B},) or (), got {tuple(b0.shape)}")
    if m_past0.shape not in ((B,), ()):
        raise ValueError(f"m_past0 must have shape (B={B},), got {tuple(m_past0.shape)}")
    if increments.shape not in ((T, 4), (B, T, 4)):
        raise ValueError(f"increments must have shape (T={T}, 4) or (B={B}, T={T}, 4), got {tuple(increments.shape)}")
    for name, t in (("q_est0", q_est0), ("P0", P0), ("b0", b0), ("m_past0", m_past0), ("increments", increments)):
        if not bool(torch.isfinite(t).all()):
            raise ValueError(f"{name} contains non-finite values")
    return B, T


def run_usque_offset(model, q_est0: Tensor, P0: Tensor, b0: Tensor, observations: Tensor, m_past0: Tensor,
                     increments: Tensor, params: UsqueParams | None = None, *,
                     offset_process_noise: float = 0.0) -> OffsetFilterHistory:
    """Run ``B`` USQUE filters on ``x = [δp (3), b (1)]`` with ``y = h(q, m_past) + b``.

    Step ``k = 1 … T`` (as :func:`~lightcurve_gp.ukf.run_usque`, with ``Q̄ = diag(Q, q_b)``, ``n = 4``):

    1. ``χ_i = x̂⁺ ± cols √((n+λ)(P⁺ + Q̄))`` with ``x̂⁺ = [0, b̂]``; 2-4. the attitude parts propagate through
       ``δ_{k−1}`` and return as GRP errors about the propagated central point; ``b_i`` is unchanged;
    5. ``x̂⁻ = Σ wm χ_i⁻``, ``P⁻ = Σ wc (χ_i⁻ − x̂⁻)(·)ᵀ + Q̄``;
    6. ``Y_i = h(q_i⁻, m_past) + b_i``, ``Pyy = Σ wc (Y_i − ŷ)² + R (+ Σ wm var_i)``, ``Pxy = Σ wc (χ_i⁻ − x̂⁻)(Y_i − ŷ)``;
    7. ``K = Pxy / Pyy``, ``x̂⁺ = x̂⁻ + K ν``, ``P⁺ = P⁻ − K Pyy Kᵀ``;
    8. ``q̂ ← δq(x̂⁺[:3]) ⊗ q_0⁻``, ``b̂ ← x̂⁺[3]``; 9. ``m_past ← (T m_past + ỹ_k)/(T + 1)``.

    Missing (NaN) observations and unusable predictions are handled as in ``run_usque``.

    Args:
        model: observation model of the reference light curve (offset 0).
        q_est0: initial attitude estimates ``(B, 4)``.
        P0: initial covariance of ``[δp, b]`` ``(4, 4)`` or ``(B, 4, 4)`` (rad², mag²).
        b0: initial offset estimates ``(B,)`` or ``()`` (mag), e.g. from :func:`initial_offset`.
        observations: ``ỹ_0 … ỹ_T`` ``(B, T+1)`` (mag, NaN = missing).
        m_past0: running mean at ``t_0`` ``(B,)`` (ignored by models with ``uses_m_past = False``).
        increments: kinematic increments ``(T, 4)`` or ``(B, T, 4)``.
        params: attitude tuning (``Q`` the attitude block; ``λ``, ``α``, ``β``, ``κ`` apply to ``n = 4``).
        offset_process_noise: random-walk variance of ``b`` per step ``q_b`` (mag²), ``≥ 0``.

    Returns:
        :class:`OffsetFilterHistory`.
    """
    params = params or UsqueParams()
    B, T = _check_offset_inputs(q_est0, P0, b0, observations, m_past0, increments)
    if not float(offset_process_noise) >= 0.0:
        raise ValueError(f"offset_process_noise must be >= 0, got {offset_process_noise!r}")
    dtype, device = q_est0.dtype, q_est0.device
    n = 4
    a, f = float(params.grp_a), float(params.grp_f)
    with torch.no_grad():
        lam, wm, wc = unscented_weights(n, params.alpha, params.beta, params.kappa, params.lam, dtype=dtype,
                                        device=device)
        scale = n + lam
        Qa = _as_cov(params.Q if isinstance(params.Q, Tensor) else float(params.Q), 3, q_est0)
        if Qa.shape not in ((3, 3), (B, 3, 3)):
            raise ValueError(f"Q must be a scalar, (3, 3) or (B={B}, 3, 3), got {tuple(Qa.shape)}")
        Q = torch.zeros(B, n, n, dtype=dtype, device=device)
        Q[:, :3, :3] = _symmetrise(Qa)
        Q[:, 3, 3] = float(offset_process_noise)
        R = torch.as_tensor(params.R, dtype=dtype, device=device)
        if R.shape not in ((), (B,)):
            raise ValueError(f"R must be a scalar or (B={B},), got {tuple(R.shape)}")
        R = R.expand(B)
        tsp = float(params.t_span_past)

        obs = observations.to(dtype=dtype, device=device)
        obs_ok = torch.isfinite(obs)
        obs_filled = torch.where(obs_ok, obs, torch.zeros_like(obs))
        inc = increments.to(dtype=dtype, device=device)
        inc = inc / torch.linalg.vector_norm(inc, dim=-1, keepdim=True)
        L_inc = _left_matrix(inc.unsqueeze(0) if inc.ndim == 2 else inc)

        q_hat = q_est0.to(dtype=dtype).clone()
        q_hat = q_hat / torch.linalg.vector_norm(q_hat, dim=-1, keepdim=True)
        b_hat = b0.to(dtype=dtype, device=device).expand(B).clone()
        P = _symmetrise(P0.to(dtype=dtype, device=device).expand(B, n, n)).clone()
        m_past = m_past0.to(dtype=dtype, device=device).expand(B).clone()
        fallbacks = torch.zeros(B, dtype=torch.int64, device=device)
        rejected = torch.zeros(B, dtype=torch.int64, device=device)
        want_var = bool(params.add_model_variance)
        nan_b = torch.full((B,), math.nan, dtype=dtype, device=device)
        zero = torch.zeros((), dtype=dtype, device=device)
        n_sig = 2 * n + 1
        wm_row = wm.view(1, 1, n_sig).expand(B, 1, n_sig)
        wc_col = wc.unsqueeze(-1)

        h_q, h_P, h_y, h_yv, h_mv, h_nu, h_mp = [q_hat], [P], [nan_b], [nan_b], [nan_b], [nan_b], [m_past]
        h_b = [b_hat]
        h_up = [torch.zeros(B, dtype=torch.bool, device=device)]

        for k in range(1, T + 1):
            s, failed = _sqrt_psd(scale * (P + Q))
            fallbacks += failed
            cols = s.transpose(-1, -2)  # (B, 4, 4): row j = column j of S
            centre = torch.cat([torch.zeros(B, 3, dtype=dtype, device=device), b_hat.unsqueeze(-1)], -1)
            chi = centre.unsqueeze(1) + torch.cat([torch.zeros(B, 1, n, dtype=dtype, device=device), cols, -cols], 1)
            dq = grp_to_quat(chi[..., :3], a, f)  # (B, S, 4)
            M = L_inc[:, k - 1] @ _right_matrix(q_hat)
            q0m = M[:, :, 3]
            N = torch.bmm(_right_matrix_conj(q0m), M)
            both = torch.bmm(dq, torch.cat([M, N], dim=1).transpose(1, 2))
            q_sig = both[..., :4]
            q_sig = q_sig / torch.linalg.vector_norm(q_sig, dim=-1, keepdim=True)
            dp_m = quat_to_grp(both[..., 4:], a, f)
            dp_m[:, 0] = 0.0
            chi_m = torch.cat([dp_m, chi[..., 3:]], -1)  # (B, S, 4)
            x_m = torch.bmm(wm_row, chi_m)  # (B, 1, 4)
            dx = chi_m - x_m
            dxw_t = (dx * wc_col).transpose(1, 2)
            P_m = torch.baddbmm(Q, dxw_t, dx)
            h_sig, var_sig = model(q=q_sig, m_past=m_past.unsqueeze(1).expand(B, n_sig), with_variance=want_var)
            y_sig = h_sig + chi_m[..., 3]
            y_hat = y_sig @ wm
            dy = y_sig - y_hat.unsqueeze(1)
            P_yy = (dy * dy) @ wc + R
            if want_var and var_sig is not None:
                m_var = var_sig @ wm
                P_yy = P_yy + m_var
            else:
                m_var = nan_b
            P_xy = torch.bmm(dxw_t, dy.unsqueeze(-1)).squeeze(-1)  # (B, 4)
            ok_k = obs_ok[:, k]
            good = torch.isfinite(P_xy.sum(-1) + y_hat + P_yy) & (P_yy > 0)
            upd = ok_k & good
            rejected += ok_k & ~good
            nu = obs_filled[:, k] - y_hat
            yy_used = torch.where(upd, P_yy, zero).unsqueeze(-1)
            K = torch.where(upd.unsqueeze(-1), P_xy / P_yy.unsqueeze(-1), zero)
            x_p = x_m.squeeze(1) + K * torch.where(upd, nu, zero).unsqueeze(-1)
            P = _symmetrise(P_m - (yy_used * K).unsqueeze(-1) * K.unsqueeze(-2))
            q_hat = torch.bmm(_right_matrix(q0m), grp_to_quat(x_p[:, :3], a, f).unsqueeze(-1)).squeeze(-1)
            q_hat = q_hat / torch.linalg.vector_norm(q_hat, dim=-1, keepdim=True)
            b_hat = x_p[:, 3]
            h_q.append(q_hat)
            h_P.append(P)
            h_y.append(y_hat)
            h_yv.append(P_yy)
            h_mv.append(m_var)
            h_nu.append(nu)
            h_mp.append(m_past)
            h_b.append(b_hat)
            h_up.append(upd)
            m_past = torch.where(ok_k, (tsp * m_past + obs_filled[:, k]) / (tsp + 1.0), m_past)

        P_full = torch.stack(h_P, 1)
        hist = OffsetFilterHistory(
            q_est=torch.stack(h_q, 1), P=P_full[..., :3, :3], y_pred=torch.stack(h_y, 1),
            y_var=torch.stack(h_yv, 1), model_var=torch.stack(h_mv, 1),
            innovation=torch.where(obs_ok, torch.stack(h_nu, 1), math.nan), m_past=torch.stack(h_mp, 1),
            updated=torch.stack(h_up, 1), fallbacks=fallbacks, rejected=rejected, m_past_final=m_past,
            offset=torch.stack(h_b, 1), offset_var=P_full[..., 3, 3], P_full=P_full,
        )
    n_fb = int((fallbacks > 0).sum())
    if n_fb:
        _warn_fallbacks(n_fb, B, "run_usque_offset")
    return hist
