"""What the prior and the light curve allow: a batch MAP estimate of the attitude from all observations so far.

Not a filter: at each checkpoint ``t`` (every ``--every`` s inside the scoring window) Gauss-Newton maximises the
posterior of the initial attitude (and, with an offset, the magnitude offset ``b``) given ``ỹ_1 … ỹ_t``, the known
dynamics and the filters' prior (``q_est,0``, ``P0 = (filter.p0_deg)² I``; ``b`` ~ N(ỹ_0 − h(q̂_0),
``filter.offset_prior_std²``)), re-linearising every observation at every iteration. The estimate at ``t`` uses
no later observation, so its Euler-angle RMSE over the checkpoints is comparable with a filter's over the window.

Observation models: the renderer with the true rho (``renderer``), the renderer at rho_reference with the offset
(``renderer_offset``) and the robust config's GP of the rho-normalised curve with the offset (``gp_offset``).
Writes ``--out`` (experiments/results/robust/map_reference.md and .json); the per-seed RMSE goes to ``--raw``
(runs/robust/map_reference_per_seed.json, not committed).

    python -m experiments.map_reference
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import torch

from lightcurve_gp.config import load_config
from lightcurve_gp.estimation import propagate_only
from lightcurve_gp.io import write_json_atomic, write_text_atomic
from lightcurve_gp.metrics import attitude_errors_deg
from lightcurve_gp.observation.parametric import Parametric
from lightcurve_gp.render import Scene
from lightcurve_gp.rotations import quat_mul, rotvec_to_quat
from lightcurve_gp.scenario import Scenario, simulate_scenario

from experiments.robust_gpukf import robust_arguments, trained_model

ROOT = Path(__file__).resolve().parents[1]


def batch_map(model, sc: Scenario, cfg, checkpoints: list[int], *, offset: bool, iterations: int = 15,
              step: float = 1e-5) -> dict[int, torch.Tensor]:
    """MAP estimates ``x = [rotation vector of q_0 ⊗ q_est,0⁻¹ (3), b]`` ``(S, 3 | 4)`` at each checkpoint index.

    Jacobians by central differences of ``step`` (rad, mag); every seed is solved in the same batch.
    """
    S = len(sc.seeds)
    n = 4 if offset else 3
    R = cfg.filter.measurement_noise
    prior_prec = torch.tensor([math.radians(cfg.filter.p0_deg) ** -2] * 3 + [cfg.filter.offset_prior_std ** -2]
                              * offset)

    def predict(x: torch.Tensor) -> torch.Tensor:  # (S, n) -> magnitudes (S, T+1)
        q = propagate_only(quat_mul(rotvec_to_quat(x[:, :3]), sc.q_est0), sc.increments)
        m, _ = model(q=q, m_past=sc.observations[:, :1].expand(-1, q.shape[1]), variance="none")
        return m + x[:, 3:] if offset else m

    x0 = torch.zeros(S, n)
    if offset:
        x0[:, 3] = sc.observations[:, 0] - predict(x0)[:, 0]
    x, out = x0.clone(), {}
    for t in checkpoints:
        for _ in range(iterations):
            m = predict(x)
            J = torch.stack([(predict(x + d) - predict(x - d)) / (2 * step) for d in step * torch.eye(n)], -1)
            J, r = J[:, 1:t + 1], (sc.observations - m)[:, 1:t + 1]
            H = J.mT @ J / R + torch.diag(prior_prec)
            g = (J.mT @ r.unsqueeze(-1)).squeeze(-1) / R - (x - x0) * prior_prec
            dx = torch.linalg.solve(H, g)
            x = x + dx
            if float(dx[:, :3].abs().max()) < 1e-9:
                break
        out[t] = x.clone()
    return out


def score(sc: Scenario, estimates: dict[int, torch.Tensor]) -> dict:
    """Euler-angle RMSE over the checkpoints (deg): median per axis, fraction of seeds below 10 deg on all axes."""
    errors = []
    for t, x in estimates.items():
        q_t = propagate_only(quat_mul(rotvec_to_quat(x[:, :3]), sc.q_est0), sc.increments[:t])[:, -1]
        errors.append(attitude_errors_deg(sc.q_true[t], q_t))
    rmse = torch.stack(errors, 1).pow(2).mean(1).sqrt()  # (S, 3)
    return {"rmse_deg_median": rmse.median(0).values.tolist(),
            "fraction_all_axes_below_10deg": float((rmse < 10).all(-1).double().mean()),
            "per_seed_rmse_deg": rmse.tolist()}


def main(argv=None) -> int:
    p = robust_arguments(__doc__.splitlines()[0], seeds=100, seed_start=200, seed_help="not a tuning seed")
    p.add_argument("--rho-true", type=float, default=0.7)
    p.add_argument("--every", type=float, default=25.0, help="checkpoint spacing inside the scoring window (s)")
    p.add_argument("--models", default="renderer,renderer_offset,gp_offset")
    p.add_argument("--raw", default=str(ROOT / "runs/robust"), type=Path, help="where per-seed results go")
    args = p.parse_args(argv)
    torch.set_default_dtype(torch.float64)
    cfg = load_config(args.config)
    scene = Scene.from_config(cfg)
    sc = simulate_scenario(cfg, seeds=range(args.seed_start, args.seed_start + args.seeds), rho_true=args.rho_true,
                           scene=scene)
    lo, hi = cfg.evaluation.rmse_window_s
    dt = cfg.scenario.dt_s
    checkpoints = [int(round(t / dt)) for t in torch.arange(lo, hi + 1e-9, args.every).tolist()]
    models = {"renderer": (lambda: Parametric(scene, args.rho_true), False),
              "renderer_offset": (lambda: Parametric(scene, cfg.model.rho_reference), True),
              "gp_offset": (lambda: trained_model(cfg, args.runs), True)}
    results = {"seeds": [args.seed_start, args.seed_start + args.seeds], "rho_true": args.rho_true,
               "checkpoints_s": [k * dt for k in checkpoints], "models": {}}
    per_seed = {}
    lines = [f"Batch MAP over all observations so far, rho_true = {args.rho_true:g}, {args.seeds} seeds from "
             f"{args.seed_start}; RMSE over the checkpoints {lo:g}, {lo + args.every:g}, ..., {hi:g} s (deg)\n",
             "| observation model | yaw | pitch | roll | < 10 deg all axes | s |", "|---|---|---|---|---|---|"]
    for name in args.models.split(","):
        make, offset = models[name]
        start = time.perf_counter()
        est = batch_map(make(), sc, cfg, checkpoints, offset=offset)
        s = score(sc, est)
        per_seed[name] = s.pop("per_seed_rmse_deg")
        s["seconds"] = time.perf_counter() - start
        if offset:
            s["offset_final_median"] = float(est[checkpoints[-1]][:, 3].median())
        results["models"][name] = s
        med = " | ".join(f"{v:.2f}" for v in s["rmse_deg_median"])
        lines.append(f"| {name} | {med} | {100 * s['fraction_all_axes_below_10deg']:.0f} % | {s['seconds']:.0f} |")
        print(lines[-1], flush=True)
    results["command"] = "python -m experiments.map_reference" + (" " + " ".join(argv) if argv else "")
    write_json_atomic(results, args.out / "map_reference.json")
    write_json_atomic({"seeds": results["seeds"], "per_seed_rmse_deg": per_seed}, args.raw / "map_reference_per_seed.json")
    write_text_atomic("\n".join(lines) + "\n", args.out / "map_reference.md")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
