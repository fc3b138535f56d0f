"""What the data allow the recommended estimator's NEES (issue 27): the whole-arc MAP's NEES beside the truth's own
likelihood-ratio statistic on the same seeds (:mod:`lightcurve_gp.evaluation.truth_reference`).

Per noise level σ (``scenario.noise_var = filter.measurement_noise = σ²``) and case: the recommended estimator's
whole-arc MAP (``map``: the surface-state filter, then the MAP of attitude and surface with every search stage, as
``estimate`` runs it), its NEES at the truth (against its reported attitude covariance; the same at every sample),
and the truth's statistic ``λ = 2 (c_prof(q_true) − c_min)``: the NEES of an estimator that always finds the global
minimum and reports the exact likelihood-ratio region. Every seed is sorted by where the estimate lies: the truth's
own basin (``same``), another basin the data favour (``other``) or a basin above the truth's (``miss``). Rows per
block of ``--report`` (the held-out block of the issue's table, 2000–2029, and the 120 seeds 2000–2119); the band is
the 95 % band of the mean of χ²(3) over the block's seeds. Each (σ, case) is one case of the case store
(``<runs>/nees_reference/cases``), so a killed run resumes. Writes ``--out`` (experiments/results/nees_reference/):
summary.md, seeds.csv.

    python -m experiments.nees_reference
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import torch

from experiments.common import ROOT, command_line, floats, seed_range, write_outputs
from lightcurve_gp.attitude.metrics import chi2_band
from lightcurve_gp.config.load import ConfigError, config_hash, load_config
from lightcurve_gp.evaluation.registry import map_solution
from lightcurve_gp.evaluation.reporting import csv_text, markdown_table
from lightcurve_gp.evaluation.truth_reference import KINDS, truth_reference
from lightcurve_gp.inference.arc_search import search_settings
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_scenario, simulate_truths
from lightcurve_gp.simulation.truths import draw_truths
from lightcurve_gp.sweep.store import resume_case

SIGMAS = "0.01,0.03,0.1,0.3,0.71"
HEADER = ("σ (mag)", "case", "seeds", "band of the mean", "map NEES mean / median", "map NEES in band",
          "truth's λ mean / median", "λ in band", "same / other / miss", "map NEES mean: same basin", "s")
SEED_COLUMNS = ("sigma", "case", "seed", "kind", "map_nees", "statistic", "basin_nees", "separation_deg",
                "estimate_cost", "basin_cost", "profile_cost")


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", default=str(ROOT / "configs" / "boxwing_realistic.yaml"))
    p.add_argument("--sigmas", default=SIGMAS, help=f"noise levels, mag (default {SIGMAS})")
    p.add_argument("--random-seeds", default="2000:2120", help="seeds of the random truths (default 2000:2120)")
    p.add_argument("--report", default="2000:2030,2000:2120",
                   help="blocks of the random seeds reported one row each (default 2000:2030,2000:2120)")
    p.add_argument("--paper-seeds", default="0:30", help="noise seeds of the paper case (default 0:30; '' for none)")
    p.add_argument("--out", type=Path, default=ROOT / "experiments" / "results" / "nees_reference")
    p.add_argument("--runs", type=Path, default=ROOT / "runs", help="case store root")
    p.add_argument("--threads", type=int, default=1)
    return p.parse_args(argv)


def one_case(cfg, scene: Scene, sc) -> dict[str, list]:
    """The recommended MAP and the truth's reference on every seed of ``sc``: per-seed columns (numbers, the kind an
    index into :data:`KINDS`)."""
    solution = map_solution(cfg, scene, sc.problem())
    ref = truth_reference(cfg, scene, sc, solution=solution, surface_known=False)
    columns = {"map_nees": ref.estimate_nees, "statistic": ref.statistic, "basin_nees": ref.basin_nees,
               "separation_deg": ref.separation_deg, "estimate_cost": ref.estimate_cost,
               "basin_cost": ref.basin_cost, "profile_cost": ref.profile_cost, "kind": ref.kind}
    return {k: v.tolist() for k, v in columns.items()}


def stored_case(cfg, case: str, seeds: range, scene: Scene, root: Path) -> tuple[dict[str, torch.Tensor], float]:
    """One (σ, case)'s per-seed columns, read back from the case store or run, and the seconds it took."""
    def compute():
        if case == "paper":
            sc = simulate_scenario(cfg, seeds=seeds, scene=scene)
        else:
            sc = simulate_truths(cfg, draw_truths(list(seeds)), scene)
        return one_case(cfg, scene, sc), []

    extra = {"study": "nees_reference", "case": case, "seeds": list(seeds),
             "search": search_settings(cfg.map, surface_known=False, noise_var=cfg.filter.measurement_noise)}
    case_id = config_hash(cfg, "geometry", "shape", "surface", "scenario", "filter", "evaluation", extra=extra)
    record, _ = resume_case(root, case_id, compute, values={"case": case, "noise_var": cfg.scenario.noise_var},
                            seeds=seeds, estimators=["map"])
    return {k: torch.tensor(v, dtype=torch.float64) for k, v in record.summary.items()}, record.seconds


