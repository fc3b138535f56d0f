"""Error metrics: Euler 3-2-1 attitude errors, windowed RMSE, filter consistency (NEES / NIS) and χ² bands.

The paper (Sec. 4.2) scores a run by the RMSE of the 3-2-1 Euler angles of ``q_err = q_true ⊗ q_est⁻¹`` over
400–600 s (docs/design.md). ``q`` and ``−q`` are the same attitude, so every attitude metric is sign invariant.
Tensors carry arbitrary leading batch dimensions; NaN marks missing values and is ignored by the RMSEs.
"""

from __future__ import annotations

import math
from typing import Sequence

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import quat_conj, quat_mul, quat_to_euler321, quat_to_grp, quat_to_rotvec

__all__ = [
    "attitude_error_quat",
    "attitude_errors_deg",
    "total_angle_deg",
    "attitude_error_vector",
    "rmse_over_window",
    "lightcurve_rmse",
    "nees",
    "nis",
    "chi2_band",
    "model_error_on_trajectory",
]


def _as_tensor(x) -> Tensor:
    return x if isinstance(x, Tensor) else torch.as_tensor(x, dtype=torch.get_default_dtype())


def attitude_error_quat(q_true: Tensor, q_est: Tensor) -> Tensor:
    """Error quaternions ``q_err = q_true ⊗ q_est⁻¹`` ``(..., 4)`` (inputs normalised first; shapes broadcast)."""
    q_true, q_est = _as_tensor(q_true), _as_tensor(q_est)
    q_true = q_true / torch.linalg.vector_norm(q_true, dim=-1, keepdim=True)
    q_est = q_est / torch.linalg.vector_norm(q_est, dim=-1, keepdim=True)
    return quat_mul(q_true, quat_conj(q_est))


def attitude_errors_deg(q_true: Tensor, q_est: Tensor) -> Tensor:
    """3-2-1 Euler angles (yaw φ, pitch θ, roll ψ) of ``q_err = q_true ⊗ q_est⁻¹`` in degrees, ``(..., 3)``.

    Yaw and roll lie in ``(−180, 180]``, pitch in ``[−90, 90]``. Sign invariant in both arguments.
    """
    return torch.rad2deg(quat_to_euler321(attitude_error_quat(q_true, q_est)))


def total_angle_deg(q_true: Tensor, q_est: Tensor) -> Tensor:
    """Rotation angle of ``q_err`` in degrees, in ``[0, 180]``, shape ``(...)``."""
    qe = attitude_error_quat(q_true, q_est)
    return torch.rad2deg(2.0 * torch.atan2(torch.linalg.vector_norm(qe[..., :3], dim=-1), qe[..., 3].abs()))


def attitude_error_vector(q_true: Tensor, q_est: Tensor, kind: str = "rotvec", *, a: float = 1.0,
                          f: float | None = None) -> Tensor:
    """Three-parameter attitude error of ``q_err = q_true ⊗ q_est⁻¹`` for :func:`nees`, ``(..., 3)``.

    Args:
        kind: ``"rotvec"`` (rotation vector Φe, rad) or ``"grp"`` (GRP ``f q̄ / (a + q4)``, the filter's own
            error state; with ``f = 2(a + 1)`` it equals the rotation vector to first order, so both give the
            same NEES for small errors).
    """
    qe = attitude_error_quat(q_true, q_est)
    if kind == "rotvec":
        return quat_to_rotvec(qe)
    if kind == "grp":
        return quat_to_grp(qe, a, f)
    raise ValueError(f"kind must be 'rotvec' or 'grp', got {kind!r}")


def _window_mask(times: Tensor, window: Sequence[float]) -> Tensor:
    lo, hi = float(window[0]), float(window[1])
    if hi < lo:
        raise ValueError(f"window end {hi:g} is before its start {lo:g}")
    return (times >= lo) & (times <= hi)


def rmse_over_window(values: Tensor, times: Tensor, window: Sequence[float] = (400.0, 600.0)) -> Tensor:
    """Root mean square of ``values (..., T)`` over the samples with ``window[0] ≤ t ≤ window[1]``.

    NaN samples are ignored; a row with no finite sample in the window gives NaN.

    Args:
        values: ``(..., T)``, e.g. one Euler angle error per time step (move angle axes before time first).
        times: ``(T,)`` sample times in seconds.
        window: inclusive ``(start, end)`` in seconds.

    Returns:
        ``(...)``.
    """
    values, times = _as_tensor(values), _as_tensor(times)
    if times.ndim != 1 or values.shape[-1] != times.shape[0]:
        raise ValueError(f"times {tuple(times.shape)} must be (T,) with T = values.shape[-1] "
                         f"(values {tuple(values.shape)})")
    v = values[..., _window_mask(times.to(values.device), window)]
    ok = torch.isfinite(v)
    sq = torch.where(ok, v * v, torch.zeros_like(v)).sum(-1)
    cnt = ok.sum(-1)
    return torch.where(cnt > 0, (sq / cnt.clamp_min(1)).sqrt(), torch.full_like(sq, math.nan))


