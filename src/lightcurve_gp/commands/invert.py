"""``python -m lightcurve_gp.invert CONFIG --light-curve FILE [FILE ...]``: attitude and spin from light curves alone.

The global inversion of :mod:`lightcurve_gp.inference.inversion` on light-curve files of one object
(:mod:`lightcurve_gp.observed.inversion_run`: several light curves sharing one spin state, each with its own geometry
and, with ``--relative``, its own unknown zero point; the config gives the shape, the surface's ``F0``, ``n_u``,
``n_v``, the inertia and, for files without geometry, the fixed Sun and observer; ρ is estimated), then the whole-arc
MAP with the surface unknown from each of the ``--polish`` leading families. Writes the new folder
``OUT/estimates/<name>/invert_<file stem>/`` (:func:`lightcurve_gp.commands.layout.invert_folder`, beside the
estimates of the same file) atomically (an existing one is refused unless ``--force``):

* ``solutions.ecsv`` — one row per family, ranked by weight (:mod:`lightcurve_gp.observed.solutions`), the
  verdict in its metadata;
* ``summary.json`` — the verdict (``unique``, ``ambiguous`` or ``no_fit``: :mod:`lightcurve_gp.inference.answer`)
  and the best fit's χ² test, the ambiguity group used, the periodogram's candidates, the polished families' fits
  (χ², p-value, verdict, surface), timings, the settings, provenance;
* ``periodogram.png`` and ``light_curve.png`` (the observed magnitudes with each leading family's prediction);
  ``rate_profile.png`` when the top family turns less than once over the arc (its rate profile, the 95 % interval
  and the 2 % of "right": :mod:`lightcurve_gp.inference.rate_profile`).

The verdict is printed in words; a light curve that nothing fits (after one widened search) is said so, exit
code 0. Sample times may have any spacing and gaps (the propagation is closed form,
:mod:`lightcurve_gp.attitude.torque_free`); passes after a gap of more than ten minutes are also reached from the
answers of each long pass alone (:mod:`lightcurve_gp.inference.bridge`). ``mag_err`` gives each sample's 1σ,
``--mag-err`` one value for a file without it. Errors are one line and exit code 2, as in every command; samples a
file's TLE and site say cannot have been observed are one warning line, or refused with ``--strict``.

A config with a ``convex:`` section runs the convex inversion of :mod:`lightcurve_gp.commands.invert_convex`
instead (pole, period and convex shape from relative light curves of a DAMIT file; its own outputs).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import torch
from matplotlib.figure import Figure
from matplotlib.ticker import FuncFormatter
from tqdm.auto import tqdm

from lightcurve_gp.commands import invert_convex
from lightcurve_gp.commands.common import (
    STRICT_HELP,
    UserError,
    add_common_arguments,
    apply_threads,
    check_new_folder,
    check_output_root,
    progress_enabled,
    provenance,
    run_command,
    warn,
)
from lightcurve_gp.commands.layout import invert_folder
from lightcurve_gp.config.load import load_config
from lightcurve_gp.evaluation.plots import save_figure
from lightcurve_gp.files import RunFolder, write_json_atomic
from lightcurve_gp.inference.families import RIGHT_RATE_REL, Families
from lightcurve_gp.inference.inversion import Inversion, InversionSettings
from lightcurve_gp.inference.rate_profile import PROFILE_CUT_NATS, RateProfile
from lightcurve_gp.inference.trajectory import TrajectoryProblem
from lightcurve_gp.observed.arc_run import arc_summary
from lightcurve_gp.observed.inversion_run import InversionRun, invert_observations, trajectory_problem
from lightcurve_gp.observed.observations_file import read_observations
from lightcurve_gp.observed.run import FileGeometryError
from lightcurve_gp.observed.solutions import solutions_table, write_solutions

__all__ = ["build_parser", "main"]


def build_parser(prog: str = "lightcurve-gp invert") -> argparse.ArgumentParser:
    """The command's options; ``prog`` is how it was called (its usage line)."""
    parser = argparse.ArgumentParser(
        prog=prog,
        description="Estimate the attitude and spin of an object from its light curve alone (no initial guess): "
                    "every family of solutions within a likelihood ratio of the best, weighted by evidence.")
    parser.add_argument("config", help="YAML config: shape, surface (F0, n_u, n_v), inertia, fixed geometry")
    parser.add_argument("--light-curve", type=Path, nargs="+", required=True, metavar="FILE",
                        help="light-curve files of one object (.ecsv, .csv, .fits; any sample times; each its own "
                             "light curve sharing one spin state)")
    parser.add_argument("--relative", action="store_true",
                        help="the files' zero points are unknown (relative photometry): one offset per file fitted")
    parser.add_argument("--polish", type=int, default=3,
                        help="leading families polished by the whole-arc MAP with the surface unknown (default 3)")
    parser.add_argument("--starts", type=int, default=10_000, help="local optimisations started (default 10000)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the Sobol' attitudes (default 0)")
    parser.add_argument("--out", type=Path, default=Path("runs"),
                        help="output root (default runs/); writes OUT/estimates/<name>/invert_<file stem>/")
    parser.add_argument("--rate-min", type=float, default=0.05, help="slowest rate searched, deg/s (default 0.05)")
    parser.add_argument("--rate-max", type=float, default=5.0, help="fastest rate searched, deg/s (default 5)")
    parser.add_argument("--mag-err", type=float, default=None,
                        help="1-sigma of every magnitude (mag) for a file without a mag_err column")
    parser.add_argument("--max-log-ratio", type=float, default=10.0,
                        help="families within this many nats of the best log-likelihood are reported (default 10)")
    parser.add_argument("--strict", action="store_true", help=STRICT_HELP)
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE",
                        help="override a config value (repeatable)")
    add_common_arguments(parser)
    return parser


