"""Where one filter's step goes: ``torch.profiler`` over a run of one GPUKF (B = 1, paper scenario).

Profiles ``--steps`` steps of ``run_usque`` with the ExactGP (N = 19 260, mean only: the paper's GPUKF) or, with
``--model parametric``, the conventional UKF; prints the wall and the process CPU time per step (medians of
``--repeats`` unprofiled runs; on a shared machine the CPU time leaves out the time spent waiting for a core), the
operators by self CPU time and the count of operator calls per step.

With ``--compile`` the filter runs with ``filter.compile: true`` (:mod:`lightcurve_gp.filters.compiled`); its first
run, which compiles, is timed apart and printed (``benchmarks/bench_compile.py`` tabulates compile time, step time
and the break-even run length).

With ``--floor`` (exact model) the same process then times, each alone, the three pieces of arithmetic the exact
GP's mean cannot avoid for the step's 7 sigma points against its N training points, in torch and in numpy: the
matrix product that gives the ``7 × N`` kernel exponents, their ``exp`` (into a preallocated buffer) and the
product with ``α`` (medians of ``--floor-repeats`` calls). Their sum is what the mean costs on the machine when each
operation runs alone; a fused loop saves the memory traffic of the ``7 × N`` arrays, not the exponentials.

    python benchmarks/profile_step.py
    python benchmarks/profile_step.py --compile
    python benchmarks/profile_step.py --model parametric --rows 25
    python benchmarks/profile_step.py --compile --floor
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import common as C


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--model", choices=("exact", "parametric"), default="exact")
    parser.add_argument("--steps", type=int, default=100, help="steps per run (default 100)")
    parser.add_argument("--repeats", type=int, default=7, help="unprofiled runs timed (median reported)")
    parser.add_argument("--rows", type=int, default=15, help="operators listed")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--compile", action="store_true", help="the compiled step (filter.compile: true); its "
                        "first run, which compiles, is timed apart")
    parser.add_argument("--floor", action="store_true", help="also time the exact GP mean's arithmetic alone "
                        "(exponent product, exp, product with alpha) in torch and numpy")
    parser.add_argument("--floor-repeats", type=int, default=301, help="calls per piece of --floor (median)")
    parser.add_argument("--cache-dir", default=str(C.ROOT / "runs" / "bench"), help="trained-model cache")
    return parser.parse_args()


def main() -> None:
    args = parse_args()

    import torch
    from torch.profiler import ProfilerActivity, profile

    from lightcurve_gp.filters.usque import UsqueParams, initial_covariance, run_usque
    from lightcurve_gp.observation.parametric import Parametric
    from lightcurve_gp.photometry.render import Scene
    from lightcurve_gp.simulation.scenario import simulate_scenario
    from lightcurve_gp.training.sets import load_or_generate

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
        return run_usque(model=model, q_est0=sc.q_est0[:1], P0=P0, observations=obs, m_past0=obs[:, 0],
                         increments=sc.increments[0, :args.steps], params=params)

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
    if args.floor and args.model == "exact":
        print_floor(model, data, per_step, repeats=args.floor_repeats)
    print(f"load average at the end {C.load_average()}")


def print_floor(model, data, per_step: float, *, repeats: int) -> None:
    """Time the exact GP mean's unavoidable arithmetic for 7 sigma-point-like inputs (module docstring) in torch
    and numpy and print it as a table next to the step's own time ``per_step`` (s)."""
    import numpy as np
    import torch

    from lightcurve_gp.observation.kernels import scaled

    q, m_past = C.sigma_like_inputs(data, 1, 7, seed=0)
    xs = scaled(model.inputs(q[0], m_past[0]), model.lengthscale)  # (7, d), the model's scaled inputs
    aug = torch.cat([xs, torch.ones_like(xs[:, :1]), (xs * xs).sum(-1, keepdim=True)], dim=-1)
    cache, alpha = model.xs_train_cache, model.alpha_scaled  # (d + 2, N), (N,)
    expo, buf = aug @ cache, torch.empty(aug.shape[0], cache.shape[1], dtype=cache.dtype)
    a_np, c_np, al_np = aug.numpy(), cache.numpy(), alpha.numpy()
    e_np, b_np = a_np @ c_np, np.empty_like(a_np @ c_np)
    pieces = {"kernel exponents (7 × (d+2)) @ ((d+2) × N)": (lambda: torch.mm(aug, cache, out=buf),
                                                           lambda: np.matmul(a_np, c_np, out=b_np)),
              "exp of the 7 × N exponents": (lambda: torch.exp(expo, out=buf), lambda: np.exp(e_np, out=b_np)),
              "(7 × N) @ α": (lambda: torch.mv(expo, alpha), lambda: e_np @ al_np)}
    table = C.Table(f"exact GP mean, 7 points against N = {cache.shape[1]} (d = {xs.shape[-1]}), float64, "
                    f"median of {repeats}", ["piece", "torch", "numpy"])
    total = [0.0, 0.0]
    for name, (fn_t, fn_n) in pieces.items():
        t, n = (C.time_call(f, repeats=repeats, warmup=5)["median"] for f in (fn_t, fn_n))
        total = [total[0] + t, total[1] + n]
        table.add([name, C.fmt_seconds(t), C.fmt_seconds(n)])
    table.add(["sum: the mean's floor", C.fmt_seconds(total[0]), C.fmt_seconds(total[1])])
    table.add(["the whole filter step above", C.fmt_seconds(per_step), ""])
    table.print()


if __name__ == "__main__":
    main()
