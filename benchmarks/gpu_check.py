"""GPU check: the CUDA tests and the batch workloads on a CUDA device, each next to the CPU of the same run.

Sections, in order of importance (a global ``--time-budget-s`` skips what is left, as "skipped: budget"):

1. **CUDA tests** — the tests that skip without CUDA, in a pytest process of their own (``benchmarks/cuda_tests.py``),
   with each test's peak CUDA memory as evidence that it ran on the GPU.
2. **filter** — filter steps per second of ``B`` = 10³, 10⁴, 10⁵ USQUE filters (``run_usque``, 7 sigma points each,
   the paper's scenario) with the sparse GP (M = 512, with and without its variance) and the exact GP (mean only,
   the paper's GPUKF); the CPU at the two smaller ``B`` only ("not measured" at 10⁵). Aim: ≥ 10⁶ filter-steps/s
   with the sparse GP on one H100-class GPU.
3. **conditioning** — the exact GP on the paper's N = 19 260 training points: ``ExactGP.from_data`` (float64), and
   the same algebra in float32 (the library conditions in float64 only).
4. **render** — the paper's training-set workload: generation (propagate + render + window) and rendering alone.
5. **sparse fit** — ``SparseGP.from_data`` with M = 512.

Each case's failure is recorded in its row and the run goes on. ``DIR/gpu_check.md`` (card, versions, cores, table)
and ``DIR/gpu_check.csv`` are rewritten after every row; ``DIR/cuda_tests.log`` holds the pytest output. Device
timings: median of ``--repeats`` after one warm-up, ``torch.cuda.synchronize()`` around each; the CPU runs the same
code with torch's default thread count. The training set is generated once per run, in memory.

    python benchmarks/gpu_check.py --out runs/gpu_check                          # CUDA, the paper's sizes
    python benchmarks/gpu_check.py --out runs/gpu_check_cpu --device cpu --quick  # a CPU-only rehearsal, ~1 min

Exit code 0 when every case ran or was skipped for time, 1 when a case or a CUDA test failed, 2 on bad arguments.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import signal
import sys
import time
import traceback
import warnings
from pathlib import Path

import common as C
import torch
from gpu_context import Context, Skip, first_line, median_time
from gpu_report import (
    Budget,
    Report,
    Row,
    footer_lines,
    machine_header,
    workload_lines,
)
from gpu_setup import check_args, memory_cap, parse_args

AIM_FILTER_STEPS_PER_S = 1e6

# ----------------------------------------------------------------------------------------------- library adapters
# Every call into lightcurve_gp lives in these functions, so an API change is adapted here alone.


def paper_config(quick: bool):
    """The paper's config (configs/boxwing.yaml); ``quick``: a 1260-point training set."""
    return C.load_cfg(C.quick_overrides(quick))


def cpu_training_set(cfg):
    from lightcurve_gp.training.sets import generate_training_set

    return generate_training_set(cfg, progress=False)


def device_training_set(cfg, scene):
    """The training set of ``cfg`` generated on ``scene``'s device (what ``generate_training_set`` does on CPU)."""
    from lightcurve_gp.training.sets import initial_attitudes, window_samples

    dev, dtype = scene.sun.device, scene.sun.dtype
    q0 = initial_attitudes(cfg.data, dtype=dtype, device=dev)
    rho = torch.tensor(cfg.data.rho_grid, dtype=dtype, device=dev).unsqueeze(-1)
    inertia = torch.tensor(cfg.shape.inertia_kg_m2, dtype=dtype, device=dev)
    return window_samples(scene, q0, rho, cfg.data, inertia)


def make_scene(cfg, device, dtype, chunk_elements: int | None = None):
    """The config's scene on ``device``; ``chunk_elements`` (attitude-facet pairs per chunk) overrides the default."""
    from lightcurve_gp.photometry.render import Scene

    scene = Scene.from_config(cfg, dtype=dtype, device=device)
    if chunk_elements:
        scene = Scene(scene.facets, scene.sun, scene.observer, scene.r_obs, grouped=scene.grouped,
                      chunk_elements=chunk_elements)
    return scene


