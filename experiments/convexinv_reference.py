"""The field's reference program on the held-out synthetic convex objects: how often does convexinv find the pole?

A reference estimator for the synthetic goal of :mod:`experiments.convex_synthetic` (pole within 5° modulo the mirror
and period within ``0.5 P²/T`` on ≥ 90 % of objects). Each object's light curves (the same seeds, made by
:func:`experiments.convex_synthetic.random_observations`) are written as a DAMIT file and given to the DAMIT program
``convexinv`` (Kaasalainen & Ďurech; built from its published C source, ``--convexinv PATH``) with its example's
settings — convexity regularisation 0.1, spherical harmonics 6 × 6, 8 triangulation rows, Lommel–Seeliger +
0.1 Lambert and the phase function (0.5, 0.1, −0.5), all fixed at the values that made the data, so the scattering
law is exact — and ``--iterations`` Levenberg–Marquardt steps, from each of ``--poles`` starting poles (β ∈ ±20°,
±60°, four longitudes each: the usual grid of starts) with the **true period** as its start (free): convexinv is given
the period the blind search has to find. Its answer is the start of least χ², as convexinv's users choose. A start at
the true pole gives convexinv's own truth's basin.

Scored as the blind search is: right when the pole of least χ² is within 5° of the truth or its mirror and its period
within the resolution. Rows (one per object, resumable) in ``<out>/rows.jsonl``, the counts in ``summary.json``.

    python -m experiments.convexinv_reference --convexinv /path/to/convexinv --seed 2000 --objects 24 \\
        --out experiments/results/convex_synthetic/convexinv_2000
"""

from __future__ import annotations

import argparse
import json
import math
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from experiments.common import append_row, seed_rows
from experiments.convex_synthetic import Sampling, random_observations, separation_deg
from lightcurve_gp.files import write_json_atomic
from lightcurve_gp.observed.damit import write_damit

#: the starting poles (λ, β) in degrees: four longitudes at each of β = 60°, 20°, −20°, −60°
POLES = tuple((lam, beta) for beta in (60.0, 20.0, -20.0, -60.0) for lam in (0.0, 90.0, 180.0, 270.0))
ITERATION = re.compile(r"^\s*\d+\s+chi2\s+(\S+)\s+dev\s+(\S+)", re.MULTILINE)


def parameter_file(lam_deg: float, beta_deg: float, period_h: float, iterations: int) -> str:
    """convexinv's input parameters: the pole and period free from the given start, everything else its example's
    (module docstring)."""
    return (f"{lam_deg:.6f} 1\n{beta_deg:.6f} 1\n{period_h:.9f} 1\n0\n0\n0.1\n6 6\n8\n0.5 0\n0.1 0\n-0.5 0\n"
            f"0.1 0\n{iterations}\n")


def run_start(program: Path, lcs: Path, folder: Path, start: tuple[float, float], period_h: float,
              iterations: int) -> dict:
    """One convexinv run from the pole ``start`` (deg) and ``period_h``: its pole, period, χ² and rms."""
    tag = f"{start[0]:.0f}_{start[1]:.0f}"
    par, out, lc = folder / f"in_{tag}", folder / f"par_{tag}", folder / f"lc_{tag}"
    par.write_text(parameter_file(start[0], start[1], period_h, iterations))
    with lcs.open() as stdin:
        done = subprocess.run([str(program), "-v", "-p", str(out), str(par), str(lc)], stdin=stdin,
                              capture_output=True, text=True, timeout=600)
    steps = ITERATION.findall(done.stdout)
    if done.returncode != 0 or not steps or not out.exists():
        return {"start": start, "failed": done.stderr.strip()[-200:] or f"exit {done.returncode}"}
    lam, beta, period = (float(v) for v in out.read_text().split()[:3])
    return {"start": start, "lam_deg": lam % 360.0, "beta_deg": beta, "period_h": period,
            "chi2": float(steps[-1][0]), "rms": float(steps[-1][1])}


def pole_error(row: dict, truth: dict) -> float:
    """Angle (deg) from a solution's pole to the truth's or its mirror (λ + 180°, β), the smaller."""
    return min(separation_deg(row["lam_deg"], row["beta_deg"], truth["lam_deg"], truth["beta_deg"]),
               separation_deg(row["lam_deg"], row["beta_deg"], truth["lam_deg"] + 180.0, truth["beta_deg"]))