def block_row(sigma: float, case: str, seeds: list[int], block: range, columns: dict[str, torch.Tensor],
              seconds: float) -> list[str]:
    """One row of :data:`HEADER`: the seeds of ``block`` among ``seeds``."""
    pick = torch.tensor([s in block for s in seeds])
    n = int(pick.sum())
    lo, hi = chi2_band(3, n)
    one_lo, one_hi = chi2_band(3, 1)
    nees, lam, kind = columns["map_nees"][pick], columns["statistic"][pick], columns["kind"][pick]
    same = nees[kind == 0]
    share = lambda v: f"{100 * float(((v > one_lo) & (v < one_hi)).float().mean()):.0f} %"  # noqa: E731
    counts = " / ".join(str(int((kind == i).sum())) for i in range(len(KINDS)))
    return [f"{sigma:g}", case, f"{block.start}–{block.stop - 1}" if case == "random" else f"{n}",
            f"[{lo:.2f}, {hi:.2f}]", f"{float(nees.mean()):.2f} / {float(nees.median()):.2f}", share(nees),
            f"{float(lam.mean()):.2f} / {float(lam.median()):.2f}", share(lam), counts,
            f"{float(same.mean()):.2f}" if same.numel() else "–", f"{seconds * n / len(seeds):.0f}"]


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    try:
        sigmas, random_seeds = floats(args.sigmas), seed_range(args.random_seeds)
        blocks = [seed_range(b) for b in args.report.split(",") if b.strip()]
        cases = {"random": random_seeds} | ({"paper": seed_range(args.paper_seeds)} if args.paper_seeds else {})
        base = load_config(args.config)
    except (ConfigError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    scene = Scene.from_config(base).to(dtype=base.torch_dtype)
    rows, seed_table, start = [], [], time.perf_counter()
    for sigma in sigmas:
        cfg = load_config(args.config, [f"scenario.noise_var={sigma ** 2!r}",
                                        f"filter.measurement_noise={sigma ** 2!r}"])
        for case, seeds in cases.items():
            columns, seconds = stored_case(cfg, case, seeds, scene, args.runs / "nees_reference")
            for block in (blocks if case == "random" else [seeds]):
                rows.append(block_row(sigma, case, list(seeds), block, columns, seconds))
            for i, seed in enumerate(seeds):
                seed_table.append({"sigma": sigma, "case": case, "seed": seed,
                                   **{k: (KINDS[int(v[i])] if k == "kind" else f"{float(v[i]):.6g}")
                                      for k, v in columns.items()}})
            print(f"σ = {sigma:g} {case}: {len(seeds)} seeds, {seconds:.0f} s", flush=True)
    note = (f"{command_line('nees_reference', argv)}; {time.perf_counter() - start:.0f} s this run (stored cases are "
            f"read back; the s column is each block's share of its case's time when it ran), {args.threads} torch "
            f"thread(s), load average {' / '.join(f'{v:.1f}' for v in os.getloadavg())} on {os.cpu_count()} cores. "
            "NEES and λ in band: the share of seeds inside the one-draw 95 % band of χ²(3); same / other / miss: "
            "the estimate in the truth's basin, in another basin of no higher cost, in a basin above the truth's "
            "(a search miss)")
    title = "# The recommended MAP's NEES beside the truth's likelihood ratio"
    text = f"{title}\n\n{note}\n\n{markdown_table(HEADER, rows)}\n"
    print(text)
    write_outputs(args.out, {"summary.md": text, "seeds.csv": csv_text(seed_table, SEED_COLUMNS)})
    return 0


if __name__ == "__main__":
    sys.exit(main())
