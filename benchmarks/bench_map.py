"""Time of the whole-arc batch MAP (``map``: surface unknown, from the surface filter's result, 7 prior starts and 8
surface starts, 8 more below 0.1 mag, 8 more and the 8 best of 2048 screened prior attitudes and lobe settings for
the seeds that fail the misfit test, and 2 along each seed's weakest direction) on ``--seeds`` random truths of 600
samples at 1 Hz, σ = 0.05 mag, beside its peer baseline in the same run: the surface-state filter alone (which
``map`` runs first). Median of ``--repeats`` per torch thread count; wall and process CPU time, per run of all seeds
and per seed, with the load average and the core count (on a shared machine the wall time is the CPU time stretched
by the other processes). Issue 27's goal: ≤ 2 s per seed, 100 seeds ≤ 60 s on 2 cores.

    python benchmarks/bench_map.py --seeds 100 --repeats 3
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import torch

from lightcurve_gp.config.load import load_config
from lightcurve_gp.filters.setup import run_surface_filter
from lightcurve_gp.inference.arc_search import whole_arc_map
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_truths
from lightcurve_gp.simulation.truths import draw_truths

ROOT = Path(__file__).resolve().parents[1]


def filter_only(cfg, scene, sc):
    return run_surface_filter(cfg, scene, q_est0=sc.q_est0, observations=sc.observations,
                              increments=sc.increments_assumed, sigma0=sc.sigma0, geometry=sc.geometry)


def whole_arc(cfg, scene, sc, surface_known: bool, again: list[int]):
    """The whole-arc MAP; appends to ``again`` how many seeds the misfit test searched again."""
    solution = whole_arc_map(cfg, scene, sc.problem(), start=filter_only(cfg, scene, sc), surface_known=surface_known)
    again.append(0 if solution.searched_again is None else int(solution.searched_again.sum()))
    return solution


def measure(fn, repeats: int) -> tuple[float, float]:
    """Median wall and process CPU seconds of ``repeats`` calls (no warm-up: nothing here compiles; the first call's
    start-up is part of its time)."""
    walls, cpus = [], []
    for _ in range(repeats):
        wall, cpu = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - wall)
        cpus.append(time.process_time() - cpu)
    return statistics.median(walls), statistics.median(cpus)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    cfg = load_config(ROOT / "configs" / "boxwing_realistic.yaml")
    scene = Scene.from_config(cfg)
    sc = simulate_truths(cfg, draw_truths(list(range(2000, 2000 + args.seeds))), scene)
    again: list[int] = []
    runs = {"surface filter (peer baseline)": lambda: filter_only(cfg, scene, sc),
            "map (filter + whole-arc MAP, surface unknown, 24 starts, 8 more and 8 screened if the fit fails, "
            "2 probes)":
                lambda: whole_arc(cfg, scene, sc, False, again),
            "matched_map's MAP (filter + MAP, surface known, 16 starts, 2 probes)":
                lambda: whole_arc(cfg, scene, sc, True, [])}
    print(f"{args.seeds} random truths (seeds 2000-{1999 + args.seeds}), {sc.steps} samples each, sigma = "
          f"{cfg.scenario.noise_var ** 0.5:g} mag, float64, {os.cpu_count()} cores")
    print(f"| estimator | threads | wall s, all seeds (median of {args.repeats}) | CPU s | wall s per seed | "
          "load average |")
    print("|---|---|---|---|---|---|")
    for threads in args.threads:
        torch.set_num_threads(threads)
        for name, fn in runs.items():
            wall, cpu = measure(fn, args.repeats)
            print(f"| {name} | {threads} | {wall:.1f} | {cpu:.1f} | {wall / args.seeds:.2f} | "
                  f"{os.getloadavg()[0]:.1f} |", flush=True)
    print(f"seeds the misfit test searched again: {sorted(set(again))} of {args.seeds}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