def object_row(program: Path, seed: int, iterations: int) -> dict:
    """One object: every start's solution, the best by χ², its score, and the start at the true pole."""
    obs, truth = random_observations(np.random.default_rng(seed), seed, Sampling())
    span_h = float(obs.t.max() - obs.t.min()) / 3600.0
    resolution = 0.5 * truth["period_h"] ** 2 / span_h
    tick = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        lcs = write_damit(obs, folder / "lcs")
        starts = [run_start(program, lcs, folder, p, truth["period_h"], iterations) for p in POLES]
        basin = run_start(program, lcs, folder, (truth["lam_deg"] % 360.0, truth["beta_deg"]), truth["period_h"],
                          iterations)
    seconds = time.perf_counter() - tick
    good = [s for s in starts if "chi2" in s]
    best = min(good, key=lambda s: s["chi2"])
    for s in good + ([basin] if "chi2" in basin else []):
        s["pole_error_deg"] = pole_error(s, truth)
        s["period_error_h"] = abs(s["period_h"] - truth["period_h"])
        s["ok"] = s["pole_error_deg"] < 5.0 and s["period_error_h"] < resolution
    row = {**truth, "resolution_h": resolution, "seconds": seconds, "starts": starts, "basin": basin,
           "best_ok": best["ok"], "any_start_ok": any(s["ok"] for s in good),
           "pole_error_deg": best["pole_error_deg"], "period_error_h": best["period_error_h"],
           "best_chi2": best["chi2"], "best_rms": best["rms"], "failed_starts": len(starts) - len(good)}
    if "chi2" in basin:
        row.update(basin_ok=basin["ok"], basin_chi2=basin["chi2"], basin_pole_error_deg=basin["pole_error_deg"],
                   basin_better=basin["chi2"] < best["chi2"])
    return row


def dnats(row: dict) -> float:
    """How much better convexinv's answer fits than its start at the truth, in nats at the known noise:
    ``(χ²_truth start − χ²_best) / (2 σ_I²)``, convexinv's χ² being the sum of squared residuals of intensities
    relative to each curve's mean and ``σ_I = σ_mag · ln 10 / 2.5`` (positive: the answer fits better)."""
    sigma = row["noise_mag"] * math.log(10.0) / 2.5
    return (row["basin_chi2"] - row["best_chi2"]) / (2.0 * sigma * sigma)


def summary(rows: list[dict]) -> dict:
    """The counts over the objects (module docstring); ``wrong_best_fits_better``: the objects whose answer is wrong
    and fits better than the start at the truth by more than a nat (``dnats``)."""
    with_basin = [r for r in rows if "basin_ok" in r]
    gain = {r["seed"]: dnats(r) for r in with_basin}
    return {"objects": len(rows), "best_ok": sum(r["best_ok"] for r in rows),
            "pole_ok": sum(r["pole_error_deg"] < 5.0 for r in rows),
            "period_ok": sum(r["period_error_h"] < r["resolution_h"] for r in rows),
            "any_start_ok": sum(r["any_start_ok"] for r in rows),
            "basin_ok": sum(r["basin_ok"] for r in with_basin),
            "truth_start_better_by_1_nat": sum(v < -1.0 for v in gain.values()),
            "within_1_nat": sum(abs(v) <= 1.0 for v in gain.values()),
            "best_better_by_1_nat": sum(v > 1.0 for v in gain.values()),
            "wrong_best_fits_better": sum(gain.get(r["seed"], 0.0) > 1.0 and not r["best_ok"] for r in rows),
            "median_dnats": float(np.median(list(gain.values()))) if gain else math.nan,
            "median_pole_error_deg": float(np.median([r["pole_error_deg"] for r in rows])),
            "median_seconds": float(np.median([r["seconds"] for r in rows]))}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--convexinv", type=Path, required=True, help="the convexinv program (built from its source)")
    parser.add_argument("--seed", type=int, default=2000)
    parser.add_argument("--objects", type=int, default=24)
    parser.add_argument("--iterations", type=int, default=50, help="convexinv's iteration stop condition")
    parser.add_argument("--out", type=Path, default=Path("experiments/results/convex_synthetic/convexinv_2000"))
    args = parser.parse_args(argv)
    if not args.convexinv.is_file():
        parser.error(f"--convexinv {args.convexinv}: no such program")
    args.out.mkdir(parents=True, exist_ok=True)
    rows_path = args.out / "rows.jsonl"
    done = {r["seed"] for r in seed_rows(rows_path)}
    for seed in range(args.seed, args.seed + args.objects):
        if seed in done:
            continue
        row = object_row(args.convexinv.resolve(), seed, args.iterations)
        append_row(rows_path, row)
        print(f"seed {seed}: pole error {row['pole_error_deg']:.1f} deg, period error {row['period_error_h']:.1e} h "
              f"(resolution {row['resolution_h']:.1e}), ok {row['best_ok']}; start at the truth: pole error "
              f"{row.get('basin_pole_error_deg', math.nan):.1f} deg, chi2 {row.get('basin_chi2', math.nan):.4g} "
              f"against the best {row['best_chi2']:.4g}; {row['seconds']:.0f} s", flush=True)
    rows = seed_rows(rows_path, range(args.seed, args.seed + args.objects))
    result = summary(rows)
    write_json_atomic(result, args.out / "summary.json")
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
