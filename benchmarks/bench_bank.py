"""Global-start bank cost: seconds per filter step of a bank of ``--bank-size`` filters on the robust config.

The model is the robust config's trained GP from the model store (``--runs``/models) when it is there, else a
stand-in of the same size: an SGPR with the config's inducing-point count on Sobol attitudes, hyperparameters not
fitted (a step's cost depends on the number of inducing points and inputs only). The bank asks for no predictive
variance (:mod:`lightcurve_gp.filters.bank`). Prints the seconds per step and the 1-minute load average before and
after; a 600-step bank costs about 600 times the step (the light curve of the paper's scenario).

``python benchmarks/bench_bank.py [--bank-size 1024] [--steps 20] [--threads 1]``
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]


def model_for(cfg, runs: Path):
    from lightcurve_gp.attitude.sampling import sobol_attitudes
    from lightcurve_gp.observation import SparseGP
    from lightcurve_gp.training.store import open_model, store_folder

    path = store_folder(cfg, runs / "models") / "model.pt"
    if path.is_file():
        return open_model(path), f"trained model {path}"
    n = 2 * cfg.model.sparse.num_inducing
    q = sobol_attitudes(n, 0, dtype=torch.float64)
    model_cfg = dataclasses.replace(cfg.model, fit_hyperparameters=False)
    gp = SparseGP.from_data(q, torch.zeros(n, dtype=torch.float64), torch.randn(n, dtype=torch.float64), model_cfg)
    return gp, f"stand-in SGPR, M = {gp.num_inducing}, not fitted"


def main() -> None:
    from lightcurve_gp.config.load import load_config
    from lightcurve_gp.filters.bank import bank_attitudes
    from lightcurve_gp.filters.setup import run_filter
    from lightcurve_gp.simulation.scenario import simulate_scenario

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--config", default=str(ROOT / "configs/boxwing_robust.yaml"))
    p.add_argument("--bank-size", type=int, default=1024)
    p.add_argument("--steps", type=int, default=20)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--runs", default=str(ROOT / "runs"), type=Path)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    cfg = load_config(args.config, [f"scenario.duration_s={args.steps}", f"evaluation.rmse_window_s=[0, {args.steps}]"])
    model, what = model_for(cfg, args.runs)
    sc = simulate_scenario(cfg, seeds=[0])
    q0 = bank_attitudes(args.bank_size)
    load_before = os.getloadavg()[0]
    start = time.perf_counter()
    run_filter(cfg, model, q_est0=q0, observations=sc.observations.expand(args.bank_size, -1),
               increments=sc.increments[0], variance="none")
    per_step = (time.perf_counter() - start) / args.steps
    print(f"{what}; bank of {args.bank_size} filters, {args.steps} steps, {args.threads} thread(s): "
          f"{per_step:.3f} s per step (x600 steps: {600 * per_step:.0f} s); load average {load_before:.1f} -> "
          f"{os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
