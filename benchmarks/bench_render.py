"""Benchmark of the renderer on the paper's full training workload.

Workload (paper section 3.2): 19260 trajectories × 21 time steps, ρ grid of 5 values with 3852 trajectories
each, 472 facets: 19260 · 21 · 472 ≈ 1.9e8 nominal facet evaluations. Attitudes are random unit quaternions.
Two layouts:

* ``paired``: 19260 × 21 distinct attitudes, trajectory ``i`` rendered with its own ρ (``rho`` of shape (19260, 1));
* ``grid``:   3852 × 21 attitudes rendered with all 5 ρ at once (``rho`` of shape (5, 1, 1)) — how the training
  set is generated (``data.window_samples``): the ρ = 1 diffuse flux is computed once and scaled.

Each case (device × dtype × grouped/per-facet × layout) runs in its own subprocess; the table shows the median
of ``--repeats`` timed runs (after one warm-up), nominal facet evaluations per second, and peak memory
(CPU: the subprocess's maximum resident set size, including the Python/torch baseline shown in the last line;
CUDA: ``torch.cuda.max_memory_allocated``).

    python benchmarks/bench_render.py                 # full workload, 3 repeats
    python benchmarks/bench_render.py --quick         # 1/10 of the trajectories, 1 repeat, both layouts
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "boxwing.yaml"
N_TRAJ, N_STEPS, N_RHO = 19260, 21, 5


def run_case(device: str, dtype_name: str, grouped: bool, layout: str, n_traj: int, repeats: int,
             threads: int | None) -> dict:
    import torch

    from lightcurve_gp.config.load import load_config
    from lightcurve_gp.photometry.render import Scene

    if threads:
        torch.set_num_threads(threads)
    dtype = getattr(torch, dtype_name)
    cfg = load_config(CONFIG)
    scene = Scene.from_config(cfg, grouped=grouped, dtype=dtype, device=device)
    rho_grid = torch.tensor(cfg.data.rho_grid, dtype=dtype, device=device)
    gen = torch.Generator().manual_seed(0)
    per_rho = n_traj // len(rho_grid)
    if layout == "paired":
        q = torch.randn(n_traj, N_STEPS, 4, generator=gen, dtype=torch.float64)
        rho = rho_grid.repeat_interleave(per_rho).reshape(-1, 1)
    else:
        q = torch.randn(per_rho, N_STEPS, 4, generator=gen, dtype=torch.float64)
        rho = rho_grid.reshape(-1, 1, 1)
    q = (q / q.norm(dim=-1, keepdim=True)).to(device=device, dtype=dtype)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    sync = torch.cuda.synchronize if device.startswith("cuda") else (lambda: None)
    m = scene.magnitude(q, rho=rho)  # warm-up
    sync()
    if device.startswith("cuda"):
        torch.cuda.reset_peak_memory_stats()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        m = scene.magnitude(q, rho=rho)
        sync()
        times.append(time.perf_counter() - t0)
    assert m.numel() == n_traj // len(rho_grid) * len(rho_grid) * N_STEPS and bool(torch.isfinite(m).all())
    peak = (torch.cuda.max_memory_allocated() / 2**20 if device.startswith("cuda")
            else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
    return dict(seconds=statistics.median(times), peak_mib=peak, baseline_mib=rss0, threads=torch.get_num_threads(),
                outputs=m.numel())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per case (median reported)")
    parser.add_argument("--quick", action="store_true", help="1/10 of the trajectories and 1 repeat")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")
    parser.add_argument("--layouts", default="paired,grid", help="comma-separated: paired, grid")
    parser.add_argument("--no-cuda", action="store_true", help="skip CUDA cases even when available")
    parser.add_argument("--case", help=argparse.SUPPRESS)  # internal: run one case, print JSON
    args = parser.parse_args()
    n_traj = (N_TRAJ // 10 // N_RHO) * N_RHO if args.quick else N_TRAJ  # a multiple of the ρ count
    repeats = 1 if args.quick and args.repeats == 3 else args.repeats

    if args.case:
        device, dtype_name, grouped, layout = args.case.split(",")
        print(json.dumps(run_case(device, dtype_name, grouped == "grouped", layout, n_traj, repeats, args.threads)))
        return

    import torch

    devices = ["cpu"] + (["cuda"] if torch.cuda.is_available() and not args.no_cuda else [])
    print(f"cores: os.cpu_count() = {os.cpu_count()}, torch threads = {args.threads or torch.get_num_threads()}, "
          f"torch {torch.__version__}" + (f", GPU {torch.cuda.get_device_name()}" if "cuda" in devices else ""))
    print(f"workload: {n_traj} trajectories x {N_STEPS} steps x 472 facets = {n_traj * N_STEPS * 472:.3g} nominal "
          f"facet evaluations; median of {repeats} run(s)")
    header = f"{'device':6} {'dtype':8} {'path':9} {'layout':7} {'seconds':>9} {'facet-evals/s':>14} {'peak MiB':>9}"
    print(header)
    print("-" * len(header))
    baseline = None
    for device in devices:
        for dtype_name in ("float64", "float32"):
            for path in ("grouped", "per-facet"):
                for layout in args.layouts.split(","):
                    case = f"{device},{dtype_name},{path},{layout}"
                    cmd = [sys.executable, __file__, "--case", case, "--repeats", str(repeats)]
                    cmd += ["--quick"] if args.quick else []
                    cmd += ["--threads", str(args.threads)] if args.threads else []
                    env = dict(os.environ, PYTHONPATH=str(ROOT / "src") + os.pathsep + os.environ.get("PYTHONPATH", ""))
                    out = subprocess.run(cmd, capture_output=True, text=True, env=env)
                    if out.returncode != 0:
                        print(f"{device:6} {dtype_name:8} {path:9} {layout:7} FAILED: {out.stderr.strip()[-300:]}")
                        continue
                    r = json.loads(out.stdout.strip().splitlines()[-1])
                    if device == "cpu":
                        baseline = r["baseline_mib"]
                    rate = n_traj * N_STEPS * 472 / r["seconds"]
                    print(f"{device:6} {dtype_name:8} {path:9} {layout:7} {r['seconds']:9.3f} {rate:14.3g} "
                          f"{r['peak_mib']:9.0f}")
    if baseline is not None:
        print(f"(CPU peak includes the process baseline before rendering, ~{baseline:.0f} MiB with inputs)")


if __name__ == "__main__":
    main()
