"""Spin unknown: the body rate estimated with the attitude (state [δp, ω, b]) against the filters that know it.

On the paper's trajectory (configs/boxwing_robust.yaml, |ω| = 0.29 °/s) the filters start with the rate off by
``σ_ω (1, −1, 1)`` °/s — a one-sigma error on each axis of the prior std ``σ_ω`` — for every ``σ_ω`` of
``--sigmas``, every ``ρ_true`` of ``--rhos`` and every duration of ``--durations`` (``--long-sigmas`` limits the
prior stds run at durations above 600 s). Estimators:

* ``gpukf`` — the robust GPUKF (attitude-only GP, magnitude offset in the state) with ω in the state;
* ``matched_ukf`` — the renderer with the true ρ, ω in the state;
* the same two with ω known exactly (``… ω known`` rows: the references of the goal);
* ``no_update`` — the initial estimate propagated with the wrong initial rate.

Once, at σ_ω = 0.03 °/s, 600 s and the first ρ_true, the matched-ρ UKF with ω is run again with a filter inertia
10 % off the truth's on each axis (``INERTIA_ERRORS``, ±10 % in alternating signs: a common scale would not change
the torque-free ω(t)).

With ``--map``, the batch MAP with ω0 unknown (:func:`map_case`) is added at each of ``--map-durations`` (default
600 s) for every σ_ω of that duration and every ρ_true — what the light curve allows at all — on ``--map-seeds`` of
the same noise seeds. It simulates the same noisy light curves and runs
:func:`lightcurve_gp.inference.spin.map_with_rate` with the filters' prior (``filter.p0_deg``,
``filter.p0_omega_deg_s``, ``filter.measurement_noise``, ``filter.offset_prior_std``) and initial estimates; its
checkpoints are every ``--map-every`` seconds to the end (each solve starts from the previous one), those inside the
scoring window scored: Euler-angle RMSE per axis, the body-rate error at each (RMS) and at the last. Observation
models: ``renderer`` (the true ρ, like ``matched_ukf``), ``gp_offset`` (the robust GP with the offset, like
``gpukf``) and ``renderer_from_truth``, the renderer's MAP solved at the scored checkpoints only, its first solve
started at the true initial state (an oracle: the posterior's mode nearest the truth, to tell a mode the optimiser
cannot reach from the prior from one the data do not single out). Beside the errors: the Laplace posterior std of ω
at the end and, for the renderer, the share of seeds whose truth has a lower negative log posterior than the MAP
found (the optimiser stopped in a worse local minimum than the truth).

Nothing is tuned here: every filter setting is the robust config's (its attitude process noise chosen on seeds
100-199, its rate process noise ``filter.omega_process_noise`` on seeds 100-149 by :mod:`experiments.spin_tuning`);
the noise seeds start at ``--seed-start`` (200). Resumable: every filter case runs through the sweep machinery (on
the local pool or dask), every MAP case through the case store (``OUT/spin_unknown/map/cases/``,
:func:`lightcurve_gp.sweep.store.resume_case`); a rerun reuses finished cases. Writes ``--results``
(experiments/results/spin): ``tables.md``, ``summary.json``, one box plot per duration and ρ_true and the seed-0
error traces with their ±3σ bands of σ_ω = 0.03 °/s, 600 s.

    python -m experiments.spin_unknown --workers 2
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import math
import os
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from experiments.common import (
    ROBUST_CONFIG,
    ROOT,
    SPIN_HEADER,
    case_overrides,
    floats,
    goal_check,
    seed_block,
    spin_table_row,
    sweep_arguments,
    trained_model,
    write_outputs,
)
from lightcurve_gp.attitude.rotations import quat_inv, quat_mul, quat_to_rotvec
from lightcurve_gp.commands.common import apply_threads
from lightcurve_gp.config.load import apply_overrides, config_from_dict, config_hash, load_raw_config
from lightcurve_gp.evaluation.plots import error_bands, rmse_boxplot
from lightcurve_gp.evaluation.reporting import CaseRecord, format_quantiles, markdown_table, quantiles
from lightcurve_gp.inference.attitude import MapPrior
from lightcurve_gp.inference.spin import RateDynamics, map_with_rate, neg_log_posterior, rate_map_errors
from lightcurve_gp.observation.parametric import Parametric
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import Scenario, simulate_scenario
from lightcurve_gp.sweep.executors import make_executor
from lightcurve_gp.sweep.runner import run_sweep
from lightcurve_gp.sweep.store import resume_case

ESTIMATORS_UNKNOWN = ("gpukf", "matched_ukf", "no_update")
ESTIMATORS_KNOWN = ("gpukf", "matched_ukf")
INERTIA_ERRORS = ((1.1, 0.9, 1.1), (0.9, 1.1, 0.9))
#: the goal at σ_ω = GOAL_SIGMA °/s for the robust GPUKF with ω: its median RMSE per axis at most 1.5 × the one with
#: ω known, at least 80 % of seeds below 10° on all axes, the full state's NEES in its band, the median final ω error
#: at most 0.005 °/s
GOAL_SIGMA = 0.03
GOALS = {"ratio": ("<=", 1.5), "fraction": (">=", 0.8), "final_omega": ("<=", 0.005)}

MAP_MODELS = ("renderer", "gp_offset", "renderer_from_truth")
MAP_LABELS = {"renderer": "MAP, renderer with the true ρ", "gp_offset": "MAP, robust GP with the offset",
              "renderer_from_truth": "MAP started at the truth (oracle), renderer with the true ρ"}
DIAGNOSTICS_HEADER = ("σ_ω (°/s)", "MAP model", "seeds", "final ω error (°/s)", "posterior ω std at the end (°/s)",
                      "prior ω std (°/s)", "truth's cost below the MAP's", "s", "load average")


def _map_models(text: str) -> list[str]:
    models = [m for m in text.split(",") if m.strip()]
    unknown = [m for m in models if m not in MAP_MODELS]
    if not models or unknown:
        raise argparse.ArgumentTypeError(f"{text!r}: each must be one of {', '.join(MAP_MODELS)}")
    return models


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m experiments.spin_unknown", description=__doc__.split("\n\n")[0])
    p.add_argument("--config", type=Path, default=ROBUST_CONFIG)
    p.add_argument("--seeds", type=int, default=100, help="noise seeds per case (default 100)")
    p.add_argument("--seed-start", type=int, default=200, help="first noise seed (default 200)")
    p.add_argument("--sigmas", type=floats, default=[0.01, 0.03, 0.1], help="prior rate stds, deg/s")
    p.add_argument("--long-sigmas", type=floats, default=[0.03], help="the prior stds run beyond 600 s")
    p.add_argument("--rhos", type=floats, default=[0.3, 0.7])
    p.add_argument("--durations", type=floats, default=[600.0, 1800.0], help="seconds; window: the last 200 s")
    p.add_argument("--out", type=Path, default=ROOT / "runs", help="root of models and cases")
    p.add_argument("--results", type=Path, default=ROOT / "experiments/results/spin")
    sweep_arguments(p)
    p.add_argument("--no-inertia", action="store_true", help="skip the inertia-error cases")
    p.add_argument("--no-gp", action="store_true", help="leave the robust GPUKF out (the renderer-based filters only)")
    p.add_argument("--map", action="store_true", help="add the batch MAP with ω0 unknown (map_case) at "
                   "every --map-durations for every σ_ω and ρ_true")
    p.add_argument("--map-durations", type=floats, default=[600.0],
                   help="durations of the MAP cases, s (default 600; each must be one of --durations)")
    p.add_argument("--map-models", type=_map_models, default=["renderer"],
                   help=f"comma-separated, of {', '.join(MAP_MODELS)} (default renderer)")
    p.add_argument("--map-every", type=float, default=50.0, help="MAP checkpoint spacing (s); scored in the window")
    p.add_argument("--map-seeds", type=int, default=None, help="noise seeds of the MAP (default: --seeds)")
    return p


# ----------------------------------------------------------------------------------------------- filters

def run_all(raw: dict, args) -> tuple[dict[tuple[float, float | None], dict[float, CaseRecord]], dict]:
    """Every sweep on one executor: ``{(duration, σ_ω or None): {ρ_true: record}}`` and the inertia-error records
    ``{error factors: record}``."""
    seeds = seed_block(args)
    columns = [(d, s) for d in args.durations for s in [None, *(args.sigmas if d <= 600 else args.long_sigmas)]]
    gp = () if args.no_gp else ("gpukf",)
    out = {}
    with make_executor(args.executor, workers=args.workers, address=args.scheduler) as ex:
        for duration, sigma in columns:
            sweep_id = f"spin_{duration:g}s_" + ("known" if sigma is None else f"sigma{sigma:g}")
            print(f"== {sweep_id}: rho_true in {args.rhos}, {args.seeds} seeds", file=sys.stderr, flush=True)
            res = run_sweep(apply_overrides(raw, case_overrides(duration, sigma)), [("scenario.rho_true", args.rhos)],
                            seeds, out=args.out, sweep_id=sweep_id, workers=args.workers, threads=args.threads,
                            estimators=[e for e in (ESTIMATORS_KNOWN if sigma is None else ESTIMATORS_UNKNOWN)
                                        if e != "gpukf" or gp],
                            progress=not args.no_progress, executor=ex)
            for cid in res.failed:
                print(f"   case {cid} failed: {res.records[cid].error}", file=sys.stderr)
            out[(duration, sigma)] = {rho: res.record(**{"scenario.rho_true": rho}) for rho in args.rhos}
        inertia = {} if args.no_inertia else inertia_error(raw, args, ex, seeds)
    return out, inertia


def inertia_error(raw: dict, args, executor, seeds) -> dict[tuple, CaseRecord]:
    """The matched-ρ UKF with ω at σ_ω = 0.03 °/s, 600 s, ρ_true = ``args.rhos[0]``, assuming a wrong inertia."""
    J = raw["shape"]["inertia_kg_m2"]
    values = [[round(j * e, 6) for j, e in zip(J, err)] for err in INERTIA_ERRORS]
    res = run_sweep(apply_overrides(raw, [*case_overrides(600.0, GOAL_SIGMA), f"scenario.rho_true={args.rhos[0]}"]),
                    [("filter.inertia_kg_m2", values)], seeds, out=args.out, sweep_id="spin_600s_inertia",
                    workers=args.workers, threads=args.threads, estimators=["matched_ukf"],
                    progress=not args.no_progress, executor=executor)
    return {err: res.record(**{"filter.inertia_kg_m2": v}) for err, v in zip(INERTIA_ERRORS, values)}


# ----------------------------------------------------------------------------------------------- batch MAP

def map_key(cfg, seeds: Sequence[int], model: str, checkpoints: Sequence[int]) -> str:
    """The case-store key of a MAP case: its whole config, seeds, model and checkpoints. ``filter.omega_process_noise``
    is a filter setting the MAP does not use (it has no process noise); it is keyed as 0 so that tuning it does not
    recompute the MAP."""
    cfg = dataclasses.replace(cfg, filter=dataclasses.replace(cfg.filter, omega_process_noise=0.0))
    return config_hash(cfg, extra={"experiment": "spin_unknown_map", "seeds": list(seeds), "model": model,
                                   "checkpoints": list(checkpoints)})


def _truth_state(sc: Scenario) -> torch.Tensor:
    """The true ``[e, δω]`` ``(6,)`` against the filters' initial estimates (the config's truth, shared by the
    seeds)."""
    e = quat_to_rotvec(quat_mul(sc.q_true[0, 0], quat_inv(sc.q_est0[0])))
    return torch.cat([e, sc.omega_true[0, 0] - sc.omega_est0[0]])


def solve_map(cfg, sc: Scenario, model, *, offset: bool, checkpoints: list[int], scored: list[int],
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
    """The MAP of observation model ``model`` on one case (read back from the case store of ``out/<config
    name>/map`` when it ran before).

    Args:
        raw_case: the case's config as a plain mapping (its duration, rate prior and initial rate error set).
        seeds: noise seeds (as the filters').
        rho_true: the truth's ρ.
        model: one of :data:`MAP_MODELS`.
        every: checkpoint spacing (s).
        out: root of the models and the case store (``runs``).

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
    scored = [k for k, t in zip(checkpoints, times) if lo - 1e-9 <= t <= hi + 1e-9]
    compute = functools.partial(_map_result, cfg, seeds=seeds, rho_true=rho_true, model=model, times=times,
                                checkpoints=checkpoints, scored=scored, out=out)
    record, _ = resume_case(out / cfg.name / "map", map_key(cfg, seeds, model, checkpoints), compute,
                            values={"experiment": "spin_unknown_map", "model": model, "rho_true": rho_true},
                            seeds=seeds, estimators=[f"map_{model}"])
    return record.summary


def _map_result(cfg, *, seeds: Sequence[int], rho_true: float, model: str, times: list[float], checkpoints: list[int],
                scored: list[int], out: Path) -> tuple[dict, list]:
    """One MAP case for the store: its result (:func:`map_case`) as the summary, no per-seed metric rows."""
    start, load = time.perf_counter(), os.getloadavg()[0]
    scene = Scene.from_config(cfg)
    sc = simulate_scenario(cfg, seeds=seeds, rho_true=rho_true, scene=scene)
    observation = trained_model(cfg, out) if model == "gp_offset" else Parametric(scene, rho_true)
    result = solve_map(cfg, sc, observation, offset=model == "gp_offset", checkpoints=checkpoints, scored=scored,
                       from_truth=model == "renderer_from_truth")
    result.update({"model": model, "seeds": list(seeds), "rho_true": rho_true, "checkpoints_s": times,
                   "scored_s": [k * cfg.scenario.dt_s for k in scored], "seconds": time.perf_counter() - start,
                   "load_average": [load, os.getloadavg()[0]]})
    return result, []


def map_results(raw: dict, args) -> dict[tuple[float, float, str], dict[float, dict]]:
    """The batch MAP with ω0 unknown of every MAP model at every MAP duration: ``{(duration, σ_ω, model): {ρ_true:
    result}}`` (beyond 600 s the σ_ω of ``--long-sigmas``, as the filters)."""
    seeds = range(args.seed_start, args.seed_start + (args.map_seeds or args.seeds))
    out = {}
    for duration in args.map_durations:
        for sigma in args.sigmas if duration <= 600 else args.long_sigmas:
            for model in args.map_models:
                print(f"== MAP {model}, {duration:g} s, sigma {sigma:g}: {len(seeds)} seeds", file=sys.stderr,
                      flush=True)
                out[(duration, sigma, model)] = {
                    rho: map_case(apply_overrides(raw, case_overrides(duration, sigma)), seeds=seeds, rho_true=rho,
                                  model=model, every=args.map_every, out=args.out) for rho in args.rhos}
    return out


# ----------------------------------------------------------------------------------------------- tables

def tables(records: dict, inertia: dict, maps: dict, args) -> tuple[list[str], dict]:
    """One Markdown table per (duration, ρ_true) with the MAP rows of its duration, the inertia-error table, the MAP
    diagnostics and the goal check at σ_ω = 0.03 °/s."""
    lines, goals = [], {}
    base = records.get((600.0, GOAL_SIGMA), {}).get(args.rhos[0])
    if base is not None and inertia:
        rows = [spin_table_row("matched_ukf, inertia exact", base, "matched_ukf")]
        rows += [spin_table_row(f"matched_ukf, inertia × ({', '.join(f'{e:g}' for e in err)})", rec, "matched_ukf")
                 for err, rec in inertia.items()]
        lines += [f"\n#### Inertia error: 600 s, σ_ω = {GOAL_SIGMA:g} °/s, ρ_true = {args.rhos[0]:g} "
                  f"({args.seeds} seeds from {args.seed_start})\n", markdown_table(SPIN_HEADER, rows).rstrip("\n")]
    for duration in args.durations:
        for rho in args.rhos:
            known = records[(duration, None)][rho]
            rows = [spin_table_row(f"{n}, ω known", known, n) for n in ESTIMATORS_KNOWN if n in known.estimators]
            for (d, sigma), by_rho in records.items():
                if d == duration and sigma is not None:
                    rows += [spin_table_row(f"{n}, σ_ω = {sigma:g}", by_rho[rho], n) for n in ESTIMATORS_UNKNOWN
                             if n in by_rho[rho].estimators]
                    rows += [map_row(f"{MAP_LABELS[m]}, σ_ω = {sigma:g} ({len(r[rho]['seeds'])} seeds)", r[rho])
                             for (d_map, s, m), r in maps.items() if s == sigma and d_map == duration]
                    if sigma == GOAL_SIGMA and "gpukf" in by_rho[rho].estimators:
                        goals[f"{duration:g}s_rho{rho:g}"] = goal(by_rho[rho], known)
            lines += [f"\n#### {duration:g} s, ρ_true = {rho:g} ({args.seeds} seeds from {args.seed_start}; RMSE "
                      f"over the last 200 s, median [q25, q75])\n", markdown_table(SPIN_HEADER, rows).rstrip("\n")]
    for rho in args.rhos if maps else ():
        for duration in args.map_durations:
            rows = [map_diagnostics_row(sigma, r[rho]) for (d, sigma, _), r in maps.items() if d == duration]
            lines += [f"\n#### Batch MAP with ω0 unknown: {duration:g} s, ρ_true = {rho:g}, what it found against "
                      "what the light curve determines\n", markdown_table(DIAGNOSTICS_HEADER, rows).rstrip("\n")]
    return lines, goals


def goal(unknown: CaseRecord, known: CaseRecord) -> dict:
    """The goal check (:data:`GOALS`) of the robust GPUKF at σ_ω = :data:`GOAL_SIGMA`: the measured values and one
    flag per criterion."""
    e = unknown.summary["estimators"]["gpukf"]
    measured = {"ratio": [a / b for a, b in zip(e["rmse_deg_median"],
                                                known.summary["estimators"]["gpukf"]["rmse_deg_median"])],
                "fraction": e["fraction_all_axes_below_10deg"], "nees": e["nees_full_mean"],
                "final_omega": quantiles(unknown.metric("gpukf", "omega_error_final_deg_s")).median}
    check = goal_check(measured, {**GOALS, "nees": ("in", tuple(e["nees_full_band_95"]))})
    return {"ratio_to_omega_known": measured["ratio"], "fraction": measured["fraction"], "nees_full": measured["nees"],
            "final_omega_error_median_deg_s": measured["final_omega"], **check.flags}


def map_row(label: str, result: dict) -> list[str]:
    """Cells of :data:`experiments.common.SPIN_HEADER` for a MAP result (no NEES, no per-step time)."""
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


def figures(records: dict, args) -> list[str]:
    names = []
    for duration in args.durations:
        for rho in args.rhos:
            known = records[(duration, None)][rho]
            boxes = {f"{n} known": known.rmse_deg(n) for n in ESTIMATORS_KNOWN if n in known.estimators}
            for (d, sigma), by_rho in records.items():
                if d == duration and sigma is not None:
                    boxes.update({f"{n} {sigma:g}": by_rho[rho].rmse_deg(n) for n in ("gpukf", "matched_ukf")
                                  if n in by_rho[rho].estimators})
            name = f"rmse_boxplot_{duration:g}s_rho{rho:g}.png"
            rmse_boxplot(boxes, args.results / name, title=f"{duration:g} s, rho_true = {rho:g}, {args.seeds} seeds")
            names.append(name)
    trace = records.get((600.0, GOAL_SIGMA))
    if trace:
        rho = args.rhos[0]
        name = f"errors_seed{trace[rho].traces['seed']}_600s_sigma{GOAL_SIGMA:g}_rho{rho:g}.png"
        error_bands(trace[rho].traces, [n for n in ("gpukf", "matched_ukf") if n in trace[rho].estimators],
                    args.results / name)
        names.append(name)
    return names


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.map and min(args.sigmas) <= 0:
        parser.error(f"--sigmas: {min(args.sigmas):g} must be > 0 with --map (the MAP's rate prior std)")
    if args.map and not set(args.map_durations) <= set(args.durations):
        parser.error(f"--map-durations: {args.map_durations} must be among --durations {args.durations}")
    apply_threads(args.threads)
    start = time.perf_counter()
    raw = apply_overrides(load_raw_config(args.config), ["name=spin_unknown"])
    records, inertia = run_all(raw, args)
    maps = map_results(raw, args) if args.map else {}
    lines, goals = tables(records, inertia, maps, args)
    names = figures(records, args)
    seconds = time.perf_counter() - start
    summary = {"goals_sigma_0.03": goals, "seconds": seconds, "figures": names, "argv": sys.argv[1:],
               "summaries": {f"{d:g}s_{'known' if s is None else f'sigma{s:g}'}_rho{rho:g}": r.summary
                             for (d, s), by_rho in records.items() for rho, r in by_rho.items()},
               "inertia_error": {str(err): r.summary for err, r in inertia.items()},
               "map": {f"{d:g}s_sigma{s:g}_{m}_rho{rho:g}": r for (d, s, m), by_rho in maps.items()
                       for rho, r in by_rho.items()}}
    write_outputs(args.results, {"tables.md": "\n".join(lines) + "\n", "summary.json": summary})
    print("\n".join(lines))
    print(f"\ngoals at sigma_omega = 0.03 deg/s: {goals}\n{seconds:.0f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