def render(scene, q, rho):
    return scene.magnitude(q, rho=rho)


def fit_exact(data, cfg, device):
    from lightcurve_gp.observation import ExactGP

    return ExactGP.from_data(data.q, data.m_past, data.y, cfg.model, device=device, keep_cholesky=False)


def fit_sparse(data, cfg, device, num_inducing: int):
    from lightcurve_gp.observation import SparseGP

    mcfg = dataclasses.replace(cfg.model, kind="sparse",
                               sparse=dataclasses.replace(cfg.model.sparse, num_inducing=num_inducing))
    return SparseGP.from_data(data.q, data.m_past, data.y, mcfg, device=device)


def condition_alpha(xs, r, outputscale: float, noise: float):
    """``α = (K + σ²I)⁻¹ r`` in the dtype of ``xs`` (scaled inputs ``(N, d)``, ``r (N,)``): ExactGP's conditioning
    algebra (``cholesky_kernel`` and two triangular solves)."""
    from lightcurve_gp.observation.exact_gp import cholesky_kernel

    chol = cholesky_kernel(xs, outputscale, noise)
    v = torch.linalg.solve_triangular(chol, r.unsqueeze(-1), upper=False)
    return torch.linalg.solve_triangular(chol.mT, v, upper=True).squeeze(-1)


def model_on(model, device, chunk_values: int | None = None):
    """A copy of a GP model on ``device`` whose kernel blocks hold at most ``chunk_values`` values (``None``: the
    class default, sized for CPU caches)."""
    moved = copy.deepcopy(model).to(device)
    vars(moved).pop("chunk_values", None)
    if chunk_values:
        moved.chunk_values = int(chunk_values)
    return moved


def exact_conditioning_inputs(model, data):
    """What conditioning an exact GP factorises: its scaled training inputs ``(N, d)``, centred targets ``(N,)``,
    ``θ1`` and ``σ²``, from a fitted ``ExactGP``."""
    r = data.y.to(torch.float64) - float(model.y_mean)
    return model.xs_train, r, float(model.outputscale), float(model.noise)


def scenario_tensors(cfg, seeds: int, device) -> dict:
    """Observations ``(seeds, T+1)``, increments, initial estimate and ``P0`` of the paper's scenario on ``device``."""
    from lightcurve_gp.filters.usque import initial_covariance
    from lightcurve_gp.simulation.scenario import simulate_scenario

    sc = simulate_scenario(cfg, seeds=range(seeds))
    return {"obs": sc.observations.to(device), "inc": sc.increments[0].to(device), "q0": sc.q_est0[0].to(device),
            "P0": initial_covariance(cfg.filter.p0_deg, dtype=cfg.torch_dtype, device=device)}


def filter_params(cfg, with_variance: bool):
    from lightcurve_gp.filters.usque import UsqueParams

    params = UsqueParams.from_config(cfg)
    return dataclasses.replace(params, variance=cfg.model.variance if with_variance else "none")


def run_filter(model, tensors: dict, params, batch: int, steps: int):
    """``steps`` steps of ``batch`` filters; filter ``b`` reads noise seed ``b mod seeds``."""
    from lightcurve_gp.filters.usque import run_usque

    rows = torch.arange(batch, device=tensors["obs"].device) % tensors["obs"].shape[0]
    obs = tensors["obs"][rows, :steps + 1]
    return run_usque(model=model, q_est0=tensors["q0"].expand(batch, 4), P0=tensors["P0"], observations=obs,
                     m_past0=obs[:, 0], increments=tensors["inc"][:steps], params=params)


# ----------------------------------------------------------------------------------------------- shared objects

FULL = {"batches": (1_000, 10_000, 100_000), "cpu_batches": (1_000, 10_000), "num_inducing": 512, "max_steps": 20,
        "seeds": 100, "case_cap_s": 6.0, "cpu_heavy_repeats": 1}
QUICK = {"batches": (10, 100, 1_000), "cpu_batches": (10, 100), "num_inducing": 128, "max_steps": 5, "seeds": 10,
         "case_cap_s": 0.5, "cpu_heavy_repeats": 3}
MIN_STEPS = 3


