"""The batch MAP over the whole arc: the initial attitude (and the surface) from every sample at once, from several
starts, with an honest Laplace covariance.

Model (ω known, so every attitude follows the initial one by the cumulative increments ``q_k = Δ_k ⊗ q_0``): samples
``ỹ_k = h(q_k; surface) + v_k``, ``v_k ~ N(0, σ_k²)``, ``k = 1 … T`` (``ỹ_0`` is the filters' ``m_past,0`` only; a
missing sample is left out). State ``x = [e, θ]``: ``e`` the rotation vector (rad) of ``q_0 = q(e) ⊗ q̄_0`` about the
prior mean ``q̄_0``, and, with the surface unknown, ``θ = (log ρ, logit F0, log n_u, log n_v)``
(:mod:`lightcurve_gp.observation.surface_state`); prior ``e ~ N(0, σ0² I)`` (the filters' ``P0``) and ``θ`` the
surface-state filter's. The cost is the negative log posterior ``½ Σ_k r_k² + ½ (x − μ)ᵀ Λ (x − μ)`` with whitened
residuals ``r_k = (ỹ_k − h_k(x)) / σ_k``; a sample the renderer cannot predict (zero flux) costs ``(1e3)²/2``.

Solved by Levenberg–Marquardt on the one least-squares core (:func:`~lightcurve_gp.inference.solver.
batch_least_squares`, forward-difference Jacobian of all samples in one rendering call), every start of every
object in one batch. The cost landscape of a light curve has several basins (the weak direction, the shape's
near-symmetries, a wide prior), so one start is not enough: each object is solved from ``K`` starts and its
**modes** are the distinct solutions (more than ``mode_angle_deg`` apart) within ``max_log_ratio`` nats of the best.
Each mode's Laplace covariance is taken in its own chart (``q_0 = q(δ) ⊗ q̂_0``, linearised at ``δ = 0``) and the modes
are weighted by their Laplace evidence ``w_m ∝ exp(−c_m) det(Σ_m)^{1/2}``, ``Σ_m`` the covariance of the whole state
``[δ, θ]`` (the posterior mass of the mode; as :mod:`lightcurve_gp.inference.families` weights inversion
families). The estimate is the best mode (the MAP); its reported attitude covariance is the mixture's second moment
about it, ``Σ_m w_m (Σ_m,δδ + d_m d_mᵀ)`` with ``d_m`` the rotation vector of ``q_m ⊗ q̂⁻¹`` — the best mode's own
covariance when it stands alone, wide when another basin fits almost as well, so
that an ambiguous object is not a confident wrong one.
"""

from __future__ import annotations

import copy
import itertools
import math
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import attitude_matrix, quat_conj, quat_mul, quat_to_rotvec, rotvec_to_quat
from lightcurve_gp.inference.jacobian import jacobian
from lightcurve_gp.inference.solver import GaussianPrior, LeastSquaresOptions, batch_least_squares
from lightcurve_gp.inference.zero_points import profile_zero_points
from lightcurve_gp.observation.surface_state import surface_from_state
from lightcurve_gp.photometry.brdf import Surface
from lightcurve_gp.photometry.render import Scene

__all__ = ["ArcProblem", "ArcStarts", "ArcSolution", "torch_threads", "ARC_OPTIONS", "solve_starts", "solve_arc",
           "arc_modes", "refine_starts", "prior_axis_starts", "prior_corner_starts", "mixture_covariance"]

#: the solver's settings: Levenberg–Marquardt, forward differences (1e-6 in rad and surface units), a problem stops
#: once every component of its step is below 1e-6 or its damping reaches 1e6; an unpredictable sample costs 1e3²/2
ARC_OPTIONS = LeastSquaresOptions(method="levenberg_marquardt", iterations=25, tolerance=1e-6,
                                  jacobian="forward_difference", step=1e-6, invalid_residual=1e3, covariance="none",
                                  chunk=256)


