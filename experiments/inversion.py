"""Global inversion against the truth: how often the top family is right, whether its weight says so, how long it takes.

Per seed ``s`` and noise level σ: the box-wing of ``--config`` (fixed geometry; ``--config configs/geo_pass.yaml``
for the GEO pass, cut to ``--duration-s``), a random truth drawn from the seed alone — attitude uniform on SO(3),
body rate of log-uniform (``--rate-law uniform``: uniform) magnitude in 0.05–5 °/s about a uniform axis,
ρ ~ U[0.1, 0.9] (unknown to the inversion) — 600 s at 1 Hz with N(0, σ²) noise. The inversion
(:mod:`lightcurve_gp.inference.inversion`, ``--starts``) and its families (:mod:`lightcurve_gp.inference.families`)
modulo the scenario's exact ambiguity group (:mod:`lightcurve_gp.photometry.ambiguity`), through
:func:`lightcurve_gp.inference.answer.answer` (the fit test, one widened search when it fails unless
``--no-widen``, the ridge probe of slow rates, the verdict). A family is **right** when the nearest image of the
truth is within 10° on every Euler axis at the first sample and its rate within 2 % of the true rate; scored: the
top family right (top-1; also at ≥ 1 °/s), a right family among those reported (top-k; also over the seeds whose
truth's basin is within the reporting ratio of the best found), the search misses, the top family's rate error,
its probability of being right ``p_right`` (the posterior mixture's mass within the tolerance of its mode: its
basin's weight times its Gaussian mass there and the mass of the other families there,
:mod:`lightcurve_gp.inference.families`) against how often it is right (calibration, binned, and the Brier score;
the same for the basin weight alone), the search's time; and each seed's kind against the truth's basin
(:mod:`lightcurve_gp.evaluation.inversion_reference`: right, the truth's family reported but not first, search
miss, data-limited), the verdict and whether the search was widened.

``--bank-size N`` runs beside it today's global start (:func:`lightcurve_gp.filters.bank.run_bank`, the model of
``--bank-config``, trained into ``runs/models`` when missing) on the same light curve, given the TRUE rate (it
cannot estimate one from SO(3) alone): its top member within 10° of an image at the first sample.

Resumable: one JSON per (config, σ, seed, starts) under ``<runs>/inversion/cases/``. Writes ``--out``: summary.md
(one table per geometry and σ) and per_seed.csv.

    python -m experiments.inversion --seeds 0:20 --sigma 0.05 0.1           # tuning seeds
    python -m experiments.inversion --seeds 1000:1100 --sigma 0.05 0.1 0.71  # held-out seeds
"""

from __future__ import annotations

import argparse
import ast
import csv
import io
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
from scipy.stats import chi2 as chi2_distribution
from tqdm.auto import tqdm

from experiments.common import seed_range, trained_model
from lightcurve_gp.attitude.dynamics import propagate
from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.config.load import load_config
from lightcurve_gp.evaluation.inversion_reference import KINDS, inversion_reference, state_nees
from lightcurve_gp.evaluation.reporting import markdown_table, quantiles
from lightcurve_gp.files import write_json_atomic, write_text_atomic
from lightcurve_gp.filters.bank import bank_attitudes, run_bank
from lightcurve_gp.inference.answer import MAX_LOG_RATIO, PROFILE_JOIN_NATS, answer
from lightcurve_gp.inference.families import RIGHT_RATE_REL, bounded_covariance, image_distance, mixture_p_right
from lightcurve_gp.inference.fit_verdict import VERDICTS, judged
from lightcurve_gp.inference.forward import GroupRenderer
from lightcurve_gp.inference.inversion import InversionSettings, polish
from lightcurve_gp.inference.probe_starts import below_one_turn
from lightcurve_gp.inference.rate_profile import capped_p_right, rate_profile, ridge_rule
from lightcurve_gp.inference.trajectory import TrajectoryProblem
from lightcurve_gp.passes.geometry import pass_geometry
from lightcurve_gp.photometry.ambiguity import ambiguity_group, near_image_turns
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_scenario

