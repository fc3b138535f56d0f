"""Benchmark of batched USQUE filtering (paper scenario) with each observation model.

Time per filter step: median of ``--repeats`` short runs (``--steps`` steps of the paper's scenario, after one
2-step warm-up run) of ``B`` filters advancing together (``lightcurve_gp.filters.usque.run_usque``), for B in
``--batches``,
with the ExactGP (N = 19260) and the SparseGP (M = 512), each with its predictive variance in ``Pyy`` and mean only
(the paper's GPUKF), and the parametric renderer; the "ω + b" rows run the 7-state filter ``[δp, ω, b]`` (body rate
and magnitude offset estimated: every sigma point propagated with its own rate, :mod:`lightcurve_gp.filters.rates`).
Reported as ms per step and µs per filter-step. Beside the batched B = 100 run, a Python loop over 100
single-filter runs (what a one-filter library offers) and the ratio. Then one whole 600 s run of one filter per
model (median over 5 noise seeds: the cost of the ExactGP's fast variance depends on how far the
sigma points spread). On CUDA (when available) also B = 100 000 with the SparseGP and the renderer.

Cases too slow for ``--budget`` seconds (projected from the previous batch size) are skipped with the reason
printed. The GP models bound their own kernel blocks (``chunk_values``), so B = 10 000 filters of the ExactGP
(10 000 × 7 sigma points × 19260 training points) never hold more than one block in memory.

    python benchmarks/bench_filter.py                  # paper size, 1 thread
    python benchmarks/bench_filter.py --quick          # 1260 training points, 20 steps, B up to 1000
    python benchmarks/bench_filter.py --rates-only     # the SparseGP and renderer rows with and without ω + b,
                                                       # and 3600 s runs of 100 7-state filters
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import statistics

import common as C

PAPER = {"GPUKF": 0.85, "UKF": 0.005}  # seconds per observation step, paper section 4
TARGETS = {  # (model, B) -> seconds per filter-step, for every row of that model (with and without its variance)
    ("ExactGP", 1): 2e-3,
    ("SparseGP", 1): 0.5e-3,
    ("SparseGP", 10_000): 20e-6,
    ("SparseGP ω", 1): 2e-3,
    ("SparseGP ω", 10_000): 50e-6,
}
WHOLE_TARGET = 1.0
LONG_RUN = (3600, 100, 30.0)  # seconds of scenario, filters, target wall seconds of the 7-state SparseGP run
LONG_RUN_ROWS = ("SparseGP M=512, ω + b", "SparseGP M=512 mean only, ω + b")
N_SIGMA = 7


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="1260 training points, 20 steps, B up to 1000")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1; 0 = torch's default)")
    parser.add_argument("--batches", default=None, help="comma-separated B (default 1,100,1000,10000)")
    parser.add_argument("--steps", type=int, default=None, help="filter steps per timed run (default 50)")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per case (median reported)")
    parser.add_argument("--budget", type=float, default=60.0, help="seconds allowed per case before skipping")
    parser.add_argument("--skip-loop", action="store_true", help="skip the loop over 100 single-filter runs")
    parser.add_argument("--skip-whole", action="store_true", help="skip the whole 600 s runs")
    parser.add_argument("--rates-only", action="store_true",
                        help="only the SparseGP and renderer rows, with and without ω + b in the state, and the 3600 s "
                             "run of 100 filters with ω + b")
    parser.add_argument("--refit", action="store_true", help="retrain the models even when cached")
    parser.add_argument("--cache-dir", default=str(C.ROOT / "runs" / "bench"), help="trained-model cache")
    parser.add_argument("--out", help="also write the tables to this file (.json: JSON, else markdown)")
    return parser.parse_args()


@dataclasses.dataclass
class Bench:
    """The scenario's tensors per device and the timing settings shared by every case."""

    cfg: object
    scenario: object
    steps: int
    repeats: int
    budget: float
    tensors: dict = dataclasses.field(default_factory=dict)

    def add_device(self, device: str) -> None:
        import torch

        from lightcurve_gp.filters.setup import prior_covariance
        from lightcurve_gp.filters.usque import initial_covariance

        dev, sc = torch.device(device), self.scenario
        P0 = initial_covariance(self.cfg.filter.p0_deg, dtype=self.cfg.torch_dtype, device=dev)
        rate_cfg = dataclasses.replace(self.cfg, filter=dataclasses.replace(self.cfg.filter, estimate_omega=True))
        P0_rates = prior_covariance(rate_cfg, offset=True, dtype=P0.dtype, device=dev)
        self.tensors[device] = {"P0": P0, "P0_rates": P0_rates, "omega0": sc.omega_est0[0].to(dev),
                                "obs": sc.observations.to(dev), "inc": sc.increments[0].to(dev),
                                "q0": sc.q_est0[0].to(dev)}

    def run(self, model, params, B, n_steps, device="cpu", start=0, rates=False):
        """``B`` filters over the first ``n_steps`` steps, on the noise seeds ``start, start + 1, ...`` (cycled);
        ``rates``: the 7-state filter ``[δp, ω, b]``."""
        import torch

        from lightcurve_gp.filters.usque import run_usque

        t = self.tensors[device]
        rows = torch.arange(start, start + B, device=t["obs"].device) % t["obs"].shape[0]
        obs = t["obs"][rows, :n_steps + 1]
        if rates:
            return run_usque(model=model, q_est0=t["q0"].expand(B, 4), P0=t["P0_rates"], observations=obs,
                             m_past0=obs[:, 0], omega0=t["omega0"], offset0=torch.zeros((), dtype=obs.dtype,
                             device=obs.device), params=params)
        return run_usque(model=model, q_est0=t["q0"].expand(B, 4), P0=t["P0"], observations=obs, m_past0=obs[:, 0],
                         increments=t["inc"][:n_steps], params=params)

    def time_case(self, model, params, B, device, rates=False):
        """Median seconds per step of ``B`` filters, steps and runs timed."""
        sync = C.synchronizer(device)
        _, warm = C.timed(lambda: (self.run(model, params, B, 2, device, rates=rates), sync()))
        per_step = warm / 2
        n_steps = max(5, min(self.steps, int(self.budget / (per_step * (self.repeats + 1)))))
        runs = max(1, min(self.repeats, int(self.budget / (per_step * n_steps))))
        res = C.time_call(lambda: self.run(model, params, B, n_steps, device, rates=rates), repeats=runs, warmup=0,
                          sync=sync)
        return res["median"] / n_steps, n_steps, runs


