"""Where one filter's step goes: ``torch.profiler`` over a run of one GPUKF (B = 1, paper scenario).

Profiles ``--steps`` steps of ``run_usque`` with the ExactGP (N = 19 260, mean only: the paper's GPUKF) or, with
``--model parametric``, the conventional UKF; prints the wall and the process CPU time per step (medians of
``--repeats`` unprofiled runs; on a shared machine the CPU time leaves out the time spent waiting for a core), the
operators by self CPU time and the count of operator calls per step.

With ``--compile`` the filter runs with ``filter.compile: true`` (:mod:`lightcurve_gp.usque_compiled`); its first
run, which compiles, is timed apart and printed.

    python benchmarks/profile_step.py
    python benchmarks/profile_step.py --compile
    python benchmarks/profile_step.py --model parametric --rows 25
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import _common as C


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", choices=("exact", "parametric"), default="exact")
    parser.add_argument("--steps", type=int, default=100, help="steps per run (default 100)")
    parser.add_argument("--repeats", type=int, default=7, help="unprofiled runs timed (median reported)")
    parser.add_argument("--rows", type=int, default=15, help="operators listed")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--compile", action="store_true", help="the compiled step (filter.compile: true); its "
                        "first run, which compiles, is timed apart")
    parser.add_argument("--cache-dir", default=str(C.ROOT / "runs" / "bench"), help="trained-model cache")
    return parser.parse_args()


def main() -> None:
    args = parse_args()

    import torch
    from torch.profiler import ProfilerActivity, profile

    from lightcurve_gp.data import load_or_generate
    from lightcurve_gp.observation.parametric import Parametric
    from lightcurve_gp.render import Scene
    from lightcurve_gp.scenario import simulate_scenario
    from lightcurve_gp.ukf import UsqueParams, initial_covariance, run_usque

    C.set_threads(args.threads)
    cfg = C.load_cfg()
    info = C.machine_info(cfg.torch_dtype, cfg.device)
    print(C.machine_line(info), flush=True)
    scene = Scene.from_config(cfg)
    params = dataclasses.replace(UsqueParams.from_config(cfg), compile=args.compile)
    if args.model == "exact":
        data, _, _ = load_or_generate(cfg, C.ROOT / "runs" / "cache", progress=False)
        model, _, _ = C.cached_gp(cfg, data, "exact", cache_dir=args.cache_dir)
        params = dataclasses.replace(params, variance="none")
    else:
        model = Parametric(scene, cfg.filter.rho_assumed)
    sc = simulate_scenario(cfg, seeds=[0], scene=scene)
    P0 = initial_covariance(cfg.filter.p0_deg, dtype=torch.float64)
    obs = sc.observations[:, :args.steps + 1]

    def run():
        return run_usque(model=model, q_est0=sc.q_est0.reshape(1, 4), P0=P0, observations=obs, m_past0=obs[:, 0],
                         increments=sc.increments[:args.steps], params=params)

    first = time.perf_counter()
    run()
    first = time.perf_counter() - first
    wall, cpu = [], []
    for _ in range(args.repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        run()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    per_step, cpu_step = statistics.median(wall) / args.steps, statistics.median(cpu) / args.steps
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        run()
    events = prof.key_averages()
    calls = sum(e.count for e in events if not e.key.startswith(("aten::empty", "aten::as_strided")))
    print(f"first run (warm-up{', compiling' if args.compile else ''}): {C.fmt_seconds(first)}")
    name = f"{args.model}{', compiled' if args.compile else ''}"
    print(f"{name}, B = 1: {C.fmt_seconds(per_step)} wall, {C.fmt_seconds(cpu_step)} CPU per step (medians "
          f"of {args.repeats} runs of {args.steps} steps, unprofiled); {calls / args.steps:.0f} operator calls per "
          "step (profiled run)")
    print(events.table(sort_by="self_cpu_time_total", row_limit=args.rows))
    print(f"load average at the end {C.load_average()}")


if __name__ == "__main__":
    main()
