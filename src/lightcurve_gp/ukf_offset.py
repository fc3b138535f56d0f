"""USQUE with a magnitude offset in the state: joint attitude and reflectance estimation.

The light curve of the paper's object is diffuse-dominated, so its magnitude at reflectance ρ is the magnitude at a
reference ``ρ0`` shifted by a constant (paper Eq. (8) with ``c_d ∝ ρ``, Eq. (4))::

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

from .ukf import FilterHistory, UsqueParams, _usque_loop, _warn_fallbacks, initial_covariance

__all__ = ["OffsetFilterHistory", "offset_to_rho", "rho_to_offset", "initial_offset", "offset_covariance",
           "run_usque_offset"]


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


def offset_covariance(p0_deg: float, offset_prior_std: float, *, dtype=None, device=None) -> Tensor:
    """``P0 = diag((p0_deg in rad)² I₃, offset_prior_std²)`` ``(4, 4)`` for the state ``[δp, b]``."""
    P0 = torch.zeros(4, 4, dtype=dtype or torch.get_default_dtype(), device=device)
    P0[:3, :3] = initial_covariance(p0_deg, dtype=P0.dtype, device=device)
    P0[3, 3] = offset_prior_std**2
    return P0


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


def run_usque_offset(model, q_est0: Tensor, P0: Tensor, b0: Tensor, observations: Tensor, m_past0: Tensor,
                     increments: Tensor, params: UsqueParams | None = None, *,
                     offset_process_noise: float = 0.0) -> OffsetFilterHistory:
    """Run ``B`` USQUE filters on ``x = [δp (3), b (1)]`` with ``y = h(q, m_past) + b``.

    Step ``k = 1 … T`` (as :func:`~lightcurve_gp.ukf.run_usque`, with ``Q̄ = diag(Q, q_b)``, ``n = 4``):

    1. ``χ_i = x̂⁺ ± cols √((n+λ)(P⁺ + Q̄))`` with ``x̂⁺ = [0, b̂]``; 2-4. the attitude parts propagate through
       ``δ_{k−1}`` and return as GRP errors about the propagated central point; ``b_i`` is unchanged;
    5. ``x̂⁻ = Σ wm χ_i⁻``, ``P⁻ = Σ wc (χ_i⁻ − x̂⁻)(·)ᵀ + Q̄``;
    6. ``Y_i = h(q_i⁻, m_past) + b_i``, ``Pyy = Σ wc (Y_i − ŷ)² + R (+ Σ wm var_i)``,
       ``Pxy = Σ wc (χ_i⁻ − x̂⁻)(Y_i − ŷ)``;
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
    if not float(offset_process_noise) >= 0.0:
        raise ValueError(f"offset_process_noise must be >= 0, got {offset_process_noise!r}")
    out = _usque_loop(model, q_est0, P0, b0, observations, m_past0, increments, params or UsqueParams(),
                      offset_process_noise=float(offset_process_noise))
    n_fb = int((out["fallbacks"] > 0).sum())
    if n_fb:
        _warn_fallbacks(n_fb, q_est0.shape[0], "run_usque_offset")
    P_full = out.pop("P")
    return OffsetFilterHistory(P=P_full[..., :3, :3], offset_var=P_full[..., 3, 3], P_full=P_full, **out)