ROOT = Path(__file__).resolve().parents[1]
FORMAT = 12
#: the rule of the kept rows' ``p_right``: the posterior mixture's mass (:func:`mixed` brings older rows to it)
P_RIGHT_RULE = "mixture"
#: the truth's basin counts as the best found when no state fits better by more than this (nats)
BASIN_BEST_NATS = 0.01
#: the fastest rate searched, the radius of the prior's rate ball (rad/s)
RATE_MAX_RAD_S = math.radians(5.0)
TRUTH_STREAM = 1 << 42
CALIBRATION_BINS = (0.0, 0.5, 0.8, 0.95, 0.99, 1.0001)


RATE_LAWS = ("log-uniform", "uniform")
#: the rows kept per stage at 4000 starts: the counts of every case named without ``_k`` (from before the shares)
KEEP_4000 = InversionSettings(starts=4000).stage_keep()


def seed_truth(seed: int, rate_law: str = "log-uniform") -> tuple[torch.Tensor, torch.Tensor, float]:
    """The seed's true initial attitude ``(4,)``, body rate ``(3,)`` (rad/s) and ρ (module docstring); the rate's
    magnitude log-uniform or uniform over 0.05–5 °/s (``rate_law``, one of :data:`RATE_LAWS`)."""
    gen = torch.Generator().manual_seed(TRUTH_STREAM + seed)
    u = torch.rand(2, generator=gen, dtype=torch.float64)
    axis = torch.randn(3, generator=gen, dtype=torch.float64)
    if rate_law == "uniform":
        rate = 0.05 + (5.0 - 0.05) * float(u[0])
    else:
        rate = math.exp(math.log(0.05) + (math.log(5.0) - math.log(0.05)) * float(u[0]))
    q0 = random_attitudes(1, seed=TRUTH_STREAM + seed, dtype=torch.float64)[0]
    return q0, math.radians(rate) * axis / axis.norm(), 0.1 + 0.8 * float(u[1])


def scenario(cfg, seed: int, sigma: float, rate_law: str = "log-uniform"):
    """The seed's light curve: ``(scene, times (K,), y (K,), truth)``."""
    q0, w0, rho = seed_truth(seed, rate_law)
    scene = Scene.from_config(cfg)
    n = int(round(cfg.scenario.duration_s / cfg.scenario.dt_s))
    times = torch.arange(n + 1, dtype=torch.float64) * cfg.scenario.dt_s
    if cfg.geometry.kind == "orbit":
        g = pass_geometry(cfg)
        scene = scene.with_geometry(g.sun, g.observer, g.range_m)
        times = g.times_s - g.times_s[0]
    index = torch.round(times / cfg.scenario.dt_s).long()  # the truth as the simulations make it: RK4 on dt_s
    q, _ = propagate(q0, w0, torch.tensor(cfg.shape.inertia_kg_m2, dtype=torch.float64), cfg.scenario.dt_s,
                     int(index[-1]))
    gen = torch.Generator().manual_seed(seed)
    y = scene.magnitude(q[index], rho=rho) + sigma * torch.randn(len(index), generator=gen, dtype=torch.float64)
    return scene, times, y, (q0, w0, rho)


def seed_problem(cfg, seed: int, sigma: float, rate_law: str = "log-uniform"):
    """The seed's inversion problem: ``(scene, problem, group, truth)`` — its light curve (:func:`scenario`) as a
    :class:`~lightcurve_gp.inference.trajectory.TrajectoryProblem` anchored at the true first attitude, and the
    scenario's exact ambiguity group with the rate unknown."""
    scene, times, y, truth = scenario(cfg, seed, sigma, rate_law)
    inertia = torch.tensor(cfg.shape.inertia_kg_m2, dtype=torch.float64)
    problem = TrajectoryProblem(GroupRenderer(scene), times, y, torch.full_like(y, sigma), inertia, truth[0][None])
    return scene, problem, ambiguity_group(scene, times_s=times, inertia=inertia, rate_known=False), truth


