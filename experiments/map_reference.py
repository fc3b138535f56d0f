"""What the prior and the light curve allow: a batch MAP estimate of the attitude from all observations so far.

At each checkpoint ``t`` (every ``--every`` s inside the scoring window)
:func:`lightcurve_gp.inference.attitude.map_known_rate`
maximises the posterior of the initial attitude (and, with an offset, the magnitude offset) given ``ỹ_1 … ỹ_t``,
the known dynamics and the filters' prior, re-linearising every observation at every iteration.

Observation models: the renderer with the true rho (``renderer``), the renderer at rho_reference with the offset
(``renderer_offset``) and the robust config's GP of the rho-normalised curve with the offset (``gp_offset``).
Writes ``--out`` (experiments/results/robust/map_reference.md and .json); the per-seed RMSE goes to ``--raw``
(runs/robust/map_reference_per_seed.json, not committed).

    python -m experiments.map_reference
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import torch

from experiments.common import ROOT, command_line, robust_arguments, seed_block, trained_model, write_outputs
from lightcurve_gp.config.load import load_config
from lightcurve_gp.evaluation.reporting import markdown_table
from lightcurve_gp.inference.attitude import MapPrior, map_known_rate, map_rmse_deg
from lightcurve_gp.observation.parametric import Parametric
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import Scenario, simulate_scenario


def run_map(model, sc: Scenario, cfg, checkpoints: list[int], offset: bool) -> tuple[dict, list]:
    """Batch MAP of one observation model on every seed: its summary and the per-seed RMSE (deg)."""
    start = time.perf_counter()
    prior = MapPrior(cfg.filter.p0_deg, cfg.filter.measurement_noise, cfg.filter.offset_prior_std)
    q_est0, increments = sc.q_est0[0], sc.increments[0]  # the config's truth, shared by the seeds
    est = map_known_rate(model, q_est0=q_est0, increments=increments, observations=sc.observations,
                         prior=prior, checkpoints=checkpoints, offset=offset)
    rmse = map_rmse_deg(est, q_true=sc.q_true[0], q_est0=q_est0, increments=increments)
    summary = {"rmse_deg_median": rmse.median(0).values.tolist(),
               "fraction_all_axes_below_10deg": float((rmse < 10).all(-1).double().mean()),
               "seconds": time.perf_counter() - start}
    if offset:
        summary["offset_final_median"] = float(est[checkpoints[-1]][:, 3].median())
    return summary, rmse.tolist()


def main(argv=None) -> int:
    p = robust_arguments(__doc__.splitlines()[0], seeds=100, seed_start=200, seed_help="not a tuning seed")
    p.add_argument("--rho-true", type=float, default=0.7)
    p.add_argument("--every", type=float, default=25.0, help="checkpoint spacing inside the scoring window (s)")
    p.add_argument("--models", default="renderer,renderer_offset,gp_offset")
    p.add_argument("--raw", default=str(ROOT / "runs/robust"), type=Path, help="where per-seed results go")
    args = p.parse_args(argv)
    cfg = load_config(args.config)
    scene = Scene.from_config(cfg)
    sc = simulate_scenario(cfg, seeds=seed_block(args), rho_true=args.rho_true, scene=scene)
    lo, hi = cfg.evaluation.rmse_window_s
    dt = cfg.scenario.dt_s
    checkpoints = [int(round(t / dt)) for t in torch.arange(lo, hi + 1e-9, args.every, dtype=torch.float64).tolist()]
    models = {"renderer": (lambda: Parametric(scene, args.rho_true), False),
              "renderer_offset": (lambda: Parametric(scene, cfg.model.rho_reference), True),
              "gp_offset": (lambda: trained_model(cfg, args.runs), True)}
    results = {"seeds": [args.seed_start, args.seed_start + args.seeds], "rho_true": args.rho_true,
               "checkpoints_s": [k * dt for k in checkpoints], "models": {}}
    per_seed, rows = {}, []
    for name in args.models.split(","):
        make, offset = models[name]
        s, per_seed[name] = run_map(make(), sc, cfg, checkpoints, offset)
        results["models"][name] = s
        rows.append([name, *(f"{v:.2f}" for v in s["rmse_deg_median"]),
                     f"{100 * s['fraction_all_axes_below_10deg']:.0f} %", f"{s['seconds']:.0f}"])
        print("| " + " | ".join(rows[-1]) + " |", flush=True)
    results["command"] = command_line("map_reference", argv or [])
    head = (f"Batch MAP over all observations so far, rho_true = {args.rho_true:g}, {args.seeds} seeds from "
            f"{args.seed_start}; RMSE over the checkpoints {lo:g}, {lo + args.every:g}, ..., {hi:g} s (deg)\n\n")
    table = markdown_table(["observation model", "yaw", "pitch", "roll", "< 10 deg all axes", "s"], rows)
    write_outputs(args.out, {"map_reference.json": results, "map_reference.md": head + table})
    write_outputs(args.raw, {"map_reference_per_seed.json": {"seeds": results["seeds"], "per_seed_rmse_deg": per_seed}})
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
