"""Global start on the paper's scenario with ρ unknown: how often the bank's top-ranked filter finds the attitude.

Per seed ``s``: the paper's scenario (spin, surface, 600 s at 1 Hz, noise variance 0.5) with a random true initial
attitude (``random_attitudes(1, seed=s)``) and ``ρ_true = (0.3, 0.4, 0.6, 0.7)[s mod 4]``, the robust config (GP of
the reference curve, magnitude offset in the state); a bank of ``--bank-size`` filters over SO(3)
(:mod:`lightcurve_gp.filters.bank`) ranked by innovation log-likelihood, the best ``--keep`` rerun with the config's
settings. Beside it, the filter started from the config's initial error about the truth
(``scenario.initial_error_deg``, the other tables' start): what an initial guess 10–15° off reaches on the same
light curve. Scored on 400–600 s: the top-ranked filter is "within 10°" when the median |Euler error| over the
window is below 10° on all three axes (the RMSE criterion of the other tables is reported beside it); "truth in the
top five" when any of the five best is within 10°. Beside these strict scores, the same "modulo symmetry": the
error against the nearest image ``q_R ⊗ q_true(t) ⊗ q_C`` of the truth under the scenario's exact ambiguity group
(derived, :func:`lightcurve_gp.evaluation.harness.scenario_ambiguity_group`; with the robust config's known spin
the four inertial 180° turns of the Sun–observer pair, not the shape's body turns, which would turn the rate too);
the images used are named in each row (``images``). Nothing here was tuned: bank size, P0 (the config's
10°) and
the bank's variance choice were fixed before any seed ran.

Pruning (``--prune-after-s S --prune-keep K``): all members run the first ``S`` seconds, the best ``K`` continue
(:func:`lightcurve_gp.filters.bank.run_bank`). ``--prune-study`` (unpruned runs only) adds to each row what every
pruning of a small grid would have done: since a survivor's continuation is its uninterrupted run, the pruned
ranking is the unpruned one restricted to the survivors, so one unpruned run scores every (S, K) exactly.

Resumable: one case file per seed under ``<runs>/global_start/cases/`` (the sweep's case store,
:func:`lightcurve_gp.sweep.store.resume_case`); a rerun skips the stored seeds. Writes ``--out``
(experiments/results/global_start/): summary.md, summary.json, per_seed.csv.

    python -m experiments.global_start --seeds 0:100 --prune-after-s 60 --prune-keep 64
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
import time
from pathlib import Path

import torch
from tqdm.auto import tqdm

from experiments.common import ROBUST_CONFIG, ROOT, command_line, seed_range, trained_model, write_outputs
from lightcurve_gp.attitude.metrics import attitude_error_vector, attitude_errors_deg, nees
from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.config.load import ConfigError, config_hash, load_config
from lightcurve_gp.evaluation.harness import scenario_ambiguity_group
from lightcurve_gp.evaluation.reporting import csv_text, markdown_table, quantiles
from lightcurve_gp.filters.bank import bank_attitudes, run_bank
from lightcurve_gp.filters.selection import innovation_log_likelihood, innovation_log_terms
from lightcurve_gp.filters.setup import run_filter
from lightcurve_gp.observed.run import nis_summary
from lightcurve_gp.simulation.scenario import simulate_scenario
from lightcurve_gp.sweep.store import resume_case
from lightcurve_gp.training.store import model_key

RHO_CYCLE = (0.3, 0.4, 0.6, 0.7)
FORMAT = 4  # 4: modulo the derived ambiguity group
PRUNE_GRID_S = (30.0, 60.0, 120.0)
PRUNE_GRID_K = (16, 32, 64, 128)


def seed_truth(seed: int) -> tuple[list[float], float]:
    """The random true initial attitude and ρ_true of a seed."""
    return [float(v) for v in random_attitudes(1, seed=seed, dtype=torch.float64)[0]], RHO_CYCLE[seed % 4]


def window_scores(q_true: torch.Tensor, q_est: torch.Tensor, times: torch.Tensor, window) -> dict:
    """Median |error| and RMSE per axis (deg) over the window of estimates ``(K, T+1, 4)`` against ``(T+1, 4)``."""
    inside = (times >= window[0]) & (times <= window[1])
    err = attitude_errors_deg(q_true.expand_as(q_est), q_est)[:, inside]  # (K, W, 3)
    return {"median_abs": err.abs().median(dim=1).values, "rmse": err.pow(2).mean(1).sqrt()}


def symmetric_scores(q_true: torch.Tensor, q_est: torch.Tensor, times: torch.Tensor, window, group) -> dict:
    """:func:`window_scores` against the nearest image ``q_R ⊗ q_true ⊗ q_C`` of the truth under the scenario's
    ambiguity ``group`` (:class:`~lightcurve_gp.photometry.ambiguity.AmbiguityGroup`): per estimate the image with the
    smallest largest-axis median |error|, its median |error| ``(K, 3)`` and its index."""
    truths = group.to(dtype=q_true.dtype, device=q_true.device).attitudes(q_true)  # (G, T+1, 4)
    medians = torch.stack([window_scores(t, q_est, times, window)["median_abs"] for t in truths])  # (G, K, 3)
    best = medians.amax(-1).argmin(0)  # (K,)
    return {"median_abs": medians[best, torch.arange(q_est.shape[0])], "symmetry": best, "truths": truths}


def prune_study(bank, dt: float) -> dict:
    """For every pruning of the grid: whether its top-1 and its top five are the unpruned bank's (module docstring).
    Keys ``"<S>s_<K>"``."""
    partial = innovation_log_terms(bank.bank_history).cumsum(-1)  # (N, T+1)
    out = {}
    for seconds in PRUNE_GRID_S:
        step = int(round(seconds / dt))
        for k in PRUNE_GRID_K:
            survivors = torch.argsort(partial[:, step], descending=True)[:k]
            ranked = survivors[torch.argsort(bank.log_likelihood[survivors], descending=True)]
            out[f"{seconds:g}s_{k}"] = {"top1_same": bool(ranked[0] == bank.order[0]),
                                        "top5_same": set(ranked[:5].tolist()) == set(bank.order[:5].tolist())}
    return out


def run_seed(cfg_path: str, seed: int, model, args) -> dict:
    """One seed's row (module docstring)."""
    q0, rho = seed_truth(seed)
    cfg = load_config(cfg_path, [f"scenario.q0={q0}", f"device={args.device}"])
    sc = simulate_scenario(cfg, seeds=[seed], rho_true=rho)
    q_true = sc.q_true[0]  # (T+1, 4): the one seed's truth
    prune = None if args.prune_after_s is None else int(round(args.prune_after_s / cfg.scenario.dt_s))
    bank = run_bank(cfg, model, observations=sc.observations[0], increments=sc.increments[0],
                    q0=bank_attitudes(args.bank_size, device=sc.observations.device), keep=args.keep,
                    prune_after=prune, prune_keep=args.prune_keep)
    window = cfg.evaluation.rmse_window_s
    scores = window_scores(q_true, bank.kept.q_est, sc.times, window)
    within = (scores["median_abs"] < 10).all(-1)
    group = scenario_ambiguity_group(cfg, sc)
    sym = symmetric_scores(q_true, bank.kept.q_est, sc.times, window, group)
    within_sym = (sym["median_abs"] < 10).all(-1)
    inside = (sc.times >= window[0]) & (sc.times <= window[1])
    err = attitude_error_vector(q_true, bank.kept.q_est[0], kind="grp")
    err_sym = attitude_error_vector(sym["truths"][sym["symmetry"][0]], bank.kept.q_est[0], kind="grp")
    nearest = int(torch.argmin(attitude_errors_deg(q_true[0].expand_as(bank.q0), bank.q0).norm(dim=-1)))
    rank_of_nearest = int((bank.order == nearest).nonzero()[0, 0]) + 1
    row = {"seed": seed, "rho_true": rho, "q0_true": q0,
           "top1_within_10deg": bool(within[0]), "top5_within_10deg": bool(within[:5].any()),
           "top1_rmse_below_10deg": bool((scores["rmse"][0] < 10).all()),
           "top1_within_10deg_mod_symmetry": bool(within_sym[0]),
           "top5_within_10deg_mod_symmetry": bool(within_sym[:5].any()), "top1_symmetry": int(sym["symmetry"][0]),
           "images": group.describe(),
           **{f"top1_median_abs_{a}_deg": float(scores["median_abs"][0, i]) for i, a in enumerate("ypr")},
           **{f"top1_median_abs_mod_symmetry_{a}_deg": float(sym["median_abs"][0, i]) for i, a in enumerate("ypr")},
           **{f"top1_rmse_{a}_deg": float(scores["rmse"][0, i]) for i, a in enumerate("ypr")},
           "top1_nees_mean": float(nees(err[inside], bank.kept.P[0][inside]).mean()),
           "top1_nees_mean_mod_symmetry": float(nees(err_sym[inside], bank.kept.P[0][inside]).mean()),
           "top1_nis_mean": nis_summary(bank.kept)["mean"], "top1_weight": float(bank.weights[bank.order[0]]),
           "rank_of_nearest_member": rank_of_nearest, "bank_seconds": bank.seconds,
           "kept_seconds": bank.kept_seconds, "load_average_1min": os.getloadavg()[0],
           "device": args.device}
    if args.prune_study:
        row["prune_study"] = prune_study(bank, cfg.scenario.dt_s)
    guided = run_filter(cfg, model, q_est0=sc.q_est0, observations=sc.observations, increments=sc.increments[0])
    row["from_config_error_within_10deg"] = bool(
        (window_scores(q_true, guided.q_est, sc.times, window)["median_abs"][0] < 10).all())
    row.update(truth_start_scores(cfg, model, sc, bank, window))
    return row


