"""How configs/boxwing_robust.yaml's process noise was chosen: the robust GPUKF on the tuning seeds for a grid of
``filter.process_noise`` values, with the mean NEES against its chi-square band.

The rule: the value whose mean NEES is nearest the band's centre. The robust experiment reports other seeds
(``python -m experiments.robust_gpukf``). Writes ``--out`` (experiments/results/robust/tuning.md).

    python -m experiments.robust_tuning
"""

from __future__ import annotations

import sys

from experiments.common import robust_arguments, seed_block, trained_model, write_outputs
from lightcurve_gp.config.load import load_config
from lightcurve_gp.evaluation.harness import run_estimators
from lightcurve_gp.evaluation.reporting import SUMMARY_HEADER, markdown_table, scenario_summary, summary_row
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import simulate_scenario


def main(argv=None) -> int:
    p = robust_arguments(__doc__.splitlines()[0], seeds=100, seed_start=100, seed_help="the tuning seeds")
    p.add_argument("--process-noise", default="5e-6,1e-6,2e-7,1e-7,0", help="comma-separated values (rad^2 per step)")
    p.add_argument("--rho-true", type=float, default=0.7)
    args = p.parse_args(argv)
    cfg = load_config(args.config)
    scene = Scene.from_config(cfg)
    model = trained_model(cfg, args.runs)
    seeds = seed_block(args)
    rows, nees = [], {}
    for value in args.process_noise.split(","):
        c = load_config(args.config, [f"filter.process_noise={value}"])
        sc = simulate_scenario(c, seeds=seeds, rho_true=args.rho_true, scene=scene)
        s = scenario_summary(run_estimators(c, sc, estimators=("gpukf",), model=model, scene=scene))
        nees[value] = s["estimators"]["gpukf"]["nees_mean"]
        rows.append(summary_row(f"process noise {value}", s["estimators"]["gpukf"]))
        print("| " + " | ".join(rows[-1]) + " |", flush=True)
    lo, hi = s["nees_band_95"]
    best = min(nees, key=lambda v: abs(nees[v] - 0.5 * (lo + hi)))
    head = (f"Robust GPUKF on the tuning seeds {seeds.start}-{seeds.stop - 1}, rho_true = {args.rho_true:g}; mean NEES "
            f"band {lo:.2f}-{hi:.2f}; nearest its centre: process noise {best}\n")
    write_outputs(args.out, {"tuning.md": head + "\n" + markdown_table(SUMMARY_HEADER, rows)})
    print(head, end="")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
