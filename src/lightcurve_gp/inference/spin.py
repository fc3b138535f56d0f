"""What the light curve allows when the spin is unknown: the batch MAP of the initial attitude *and* body rate.

:func:`.attitude.map_known_rate` with the initial rate as a parameter. At each checkpoint ``t`` Gauss–Newton with
backtracking (:func:`.solver.batch_least_squares`) maximises the posterior of ``x = [e, δω, b]`` given
``ỹ_1 … ỹ_t``: ``e`` the rotation vector (rad) of ``q_0 ⊗ q_est,0⁻¹``, ``δω`` the correction (rad/s) of the initial
body rate ``ω_est,0`` and, with an offset, ``b`` the magnitude offset (mag). Every evaluation propagates its own
trajectory from ``(exp(e) ⊗ q_est,0, ω_est,0 + δω)`` with the torque-free Euler equations and the quaternion
kinematics (:func:`.dynamics.propagate`, RK4, the inertia known). The prior is the rate filters': ``e ~ N(0, p0² I)``,
``δω ~ N(0, σ_ω² I)`` (``filter.p0_omega_deg_s``) and ``b ~ N(ỹ_0 − h(q̂_0), offset_prior_std²)``. The estimate at
``t`` uses no later observation, so its errors over the checkpoints compare with a filter's over its window.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial
from typing import Sequence

import torch
from torch import Tensor

from lightcurve_gp.attitude.dynamics import propagate
from lightcurve_gp.attitude.metrics import attitude_errors_deg
from lightcurve_gp.attitude.rotations import quat_mul, rotvec_to_quat
from lightcurve_gp.inference.attitude import MapPrior, chunked_magnitudes, select_seeds
from lightcurve_gp.inference.solver import GaussianPrior, LeastSquaresOptions, batch_least_squares, least_squares_cost
from lightcurve_gp.observation.base import ObservationModel

__all__ = ["RateMapEstimate", "RateDynamics", "map_with_rate", "neg_log_posterior", "prior_mean", "rate_map_trajectory",
           "rate_map_errors"]


@dataclass(frozen=True)
class RateDynamics:
    """The assumed spin: the prior mean of the initial rate ``omega_est0 (3,)`` (rad/s), its prior standard
    deviation ``p0_omega_deg_s`` (deg/s per axis, ``filter.p0_omega_deg_s``), the principal moments of inertia
    ``inertia (3,)`` (kg m²) and the step ``dt`` (s)."""

    omega_est0: Tensor
    p0_omega_deg_s: float
    inertia: Tensor
    dt: float

    def __post_init__(self) -> None:
        if tuple(self.omega_est0.shape) != (3,):
            raise ValueError(f"omega_est0: shape {tuple(self.omega_est0.shape)}, expected (3,) (rad/s)")
        if not (math.isfinite(self.p0_omega_deg_s) and self.p0_omega_deg_s > 0):
            raise ValueError(f"filter.p0_omega_deg_s: {self.p0_omega_deg_s} must be > 0 for the MAP with the rate "
                             "unknown (use map_known_rate for a known rate)")
        if tuple(self.inertia.shape) != (3,) or not bool((self.inertia > 0).all()):
            raise ValueError(f"inertia: {self.inertia.tolist()} must be three positive principal moments (kg m^2)")
        if not self.dt > 0:
            raise ValueError(f"dt: {self.dt} must be > 0 (s)")


@dataclass(frozen=True)
class RateMapEstimate:
    """The MAP at one checkpoint: states ``x (S, 6 | 7)`` = ``[e (rad), δω (rad/s), b (mag)]`` and the Laplace
    approximation of their posterior covariance ``(S, 6 | 7, 6 | 7)`` (inverse Gauss–Newton information)."""

    x: Tensor
    covariance: Tensor


def rate_map_trajectory(x: Tensor, *, q_est0: Tensor, dynamics: RateDynamics, n_steps: int) -> tuple[Tensor, Tensor]:
    """Attitudes ``(S, n_steps+1, 4)`` and rates ``(S, n_steps+1, 3)`` (rad/s) from the initial states ``x (S, ≥6)``
    and the initial estimates ``q_est0 (4,) | (S, 4)``."""
    q0 = quat_mul(rotvec_to_quat(x[:, :3]), q_est0)
    return propagate(q0, dynamics.omega_est0 + x[:, 3:6], dynamics.inertia, dynamics.dt, n_steps)


def _prior_precision(prior: MapPrior, dynamics: RateDynamics, offset: bool, dtype: torch.dtype) -> Tensor:
    """Diagonal of the prior information ``(6,)`` or ``(7,)``: attitude (rad⁻²), rate ((rad/s)⁻²), offset (mag⁻²)."""
    p = prior.precision(offset, dtype)
    rate = torch.full((3,), math.radians(dynamics.p0_omega_deg_s) ** -2, dtype=dtype)
    return torch.cat([p[:3], rate, p[3:]])


def _residual(model: ObservationModel, x: Tensor, rows: Tensor, *, q_est0: Tensor, dynamics: RateDynamics,
              observations: Tensor, t: int) -> Tensor:
    """Residuals ``ỹ_k − h(q_k) − b`` ``(A, t+1)`` (mag), ``k = 0 … t``, of states ``x (A, 6 | 7)`` of the seeds
    ``rows (A,)`` (the offset added with a seventh state); ``k = 0`` only sets the offset's prior, the solver
    drops it (``first_column=1``)."""
    q, _ = rate_map_trajectory(x, q_est0=select_seeds(q_est0, rows), dynamics=dynamics, n_steps=t)
    m = chunked_magnitudes(model, q=q, m_past=observations[rows, :1], chunk=observations.shape[0])
    m = m + x[:, 6:] if x.shape[-1] == 7 else m
    return observations[rows, :t + 1] - m


def prior_mean(model: ObservationModel, *, q_est0: Tensor, observations: Tensor, offset: bool) -> Tensor:
    """The prior mean ``(S, 6 | 7)``: zero corrections and, with an offset, ``b0 = ỹ_0 − h(q̂_0)`` (mag)."""
    S, dtype = observations.shape[0], observations.dtype
    x0 = torch.zeros(S, 7 if offset else 6, dtype=dtype)
    if offset:
        m, _ = model(q=q_est0.expand(S, 4)[:, None], m_past=observations[:, :1], variance="none")
        x0[:, 6] = observations[:, 0] - m[:, 0]
    return x0


def neg_log_posterior(model: ObservationModel, x: Tensor, *, q_est0: Tensor, dynamics: RateDynamics,
                      observations: Tensor, prior: MapPrior, t: int) -> Tensor:
    """The negative log posterior (up to a constant) ``(S,)`` of states ``x (S, 6 | 7)`` given ``ỹ_1 … ỹ_t``:
    what :func:`map_with_rate` minimises, to compare its estimate with another state (e.g. the truth's)."""
    offset, every = x.shape[-1] == 7, torch.arange(x.shape[0])
    x0 = prior_mean(model, q_est0=q_est0, observations=observations, offset=offset)
    r = _residual(model, x, every, q_est0=q_est0, dynamics=dynamics, observations=observations, t=t)
    gaussian = GaussianPrior.independent(x0, _prior_precision(prior, dynamics, offset, x.dtype))
    return least_squares_cost(r[:, 1:], x, every, prior=gaussian, variance=prior.measurement_noise)


def _check_checkpoints(checkpoints: Sequence[int], n_steps: int) -> None:
    if not checkpoints or list(checkpoints) != sorted(set(checkpoints)) or checkpoints[0] < 1 \
            or checkpoints[-1] > n_steps:
        raise ValueError(f"checkpoints: {list(checkpoints)} must be increasing step indices in 1 … {n_steps}")


def map_with_rate(model: ObservationModel, *, q_est0: Tensor, dynamics: RateDynamics, observations: Tensor,
                  prior: MapPrior, checkpoints: Sequence[int], offset: bool, iterations: int = 15,
                  step: float = 1e-5, rate_step: float = 1e-8, halvings: int = 10,
                  x_start: Tensor | None = None) -> dict[int, RateMapEstimate]:
    """The MAP of ``[e, δω, b]`` at each checkpoint index (observations ``1 … t`` used).

    Args:
        model: observation model; its ``m_past`` input is held at the first observation.
        q_est0: initial attitude estimate ``(4,)`` or ``(S, 4)``, the prior mean.
        dynamics: the prior mean and std of the initial rate, the inertia and the step.
        observations: ``(S, T+1)`` magnitudes (mag), ``ỹ_0`` first, one per ``dynamics.dt``.
        prior: attitude prior, measurement noise variance and offset prior (as :func:`.attitude.map_known_rate`).
        checkpoints: step indices ``t`` in increasing order; each solve starts from the previous one.
        offset: estimate a magnitude offset ``b`` as a seventh state.
        iterations: Gauss–Newton iterations per checkpoint at most (stops when the attitude step is below 1e-9 rad
            and the rate step below 1e-12 rad/s).
        step: central-difference step of the attitude (rad) and offset (mag) columns of the Jacobian.
        rate_step: central-difference step of the rate columns (rad/s).
        halvings: step halvings per iteration when a Gauss–Newton step raises a seed's negative log posterior (the
            rate makes the posterior far less quadratic than the attitude alone: an error in ω grows with time).
            The covariance is the inverse information of each seed's last linearisation (before its last step).
        x_start: where the first solve starts ``(S, 6 | 7)`` (default: the prior mean); the prior is unchanged.
    """
    T = observations.shape[1] - 1
    _check_checkpoints(checkpoints, T)
    dtype = observations.dtype
    x0 = prior_mean(model, q_est0=q_est0, observations=observations, offset=offset)
    options = LeastSquaresOptions(
        method="gauss_newton", iterations=iterations, halvings=halvings, jacobian="central",
        step=torch.tensor([step] * 3 + [rate_step] * 3 + [step] * offset, dtype=dtype),
        tolerance=torch.tensor([1e-9] * 3 + [1e-12] * 3 + [math.inf] * offset, dtype=dtype),
        covariance="last_linearization", stop_together=True, first_column=1)
    gaussian = GaussianPrior.independent(x0, _prior_precision(prior, dynamics, offset, dtype))
    x, out = (x0 if x_start is None else x_start).clone(), {}
    for t in checkpoints:
        residual = partial(_residual, model, q_est0=q_est0, dynamics=dynamics, observations=observations, t=t)
        result = batch_least_squares(residual, x, prior=gaussian, variance=prior.measurement_noise, options=options)
        x = result.x
        out[t] = RateMapEstimate(x.clone(), result.covariance)
    return out


def rate_map_errors(estimates: dict[int, RateMapEstimate], *, q_true: Tensor, omega_true: Tensor, q_est0: Tensor,
                    dynamics: RateDynamics) -> tuple[Tensor, Tensor]:
    """Euler-angle errors ``(S, C, 3)`` (deg) and body-rate error norms ``(S, C)`` (deg/s) of the MAP at each of its
    ``C`` checkpoints ``t`` (the state at ``t`` propagated from the MAP initial state of that checkpoint) against the
    truth ``q_true (T+1, 4)``, ``omega_true (T+1, 3)`` (rad/s)."""
    att, rate = [], []
    for t, est in estimates.items():
        q, w = rate_map_trajectory(est.x, q_est0=q_est0, dynamics=dynamics, n_steps=t)
        att.append(attitude_errors_deg(q_true[t], q[:, -1]))
        rate.append(torch.rad2deg(torch.linalg.vector_norm(w[:, -1] - omega_true[t], dim=-1)))
    return torch.stack(att, 1), torch.stack(rate, 1)
