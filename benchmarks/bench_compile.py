"""What the compiled filter step (``filter.compile: true``) costs and saves: the table that sets its default.

For the conventional UKF with the renderer (``Parametric``) and the GPUKF with the exact GP (mean only, the paper's
GPUKF; the GP conditioned on the 42-axis training grid, N = 1260, unless ``--full``: N = 19 260), paper scenario,
at each ``B`` of ``--batches``, one torch thread:

* compile: the first compiled run (2 steps) less two compiled steps, in a fresh process with an empty inductor cache
  (``TORCHINDUCTOR_CACHE_DIR``; cold) and in a second fresh process with that cache filled (warm); wall and CPU
  seconds (one compile thread: CPU of the process and of the compiler processes it waited for);
* eager and compiled step: median of ``--repeats`` runs of ``--steps`` steps, per step;
* break-even: the run length (steps) from which compiling pays, compile / (eager − compiled step), cold and warm;
  and the paper's 600-step run of ``B`` filters eager and compiled (warm compile included);
* peers at B = 1 in the cold process: a numpy GPUKF on the same GP and filterpy's UKF on the same renderer
  (``peers``), per step; and the largest difference between the eager and the compiled estimates.

Each case runs in child processes of this script (``--child``), so no compiled graph or in-memory cache carries
over from one case to the next.

    python benchmarks/bench_compile.py                       # renderer and exact GP at B = 1, 100
    python benchmarks/bench_compile.py --models renderer --batches 1 --repeats 3   # a rehearsal
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

import common as C

PAPER_STEPS = 600  # steps of the paper's run (600 s at 1 s)
LABELS = {"renderer": "UKF, renderer (Parametric)", "exact": "GPUKF, ExactGP mean"}


def parse_args(argv=None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", default="renderer,exact", help="comma-separated: renderer, exact")
    parser.add_argument("--batches", default="1,100", help="comma-separated B (default 1,100)")
    parser.add_argument("--steps", type=int, default=50, help="steps per timed run (default 50)")
    parser.add_argument("--repeats", type=int, default=7, help="timed runs per step time (median reported)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    parser.add_argument("--full", action="store_true", help="the exact GP on the paper's 19 260 training points "
                        "(trained into --cache-dir when missing: minutes, 6 GB)")
    parser.add_argument("--cache-dir", default=str(C.ROOT / "runs" / "bench"), help="trained-model cache")
    parser.add_argument("--out", help="also write the table to this file (.json: JSON, else markdown)")
    parser.add_argument("--child", help=argparse.SUPPRESS)  # JSON spec of one timed process (internal)
    return parser.parse_args(argv)


def cpu_seconds() -> float:
    """User + system CPU seconds of this process and of the child processes it has waited for."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def overrides(full: bool) -> list[str]:
    return C.quick_overrides(not full)


def build_case(spec: dict):
    """``(run(n_steps, compile_) -> FilterHistory, peer(n_steps) -> estimates | None)`` of ``spec``'s model and
    ``B`` filters (noise seeds cycling through 10)."""
    import dataclasses

    import torch
    from peers import UsqueSetup, filterpy_runner, numpy_runner

    from lightcurve_gp.filters.usque import UsqueParams, initial_covariance, run_usque
    from lightcurve_gp.observation.parametric import Parametric
    from lightcurve_gp.photometry.render import Scene
    from lightcurve_gp.simulation.scenario import simulate_scenario
    from lightcurve_gp.training.sets import load_or_generate

    cfg = C.load_cfg(overrides(spec["full"]))
    scene = Scene.from_config(cfg)
    sc = simulate_scenario(cfg, seeds=range(10), scene=scene)
    P0 = initial_covariance(cfg.filter.p0_deg, dtype=torch.float64)
    params = UsqueParams.from_config(cfg)
    if spec["model"] == "exact":
        data, _, _ = load_or_generate(cfg, C.ROOT / "runs" / "cache", progress=False)
        model, _, _ = C.cached_gp(cfg, data, "exact", cache_dir=spec["cache_dir"])
        params = dataclasses.replace(params, variance="none")
        peer = numpy_runner(UsqueSetup(params), model, sc, P0)
    else:
        model = Parametric(scene, cfg.filter.rho_assumed)
        peer = filterpy_runner(UsqueSetup(params), scene, cfg.filter.rho_assumed, sc, P0)
    B = spec["B"]
    obs = sc.observations[torch.arange(B) % sc.observations.shape[0]]

    def run(n: int, compile_: bool):
        return run_usque(model=model, q_est0=sc.q_est0[:1].expand(B, 4), P0=P0,
                         observations=obs[:, :n + 1], m_past0=obs[:, 0], increments=sc.increments[0, :n],
                         params=dataclasses.replace(params, compile=compile_))

    return run, (lambda n: peer(n, 0)) if B == 1 else None


