"""Realistic photometry (issue 27): every estimator at σ ∈ {0.01, 0.03, 0.1, 0.3, 0.71} mag on held-out seeds, with
the Cramér–Rao bound beside every RMSE.

Cases per noise level σ (``scenario.noise_var = filter.measurement_noise = σ²``, the config's filter rule:
``R = σ²``, ``Q = 1e-5`` rad² per step, no multiplier):

* ``paper`` — the config's truth (the paper's trajectory, ρ = 0.5, initial error (−10, 5, −10)°, P0 = 10°), noise
  seeds ``--paper-seeds`` (default 0:30; the tuning seeds were 100–129);
* ``random`` — the generalisation suite's random truths (:func:`lightcurve_gp.simulation.truths.draw_truths`:
  attitude, spin, surface, initial error per seed), seeds ``--random-seeds`` (default 2000:2030, the suite's
  held-out block; the tuning seeds were 1000–1029).

Estimators (:mod:`lightcurve_gp.evaluation.registry`): ``map`` (the recommended estimator: the surface-state filter,
then the whole-arc MAP of attitude and surface from 16 starts, from 8 more and the 8 best of 2048 screened prior
attitudes and lobe settings where the fit fails the misfit test, and from
2 more along each seed's weakest direction), ``matched_map`` (the same with the truth's surface known: the oracle the
goals compare with), ``surface_ukf_select``, ``matched_ukf`` and the GP filter ``gpukf``
(``filter.model_error: heldout``) with the robust GP read from the model store ``--models`` (never trained here: a
missing model is an error). Per (σ, case) and estimator: median RMSE per axis,
median CRB per axis (the filtering bound for filters, the smoothing bound for the whole-arc MAP; same seeds, same
unknowns), RMSE/CRB, share below 10° on all axes and its ratio to ``matched_map``'s, NEES mean, median and share in the
one-draw band, seconds for all seeds. Each (σ, case, estimator) is one case of the sweep's case store
(``<runs>/realistic_noise/cases``), so a killed run resumes. At σ = 0.71 the rows ``today: …`` run
``surface_ukf_select`` and ``gpukf`` under ``--today`` (the robust config as a user finds it: Q = 0, the surface
filter's R five times the noise) on the same data, the issue's "no worse than today" reference. Writes ``--out``
(experiments/results/realistic_noise/): summary.md, summary.csv.

    nice python -m experiments.realistic_noise --models runs/models --threads 1
"""

from __future__ import annotations

import argparse
import functools
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

import torch

from experiments.common import ROOT, command_line, floats, seed_range, write_outputs
from lightcurve_gp.config.load import ConfigError, config_hash, load_config
from lightcurve_gp.evaluation.harness import run_estimators
from lightcurve_gp.evaluation.reporting import csv_text, format_triple, markdown_table, scenario_summary, seed_rows
from lightcurve_gp.inference.arc_search import search_settings
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_scenario, simulate_truths
from lightcurve_gp.simulation.truths import draw_truths
from lightcurve_gp.sweep.store import resume_case
from lightcurve_gp.training.store import model_key, open_model, store_folder

ESTIMATORS = ("map", "matched_map", "surface_ukf_select", "matched_ukf", "gpukf")
SIGMAS = "0.01,0.03,0.1,0.3,0.71"
FORMAT = 2
HEADER = ("σ (mag)", "case", "estimator", "RMSE yaw / pitch / roll (°)", "CRB yaw / pitch / roll (°)", "RMSE / CRB",
          "< 10° all axes", "share / matched_map", "NEES mean", "NEES median", "NEES in band", "s (all seeds)")
QUICK = ["scenario.duration_s=120", "evaluation.rmse_window_s=[60, 120]"]


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", default=str(ROOT / "configs" / "boxwing_realistic.yaml"))
    p.add_argument("--sigmas", default=SIGMAS, help=f"noise levels, mag (default {SIGMAS})")
    p.add_argument("--paper-seeds", default="0:30", help="noise seeds of the paper case (default 0:30)")
    p.add_argument("--random-seeds", default="2000:2030", help="seeds of the random truths (default 2000:2030)")
    p.add_argument("--estimators", default=",".join(ESTIMATORS))
    p.add_argument("--models", type=Path, default=ROOT / "runs" / "models",
                   help="model store holding the trained GP of the config (never trained here)")
    p.add_argument("--runs", type=Path, default=ROOT / "runs", help="case store root")
    p.add_argument("--out", type=Path, default=ROOT / "experiments" / "results" / "realistic_noise")
    p.add_argument("--today", default=str(ROOT / "configs" / "boxwing_robust.yaml"),
                   help="the config whose filters are today's reference at σ = 0.71 (empty: none)")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--quick", action="store_true",
                   help="120 s arcs, the σ and seeds given, no GP (a smoke run; writes nothing to --out unless given)")
    return p.parse_args(argv)


def stored_model(cfg, models: Path):
    """The trained GP of ``cfg`` from the model store (an error when it is missing: this experiment trains none)."""
    path = store_folder(cfg, models) / "model.pt"
    if not path.is_file():
        raise ConfigError(f"--models: {path} missing; train the robust GP into the store first "
                          "(python -m experiments.robust_training)")
    model = open_model(path)
    if model.extra.get("model_key") != model_key(cfg):
        raise ConfigError(f"--models: {path} was trained for another config (model key)")
    return model


def sigma_config(path: str, sigma: float, quick: bool, *, filters: bool = True):
    """The config at noise level ``sigma``: the truth's noise ``σ²`` and (``filters``) every filter's ``R = σ²``."""
    return load_config(path, [f"scenario.noise_var={sigma ** 2!r}",
                              *([f"filter.measurement_noise={sigma ** 2!r}"] if filters else []),
                              *(QUICK if quick else [])])