def load_models(cfg, args):
    """(label, target key, model, filter parameters) per row, and the scene: "mean only" is the paper's GPUKF (GP
    mean in the filter); the other GP rows add the model's predictive variance (model.variance = fast) to Pyy."""
    from lightcurve_gp.filters.usque import UsqueParams
    from lightcurve_gp.observation.parametric import Parametric
    from lightcurve_gp.photometry.render import Scene
    from lightcurve_gp.training.sets import load_or_generate

    data, _, _ = load_or_generate(cfg, C.ROOT / "runs" / "cache", progress=False)
    sparse, _, _ = C.cached_gp(cfg, data, "sparse", num_inducing=512, cache_dir=args.cache_dir,
                                      refit=args.refit)
    scene = Scene.from_config(cfg)
    with_var = UsqueParams.from_config(cfg)
    mean_only = dataclasses.replace(with_var, variance="none")
    parametric = Parametric(scene, cfg.filter.rho_assumed)
    rate_rows = [("SparseGP M=512, ω + b", "SparseGP ω", sparse, with_var, True),
                 ("SparseGP M=512 mean only, ω + b", "SparseGP ω", sparse, mean_only, True),
                 ("Parametric, ω + b", "Parametric ω", parametric, with_var, True)]
    if args.rates_only:
        print(f"training set N = {len(data)}; SparseGP M = {sparse.num_inducing}", flush=True)
        return [("SparseGP M=512", "SparseGP", sparse, with_var, False),
                ("SparseGP M=512 mean only", "SparseGP", sparse, mean_only, False),
                ("Parametric", "Parametric", parametric, with_var, False), *rate_rows], scene
    exact, ex_extra, ex_cached = C.cached_gp(cfg, data, "exact", cache_dir=args.cache_dir, refit=args.refit,
                                             after_fit=C.exact_variance_check(data))
    print(f"training set N = {len(data)}; ExactGP {'loaded' if ex_cached else 'trained'} "
          f"(conditioning {ex_extra['fit_s']:.1f} s), SparseGP M = {sparse.num_inducing}", flush=True)
    models = [("ExactGP fast var", "ExactGP", exact, with_var, False),
              ("ExactGP mean only", "ExactGP", exact, mean_only, False),
              ("SparseGP M=512", "SparseGP", sparse, with_var, False),
              ("SparseGP M=512 mean only", "SparseGP", sparse, mean_only, False),
              ("Parametric", "Parametric", parametric, with_var, False), *rate_rows]
    return models, scene


