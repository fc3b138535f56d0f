"""What the data say of the truth, for the global inversion: the truth's own basin and each answer's kind.

The global inversion (:mod:`lightcurve_gp.inference.answer`) finds states by a search; a wrong answer is either the
search's fault or the data's. The **truth's basin** tells them apart: the local minimum of the whole light curve's
cost ``c = ½ Σ r²`` reached by Levenberg–Marquardt from the true state ``(q_0, ω_0, ln ρ)`` and from each of its
exact images (:class:`~lightcurve_gp.photometry.ambiguity.AmbiguityGroup`; they have the same cost, so the lowest of
their polished costs is the basin's). The truth's raw cost is not the reference: a maximum-likelihood state with
``k = 7`` free parameters fits about ``k / 2`` nats better than the truth by construction, and the basin is never
above the truth itself.

Every answer is of one kind (:data:`KINDS`, in this order of precedence):

* ``right``: the top family is the truth's — an image of it within :data:`RIGHT_ANGLE_DEG` on every Euler axis at
  the first sample and its rate within :data:`RIGHT_RATE_REL` of the true rate's magnitude;
* ``ambiguous_reported``: the truth's family is among those reported, not first;
* ``search_miss``: the best state found fits worse than the truth's basin by more than :data:`MISS_NATS`: a better
  state exists and the search did not reach it;
* ``data_limited``: the best state found is another basin, at least as good as the truth's (within
  :data:`MISS_NATS`), or the truth's basin itself lies outside the limits of ``right`` (measured: a 2 °/s tumbler
  over 200 s at 0.05 mag, whose basin is 3.2 % off in rate): the light curve does not single out the truth and no
  search could. ``basin_right`` says which.

Beside the kind, ``basin_rank`` says where the **truth's own family** is among those reported: the first family
whose state lies within the limits of ``right`` of the truth's basin (modulo the exact images), the truth's family
even where the basin itself is beyond the limits of the truth (a slow tumbler whose rate the light curve leaves
free).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from lightcurve_gp.attitude.metrics import attitude_error_vector, attitude_errors_deg, nees
from lightcurve_gp.inference.families import RIGHT_ANGLE_DEG, RIGHT_RATE_REL, Families, image_distance
from lightcurve_gp.inference.fit_verdict import FitTest, fit_test
from lightcurve_gp.inference.inversion import polish
from lightcurve_gp.inference.trajectory import TrajectoryProblem
from lightcurve_gp.photometry.ambiguity import AmbiguityGroup

__all__ = ["KINDS", "MISS_NATS", "InversionReference", "truth_basin",
           "nearest_images", "state_errors", "state_nees", "answer_kind", "inversion_reference"]

#: the kinds of an answer (module docstring)
KINDS = ("right", "ambiguous_reported", "search_miss", "data_limited")
#: a best state worse than the truth's basin by more than this (nats) is a search miss
MISS_NATS = 1.0


@dataclass(frozen=True)
class InversionReference:
    """An answer against the truth (module docstring).

    Attributes:
        truth_cost: ``c`` at the true state; basin_cost: at the truth's basin; best_cost: the best state found.
        basin_fit: the basin's χ² test (what a search that found it would report).
        basin_right: whether the truth's basin itself is within the limits of ``right``.
        axis_error_deg: each family's largest Euler error to its nearest image of the truth ``(F,)`` (deg);
        rate_error_rel: its rate difference over the true rate ``(F,)``; right: both within the limits ``(F,)``.
        nees: each family's NEES ``(F,)`` against the image of the truth nearest it (:func:`state_nees`; χ²₆ when
            the family is the truth's and its covariance honest).
        truth_rank: the rank (1 = top) of the first family that is right, 0 when none is.
        basin_rank: the rank of the first family within the limits of ``right`` of the truth's basin, 0 when none is.
        kind: one of :data:`KINDS`.
    """

    truth_cost: float
    basin_cost: float
    best_cost: float
    basin_fit: FitTest
    basin_right: bool
    axis_error_deg: Tensor
    rate_error_rel: Tensor
    nees: Tensor
    right: Tensor
    truth_rank: int
    basin_rank: int
    kind: str

    def as_dict(self) -> dict:
        return {"kind": self.kind, "truth_rank": self.truth_rank, "basin_rank": self.basin_rank,
                "truth_cost": self.truth_cost,
                "basin_cost": self.basin_cost, "best_cost": self.best_cost,
                "best_minus_basin": self.best_cost - self.basin_cost, "basin_chi2_per_dof": self.basin_fit.chi2_per_dof,
                "basin_right": self.basin_right,
                "top1_max_axis_error_deg": float(self.axis_error_deg[0]),
                "top1_rate_error_rel": float(self.rate_error_rel[0]), "top1_nees": float(self.nees[0])}


def truth_basin(problem: TrajectoryProblem, group: AmbiguityGroup, *, q0: Tensor, omega0: Tensor, rho: float,
                iterations: int = 20) -> tuple[float, float, Tensor, Tensor]:
    """The truth's raw cost, its basin's (module docstring) and the basin's initial attitude ``(4,)`` and body rate
    ``(3,)`` (rad/s) for the true ``q0 (4,)``, ``omega0 (3,)`` (rad/s) and ``rho``."""
    q_img, w_img = group.attitudes(q0), group.rates(omega0)  # (G, 4), (G, 3)
    x = torch.cat([torch.zeros_like(w_img), w_img, torch.full_like(w_img[:, :1], math.log(rho))], -1)
    raw = 0.5 * problem.with_anchors(q_img[:1]).residual(x[:1], torch.zeros(1, dtype=torch.long)).square().sum()
    basin = polish(problem, q_img, x, iterations=iterations)
    k = int(basin.cost.argmin())
    return float(raw), float(basin.cost[k]), basin.q0[k], basin.omega0[k]


def nearest_images(group: AmbiguityGroup, q: Tensor, omega: Tensor, *, q0: Tensor,
                   omega0: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """The image of the truth ``q0 (4,)``, ``omega0 (3,)`` (rad/s) nearest each state ``q (M, 4)``, ``omega (M, 3)``:
    the one of least ``angle / RIGHT_ANGLE_DEG + |Δω| / (RIGHT_RATE_REL |ω|)``; its attitudes ``(M, 4)``, rates
    ``(M, 3)`` (rad/s) and rate differences ``|Δω|`` ``(M,)`` (°/s)."""
    rate = math.degrees(float(torch.linalg.vector_norm(omega0)))
    _, rate_err, image = image_distance(group, q, omega, q0, omega0, angle_deg=RIGHT_ANGLE_DEG,
                                        rate_deg_s=max(RIGHT_RATE_REL * rate, 1e-9))
    return group.attitudes(q0)[image], group.rates(omega0)[image], rate_err


def state_errors(group: AmbiguityGroup, q: Tensor, omega: Tensor, *, q0: Tensor,
                 omega0: Tensor) -> tuple[Tensor, Tensor]:
    """The largest Euler error (deg) of states ``q (M, 4)``, ``omega (M, 3)`` (rad/s) to the image of the truth
    nearest each (:func:`nearest_images`) and that image's rate difference over the true rate ``(M,)`` each."""
    q_img, _, rate_err = nearest_images(group, q, omega, q0=q0, omega0=omega0)
    rate = math.degrees(float(torch.linalg.vector_norm(omega0)))
    return attitude_errors_deg(q_img, q).abs().amax(-1), rate_err / rate


