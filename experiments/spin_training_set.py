"""What sampling the spin does to the paper's ``[q, m_app_past]`` training set (``data.omega0_deg_s`` a range).

For the paper's set (configs/boxwing.yaml; ``--set`` overrides, e.g. a smaller icosphere) with its one spin and
with a range of spins, prints how much the GP input ``m_app_past`` says about the target ``m_app`` (RMS of
``m_app − m_app_past``, the share of the target's variance a straight line in ``m_app_past`` explains) and how far
``m_app_past`` moves between the two sets for the same initial attitude and ρ (RMS, mag).

    python -m experiments.spin_training_set --set data.icosphere_subdivisions=1
"""

from __future__ import annotations

import argparse
import dataclasses
import sys

import torch

from lightcurve_gp.commands.common import apply_threads
from lightcurve_gp.config.load import SpinRangeConfig, load_config
from lightcurve_gp.training.sets import generate_training_set

RANGE = SpinRangeConfig(low=[-0.5, -0.5, -0.5], high=[0.5, 0.5, 0.5])


def statistics(m_past: torch.Tensor, y: torch.Tensor) -> dict:
    """RMS of ``y − m_past`` (mag) and the R² of the least-squares line ``y ≈ a m_past + c``."""
    X = torch.stack([m_past, torch.ones_like(m_past)], -1)
    coef = torch.linalg.lstsq(X, y.unsqueeze(-1)).solution
    resid = y - (X @ coef).squeeze(-1)
    return {"rms_y_minus_m_past": float((y - m_past).pow(2).mean().sqrt()),
            "r2_line_in_m_past": float(1 - resid.var() / y.var())}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m experiments.spin_training_set", description=__doc__.split("\n\n")[0])
    p.add_argument("--config", default="configs/boxwing.yaml")
    p.add_argument("--set", dest="overrides", action="append", default=[])
    args = p.parse_args(argv)
    apply_threads(1)
    cfg = load_config(args.config, overrides=args.overrides)
    ranged = dataclasses.replace(cfg, data=dataclasses.replace(cfg.data, omega0_deg_s=RANGE))
    one, many = generate_training_set(cfg, progress=False), generate_training_set(ranged, progress=False)
    if len(one) != len(many):
        print(f"the two sets dropped different points ({len(one)} vs {len(many)})", file=sys.stderr)
        return 1
    print(f"{len(one)} training points; spins: {cfg.data.omega0_deg_s} deg/s vs uniform in "
          f"[{RANGE.low[0]:g}, {RANGE.high[0]:g}] deg/s per axis")
    for name, ts in (("one spin", one), ("spin range", many)):
        print(f"  {name}: {statistics(ts.m_past, ts.y)}")
    moved = (one.m_past - many.m_past).pow(2).mean().sqrt()
    print(f"  m_app_past between the sets, same initial attitude and rho: RMS {float(moved):.3f} mag; "
          f"target m_app: RMS {float((one.y - many.y).pow(2).mean().sqrt()):.3f} mag")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