def measure_batches(bench: Bench, row, batches, *, step_tab, loop_tab, with_loop: bool) -> None:
    """One model's step time for each B on the CPU (skipping B projected over the budget); at B = 100 also the
    Python loop over 100 single-filter runs."""
    label, target_key, model, params, rates = row
    last = None  # (B, seconds per filter-step) of the previous batch size
    for B in batches:
        projected = last[1] * B if last is not None else 0.0
        if projected * 2 > bench.budget:
            step_tab.add([label, "cpu", B, "—", "—", "—", "", "skipped"],
                         {"model": label, "B": B, "skipped": f"projected {projected:.2g} s per step"})
            step_tab.note(f"{label} at B = {B} skipped: projected {projected:.3g} s per step from "
                          f"B = {last[0]} (> --budget {bench.budget:g} s for a warm-up and one run)")
            continue
        per_step, n_steps, runs = bench.time_case(model, params, B, "cpu", rates=rates)
        last = (B, per_step / B)
        t = TARGETS.get((target_key, B))
        status = "" if t is None else ("ok" if per_step / B <= t else "MISS")
        step_tab.add([label, "cpu", B, f"{n_steps} x {runs}", f"{per_step * 1e3:.3g}",
                      f"{per_step / B * 1e6:.3g}", "" if t is None else f"≤ {C.fmt_seconds(t)}", status],
                     {"model": label, "device": "cpu", "B": B, "steps": n_steps, "runs": runs,
                      "s_per_step": per_step, "s_per_filter_step": per_step / B, "target": t, "status": status})
        if B == 100 and with_loop:
            n_loop = min(n_steps, 20)
            _, loop_s = C.timed(lambda: [bench.run(model, params, 1, n_loop, start=b, rates=rates)
                                         for b in range(100)])
            loop_step = loop_s / n_loop
            loop_tab.add([label, f"{per_step * 1e3:.3g}", f"{loop_step * 1e3:.3g}", f"{loop_step / per_step:.3g}x"],
                         {"model": label, "batched_s_per_step": per_step, "loop_s_per_step": loop_step,
                          "ratio": loop_step / per_step, "loop_steps": n_loop})
        print(f"  {label} B = {B}: {per_step * 1e3:.3g} ms per step", flush=True)


def measure_whole(bench: Bench, row, whole_seeds: int, whole_tab) -> None:
    """One model's whole run of one filter, median over the first ``whole_seeds`` noise seeds."""
    label, _, model, params, rates = row
    T = bench.scenario.increments.shape[0]
    times = [C.timed(lambda: bench.run(model, params, 1, T, start=seed, rates=rates))[1]
             for seed in range(whole_seeds)]
    s = statistics.median(times)
    whole_tab.add([label, f"{s:.3g}", f"{min(times):.3g}–{max(times):.3g}", f"{s / T * 1e3:.3g}",
                   f"≤ {WHOLE_TARGET:g} s", "ok" if s <= WHOLE_TARGET else "MISS"],
                  {"model": label, "seconds": s, "steps": T, "seconds_per_seed": times})
    print(f"  {label} whole run: {s:.3g} s", flush=True)


def measure_cuda(bench: Bench, models, step_tab) -> None:
    """B = 10 000 and 100 000 filters on CUDA with the SparseGP rows and the renderer."""
    bench.add_device("cuda")
    for label, _, model, params, rates in models:
        if label.startswith("ExactGP"):
            continue
        model = copy.deepcopy(model).to("cuda")
        for B in (10_000, 100_000):
            per_step, n_steps, runs = bench.time_case(model, params, B, "cuda", rates=rates)
            step_tab.add([label, "cuda", B, f"{n_steps} x {runs}", f"{per_step * 1e3:.3g}",
                          f"{per_step / B * 1e6:.3g}", "", f"{B / per_step:.3g} filter-steps/s"],
                         {"model": label, "device": "cuda", "B": B, "steps": n_steps, "runs": runs,
                          "s_per_step": per_step, "filter_steps_per_s": B / per_step})