def run_seed(cfg, seed: int, sigma: float, args) -> dict:
    """One seed's row (module docstring)."""
    scene, problem, group, (q0, w0, rho) = seed_problem(cfg, seed, sigma, args.rate_law)
    start = time.perf_counter()
    settings = InversionSettings(starts=args.starts, attitudes=args.attitudes,
                                 keep=tuple(args.keep) if args.keep else None,
                                 early_arcs=args.early_arcs, cohort_quotas=not args.shared_pruning)
    ans = answer(problem, group, settings=settings, rate_max_rad_s=RATE_MAX_RAD_S, widen=not args.no_widen,
                 image_turns=near_image_turns(scene))
    seconds = time.perf_counter() - start
    inv, fam = ans.inversion, ans.families
    ref = inversion_reference(problem, group, fam, best_cost=float(inv.cost.min()), q0=q0, omega0=w0, rho=rho)
    row = {"seed": seed, "sigma": sigma, "config": cfg.name, "rate_law": args.rate_law,
           "rate_deg_s": math.degrees(float(w0.norm())), "rho_true": rho, "families": len(fam),
           "top1": bool(ref.right[0]), "topk": bool(ref.right.any()), "top1_weight": float(fam.weight[0]),
           "top1_mass": float(fam.mass[0]), "top1_p_right": float(fam.p_right[0]),
           "p_right_sum": float(fam.p_right.sum()), "beyond_rate_range": fam.beyond, "p_right_rule": P_RIGHT_RULE,
           "best_below_truth": float(inv.cost.min()) < ref.truth_cost - 1e-6,
           **ref.as_dict(), "verdict": ans.verdict, "chi2_per_dof": ans.fit.chi2_per_dof, "p_value": ans.fit.p_value,
           "widened": ans.widened, "first_chi2_per_dof": ans.first_fit.chi2_per_dof,
           "probe_rows": ans.probe_rows, "probe_gain_nats": ans.probe_gain_nats,
           "rate_lo_deg_s": ans.rate_interval_deg_s[0], "rate_hi_deg_s": ans.rate_interval_deg_s[1],
           "ridge": ans.ridge, "rate_profile": None if ans.profile is None else ans.profile.as_dict(),
           "seconds": seconds, "stage_seconds": {**inv.seconds, **ans.seconds}, "starts": args.starts,
           "images": len(group),
           "families_state": {"q0": fam.q0.tolist(), "omega0_deg_s": torch.rad2deg(fam.omega0).tolist(),
                              "log_rho": fam.log_rho.tolist(), "weight": fam.weight.tolist(),
                              "p_right": fam.p_right.tolist(), "log_likelihood": fam.log_likelihood.tolist(),
                              "mass": fam.mass.tolist(), "nees": ref.nees.tolist()},
           "truth": {"q0": q0.tolist(), "omega0_deg_s": torch.rad2deg(w0).tolist(), "rho": rho}}
    if args.bank_size:
        row.update(bank_scores(args, seed, sigma, (q0, w0, rho), group))
    return row


def cached_nees(cfg, row: dict) -> dict:
    """The NEES of a kept row's families (rows made before it was kept): the seed's light curve made again, the
    Laplace covariance taken at each family's state (a polish of no step) and
    :func:`~lightcurve_gp.evaluation.inversion_reference.state_nees` against the truth; the keys
    ``top1_nees`` and ``families_state["nees"]``."""
    _, problem, group, (q0, w0, _) = seed_problem(cfg, row["seed"], row["sigma"], row.get("rate_law", "log-uniform"))
    state = row["families_state"]
    q = torch.tensor(state["q0"], dtype=torch.float64)
    w = torch.deg2rad(torch.tensor(state["omega0_deg_s"], dtype=torch.float64))
    x = torch.cat([torch.zeros_like(w), w, torch.tensor(state["log_rho"], dtype=torch.float64)[:, None]], -1)
    fam = polish(problem, q, x, iterations=0)
    values = state_nees(group, fam.q0, fam.omega0, fam.covariance, q0=q0, omega0=w0)
    return {"top1_nees": float(values[0]), "families_state": {**state, "nees": values.tolist()}}


