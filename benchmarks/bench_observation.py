"""Benchmark of the observation models' per-call latency and one-off costs (paper setup, N = 19260).

Latency: median of ``--repeats`` calls after one warm-up, for 7, 13 and 13 000 points (1 and 1000 sigma-point-like
sets: points within 3° of an attitude a few degrees from a training attitude, ``m_past`` of that training point),
mean only and mean + variance, for the ExactGP (fast variance), SparseGP at M = 256/512/1024 and the parametric
renderer. Beside them, GPyTorch's own ``likelihood(model(x))`` with default settings on the same training data,
timed once (it costs tens of seconds per call at this N) on 13 points, and the ratio to the ExactGP.

One-off costs: training-set generation, exact conditioning, sparse fitting, fast-vs-exact variance error.
Trained models are cached in ``runs/bench/`` (reused while the config matches; the cached files keep the training
times measured when they were made).

    python benchmarks/bench_observation.py                # paper size, 1 thread
    python benchmarks/bench_observation.py --quick        # 1260 training points
    python benchmarks/bench_observation.py --skip-gpytorch --out runs/bench/observation.md
"""

from __future__ import annotations

import argparse

import common as C

TARGETS = {  # (model label, points, with variance) -> seconds, on a 2-core CPU in float64
    ("ExactGP", 13, False): 1e-3,
    ("ExactGP", 13, True): 3e-3,
    ("SparseGP M=512", 13, True): 0.3e-3,
}
SIZES = ((1, 7), (1, 13), (1000, 13))  # (sets, points per set)


def parse_args() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="1260 training points (data.icosphere_subdivisions=1)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1; 0 = torch's default)")
    parser.add_argument("--repeats", type=int, default=7, help="timed calls per case after one warm-up (>= 5)")
    parser.add_argument("--skip-gpytorch", action="store_true", help="skip the (tens of seconds) GPyTorch call")
    parser.add_argument("--refit", action="store_true", help="retrain the models even when cached")
    parser.add_argument("--cache-dir", default=str(C.ROOT / "runs" / "bench"), help="trained-model cache")
    parser.add_argument("--out", help="also write the tables to this file (.json: JSON, else markdown)")
    return parser.parse_args()


def _cache_note(cached: bool) -> str:
    return "cached model; time measured when it was trained" if cached else "trained in this run"


def one_off_costs(cfg, args):
    """Training-set generation, exact conditioning with its fast-variance check, sparse fitting at each M:
    the table, the training data, the ExactGP and the SparseGPs by M."""
    from lightcurve_gp.training.sets import generate_training_set, load_or_generate

    once = C.Table("One-off costs", ["item", "value", "target", "note"])
    data, seconds = C.timed(lambda: load_or_generate(cfg, C.ROOT / "runs" / "cache", progress=False)[0])
    _, gen_s = C.timed(lambda: generate_training_set(cfg, progress=False))
    n = len(data)
    print(f"training set: N = {n} points")
    once.add(["training-set generation", C.fmt_seconds(gen_s), "", f"N = {n}; loading the cache: "
              f"{C.fmt_seconds(seconds)}"], {"item": "data_generation_s", "value": gen_s, "n": n})

    exact, ex_extra, ex_cached = C.cached_gp(cfg, data, "exact", cache_dir=args.cache_dir, refit=args.refit,
                                             after_fit=C.exact_variance_check(data))
    fit_s = ex_extra["fit_s"]
    once.add(["ExactGP conditioning", C.fmt_seconds(fit_s), "≤ 60 s",
              f"{'ok' if fit_s <= 60 else 'MISS'}; N = {n}; {_cache_note(ex_cached)}"],
             {"item": "exact_conditioning_s", "value": fit_s, "cached": ex_cached})
    ve = ex_extra["variance_error"]
    once.add(["fast-vs-exact variance, max rel. error", f"{ve['max_rel']:.3g}", "",
              f"median {ve['median_rel']:.3g}, max abs {ve['max_abs']:.3g} mag², min exact {ve['min_exact']:.3g}; "
              f"{ve['n']} points (50 sets of 13), {exact.neighbors} neighbours"],
             {"item": "fast_variance_error", **ve})

    sparse = {}
    for m in (256, 512, 1024):
        model, extra, cached = C.cached_gp(cfg, data, "sparse", num_inducing=m, cache_dir=args.cache_dir,
                                           refit=args.refit)
        sparse[m] = model
        once.add([f"SparseGP fitting, M = {model.num_inducing}", C.fmt_seconds(extra["fit_s"]), "",
                  f"k-means init, inducing points {'optimised' if cfg.model.sparse.optimize_inducing else 'fixed'}; "
                  f"{_cache_note(cached)}"], {"item": f"sparse_fit_s_M{m}", "value": extra["fit_s"], "cached": cached})
    return once, data, exact, sparse


