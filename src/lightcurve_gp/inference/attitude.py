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

from lightcurve_gp.attitude.dynamics import propagate_only
from lightcurve_gp.attitude.metrics import attitude_errors_deg
from lightcurve_gp.attitude.rotations import quat_mul, rotvec_to_quat
from lightcurve_gp.inference.solver import GaussianPrior, LeastSquaresOptions, batch_least_squares
from lightcurve_gp.observation.base import ObservationModel

__all__ = ["MapPrior", "chunked_magnitudes", "map_attitude", "map_known_rate", "map_rmse_deg", "select_seeds"]


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


def chunked_magnitudes(model: ObservationModel, *, q: Tensor, m_past: Tensor, chunk: int) -> Tensor:
    """Magnitudes ``(A, t+1)`` (mag) of attitudes ``q (A, t+1, 4)`` with their held inputs ``m_past (A, 1)`` (mag),
    the model evaluated ``chunk`` rows at a time (its memory: that of one chunk)."""
    t1 = q.shape[1]
    parts = [model(q=qc, m_past=mc.expand(-1, t1), variance="none")[0] for qc, mc in zip(q.split(chunk),
                                                                                       m_past.split(chunk))]
    return torch.cat(parts)


def select_seeds(values: Tensor, rows: Tensor) -> Tensor:
    """``values`` as given when shared (``(4,)``, one initial estimate for every seed), else its rows
    ``values[rows]`` (``(S, 4)`` per seed)."""
    return values if values.dim() == 1 else values[rows]


def _magnitudes(model: ObservationModel, x: Tensor, rows: Tensor, *, q_est0: Tensor, increments: Tensor,
                m_past: Tensor) -> Tensor:
    """Magnitudes ``(A, t+1)`` of states ``x (A, 3 | 4)`` of the seeds ``rows`` along the known dynamics
    (``increments (t, 4)``), the offset added with a fourth state."""
    q = propagate_only(quat_mul(rotvec_to_quat(x[:, :3]), select_seeds(q_est0, rows)), increments)
    m = chunked_magnitudes(model, q=q, m_past=m_past[rows], chunk=m_past.shape[0])
    return m + x[:, 3:] if x.shape[-1] == 4 else m


def map_known_rate(model: ObservationModel, *, q_est0: Tensor, increments: Tensor, observations: Tensor,
                   prior: MapPrior, checkpoints: Sequence[int], offset: bool, iterations: int = 15,
                   step: float = 1e-5) -> dict[int, Tensor]:
    """MAP states ``x (S, 3 | 4)`` at each checkpoint index (observations ``1 … t`` used).

    Gauss–Newton (:func:`~lightcurve_gp.inference.solver.batch_least_squares`, central differences) on the
    residuals ``ỹ_k − h(q_k) − b`` of variance ``R``, ``k = 1 … t``, until every attitude component of every seed's
    step is below 1e-9 rad.

    Args:
        model: observation model; its ``m_past`` input is held at the first observation.
        q_est0: initial estimate ``(4,)`` or ``(S, 4)``, the prior mean.
        increments: per-step quaternion increments ``(T, 4)``.
        observations: ``(S, T+1)`` magnitudes, ``ỹ_0`` first.
        checkpoints: step indices ``t`` in increasing order; each solve starts from the previous one.
        offset: estimate a magnitude offset ``b`` as a fourth state.
        iterations: Gauss–Newton iterations per checkpoint at most.
        step: central-difference step of the Jacobian (rad, mag).
    """
    S, n, dtype = observations.shape[0], 4 if offset else 3, observations.dtype
    m_past, every = observations[:, :1], torch.arange(S)
    x0 = torch.zeros(S, n, dtype=dtype)
    if offset:
        x0[:, 3] = observations[:, 0] - _magnitudes(model, x0[:, :3], every, q_est0=q_est0,
                                                    increments=increments[:0], m_past=m_past)[:, 0]
    options = LeastSquaresOptions(method="gauss_newton", iterations=iterations, jacobian="central", step=step,
                                  tolerance=torch.tensor([1e-9] * 3 + [math.inf] * offset, dtype=dtype),
                                  covariance="none", stop_together=True, first_column=1)
    gaussian = GaussianPrior.independent(x0, prior.precision(offset, dtype))
    x, out = x0, {}
    for t in checkpoints:
        def residual(states: Tensor, rows: Tensor, t: int = t) -> Tensor:
            m = _magnitudes(model, states, rows, q_est0=q_est0, increments=increments[:t], m_past=m_past)
            return observations[rows, :t + 1] - m  # sample 0 only sets the offset's prior: first_column=1

        x = batch_least_squares(residual, x, prior=gaussian, variance=prior.measurement_noise, options=options).x
        out[t] = x.clone()
    return out


def map_attitude(x: Tensor, *, q_est0: Tensor, increments: Tensor) -> Tensor:
    """The attitude ``(S, 4)`` after ``len(increments)`` steps of the MAP initial attitude of states ``x``."""
    return propagate_only(quat_mul(rotvec_to_quat(x[:, :3]), q_est0), increments)[:, -1]


def map_rmse_deg(estimates: dict[int, Tensor], *, q_true: Tensor, q_est0: Tensor, increments: Tensor) -> Tensor:
    """Euler-angle RMSE ``(S, 3)`` (deg) over the checkpoints of :func:`map_known_rate`'s estimates against the true
    attitudes ``q_true (T+1, 4)``."""
    errors = [attitude_errors_deg(q_true[t], map_attitude(x, q_est0=q_est0, increments=increments[:t]))
              for t, x in estimates.items()]
    return torch.stack(errors, 1).pow(2).mean(1).sqrt()
