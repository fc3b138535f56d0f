"""The paper's USQUE variant against Crassidis & Markley's, on identical noise, with ω known and with ω estimated.

Variants (``filter.sigma_redraw`` × ``filter.q_placement``): the default propagates the sigma points of ``P⁺ + Q`` and
updates with them, adding ``Q`` again to ``P⁻`` (Crassidis & Markley 2003); the paper (Sec. 2.5) draws the sigma
points of ``P⁺``, adds ``Q`` once after the propagation and draws the update's sigma points again from
``(x̂⁻, P⁻)``; the two mixed variants complete the grid. Estimator: the matched-ρ UKF (ρ known) on the paper's
trajectory with ``Q = 1e-4`` per step, ``P0 = (10°)²`` — the setting an independent implementation of the paper's
variant was compared in — over ``--seeds`` noise seeds (default 200 from 0), once with ω known and once with ω in
the state (prior std and initial error 0.03 °/s per axis, as in experiments/spin_unknown.py). Nothing is tuned.
Writes ``--results`` (experiments/results/spin/variants.md, variants.json).

    python -m experiments.usque_variants --workers 2
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path
from typing import Sequence

import numpy as np

from experiments.common import (
    ROBUST_CONFIG,
    ROOT,
    SPIN_HEADER,
    case_overrides,
    seed_block,
    spin_table_row,
    sweep_arguments,
    write_outputs,
)
from lightcurve_gp.commands.common import apply_threads
from lightcurve_gp.config.load import apply_overrides, load_raw_config
from lightcurve_gp.evaluation.reporting import CaseRecord, markdown_table
from lightcurve_gp.sweep.executors import make_executor
from lightcurve_gp.sweep.runner import run_sweep

PAIR = ((False, "both"), (True, "after"))  # (sigma_redraw, q_placement): the default, the paper
AXES = [("filter.sigma_redraw", [False, True]), ("filter.q_placement", ["both", "after"])]
BASE = ["name=usque_variants", "filter.process_noise=1e-4"]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m experiments.usque_variants", description=__doc__.split("\n\n")[0])
    p.add_argument("--config", type=Path, default=ROBUST_CONFIG)
    p.add_argument("--seeds", type=int, default=200)
    p.add_argument("--seed-start", type=int, default=0)
    p.add_argument("--sigma", type=float, default=0.03, help="prior rate std and initial rate error, deg/s")
    p.add_argument("--out", type=Path, default=ROOT / "runs")
    p.add_argument("--results", type=Path, default=ROOT / "experiments/results/spin")
    sweep_arguments(p)
    return p


def label(values: dict) -> str:
    redraw, placement = values["filter.sigma_redraw"], values["filter.q_placement"]
    names = {(False, "both"): "Crassidis & Markley (default)", (True, "after"): "paper"}
    return names.get((redraw, placement), f"redraw {str(redraw).lower()}, Q {placement}")


def paired(default: CaseRecord, paper: CaseRecord) -> dict:
    """Seed-by-seed comparison on identical noise: seeds below 10° on all axes with one variant only (an exact
    two-sided McNemar test of the difference), and the median ratio of the total RMSE (paper / default)."""
    a, b = default.rmse_deg("matched_ukf"), paper.rmse_deg("matched_ukf")
    ok_a, ok_b = (a < 10).all(1), (b < 10).all(1)
    only_paper, only_default = int((ok_b & ~ok_a).sum()), int((ok_a & ~ok_b).sum())
    n, k = only_paper + only_default, min(only_paper, only_default)
    p_value = min(1.0, 2 * sum(math.comb(n, i) for i in range(k + 1)) / 2 ** n) if n else 1.0
    ratio = np.sqrt((b ** 2).sum(1)) / np.sqrt((a ** 2).sum(1))
    return {"below_10deg_only_paper": only_paper, "below_10deg_only_default": only_default,
            "mcnemar_p": p_value, "total_rmse_ratio_median": float(np.median(ratio)),
            "paper_lower_total_rmse_fraction": float((ratio < 1).mean())}


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    apply_threads(args.threads)
    start = time.perf_counter()
    raw = apply_overrides(load_raw_config(args.config), BASE)
    seeds = seed_block(args)
    lines, out = [], {}
    with make_executor(args.executor, workers=args.workers, address=args.scheduler) as ex:
        for sigma in (None, args.sigma):
            sweep_id = "variants_" + ("known" if sigma is None else f"sigma{sigma:g}")
            res = run_sweep(apply_overrides(raw, case_overrides(600.0, sigma)), AXES, seeds, out=args.out,
                            sweep_id=sweep_id, estimators=["matched_ukf"], workers=args.workers,
                            threads=args.threads, progress=not args.no_progress, executor=ex)
            rows = [spin_table_row(label(c.values), res.records[c.case_id], "matched_ukf") for c in res.cases]
            title = "ω known" if sigma is None else f"ω estimated, σ_ω = {sigma:g} °/s"
            lines += [f"\n#### Matched-ρ UKF, {title} ({args.seeds} seeds from {args.seed_start}; RMSE over "
                      "400-600 s, median [q25, q75])\n", markdown_table(SPIN_HEADER, rows).rstrip("\n")]
            out[sweep_id] = {label(c.values): res.records[c.case_id].summary for c in res.cases}
            by = {(c.values["filter.sigma_redraw"], c.values["filter.q_placement"]): res.records[c.case_id]
                  for c in res.cases}
            pair = paired(by[PAIR[0]], by[PAIR[1]])
            out[sweep_id]["paired"] = pair
            lines.append(f"\nPaper vs default on the same seeds: {pair['below_10deg_only_paper']} seeds below 10° "
                         f"only with the paper's variant, {pair['below_10deg_only_default']} only with the default "
                         f"(exact McNemar p = {pair['mcnemar_p']:.2g}); total RMSE paper / default: median "
                         f"{pair['total_rmse_ratio_median']:.3f}, lower on "
                         f"{100 * pair['paper_lower_total_rmse_fraction']:.0f} % of the seeds.")
    seconds = time.perf_counter() - start
    write_outputs(args.results, {"variants.md": "\n".join(lines) + "\n",
                                 "variants.json": {"seconds": seconds, "argv": sys.argv[1:], "summaries": out}})
    print("\n".join(lines) + f"\n\n{seconds:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
