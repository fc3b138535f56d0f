"""What the prior and the light curve allow: a batch maximum-a-posteriori (MAP) estimate of the attitude.

Not a filter: at each checkpoint ``t`` Gauss–Newton maximises the posterior of the initial attitude (and, with an
offset, the magnitude offset ``b``) given the observations ``ỹ_1 … ỹ_t``, the known dynamics (the per-step
quaternion increments) and the filters' prior — ``q_est,0`` with ``P0 = (p0_deg)² I`` on the rotation vector and,
with an offset, ``b ~ N(ỹ_0 − h(q̂_0), offset_prior_std²)`` — re-linearising every observation at every
iteration. The estimate at ``t`` uses no later observation, so its Euler-angle RMSE over the checkpoints is
comparable with a filter's over the scoring window. Every seed is solved in the same batch.

The state is ``x = [e, b]``: ``e`` the rotation vector (rad) of ``q_0 ⊗ q_est,0⁻¹`` and ``b`` the offset (mag).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch
from torch import Tensor

from .estimation import propagate_only
from .metrics import attitude_errors_deg
from .observation.base import ObservationModel
from .rotations import quat_mul, rotvec_to_quat

__all__ = ["MapPrior", "batch_map", "map_attitude", "map_rmse_deg"]


@dataclass(frozen=True)
class MapPrior:
    """The filters' prior: ``p0_deg`` (deg, per axis), the measurement noise variance ``R`` (mag²) and the offset's
    prior standard deviation (mag, used only with an offset)."""

    p0_deg: float
    measurement_noise: float
    offset_prior_std: float = 1.0

    def precision(self, offset: bool, dtype: torch.dtype) -> Tensor:
        """Diagonal of the prior information matrix ``(3,)`` or ``(4,)``."""
        values = [math.radians(self.p0_deg) ** -2] * 3 + [self.offset_prior_std ** -2] * offset
        return torch.tensor(values, dtype=dtype)


def _predict(model: ObservationModel, x: Tensor, q_est0: Tensor, increments: Tensor, m_past: Tensor,
             offset: bool) -> Tensor:
    """Magnitudes ``(S, T+1)`` of states ``x (S, 3 | 4)`` along the known dynamics."""
    q = propagate_only(quat_mul(rotvec_to_quat(x[:, :3]), q_est0), increments)
    m, _ = model(q=q, m_past=m_past.expand(-1, q.shape[1]), variance="none")
    return m + x[:, 3:] if offset else m


def batch_map(model: ObservationModel, *, q_est0: Tensor, increments: Tensor, observations: Tensor,
              prior: MapPrior, checkpoints: Sequence[int], offset: bool, iterations: int = 15,
              step: float = 1e-5) -> dict[int, Tensor]:
    """MAP states ``x (S, 3 | 4)`` at each checkpoint index (observations ``1 … t`` used).

    Args:
        model: observation model; its ``m_past`` input is held at the first observation.
        q_est0: initial estimate ``(4,)`` or ``(S, 4)``, the prior mean.
        increments: per-step quaternion increments ``(T, 4)``.
        observations: ``(S, T+1)`` magnitudes, ``ỹ_0`` first.
        checkpoints: step indices ``t`` in increasing order; each solve starts from the previous one.
        offset: estimate a magnitude offset ``b`` as a fourth state.
        iterations: Gauss–Newton iterations per checkpoint at most (stops when the attitude step is < 1e-9 rad).
        step: central-difference step of the Jacobian (rad, mag).
    """
    S, n, dtype = observations.shape[0], 4 if offset else 3, observations.dtype
    R = prior.measurement_noise
    prior_prec = prior.precision(offset, dtype)
    m_past = observations[:, :1]

    def predict(x: Tensor) -> Tensor:
        return _predict(model, x, q_est0, increments, m_past, offset)

    x0 = torch.zeros(S, n, dtype=dtype)
    if offset:
        x0[:, 3] = observations[:, 0] - predict(x0)[:, 0]
    x, out = x0.clone(), {}
    for t in checkpoints:
        for _ in range(iterations):
            m = predict(x)
            J = torch.stack([(predict(x + d) - predict(x - d)) / (2 * step) for d in step * torch.eye(n, dtype=dtype)],
                            -1)
            J, r = J[:, 1:t + 1], (observations - m)[:, 1:t + 1]
            H = J.mT @ J / R + torch.diag(prior_prec)
            g = (J.mT @ r.unsqueeze(-1)).squeeze(-1) / R - (x - x0) * prior_prec
            dx = torch.linalg.solve(H, g)
            x = x + dx
            if float(dx[:, :3].abs().max()) < 1e-9:
                break
        out[t] = x.clone()
    return out


def map_attitude(x: Tensor, *, q_est0: Tensor, increments: Tensor) -> Tensor:
    """The attitude ``(S, 4)`` after ``len(increments)`` steps of the MAP initial attitude of states ``x``."""
    return propagate_only(quat_mul(rotvec_to_quat(x[:, :3]), q_est0), increments)[:, -1]


def map_rmse_deg(estimates: dict[int, Tensor], *, q_true: Tensor, q_est0: Tensor, increments: Tensor) -> Tensor:
    """Euler-angle RMSE ``(S, 3)`` (deg) over the checkpoints of :func:`batch_map`'s estimates against the true
    attitudes ``q_true (T+1, 4)``."""
    errors = [attitude_errors_deg(q_true[t], map_attitude(x, q_est0=q_est0, increments=increments[:t]))
              for t, x in estimates.items()]
    return torch.stack(errors, 1).pow(2).mean(1).sqrt()