def training_data(ctx: Context):
    """The CPU training set, generated once per run."""
    return ctx.once("training set (CPU)", lambda: cpu_training_set(ctx.cfg))


def gp(ctx: Context, kind: str, device: torch.device):
    """The exact or sparse GP, fitted once on the device (kernel blocks of ``--gpu-chunk-values`` on CUDA) and
    copied once to the CPU for the CPU rows."""
    if device != ctx.device:
        return ctx.once(f"{kind} GP copy on CPU", lambda: model_on(gp(ctx, kind, ctx.device), ctx.cpu))

    def build():
        data = training_data(ctx)
        if kind == "exact" and ctx.device.type == "cpu":
            ctx.check_cholesky(len(data), torch.float64, runs=1)
        fitted = (fit_exact(data, ctx.cfg, ctx.device) if kind == "exact"
                  else fit_sparse(data, ctx.cfg, ctx.device, ctx.sizes["num_inducing"]))
        return model_on(fitted, ctx.device, ctx.args.gpu_chunk_values if ctx.cuda else None)

    return ctx.once(f"{kind} GP on {ctx.device}", build)


def scenario(ctx: Context, device: torch.device) -> dict:
    return ctx.once(f"scenario on {device}", lambda: scenario_tensors(ctx.cfg, ctx.sizes["seeds"], device))


def max_abs_diff(symbol: str):
    return lambda dev, cpu: f"max |Δ{symbol}| vs CPU {float((dev.double().cpu() - cpu.double()).abs().max()):.2g}"


def rel_diff(a, b) -> float:
    a, b = a.double().cpu(), b.double().cpu()
    return float((a - b).norm() / b.norm())


# ----------------------------------------------------------------------------------------------- sections

def section_cuda_tests(ctx: Context) -> None:
    """The CUDA tests in a pytest process of their own (``cuda_tests.py``): one row per test, then a summary."""
    import cuda_tests  # the CUDA section only

    timeout = max(10.0, min(ctx.args.tests_timeout_s, ctx.budget.left()))
    ctx.log(f"CUDA tests: pytest in a subprocess (log {ctx.out / 'cuda_tests.log'}, timeout {timeout:.0f} s)")
    res = cuda_tests.run(ctx.out, timeout)
    if isinstance(res, str):
        ctx.failures += 1
        ctx.report.add(Row("CUDA tests", "summary", note=f"FAILED: {res}"))
        return
    for nodeid, test in res["tests"].items():
        note, failed = cuda_tests.describe(test, expect_cuda=ctx.cuda)
        ctx.failures += failed
        ctx.report.add(Row("CUDA tests", nodeid, device_s=test["duration_s"], unit="s", note=note, cpu_note="—"))
    summary = cuda_tests.summary(res)
    ctx.report.add(Row("CUDA tests", "summary", note=summary))
    ctx.test_packages = res.get("packages", [])
    ctx.log(f"CUDA tests: {summary}")


def filter_part(ctx: Context, kind: str, params, batch: int, device: torch.device, last: dict):
    """Seconds per step of ``batch`` filters on ``device``: a 2-step warm-up, then the median of ``--repeats`` runs
    of as many steps (3 … max_steps) as fit the case's time cap. ``last`` holds the previous batch's cost per
    filter-step, to skip a case whose projection exceeds the budget left."""
    model, tensors, sync = gp(ctx, kind, device), scenario(ctx, device), ctx.sync(device)
    repeats = ctx.args.repeats
    if device.type in last:
        projected = last[device.type] * batch * (2 + repeats * MIN_STEPS)
        if projected > ctx.budget.left():
            raise Skip(f"projected {projected:.3g} s > {ctx.budget.left():.0f} s of budget left")
    t0 = time.perf_counter()
    warm = run_filter(model, tensors, params, batch, 2)
    sync()
    per_step = (time.perf_counter() - t0) / 2
    cap = ctx.args.case_cap_s or ctx.sizes["case_cap_s"]
    steps = max(MIN_STEPS, min(ctx.sizes["max_steps"], int(cap / (per_step * repeats))))
    seconds, _ = median_time(lambda: run_filter(model, tensors, params, batch, steps), sync, repeats=repeats,
                             warmup=0)
    last[device.type] = seconds / steps / batch
    refused, fallbacks = int(warm.rejected.sum()), int(warm.fallbacks.sum())
    note = f"{repeats} x {steps} steps" + (f", {refused} updates refused in the warm-up" if refused else "")
    note += f", {fallbacks} square-root fallbacks in the warm-up" if fallbacks else ""
    return seconds / steps, note, warm.q_est[:, -1]