class ArcProblem:
    """The whitened residuals of ``M`` problems (object ``seed[i]`` seen from the reference ``q_ref[i]``).

    Args:
        scene: the renderer of the known shape (fixed, or per sample along a pass).
        q_ref: the chart's centre of each problem ``(M, 4)``: ``q_0 = q(e) ⊗ q_ref``.
        seed: the object of each problem ``(M,)`` (int64 into the objects' rows below).
        cumulative: ``Δ_k`` of each object ``(S, T+1, 4)``; observations: ``(S, T+1)`` (mag, NaN: missing).
        weight: ``1/σ_k`` ``(S, T+1)`` (mag⁻¹), 0 for a sample left out (``k = 0``, missing).
        surface: the known surface of each object (fields ``(S,)``); ``None``: the surface state is in ``x``.
        zero_points: ``(T+1, C)`` indicator of the samples of each light curve whose zero point is unknown
            (relative photometry), or ``None``: each such curve's magnitude offset is profiled out of the residuals
            (its weighted mean residual removed, the exact minimum over the offset), so the state keeps its size.
        workers: Python threads that render the pieces of one call side by side (each piece's operations release
            the interpreter); the results do not depend on it. Run with one torch thread (:func:`torch_threads`) so
            the two kinds of parallelism do not compete.
    """

    def __init__(self, scene: Scene, *, q_ref: Tensor, seed: Tensor, cumulative: Tensor, observations: Tensor,
                 weight: Tensor, surface: Surface | None, zero_points: Tensor | None = None,
                 workers: int = 1) -> None:
        self.scene, self.q_ref, self.seed, self.surface = scene, q_ref, seed, surface
        self.zero_points = None if zero_points is None else zero_points.to(weight)
        self.workers = int(workers)
        self.y = torch.where(weight > 0, observations, 0.0)
        self.weight = weight
        # A(Δ_k)ᵀ (S, T+1, 3, 3): with A(q_k) = A(Δ_k) A(q_0) the body vectors of every sample are one product away
        self.turns = attitude_matrix(cumulative).mT.contiguous()

    def recentred(self, q_ref: Tensor, seed: Tensor) -> ArcProblem:
        """The same objects seen from other chart centres ``q_ref (M', 4)`` of objects ``seed (M',)``."""
        other = copy.copy(self)
        other.q_ref, other.seed = q_ref, seed
        return other

    def subset(self, rows: Tensor) -> ArcProblem:
        """The problems ``rows (M',)`` of this one (their chart centres and objects)."""
        return self.recentred(self.q_ref[rows], self.seed[rows])

    def reweighted(self, weight: Tensor) -> ArcProblem:
        """The same problems with other weights ``1/σ_k`` ``(S, T+1)`` (the same samples left out)."""
        other = copy.copy(self)
        other.weight = weight
        return other

    def attitude(self, x: Tensor, rows: Tensor) -> Tensor:
        """Initial attitudes ``q_0 = q(e) ⊗ q_ref`` ``(A, 4)`` of states ``x (A, n)`` of problems ``rows``."""
        return quat_mul(rotvec_to_quat(x[:, :3]), self.q_ref[rows])

    def magnitudes(self, x: Tensor, rows: Tensor) -> Tensor:
        """Predicted magnitudes ``(A, T+1)`` (mag) of states ``x (A, n)`` of problems ``rows``: the body vectors
        ``(A(Δ_k) A(q_0) [ŝ, v̂, ĥ])ᵀ`` of every sample (:meth:`Scene.body_vectors`), rendered a few problems at a
        time so that the vectors of a piece stay in the cache."""
        s = self.seed[rows]
        initial = self.scene.frame().mT @ attitude_matrix(self.attitude(x, rows)).mT.unsqueeze(-3)  # (A, 1|T+1, 3, 3)
        surface = surface_from_state(x[:, 3:7]) if self.surface is None else Surface(*(t[s] for t in self.surface))
        size = max(1, self.scene.chunk_attitudes // self.turns.shape[1])

        def render(piece: Tensor) -> Tensor:
            turns = self.turns[s[piece]]
            # one initial frame per problem: einsum, 3x faster than the broadcast matmul of the per-sample case
            body = torch.einsum("aij,atjk->atik", initial[piece, 0], turns) if initial.shape[1] == 1 else \
                initial[piece] @ turns
            return self.scene.magnitude_of_body(body, surface=Surface(*(t[piece] for t in surface)))

        pieces = torch.arange(rows.shape[0], device=rows.device).split(size)
        if self.workers > 1 and len(pieces) > 1:
            with ThreadPoolExecutor(min(self.workers, len(pieces))) as pool:
                return torch.cat(list(pool.map(render, pieces)))
        return torch.cat([render(piece) for piece in pieces])

    def __call__(self, x: Tensor, rows: Tensor) -> Tensor:
        """Whitened residuals ``(A, T+1)``; 0 where a sample is left out; the relative light curves' offsets
        profiled out (:meth:`offsets`)."""
        return self.residuals(x, rows)[0]

    def residuals(self, x: Tensor, rows: Tensor) -> tuple[Tensor, Tensor | None]:
        """Whitened residuals ``(A, T+1)`` and the relative light curves' best magnitude offsets ``(A, C)`` (added
        to the prediction; ``None`` without relative curves)."""
        s = self.seed[rows]
        w = self.weight[s]
        r = torch.where(w > 0, (self.y[s] - self.magnitudes(x, rows)) * w, 0.0)
        if self.zero_points is None:
            return r, None
        r, offsets, _ = profile_zero_points(r, w, self.zero_points)
        return r, offsets


@contextmanager
def torch_threads(count: int) -> Iterator[None]:
    """Run the block with ``count`` torch intra-op threads and restore the caller's count afterwards (the count is
    the process's: other threads running torch meanwhile see it too)."""
    before = torch.get_num_threads()
    torch.set_num_threads(count)
    try:
        yield
    finally:
        torch.set_num_threads(before)


@dataclass
class ArcStarts:
    """The solutions of ``S`` objects from ``K`` starts each, before their modes are found.

    Attributes:
        q0: the solutions' initial attitudes ``(K, S, 4)``; theta: their surface states ``(K, S, 4)`` or ``None``.
        covariance: each solution's Laplace covariance of ``[δ, θ]`` in its own chart ``(K, S, n, n)`` (NaN where
            singular or where an object has no such start).
        cost: the costs ``(K, S)`` (``inf`` where an object has no such start).
    """

    q0: Tensor
    theta: Tensor | None
    covariance: Tensor
    cost: Tensor

    def usable_cost(self) -> Tensor:
        """The costs ``(K, S)``, ``inf`` where a solution's cost or covariance is not finite (it is no mode)."""
        finite = torch.isfinite(self.cost) & torch.isfinite(self.covariance).flatten(-2).all(-1)
        return torch.where(finite, self.cost, math.inf)

    def extended(self, other: ArcStarts, rows: Tensor) -> ArcStarts:
        """These starts and ``other``'s, solved for the objects ``rows (S',)`` only: ``(K + K', S, ...)``, the
        objects outside ``rows`` padded with ``inf`` cost and NaN covariance."""
        return ArcStarts(q0=_stacked(self.q0, other.q0, rows, self.q0[0]),
                         theta=None if self.theta is None else _stacked(self.theta, other.theta, rows, 0.0),
                         covariance=_stacked(self.covariance, other.covariance, rows, math.nan),
                         cost=_stacked(self.cost, other.cost, rows, math.inf))


def _stacked(first: Tensor, second: Tensor, rows: Tensor, fill: float | Tensor) -> Tensor:
    """``first (K, S, ...)`` above ``second (K', S', ...)`` placed at objects ``rows`` and ``fill`` (broadcast to
    ``(K', S, ...)``) elsewhere."""
    out = first.new_empty((second.shape[0], *first.shape[1:]))
    out[:] = fill
    out[:, rows] = second
    return torch.cat([first, out])


@dataclass
class ArcSolution:
    """The whole-arc MAP of ``S`` objects from ``K`` starts each.

    Attributes:
        q0: the estimate, the best mode's initial attitude ``(S, 4)``; theta: its surface state ``(S, 4)`` or
            ``None``.
        covariance: the best mode's Laplace covariance of ``[δ, θ]`` in its own chart ``(S, n, n)``.
        attitude_covariance: the reported attitude covariance ``(S, 3, 3)`` (rad²): the modes' mixture about the
            estimate (module docstring).
        cost: the best cost ``(S,)``; modes: the number of modes kept ``(S,)``; best_start: the start that found
            it ``(S,)``; weight_best: the best mode's evidence weight ``(S,)``.
        start_q0, start_cost: every start's solution ``(K, S, 4)`` and cost ``(K, S)`` (``inf`` where an object had
            no such start).
        searched_again: the objects a second search was run for ``(S,)`` (bool), ``None`` when there was none to
            run (:func:`~lightcurve_gp.evaluation.whole_arc.whole_arc_map`'s misfit test).
    """

    q0: Tensor
    theta: Tensor | None
    covariance: Tensor
    attitude_covariance: Tensor
    cost: Tensor
    modes: Tensor
    best_start: Tensor
    weight_best: Tensor
    start_q0: Tensor
    start_cost: Tensor
    searched_again: Tensor | None = None


def prior_axis_starts(q_prior: Tensor, sigma0: Tensor, *, spread: float = math.sqrt(3.0)) -> Tensor:
    """The prior mean and ``±spread · σ0`` about each body axis of it: ``(7, S, 4)`` from ``q_prior (S, 4)``,
    ``sigma0 (S,)`` (rad)."""
    S = q_prior.shape[0]
    starts = [q_prior]
    for axis in range(3):
        for sign in (1.0, -1.0):
            e = torch.zeros(S, 3, dtype=q_prior.dtype, device=q_prior.device)
            e[:, axis] = sign * spread * sigma0.to(q_prior)
            starts.append(quat_mul(rotvec_to_quat(e), q_prior))
    return torch.stack(starts)


def prior_corner_starts(q_prior: Tensor, sigma0: Tensor) -> Tensor:
    """The prior mean turned by ``(±σ0, ±σ0, ±σ0)`` (the eight corners of the cube, ``√3 σ0`` away): ``(8, S, 4)``
    from ``q_prior (S, 4)``, ``sigma0 (S,)`` (rad)."""
    corners = torch.tensor(list(itertools.product((1.0, -1.0), repeat=3)), dtype=q_prior.dtype,
                           device=q_prior.device)  # (8, 3)
    e = corners.unsqueeze(1) * sigma0.to(q_prior).view(1, -1, 1)
    return quat_mul(rotvec_to_quat(e), q_prior.unsqueeze(0))


def refine_starts(problem: ArcProblem, *, starts: Tensor, theta_starts: Tensor | None, prior_mean: Tensor,
                  prior_precision: Tensor, keep: int, options: LeastSquaresOptions = ARC_OPTIONS
                  ) -> tuple[Tensor, Tensor | None]:
    """Solve the ``S`` objects of ``problem`` (its ``q_ref (S, 4)`` the prior mean) from every start ``(K, S, 4)``
    (and surface state ``(K, S, 4)``) and return the ``keep`` best solutions per object by cost, ``(keep, S, 4)``
    and ``(keep, S, 4)`` or ``None``: the starts of a later, sharper problem (a continuation)."""
    K, S = starts.shape[:2]
    seed = torch.arange(S, device=starts.device).repeat(K)
    e0 = quat_to_rotvec(quat_mul(starts.reshape(K * S, 4), quat_conj(problem.q_ref[seed])))
    x0 = e0 if theta_starts is None else torch.cat([e0, theta_starts.reshape(K * S, -1)], -1)
    tiled = problem.subset(seed)
    gaussian = GaussianPrior.independent(prior_mean[seed], prior_precision[seed])
    result = batch_least_squares(tiled, x0, prior=gaussian, variance=1.0, options=options)
    q = tiled.attitude(result.x, torch.arange(K * S, device=starts.device)).view(K, S, 4)
    cost = torch.where(torch.isfinite(result.cost), result.cost, math.inf).view(K, S)
    best = cost.topk(min(keep, K), dim=0, largest=False).indices  # (keep, S)
    q_best = q.gather(0, best.unsqueeze(-1).expand(-1, -1, 4))
    if theta_starts is None:
        return q_best, None
    theta = result.x[:, 3:].view(K, S, -1)
    return q_best, theta.gather(0, best.unsqueeze(-1).expand(-1, -1, theta.shape[-1]))


def solve_starts(problem: ArcProblem, *, starts: Tensor, theta_starts: Tensor | None, prior_mean: Tensor,
                 prior_precision: Tensor, options: LeastSquaresOptions = ARC_OPTIONS) -> ArcStarts:
    """Solve the ``S`` problems of ``problem`` (each ``q_ref`` the prior mean of its object) from the starts
    ``(K, S, 4)`` (and surface states ``(K, S, 4)`` with the surface unknown), all ``K S`` in one batch, each
    solution with its Laplace covariance.

    Args:
        prior_mean: ``μ`` of ``x = [e, θ]`` ``(S, n)`` (``e``'s part 0); prior_precision: ``Λ``'s diagonal ``(S, n)``.
    """
    K, S = starts.shape[:2]
    seed = torch.arange(S, device=starts.device).repeat(K)
    q_prior = problem.q_ref
    e0 = quat_to_rotvec(quat_mul(starts.reshape(K * S, 4), quat_conj(q_prior[seed])))
    x0 = e0 if theta_starts is None else torch.cat([e0, theta_starts.reshape(K * S, -1)], -1)
    tiled = problem.subset(seed)
    gaussian = GaussianPrior.independent(prior_mean[seed], prior_precision[seed])
    result = batch_least_squares(tiled, x0, prior=gaussian, variance=1.0, options=options)
    q_all = tiled.attitude(result.x, torch.arange(K * S, device=starts.device))
    theta_all = None if theta_starts is None else result.x[:, 3:]
    cov_all = _local_covariance(tiled, q_all, theta_all, prior_precision[seed], options)
    return ArcStarts(q0=q_all.view(K, S, 4), theta=None if theta_all is None else theta_all.view(K, S, -1),
                     covariance=cov_all.view(K, S, *cov_all.shape[-2:]), cost=result.cost.view(K, S))


def solve_arc(problem: ArcProblem, *, starts: Tensor, theta_starts: Tensor | None, prior_mean: Tensor,
              prior_precision: Tensor, options: LeastSquaresOptions = ARC_OPTIONS, max_log_ratio: float = 10.0,
              mode_angle_deg: float = 1.0) -> ArcSolution:
    """The whole-arc MAP of the ``S`` problems of ``problem`` from the starts ``(K, S, 4)`` (:func:`solve_starts`,
    then :func:`arc_modes`; module docstring)."""
    solved = solve_starts(problem, starts=starts, theta_starts=theta_starts, prior_mean=prior_mean,
                          prior_precision=prior_precision, options=options)
    return arc_modes(solved, max_log_ratio=max_log_ratio, mode_angle_deg=mode_angle_deg)


def _local_covariance(problem: ArcProblem, q0: Tensor, theta: Tensor | None, precision: Tensor,
                      options: LeastSquaresOptions) -> Tensor:
    """Laplace covariances ``(M, n, n)`` of the solutions ``q0 (M, 4)`` (and ``θ``) of the ``M`` problems of
    ``problem``, each in its own chart (``δ = 0`` at the solution): ``(JᵀJ + Λ)⁻¹``, NaN where singular."""
    local = problem.recentred(q0, problem.seed)
    x = torch.zeros(q0.shape[0], 3, dtype=q0.dtype, device=q0.device)
    x = x if theta is None else torch.cat([x, theta], -1)
    rows = torch.arange(q0.shape[0], device=q0.device)
    size = options.chunk or q0.shape[0]
    blocks = []
    for xc, rc in zip(x.split(size), rows.split(size)):
        r, J = jacobian(local, xc, rc, method=options.jacobian, step=options.step)
        J = torch.where((torch.isfinite(r) & torch.isfinite(J).all(-1)).unsqueeze(-1), J, 0.0)
        blocks.append(J.mT @ J + torch.diag_embed(precision[rc]))
    cov, info = torch.linalg.inv_ex(torch.cat(blocks))
    return torch.where((info != 0)[:, None, None], torch.nan, cov)


def arc_modes(solved: ArcStarts, *, max_log_ratio: float = 10.0, mode_angle_deg: float = 1.0) -> ArcSolution:
    """The best start per object, its modes and the mixture covariance about it (module docstring).

    Args:
        solved: every start's solution.
        max_log_ratio: modes more than this many nats above the best are dropped.
        mode_angle_deg: solutions closer than this are one mode.
    """
    q0, theta, cov, cost = solved.q0, solved.theta, solved.covariance, solved.usable_cost()
    K, S = cost.shape
    finite = torch.isfinite(cost)
    best = cost.argmin(0)
    cols = torch.arange(S, device=cost.device)
    q_best, cost_best = q0[best, cols], cost[best, cols]
    d = quat_to_rotvec(quat_mul(q0, quat_conj(q_best).unsqueeze(0)))  # (K, S, 3)
    candidate = finite & (cost - cost_best <= max_log_ratio)
    # one mode per cluster: a start counts when no better start lies within the angle (greedy, best first)
    order = torch.argsort(cost, dim=0)
    head = torch.zeros_like(candidate)
    for rank in range(K):
        i = order[rank]
        apart = quat_to_rotvec(quat_mul(q0, quat_conj(q0[i, cols]).unsqueeze(0)))
        near = torch.rad2deg(torch.linalg.vector_norm(apart, dim=-1)) < mode_angle_deg  # (K, S)
        head[i, cols] = candidate[i, cols] & ~(head & near).any(0)
    eye = torch.eye(cov.shape[-1], dtype=cov.dtype, device=cov.device)
    logdet = torch.linalg.slogdet(torch.where(head[..., None, None], cov, eye))  # the mode's whole volume
    log_w = torch.where(head & (logdet.sign > 0), -cost + 0.5 * logdet.logabsdet, -math.inf)
    w = torch.softmax(log_w, dim=0)  # (K, S), zero off the modes
    att = torch.where(head[..., None, None], cov[..., :3, :3], eye[:3, :3])
    mixture = mixture_covariance(att, torch.where(head.unsqueeze(-1), d, 0.0), w)
    return ArcSolution(q0=q_best, theta=None if theta is None else theta[best, cols], covariance=cov[best, cols],
                       attitude_covariance=mixture, cost=cost_best, modes=head.sum(0), best_start=best,
                       weight_best=w[best, cols], start_q0=q0, start_cost=cost)


def mixture_covariance(covariances: Tensor, offsets: Tensor, weights: Tensor) -> Tensor:
    """``Σ_m w_m (Σ_m + d_m d_mᵀ)`` ``(..., 3, 3)`` of mode covariances ``(M, ..., 3, 3)``, offsets from the estimate
    ``(M, ..., 3)`` and weights ``(M, ...)`` (summing to 1 over ``M``)."""
    return (weights[..., None, None] * (covariances + offsets.unsqueeze(-1) * offsets.unsqueeze(-2))).sum(0)
