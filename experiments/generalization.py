"""Generalisation suite: every estimator on random truths (attitude, spin, surface, initial error per seed).

Seeds come in two blocks: the tuning block (default 1000-1099) may inform choices; the held-out block (default
2000-2299) is never used for one and gives the reported numbers; the paper block (``--blocks paper``, noise seeds
0-199, ``--paper-rho`` 0.7) is the paper's case: every seed the config's truth, the seeds differing by noise alone
(:func:`lightcurve_gp.simulation.truths.paper_case_draw`). ``--error-angles`` adds the initial-error table:
the same truths of ``--error-seeds`` (default 2000-2099) with a fixed initial-error angle (5, 10, 20, 30 deg, random
axis, P0 matched). Truths: :mod:`lightcurve_gp.simulation.truths` (simulated by
:func:`lightcurve_gp.simulation.scenario.simulate_truths`); estimators: :mod:`lightcurve_gp.evaluation.registry`
(``robust_gpukf`` in these tables is the registry's ``gpukf`` of the robust config, the offset in its state);
rows and summaries: :mod:`lightcurve_gp.evaluation.suite_summary`.

Resumable: seeds run in blocks of ``--block-size``; each (block, estimator) is one case of the sweep's case store
(:func:`lightcurve_gp.sweep.store.resume_case`), ``<runs>/generalization/cases/<case-id>.json``: a
:class:`~lightcurve_gp.evaluation.reporting.CaseRecord` whose rows hold the metrics and whose summary holds the
suite's per-seed rows. The id hashes what the estimator depends on, the seeds and the error mode (:func:`block_id`);
a record is written atomically when its case finishes, and a rerun skips stored cases, so a killed run continues and
a new candidate config reruns only what it changes (its GPUKF, for a new model). The GP comes from the model store
``<runs>/models/`` (trained there when missing).
Writes to ``--out`` (experiments/results/generalization/): summary.md/.csv (held-out and tuning blocks, per surface
class, |omega0| bin and initial-error bin), initial_error.md/.csv, bar charts of the share below 10 deg and of the
NEES-consistent share, RMSE box plots; per-seed rows go to ``<runs>/generalization/<config name>/per_seed.csv`` (and
``per_seed_initial_error.csv``). Each table is written only by a command that ran its blocks.

    python -m experiments.generalization --model-config configs/boxwing_robust.yaml
"""

from __future__ import annotations

import argparse
import functools
import sys
import time
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch
from matplotlib.figure import Figure
from tqdm.auto import tqdm

from experiments.common import (
    ROBUST_CONFIG,
    ROOT,
    SUITE_ESTIMATORS,
    command_line,
    registry_name,
    seed_range,
    trained_model,
    truth_draw,
    truth_mode_label,
    write_outputs,
)
from lightcurve_gp.config.load import ConfigError, config_hash, config_to_dict, load_config
from lightcurve_gp.evaluation.harness import run_estimators
from lightcurve_gp.evaluation.plots import rmse_boxplot, save_figure
from lightcurve_gp.evaluation.reporting import SeedRow, csv_text, markdown_table
from lightcurve_gp.evaluation.scoring import nees_band
from lightcurve_gp.evaluation.suite_summary import SUMMARY_COLUMNS, suite_rows, summarize, whitened_correlation
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import Scenario, simulate_truths
from lightcurve_gp.sweep.store import resume_case
from lightcurve_gp.training.store import model_key

SUITE_FORMAT = 1


def suite_estimator_rows(cfg, truths: Scenario, name: str, *, model, scene, map_every: float,
                         error_mode: str) -> list[dict[str, Any]]:
    """The suite's per-seed rows of estimator ``name`` (a table name) on the drawn truths."""
    result = run_estimators(cfg, truths, estimators=[registry_name(name)], model=model, scene=scene,
                            map_every_s=map_every)
    return [{**row, "estimator": name} for row in suite_rows(result, nees_band(), error_mode=error_mode)]