def per_step(fn, steps: int, repeats: int) -> tuple[float, float]:
    """Median wall and median CPU seconds per step of ``repeats`` calls ``fn(steps)`` (the step runs on one thread:
    its CPU time is what it takes on a core of its own, whatever the machine's load)."""
    wall, cpu = [], []
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn(steps)
        wall.append((time.perf_counter() - t0) / steps)
        cpu.append((time.process_time() - c0) / steps)
    return statistics.median(wall), statistics.median(cpu)


def child(spec: dict) -> dict:
    """One timed process (module docstring): the compiled first run and step, with ``spec["eager"]`` also the eager
    step, the peer's step and the largest difference of the estimates."""
    C.set_threads(spec["threads"])
    run, peer = build_case(spec)
    steps, repeats, out = spec["steps"], spec["repeats"], {}
    if spec["eager"]:
        run(2, False)  # first-call allocations
        out["eager_s"], out["eager_cpu_s"] = per_step(lambda n: run(n, False), steps, repeats)
    t0, c0 = time.perf_counter(), cpu_seconds()
    run(2, True)
    out["first_wall_s"], out["first_cpu_s"] = time.perf_counter() - t0, cpu_seconds() - c0
    out["compiled_s"], out["compiled_cpu_s"] = per_step(lambda n: run(n, True), steps, repeats)
    if spec["eager"]:
        a, b = run(steps, False), run(steps, True)
        out["max_diff"] = float((a.q_est - b.q_est).abs().max())
        if peer is not None:
            peer(2)
            out["peer_s"], out["peer_cpu_s"] = per_step(peer, steps, max(1, repeats // 2))
    return out


def spawn(spec: dict, cache: str) -> dict:
    """:func:`child` of ``spec`` in a fresh process whose inductor cache is ``cache``."""
    # one compile thread: the compiler runs in this process and the ones it waits for (their CPU time is counted)
    env = {**os.environ, "TORCHINDUCTOR_CACHE_DIR": cache, "TORCHINDUCTOR_COMPILE_THREADS": "1"}
    done = subprocess.run([sys.executable, __file__, "--child", json.dumps(spec)], env=env, capture_output=True,
                          text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"child {spec} failed:\n{done.stderr[-4000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def measure(model: str, B: int, args: argparse.Namespace, scratch: str) -> dict:
    """The cold and the warm process of one case; compile seconds (wall and CPU) less the two compiled steps of the
    first run, compiled step times the median of both processes'."""
    spec = {"model": model, "B": B, "steps": args.steps, "repeats": args.repeats, "threads": args.threads,
            "full": args.full, "cache_dir": args.cache_dir}
    cache = tempfile.mkdtemp(prefix=f"inductor-{model}-{B}-", dir=scratch)
    cold = spawn({**spec, "eager": True}, cache)
    warm = spawn({**spec, "eager": False, "repeats": max(1, args.repeats // 2)}, cache)
    out = dict(cold)
    for unit in ("", "_cpu"):
        step = out[f"compiled{unit}_s"] = statistics.median([cold[f"compiled{unit}_s"], warm[f"compiled{unit}_s"]])
        out[f"cold{unit}_s"] = cold[f"first{'_cpu' if unit else '_wall'}_s"] - 2 * step
        out[f"warm{unit}_s"] = warm[f"first{'_cpu' if unit else '_wall'}_s"] - 2 * step
        saved = out[f"eager{unit}_s"] - step
        for k in ("cold", "warm"):
            out[f"break_even_{k}{unit}_steps"] = out[f"{k}{unit}_s"] / saved if saved > 0 else float("inf")
    return out


def row(model: str, B: int, m: dict) -> list:
    """The table's cells of one case: seconds as wall (CPU), break-even and speed-up by CPU time."""
    both = lambda k: f"{C.fmt_seconds(m[f'{k}_s'])} ({C.fmt_seconds(m[f'{k}_cpu_s'])})"  # noqa: E731
    steps = lambda s: "never" if s == float("inf") else f"{s:,.0f}"  # noqa: E731
    paper = {unit: (PAPER_STEPS * m[f"eager{unit}_s"], PAPER_STEPS * m[f"compiled{unit}_s"] + m[f"warm{unit}_s"])
             for unit in ("", "_cpu")}
    return [LABELS[model], B, both("cold"), both("warm"), both("eager"), both("compiled"),
            f"{m['eager_cpu_s'] / m['compiled_cpu_s']:.2g}x", steps(m["break_even_cold_cpu_steps"]),
            steps(m["break_even_warm_cpu_steps"]),
            " / ".join(f"{C.fmt_seconds(a)} ({C.fmt_seconds(b)})" for a, b in zip(paper[""], paper["_cpu"])),
            both("peer") if "peer_s" in m else "", f"{m['max_diff']:.1g}"]


def main() -> None:
    args = parse_args()
    if args.child:
        print(json.dumps(child(json.loads(args.child))))
        return
    C.set_threads(args.threads)
    info = C.machine_info("float64")
    print(f"{datetime.datetime.now().astimezone():%Y-%m-%d %H:%M %Z}; {C.machine_line(info)}", flush=True)
    models, batches = args.models.split(","), [int(b) for b in args.batches.split(",")]
    if "exact" in models:  # trained once here, loaded by every child
        from lightcurve_gp.training.sets import load_or_generate

        cfg = C.load_cfg(overrides(args.full))
        data, _, _ = load_or_generate(cfg, C.ROOT / "runs" / "cache", progress=False)
        C.cached_gp(cfg, data, "exact", cache_dir=args.cache_dir)
    n_train = "19 260" if args.full else "1260"
    table = C.Table(f"filter.compile: compile time, step time and break-even (one thread, paper scenario, float64; "
                    f"exact GP N = {n_train})",
                    ["filter", "B", "compile cold", "compile warm", "eager step", "compiled step", "speed-up",
                     "break-even cold (steps)", "break-even warm (steps)", "600-step run: eager / compiled + warm",
                     "peer step (B = 1)", "max Δq̂ eager vs compiled"])
    with tempfile.TemporaryDirectory(prefix="bench-compile-") as scratch:
        for model in models:
            for B in batches:
                print(f"  {LABELS[model]}, B = {B}: cold and warm processes ...", flush=True)
                m = measure(model, B, args, scratch)
                table.add(row(model, B, m), {"model": model, "B": B, **m})
    table.note("seconds as wall (CPU); speed-up and break-even (compile / (eager − compiled step)) by CPU time, "
               "which the machine's load does not inflate; compile: the first compiled run of 2 steps less 2 "
               "compiled steps, cold: empty inductor cache, warm: a second process on the filled cache (CPU includes "
               "the compiler processes)")
    table.note("peer: numpy GPUKF on the same GP (exact rows), filterpy UKF on the same renderer (renderer rows)")
    table.note(f"load average at the end {C.load_average()} (at the start: the first line)")
    table.print()
    if args.out:
        print(f"wrote {C.write_report(args.out, info, [table])}")


if __name__ == "__main__":
    main()