def profiled(cfg, row: dict, args) -> dict:
    """A kept row made before the answer profiled a slow top family's rate
    (:mod:`lightcurve_gp.inference.rate_profile`), with the answer's rule applied: above one turn over the arc
    nothing changes; below it the top family's profile from its kept state caps its ``p_right``
    (:func:`~lightcurve_gp.inference.rate_profile.ridge_rule`), sets the ridge and the verdict and widens the rate
    interval, unless a profile point fits better than the family by more than
    :data:`~lightcurve_gp.inference.answer.PROFILE_JOIN_NATS`: the answer would then have joined it to the
    solutions, so the seed is run again."""
    state = row["families_state"]
    w = torch.deg2rad(torch.tensor(state["omega0_deg_s"][0], dtype=torch.float64))
    if not below_one_turn(float(w.norm()), span_s=args.duration_s):
        return {**row, "ridge": False, "rate_profile": None}
    _, problem, _, _ = seed_problem(cfg, row["seed"], row["sigma"], row.get("rate_law", "log-uniform"))
    profile = rate_profile(problem, q0=torch.tensor(state["q0"][0], dtype=torch.float64), omega0=w,
                           log_rho=torch.tensor(state["log_rho"][0], dtype=torch.float64),
                           span_s=float(problem.times[-1] - problem.times[0]),
                           rate_range_deg_s=InversionSettings.rate_range_deg_s)
    if profile.gain_nats > PROFILE_JOIN_NATS:
        return run_seed(cfg, row["seed"], row["sigma"], args)
    p_right, ridge = ridge_rule(profile, weight=state["weight"][0], p_right=state["p_right"][0])
    verdict = judged(fits=row["verdict"] != "no_fit", top_weight=p_right, ridge=ridge)
    p_rights = [p_right, *state["p_right"][1:]]
    lo, hi = profile.interval_deg_s
    return {**row, "top1_p_right": p_right, "p_right_sum": float(sum(p_rights)), "verdict": verdict, "ridge": ridge,
            "rate_profile": profile.as_dict(), "rate_lo_deg_s": min(row["rate_lo_deg_s"], lo),
            "rate_hi_deg_s": max(row["rate_hi_deg_s"], hi), "families_state": {**state, "p_right": p_rights}}


def mixed(cfg, row: dict) -> dict:
    """A kept row made before ``p_right`` counted the other families' mass within the top family's tolerance
    (:func:`~lightcurve_gp.inference.families.mixture_p_right`), with today's rule applied to its kept families —
    their states, weights and masses; the Laplace covariances taken again at each state (a polish of no step, as the
    answer takes them) — then, as the answer does, the kept rate profile's cap on the top family
    (:func:`~lightcurve_gp.inference.rate_profile.ridge_rule`), every ``p_right`` 0 under ``no_fit`` and the
    verdict from the kept fit test."""
    state = row["families_state"]
    _, problem, group, _ = seed_problem(cfg, row["seed"], row["sigma"], row.get("rate_law", "log-uniform"))
    q = torch.tensor(state["q0"], dtype=torch.float64)
    w = torch.deg2rad(torch.tensor(state["omega0_deg_s"], dtype=torch.float64))
    x = torch.cat([torch.zeros_like(w), w, torch.tensor(state["log_rho"], dtype=torch.float64)[:, None]], -1)
    fam = polish(problem, q, x, iterations=0)
    p_rights = mixture_p_right(group, q0=q, omega0=w, covariance=bounded_covariance(fam.covariance, RATE_MAX_RAD_S),
                               weight=torch.tensor(state["weight"], dtype=torch.float64),
                               mass=torch.tensor(state["mass"], dtype=torch.float64)).tolist()
    profile = row.get("rate_profile")
    if profile:
        p_rights[0] = capped_p_right(profile["share"], weight=state["weight"][0], p_right=p_rights[0])
    if row["verdict"] == "no_fit":
        p_rights = [0.0] * len(p_rights)
    verdict = judged(fits=row["verdict"] != "no_fit", top_weight=p_rights[0], ridge=row["ridge"])
    return {**row, "top1_p_right": p_rights[0], "p_right_sum": float(sum(p_rights)), "verdict": verdict,
            "p_right_rule": P_RIGHT_RULE, "families_state": {**state, "p_right": p_rights}}


def brought_up(cfg, row: dict, args) -> dict:
    """A kept row with every rule the answer has gained since it was made applied to its kept families: the NEES
    (:func:`cached_nees`), no ``p_right`` under ``no_fit`` (:func:`without_p_right`), the slow top family's rate
    profile (:func:`profiled`) and the mixture's ``p_right`` (:func:`mixed`); the row itself when none applies."""
    if "top1_nees" not in row:
        row = {**row, **cached_nees(cfg, row)}
    if row["verdict"] == "no_fit" and row["p_right_sum"] > 0.0:
        row = without_p_right(row)
    if "rate_profile" not in row:
        row = profiled(cfg, row, args)
    if row.get("p_right_rule") != P_RIGHT_RULE:
        row = mixed(cfg, row)
    return row