def block_id(cfg, seeds: Sequence[int], error_deg, estimator: str, map_every: float) -> str:
    """Content hash of one (block, estimator) case: what the estimator's result depends on, the seeds, the truth
    mode ``error_deg`` (``None``, a fixed initial-error angle, or ``("paper", rho)``).

    Only the robust GPUKF depends on the trained model (``data`` and ``model`` sections); the other estimators use
    ``model.rho_reference`` alone from those, so a new candidate config with the same scenario, surface and filter
    tuning reuses their stored blocks and runs its GPUKF only.
    """
    sections = [k for k in config_to_dict(cfg) if k != "name" and (estimator == "robust_gpukf"
                                                                   or k not in ("data", "model"))]
    return config_hash(cfg, *sections, extra={
        "suite": "generalization", "format": SUITE_FORMAT, "seeds": list(seeds),
        "error_deg": list(error_deg) if isinstance(error_deg, tuple) else error_deg,
        "estimator": estimator, "map_every_s": map_every if estimator.startswith("map_") else None,
        "model": model_key(cfg) if estimator == "robust_gpukf" else cfg.model.rho_reference})


def estimator_case(cfg, truths: Callable[[], Scenario], name: str, *, model, scene, map_every: float,
                   error_deg) -> tuple[dict[str, Any], list[SeedRow]]:
    """One (block, estimator) case for the store: the suite's per-seed rows (truth descriptors, classes, bins,
    whitened errors) under ``summary["per_seed"]``, and their :class:`SeedRow` metrics. ``truths()`` gives the
    block's truths (simulated once per block)."""
    start = time.perf_counter()
    sc = truths()
    rows = suite_estimator_rows(cfg, sc, name, model=model, scene=scene, map_every=map_every,
                                error_mode=truth_mode_label(error_deg))
    seconds = time.perf_counter() - start
    metrics = [SeedRow(r["seed"], name, r["rmse_yaw_deg"], r["rmse_pitch_deg"], r["rmse_roll_deg"],
                       nees_mean=r["nees_mean"], seconds_per_step=seconds / sc.steps) for r in rows]
    return {"per_seed": rows}, metrics


def run_block(cfg, model, scene, seeds: Sequence[int], error_deg, estimators: Sequence[str],
              map_every: float, root: Path) -> tuple[list[dict[str, Any]], int]:
    """Rows of one block of seeds, each estimator read back from the case store of ``root`` or run and stored
    there; also the number of estimators that ran."""
    truths = functools.cache(lambda: simulate_truths(cfg, truth_draw(cfg, seeds, error_deg), scene))
    values = {"suite": "generalization",
              "error_deg": truth_mode_label(error_deg) if isinstance(error_deg, tuple) else error_deg}
    rows, ran = [], 0
    for name in estimators:
        compute = functools.partial(estimator_case, cfg, truths, name, model=model, scene=scene,
                                    map_every=map_every, error_deg=error_deg)
        record, now = resume_case(root, block_id(cfg, seeds, error_deg, name, map_every), compute, values=values,
                                  seeds=seeds, estimators=[name])
        rows += record.summary["per_seed"]
        ran += now
    return rows, ran


def run_blocks(cfg, model, scene, seeds: range, error_deg, estimators, args, label: str):
    """All blocks of ``seeds`` for one error mode; returns the rows, the summed estimator seconds (as stored) and
    the number of (block, estimator) cases run and read back."""
    blocks = [seeds[i:i + args.block_size] for i in range(0, len(seeds), args.block_size)]
    rows, ran = [], 0
    for block in tqdm(blocks, desc=label, unit="block"):
        block_rows, block_ran = run_block(cfg, model, scene, block, error_deg, estimators, args.map_every,
                                          args.runs / "generalization")
        rows += [{**row, "block": label} for row in block_rows]
        ran += block_ran
    seconds = {}
    for row in rows:
        if row["seed"] in {b[0] for b in blocks}:  # one row per block and estimator carries the batch time
            seconds[row["estimator"]] = seconds.get(row["estimator"], 0.0) + row["seconds_batch"]
    return rows, seconds, (ran, len(blocks) * len(estimators))