def state_nees(group: AmbiguityGroup, q: Tensor, omega: Tensor, covariance: Tensor, *, q0: Tensor,
               omega0: Tensor) -> Tensor:
    """The NEES ``eᵀ Σ⁻¹ e`` ``(M,)`` of states ``q (M, 4)``, ``omega (M, 3)`` (rad/s) with Laplace covariances
    ``(M, 6+, 6+)`` of ``[θ, ω, …]`` (the block ``[:6, :6]``), against the image of the truth nearest each
    (:func:`nearest_images`): ``e = [θ, δω]`` with ``exp(θ) ⊗ q = q_image`` (rad) and ``δω = ω_image − ω``
    (rad/s). A right state with an honest covariance gives χ²₆ (mean 6)."""
    q_img, w_img, _ = nearest_images(group, q, omega, q0=q0, omega0=omega0)
    error = torch.cat([attitude_error_vector(q_img, q), w_img - omega], -1)
    return nees(error, covariance[:, :6, :6])


def answer_kind(*, right: Tensor, best_cost: float, basin_cost: float, miss_nats: float = MISS_NATS) -> str:
    """The kind of an answer (module docstring) from which families are the truth's ``right (F,)`` (bool, top
    first), the best cost found and the truth's basin's."""
    if bool(right[0]):
        return "right"
    if bool(right.any()):
        return "ambiguous_reported"
    if best_cost > basin_cost + miss_nats:
        return "search_miss"
    return "data_limited"


def inversion_reference(problem: TrajectoryProblem, group: AmbiguityGroup, fam: Families, *, best_cost: float,
                        q0: Tensor, omega0: Tensor, rho: float) -> InversionReference:
    """The answer ``fam`` (its families, best weight first) with the best cost found ``best_cost`` against the truth
    ``q0 (4,)``, ``omega0 (3,)`` (rad/s), ``rho`` on ``problem`` (module docstring)."""
    raw, basin, basin_q, basin_w = truth_basin(problem, group, q0=q0, omega0=omega0, rho=rho)
    axes, rel = state_errors(group, fam.q0, fam.omega0, q0=q0, omega0=omega0)
    family_nees = state_nees(group, fam.q0, fam.omega0, fam.covariance, q0=q0, omega0=omega0)
    right = (axes < RIGHT_ANGLE_DEG) & (rel < RIGHT_RATE_REL)
    basin_axes, basin_rel = state_errors(group, basin_q[None], basin_w[None], q0=q0, omega0=omega0)
    rank = int(torch.nonzero(right)[0, 0]) + 1 if bool(right.any()) else 0
    fam_axes, fam_rel = state_errors(group, fam.q0, fam.omega0, q0=basin_q, omega0=basin_w)
    near_basin = (fam_axes < RIGHT_ANGLE_DEG) & (fam_rel < RIGHT_RATE_REL)
    basin_rank = int(torch.nonzero(near_basin)[0, 0]) + 1 if bool(near_basin.any()) else 0
    samples = int(torch.isfinite(problem.y).sum())
    return InversionReference(truth_cost=raw, basin_cost=basin, best_cost=float(best_cost),
                              basin_fit=fit_test(basin, samples=samples),
                              basin_right=bool(basin_axes[0] < RIGHT_ANGLE_DEG) and bool(basin_rel[0] < RIGHT_RATE_REL),
                              axis_error_deg=axes, rate_error_rel=rel, nees=family_nees,
                              right=right, truth_rank=rank, basin_rank=basin_rank,
                              kind=answer_kind(right=right, best_cost=float(best_cost), basin_cost=basin))
