"""What a light curve allows at all: a batch MAP estimate of the initial attitude (and surface) from all samples so far.

Not a filter. At each checkpoint index ``t`` it maximises, per seed, the posterior of the state given ``ỹ_1 … ỹ_t``,
the known dynamics (each seed its own kinematic increments) and the filters' prior, re-linearising every
observation at every iteration (Levenberg–Marquardt, :func:`~lightcurve_gp.inference.solver.batch_least_squares`,
Jacobians by forward differences; every seed in one batch, warm-started from the previous checkpoint). State and
prior:

* attitude: ``e`` (3, rad), the rotation vector with ``q_0 = q(e) ⊗ q̂_0``; prior ``N(0, σ0² I)`` (the filters' P0);
* ``surface=False``: the magnitude offset ``b`` (mag) on the renderer at a reference surface,
  ``y = h_ref(q) + b`` (what the honest joint UKF assumes); prior ``N(ỹ_0 − h_ref(q̂_0), offset_std²)``;
* ``surface=True``: ``(log ρ, logit F0, log n_u, log n_v)`` of the renderer — the surface unknown, the shape known —
  with the prior of :func:`lightcurve_gp.observation.surface_state.surface_state_prior` (the surface-state filter's).

The estimate at ``t`` uses no later sample, so its errors at the checkpoints compare with a filter's over the same
window. Its covariance is the inverse Gauss–Newton Hessian at the estimate (the Laplace approximation); the attitude
block, turned to time ``t`` by ``A(Δ_t)`` (the cumulative increment), gives the NEES.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial
from typing import Sequence

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import attitude_matrix, quat_mul, quat_normalize, rotvec_to_quat
from lightcurve_gp.inference.solver import GaussianPrior, LeastSquaresOptions, batch_least_squares
from lightcurve_gp.observation.surface_state import surface_from_state, surface_state_prior
from lightcurve_gp.photometry.brdf import Surface
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.truths import TruthRanges

__all__ = ["SurfaceMapEstimate", "cumulative_increments", "map_with_surface"]


@dataclass
class SurfaceMapEstimate:
    """Batch MAP estimates at ``K`` checkpoints of ``S`` seeds.

    Attributes:
        checkpoints: sample indices ``t`` of the checkpoints, length ``K``.
        x: state estimates ``(S, K, n)`` (see the module docstring for the layout).
        q_est: attitude estimates at the checkpoint times ``(S, K, 4)``.
        P: attitude covariances at the checkpoint times ``(S, K, 3, 3)`` (rad²).
    """

    checkpoints: list[int]
    x: Tensor
    q_est: Tensor
    P: Tensor


def cumulative_increments(increments: Tensor) -> Tensor:
    """``Δ_0 = 1``, ``Δ_{k+1} = normalise(δ_k ⊗ Δ_k)`` from increments ``(S, T, 4)`` → ``(S, T+1, 4)``.

    ``q_k = Δ_k ⊗ q_0`` for every attitude moved by the same (known) rate history.
    """
    out = [torch.zeros_like(increments[:, 0]).index_fill_(-1, torch.tensor([3]), 1.0)]
    for delta in increments.unbind(1):
        out.append(quat_normalize(quat_mul(delta, out[-1])))
    return torch.stack(out, 1)


class _Problem:
    """Prediction and prior of one batch of ``S`` seeds (``mean``, ``precision`` ``(S, n)``)."""

    def __init__(self, scene: Scene, q_est0: Tensor, cumulative: Tensor, y0: Tensor, sigma0: Tensor, *,
                 reference: Surface, offset_std: float, surface: bool, ranges: TruthRanges) -> None:
        self.scene, self.q_est0, self.cum, self.surface, self.reference = scene, q_est0, cumulative, surface, reference
        S = q_est0.shape[0]
        if surface:
            mean, std = surface_state_prior(scene=scene, q_est0=q_est0, y0=y0, reference=reference,
                                            offset_std=offset_std, ranges=ranges)
        else:
            b0 = y0 - self._magnitude(q_est0.unsqueeze(1), self._reference(S))[:, 0]
            mean = torch.where(torch.isfinite(b0), b0, torch.zeros_like(b0)).unsqueeze(-1)
            std = torch.tensor([offset_std], dtype=q_est0.dtype)
        self.mean = torch.cat([torch.zeros(S, 3, dtype=q_est0.dtype), mean], -1)
        self.precision = torch.cat([sigma0.pow(-2).unsqueeze(-1).expand(S, 3), std.pow(-2).expand(S, -1)], -1)

    def _magnitude(self, q: Tensor, surface: Surface) -> Tensor:
        return self.scene.magnitude(q, surface=surface)

    def predict(self, x: Tensor, t: int, rows: Tensor) -> Tensor:
        """Magnitudes ``(len(rows), t)`` of samples ``1 … t`` for states ``x (len(rows), n)`` of seeds ``rows``."""
        q0 = quat_mul(rotvec_to_quat(x[:, :3]), self.q_est0[rows])
        q = quat_mul(self.cum[rows, 1:t + 1], q0.unsqueeze(1))
        if self.surface:
            return self._magnitude(q, surface_from_state(x[:, 3:]))
        return self._magnitude(q, self._reference(x.shape[0])) + x[:, 3:4]

    def _reference(self, rows: int) -> Surface:
        return Surface(*(t.to(self.q_est0).expand(rows) for t in self.reference))

    def residual(self, x: Tensor, rows: Tensor, *, observations: Tensor, t: int) -> Tensor:
        """Residuals ``ỹ_k − h_k(x)`` ``(A, t)`` (mag), ``k = 1 … t``, of states ``x (A, n)`` of the seeds ``rows``."""
        return observations[rows, 1:t + 1] - self.predict(x, t, rows)


def map_with_surface(scene: Scene, *, q_est0: Tensor, sigma0: Tensor, observations: Tensor, increments: Tensor,
                     checkpoints: Sequence[int], measurement_noise: float, reference: Surface, offset_std: float,
                     surface: bool, ranges: TruthRanges = TruthRanges(), iterations: int = 10,
                     warm_iterations: int = 4, step: float = 1e-6, tolerance: float = 5e-5) -> SurfaceMapEstimate:
    """Batch MAP estimates at every checkpoint (see the module docstring).

    Args:
        scene: renderer of the known shape and geometry (float64).
        q_est0: prior means of the initial attitudes ``(S, 4)``; sigma0: their standard deviations ``(S,)`` (rad).
        observations: ``ỹ_0 … ỹ_T`` ``(S, T+1)`` (mag); increments: each seed's ``(S, T, 4)``.
        checkpoints: increasing sample indices ``t ≥ 1`` at which to estimate.
        measurement_noise: the noise variance R (mag²).
        reference: the reference surface, fields ``(1,)`` (ρ_ref and, for ``surface=False``, the assumed material).
        offset_std: prior standard deviation of the offset (mag).
        surface: estimate the surface parameters too (else the offset).
        iterations: at most this many iterations at the first checkpoint (from the prior mean);
            ``warm_iterations`` at each later one (from the previous estimate).
        step: forward-difference step (rad, mag and log units alike).
        tolerance: a seed's iterations stop once its attitude step is below this (rad), or once its damping
            reaches 1e6 (no step lowers the cost); only the seeds still moving are evaluated. A non-finite
            prediction costs ``(1e3)² / R`` per sample.
    """
    cum = cumulative_increments(increments)
    problem = _Problem(scene, q_est0, cum, observations[:, 0], sigma0, reference=reference, offset_std=offset_std,
                       surface=surface, ranges=ranges)
    n = problem.mean.shape[-1]
    gaussian = GaussianPrior.independent(problem.mean, problem.precision)
    x, xs, covs = problem.mean, [], []
    for i, t in enumerate(checkpoints):
        options = LeastSquaresOptions(
            method="levenberg_marquardt", iterations=iterations if i == 0 else warm_iterations,
            jacobian="forward_difference", step=step, invalid_residual=1e3,
            tolerance=torch.tensor([tolerance] * 3 + [math.inf] * (n - 3), dtype=x.dtype))
        result = batch_least_squares(partial(problem.residual, observations=observations, t=t), x, prior=gaussian,
                                     variance=measurement_noise, options=options)
        x = result.x
        xs.append(x)
        covs.append(result.covariance[:, :3, :3])
    x_all = torch.stack(xs, 1)
    rot = attitude_matrix(cum[:, list(checkpoints)])  # (S, K, 3, 3): A(Δ_t) turns the error to time t
    P = rot @ torch.stack(covs, 1) @ rot.mT
    q0 = quat_mul(rotvec_to_quat(x_all[..., :3]), q_est0.unsqueeze(1))
    q_est = quat_mul(cum[:, list(checkpoints)], q0)
    return SurfaceMapEstimate(list(checkpoints), x_all, q_est, P)