# ------------------------------------------------------------------------------------------------ tables

TABLE_HEADER = ("seeds", "< 10 deg all axes", "yaw", "pitch", "roll", "RMSE / CRB", "NEES in band", "mean NEES",
                "median NEES")


def _ratio(e: dict[str, Any]) -> str:
    """The median RMSE over the median bound per axis, "–" for rows stored before the bound was computed."""
    values = [e.get(f"rmse_over_crb_{a}", float("nan")) for a in ("yaw", "pitch", "roll")]
    return "–" if not all(np.isfinite(values)) else " / ".join(f"{v:.1f}" for v in values)


def summary_table(summary: Sequence[dict[str, Any]], first: str) -> str:
    """The summary entries as one Markdown table led by the columns ``first`` (``"group"``) and ``"estimator"``."""
    cells = [[e[first], e["estimator"], e["seeds"], f"{100 * e['share_below_10deg']:.0f} %",
              *(f"{e[k]:.2f}" for k in ("rmse_yaw_median", "rmse_pitch_median", "rmse_roll_median")), _ratio(e),
              f"{100 * e['share_nees_in_band']:.0f} %", f"{e['nees_mean']:.3g}", f"{e['nees_median']:.3g}"]
             for e in summary]
    return markdown_table((first, "estimator", *TABLE_HEADER), cells).rstrip("\n")


def block_report(rows, seconds: dict[str, float], title: str) -> tuple[list[str], list[dict[str, Any]]]:
    """Markdown section (per grouping one table) and the summary entries of one block of rows."""
    summary = summarize(rows)
    lines = [f"\n## {title}\n", "Wall time of the batched runs (s): "
             + ", ".join(f"{n} {s:.0f}" for n, s in seconds.items()) + ".",
             "\nSpearman correlation of the whitened attitude error at the window's first and last scored sample "
             "(pooled over seeds and axes): "
             + ", ".join(f"{n} {whitened_correlation(rows, n):.2f}" for n in seconds if n != "no_update") + "."]
    for grouping in dict.fromkeys(e["grouping"] for e in summary):
        lines += [f"\n### by {grouping}\n", summary_table([e for e in summary if e["grouping"] == grouping], "group")]
    return lines, summary


# ------------------------------------------------------------------------------------------------ figures

def bar_chart(summary: Sequence[dict[str, Any]], metric: str, ylabel: str, path: Path, title: str) -> Path:
    """One panel per grouping: bars of ``metric`` per group, one bar per estimator."""
    groupings = [g for g in dict.fromkeys(e["grouping"] for e in summary)]
    estimators = list(dict.fromkeys(e["estimator"] for e in summary))
    fig = Figure(figsize=(3.6 * len(groupings), 3.8), layout="constrained")
    axes = fig.subplots(1, len(groupings), sharey=True, squeeze=False)
    width = 0.8 / len(estimators)
    for ax, grouping in zip(axes[0], groupings):
        entries = [e for e in summary if e["grouping"] == grouping]
        groups = list(dict.fromkeys(e["group"] for e in entries))
        for j, name in enumerate(estimators):
            values = {e["group"]: e[metric] for e in entries if e["estimator"] == name}
            ax.bar(np.arange(len(groups)) + (j - (len(estimators) - 1) / 2) * width,
                   [100 * values.get(g, np.nan) for g in groups], width, label=name)
        ax.set_xticks(range(len(groups)), groups, fontsize=8)
        ax.set_title(grouping, fontsize=9)
    axes[0][0].set_ylabel(ylabel)
    fig.legend(*axes[0][0].get_legend_handles_labels(), loc="outside lower center", ncols=len(estimators),
               frameon=False, fontsize=8)
    fig.suptitle(title)
    return save_figure(fig, path)


