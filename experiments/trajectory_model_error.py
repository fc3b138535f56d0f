"""Each config's observation model against the renderer along the scenario's true trajectory (noise-free, ρ0).

The error of a model along the very trajectory a filter follows is what biases the filter: a constant part the offset
state absorbs, an attitude-dependent part (``rms_about_mean``) it cannot, which the filter answers with an attitude
error. Prints one Markdown row per config (mag): mean error, RMS about it, RMS, mean predictive std and the share of
samples within two predictive standard deviations; along a pass (``geometry.kind: orbit``) every sample under its
own geometry, the samples without a magnitude (shadow, below the horizon) left out. Models come from the model store
``<runs>/models/`` (trained there when missing).

    python -m experiments.trajectory_model_error configs/boxwing_robust.yaml configs/boxwing_surface.yaml
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from experiments.common import ROOT, trained_model
from lightcurve_gp.config.load import ConfigError, load_config
from lightcurve_gp.evaluation.reporting import markdown_table
from lightcurve_gp.observation.along_pass import bind_geometry
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_scenario


def trajectory_error_row(cfg, model) -> list[str]:
    """One table row: the model's error against the renderer at ``model.rho_reference`` along the truth."""
    scene = Scene.from_config(cfg).to(dtype=cfg.torch_dtype)
    sc = simulate_scenario(cfg, seeds=[0], rho_true=cfg.model.rho_reference, scene=scene)
    with torch.no_grad():
        mean, var = prediction_along_truth(model, sc)
    m_clean = sc.m_clean[0]
    seen = torch.isfinite(m_clean)  # along a pass: samples in shadow or below the horizon have no magnitude
    mean, var, err = mean[seen], var[seen], (mean - m_clean)[seen]
    within = (err.abs() <= 2.0 * var.sqrt()).double().mean()
    values = (err.mean(), (err - err.mean()).pow(2).mean().sqrt(), err.pow(2).mean().sqrt(), var.sqrt().mean())
    return [cfg.name, *(f"{float(v):+.3f}" if i == 0 else f"{float(v):.3f}" for i, v in enumerate(values)),
            f"{100 * float(within):.0f} %"]


def prediction_along_truth(model, sc) -> tuple[torch.Tensor, torch.Tensor]:
    """The model's mean and variance ``(T+1,)`` (mag, mag²) at the true attitudes; along a pass each sample under
    its own geometry (:func:`lightcurve_gp.observation.along_pass.bind_geometry`)."""
    q_true, m_clean = sc.q_true[0], sc.m_clean[0]  # the first seed's truth
    if sc.geometry is None:
        return model(q=q_true, m_past=m_clean, variance="exact")
    g, past = sc.geometry, torch.nan_to_num(m_clean)  # the pass models do not use m_past; unseen samples are NaN
    per_sample = [bind_geometry(model, sun=g.sun[t], observer=g.observer[t], range_m=float(g.range_m[t]))(
        q=q_true[t:t + 1], m_past=past[t:t + 1], variance="exact") for t in range(len(g))]
    return torch.cat([p[0] for p in per_sample], -1), torch.cat([p[1] for p in per_sample], -1)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("configs", nargs="+", help="configs whose models to compare")
    p.add_argument("--runs", default=str(ROOT / "runs"), type=Path, help="the model store's parent folder")
    p.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = p.parse_args(argv)
    try:
        cfgs = [load_config(c) for c in args.configs]
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    torch.set_num_threads(args.threads)
    rows = [trajectory_error_row(cfg, trained_model(cfg, args.runs)) for cfg in cfgs]
    print(markdown_table(("config", "mean error", "RMS about the mean", "RMS", "mean predictive std",
                          "within 2 std"), rows), end="")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
