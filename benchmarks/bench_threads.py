"""Thread policy benchmark: 100 filter steps of the README's library snippet with 1 and 2 torch threads, with the
machine otherwise idle and with one core kept busy by a spinning process (oversubscription).

``python benchmarks/bench_threads.py [--steps 100] [--repeats 3] [--out runs/bench/threads.md]``
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import CONFIG, Table, fmt_seconds, machine_info, time_call, write_report  # noqa: E402


def _spin(stop) -> None:
    x = 0
    while not stop.is_set():
        x += 1


def _filter_steps(steps: int):
    from lightcurve_gp.config.load import load_config
    from lightcurve_gp.filters.usque import UsqueParams, initial_covariance, run_usque
    from lightcurve_gp.observation import ExactGP
    from lightcurve_gp.photometry.render import Scene
    from lightcurve_gp.simulation.scenario import simulate_scenario
    from lightcurve_gp.training.sets import generate_training_set

    cfg = load_config(CONFIG, overrides=["data.icosphere_subdivisions=1"])
    scene = Scene.from_config(cfg)
    truth = simulate_scenario(cfg, seeds=range(10), scene=scene)
    data = generate_training_set(cfg, progress=False)
    gp = ExactGP.from_data(data.q, data.m_past, data.y, cfg.model)
    params = UsqueParams.from_config(cfg)
    obs, inc = truth.observations[:, :steps + 1], truth.increments[0, :steps]
    P0 = initial_covariance(cfg.filter.p0_deg)
    return lambda: run_usque(model=gp, q_est0=truth.q_est0.expand(10, 4), P0=P0, observations=obs, m_past0=obs[:, 0],
                             increments=inc, params=params)


def main(argv: list[str] | None = None) -> int:
    import torch

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--out", type=Path, default=Path("runs/bench/threads.md"))
    args = p.parse_args(argv)
    run = _filter_steps(args.steps)
    table = Table(f"{args.steps} filter steps of the README snippet (10 filters, ExactGP N = 1260)",
                  ["torch threads", "other core idle", "other core busy"])
    for threads in (1, 2):
        torch.set_num_threads(threads)
        idle = time_call(run, repeats=args.repeats)
        stop = multiprocessing.Event()
        spinner = multiprocessing.Process(target=_spin, args=(stop,), daemon=True)
        spinner.start()
        try:
            busy = time_call(run, repeats=args.repeats)
        finally:
            stop.set()
            spinner.join()
        table.add([threads, fmt_seconds(idle["median"]), fmt_seconds(busy["median"])],
                  {"threads": threads, "idle_s": idle["median"], "busy_s": busy["median"]})
    table.print()
    write_report(args.out, machine_info(torch.float64), [table])
    return 0


if __name__ == "__main__":
    sys.exit(main())