def run_case(cfg, scenario, name: str, *, model, scene) -> tuple[dict[str, Any], list]:
    """One estimator on one scenario: its summary entry (:func:`scenario_summary`) and per-seed rows."""
    result = run_estimators(cfg, scenario, estimators=[name], model=model, scene=scene)
    return scenario_summary(result)["estimators"][name], seed_rows(result)


def cell(cfg, case: str, seeds: range, estimators, *, model, scene, root: Path
         ) -> tuple[dict[str, dict[str, Any]], float]:
    """Every estimator's summary entry on one (σ, case), each read back from the case store or run, and the wall
    seconds the cases took when they ran (as stored)."""
    if case == "paper":
        make = functools.cache(lambda: simulate_scenario(cfg, seeds=seeds, scene=scene))
    else:
        make = functools.cache(lambda: simulate_truths(cfg, draw_truths(list(seeds)), scene))
    out, seconds = {}, 0.0
    for name in estimators:
        sections = ["geometry", "shape", "surface", "scenario", "filter", "evaluation"]
        extra = {"study": "realistic_noise", "format": FORMAT, "case": case, "seeds": list(seeds), "estimator": name,
                 "model": model_key(cfg) if name == "gpukf" else None}
        if name in ("map", "matched_map"):  # the search's settings
            extra["search"] = search_settings(cfg.map, surface_known=name == "matched_map",
                                              noise_var=cfg.filter.measurement_noise)
        case_id = config_hash(cfg, *sections, extra=extra)
        compute = functools.partial(lambda n: run_case(cfg, make(), n, model=model, scene=scene), name)
        record, _ = resume_case(root, case_id, compute, values={"case": case, "noise_var": cfg.scenario.noise_var},
                                seeds=seeds, estimators=[name])
        out[name], seconds = record.summary, seconds + record.seconds
    return out, seconds


def table_rows(sigma: float, case: str, entries: dict[str, dict[str, Any]], ref: float | None = None
               ) -> list[list[Any]]:
    """One row of :data:`HEADER` per estimator of one (σ, case); ``ref``: ``matched_map``'s share (default: from
    ``entries``)."""
    ref = entries.get("matched_map", {}).get("fraction_all_axes_below_10deg") if ref is None else ref
    rows = []
    for name, e in entries.items():
        share = e["fraction_all_axes_below_10deg"]
        ratio = share / ref if ref else math.nan
        inband = e.get("share_nees_in_band", math.nan)
        rows.append([f"{sigma:g}", case, name, format_triple(e["rmse_deg_median"]),
                     format_triple(e.get("crb_deg_median")), format_triple(e.get("rmse_over_crb"), 1),
                     f"{100 * share:.0f} %",
                     "–" if math.isnan(ratio) else f"{ratio:.2f}", f"{e['nees_mean']:.2f}",
                     f"{e.get('nees_median', math.nan):.2f}",
                     "–" if math.isnan(inband) else f"{100 * inband:.0f} %", f"{e['seconds']:.1f}"])
    return rows


def run_all(args, sigmas, cases, estimators, *, model, scene) -> tuple[list[list[Any]], float]:
    """The table rows of every (σ, case), with today's reference rows at σ ≥ 0.7, and the stored wall seconds of
    all their cases."""
    root, rows, total = args.runs / "realistic_noise", [], 0.0
    for sigma in sigmas:
        cfg = sigma_config(args.config, sigma, args.quick)
        for case, seeds in cases.items():
            t = time.perf_counter()
            entries, seconds = cell(cfg, case, seeds, estimators, model=model, scene=scene, root=root)
            rows, total = rows + table_rows(sigma, case, entries), total + seconds
            if args.today and sigma >= 0.7:
                today = sigma_config(args.today, sigma, args.quick, filters=False)
                names = [e for e in ("surface_ukf_select", "gpukf") if e in estimators]
                ref = entries.get("matched_map", {}).get("fraction_all_axes_below_10deg")
                entries, seconds = cell(today, case, seeds, names, model=model, scene=scene, root=root)
                rows += table_rows(sigma, case, {f"today: {k}": v for k, v in entries.items()}, ref)
                total += seconds
            print(f"σ = {sigma:g} {case}: {time.perf_counter() - t:.0f} s", flush=True)
    return rows, total


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    estimators = [e for e in args.estimators.split(",") if e and not (args.quick and e == "gpukf")]
    sigmas = floats(args.sigmas)
    cases = {"paper": seed_range(args.paper_seeds), "random": seed_range(args.random_seeds)}
    base = load_config(args.config, QUICK if args.quick else [])
    model = stored_model(base, args.models) if "gpukf" in estimators else None
    scene = Scene.from_config(base).to(dtype=base.torch_dtype)
    start = time.perf_counter()
    rows, computed = run_all(args, sigmas, cases, estimators, model=model, scene=scene)
    note = (f"{command_line('realistic_noise', argv)}; the cases took {computed:.0f} s wall when they ran (this "
            f"run {time.perf_counter() - start:.0f} s: stored cases are read back), {args.threads} torch thread(s), "
            f"niceness {os.nice(0)}, load average "
            f"{' / '.join(f'{v:.1f}' for v in os.getloadavg())} on {os.cpu_count()} cores; held-out seeds: paper "
            f"{args.paper_seeds}, random {args.random_seeds}")
    text = (f"# Realistic noise: held-out seeds\n\n{note}\n\n{markdown_table(HEADER, rows)}\n")
    print(text)
    write_outputs(args.out, {"summary.md": text, "summary.csv": csv_text([dict(zip(HEADER, r)) for r in rows], HEADER)})
    return 0


if __name__ == "__main__":
    sys.exit(main())