def truth_start_scores(cfg, model, sc, bank, window) -> dict:
    """A bank member started at the true initial attitude (the bank's settings): its log-likelihood against the
    top-ranked member's, and whether it ends within 10°. Where the top-ranked member's ℓ is the higher, a wrong
    attitude explains the light curve better than the truth, and no ranking by likelihood can find the truth."""
    truth = run_filter(cfg, model, q_est0=sc.q_true[:, 0], observations=sc.observations, increments=sc.increments[0],
                       variance="none")
    truth_ll, top_ll = float(innovation_log_likelihood(truth)[0]), float(bank.log_likelihood[bank.order[0]])
    return {"truth_start_log_likelihood": truth_ll, "top1_log_likelihood": top_ll,
            "top1_ll_above_truth_start": top_ll > truth_ll,
            "truth_start_within_10deg": bool(
                (window_scores(sc.q_true[0], truth.q_est, sc.times, window)["median_abs"][0] < 10).all())}


def case_key(args, cfg, seed: int) -> str:
    """Content hash of one seed's case: the sections it reads, the model, the seed and the bank's settings."""
    return config_hash(cfg, "scenario", "filter", "evaluation", extra={
        "experiment": "global_start", "format": FORMAT, "seed": seed, "bank": args.bank_size, "keep": args.keep,
        "model": model_key(cfg), "prune": None if args.prune_after_s is None else [args.prune_after_s, args.prune_keep],
        "prune_study": args.prune_study})