def read_per_seed_csv(text: str) -> list[dict]:
    """The rows of :func:`per_seed_csv`'s text: each value as Python wrote it (numbers, booleans, nested values), an
    empty cell as ``None`` (a key the row lacked), anything else as its text."""
    def value(cell: str):
        if cell == "":
            return None
        try:
            return ast.literal_eval(cell)
        except (ValueError, SyntaxError):
            return cell
    csv.field_size_limit(max(csv.field_size_limit(), len(text)))
    return [{k: value(v) for k, v in r.items()} for r in csv.DictReader(io.StringIO(text))]


def kept_rows(cfg, args) -> list[dict]:
    """``--kept``: the rows of an earlier run's per-seed CSV brought up to today's rules (:func:`brought_up`).

    Raises:
        SystemExit: the file cannot be read, or a row is of another config than ``--config``.
    """
    try:
        rows = read_per_seed_csv(args.kept.read_text())
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise SystemExit(f"--kept {args.kept}: cannot read it ({exc})") from None
    for line, row in enumerate(rows, start=2):
        if row.get("config") != cfg.name:
            raise SystemExit(f"--kept {args.kept}, line {line}: a row of config {row.get('config')!r}, "
                             f"not --config's {cfg.name!r}")
    return [brought_up(cfg, {k: v for k, v in row.items() if v is not None}, args)
            for row in tqdm(rows, desc=f"{args.kept.name}: kept rows")]


def without_p_right(row: dict) -> dict:
    """A kept ``no_fit`` row made before the answer stated no ``p_right`` under that verdict
    (:mod:`lightcurve_gp.inference.answer`, rule 1), with the answer's rule applied: every ``p_right`` 0."""
    state = row["families_state"]
    return {**row, "top1_p_right": 0.0, "p_right_sum": 0.0,
            "families_state": {**state, "p_right": [0.0] * len(state["p_right"])}}


def bank_scores(args, seed: int, sigma: float, truth, group) -> dict:
    """Today's global start on the seed's light curve with the true rate (module docstring)."""
    q0, w0, rho = truth
    cfg = load_config(args.bank_config, [f"scenario.q0={q0.tolist()}",
                                         f"scenario.omega0_deg_s={np.degrees(w0.numpy()).tolist()}",
                                         f"scenario.noise_var={sigma ** 2}"])
    sc = simulate_scenario(cfg, seeds=[seed], rho_true=rho)
    bank = run_bank(cfg, trained_model(cfg, args.runs), observations=sc.observations[0], increments=sc.increments[0],
                    q0=bank_attitudes(args.bank_size), keep=5, R=sigma ** 2)
    est0 = bank.kept.q_est[:, 0]
    angle, _, _ = image_distance(group, est0, w0.expand(5, 3), q0, w0)
    return {"bank_top1": bool(angle[0] < 10.0), "bank_top5": bool((angle < 10.0).any()),
            "bank_top1_weight": float(bank.weights[bank.order[0]]), "bank_seconds": bank.seconds}


def count_p_value(p: np.ndarray, k: int) -> float:
    """Two-sided chance that ``n`` seeds right with their own probabilities ``p (n,)`` (independent; the count is
    Poisson-binomial, its distribution by convolution) give a count at least as far from its mean ``Σ p`` as ``k``."""
    pmf = np.array([1.0])
    for q in np.clip(np.asarray(p, dtype=float), 0.0, 1.0):
        pmf = np.convolve(pmf, [1.0 - q, q])
    mean = float(np.sum(p))
    far = np.abs(np.arange(len(pmf)) - mean) >= abs(k - mean) - 1e-9
    return float(min(1.0, pmf[far].sum()))


def calibration(rows: list[dict], key: str = "top1_p_right") -> str:
    """Mean top-family probability (``key``: its p_right, or its basin weight) against the share right, per bin,
    with twice the standard deviation of that share were every seed right with its own probability
    (``2 √(mean p(1 − p) / n)``): how far an honest probability's bin may stray by chance; and the chance of a
    count right at least that far off under those probabilities (:func:`count_p_value`)."""
    w = np.array([r[key] for r in rows])
    ok = np.array([r["top1"] for r in rows], dtype=float)
    parts = []
    for lo, hi in zip(CALIBRATION_BINS[:-1], CALIBRATION_BINS[1:]):
        inside = (w >= lo) & (w < hi)
        if inside.any():
            mean, n = float(w[inside].mean()), int(inside.sum())
            spread = 2.0 * math.sqrt(max(float((w[inside] * (1.0 - w[inside])).mean()), 0.0) / n)
            chance = count_p_value(w[inside], int(ok[inside].sum()))
            parts.append(f"[{lo:g}, {min(hi, 1):g}]: w̄ {mean:.2f} vs {ok[inside].mean():.2f} (n {n}, ±{spread:.2f}, "
                         f"p {chance:.2g})")
    return "; ".join(parts)


