"""What the data say of the truth: the reference a whole-arc estimator's NEES is read against.

A whole-arc estimate reports a Gaussian covariance about its best mode; its NEES at the truth is χ²(3) only as far as
the negative log posterior is quadratic over the distance to the truth. The data's own, covariance-free measure of
that distance is the **likelihood-ratio statistic of the truth**

    ``λ = 2 (c_prof(q_true) − c_min)``,

``c_prof(q) = min_θ c(q, θ)`` the cost (negative log posterior, :mod:`lightcurve_gp.inference.arc`) with the initial
attitude held at ``q`` and the surface state profiled out (with the surface known, the cost at ``q``), and ``c_min``
the lowest cost known: the estimate's, or the truth's own basin's where that is lower. Where the cost is quadratic
``λ`` equals the NEES of the truth's own basin's Laplace covariance; where the basin is not, no Gaussian about any
point estimate is consistent with these data, and ``λ``'s mean over the seeds is the reference the estimator's NEES
is compared with (the statistic of an estimator that always finds the global minimum and reports the exact
likelihood-ratio region).

The truth's basin is the local minimum reached from the truth itself (its attitude and surface state). It sorts
every seed into one of three kinds by where the estimate lies:

* ``same``: the estimate is the truth's basin (within ``same_deg``): its NEES is the basin's shape, not the search;
* ``other``: another basin, of no higher cost than the truth's (within ``miss_nats``): the data favour it, no search
  could do better;
* ``miss``: the truth's basin fits better by more than ``miss_nats`` and the search did not find it.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from lightcurve_gp.attitude.metrics import attitude_error_vector, nees
from lightcurve_gp.config.load import Config
from lightcurve_gp.inference.arc import ArcSolution, solve_starts
from lightcurve_gp.inference.arc_search import arc_setup
from lightcurve_gp.inference.crb import surface_state
from lightcurve_gp.inference.solver import GaussianPrior, least_squares_cost
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import Scenario

__all__ = ["KINDS", "PIN_PRECISION", "TruthReference", "truth_reference"]

#: the seed kinds (module docstring), in the order of :attr:`TruthReference.kind`'s codes
KINDS = ("same", "other", "miss")
#: the precision (rad⁻²) that holds the attitude at the truth while the surface state is profiled out
PIN_PRECISION = 1e12


@dataclass
class TruthReference:
    """The truth's likelihood ratio and basin on ``S`` seeds (module docstring).

    Attributes:
        statistic: ``λ = 2 (c_prof(q_true) − c_min)`` ``(S,)`` (dimensionless, χ²(3) where the cost is quadratic).
        profile_cost: ``c_prof(q_true)`` ``(S,)`` (nats).
        basin_cost: the cost of the truth's basin ``(S,)`` (nats); estimate_cost: the estimate's ``(S,)``.
        basin_nees: the truth's NEES against its own basin's Laplace attitude covariance ``(S,)``.
        estimate_nees: the truth's NEES against the estimate's reported attitude covariance ``(S,)``.
        separation_deg: the angle between the estimate and the truth's basin ``(S,)`` (degrees).
        kind: per seed an index into :data:`KINDS` ``(S,)`` (int64).
    """

    statistic: Tensor
    profile_cost: Tensor
    basin_cost: Tensor
    estimate_cost: Tensor
    basin_nees: Tensor
    estimate_nees: Tensor
    separation_deg: Tensor
    kind: Tensor

    def count(self, kind: str) -> int:
        """The seeds of one kind of :data:`KINDS`."""
        return int((self.kind == KINDS.index(kind)).sum())


def truth_reference(cfg: Config, scene: Scene, sc: Scenario, *, solution: ArcSolution, surface_known: bool,
                    R: float | Tensor | None = None, same_deg: float = 1.0, miss_nats: float = 0.5) -> TruthReference:
    """The truth's likelihood ratio and basin on every seed of ``sc`` (module docstring).

    Args:
        cfg, scene, sc: as :func:`~lightcurve_gp.evaluation.whole_arc.whole_arc_map`'s (the same prior and noise).
        solution: the whole-arc estimate of the same seeds (``q0 (S, 4)``, ``cost (S,)``,
            ``attitude_covariance (S, 3, 3)``), found with the same ``surface_known`` and ``R``.
        surface_known: the cost with the truth's surface (no profile) or with the surface state unknown.
        R: the noise variance (mag²; default ``filter.measurement_noise``).
        same_deg: an estimate within this angle (degrees) of the truth's basin is that basin.
        miss_nats: a truth's basin lower than the estimate by more than this is a search miss.
    """
    S = sc.q_est0.shape[0]
    if solution.q0.shape != (S, 4):
        raise ValueError(f"solution: q0 {tuple(solution.q0.shape)} is not one attitude per seed of the scenario "
                         f"({S}, 4)")
    setup = arc_setup(cfg, scene, sc.problem(), surface_known=surface_known, R=R)
    problem, mean, precision = setup.problem, setup.prior_mean, setup.prior_precision
    q_true = sc.q_true[:, 0].to(sc.q_est0)
    theta_true = None if surface_known else surface_state(sc.surface).to(q_true)
    basin = solve_starts(problem, starts=q_true.unsqueeze(0),
                         theta_starts=None if theta_true is None else theta_true.unsqueeze(0),
                         prior_mean=mean, prior_precision=precision)
    e_true = attitude_error_vector(q_true, sc.q_est0)  # the truth in the problem's chart
    rows = torch.arange(S, device=q_true.device)
    prior = GaussianPrior.independent(mean, precision)
    if theta_true is None:
        x = e_true
    else:  # the attitude held at the truth by a stiff prior, the surface state free from the truth's and the estimate's
        pinned_mean, pinned = mean.clone(), precision.clone()
        pinned_mean[:, :3], pinned[:, :3] = e_true, PIN_PRECISION
        held = solve_starts(problem, starts=q_true.expand(2, S, 4), prior_mean=pinned_mean, prior_precision=pinned,
                            theta_starts=torch.stack([theta_true, solution.theta.to(theta_true)]))
        x = torch.cat([e_true.expand(2, S, 3), held.theta], -1).flatten(0, 1)  # (2 S, 7)
    twice = rows.repeat(x.shape[0] // S)
    profile = least_squares_cost(problem(x, twice), x, twice, prior=prior, invalid_residual=1e3)
    profile = profile.view(-1, S).min(0).values
    c_min = torch.minimum(solution.cost, basin.cost[0])
    separation = torch.rad2deg(torch.linalg.vector_norm(attitude_error_vector(basin.q0[0], solution.q0), dim=-1))
    miss = basin.cost[0] < solution.cost - miss_nats
    kind = torch.where(separation < same_deg, 0, torch.where(miss, 2, 1))
    return TruthReference(statistic=2.0 * (profile - c_min), profile_cost=profile, basin_cost=basin.cost[0],
                          estimate_cost=solution.cost,
                          basin_nees=nees(attitude_error_vector(q_true, basin.q0[0]), basin.covariance[0, :, :3, :3]),
                          estimate_nees=nees(attitude_error_vector(q_true, solution.q0), solution.attitude_covariance),
                          separation_deg=separation, kind=kind)