def section_filter(ctx: Context) -> None:
    """Filter steps per second at each batch size; sparse GP first (the ≥ 10⁶ filter-steps/s aim), then exact."""
    cases = (("SparseGP mean only", "sparse", False), ("SparseGP mean + variance", "sparse", True),
             ("ExactGP mean only (paper's GPUKF)", "exact", False))
    n = len(training_data(ctx))
    for label, kind, with_var in cases:
        params, last_dev, last_cpu = filter_params(ctx.cfg, with_var), {}, {}
        size_model = f"M = {ctx.sizes['num_inducing']}" if kind == "sparse" else f"N = {n}"
        for batch in ctx.sizes["batches"]:
            dev_fn = functools.partial(filter_part, ctx, kind, params, batch, ctx.device, last_dev)
            cpu_fn = (functools.partial(filter_part, ctx, kind, params, batch, ctx.cpu, last_cpu)
                      if batch in ctx.sizes["cpu_batches"] else None)
            ctx.case("filter", label, f"B = {batch}, {size_model}", dev_fn, cpu_fn, unit="s per step", batch=batch,
                     compare=lambda d, c: max_abs_diff("q̂")(d, c) + " after 2 steps")


def section_conditioning(ctx: Context) -> None:
    """Exact conditioning: ExactGP.from_data (float64) and its algebra in float32, device vs CPU."""
    data, cfg = training_data(ctx), ctx.cfg
    n = len(data)
    reps = f"{ctx.sizes['cpu_heavy_repeats']} run(s)"

    def cpu_runs(device):  # as ctx.timed(heavy=True) runs them
        return ctx.sizes["cpu_heavy_repeats"] if device != ctx.device else 1 + ctx.args.repeats

    def f64(device):
        if device.type == "cpu":
            ctx.check_cholesky(n, torch.float64, runs=cpu_runs(device))
        seconds, model = ctx.timed(device, lambda: fit_exact(data, cfg, device), heavy=True)
        return seconds, reps if device != ctx.device else "", model.alpha

    ctx.case("conditioning", "ExactGP.from_data, float64", f"N = {n}", lambda: f64(ctx.device), lambda: f64(ctx.cpu),
             compare=lambda d, c: f"|α_dev − α_CPU| / |α_CPU| = {rel_diff(d, c):.2g}")
    ref = gp(ctx, "exact", ctx.device)
    xs64, r, theta1, noise = exact_conditioning_inputs(ref, data)

    def f32(device):
        if device.type == "cpu":
            ctx.check_cholesky(n, torch.float32, runs=cpu_runs(device))
        xs, rr = xs64.to(device, torch.float32), r.to(device, torch.float32)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            seconds, alpha = ctx.timed(device, lambda: condition_alpha(xs, rr, theta1, noise), heavy=True)
        note = f"|α32 − α64| / |α64| = {rel_diff(alpha, ref.alpha):.2g}"
        note += "".join(f"; {w.message}" for w in caught[:1])
        return seconds, note + (f" ({reps})" if device != ctx.device else ""), alpha

    ctx.case("conditioning", "Cholesky + solves, float32", f"N = {n}", lambda: f32(ctx.device), lambda: f32(ctx.cpu))