def brier(rows: list[dict], key: str = "top1_p_right") -> float:
    """The Brier score of the top family's ``key`` (p_right, or basin weight) as the probability that it is right:
    mean ``(p − right)²``."""
    return float(np.mean([(r[key] - float(r["top1"])) ** 2 for r in rows]))


def arc_right(row: dict, span_s: float) -> bool:
    """The top family within 10° of the truth's image at the first sample and its rate error, accumulated over the
    arc (``|Δω| · span``), below 10° as well: right over the whole light curve even where 2 % of a slow rate is
    beyond what the light curve can tell."""
    drift = row["top1_rate_error_rel"] * row["rate_deg_s"] * span_s
    return row["top1_max_axis_error_deg"] < 10.0 and drift < 10.0


def kinds(rows: list[dict]) -> str:
    """How many seeds of each kind (:data:`~lightcurve_gp.evaluation.inversion_reference.KINDS`)."""
    return ", ".join(f"{k.replace('_', ' ')} {sum(r['kind'] == k for r in rows)}" for k in KINDS)


def verdicts(rows: list[dict]) -> str:
    """How many seeds got each verdict, and how many were widened."""
    counts = ", ".join(f"{v.replace('_', ' ')} {sum(r['verdict'] == v for r in rows)}" for v in VERDICTS)
    return f"{counts}; widened {sum(r['widened'] for r in rows)}; ridge {sum(bool(r.get('ridge')) for r in rows)}"


def fast_right(rows: list[dict], fast_deg_s: float = 1.0) -> str:
    """Top-1 right among the seeds at ``fast_deg_s`` or faster, ``k/n``, and among those of them whose truth's basin
    is itself right and the best found (to :data:`BASIN_BEST_NATS`) — the seeds where the maximum-likelihood answer is
    right (for the others the truth's basin is not right, or another basin fits better: data-limited)."""
    fast = [r for r in rows if r["rate_deg_s"] >= fast_deg_s]
    clear = [r for r in fast if r.get("basin_right") and r["best_minus_basin"] >= -BASIN_BEST_NATS]
    return f"{sum(r['top1'] for r in fast)}/{len(fast)} ({sum(r['top1'] for r in clear)}/{len(clear)})"


def on_reported_ridge(row: dict, span_s: float = 600.0) -> bool:
    """A slow tumbler (less than one turn over ``span_s``) whose true rate lies in the answer's reported rate interval
    (to within the 2 % of "right"): its posterior a ridge that the answer reports as such."""
    rate = row["rate_deg_s"]
    return (bool(below_one_turn(math.radians(rate), span_s=span_s))
            and row["rate_lo_deg_s"] * (1.0 - RIGHT_RATE_REL) <= rate <= row["rate_hi_deg_s"] * (1.0 + RIGHT_RATE_REL))


def reported_within_ratio(rows: list[dict], ratio_nats: float = MAX_LOG_RATIO, span_s: float = 600.0) -> str:
    """The truth's own family (the family of the truth's basin, ``basin_rank > 0``) among those reported, over the
    seeds whose truth's basin is within the reporting ratio of the best state found (``basin − best ≤ ratio_nats``):
    ``k/n (share)``, and in brackets the share counting also the slow tumblers on a reported ridge
    (:func:`on_reported_ridge`)."""
    sel = [r for r in rows if r["basin_cost"] - r["best_cost"] <= ratio_nats]
    k = sum(r.get("basin_rank", 0) > 0 for r in sel)
    ridge = sum(r.get("basin_rank", 0) == 0 and on_reported_ridge(r, span_s) for r in sel)
    n = max(len(sel), 1)
    return f"{k}/{len(sel)} ({100 * k / n:.0f} %; with the ridges {100 * (k + ridge) / n:.0f} %)"