def write_figures(rows, summary, out: Path, label: str) -> None:
    bar_chart(summary, "share_below_10deg", "seeds below 10 deg [%]", out / f"below10_{label}.png",
              f"share below 10 deg on all axes ({label} seeds)")
    bar_chart(summary, "share_nees_in_band", "NEES in its band [%]", out / f"nees_consistent_{label}.png",
              f"share of seeds with time-averaged NEES in its single-run band ({label} seeds)")
    names = list(dict.fromkeys(r["estimator"] for r in rows))
    rmse = {n: np.array([[r[k] if r[k] is not None else np.nan for k in ("rmse_yaw_deg", "rmse_pitch_deg",
                                                                          "rmse_roll_deg")]
                         for r in rows if r["estimator"] == n]) for n in names}
    rmse_boxplot(rmse, out / f"rmse_boxplot_{label}.png", title=f"RMSE over 400-600 s ({label} seeds)")


# ------------------------------------------------------------------------------------------------ main

def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model-config", default=str(ROBUST_CONFIG),
                   help="the robust config to evaluate (its model is trained into <runs>/models/ when missing)")
    p.add_argument("--tuning-seeds", default="1000:1100", type=seed_range, help="FIRST:END (choices allowed)")
    p.add_argument("--heldout-seeds", default="2000:2300", type=seed_range, help="FIRST:END (never for choices)")
    p.add_argument("--blocks", default="tuning,heldout", help="which of tuning,heldout,paper to run ('' for none)")
    p.add_argument("--paper-seeds", default="0:200", type=seed_range, help="noise seeds of the paper block")
    p.add_argument("--paper-rho", default=0.7, type=float, help="the true reflectance of the paper block")
    p.add_argument("--error-angles", default="", help="fixed initial-error angles (deg), e.g. 5,10,20,30")
    p.add_argument("--error-seeds", default="2000:2100", type=seed_range, help="seeds of the initial-error table")
    p.add_argument("--estimators", default=",".join(SUITE_ESTIMATORS))
    p.add_argument("--error-estimators", default="robust_gpukf,matched_ukf,joint_ukf,map_surface,no_update")
    p.add_argument("--block-size", type=int, default=50)
    p.add_argument("--map-every", type=float, default=50.0, help="MAP checkpoint spacing in the window (s)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    p.add_argument("--out", default=str(ROOT / "experiments/results/generalization"), type=Path)
    p.add_argument("--runs", default=str(ROOT / "runs"), type=Path, help="trained models and the result store")
    return p


def _names(text: str) -> list[str]:
    names = [e.strip() for e in text.split(",") if e.strip()]
    unknown = [e for e in names if e not in SUITE_ESTIMATORS]
    if unknown:
        raise ConfigError(f"--estimators: unknown estimator {unknown[0]!r}; choose from {', '.join(SUITE_ESTIMATORS)}")
    return names


def checked(args) -> tuple[Any, list[str], list[str], list[str], list[float]]:
    """The config, the estimators, the initial-error table's estimators, the blocks and the angles; a
    :class:`ConfigError` naming the option when one is wrong."""
    cfg = load_config(args.model_config)
    estimators, error_estimators = _names(args.estimators), _names(args.error_estimators)
    angles = [float(a) for a in args.error_angles.split(",") if a.strip()]
    blocks = [b.strip() for b in args.blocks.split(",") if b.strip()]
    if any(b not in ("tuning", "heldout", "paper") for b in blocks) or not (blocks or angles):
        raise ConfigError(f"--blocks: {args.blocks!r} must name tuning, heldout and/or paper (or give "
                          "--error-angles)")
    if "robust_gpukf" in estimators + error_estimators and not cfg.filter.estimate_offset:
        raise ConfigError(f"{args.model_config}: filter.estimate_offset: robust_gpukf needs the offset state "
                          f"(true)")
    return cfg, estimators, error_estimators, blocks, angles


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        cfg, estimators, error_estimators, blocks, angles = checked(args)
    except (ConfigError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    torch.set_num_threads(args.threads)
    start = time.perf_counter()
    needs_model = ("robust_gpukf" in estimators and blocks) or ("robust_gpukf" in error_estimators and angles)
    model = trained_model(cfg, args.runs) if needs_model else None
    scene = Scene.from_config(cfg).to(dtype=torch.float64)
    command = command_line("generalization", sys.argv[1:] if argv is None else argv)
    report, all_rows, all_summary, counts = suite_tables(cfg, model, scene, blocks, estimators, args, command)
    error_summary, error_rows = [], []
    for angle in angles:
        rows, _, count = run_blocks(cfg, model, scene, args.error_seeds, angle, error_estimators, args,
                                    f"error {angle:g}")
        counts = [a + b for a, b in zip(counts, count)]
        error_rows += rows
        error_summary += [{"initial_error_deg": angle, **e} for e in summarize(rows, {"all": None})]
    wall = time.perf_counter() - start
    report.append(f"\nWall time of this command: {wall:.0f} s; it ran {counts[0]} of {counts[1]} (block, estimator) "
                  "cases and read the others back from the store (the batch times above are those of the runs).")
    if blocks:
        write_outputs(args.out, {"summary.md": "\n".join(report) + "\n",
                                 "summary.csv": csv_text(all_summary, ("block", *SUMMARY_COLUMNS)),
                                 "summary.json": {"command": command, "wall_seconds": wall, "summary": all_summary}})
        print("\n".join(report))
    if error_summary:
        write_error_table(error_summary, args, command, report[-1].strip())
    for rows, name in ((all_rows, "per_seed.csv"), (error_rows, "per_seed_initial_error.csv")):
        if rows:
            columns = [k for k in rows[0] if k not in ("white_first", "white_last")]
            write_outputs(args.runs / "generalization" / cfg.name, {name: csv_text(rows, columns)})
    return 0


def suite_tables(cfg, model, scene, blocks: Sequence[str], estimators, args, command: str):
    """The report's lines, every row and the summary entries of the suite's blocks (their figures written), and
    the numbers of (block, estimator) cases run and in all."""
    band = nees_band()
    report = [f"# Generalisation suite: {cfg.name}\n",
              f"Command: `{command}`. Median RMSE in deg "
              f"over {cfg.evaluation.rmse_window_s[0]:g}-{cfg.evaluation.rmse_window_s[1]:g} s (MAP: its checkpoints "
              f"every {args.map_every:g} s there); NEES band of one chi-square(3) sample {band[0]:.2f}-{band[1]:.2f}."]
    all_rows, all_summary, counts = [], [], [0, 0]
    for label in blocks:
        seeds = {"heldout": args.heldout_seeds, "tuning": args.tuning_seeds, "paper": args.paper_seeds}[label]
        mode = ("paper", args.paper_rho) if label == "paper" else None
        rows, seconds, count = run_blocks(cfg, model, scene, seeds, mode, estimators, args, label)
        counts = [a + b for a, b in zip(counts, count)]
        title = f"{label} seeds {seeds.start}-{seeds.stop - 1}" + (f", rho {args.paper_rho:g}" if mode else "")
        lines, summary = block_report(rows, seconds, title)
        report += lines
        all_rows += rows
        all_summary += [{"block": label, **e} for e in summary]
        write_figures(rows, summary, args.out, label)
    return report, all_rows, all_summary, counts


def write_error_table(error_summary, args, command: str, timing: str) -> None:
    seeds = args.error_seeds
    lines = [f"# Accuracy against the initial error ({len(seeds)} seeds {seeds.start}-{seeds.stop - 1}, the same "
             "truths at every angle, random axis, P0 = (angle / sqrt 3)^2 I)\n",
             f"Command: `{command}`. {timing} Median RMSE in deg; NEES band of one chi-square(3) sample.\n",
             summary_table([{**e, "group": f"{e['initial_error_deg']:g} deg"} for e in error_summary], "group")]
    write_outputs(args.out, {"initial_error.md": "\n".join(lines) + "\n",
                             "initial_error.csv": csv_text(error_summary, ("initial_error_deg", *SUMMARY_COLUMNS))})
    print("\n".join(lines))


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