def _settings(args: argparse.Namespace) -> InversionSettings:
    if args.starts < 1:
        raise UserError(f"--starts: {args.starts} must be >= 1")
    if not 0.0 < args.rate_min < args.rate_max:
        raise UserError(f"--rate-min/--rate-max: need 0 < min < max, got {args.rate_min:g} and {args.rate_max:g}")
    if args.mag_err is not None and not args.mag_err > 0:
        raise UserError(f"--mag-err: {args.mag_err:g} must be > 0 mag")
    if args.polish < 0:
        raise UserError(f"--polish: {args.polish} must be >= 0")
    if not args.max_log_ratio >= 0:
        raise UserError(f"--max-log-ratio: {args.max_log_ratio:g} must be >= 0")
    return InversionSettings(starts=args.starts, seed=args.seed, rate_range_deg_s=(args.rate_min, args.rate_max))


def _predictions(problem: TrajectoryProblem, fam: Families, top: int = 5) -> np.ndarray:
    """The magnitudes ``(min(top, F), K)`` of the leading families."""
    n = min(top, len(fam))
    x = torch.cat([torch.zeros(n, 3, dtype=fam.q0.dtype), fam.omega0[:n], fam.log_rho[:n, None]], -1)
    r = problem.with_anchors(fam.q0[:n]).residual(x, torch.arange(n))
    return (problem.y - r * problem.sigma).cpu().numpy()


