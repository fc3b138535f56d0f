"""Cost of real passes (issue goals): geometry sampling of 7200 samples, rendering the truth of a 2 h pass, and one
filter step of the geometry-aware sparse GP against the attitude-only one.

* geometry: :func:`lightcurve_gp.passes.geometry.pass_geometry` of ``configs/geo_pass.yaml`` (7201 samples), median of
  ``--repeats`` calls after one warm-up (the first call of a process also imports astropy and reads the IERS
  tables: reported apart);
* truth rendering: ``Scene.magnitude`` of the 7201 true attitudes with the per-sample scene;
* filter step: one :func:`~lightcurve_gp.filters.usque.run_usque` over ``--steps`` steps of ``--filters`` offset
filters,
  per step, with a ``body_geometry`` SGPR bound along the pass (:class:`AlongPass`) and with an ``attitude_matrix``
  SGPR of the same size (M inducing points, fitted on the same number of points, no hyperparameter fit: the cost of
  a prediction does not depend on the fitted values).

    python benchmarks/bench_passes.py --threads 1
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]


def _median_time(fn, repeats: int) -> float:
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _filter_step_seconds(cfg, geometry, inputs: str, filters: int, steps: int, repeats: int) -> float:
    from lightcurve_gp.attitude.rotations import quat_normalize
    from lightcurve_gp.config.load import config_from_dict, config_to_dict
    from lightcurve_gp.filters.setup import run_filter
    from lightcurve_gp.observation.sparse_gp import SparseGP
    from lightcurve_gp.training.sets import generate_training_set, model_targets

    raw = config_to_dict(cfg)
    raw["model"].update(inputs=inputs, fit_hyperparameters=False)
    raw["filter"]["model_error"] = "none"  # an untrained stand-in GP has no held-out metrics
    if inputs != "body_geometry":
        raw["model"].pop("reference_range_km", None)
    c = config_from_dict(raw)
    data = model_targets(generate_training_set(c, progress=False), c.model)
    gp = SparseGP.from_data(data.q, data.m_past, data.y, c.model)
    gen = torch.Generator().manual_seed(0)
    q0 = quat_normalize(torch.randn(filters, 4, generator=gen, dtype=torch.float64))
    obs = 13.0 + torch.randn(filters, steps + 1, generator=gen, dtype=torch.float64)
    inc = quat_normalize(torch.tensor([0.001, -0.001, 0.002, 1.0], dtype=torch.float64)).expand(steps, 4)

    def run():
        run_filter(c, gp, q_est0=q0, observations=obs, increments=inc, offset=True,
                   geometry=geometry if inputs == "body_geometry" else None)

    return _median_time(run, repeats) / steps


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--filters", type=int, default=100)
    p.add_argument("--steps", type=int, default=200)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    t0 = time.perf_counter()
    from lightcurve_gp.config.load import load_config
    from lightcurve_gp.passes.geometry import pass_geometry
    from lightcurve_gp.photometry.render import Scene
    from lightcurve_gp.simulation.scenario import simulate_scenario

    cfg = load_config(ROOT / "configs" / "geo_pass.yaml")
    geometry = pass_geometry(cfg)
    first = time.perf_counter() - t0
    geo_s = _median_time(lambda: pass_geometry(cfg), args.repeats)
    q_true = simulate_scenario(cfg, seeds=[0]).q_true[0]
    scene = Scene.from_geometry(Scene.from_config(cfg).facets, geometry)
    render_s = _median_time(lambda: scene.magnitude(q_true, rho=0.5), args.repeats)
    aware = _filter_step_seconds(cfg, geometry, "body_geometry", args.filters, args.steps, args.repeats)
    plain = _filter_step_seconds(cfg, geometry, "attitude_matrix", args.filters, args.steps, args.repeats)
    print(f"threads {args.threads}; geometry of {len(geometry)} samples: {geo_s:.3f} s (goal <= 1 s; first call of "
          f"the process with imports and IERS tables {first:.2f} s)")
    print(f"truth rendering of {len(geometry)} samples: {render_s:.3f} s (goal <= 1 s)")
    print(f"filter step, {args.filters} offset filters, M = {cfg.model.sparse.num_inducing}: body_geometry "
          f"{1e3 * aware:.2f} ms, attitude_matrix {1e3 * plain:.2f} ms, ratio {aware / plain:.2f} (goal <= 1.5)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
