"""The whole-arc batch MAP's search: started from a filter's result and a small set of prior starts, solved for every
object of a :class:`~lightcurve_gp.observations.problem.Problem` at once (:mod:`lightcurve_gp.inference.arc`); its
settings are the config's ``map:`` section (:class:`~lightcurve_gp.config.schema.MapConfig`, written ``map.x``
below, validated and hashed like every section).

Starts (``K`` per seed, one batch): the filter's final attitude moved back to ``t_0`` by the known motion (and its
final surface state), the prior mean ``q_est,0`` and the prior mean turned by ``±√3 σ0`` about each body axis; with
the surface unknown also the filter's and the prior mean's attitude and surface state with both lobe exponents set
to each of ``map.lobe_starts`` (a light curve whose glints come from a lobe decades from the prior's is out of reach
of a local search in ``log n``); with ``screen > 0`` also the ``keep`` best by posterior cost of ``screen``
quasi-random draws from the prior (a scrambled Sobol' sequence mapped to ``N(0, σ0² I)``, the surface at its prior
mean), which costs one rendering of the arc per draw. Below the noise floor (``R < map.noise_floor_mag²``, 0.1 mag) the
search is a continuation in the noise: every start, and the prior mean turned to the eight corners
``(±σ0, ±σ0, ±σ0)``, is first solved with ``max(R, floor²)`` for at most ``map.floor_iterations``
Levenberg–Marquardt iterations (a landscape whose narrow basins the prior still outweighs; this stage only ranks
basins) and the ``map.floor_keep`` best solutions per seed start the solve with ``R``; at and above the floor
nothing changes.

The misfit test (surface unknown): the best cost of a seed whose fit is right is ``½ χ²_ν`` of its ``ν`` observed
samples, mean ``ν/2`` and standard deviation ``√(ν/2)``, whatever the noise; a seed above
``ν/2 + map.misfit_z √(ν/2)`` is searched again, from its best solution's and the filter's attitude and surface state
with the lobe exponents set to each unequal pair of ``map.lobe_pairs`` (a glint of a lobe narrow along one axis and
broad along the other is out of reach of starts with ``n_u = n_v``), and from the ``map.again_keep`` best of
``map.again_draws`` quasi-random prior draws of the attitude, each with every lobe setting of ``map.lobe_pairs`` and
``map.lobe_starts``, ranked by posterior cost (at the floor below it: the attitude of a narrow-lobed truth far from
the filter's answer is out of reach of both other kinds of start), each with the same continuation below the floor;
the modes are found among the solutions of both searches. Seeds that pass the test cost nothing more (with
``map.misfit_z = 1`` about one in six whose fit is right is searched again).

The weak-direction probe (every seed, surface known or not): a second basin of about the same cost often lies along
the valley of the best solution's weakest attitude direction, a few of its standard deviations away, behind a ridge
that a local search does not cross; the mixture then holds one mode where the data hold two. Every seed is started
again from its best solution moved ``±k`` standard deviations along that direction, the surface state along the
valley with it (:func:`weak_direction_starts`, ``k`` in ``map.probe_sigmas``), solved with the true noise, and the
modes are found among all solutions. Each choice was made on the tuning seeds of the random truths (1000–1089; the
study ``docs/studies/realistic-photometry.md`` has the numbers).

The measurement noise is the problem's ``R`` (a file's ``mag_err²``) or the filters' ``filter.measurement_noise``; ω is
known (the problem's assumed rate); the unknown zero point of every relative light curve is profiled out. The estimate
at sample ``k`` is ``q̂_k = Δ_k ⊗ q̂_0`` with covariance ``A(Δ_k) Σ A(Δ_k)ᵀ`` (``Σ`` the reported attitude covariance
at ``t_0``; :func:`lightcurve_gp.evaluation.registry.arc_estimate`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from contextlib import nullcontext
from dataclasses import dataclass, replace
from typing import Any

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import quat_conj, quat_mul, rotvec_to_quat
from lightcurve_gp.config.load import Config
from lightcurve_gp.config.schema import MapConfig
from lightcurve_gp.filters.setup import first_observation
from lightcurve_gp.filters.state import FilterHistory
from lightcurve_gp.inference.arc import (
    ARC_OPTIONS,
    ArcProblem,
    ArcSolution,
    ArcStarts,
    arc_modes,
    prior_axis_starts,
    prior_corner_starts,
    refine_starts,
    solve_starts,
    torch_threads,
)
from lightcurve_gp.inference.solver import GaussianPrior, least_squares_cost
from lightcurve_gp.inference.surface import cumulative_increments
from lightcurve_gp.observation.surface_state import reference_surface, surface_state_prior
from lightcurve_gp.observations.problem import Problem
from lightcurve_gp.photometry.render import Scene

__all__ = ["ArcSetup", "arc_setup", "SCREEN_SEED", "weak_direction_starts", "search_settings", "misfit_threshold",
           "whole_arc_map"]

#: seed of the scrambled Sobol' draws of the screening
SCREEN_SEED = 27


def _weights(observations: Tensor, R: float | Tensor) -> Tensor:
    """``1/σ_k`` ``(S, T+1)``: 0 at ``k = 0`` and where a sample is missing."""
    R = torch.as_tensor(R, dtype=observations.dtype, device=observations.device)
    w = torch.where(torch.isfinite(observations), R.rsqrt().expand_as(observations), 0.0).clone()
    w[:, 0] = 0.0
    return w


def _screened(problem: ArcProblem, prior: GaussianPrior, thetas: Tensor | None, sigma0: Tensor, *, count: int,
              keep: int) -> tuple[Tensor, Tensor | None]:
    """The ``keep`` best per seed by posterior cost of ``count`` prior draws of the attitude, each with every surface
    state of ``thetas`` ``(L, S, 4)`` (or none, the surface known): attitudes ``(keep, S, 4)`` and surface states
    ``(keep, S, 4)`` or ``None``. One rendering of the arc per draw and surface state."""
    S = sigma0.shape[0]
    L = 1 if thetas is None else thetas.shape[0]
    engine = torch.quasirandom.SobolEngine(3, scramble=True, seed=SCREEN_SEED)
    u = engine.draw(count).to(sigma0).clamp(1e-6, 1 - 1e-6)
    z = math.sqrt(2.0) * torch.erfinv(2.0 * u - 1.0)  # (count, 3) standard normals
    e = (z.view(count, 1, 1, 3) * sigma0.view(1, 1, S, 1)).expand(count, L, S, 3)
    x = e if thetas is None else torch.cat([e, thetas.unsqueeze(0).expand(count, L, S, thetas.shape[-1])], -1)
    x = x.reshape(count * L, S, -1)
    rows = torch.arange(S, device=sigma0.device).repeat(count * L)
    costs = []
    for xc, rc in zip(x.reshape(count * L * S, -1).split(1024), rows.split(1024)):
        costs.append(least_squares_cost(problem(xc, rc), xc, rc, prior=prior, invalid_residual=1e3))
    best = torch.cat(costs).view(count * L, S).topk(keep, dim=0, largest=False).indices  # (keep, S)
    x_best = x.gather(0, best.unsqueeze(-1).expand(keep, S, x.shape[-1]))
    q = quat_mul(rotvec_to_quat(x_best[..., :3]), problem.q_ref.unsqueeze(0))
    return q, None if thetas is None else x_best[..., 3:]


def _with_lobes(theta: Tensor, pairs: Sequence[tuple[float, float]]) -> Tensor:
    """Surface states ``theta (B, S, 4)`` repeated once per pair of lobe exponents, ``(log n_u, log n_v)`` set to
    it: ``(L B, S, 4)``, pair-major (the attitudes repeated with ``.repeat(L, 1, 1)`` match them)."""
    out = theta.repeat(len(pairs), 1, 1)
    logs = torch.tensor([[math.log(n_u), math.log(n_v)] for n_u, n_v in pairs], dtype=theta.dtype,
                        device=theta.device)  # (L, 2)
    out[..., 2:4] = logs.repeat_interleave(theta.shape[0], dim=0).unsqueeze(1)
    return out


def weak_direction_starts(solved: ArcStarts, sigmas: Sequence[float]) -> tuple[Tensor, Tensor | None]:
    """Every object's best solution moved along its weakest attitude direction: ``(2 L, S, 4)`` attitudes and
    surface states (or ``None``), ``L = len(sigmas)``, the signs outermost.

    With ``Σ`` the best solution's Laplace covariance of ``[δ, θ]`` in its own chart and ``u`` the top eigenvector
    (variance ``λ``) of its attitude block, the move of ``±k`` standard deviations is the conditional mean shift
    ``Δx = ±(k / √λ) Σ[:, :3] u``: ``δ = ±k √λ u`` and the surface state along the valley with it."""
    cost, best = solved.usable_cost().min(0)
    cols = torch.arange(cost.shape[0], device=cost.device)
    cov = solved.covariance[best, cols]  # (S, n, n)
    cov = torch.where(torch.isfinite(cov), cov, 0.0)
    lam, vec = torch.linalg.eigh(cov[:, :3, :3])
    u, s = vec[..., -1], lam[..., -1].clamp(min=0.0).sqrt()  # (S, 3), (S,)
    shift = (cov[:, :, :3] @ u.unsqueeze(-1)).squeeze(-1) / s.clamp(min=1e-12).unsqueeze(-1)  # (S, n) per unit k
    ks = torch.tensor([sign * k for sign in (1.0, -1.0) for k in sigmas], dtype=cov.dtype, device=cov.device)
    dx = ks.view(-1, 1, 1) * shift.unsqueeze(0)  # (2L, S, n)
    q = quat_mul(rotvec_to_quat(dx[..., :3]), solved.q0[best, cols].unsqueeze(0))
    theta = None if solved.theta is None else solved.theta[best, cols].unsqueeze(0) + dx[..., 3:]
    return q, theta


def search_settings(settings: MapConfig, *, surface_known: bool, noise_var: float) -> dict[str, Any]:
    """The search of :func:`whole_arc_map` under ``settings`` as JSON values, what a stored result depends on (a case
    key): the continuation (``None`` at and above the floor), the surface starts and the misfit test's second search
    (surface unknown only) and the probe."""
    floor_mag = settings.noise_floor_mag
    floor = floor_mag is not None and noise_var < floor_mag ** 2
    out: dict[str, Any] = {"floor": [floor_mag, settings.floor_keep, settings.floor_iterations] if floor else None,
                           "lobes": None if surface_known else list(settings.lobe_starts),
                           "probe": list(settings.probe_sigmas)}
    if not surface_known:
        out["misfit"] = [settings.misfit_z, [list(p) for p in settings.lobe_pairs], settings.again_draws,
                         settings.again_keep]
    return out


def misfit_threshold(weight: Tensor, z: float) -> Tensor:
    """The cost ``ν/2 + z √(ν/2)`` ``(S,)`` above which a seed's fit is suspect, ``ν`` its samples with weight
    ``(S, T+1)`` > 0 (the whitened residuals' ``½ χ²_ν`` has mean ``ν/2`` and standard deviation ``√(ν/2)``)."""
    nu = (weight > 0).sum(-1).to(weight.dtype)
    return nu / 2 + z * (nu / 2).sqrt()


def _floored(problem: ArcProblem, observations: Tensor, R: float | Tensor, floor_mag: float | None
              ) -> ArcProblem | None:
    """``problem`` with every noise variance raised to at least ``floor_mag²``; ``None`` when no sample is below it
    (or no floor)."""
    R = torch.as_tensor(R, dtype=observations.dtype, device=observations.device)
    if floor_mag is None or not bool((R < floor_mag ** 2).any()):
        return None
    return problem.reweighted(_weights(observations, R.clamp(min=floor_mag ** 2)))


@dataclass(frozen=True)
class ArcSetup:
    """The whole-arc problem of a scenario and its prior (:func:`arc_setup`).

    Attributes:
        problem: the whitened residuals of every seed, each seen from its prior mean ``q_est0``.
        prior_mean: ``μ`` of ``x = [e, θ]`` ``(S, n)`` (``e``'s part 0; ``n = 3``, or 7 with the surface unknown).
        prior_precision: ``Λ``'s diagonal ``(S, n)`` (rad⁻², surface units⁻²).
        theta0: the surface state's prior mean ``(S, 4)``, ``None`` with the surface known.
        cumulative: the assumed motion ``Δ_k`` of every seed ``(S, T+1, 4)``: ``q_k = Δ_k ⊗ q_0``.
    """

    problem: ArcProblem
    prior_mean: Tensor
    prior_precision: Tensor
    theta0: Tensor | None
    cumulative: Tensor


def arc_setup(cfg: Config, scene: Scene, sc: Problem, *, surface_known: bool, R: float | Tensor | None = None,
              workers: int = 1) -> ArcSetup:
    """The whole-arc problem of every seed of ``sc`` and its prior: the attitude ``e ~ N(0, σ0² I)`` about ``q_est0``
    and, with the surface unknown, the surface-state filter's prior of ``θ``; ``R`` the noise variance (mag², a
    number or per sample ``(S, T+1)``; default ``filter.measurement_noise``), ω known (the assumed increments)."""
    cum = cumulative_increments(sc.increments_assumed.to(sc.q_est0))
    S = sc.q_est0.shape[0]
    R = sc.noise_variance(cfg.filter.measurement_noise) if R is None else R
    problem = ArcProblem(scene, q_ref=sc.q_est0, seed=torch.arange(S), cumulative=cum, observations=sc.observations,
                         weight=_weights(sc.observations, R), surface=sc.surface if surface_known else None,
                         zero_points=sc.obs.zero_point_indicator(), workers=workers)
    sigma0 = sc.sigma0.to(sc.q_est0)
    mean, precision = torch.zeros(S, 3, dtype=cum.dtype), sigma0.pow(-2).unsqueeze(-1).expand(S, 3)
    theta0 = None
    if not surface_known:
        first = scene.sample(0) if scene.per_sample else scene
        theta0, std = surface_state_prior(scene=first, q_est0=sc.q_est0, y0=first_observation(sc.observations),
                                          reference=reference_surface(cfg), offset_std=cfg.filter.offset_prior_std)
        mean, precision = torch.cat([mean, theta0], -1), torch.cat([precision, std.pow(-2).expand(S, 4)], -1)
    return ArcSetup(problem, mean, precision, theta0, cum)


def whole_arc_map(cfg: Config, scene: Scene, sc: Problem, *, start: FilterHistory | None, surface_known: bool,
                  R: float | Tensor | None = None, settings: MapConfig | None = None,
                  workers: int | None = None) -> ArcSolution:
    """The whole-arc MAP of every object of ``sc`` (module docstring).

    Args:
        cfg: the config (``filter.measurement_noise``, ``filter.offset_prior_std``, the reference surface, ``map``).
        scene: the renderer of the known shape (fixed, or per sample along the pass).
        sc: the problem; its ``q_est0`` and ``sigma0`` are the prior, its assumed increments the motion.
        start: a filter's run on the same objects (its final estimate is one start), or ``None``.
        surface_known: render with the truth's surface (an oracle, like ``matched_ukf``: ``sc.surface``); else the
            surface state is estimated with the surface-state filter's prior.
        R: the noise variance (mag²), a number or per sample ``(S, T+1)``; default the problem's, else
            ``filter.measurement_noise``.
        settings: the search (default ``cfg.map``): ``screen`` and ``keep`` prior draws screened by cost for starts;
            the continuation below ``noise_floor_mag`` (every start, and the prior's cube corners, first solved with
            ``max(R, floor²)`` for at most ``floor_iterations``, the ``floor_keep`` best per object then solved with
            ``R``; ``None``: none); with the surface unknown the surface starts at each of ``lobe_starts`` and the
            misfit test (``misfit_z``; ``None``: none) whose failing objects are searched again from the unequal
            ``lobe_pairs`` and from the ``again_keep`` best of ``again_draws`` prior draws with every lobe setting;
            the probe along the weakest direction at each of ``probe_sigmas`` (empty: none).
        workers: threads that render independent pieces of the problems side by side, torch held to one thread
            meanwhile (:class:`~lightcurve_gp.inference.arc.ArcProblem`); default the caller's torch thread count.
            The result does not depend on it.
    """
    settings = cfg.map if settings is None else settings
    screen, keep = settings.screen, settings.keep
    noise_floor_mag, floor_keep, floor_iterations = (settings.noise_floor_mag, settings.floor_keep,
                                                     settings.floor_iterations)
    lobe_starts, misfit_z = tuple(settings.lobe_starts), settings.misfit_z
    lobe_pairs = tuple(tuple(p) for p in settings.lobe_pairs)
    again_draws, again_keep, probe_sigmas = settings.again_draws, settings.again_keep, tuple(settings.probe_sigmas)
    workers = torch.get_num_threads() if workers is None else int(workers)
    R = sc.noise_variance(cfg.filter.measurement_noise) if R is None else R
    setup = arc_setup(cfg, scene, sc, surface_known=surface_known, R=R, workers=workers)
    problem, mean, precision, theta0 = setup.problem, setup.prior_mean, setup.prior_precision, setup.theta0
    S, sigma0, cum = sc.q_est0.shape[0], sc.sigma0.to(sc.q_est0), setup.cumulative
    floored = _floored(problem, sc.observations, R, noise_floor_mag)
    starts = [prior_axis_starts(sc.q_est0, sigma0)] + ([] if floored is None else [prior_corner_starts(sc.q_est0,
                                                                                                      sigma0)])
    thetas = [None if theta0 is None else theta0.expand(starts[0].shape[0] + 8 * len(starts[1:]), S, 4)]
    if start is not None:
        starts.insert(0, quat_mul(quat_conj(cum[:, -1]), start.q_est[:, -1]).unsqueeze(0))
        thetas.insert(0, None if theta0 is None else start.theta[:, -1].unsqueeze(0))
    if theta0 is not None and lobe_starts:  # the filter's answer (first) and the prior mean, one per lobe exponent
        base_q, base_t = sc.q_est0.unsqueeze(0), theta0.unsqueeze(0)
        if start is not None:
            base_q, base_t = torch.cat([starts[0], base_q]), torch.cat([thetas[0], base_t])
        starts.append(base_q.repeat(len(lobe_starts), 1, 1))
        thetas.append(_with_lobes(base_t, [(n, n) for n in lobe_starts]))
    with torch_threads(1) if workers > 1 else nullcontext():  # the renderings below: the worker threads' share
        if screen:
            prior = GaussianPrior.independent(mean, precision)
            q_s, t_s = _screened(problem, prior, None if theta0 is None else theta0.unsqueeze(0), sigma0,
                                 count=screen, keep=keep)
            starts.append(q_s)
            thetas.append(t_s)
        starts, thetas = torch.cat(starts), None if theta0 is None else torch.cat(thetas)
        search = functools.partial(_search, prior_mean=mean, prior_precision=precision, floor_keep=floor_keep,
                                   floor_iterations=floor_iterations)
        solved, again = search(problem, floored, starts=starts, thetas=thetas), None
        if theta0 is not None and lobe_pairs and misfit_z is not None:
            best_cost, best = solved.usable_cost().min(0)
            again = best_cost > misfit_threshold(problem.weight, misfit_z)
            rows = again.nonzero().flatten()
            if rows.numel():  # from the best solution's attitude and surface state (and the filter's)
                base_q, base_t = solved.q0[best[rows], rows].unsqueeze(0), solved.theta[best[rows], rows].unsqueeze(0)
                if start is not None:
                    base_q = torch.cat([base_q, starts[:1, rows]])
                    base_t = torch.cat([base_t, thetas[:1, rows]])
                second = search(problem.subset(rows), None if floored is None else floored.subset(rows),
                                starts=base_q.repeat(len(lobe_pairs), 1, 1), thetas=_with_lobes(base_t, lobe_pairs),
                                rows=rows)
                solved = solved.extended(second, rows)
                if again_draws:  # prior draws of the attitude with every lobe setting, ranked at the floor
                    ranked = problem.subset(rows) if floored is None else floored.subset(rows)
                    lobes = _with_lobes(theta0[rows].unsqueeze(0), [*lobe_pairs, *((n, n) for n in lobe_starts)])
                    q_s, t_s = _screened(ranked, GaussianPrior.independent(mean[rows], precision[rows]), lobes,
                                         sigma0[rows], count=again_draws, keep=again_keep)
                    screened = search(problem.subset(rows), None if floored is None else floored.subset(rows),
                                      starts=q_s, thetas=t_s, rows=rows)
                    solved = solved.extended(screened, rows)
        if probe_sigmas:  # every seed, from its best solution along its weakest direction, with the true noise
            q_p, t_p = weak_direction_starts(solved, probe_sigmas)
            solved = solved.extended(search(problem, None, starts=q_p, thetas=t_p), torch.arange(S))
        return replace(arc_modes(solved), searched_again=again)


def _search(problem: ArcProblem, floored: ArcProblem | None, *, starts: Tensor, thetas: Tensor | None,
            prior_mean: Tensor, prior_precision: Tensor, floor_keep: int, floor_iterations: int,
            rows: Tensor | None = None) -> ArcStarts:
    """Every start's solution ``(K, S', ...)`` of the problems of ``problem`` (objects ``rows`` of the prior, all
    when ``None``): first the continuation's stage on ``floored`` when given, then the solve."""
    mean, precision = (prior_mean, prior_precision) if rows is None else (prior_mean[rows], prior_precision[rows])
    if floored is not None:
        starts, thetas = refine_starts(floored, starts=starts, theta_starts=thetas, prior_mean=mean,
                                       prior_precision=precision, keep=floor_keep,
                                       options=replace(ARC_OPTIONS, iterations=floor_iterations))
    return solve_starts(problem, starts=starts, theta_starts=thetas, prior_mean=mean, prior_precision=precision)