def nees_right(rows: list[dict]) -> str:
    """The top family's NEES (6 degrees of freedom, :func:`~lightcurve_gp.evaluation.inversion_reference.state_nees`)
    over the seeds where it is right: median [IQR] and how many exceed χ²₆'s 99th percentile (16.8); "—" without a
    value."""
    values = [r["top1_nees"] for r in rows if r["top1"] and "top1_nees" in r]
    if not values:
        return "—"
    q = quantiles(values)
    limit = float(chi2_distribution.ppf(0.99, 6))
    wide = sum(v > limit for v in values)
    return f"{q.median:.1f} [{q.q25:.1f}, {q.q75:.1f}], > {limit:.1f}: {wide}/{len(values)}"


def misses(rows: list[dict]) -> str:
    """Search misses (best found worse than the truth's basin by more than the miss margin): ``k/n (share)``."""
    k = sum(r["kind"] == "search_miss" for r in rows)
    return f"{k}/{len(rows)} ({100 * k / len(rows):.0f} %)"


def report(rows: list[dict], command: str, span_s: float = 600.0) -> str:
    text = ["# Global inversion: top family against the truth (random attitude, rate 0.05-5 deg/s, rho unknown)\n",
            f"Command: `{command}`\n",
            "Right: an image of the truth within 10° on every Euler axis at the first sample and the rate within 2 %. "
            "Kinds against the truth's basin (evaluation/inversion_reference.py): right, a right family reported "
            "but not first, search miss (best found worse than the truth's basin by > 1 nat), data-limited (another "
            "basin at least as good). Wrong & unique: the top family wrong and the verdict unique (p_right >= 0.9, "
            "fit passed), beside the count honest probabilities expect (the sum of 1 - p_right over the unique "
            "seeds). p_right: the posterior mixture's mass of the region of right states about the top family's "
            "mode, its basin weight times its Gaussian mass there and the other families' mass there "
            "(inference/families.py); calibration and Brier of p_right, and of the basin weight "
            "alone. The truth's basin family: a reported family within 10° and 2 % of the truth's basin (the "
            "polish from the truth), counted over the seeds whose basin is within the reporting ratio of the best.\n"]
    for name, law in sorted({(r["config"], r.get("rate_law", "log-uniform")) for r in rows}):
        cells = []
        mine = [r for r in rows if r["config"] == name and r.get("rate_law", "log-uniform") == law]
        for sigma in sorted({r["sigma"] for r in mine}):
            sel = [r for r in mine if r["sigma"] == sigma]
            n = len(sel)
            pct = lambda key: f"{100 * sum(bool(r.get(key)) for r in sel) / n:.0f} %"  # noqa: E731
            rate = quantiles([100 * r["top1_rate_error_rel"] for r in sel])
            secs = quantiles([r["seconds"] for r in sel])
            bank = pct("bank_top1") + " / " + pct("bank_top5") if "bank_top1" in sel[0] else "not run"
            arc = f"{100 * sum(arc_right(r, span_s) for r in sel) / n:.0f} %"
            unique = [r for r in sel if r["verdict"] == "unique"]
            wrong_unique = (f"{sum(not r['top1'] for r in unique)} (expected "
                            f"{sum(1.0 - r['top1_p_right'] for r in unique):.1f} of {len(unique)})")
            cells.append([sigma, n, pct("top1"), fast_right(sel), arc, pct("topk"),
                          reported_within_ratio(sel, span_s=span_s), misses(sel), kinds(sel), verdicts(sel),
                          wrong_unique,
                          f"{rate.median:.2g} [{rate.q25:.2g}, {rate.q75:.2g}]", nees_right(sel), calibration(sel),
                          f"{brier(sel):.3f}", calibration(sel, "top1_weight"), f"{brier(sel, 'top1_weight'):.3f}",
                          f"{secs.median:.0f}", bank])
        text.append(f"\n## {name}, rates {law}\n\n" + markdown_table(
            ("σ (mag)", "seeds", "top-1 right (10°, rate 2 %)",
             "top-1 right at ≥ 1 °/s (where the truth's basin is right and the best found)",
             "top-1 within 10° over the arc", "right family reported",
             "truth's basin family reported (basin within the ratio; with the slow tumblers' reported ridges)",
             "search misses", "kinds", "verdicts", "wrong & unique (expected: Σ 1 − p_right over the unique)",
             "top-1 rate error %, median [IQR]",
             "NEES of the right top family (6 dof: 6), median [IQR]",
             "calibration of p_right (bin: mean p_right vs share right)", "Brier (p_right)",
             "calibration of the basin weight", "Brier (weight)", "s per seed (median)",
             "bank top-1 / top-5 (true rate given)"), cells))
    return "\n".join(text) + "\n"


