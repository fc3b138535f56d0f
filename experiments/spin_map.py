"""The batch MAP with ω0 unknown beside the spin filters: what the light curve allows at all over the same window.

For one case of :mod:`experiments.spin_unknown` (a duration, a rate prior σ_ω and a ρ_true) :func:`map_case`
simulates the same noisy light curves (the same noise seeds) and runs :func:`lightcurve_gp.inference.spin.map_with_rate`
with the filters' prior (``filter.p0_deg``, ``filter.p0_omega_deg_s``, ``filter.measurement_noise``,
``filter.offset_prior_std``) and the filters' initial estimates ``q_est,0``, ``ω_est,0``. Its checkpoints are every
``every`` seconds from ``every`` to the end (each solve starts from the previous one); the ones inside the scoring
window are scored: Euler-angle RMSE per axis over them, the body-rate error at each (RMS over them) and at the last.
Observation models: ``renderer`` (the true ρ, like ``matched_ukf``) and ``gp_offset`` (the robust config's GP with
the magnitude offset, like ``gpukf``); ``renderer_from_truth`` is the renderer's MAP solved at the scored checkpoints
only, its first solve started at the true initial state (an oracle: the posterior's mode nearest the truth, to tell
a mode the optimiser cannot reach from the prior from one the data do not single out). Beside the errors: the
Laplace posterior std of ω at the end (what the light curve determines about the rate) and, for the renderer, the
share of seeds whose truth has a lower negative log posterior than the MAP found (the optimiser stopped in a worse
local minimum than the truth).

Each result is stored in ``OUT/<config name>/map/<key>.json`` (the key hashes the case's config, seeds, model and
checkpoints), so a rerun reads it back.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import time
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from experiments._models import trained_model
from lightcurve_gp.attitude.rotations import quat_inv, quat_mul, quat_to_rotvec
from lightcurve_gp.config.load import apply_overrides, config_from_dict, config_to_dict
from lightcurve_gp.evaluation.reporting import format_quantiles, quantiles
from lightcurve_gp.files import write_json_atomic
from lightcurve_gp.inference.attitude import MapPrior
from lightcurve_gp.inference.spin import RateDynamics, map_with_rate, neg_log_posterior, rate_map_errors
from lightcurve_gp.observation.parametric import Parametric
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import Scenario, simulate_scenario

__all__ = ["MAP_MODELS", "MAP_LABELS", "map_case", "map_row", "map_diagnostics_row", "DIAGNOSTICS_HEADER"]

MAP_MODELS = ("renderer", "gp_offset", "renderer_from_truth")
MAP_LABELS = {"renderer": "MAP, renderer with the true ρ", "gp_offset": "MAP, robust GP with the offset",
              "renderer_from_truth": "MAP started at the truth (oracle), renderer with the true ρ"}
DIAGNOSTICS_HEADER = ("σ_ω (°/s)", "MAP model", "seeds", "final ω error (°/s)", "posterior ω std at the end (°/s)",
                      "prior ω std (°/s)", "truth's cost below the MAP's", "s", "load average")


def _key(cfg, seeds: Sequence[int], model: str, checkpoints: Sequence[int]) -> str:
    """The store key of a MAP case. ``filter.omega_process_noise`` is a filter setting the MAP does not use (it has
    no process noise); it is keyed as 0 so that tuning it does not recompute the MAP."""
    cfg = dataclasses.replace(cfg, filter=dataclasses.replace(cfg.filter, omega_process_noise=0.0))
    blob = json.dumps({"config": config_to_dict(cfg), "seeds": list(seeds), "model": model,
                       "checkpoints": list(checkpoints)}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def _truth_state(sc: Scenario) -> torch.Tensor:
    """The true ``[e, δω]`` ``(6,)`` against the filters' initial estimates (the config's truth, shared by the
    seeds)."""
    e = quat_to_rotvec(quat_mul(sc.q_true[0, 0], quat_inv(sc.q_est0[0])))
    return torch.cat([e, sc.omega_true[0, 0] - sc.omega_est0[0]])


def _solve(cfg, sc: Scenario, model, *, offset: bool, checkpoints: list[int], scored: list[int],
           from_truth: bool = False) -> dict:
    """Run the MAP on every seed of ``sc`` and score it (per-seed lists)."""
    prior = MapPrior(cfg.filter.p0_deg, cfg.filter.measurement_noise, cfg.filter.offset_prior_std)
    inertia = cfg.filter.inertia_kg_m2 or cfg.shape.inertia_kg_m2
    q_est0 = sc.q_est0[0]  # the config's truth: every seed starts from the same estimate
    dynamics = RateDynamics(omega_est0=sc.omega_est0[0], p0_omega_deg_s=cfg.filter.p0_omega_deg_s, dt=cfg.scenario.dt_s,
                            inertia=torch.tensor(inertia, dtype=sc.observations.dtype))
    x_start = _truth_state(sc).expand(sc.observations.shape[0], 6) if from_truth else None
    est = map_with_rate(model, q_est0=q_est0, dynamics=dynamics, observations=sc.observations, prior=prior,
                        checkpoints=checkpoints, offset=offset, x_start=x_start)
    in_window = {t: est[t] for t in scored}
    att, rate = rate_map_errors(in_window, q_true=sc.q_true[0], omega_true=sc.omega_true[0], q_est0=q_est0,
                                dynamics=dynamics)
    last = est[checkpoints[-1]]
    omega_std = torch.rad2deg(last.covariance.diagonal(dim1=-2, dim2=-1)[:, 3:6].sum(-1).sqrt())  # of |δω|
    out = {"rmse_deg": att.pow(2).mean(1).sqrt().tolist(), "omega_rmse_deg_s": rate.pow(2).mean(1).sqrt().tolist(),
           "omega_error_final_deg_s": rate[:, -1].tolist(), "omega_posterior_std_final_deg_s": omega_std.tolist()}
    if not offset:
        truth = _truth_state(sc).expand_as(last.x)
        costs = [neg_log_posterior(model, x, q_est0=q_est0, dynamics=dynamics, observations=sc.observations,
                                   prior=prior, t=checkpoints[-1]) for x in (last.x, truth)]
        out["truth_cost_below_map"] = (costs[1] < costs[0]).tolist()
    return out


def map_case(raw_case: dict, *, seeds: Sequence[int], rho_true: float, model: str, every: float,
             out: Path) -> dict:
    """The MAP of observation model ``model`` on one case (read back from the store when it ran before).

    Args:
        raw_case: the case's config as a plain mapping (its duration, rate prior and initial rate error set).
        seeds: noise seeds (as the filters').
        rho_true: the truth's ρ.
        model: one of :data:`MAP_MODELS`.
        every: checkpoint spacing (s).
        out: root of the store (``runs``).

    Returns:
        Per-seed ``rmse_deg`` (S × 3), ``omega_rmse_deg_s``, ``omega_error_final_deg_s``,
        ``omega_posterior_std_final_deg_s`` and (renderer) ``truth_cost_below_map``; ``checkpoints_s``,
        ``scored_s``, ``seconds`` and ``load_average`` (start, end).
    """
    if model not in MAP_MODELS:
        raise ValueError(f"--map-models: {model!r} is not one of {', '.join(MAP_MODELS)}")
    cfg = config_from_dict(apply_overrides(raw_case, [f"scenario.rho_true={rho_true:g}"]))
    dt, (lo, hi) = cfg.scenario.dt_s, cfg.evaluation.rmse_window_s
    times = torch.arange(every, cfg.scenario.duration_s + 1e-9, every, dtype=torch.float64).tolist()
    if model == "renderer_from_truth":
        times = [t for t in times if t >= lo - 1e-9]
    checkpoints = [int(round(t / dt)) for t in times]
    path = out / cfg.name / "map" / f"{_key(cfg, seeds, model, checkpoints)}.json"
    if path.exists():
        return json.loads(path.read_text())
    start, load = time.perf_counter(), os.getloadavg()[0]
    scene = Scene.from_config(cfg)
    sc = simulate_scenario(cfg, seeds=seeds, rho_true=rho_true, scene=scene)
    observation = trained_model(cfg, out) if model == "gp_offset" else Parametric(scene, rho_true)
    scored = [k for k, t in zip(checkpoints, times) if lo - 1e-9 <= t <= hi + 1e-9]
    result = _solve(cfg, sc, observation, offset=model == "gp_offset", checkpoints=checkpoints, scored=scored,
                    from_truth=model == "renderer_from_truth")
    result.update({"model": model, "seeds": list(seeds), "rho_true": rho_true, "checkpoints_s": times,
                   "scored_s": [k * dt for k in scored], "seconds": time.perf_counter() - start,
                   "load_average": [load, os.getloadavg()[0]]})
    write_json_atomic(result, path)
    return result


def map_row(label: str, result: dict) -> list[str]:
    """Cells of :data:`experiments.spin_unknown.HEADER` for a MAP result (no NEES, no per-step time)."""
    rmse = np.asarray(result["rmse_deg"])
    below = 100 * float((rmse < 10).all(-1).mean())
    return [label, *(format_quantiles(quantiles(rmse[:, i])) for i in range(3)), f"{below:.0f} %", "–", "–", "–",
            format_quantiles(quantiles(result["omega_rmse_deg_s"]), 4),
            format_quantiles(quantiles(result["omega_error_final_deg_s"]), 4), "–"]


def map_diagnostics_row(sigma: float, result: dict) -> list[str]:
    """Cells of :data:`DIAGNOSTICS_HEADER`: what the MAP found against what the light curve determines."""
    below = result.get("truth_cost_below_map")
    share = "–" if below is None else f"{100 * float(np.mean(below)):.0f} %"
    prior = math.sqrt(3) * sigma
    lo, hi = result["load_average"]
    return [f"{sigma:g}", result["model"], str(len(result["seeds"])),
            format_quantiles(quantiles(result["omega_error_final_deg_s"]), 4),
            format_quantiles(quantiles(result["omega_posterior_std_final_deg_s"]), 4), f"{prior:.4f}", share,
            f"{result['seconds']:.0f}", f"{lo:.1f}–{hi:.1f}"]