def section_render(ctx: Context) -> None:
    """The training-set workload: generation (propagate + render + window), then rendering alone (f64, f32)."""
    cfg, data = ctx.cfg, training_data(ctx)
    samples = round(cfg.data.t_span_past / cfg.data.dt_s) + 1
    chunk = ctx.args.gpu_render_chunk if ctx.cuda else None

    def generate(device):
        scene = make_scene(cfg, device, cfg.torch_dtype, chunk if device == ctx.device else None)
        seconds, ts = ctx.timed(device, lambda: device_training_set(cfg, scene))
        return seconds, "", ts.y

    ctx.case("render", "training-set generation (propagate + render + window)", f"N = {len(data)} × {samples} samples",
             lambda: generate(ctx.device), lambda: generate(ctx.cpu), compare=max_abs_diff("y"))
    gen = torch.Generator().manual_seed(0)
    q = torch.randn(len(data), samples, 4, generator=gen, dtype=torch.float64)
    q = q / q.norm(dim=-1, keepdim=True)
    rho = data.rho.to(torch.float64).unsqueeze(-1)  # (N, 1): trajectory i with its own ρ
    for dtype in (torch.float64, torch.float32):
        def magnitudes(device, dtype=dtype):
            scene = make_scene(cfg, device, dtype, chunk if device == ctx.device else None)
            qd, rd = q.to(device, dtype), rho.to(device, dtype)
            seconds, m = ctx.timed(device, lambda: render(scene, qd, rd))
            return seconds, "", m

        ctx.case("render", f"render only, {str(dtype).replace('torch.', '')}", f"{len(data)} × {samples} attitudes",
                 functools.partial(magnitudes, ctx.device), functools.partial(magnitudes, ctx.cpu),
                 compare=max_abs_diff("m"))


def section_sparse_fit(ctx: Context) -> None:
    """SparseGP.from_data (k-means inducing points and the prediction cache), device vs CPU."""
    data, m = training_data(ctx), ctx.sizes["num_inducing"]
    probe_q, probe_m = data.q[:2000], data.m_past[:2000]

    def fit(device):
        seconds, model = ctx.timed(device, lambda: fit_sparse(data, ctx.cfg, device, m))
        mean, _ = model.predict(probe_q.to(device), probe_m.to(device), variance="none")
        return seconds, "", mean

    ctx.case("sparse fit", "SparseGP.from_data", f"M = {m}, N = {len(data)}", lambda: fit(ctx.device),
             lambda: fit(ctx.cpu), compare=lambda d, c: max_abs_diff("mean")(d, c) + f" on {len(probe_q)} inputs")


SECTIONS = (("CUDA tests", section_cuda_tests), ("filter", section_filter), ("conditioning", section_conditioning),
            ("render", section_render), ("sparse fit", section_sparse_fit))


def main(argv=None) -> int:
    args = parse_args(argv, description=__doc__)
    device = check_args(args)
    if args.cpu_threads:
        torch.set_num_threads(args.cpu_threads)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # a kill by timeout still writes the footer
    budget = Budget(args.time_budget_s)
    cap = memory_cap(device)
    ctx = Context(args, budget, QUICK if args.quick else FULL, paper_config(args.quick), Path(args.out))
    ctx.out.mkdir(parents=True, exist_ok=True)
    header = machine_header(device, ctx.gflops, cap) + workload_lines(ctx.sizes, args, ctx.cfg.dtype)
    ctx.report = Report(ctx.out, device.type, header)
    ctx.log(f"writing {ctx.report.md_path}; budget {args.time_budget_s:.0f} s")
    status = "interrupted"
    try:
        for name, section in SECTIONS:
            if budget.left() <= 0:
                ctx.report.add(Row(name, "(whole section)", note="skipped: budget"))
                continue
            ctx.log(f"section {name}")
            try:
                section(ctx)
            except Exception as error:  # noqa: BLE001 - a section's failure is recorded, the next one runs
                traceback.print_exc()
                ctx.failures += 1
                note = f"FAILED: {type(error).__name__}: {first_line(error)}"
                ctx.report.add(Row(name, "(whole section)", note=note))
        status = "finished"
    finally:
        ctx.report.finish(footer_lines(ctx.report.rows, device_type=device.type, aim=AIM_FILTER_STEPS_PER_S,
                                       status=status, elapsed=budget.elapsed(), budget=budget.seconds,
                                       failures=ctx.failures, test_packages=ctx.test_packages))
        print(ctx.report.md_path.read_text(), flush=True)
    return 1 if ctx.failures else 0


if __name__ == "__main__":
    sys.exit(main())