def _figures(folder: Path, t: np.ndarray, problem: TrajectoryProblem, inv: Inversion, fam: Families,
             profile: RateProfile | None = None) -> None:
    fig = Figure(figsize=(7.0, 3.5), layout="constrained")
    ax = fig.subplots()
    pg = inv.periodogram
    ax.plot(360.0 * pg.frequency_hz, pg.power, color="black", lw=0.8)
    for rate in pg.rates_deg_s:
        ax.axvline(rate, color="tab:red", lw=0.6, ls=":")
    ax.set_xscale("log")
    ax.set_xlabel("360° × frequency [deg/s] (red: rate candidates)")
    ax.set_ylabel("Lomb–Scargle power")
    save_figure(fig, folder / "periodogram.png")
    fig = Figure(figsize=(7.0, 4.0), layout="constrained")
    ax = fig.subplots()
    ax.plot(t, problem.y.cpu().numpy(), ".", color="black", ms=2, label="observed")
    for k, m in enumerate(_predictions(problem, fam)):
        ax.plot(t, m, lw=1, label=f"family {k + 1} (w {float(fam.weight[k]):.2f})")
    ax.invert_yaxis()
    ax.set_xlabel("time from the first sample [s]")
    ax.set_ylabel("$m_{app}$ [mag] (brighter ↑)")
    fig.legend(loc="outside lower center", ncols=3, frameon=False, fontsize=8)
    save_figure(fig, folder / "light_curve.png")
    if profile is not None:
        _profile_figure(folder, profile)


def _profile_figure(folder: Path, profile: RateProfile) -> None:
    """``rate_profile.png``: the top family's data cost over its rate, the 95 % interval and the 2 % of "right"."""
    fig = Figure(figsize=(7.0, 3.5), layout="constrained")
    ax = fig.subplots()
    rates = profile.rates_deg_s.cpu().numpy()
    delta = (profile.cost - profile.cost.min()).cpu().numpy()
    lo, hi = profile.interval_deg_s
    ax.axvspan(lo, hi, color="tab:blue", alpha=0.2, label=f"95 % interval {lo:.4g}–{hi:.4g} deg/s")
    own = profile.rate_deg_s
    for edge in (own * (1 - RIGHT_RATE_REL), own * (1 + RIGHT_RATE_REL)):
        ax.axvline(edge, color="tab:green", lw=0.8, ls="--")
    ax.plot([], [], color="tab:green", lw=0.8, ls="--", label=f"{100 * RIGHT_RATE_REL:g} % about the family's "
            f"{own:.4g} deg/s")
    ax.plot(rates, delta, ".-", color="black", lw=0.8)
    ax.axhline(PROFILE_CUT_NATS, color="tab:red", lw=0.6, ls=":")
    ax.set_xscale("log")
    plain = FuncFormatter(lambda value, _: f"{value:g}")
    ax.xaxis.set_major_formatter(plain)
    ax.xaxis.set_minor_formatter(plain)
    ax.set_yscale("symlog", linthresh=1.0)
    ax.set_ylim(bottom=0.0)
    ax.set_xlabel("rate |ω| [deg/s] (held; attitude, axis and ρ polished)")
    ax.set_ylabel("½χ² above the profile's minimum [nats]")
    ax.set_title("resolved" if profile.resolved else "a ridge: the rate is not resolved", fontsize=9)
    fig.legend(loc="outside lower center", ncols=2, frameon=False, fontsize=8)
    save_figure(fig, folder / "rate_profile.png")


def _polished(run: InversionRun) -> list[dict]:
    """Each polished family's fit: the whole-arc MAP's χ², p-value, verdict and surface."""
    out = []
    for k, arc in enumerate(run.polished):
        fit = arc_summary(arc, {})
        out.append({"family": k + 1, "verdict": fit["verdict"], **fit["fit"], "surface": fit["surface"],
                    "zero_points_mag": fit["zero_points_mag"], "seconds": arc.seconds})
    return out


def _summary(run: InversionRun, settings: InversionSettings, record: dict) -> dict:
    ans, inv, fam, group = run.answer, run.inversion, run.families, run.group
    return {**ans.as_dict(), "verdict_words": ans.words(), "families": len(fam), "beyond_rate_range": fam.beyond,
            "polished": _polished(run),
            "converged_solutions": int(inv.q0.shape[0]), "images": list(group.labels),
            "ambiguity_images": group.as_dict(), "top_weight": float(fam.weight[0]),
            "top_p_right": float(fam.p_right[0]),
            "rate_candidates_deg_s": [float(r) for r in inv.periodogram.rates_deg_s],
            "periodogram_detection": inv.periodogram.detection,
            "screened_rates": int(inv.rate_grid.shape[0]),
            "seconds": {**inv.seconds, **ans.seconds, "polish": run.seconds},
            "settings": {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(settings).items()},
            "run": record}


