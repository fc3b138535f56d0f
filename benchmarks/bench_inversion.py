"""Time of the global inversion per light curve: 600 samples at 1 Hz, the box-wing under the paper's fixed geometry,
``--starts`` starts, with 1 and 2 torch threads (median of ``--repeats``; wall and process CPU time, the load average
beside them: on a shared machine the wall time is the CPU time stretched by the other processes): the search alone
(``invert``) and the whole answer that ``python -m lightcurve_gp.invert`` gives (``answer``: the search, the families,
the fit test and the probes); and the rate profile that the answer runs for a slow top family
(``rate_profile``: 29 polishes with the rate held, here about the truth: its cost does not depend on the rate).

    python benchmarks/bench_inversion.py --starts 10000 --repeats 3
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time
from pathlib import Path

import torch

from lightcurve_gp.attitude.dynamics import propagate
from lightcurve_gp.attitude.rotations import quat_normalize
from lightcurve_gp.config.load import load_config
from lightcurve_gp.inference.answer import answer
from lightcurve_gp.inference.forward import GroupRenderer
from lightcurve_gp.inference.inversion import InversionSettings, invert
from lightcurve_gp.inference.rate_profile import rate_profile
from lightcurve_gp.inference.trajectory import TrajectoryProblem
from lightcurve_gp.photometry.ambiguity import ambiguity_group
from lightcurve_gp.photometry.render import Scene

ROOT = Path(__file__).resolve().parents[1]
#: the light curve's body rate (deg/s) and ρ
RATE_DEG_S = (0.9, -0.7, 1.1)
RHO = 0.5


def problem(sigma: float = 0.05):
    """The benchmark's light curve as a problem anchored at the true first attitude, its ambiguity group, and the
    true body rate ``(3,)`` (rad/s)."""
    cfg = load_config(ROOT / "configs" / "boxwing.yaml")
    scene = Scene.from_config(cfg)
    inertia = torch.tensor(cfg.shape.inertia_kg_m2, dtype=torch.float64)
    q0 = quat_normalize(torch.tensor([0.3, -0.2, 0.5, 0.78], dtype=torch.float64))
    w0 = torch.deg2rad(torch.tensor(RATE_DEG_S, dtype=torch.float64))
    q, _ = propagate(q0, w0, inertia, 1.0, 600)
    gen = torch.Generator().manual_seed(0)
    y = scene.magnitude(q, rho=RHO) + sigma * torch.randn(601, generator=gen, dtype=torch.float64)
    prob = TrajectoryProblem(GroupRenderer(scene), torch.arange(601, dtype=torch.float64), y, torch.full_like(y, sigma),
                             inertia, q0[None])
    group = ambiguity_group(scene, times_s=torch.arange(601.0), inertia=inertia, rate_known=False, probes=2)
    return prob, group, w0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--starts", type=int, default=10_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    prob, group, w0 = problem()
    print(f"| what | threads | starts | wall s (median of {args.repeats}) | CPU s | load average | cores |")
    print("|---|---|---|---|---|---|---|")
    runs = {"search (invert)": lambda s: invert(prob, group, settings=s),
            "whole answer (answer)": lambda s: answer(prob, group, settings=s),
            "rate profile (rate_profile, 29 points)": lambda s: rate_profile(
                prob, q0=prob.anchors[0], omega0=w0, log_rho=torch.tensor(math.log(RHO), dtype=torch.float64),
                span_s=600.0, rate_range_deg_s=s.rate_range_deg_s)}
    for threads in args.threads:
        torch.set_num_threads(threads)
        for what, run in runs.items():
            walls, cpus = [], []
            for _ in range(args.repeats):
                wall, cpu = time.perf_counter(), time.process_time()
                run(InversionSettings(starts=args.starts))
                walls.append(time.perf_counter() - wall)
                cpus.append(time.process_time() - cpu)
            print(f"| {what} | {threads} | {args.starts} | {statistics.median(walls):.1f} | "
                  f"{statistics.median(cpus):.1f} | {os.getloadavg()[0]:.1f} | {os.cpu_count()} |", flush=True)
    print("reference: 10^4 starts in 48 min = 2880 s on a laptop CPU (Robinson & Frueh 2025)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