def seed_case(cfg_path: str, seed: int, model, args) -> tuple[dict, list]:
    """One seed's case for the store: its row (:func:`run_seed`) as the summary, no per-seed metric rows."""
    return {"row": run_seed(cfg_path, seed, model, args)}, []


def report(rows: list[dict], args, command: str, wall: float) -> str:
    n = len(rows)
    share = lambda key: f"{100 * sum(r[key] for r in rows) / n:.0f} %"  # noqa: E731
    spread = lambda key: quantiles(torch.tensor([r[key] for r in rows], dtype=torch.float64))  # noqa: E731
    secs, kept, nees_top, nees_sym = (spread(k) for k in ("bank_seconds", "kept_seconds", "top1_nees_mean",
                                                          "top1_nees_mean_mod_symmetry"))
    loads = [r["load_average_1min"] for r in rows]
    bank = f"{args.bank_size}" + ("" if args.prune_after_s is None else
                                  f", best {args.prune_keep} after {args.prune_after_s:g} s")
    iqr = lambda q, f: f"{q.median:{f}} [{q.q25:{f}}, {q.q75:{f}}]"  # noqa: E731
    cells = [[n, bank, share("top1_within_10deg"), share("top1_within_10deg_mod_symmetry"),
              share("top1_rmse_below_10deg"), share("top5_within_10deg"), share("top5_within_10deg_mod_symmetry"),
              iqr(nees_top, ".1f"), iqr(nees_sym, ".2f"), iqr(secs, ".0f"), iqr(kept, ".0f"),
              f"{min(loads):.1f}-{max(loads):.1f}", ", ".join(sorted({r.get("device", "cpu") for r in rows}))]]
    table = markdown_table(("seeds", "bank", "top-1 within 10° (median \\|err\\|)", "top-1 within 10° mod symmetry",
                            "top-1 RMSE < 10°", "truth in top 5", "truth in top 5 mod symmetry",
                            "top-1 NEES median [IQR]", "top-1 NEES mod symmetry", "bank s per seed, median [IQR]",
                            "rerun of best 5, s", "load average", "device"), cells)
    images = "; ".join(sorted({", ".join(r.get("images", ["the shape's body turns (rows before format 4)"]))
                               for r in rows}))
    text = (f"# Global start: bank of {args.bank_size} filters, paper scenario, rho unknown\n\n"
            f"Command: `{command}`; wall time {wall:.0f} s for the seeds run by this command.\n\n{table}\n"
            f"NEES of one run's window mean: 3 for a consistent filter. \"Mod symmetry\": modulo the images "
            f"{images}.\n")
    guided = [r["from_config_error_within_10deg"] for r in rows if "from_config_error_within_10deg" in r]
    if guided:
        text += (f"\nStarted from the config's initial error about the truth instead of the bank: within 10° on "
                 f"{sum(guided)} of {len(guided)} seeds ({100 * sum(guided) / len(guided):.0f} %).\n")
    truth = [r for r in rows if "truth_start_log_likelihood" in r]
    if truth:
        above = sum(r["top1_ll_above_truth_start"] for r in truth)
        gap = quantiles(torch.tensor([r["top1_log_likelihood"] - r["truth_start_log_likelihood"] for r in truth],
                                     dtype=torch.float64))
        text += (f"\nA bank member started at the true initial attitude: within 10° on "
                 f"{sum(r['truth_start_within_10deg'] for r in truth)} of {len(truth)} seeds; the top-ranked member's "
                 f"log-likelihood above it on {above} of {len(truth)} seeds (ℓ_top − ℓ_truth median {gap.median:.1f} "
                 f"[{gap.q25:.1f}, {gap.q75:.1f}] nats).\n")
    if rows and "prune_study" in rows[0]:
        grid = rows[0]["prune_study"].keys()
        cells = [[key, f"{sum(r['prune_study'][key]['top1_same'] for r in rows)}/{n}",
                  f"{sum(r['prune_study'][key]['top5_same'] for r in rows)}/{n}"] for key in grid]
        text += ("\n## Pruning study (what each pruning would have ranked, against this unpruned bank)\n\n"
                 + markdown_table(("after / keep", "same top-1", "same top five"), cells))
    return text


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", default=str(ROBUST_CONFIG))
    p.add_argument("--seeds", default="0:100", type=seed_range, help="FIRST:END")
    p.add_argument("--bank-size", type=int, default=1024)
    p.add_argument("--keep", type=int, default=5)
    p.add_argument("--prune-after-s", type=float, default=None,
                   help="run every member this many seconds, then only the best --prune-keep (default: no pruning)")
    p.add_argument("--prune-keep", type=int, default=64)
    p.add_argument("--prune-study", action="store_true",
                   help="unpruned runs: score every pruning of a small grid against the unpruned ranking")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--device", default="cpu", help="torch device of the filters (cpu, cuda); the bank's seconds are "
                   "that device's")
    p.add_argument("--out", default=str(ROOT / "experiments/results/global_start"), type=Path)
    p.add_argument("--runs", default=str(ROOT / "runs"), type=Path)
    args = p.parse_args(argv)
    try:
        cfg = load_config(args.config)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.prune_study and args.prune_after_s is not None:
        print("error: --prune-study scores prunings against an unpruned bank; leave out --prune-after-s",
              file=sys.stderr)
        return 2
    torch.set_num_threads(args.threads)
    model = trained_model(cfg, args.runs).to(args.device)
    command = command_line("global_start", sys.argv[1:] if argv is None else argv)
    start, rows = time.perf_counter(), []
    for seed in tqdm(args.seeds, desc="seeds", unit="seed"):
        record, _ = resume_case(args.runs / "global_start", case_key(args, cfg, seed),
                                functools.partial(seed_case, args.config, seed, model, args),
                                values={"experiment": "global_start"}, seeds=[seed], estimators=["bank"])
        rows.append(record.summary["row"])
    text = report(rows, args, command, time.perf_counter() - start)
    table = [{k: v for k, v in r.items() if k not in ("q0_true", "prune_study", "images")} for r in rows]
    write_outputs(args.out, {"summary.md": text, "summary.json": {"command": command, "rows": rows},
                             "per_seed.csv": csv_text(table)})
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