def latency(models, inputs, *, repeats: int, info: dict):
    """Median latency of each model on each input size, mean only and mean + variance: the table and the ExactGP's
    mean + variance seconds on 13 points."""
    import torch

    lat = C.Table(f"Per-call latency (median of {repeats} after 1 warm-up; {info['torch_threads']} thread(s), "
                  f"{info['dtype']})", ["model", "points", "mean only", "mean+var", "target", "status"])

    def call(model, q, m, var):
        with torch.no_grad():
            return model(q=q, m_past=m, variance="fast" if var else "none")

    ours_13 = None
    for label, model, desc in models:
        for pts, (q, m) in inputs.items():
            res = {}
            for var in (False, True):
                res[var] = C.time_call(lambda: call(model, q, m, var), repeats=repeats)["median"]
            targets, status = [], []
            for var in (False, True):
                t = TARGETS.get((label, pts, var))
                if t is not None:
                    targets.append(f"{'mean+var' if var else 'mean'} ≤ {C.fmt_seconds(t)}")
                    status.append("ok" if res[var] <= t else "MISS")
            lat.add([label, pts, C.fmt_seconds(res[False]), C.fmt_seconds(res[True]), "; ".join(targets),
                     " ".join(status)],
                    {"model": label, "desc": desc, "points": pts, "mean_s": res[False], "mean_var_s": res[True],
                     "targets": targets, "status": status})
            if label == "ExactGP" and pts == 13:
                ours_13 = res[True]
        print(f"  timed {label} ({desc})", flush=True)
    lat.note("inputs: sets of 7 or 13 points within 3° of an attitude 5° from a random training attitude, "
             "m_past of that training point; 13 000 points = 1000 such sets of 13")
    lat.note("targets are for a 2-core CPU in float64; this machine may be shared with other work "
             f"(load average at start {info['loadavg']}, now {C.load_average()})")
    return lat, ours_13


def gpytorch_default_call(exact, data, inputs_13, ours_13):
    """GPyTorch's ``likelihood(model(x))`` with default settings on the same data, timed once on 13 points."""
    import torch

    from lightcurve_gp.observation.fitting import gpytorch_exact_model

    gp = C.Table("GPyTorch default likelihood(model(x)) on the same data (timed once)",
                 ["call", "points", "seconds", "this ExactGP", "ratio", "max |Δmean|", "max |Δvar|"])
    ls = float(exact.lengthscale[0])
    gmodel, glik = gpytorch_exact_model(exact.x_train, data.y.to(torch.float64) - exact.y_mean,
                                        float(exact.outputscale), ls, float(exact.noise))
    gmodel.eval()
    glik.eval()
    q, m = inputs_13
    xt = exact.inputs(q.reshape(-1, 4).double(), m.reshape(-1).double())

    def gcall():
        with torch.no_grad():
            out = glik(gmodel(xt))
            return out.mean, out.variance

    (gmean, gvar), g_s = C.timed(gcall)
    with torch.no_grad():
        mean, var = exact(q=q, m_past=m, variance="fast")
    dmean = float((gmean + exact.y_mean - mean.reshape(-1)).abs().max())
    dvar = float((gvar - float(exact.noise) - var.reshape(-1)).abs().max())
    gp.add(["likelihood(model(x)), mean+var", 13, C.fmt_seconds(g_s), C.fmt_seconds(ours_13),
            f"{g_s / ours_13:.3g}x", f"{dmean:.2g}", f"{dvar:.2g}"],
           {"gpytorch_s": g_s, "ours_s": ours_13, "ratio": g_s / ours_13, "max_abs_dmean": dmean,
            "max_abs_dvar": dvar})
    gp.note("timed once (repeats = 1): GPyTorch's default settings solve with CG/Lanczos above 800 points and "
            "redo the predictive variance against the full N×N system on a fresh call")
    gp.note("Δ compares GPyTorch's (approximate, CG) answer with this ExactGP's (exact mean, fast variance; "
            "GPyTorch's variance minus the noise σ²)")
    return gp


def main() -> None:
    args = parse_args()

    from lightcurve_gp.observation.parametric import Parametric
    from lightcurve_gp.photometry.render import Scene

    C.set_threads(args.threads)
    cfg = C.load_cfg(C.quick_overrides(args.quick))
    info = C.machine_info(cfg.torch_dtype, cfg.device)
    print(C.machine_line(info))

    once, data, exact, sparse = one_off_costs(cfg, args)
    scene = Scene.from_config(cfg)
    parametric = Parametric(scene, cfg.filter.rho_assumed)
    once.print()

    models = [("ExactGP", exact, f"N = {exact.num_train}, fast variance ({exact.neighbors} neighbours)")]
    models += [(f"SparseGP M={m}", sp, f"M = {sp.num_inducing}") for m, sp in sparse.items()]
    models += [("Parametric", parametric, f"renderer, {len(scene.facets)} facets")]
    inputs = {s * p: C.sigma_like_inputs(data, s, p, seed=10 + s) for s, p in SIZES}
    lat, ours_13 = latency(models, inputs, repeats=args.repeats, info=info)
    lat.print()

    tables = [once, lat]
    if not args.skip_gpytorch:
        gp = gpytorch_default_call(exact, data, inputs[13], ours_13)
        gp.print()
        tables.append(gp)
    if args.out:
        print(f"wrote {C.write_report(args.out, C.machine_info(cfg.torch_dtype, cfg.device), tables)}")


if __name__ == "__main__":
    main()
