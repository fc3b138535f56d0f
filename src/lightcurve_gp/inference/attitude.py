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
from functools import partial
from typing import Callable, Sequence

import torch
from torch import Tensor

from lightcurve_gp.attitude.dynamics import propagate_only
from lightcurve_gp.attitude.metrics import attitude_errors_deg
from lightcurve_gp.attitude.rotations import quat_mul, rotvec_to_quat
from lightcurve_gp.observation.base import ObservationModel

__all__ = ["MapPrior", "batch_map", "blockwise_magnitudes", "gauss_newton", "map_attitude", "map_rmse_deg",
           "tile_seeds"]


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


def blockwise_magnitudes(model: ObservationModel, *, q: Tensor, m_past: Tensor) -> Tensor:
    """Magnitudes ``(K·S, t+1)`` of attitudes ``q (K·S, t+1, 4)``, ``K`` blocks of the ``S`` seeds whose ``m_past``
    ``(S, 1)`` they share, the model evaluated one block at a time (its memory: that of one block)."""
    S, t1 = m_past.shape[0], q.shape[1]
    blocks = [model(q=block, m_past=m_past.expand(-1, t1), variance="none")[0] for block in q.split(S)]
    return torch.cat(blocks)


def tile_seeds(q_est0: Tensor, rows: int) -> Tensor:
    """The initial estimate ``(4,)`` as given, or ``(S, 4)`` repeated to ``rows = K·S`` rows (``K`` blocks)."""
    return q_est0 if q_est0.dim() == 1 else q_est0.repeat(rows // q_est0.shape[0], 1)


def _predict(model: ObservationModel, x: Tensor, q_est0: Tensor, increments: Tensor, m_past: Tensor,
             offset: bool) -> Tensor:
    """Magnitudes ``(K·S, t+1)`` of states ``x (K·S, 3 | 4)`` along the known dynamics (``increments (t, 4)``)."""
    q = propagate_only(quat_mul(rotvec_to_quat(x[:, :3]), tile_seeds(q_est0, x.shape[0])), increments)
    m = blockwise_magnitudes(model, q=q, m_past=m_past)
    return m + x[:, 3:] if offset else m


def _neg_log_posterior(m: Tensor, x: Tensor, *, y: Tensor, r_var: float, x_prior: Tensor, prior_precision: Tensor
                       ) -> Tensor:
    """``½ Σ (ỹ_k − m_k)²/R + ½ (x − x_prior)ᵀ P0⁻¹ (x − x_prior)`` ``(K·S,)`` of states ``x (K·S, n)`` and their
    magnitudes ``m (K·S, t+1)`` (``K`` blocks of the seeds) against ``y (S, t+1)`` (``ỹ_0`` left out: it sets the
    offset's prior)."""
    S = y.shape[0]
    r = (y.repeat(m.shape[0] // S, 1) - m)[:, 1:]
    prior_term = ((x - x_prior.repeat(x.shape[0] // S, 1)).pow(2) * prior_precision).sum(-1)
    return 0.5 * (r.pow(2).sum(-1) / r_var + prior_term)


def gauss_newton(predict: Callable[[Tensor, int], Tensor], *, x: Tensor, x_prior: Tensor, prior_precision: Tensor,
                 observations: Tensor, measurement_noise: float, t: int, steps: Tensor, tolerance: Tensor,
                 iterations: int, halvings: int = 0) -> tuple[Tensor, Tensor]:
    """Gauss–Newton on the posterior of states ``x (S, n)`` given ``ỹ_1 … ỹ_t``, every observation re-linearised
    at every iteration.

    Args:
        predict: ``predict(x, t)`` → magnitudes ``(K·S, t+1)`` of states ``x (K·S, n)``, ``ỹ_0`` first: ``K``
            blocks of the ``S`` seeds (all the Jacobian's differences go in one call).
        x: the starting states ``(S, n)``.
        x_prior: the prior means ``(S, n)``; ``prior_precision (n,)`` the prior's diagonal information.
        observations: ``(S, T+1)`` magnitudes (mag), ``T ≥ t``; ``measurement_noise`` their variance (mag²).
        steps: central-difference step of each state component ``(n,)``.
        tolerance: stop when every component of the Gauss–Newton step is below it ``(n,)``.
        iterations: Gauss–Newton iterations at most.
        halvings: with ``> 0``, a seed whose step raises its negative log posterior halves the step, up to this
            many times (then it keeps its state for this iteration); 0: the plain Gauss–Newton step.

    Returns:
        The states ``(S, n)`` and the Gauss–Newton information matrix ``JᵀJ/R + P0⁻¹`` ``(S, n, n)`` at the last
        linearisation (its inverse: the Laplace approximation of the posterior covariance).
    """
    r_var, H, y = measurement_noise, None, observations[:, :t + 1]
    cost = partial(_neg_log_posterior, y=y, r_var=r_var, x_prior=x_prior, prior_precision=prior_precision)
    for _ in range(iterations):
        m, J = _jacobian(predict, x, t, steps)
        H = J.mT @ J / r_var + torch.diag(prior_precision)
        g = (J.mT @ (y - m)[:, 1:].unsqueeze(-1)).squeeze(-1) / r_var - (x - x_prior) * prior_precision
        dx = torch.linalg.solve(H, g)
        if halvings:
            dx = _backtrack(predict, cost, x=x, dx=dx, cost_now=cost(m, x), t=t, halvings=halvings)
        x = x + dx
        if bool((dx.abs() < tolerance).all()):
            break
    return x, H


def _jacobian(predict, x: Tensor, t: int, steps: Tensor) -> tuple[Tensor, Tensor]:
    """``predict(x)`` ``(S, t+1)`` and its central-difference Jacobian without ``ỹ_0`` ``(S, t, n)``, in one call."""
    S, n = x.shape
    shifts = torch.cat([torch.diag(steps), -torch.diag(steps)])  # (2n, n)
    m_all = predict(torch.cat([x, (x[None] + shifts[:, None]).reshape(2 * n * S, n)]), t)
    plus, minus = m_all[S:].reshape(2, n, S, t + 1)
    return m_all[:S], ((plus - minus) / (2 * steps[:, None, None])).permute(1, 2, 0)[:, 1:]


def _backtrack(predict, cost, *, x: Tensor, dx: Tensor, cost_now: Tensor, t: int, halvings: int) -> Tensor:
    """Per seed, the longest step ``dx / 2^k`` (``k ≤ halvings``) that does not raise the cost; zero if none."""
    out, pending = torch.zeros_like(dx), torch.ones(x.shape[0], dtype=torch.bool)
    for k in range(halvings + 1):
        trial = dx / 2 ** k
        ok = pending & (cost(predict(x + trial, t), x + trial) <= cost_now)
        out[ok], pending = trial[ok], pending & ~ok
        if not bool(pending.any()):
            break
    return out


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
    m_past = observations[:, :1]

    def predict(x: Tensor, t: int) -> Tensor:
        return _predict(model, x, q_est0, increments[:t], m_past, offset)

    x0 = torch.zeros(S, n, dtype=dtype)
    if offset:
        x0[:, 3] = observations[:, 0] - predict(x0, 0)[:, 0]
    steps = torch.full((n,), step, dtype=dtype)
    tolerance = torch.tensor([1e-9] * 3 + [math.inf] * offset, dtype=dtype)
    x, out = x0.clone(), {}
    for t in checkpoints:
        x, _ = gauss_newton(predict, x=x, x_prior=x0, prior_precision=prior.precision(offset, dtype),
                            observations=observations, measurement_noise=prior.measurement_noise, t=t, steps=steps,
                            tolerance=tolerance, iterations=iterations)
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
