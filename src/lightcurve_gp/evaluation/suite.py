"""Estimators of the generalisation suite on random truths (:mod:`lightcurve_gp.simulation.truths`), all seeds batched.

Every filter uses the tuning of the config's ``filter`` section and starts from the seed's ``q_est,0`` with
``P0 = σ0² I`` (the seed's own, matched to its initial error); the offset filters add ``b`` with prior
``N(ỹ_0 − h(q̂_0), filter.offset_prior_std²)``. Estimators (names used in tables):

* ``robust_gpukf`` — the config's GP of the ρ-normalised reference curve with the offset state: surface unknown,
  shape known;
* ``matched_ukf`` — the renderer with the seed's true surface (knows everything);
* ``joint_ukf`` — the renderer at the reference surface (``model.rho_reference`` and the config's F0, n_u, n_v,
  the GP's training surface) with the offset state: it does not know F0, n_u, n_v;
* ``surface_ukf`` — the renderer with the surface as states (:mod:`~.surface_state`: log ρ, logit F0, log n_u,
  log n_v beside the attitude, the MAP's prior): surface unknown, shape known, the ideal emulator of a GP whose
  inputs include the surface;
* ``surface_ukf_select`` — the surface-state filter run with the paper's ``λ = 0`` and with Julier's
  ``λ = 3 − n``, each seed's run of higher innovation likelihood kept
  (:func:`~.estimation.run_surface_filter_selected`);
* ``map_surface`` — the batch MAP reference with attitude, ρ, F0, n_u, n_v unknown (:mod:`~.inference.surface`);
* ``map_offset`` — the batch MAP with attitude and offset on the reference surface (the joint UKF's model);
* ``no_update`` — the initial estimate propagated with the known ω (its covariance stays ``P0``).

Metrics per seed: RMSE of each Euler angle over the scoring window (filters: every sample of
``evaluation.rmse_window_s``; MAP: its checkpoints in that window), the time-averaged NEES of the GRP error against
the attitude covariance, and the whitened errors ``L⁻¹ e`` (``L Lᵀ = P``) at the first and last scored sample,
whose correlation tells how many independent samples the time average holds (see :func:`nees_band`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Sequence

import torch
from torch import Tensor

from lightcurve_gp.attitude.metrics import attitude_error_vector, attitude_errors_deg, chi2_band, nees
from lightcurve_gp.attitude.rotations import quat_mul
from lightcurve_gp.config.load import Config
from lightcurve_gp.evaluation.estimators import run_surface_filter, run_surface_filter_selected
from lightcurve_gp.filters.offset import initial_offset
from lightcurve_gp.filters.usque import UsqueParams, run_usque
from lightcurve_gp.inference.surface import cumulative_increments, map_with_surface
from lightcurve_gp.observation.parametric import Parametric
from lightcurve_gp.observation.surface_state import reference_surface
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.truths import TruthBatch

__all__ = ["SUITE_ESTIMATORS", "Scored", "nees_band", "score", "run_suite"]

SUITE_ESTIMATORS = ("robust_gpukf", "matched_ukf", "joint_ukf", "surface_ukf", "surface_ukf_select", "map_surface",
                    "map_offset", "no_update")


def nees_band(independent_samples: int = 1, confidence: float = 0.95) -> tuple[float, float]:
    """The single-run band of a time-averaged NEES that holds ``independent_samples`` independent χ²(3) draws.

    A filter's attitude error is strongly autocorrelated: with ω known and no process noise it is one random vector
    turned by the known motion and corrected a little by each sample. On the suite's held-out seeds the whitened
    errors at the two ends of the 200 s window still correlate 0.26-0.52 (Spearman, pooled; neighbouring samples far
    more), so the average of the ~200 NEES samples holds one to two independent draws, not 200. The default is the
    band of one draw, ``[0.22, 9.35]`` (two: ``[0.62, 7.22]``); the band of 200 independent draws, ``[2.67, 3.35]``,
    would reject a consistent filter in most runs. Check: the no-update baseline, whose ``P0`` matches its initial
    error by construction, has 94 % of its held-out seeds inside the one-draw band.
    """
    return chi2_band(3, independent_samples, confidence)


@dataclass
class Scored:
    """One estimator on ``S`` seeds.

    Attributes:
        rmse_deg: RMSE of yaw, pitch, roll over the scored samples ``(S, 3)`` (deg).
        nees_mean: time-averaged NEES ``(S,)``.
        white_first, white_last: whitened errors at the first and last scored sample ``(S, 3)``.
        offset_final: the final offset estimate ``(S,)`` (mag) of offset filters, else ``None``.
        seconds: wall time of the batched run (s).
    """

    rmse_deg: Tensor
    nees_mean: Tensor
    white_first: Tensor
    white_last: Tensor
    offset_final: Tensor | None
    seconds: float


def score(q_true: Tensor, q_est: Tensor, P: Tensor, seconds: float, offset_final: Tensor | None = None,
          *, grp_a: float = 1.0, grp_f: float = 4.0) -> Scored:
    """Metrics of estimates ``q_est (S, K, 4)`` with covariances ``P (S, K, 3, 3)`` against ``q_true (S, K, 4)``."""
    errors = attitude_errors_deg(q_true, q_est)
    rmse = errors.pow(2).mean(1).sqrt()
    e = attitude_error_vector(q_true, q_est, kind="grp", a=grp_a, f=grp_f)
    white = torch.linalg.solve_triangular(torch.linalg.cholesky(P[:, [0, -1]]), e[:, [0, -1]].unsqueeze(-1),
                                          upper=False).squeeze(-1)
    return Scored(rmse, nees(e, P).mean(1), white[:, 0], white[:, 1], offset_final, seconds)


def _window(cfg: Config, times: Tensor) -> Tensor:
    lo, hi = cfg.evaluation.rmse_window_s
    return ((times >= lo) & (times <= hi)).nonzero().squeeze(-1)


def _offset_covariance(sigma0: Tensor, offset_std: float) -> Tensor:
    """``P0 = diag(σ0² I₃, offset_std²)`` ``(S, 4, 4)`` for the state ``[δp, b]``."""
    P0 = torch.zeros(sigma0.shape[0], 4, 4, dtype=sigma0.dtype)
    P0[:, :3, :3] = sigma0.pow(2).view(-1, 1, 1) * torch.eye(3, dtype=sigma0.dtype)
    P0[:, 3, 3] = offset_std ** 2
    return P0


def _run_filter(name: str, cfg: Config, truths: TruthBatch, scene: Scene,
                gp_model) -> tuple[Tensor, Tensor, Tensor | None]:
    """History ``(q_est (S, T+1, 4), P (S, T+1, 3, 3), final offset or None)`` of one filter."""
    obs, q_est0 = truths.observations, truths.draw.q_est0
    run = dict(q_est0=q_est0, observations=obs, m_past0=obs[:, 0], increments=truths.increments,
               params=UsqueParams.from_config(cfg))
    if name == "matched_ukf":
        h = run_usque(model=Parametric(scene, surface=truths.draw.surface), P0=truths.P0, **run)
        return h.q_est, h.P, None
    if name == "surface_ukf":
        h = run_surface_filter(cfg, scene, observations=obs, q_est0=q_est0, increments=truths.increments,
                               P0_attitude=truths.P0)
        return h.q_est, h.P, None
    if name == "surface_ukf_select":
        h, _ = run_surface_filter_selected(cfg, scene, observations=obs, q_est0=q_est0, increments=truths.increments,
                                           P0_attitude=truths.P0)
        return h.q_est, h.P, None
    model = gp_model if name == "robust_gpukf" else Parametric(scene, cfg.model.rho_reference)
    P0 = _offset_covariance(truths.draw.sigma0, cfg.filter.offset_prior_std)
    run["params"] = UsqueParams.from_config(cfg, model=model)
    h = run_usque(model=model, P0=P0, offset0=initial_offset(model, q_est0, obs[:, 0], obs[:, 0]), **run)
    return h.q_est, h.P, h.offset[:, -1]


def _run_map(name: str, cfg: Config, truths: TruthBatch, scene: Scene, every_s: float) -> Scored:
    lo, hi = cfg.evaluation.rmse_window_s
    dt = cfg.scenario.dt_s
    count = int(round((hi - lo) / every_s))
    checkpoints = [int(round((lo + i * every_s) / dt)) for i in range(count + 1)]
    reference = reference_surface(cfg)
    start = time.perf_counter()
    est = map_with_surface(scene, q_est0=truths.draw.q_est0, sigma0=truths.draw.sigma0,
                           observations=truths.observations, increments=truths.increments, checkpoints=checkpoints,
                           measurement_noise=cfg.filter.measurement_noise, reference=reference,
                           offset_std=cfg.filter.offset_prior_std, surface=name == "map_surface")
    seconds = time.perf_counter() - start
    offset = None if name == "map_surface" else est.x[:, -1, 3]
    return score(truths.q_true[:, checkpoints], est.q_est, est.P, seconds, offset, grp_a=cfg.filter.grp_a,
                 grp_f=cfg.filter.grp_f)


def run_suite(cfg: Config, truths: TruthBatch, *, gp_model=None, estimators: Sequence[str] = SUITE_ESTIMATORS,
              map_every_s: float = 50.0, scene: Scene | None = None) -> dict[str, Scored]:
    """Run the chosen estimators on every truth of the batch (float64, CPU).

    Args:
        cfg: the robust config (filter tuning, reference surface, scoring window).
        truths: from :func:`lightcurve_gp.simulation.truths.simulate_truths`.
        gp_model: the trained GP of ``cfg`` (needed by ``robust_gpukf``).
        estimators: any of :data:`SUITE_ESTIMATORS`.
        map_every_s: checkpoint spacing of the MAP estimators inside the window (s).
        scene: the renderer of ``cfg`` (its surface is the reference surface).
    """
    unknown = [e for e in estimators if e not in SUITE_ESTIMATORS]
    if unknown:
        raise ValueError(f"unknown estimator {unknown[0]!r}; choose from {', '.join(SUITE_ESTIMATORS)}")
    if "robust_gpukf" in estimators and gp_model is None:
        raise ValueError("the robust_gpukf estimator needs the trained GP of the config")
    scene = (scene or Scene.from_config(cfg)).to(dtype=torch.float64)
    window = _window(cfg, truths.times)
    out = {}
    for name in estimators:
        if name.startswith("map_"):
            out[name] = _run_map(name, cfg, truths, scene, map_every_s)
            continue
        start = time.perf_counter()
        if name == "no_update":
            cum = cumulative_increments(truths.increments)
            q_est, P, offset = quat_mul(cum, truths.draw.q_est0.unsqueeze(1)), truths.P0.unsqueeze(1), None
            P = P.expand(-1, truths.times.shape[0], -1, -1)
        else:
            q_est, P, offset = _run_filter(name, cfg, truths, scene, gp_model)
        out[name] = score(truths.q_true[:, window], q_est[:, window], P[:, window], time.perf_counter() - start,
                          offset, grp_a=cfg.filter.grp_a, grp_f=cfg.filter.grp_f)
    return out