def per_seed_csv(rows: list[dict]) -> str:
    """The rows as CSV text, one column per key of the first row but the stage times (nested values quoted)."""
    keys = [k for k in rows[0] if k != "stage_seconds"]
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(keys)
    writer.writerows([r.get(k, "") for k in keys] for r in rows)
    return text.getvalue()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--config", default=str(ROOT / "configs" / "boxwing.yaml"))
    parser.add_argument("--seeds", type=seed_range, default=range(0, 20))
    parser.add_argument("--sigma", type=float, nargs="+", default=[0.05, 0.1])
    parser.add_argument("--starts", type=int, default=10_000)
    parser.add_argument("--attitudes", type=int, default=InversionSettings.attitudes,
                        help="Sobol' attitudes of the screening grid (the rest of the grid goes to rates)")
    parser.add_argument("--keep", type=int, nargs="+", default=None,
                        help="rows carried into each continuation stage after the first (default: the shares "
                             f"{' '.join(map(str, InversionSettings.keep_share))} of --starts)")
    parser.add_argument("--early-arcs", type=int, default=InversionSettings.early_arcs,
                        help="arcs before its entry arc that each rate is also screened on (0: the entry arc alone)")
    parser.add_argument("--shared-pruning", action="store_true",
                        help="all rows compete for the stage's keep (no per-cohort quotas)")
    parser.add_argument("--no-widen", action="store_true", help="no widened search when the first fit fails")
    parser.add_argument("--rate-law", choices=RATE_LAWS, default="log-uniform",
                        help="the truth's rate magnitude over 0.05-5 deg/s")
    parser.add_argument("--duration-s", type=float, default=600.0)
    parser.add_argument("--bank-size", type=int, default=0, help="filters of today's global start beside it (0: none)")
    parser.add_argument("--bank-config", default=str(ROOT / "configs" / "boxwing_robust.yaml"))
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--runs", type=Path, default=ROOT / "runs")
    parser.add_argument("--out", type=Path, default=ROOT / "experiments" / "results" / "inversion")
    parser.add_argument("--kept", type=Path, default=None,
                        help="a per_seed.csv of an earlier run: its rows with today's rules applied to their kept "
                             "families, no search (--config as the run's)")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    cfg = load_config(args.config, [f"scenario.duration_s={args.duration_s}",
                                    f"evaluation.rmse_window_s=[0, {args.duration_s}]"])
    cases = args.runs / "inversion" / "cases"
    rows = []
    if args.kept is not None:
        rows = kept_rows(cfg, args)
    for sigma in args.sigma if args.kept is None else ():
        for seed in tqdm(args.seeds, desc=f"{cfg.name} σ {sigma:g}"):
            grid = "" if args.attitudes == InversionSettings.attitudes else f"_a{args.attitudes}"
            keep = InversionSettings(starts=args.starts, keep=tuple(args.keep) if args.keep else None).stage_keep()
            if keep != KEEP_4000:  # rows of the counts every earlier case used keep their names
                grid += "_k" + "-".join(map(str, keep))
            grid += "_nowiden" if args.no_widen else ""
            grid += f"_e{args.early_arcs}" if args.early_arcs != InversionSettings.early_arcs else ""
            grid += "_shared" if args.shared_pruning else ""
            grid += "_uniform" if args.rate_law == "uniform" else ""
            path = cases / f"{cfg.name}_s{sigma:g}_n{args.starts}{grid}_b{args.bank_size}_v{FORMAT}_{seed}.json"
            if path.exists():
                kept = json.loads(path.read_text())
                row = brought_up(cfg, kept, args)
                if row != kept:
                    write_json_atomic(row, path)
                rows.append(row)
                continue
            row = run_seed(cfg, seed, sigma, args)
            write_json_atomic(row, path)
            rows.append(row)
    command = "python -m experiments.inversion " + " ".join(argv if argv is not None else sys.argv[1:])
    args.out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(report(rows, command, args.duration_s), args.out / "summary.md")
    write_text_atomic(per_seed_csv(rows), args.out / "per_seed.csv")
    print(report(rows, command, args.duration_s))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
