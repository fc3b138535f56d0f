"""Time of the default estimator on a light-curve file: ``estimate --light-curve FILE --initial-attitude=Q`` on a
600-sample file (the realistic config, 0.05 mag), beside its peer baseline in the same run (the surface-state
filter alone, which the default runs first), with one and two torch threads: the library call
(:func:`lightcurve_gp.observed.arc_run.estimate_arc`: reading excluded) and the whole command in this process
(reading, the run, the tables and two figures written). Median of ``--repeats``; the load average and the core count.
Issue 37's goal: a 600-sample file through the default estimator in ≤ 5 s on one thread.

    python benchmarks/bench_file.py --repeats 3
"""

from __future__ import annotations

import argparse
import math
import tempfile
from pathlib import Path

import torch
from common import Table, machine_info, machine_line, time_call

from lightcurve_gp.commands import estimate, simulate
from lightcurve_gp.config.load import load_config
from lightcurve_gp.filters.setup import run_surface_filter
from lightcurve_gp.observations.problem import problem_from_observations
from lightcurve_gp.observed.arc_run import estimate_arc, file_scene
from lightcurve_gp.observed.observations_file import read_observations
from lightcurve_gp.simulation.scenario import simulate_scenario

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "boxwing_realistic.yaml"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--seed", type=int, default=3)
    args = parser.parse_args()
    cfg = load_config(CONFIG)
    work = Path(tempfile.mkdtemp(prefix="bench_file_"))
    path = work / "obs.ecsv"
    assert simulate.main([str(CONFIG), "--out", str(path), "--seed", str(args.seed), "--no-progress"]) == 0
    q0 = simulate_scenario(cfg, [args.seed]).q_est0[0]
    omega0 = torch.deg2rad(torch.tensor(cfg.scenario.omega0_deg_s, dtype=torch.float64))
    sigma0 = math.radians(cfg.filter.p0_deg)
    obs = read_observations([path])
    scene = file_scene(cfg, obs)
    problem = problem_from_observations(obs, q_est0=q0, sigma0=sigma0, omega0=omega0,
                                        inertia=cfg.shape.inertia_kg_m2)
    quaternion = ",".join(f"{v:.12g}" for v in q0.tolist())
    command = [str(CONFIG), "--light-curve", str(path), f"--initial-attitude={quaternion}", "--out", str(work),
               "--force", "--no-progress"]
    table = Table(f"default estimator on a {len(obs)}-sample file (median of {args.repeats})",
                  ["threads", "surface filter alone (peer)", "estimate_arc (library)", "estimate command"])
    for threads in args.threads:
        torch.set_num_threads(threads)
        peer = time_call(lambda: run_surface_filter(cfg, scene, q_est0=problem.q_est0,
                                                    observations=problem.observations,
                                                    increments=problem.increments_assumed, sigma0=problem.sigma0,
                                                    R=problem.R), repeats=args.repeats, warmup=1)
        library = time_call(lambda: estimate_arc(cfg, obs, q0=q0, sigma0=sigma0, omega0=omega0),
                            repeats=args.repeats, warmup=1)
        whole = time_call(lambda: estimate.main([*command, "--threads", str(threads)]), repeats=args.repeats,
                          warmup=0)
        table.add([threads, *(f"{t['median']:.2f} s ({t['min']:.2f}-{t['max']:.2f})" for t in (peer, library, whole))])
    table.note(machine_line(machine_info()))
    table.print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
