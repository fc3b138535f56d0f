"""One filter against its peers, measured in one run and one process: per GPUKF step and per 600 s run.

Paper scenario (``configs/boxwing.yaml``), one filter (B = 1), float64, ``--threads`` torch threads (default 1):

* GPUKF with the exact GP (N = 19 260, mean only, as in the paper): the library's USQUE, eager and with
  ``filter.compile: true`` (the step as compiled graphs, :mod:`lightcurve_gp.filters.compiled`); the same filter with
  GPyTorch's default prediction path ``likelihood(model(x)).mean`` as its observation model (its one-off mean
  solve timed apart); a straightforward numpy GPUKF written for this benchmark (``peers.numpy_gpukf``).
* Conventional UKF with the renderer: the library's USQUE with the parametric model, eager and compiled; filterpy's
  ``UnscentedKalmanFilter`` driving the same renderer (``peers.filterpy_usque``).
* Many filters at once: the library's SparseGP (M = 512, mean only) at B = ``--batch`` per filter-step, eager and
  compiled, against the numpy GPUKF's single filter.

Per step: median over ``--repeats`` runs of ``--steps`` steps (noise seeds 0, 1, …); per run: median over
``--run-repeats`` whole 600-step runs. The cases are timed round-robin inside each repeat, so a change of the
machine's load hits every case alike. The ratios ``step / ours`` are to the library's eager step; the notes give
the peers' ratios to the compiled step, and each compiled case's first run (which compiles; inductor's on-disk
cache makes a second process's compile shorter). Every peer's estimates are compared with the library's on the same seed
(largest angle between the two along the run). The paper's 0.83–0.88 s per GPUKF step is quoted, not measured.

    python benchmarks/compare_peers.py                      # ~2 min with the models cached, + GPyTorch's solve
    python benchmarks/compare_peers.py --skip-gpytorch --out runs/bench/peers.md
    python benchmarks/compare_peers.py --quick --repeats 3 --run-repeats 1 --batch 100   # rehearsal
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import common as C
import numpy as np

PAPER_GPUKF_S = (0.83, 0.88)  # seconds per GPUKF step, paper Sec. 4 (quoted)
PAPER_UKF_S = (0.003, 0.007)  # seconds per UKF step, paper Sec. 4 (quoted)


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="1260 training points (a rehearsal, seconds)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    parser.add_argument("--steps", type=int, default=50, help="steps per timed per-step run (default 50)")
    parser.add_argument("--repeats", type=int, default=7, help="per-step runs per case (median reported)")
    parser.add_argument("--run-repeats", type=int, default=3, help="whole 600 s runs per case (median reported)")
    parser.add_argument("--batch", type=int, default=10_000, help="B of the many-filters row (0: skip)")
    parser.add_argument("--skip-compiled", action="store_true", help="leave out the filter.compile: true cases")
    parser.add_argument("--skip-gpytorch", action="store_true", help="skip GPyTorch (its first call solves "
                        "against all N points with CG: minutes)")
    parser.add_argument("--gpytorch-steps", type=int, default=2, help="steps of the one timed run of GPyTorch's "
                        "default path (it solves for the predictive covariance every call; its 600 s run is "
                        "projected from them)")
    parser.add_argument("--cache-dir", default=str(C.ROOT / "runs" / "bench"), help="trained-model cache")
    parser.add_argument("--out", help="also write the tables to this file (.json: JSON, else markdown)")
    return parser.parse_args()


@dataclasses.dataclass
class Case:
    """One filter implementation: ``run(n_steps, seed) -> estimates (n_steps + 1, 4)`` numpy."""

    label: str
    family: str  # "GPUKF" | "UKF"
    run: object
    steps: int | None = None  # steps per timed run (None: --steps)
    repeats: int | None = None  # timed per-step runs (None: --repeats)
    projected: bool = False  # per 600 s run = median per step × 600 (too slow to run whole)
    per_step: list = dataclasses.field(default_factory=list)
    per_run: list = dataclasses.field(default_factory=list)
    estimates: np.ndarray | None = None  # of noise seed 0: the whole run, or the first per-step run when projected
    first_s: float | None = None  # the warm-up run (2 steps; with filter.compile it compiles)


def library_runner(model, params, sc, P0):
    """The library's ``run_usque`` on one filter (seed ``seed`` of the scenario's observations)."""
    from lightcurve_gp.filters.usque import run_usque

    def run(n_steps: int, seed: int) -> np.ndarray:
        obs = sc.observations[seed:seed + 1, :n_steps + 1]
        hist = run_usque(model=model, q_est0=sc.q_est0[:1], P0=P0, observations=obs,
                         m_past0=obs[:, 0], increments=sc.increments[0, :n_steps], params=params)
        return hist.q_est[0].numpy()

    return run


def max_angle_deg(q1: np.ndarray, q2: np.ndarray) -> float:
    """Largest rotation angle between two unit-attitude sequences ``(T, 4)`` over the first ``len(q1)`` steps
    (sign invariant, accurate near zero: ``4 atan2(‖q1 − q2‖, ‖q1 + q2‖)`` with the nearer sign), degrees."""
    q2 = q2[:len(q1)]
    q2 = np.where(((q1 * q2).sum(-1) < 0)[:, None], -q2, q2)
    angle = 4.0 * np.arctan2(np.linalg.norm(q1 - q2, axis=-1), np.linalg.norm(q1 + q2, axis=-1))
    return float(np.degrees(angle).max())


def time_round_robin(cases: list[Case], *, steps: int, repeats: int, run_repeats: int, T: int) -> None:
    """Fill each case's ``per_step`` (s) and ``per_run`` (s) lists, cases interleaved in every repeat; keep the
    whole-run estimates of seed 0."""
    for case in cases:
        t0 = time.perf_counter()
        case.run(2, 0)  # warm-up (first-call allocations; compiling)
        case.first_s = time.perf_counter() - t0
    for r in range(repeats):
        for case in cases:
            if r < (case.repeats or repeats):
                n = case.steps or steps
                t0 = time.perf_counter()
                est = case.run(n, r)
                case.per_step.append((time.perf_counter() - t0) / n)
                if r == 0 and case.projected:
                    case.estimates = est
        print(f"  per-step runs {r + 1}/{repeats} done", flush=True)
    for case in cases:
        if case.projected:
            case.per_run.append(statistics.median(case.per_step) * T)
    for r in range(run_repeats):
        for case in cases:
            if not case.projected:
                t0 = time.perf_counter()
                est = case.run(T, r)
                case.per_run.append(time.perf_counter() - t0)
                if r == 0:
                    case.estimates = est
        print(f"  whole runs {r + 1}/{run_repeats} done", flush=True)


def time_batch(model, params, sc, P0, B: int, steps: int, repeats: int) -> float:
    """Median seconds per step of ``B`` filters (observations cycling through the scenario's seeds)."""
    from lightcurve_gp.filters.usque import run_usque

    rows = np.arange(B) % sc.observations.shape[0]
    obs = sc.observations[rows, :steps + 1]
    go = lambda n: run_usque(model=model, q_est0=sc.q_est0[:1].expand(B, 4), P0=P0,  # noqa: E731
                             observations=obs[:, :n + 1], m_past0=obs[:, 0], increments=sc.increments[0, :n],
                             params=params)
    go(1)
    return statistics.median(C.timed(lambda: go(steps))[1] / steps for _ in range(repeats))


def build_tables(cases, gpytorch_solve_s, batch_row, sc, info_start) -> list:
    ours = {}
    for c in cases:
        if c.label.startswith("lightcurve-gp"):
            ours.setdefault(c.family, c)  # the eager one: the first
    tab = C.Table("One filter (B = 1), paper scenario: per step and per 600 s run (medians)",
                  ["filter", "implementation", "per step", "per 600 s run", "step / ours", "run / ours",
                   "max angle to ours"])
    for c in cases:
        ref = ours[c.family]
        step, run = statistics.median(c.per_step), statistics.median(c.per_run)
        ref_step, ref_run = statistics.median(ref.per_step), statistics.median(ref.per_run)
        run_cell = C.fmt_seconds(run) + (" (projected)" if c.projected else "")
        tab.add([c.family, c.label, C.fmt_seconds(step), run_cell, f"{step / ref_step:.3g}x",
                 f"{run / ref_run:.3g}x", f"{max_angle_deg(c.estimates, ref.estimates):.2g}°"],
                {"family": c.family, "label": c.label, "s_per_step": step, "s_per_run": run, "projected": c.projected,
                 "per_step_all": c.per_step, "per_run_all": c.per_run, "step_ratio": step / ref_step,
                 "run_ratio": run / ref_run, "max_angle_deg": max_angle_deg(c.estimates, ref.estimates)})
    T = sc.steps
    for family, (lo, hi) in (("GPUKF", PAPER_GPUKF_S), ("UKF", PAPER_UKF_S)):
        ref_step = statistics.median(ours[family].per_step)
        tab.add([family, "paper, Sec. 4 (quoted, not measured)", f"{lo:g}–{hi:g} s", f"{lo * T:.3g}–{hi * T:.3g} s",
                 f"{lo / ref_step:.3g}–{hi / ref_step:.3g}x", "", ""], {"family": family, "paper_s": [lo, hi]})
    if gpytorch_solve_s is not None:
        tab.note(f"GPyTorch's first call solved for its mean cache in {C.fmt_seconds(gpytorch_solve_s)} (once per "
                 "model, not in the rows)")
    numpy_step = statistics.median(next(c for c in cases if c.label.startswith("numpy")).per_step)
    for c in cases:
        if "compile" in c.label:
            peers = [p for p in cases if p.family == c.family and not p.label.startswith("lightcurve-gp")]
            step = statistics.median(c.per_step)
            ratios = ", ".join(f"{p.label.split(' (')[0]} {statistics.median(p.per_step) / step:.3g}x" for p in peers)
            tab.note(f"{c.label}: first run (2 steps, compiling) {C.fmt_seconds(c.first_s)}; peer step / its step: "
                     f"{ratios}")
    for label, (B, per_step) in batch_row or ():
        tab.note(f"many filters: lightcurve-gp SparseGP M = 512 mean only{label} at B = {B}: "
                 f"{C.fmt_seconds(per_step / B)} per filter-step = numpy GPUKF single filter / "
                 f"{numpy_step / (per_step / B):.3g}")
    tab.note(f"load average at start {info_start['loadavg']}, at the end {C.load_average()}; "
             f"os.cpu_count() = {info_start['os_cpu_count']}, torch threads = {info_start['torch_threads']}")
    return [tab]


def build_cases(args, exact, data, scene, rho: float, sc, P0, params) -> tuple[list[Case], float | None]:
    """The cases of the one-filter table (module docstring) and GPyTorch's first-call solve time (s, or ``None``)."""
    from peers import GPyTorchMean, UsqueSetup, filterpy_runner, numpy_runner

    from lightcurve_gp.observation.parametric import Parametric

    setup, mean_only = UsqueSetup(params), dataclasses.replace(params, variance="none")
    compiled = dataclasses.replace(mean_only, compile=True)
    cases = [Case("lightcurve-gp (ExactGP, mean)", "GPUKF", library_runner(exact, mean_only, sc, P0))]
    if not args.skip_compiled:
        cases.append(Case("lightcurve-gp (ExactGP, mean), filter.compile", "GPUKF",
                          library_runner(exact, compiled, sc, P0)))
    cases.append(Case("numpy GPUKF (exact GP, cdist + matvec)", "GPUKF", numpy_runner(setup, exact, sc, P0)))
    gpytorch_solve_s = None
    if not args.skip_gpytorch:
        gdefault = GPyTorchMean(exact, data.y)
        gmean = gdefault.skipping_variances()
        print("GPyTorch: first call (its mean solve over all N points) ...", flush=True)
        _, gpytorch_solve_s = C.timed(lambda: gmean(q=sc.q_est0[:1], m_past=sc.observations[0, :1]))
        cases.append(Case("GPyTorch likelihood(model(x)).mean in this USQUE, default settings", "GPUKF",
                          library_runner(gdefault, mean_only, sc, P0), steps=args.gpytorch_steps, repeats=1,
                          projected=True))
        cases.append(Case("GPyTorch, the same with skip_posterior_variances", "GPUKF",
                          library_runner(gmean, mean_only, sc, P0)))
    cases.append(Case("lightcurve-gp (renderer)", "UKF", library_runner(Parametric(scene, rho), params, sc, P0)))
    if not args.skip_compiled:
        cases.append(Case("lightcurve-gp (renderer), filter.compile", "UKF",
                          library_runner(Parametric(scene, rho), dataclasses.replace(params, compile=True), sc, P0)))
    cases.append(Case("filterpy UnscentedKalmanFilter + the renderer", "UKF",
                      filterpy_runner(setup, scene, rho, sc, P0)))
    return cases, gpytorch_solve_s


def main() -> None:
    args = parse_args()

    import torch

    from lightcurve_gp.filters.usque import UsqueParams, initial_covariance
    from lightcurve_gp.photometry.render import Scene
    from lightcurve_gp.simulation.scenario import simulate_scenario
    from lightcurve_gp.training.sets import load_or_generate

    C.set_threads(args.threads)
    cfg = C.load_cfg(C.quick_overrides(args.quick))
    info = C.machine_info(cfg.torch_dtype, cfg.device)
    print(C.machine_line(info), flush=True)
    data, _, _ = load_or_generate(cfg, C.ROOT / "runs" / "cache", progress=False)
    exact, _, _ = C.cached_gp(cfg, data, "exact", cache_dir=args.cache_dir)
    scene = Scene.from_config(cfg)
    sc = simulate_scenario(cfg, seeds=range(max(args.repeats, args.run_repeats, 20)), scene=scene)
    P0 = initial_covariance(cfg.filter.p0_deg, dtype=torch.float64)
    params = UsqueParams.from_config(cfg)
    mean_only = dataclasses.replace(params, variance="none")
    cases, gpytorch_solve_s = build_cases(args, exact, data, scene, cfg.filter.rho_assumed, sc, P0, params)
    time_round_robin(cases, steps=args.steps, repeats=args.repeats, run_repeats=args.run_repeats,
                     T=sc.steps)
    batch_row = None
    if args.batch:
        sparse, _, _ = C.cached_gp(cfg, data, "sparse", num_inducing=512, cache_dir=args.cache_dir)
        variants = [("", mean_only)] + ([] if args.skip_compiled else [(", filter.compile",
                                                                       dataclasses.replace(mean_only, compile=True))])
        batch_row = [(label, (args.batch, time_batch(sparse, p, sc, P0, args.batch, steps=10, repeats=3)))
                     for label, p in variants]
    tables = build_tables(cases, gpytorch_solve_s, batch_row, sc, info)
    for t in tables:
        t.print()
    if args.out:
        print(f"wrote {C.write_report(args.out, C.machine_info(cfg.torch_dtype, cfg.device), tables)}")


if __name__ == "__main__":
    main()
