"""Filter settings of the generalisation suite's filters, compared on tuning seeds only (never the held-out block).

Each candidate is an estimator of the suite with config overrides (``name`` or ``name@key=value@key=value``); all
run on the same truths (``lightcurve_gp.simulation.truths``, the suite's random draws, or with ``--paper-rho`` the
paper's case
of the suite's paper block) of every block of ``--blocks`` seeds,
and the table gives, per block and pooled, the share of seeds below 10° on all axes over the scoring window, the
share whose time-averaged NEES lies in its single-run band, the median NEES and the median RMSE per axis. This is
how the unscented λ rule of the robust config was chosen (see experiments/README.md).

    python -m experiments.surface_filter_tuning --blocks 1000:1100,1100:1200,1200:1300 \\
        surface_ukf surface_ukf@filter.lam_rule=julier matched_ukf
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import torch

from experiments.common import (
    ROBUST_CONFIG,
    ROOT,
    SUITE_ESTIMATORS,
    registry_name,
    seed_range,
    trained_model,
    truth_draw,
)
from lightcurve_gp.config.load import ConfigError, load_config
from lightcurve_gp.evaluation.harness import run_estimators
from lightcurve_gp.evaluation.reporting import markdown_table
from lightcurve_gp.evaluation.scoring import nees_band
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_truths


def parse_candidate(text: str) -> tuple[str, list[str]]:
    """``"name@key=value@…"`` → ``(name, ["key=value", …])``; the name must be a filter or MAP of the suite."""
    name, *overrides = text.split("@")
    if name not in SUITE_ESTIMATORS:
        raise ConfigError(f"candidate {text!r}: unknown estimator {name!r}; choose from {', '.join(SUITE_ESTIMATORS)}")
    return name, overrides


def candidate_row(scored, band) -> dict[str, float]:
    """Shares and medians of one candidate on one block."""
    below = (scored.rmse_deg < 10).all(-1).double()
    inside = ((scored.nees_mean > band[0]) & (scored.nees_mean < band[1])).double()
    return {"n": below.numel(), "below10": float(below.sum()), "nees_in": float(inside.sum()),
            "nees": scored.nees_mean, "rmse": scored.rmse_deg}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("candidates", nargs="+", help="estimator[@key=value...] (config overrides of the candidate)")
    p.add_argument("--config", default=str(ROBUST_CONFIG))
    p.add_argument("--blocks", default="1000:1100", help="comma-separated FIRST:END seed ranges (tuning seeds)")
    p.add_argument("--paper-rho", type=float, default=None,
                   help="run the blocks on the paper's case with this true rho (the suite's paper block) instead of "
                        "random truths")
    p.add_argument("--runs", default=str(ROOT / "runs"), type=Path, help="where the trained GP is stored")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args(argv)
    try:
        base = load_config(args.config)
        candidates = [(text, *parse_candidate(text)) for text in args.candidates]
        configs = {text: load_config(args.config, overrides) for text, _, overrides in candidates}
        blocks = [seed_range(b) for b in args.blocks.split(",") if b.strip()]
    except (ConfigError, ValueError, argparse.ArgumentTypeError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    torch.set_num_threads(args.threads)
    scene = Scene.from_config(base).to(dtype=torch.float64)
    model = trained_model(base, args.runs) if any(n == "robust_gpukf" for _, n, _ in candidates) else None
    band, start = nees_band(), time.perf_counter()
    pooled = {text: [] for text, _, _ in candidates}
    cells = []
    for block in blocks:
        mode = None if args.paper_rho is None else ("paper", args.paper_rho)
        truths = simulate_truths(base, truth_draw(base, list(block), mode), scene)
        for text, name, _ in candidates:
            t0 = time.perf_counter()
            scored = run_estimators(configs[text], truths, estimators=[registry_name(name)], model=model,
                                    scene=scene).results[registry_name(name)]
            row = candidate_row(scored, band)
            pooled[text].append(row)
            cells.append(_cells(f"{block.start}-{block.stop - 1}", text, [row], time.perf_counter() - t0))
    for text, rows in pooled.items():
        cells.append(_cells("pooled", text, rows, None))
    print(markdown_table(("seeds", "candidate", "n", "< 10° all axes", "NEES in band", "median NEES",
                          "median RMSE y / p / r (deg)", "s"), cells))
    print(f"wall {time.perf_counter() - start:.0f} s, load average {os.getloadavg()[0]:.1f}, "
          f"{torch.get_num_threads()} thread(s)")
    return 0


def _cells(label: str, text: str, rows: list[dict], seconds: float | None) -> list:
    n = sum(r["n"] for r in rows)
    rmse = torch.cat([r["rmse"] for r in rows]).median(0).values
    nees_median = float(torch.cat([r["nees"] for r in rows]).median())
    return [label, f"`{text}`", n, f"{100 * sum(r['below10'] for r in rows) / n:.0f} %",
            f"{100 * sum(r['nees_in'] for r in rows) / n:.0f} %", f"{nees_median:.2f}",
            " / ".join(f"{v:.2f}" for v in rmse),
            "" if seconds is None else f"{seconds:.0f}"]


if __name__ == "__main__":
    sys.exit(main())