def measure_long_run(cfg, models, scene, long_tab) -> None:
    """A 3600 s run of 100 filters with ω + b in the state and the SparseGP, with its variance and mean only (the
    paper's GPUKF): one timed run each."""
    from lightcurve_gp.simulation.scenario import simulate_scenario

    duration, B, target = LONG_RUN
    long_cfg = C.load_cfg([f"scenario.duration_s={duration}", *C.quick_overrides(False)])
    long_cfg = dataclasses.replace(long_cfg, data=cfg.data)
    sc = simulate_scenario(long_cfg, seeds=range(B), scene=scene)
    bench = Bench(cfg=long_cfg, scenario=sc, steps=duration, repeats=1, budget=1e9)
    bench.add_device("cpu")
    for label, _, model, params, _ in (r for r in models if r[0] in LONG_RUN_ROWS):
        _, seconds = C.timed(lambda: bench.run(model, params, B, duration, rates=True))
        long_tab.add([label, B, duration, f"{seconds:.3g}", f"≤ {target:g} s", "ok" if seconds <= target else "MISS"],
                     {"model": label, "B": B, "steps": duration, "seconds": seconds, "target": target})
        print(f"  {label}: {B} filters over {duration} s in {seconds:.3g} s", flush=True)


def print_paper_comparison(step_tab) -> None:
    """One filter's step time against the paper's (section 4) for the ExactGP and the renderer."""
    b1 = {r["model"]: r["s_per_step"] for r in step_tab.records if r.get("B") == 1 and "s_per_step" in r}
    for label, paper in (("ExactGP fast var", "GPUKF"), ("Parametric", "UKF")):
        if label in b1:
            print(f"{label}, one filter: {b1[label] * 1e3:.3g} ms per step = paper's {paper} "
                  f"({PAPER[paper]} s) / {PAPER[paper] / b1[label]:.3g}")


def main() -> None:
    args = parse_args()
    batches = [int(b) for b in (args.batches or ("1,100,1000" if args.quick else "1,100,1000,10000")).split(",")]
    steps = args.steps or (20 if args.quick else 50)

    import torch

    from lightcurve_gp.simulation.scenario import simulate_scenario

    C.set_threads(args.threads)
    cfg = C.load_cfg(C.quick_overrides(args.quick))
    info = C.machine_info(cfg.torch_dtype, cfg.device)
    print(C.machine_line(info))
    models, scene = load_models(cfg, args)
    seeds = max(batches + ([100] if not args.skip_loop else []))
    sc = simulate_scenario(cfg, seeds=range(seeds), scene=scene)
    bench = Bench(cfg=cfg, scenario=sc, steps=steps, repeats=args.repeats, budget=args.budget)
    bench.add_device("cpu")

    step_tab = C.Table(f"Filter step time (median of up to {args.repeats} runs of {steps} steps; "
                       f"{info['torch_threads']} thread(s), {info['dtype']})",
                       ["model", "device", "B", "steps x runs", "ms / step", "µs / filter-step", "target", "status"])
    loop_tab = C.Table("Batched vs a Python loop of single-filter runs (B = 100)",
                       ["model", "batched ms/step", "loop ms/step", "loop / batched"])
    whole_seeds = min(1 if args.quick else 5, sc.observations.shape[0])
    whole_tab = C.Table(f"One whole 600 s run of one filter (median over noise seeds 0-{whole_seeds - 1}, "
                        "one run each)", ["model", "seconds", "range", "ms / step", "target", "status"])
    long_tab = C.Table(f"A {LONG_RUN[0]} s run of {LONG_RUN[1]} filters with ω + b in the state (one run)",
                       ["model", "B", "steps", "seconds", "target", "status"])
    for row in models:
        measure_batches(bench, row, batches, step_tab=step_tab, loop_tab=loop_tab, with_loop=not args.skip_loop)
        if not args.skip_whole:
            measure_whole(bench, row, whole_seeds, whole_tab)
    if not args.quick:
        measure_long_run(cfg, models, scene, long_tab)
    if torch.cuda.is_available():
        measure_cuda(bench, models, step_tab)
    else:
        step_tab.note("no CUDA device: the B = 100 000 cases (SparseGP, Parametric) need one")

    step_tab.note(f"paper (MATLAB/Python, one filter): GPUKF {PAPER['GPUKF']} s per step, "
                  f"UKF {PAPER['UKF']} s per step")
    step_tab.note(f"observations of B filters cycle through {sc.observations.shape[0]} noise seeds; "
                  f"load average at start {info['loadavg']}, now {C.load_average()}")
    tables = [step_tab] + ([loop_tab] if loop_tab.rows else []) + ([whole_tab] if whole_tab.rows else []) \
        + ([long_tab] if long_tab.rows else [])
    for t in tables:
        t.print()
    print_paper_comparison(step_tab)
    if args.out:
        print(f"wrote {C.write_report(args.out, C.machine_info(cfg.torch_dtype, cfg.device), tables)}")


if __name__ == "__main__":
    main()