def _folder(args: argparse.Namespace, cfg) -> Path:
    first = Path(args.light_curve[0])
    more = len(args.light_curve) - 1
    return invert_folder(args.out, cfg.name, first if not more else first.with_name(f"{first.stem}_and_{more}_more"))


def _run(args: argparse.Namespace) -> int:
    apply_threads(args.threads)
    cfg = load_config(args.config, args.overrides)
    if cfg.convex is not None:  # a convex: section: pole, period and convex shape (commands/invert_convex.py)
        return invert_convex.run(cfg, args)
    settings = _settings(args)
    try:
        obs = read_observations(args.light_curve, mag_err=args.mag_err, relative=args.relative, strict=args.strict,
                                warn=warn)
        trajectory_problem(cfg, obs)  # the geometry checked before anything runs
    except (FileGeometryError, ValueError) as exc:
        raise UserError(str(exc)) from None
    check_output_root(args.out)
    folder = _folder(args, cfg)
    check_new_folder(folder, args.force)
    show = progress_enabled(args.no_progress)
    say = (lambda message: tqdm.write(message, file=sys.stderr)) if show else None
    source = obs.curves[0].source + (f" and {len(obs.curves) - 1} more" if len(obs.curves) > 1 else "")
    try:
        run = invert_observations(cfg, obs, settings=settings, max_log_ratio=args.max_log_ratio,
                                  polish=args.polish, progress=say)
    except ValueError as exc:  # the periodogram's one-line errors (e.g. a rate range that excludes it)
        raise UserError(f"{source}: {exc}") from None
    fam, inv = run.families, run.inversion
    record = provenance(cfg, config_file=str(args.config), light_curves=[str(p) for p in args.light_curve],
                        relative=args.relative)
    ans = run.answer
    table = solutions_table(fam, {"light_curve": source, "config": cfg.name, "verdict": ans.verdict,
                                  "chi2_per_dof": ans.fit.chi2_per_dof, "p_value": ans.fit.p_value})
    with RunFolder(folder, force=args.force) as tmp:
        write_solutions(table, tmp / "solutions.ecsv")
        write_json_atomic(_summary(run, settings, record), tmp / "summary.json")
        _figures(tmp, run.problem.times.cpu().numpy(), run.problem, inv, fam, run.answer.profile)
    best = table[0]
    print(f"{source}: {obs.describe()}")
    print(f"{len(fam)} families within {args.max_log_ratio:g} nats (modulo {len(run.group)} exact images); "
          f"best weight {float(best['weight']):.3f} (p_right {float(best['p_right']):.3f}), "
          f"rate {math.hypot(*(float(best[f'omega_{a}']) for a in 'xyz')):.4g} deg/s, "
          f"rho {float(best['rho']):.3g}; {sum(inv.seconds.values()) + run.seconds:.1f} s")
    print(f"verdict: {run.answer.words()}")
    if fam.beyond:
        print(f"{fam.beyond} more basins within {args.max_log_ratio:g} nats turn faster than the fastest rate "
              f"searched ({settings.rate_range_deg_s[1]:g} deg/s) and are left out (--rate-max widens the range)")
    for k, arc in enumerate(run.polished):
        print(f"family {k + 1} polished by the whole-arc MAP (surface unknown): chi2/dof {arc.chi2 / arc.dof:.2f}, "
              f"p = {arc.p_value:.3g}, {arc.verdict.replace('_', ' ')}")
    print(f"written: {folder}")
    return 0


def main(argv: list[str] | None = None, *, prog: str = "lightcurve-gp invert") -> int:
    """Run the command on ``argv`` (default ``sys.argv[1:]``), its usage shown as ``prog``; returns the exit code."""
    args = build_parser(prog).parse_args(argv)
    return run_command(lambda: _run(args), debug=args.debug)

