"""The estimators by name: what each one runs on a scenario (the names of every table, figure and JSON file).

Filters are the USQUE of :mod:`lightcurve_gp.filters` started by :mod:`lightcurve_gp.filters.setup` from the seed's
``q_est,0`` with ``P0 = σ0² I`` (the scenario's ``σ0``: ``filter.p0_deg`` for the config's truth, the drawn one for
random truths), ``m_past,0 = ỹ_0`` and, with the offset in the state, ``b0 = ỹ_0 − h(q̂_0)``; ω is in the state
with ``filter.estimate_omega`` (from ``ω_est,0``), otherwise the filters propagate with the rate the scenario
assumes. Along a pass every model predicts step ``k`` with the geometry of sample ``k``.

* ``gpukf`` — USQUE with the trained GP (paper section 3.3); with ``filter.estimate_offset`` the GP models the
  reference light curve and the offset ``b`` is in the state (surface unknown, shape known; the generalisation
  suite's tables call it ``robust_gpukf``);
* ``ukf`` — the conventional UKF: the renderer with the assumed ``filter.rho_assumed``;
* ``matched_ukf`` — an oracle: the renderer with the true surface (the config's truth, ``scenario.surface``, or each
  seed's);
* ``joint_ukf`` — the renderer at the reference surface (``model.rho_reference`` and the config's F0, n_u, n_v) with
  the offset in the state: a conventional UKF that estimates ρ but not F0, n_u, n_v;
* ``surface_ukf`` — the renderer with the surface as states (log ρ, logit F0, log n_u, log n_v,
  :mod:`lightcurve_gp.observation.surface_state`): surface unknown, shape known (ω known);
* ``surface_ukf_select`` — that filter run with the paper's ``λ = 0`` and with Julier's ``λ = 3 − n``, each seed's
  run of higher innovation likelihood kept (:func:`run_surface_filter_selected`);
* ``map_surface`` — the batch MAP reference with attitude, ρ, F0, n_u, n_v unknown, at checkpoints every
  ``map_every_s`` inside the scoring window (:func:`map_estimate`; fixed geometry, ω known);
* ``map_offset`` — the batch MAP with attitude and offset on the reference surface (the joint UKF's model);
* ``map`` — the whole-arc batch MAP of the initial attitude and the surface state (surface unknown, shape known,
  ω known) from every sample at once: started from the ``surface_ukf`` run and seven prior starts, its Laplace
  covariance (a mixture where several basins fit) carried to every sample
  (:mod:`lightcurve_gp.inference.arc_search`, settings ``map:``);
* ``matched_map`` — the same with the truth's surface known (an oracle, started from the ``matched_ukf`` run);
* ``no_update`` — the initial estimate propagated with the assumed rate (a filter that learned nothing; its
  covariance stays ``P0``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable

import torch
from torch import Tensor

from lightcurve_gp.attitude.dynamics import propagate_only
from lightcurve_gp.attitude.rotations import attitude_matrix, quat_mul
from lightcurve_gp.config.load import Config
from lightcurve_gp.evaluation.scoring import Estimate
from lightcurve_gp.filters.selection import select_by_likelihood
from lightcurve_gp.filters.setup import run_filter, run_surface_filter
from lightcurve_gp.filters.state import FilterHistory
from lightcurve_gp.inference.arc import ArcSolution
from lightcurve_gp.inference.arc_search import whole_arc_map
from lightcurve_gp.inference.surface import cumulative_increments, map_with_surface
from lightcurve_gp.observation.base import ObservationModel
from lightcurve_gp.observation.parametric import Parametric
from lightcurve_gp.observation.surface_state import reference_surface
from lightcurve_gp.observations.problem import Problem
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.truths import truth_is_model_surface

__all__ = ["RunContext", "Estimator", "ESTIMATORS", "DEFAULT_ESTIMATORS", "SELECTED_LAM_RULES",
           "run_surface_filter_selected", "map_checkpoints", "map_estimate", "map_solution", "arc_estimate"]

#: the λ rules the selecting surface-state filter runs with (``filter.lam_rule``)
SELECTED_LAM_RULES = ("given", "julier")


@dataclass(frozen=True)
class RunContext:
    """What an estimator runs with: the config (the whole-arc MAPs' search in its ``map`` section), the problem
    (observations and priors), its renderer (fixed, or per sample along the pass), the trained GP (or ``None``) and
    the checkpoint MAPs' spacing (s)."""

    cfg: Config
    problem: Problem
    scene: Scene
    model: ObservationModel | None = None
    map_every_s: float = 50.0


@dataclass(frozen=True)
class Estimator:
    """One entry of :data:`ESTIMATORS`.

    Attributes:
        name: the name the tables use.
        run: the batched run on every seed of the context's scenario.
        needs_model: whether it needs the trained GP.
        estimates_omega: whether it runs with ``filter.estimate_omega`` (ω in the state or propagated with the
            assumed rate); the others take ω as known and refuse that setting.
        along_pass: whether it runs along a pass (``geometry.kind: orbit``).
    """

    name: str
    run: Callable[[RunContext], Estimate]
    needs_model: bool = False
    estimates_omega: bool = True
    along_pass: bool = True


def _usque(ctx: RunContext, model: ObservationModel, *, offset: bool | None = None) -> Estimate:
    """The config's USQUE with ``model`` on every seed (module docstring)."""
    sc, cfg = ctx.problem, ctx.cfg
    history = run_filter(cfg, model, q_est0=sc.q_est0, observations=sc.observations,
                         increments=sc.increments_assumed, sigma0=sc.sigma0, offset=offset,
                         omega0=sc.omega_est0 if cfg.filter.estimate_omega else None, geometry=sc.geometry,
                         scene=ctx.scene)
    return Estimate.of_filter(history)


def _gpukf(ctx: RunContext) -> Estimate:
    return _usque(ctx, ctx.model.to(torch.device(ctx.cfg.device)))


def _ukf(ctx: RunContext) -> Estimate:
    return _usque(ctx, Parametric(ctx.scene, ctx.cfg.filter.rho_assumed), offset=False)


def _matched_ukf(ctx: RunContext) -> Estimate:
    sc = _oracle(ctx, "matched_ukf")
    model = Parametric(ctx.scene, sc.rho_true) if sc.rho_true is not None and truth_is_model_surface(ctx.cfg) \
        else Parametric(ctx.scene, surface=sc.surface.to(device=sc.q_est0.device, dtype=sc.q_est0.dtype))
    return _usque(ctx, model, offset=False)


def _oracle(ctx: RunContext, name: str) -> Problem:
    """The problem of an oracle estimator, which needs the truth's surface (a simulation's)."""
    if ctx.problem.surface is None:
        raise ValueError(f"{name}: an oracle that renders with the true surface; observations without a known "
                         f"surface (a file) cannot run it")
    return ctx.problem


def _joint_ukf(ctx: RunContext) -> Estimate:
    return _usque(ctx, Parametric(ctx.scene, ctx.cfg.model.rho_reference), offset=True)


def run_surface_filter_selected(cfg: Config, scene: Scene, *, q_est0: Tensor, observations: Tensor,
                                increments: Tensor, sigma0: Tensor | None = None,
                                geometry=None) -> tuple[FilterHistory, Tensor]:
    """:func:`~lightcurve_gp.filters.setup.run_surface_filter` with ``cfg``'s filter under each rule of
    :data:`SELECTED_LAM_RULES` (the paper's ``λ`` as the config gives it, and ``λ = 3 − n``) on the same
    observations; per seed the run of higher innovation log-likelihood
    (:func:`lightcurve_gp.filters.selection.select_by_likelihood`) and which rule that was ``(B,)`` (an index into
    :data:`SELECTED_LAM_RULES`). Arguments as :func:`~lightcurve_gp.filters.setup.run_surface_filter`'s."""
    runs = [run_surface_filter(dataclasses.replace(cfg, filter=dataclasses.replace(cfg.filter, lam_rule=rule)), scene,
                               observations=observations, q_est0=q_est0, increments=increments, sigma0=sigma0,
                               geometry=geometry)
            for rule in SELECTED_LAM_RULES]
    return select_by_likelihood(runs)


def _surface_ukf(ctx: RunContext) -> Estimate:
    sc = ctx.problem
    return Estimate.of_filter(run_surface_filter(ctx.cfg, ctx.scene, q_est0=sc.q_est0, observations=sc.observations,
                                                 increments=sc.increments_assumed, sigma0=sc.sigma0,
                                                 geometry=sc.geometry))


def _surface_ukf_select(ctx: RunContext) -> Estimate:
    sc = ctx.problem
    history, _ = run_surface_filter_selected(ctx.cfg, ctx.scene, q_est0=sc.q_est0, observations=sc.observations,
                                             increments=sc.increments_assumed, sigma0=sc.sigma0,
                                             geometry=sc.geometry)
    return Estimate.of_filter(history)


def map_checkpoints(cfg: Config, every_s: float) -> list[int]:
    """The MAP's checkpoints: sample indices every ``every_s`` seconds from the start to the end of
    ``evaluation.rmse_window_s`` (on the ``scenario.dt_s`` grid)."""
    lo, hi = cfg.evaluation.rmse_window_s
    count = int(round((hi - lo) / every_s))
    return [int(round((lo + i * every_s) / cfg.scenario.dt_s)) for i in range(count + 1)]


def map_estimate(cfg: Config, scene: Scene, sc: Problem, *, surface: bool, every_s: float) -> Estimate:
    """The batch MAP reference on every seed of ``sc`` at :func:`map_checkpoints` (the only call of the MAP
    solvers here): attitude and surface unknown (``surface``), or attitude and offset on the reference surface;
    ``R = filter.measurement_noise``, the offset's prior std ``filter.offset_prior_std``."""
    checkpoints = map_checkpoints(cfg, every_s)
    est = map_with_surface(scene, q_est0=sc.q_est0, sigma0=sc.sigma0, observations=sc.observations,
                           increments=sc.increments_assumed, checkpoints=checkpoints,
                           measurement_noise=cfg.filter.measurement_noise, reference=reference_surface(cfg),
                           offset_std=cfg.filter.offset_prior_std, surface=surface)
    return Estimate(est.q_est, est.P, samples=torch.tensor(checkpoints, device=est.q_est.device),
                    offset_final=None if surface else est.x[:, -1, 3])


def map_solution(cfg: Config, scene: Scene, sc: Problem) -> ArcSolution:
    """What ``map`` runs on every seed of ``sc``: the surface-state filter, then the whole-arc MAP of attitude and
    surface state started from its result (:func:`~lightcurve_gp.inference.arc_search.whole_arc_map`, the search of
    ``cfg.map``)."""
    start = run_surface_filter(cfg, scene, q_est0=sc.q_est0, observations=sc.observations,
                               increments=sc.increments_assumed, sigma0=sc.sigma0, geometry=sc.geometry, R=sc.R)
    return whole_arc_map(cfg, scene, sc, start=start, surface_known=False)


def arc_estimate(sc: Problem, solution: ArcSolution) -> Estimate:
    """The :class:`~lightcurve_gp.evaluation.scoring.Estimate` of a whole-arc solution at every sample: ``q̂_k = Δ_k ⊗
    q̂_0`` with covariance ``A(Δ_k) Σ A(Δ_k)ᵀ`` (``Σ`` the reported attitude covariance at ``t_0``)."""
    cum = cumulative_increments(sc.increments_assumed.to(sc.q_est0))
    rot = attitude_matrix(cum)  # A(Δ_k) turns the error at t_0 to sample k
    P = rot @ solution.attitude_covariance.unsqueeze(1) @ rot.mT
    return Estimate(quat_mul(cum, solution.q0.unsqueeze(1)), P)


def _map(ctx: RunContext) -> Estimate:
    return arc_estimate(ctx.problem, map_solution(ctx.cfg, ctx.scene, ctx.problem))


def _matched_map(ctx: RunContext) -> Estimate:
    sc = _oracle(ctx, "matched_map")
    start = _matched_ukf(ctx).history
    return arc_estimate(sc, whole_arc_map(ctx.cfg, ctx.scene, sc, start=start, surface_known=True))


def _no_update(ctx: RunContext) -> Estimate:
    sc = ctx.problem
    q_est = propagate_only(sc.q_est0, sc.increments_assumed.transpose(0, 1))  # (S, T+1, 4)
    P = sc.P0.to(q_est).unsqueeze(1).expand(-1, q_est.shape[1], -1, -1)
    return Estimate(q_est, P, uses_observations=False)


#: every estimator by name, in the order of the tables
ESTIMATORS: dict[str, Estimator] = {e.name: e for e in (
    Estimator("gpukf", _gpukf, needs_model=True),
    Estimator("ukf", _ukf),
    Estimator("matched_ukf", _matched_ukf),
    Estimator("joint_ukf", _joint_ukf),
    Estimator("surface_ukf", _surface_ukf, estimates_omega=False),
    Estimator("surface_ukf_select", _surface_ukf_select, estimates_omega=False),
    Estimator("map_surface", lambda ctx: map_estimate(ctx.cfg, ctx.scene, ctx.problem, surface=True,
                                                      every_s=ctx.map_every_s), estimates_omega=False,
              along_pass=False),
    Estimator("map_offset", lambda ctx: map_estimate(ctx.cfg, ctx.scene, ctx.problem, surface=False,
                                                     every_s=ctx.map_every_s), estimates_omega=False,
              along_pass=False),
    Estimator("map", _map, estimates_omega=False),
    Estimator("matched_map", _matched_map, estimates_omega=False),
    Estimator("no_update", _no_update),
)}
#: what the tables and the estimate command run unless told otherwise
DEFAULT_ESTIMATORS = ("gpukf", "ukf", "matched_ukf", "no_update")