def lightcurve_rmse(pred: Tensor, reference: Tensor, times: Tensor,
                    window: Sequence[float] = (400.0, 600.0)) -> Tensor:
    """RMSE of ``pred − reference`` (magnitudes ``(..., T)``) over an inclusive time window, NaN ignored."""
    return rmse_over_window(_as_tensor(pred) - _as_tensor(reference), times, window)


def nees(err_vec: Tensor, P: Tensor) -> Tensor:
    """Normalised estimation error squared ``eᵀ P⁻¹ e`` for errors ``(..., 3)`` and covariances ``(..., 3, 3)``.

    For USQUE pass :func:`attitude_error_vector` of the truth against the posterior estimate (rotation vector
    by default; the GRP error is the filter's own state and agrees to first order) and the posterior ``P``.
    Consistent errors give ``E[NEES] = 3``; compare averages with :func:`chi2_band`.
    """
    err_vec, P = _as_tensor(err_vec), _as_tensor(P)
    P = 0.5 * (P + P.transpose(-1, -2))
    sol = torch.linalg.solve(P, err_vec.unsqueeze(-1)).squeeze(-1)
    return (err_vec * sol).sum(-1)


def nis(innovation: Tensor, S: Tensor) -> Tensor:
    """Normalised innovation squared ``νᵀ S⁻¹ ν``.

    Scalar measurements: ``innovation`` and ``S`` of the same shape ``(...)`` give ``ν² / S``.
    Vector measurements: ``innovation (..., m)`` and ``S (..., m, m)``. NaN innovations give NaN.
    """
    innovation, S = _as_tensor(innovation), _as_tensor(S)
    if S.shape == innovation.shape:
        return innovation * innovation / S
    if S.shape[-2:] != (innovation.shape[-1], innovation.shape[-1]):
        raise ValueError(f"S {tuple(S.shape)} matches neither innovation {tuple(innovation.shape)} nor (..., m, m)")
    sol = torch.linalg.solve(0.5 * (S + S.transpose(-1, -2)), innovation.unsqueeze(-1)).squeeze(-1)
    return (innovation * sol).sum(-1)


def chi2_band(dof: int, n_samples: int, confidence: float = 0.95) -> tuple[float, float]:
    """Two-sided ``confidence`` interval of the mean of ``n_samples`` independent χ²(dof) statistics.

    ``n · mean ~ χ²(n · dof)``, so the band is ``χ²⁻¹((1 ∓ c)/2; n dof) / n``; consistent NEES/NIS averages fall
    inside it with probability ``confidence``.
    """
    from scipy.stats import chi2

    if dof < 1 or n_samples < 1 or not 0.0 < confidence < 1.0:
        raise ValueError(f"need dof >= 1, n_samples >= 1, 0 < confidence < 1; got {dof}, {n_samples}, {confidence}")
    k = dof * n_samples
    lo, hi = chi2.ppf(0.5 * (1.0 - confidence), k), chi2.ppf(0.5 * (1.0 + confidence), k)
    return float(lo / n_samples), float(hi / n_samples)


def model_error_on_trajectory(model, *, q: Tensor, m_true: Tensor, m_past: Tensor,
                              variance: str = "fast") -> dict[str, float]:
    """An observation model's error against the true light curve along one trajectory (all in mag).

    Args:
        model: an :class:`~lightcurve_gp.observation.base.ObservationModel`.
        q: attitudes ``(T, 4)`` of the trajectory.
        m_true: the noise-free magnitudes ``(T,)`` there (e.g. the renderer's at the model's reference ρ).
        m_past: the model's ``m_past`` input ``(T,)``.
        variance: the model's variance choice (``"fast"`` or ``"exact"``).

    Returns:
        ``mean_error`` (mean of prediction − truth), ``rms_about_mean`` (its spread), ``rms`` and
        ``mean_predictive_std`` (mean of the model's predictive standard deviation).
    """
    mean, var = model(q=q, m_past=m_past, variance=variance)
    err = mean - m_true
    return {"mean_error": float(err.mean()), "rms_about_mean": float((err - err.mean()).pow(2).mean().sqrt()),
            "rms": float(err.pow(2).mean().sqrt()), "mean_predictive_std": float(var.sqrt().mean())}
