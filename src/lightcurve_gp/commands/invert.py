"""``python -m lightcurve_gp.invert CONFIG --light-curve FILE``: attitude and spin from a light curve, no initial guess.

The global inversion of :mod:`lightcurve_gp.inference.inversion` on a light-curve file (the config gives the shape,
the surface's ``F0``, ``n_u``, ``n_v``, the inertia, the propagation step ``scenario.dt_s`` and, for a file
without geometry, the fixed Sun and observer; ρ is estimated). Writes the new folder
``OUT/estimates/<name>/invert_<file stem>/`` (:func:`lightcurve_gp.commands.layout.invert_folder`, beside the
estimates of the same file) atomically (an existing one is refused unless ``--force``):

* ``solutions.ecsv`` — one row per family, ranked by weight (:mod:`lightcurve_gp.observed.solutions`), the
  verdict in its metadata;
* ``summary.json`` — the verdict (``unique``, ``ambiguous`` or ``no_fit``: :mod:`lightcurve_gp.inference.answer`)
  and the best fit's χ² test, the ambiguity group used, the periodogram's candidates, timings, the settings,
  provenance;
* ``periodogram.png`` and ``light_curve.png`` (the observed magnitudes with each leading family's prediction).

The verdict is printed in words; a light curve that nothing fits (after one widened search) is said so, exit
code 0. Sample times must lie on the ``scenario.dt_s`` grid (the propagation's step); ``mag_err`` gives each
sample's 1σ, ``--mag-err`` one value for a file without it. Errors are one line and exit code 2, as in every
command; samples a file's TLE and site say cannot have been observed are one warning line, or refused with
``--strict``.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np
import torch
from matplotlib.figure import Figure
from tqdm.auto import tqdm

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
from lightcurve_gp.inference.answer import Answer, answer
from lightcurve_gp.inference.families import Families
from lightcurve_gp.inference.forward import GroupRenderer
from lightcurve_gp.inference.inversion import Inversion, InversionSettings
from lightcurve_gp.inference.trajectory import TrajectoryProblem
from lightcurve_gp.observed.lightcurve_file import LightCurve, read_light_curve
from lightcurve_gp.observed.run import FileGeometryError, file_geometry
from lightcurve_gp.observed.solutions import solutions_table, write_solutions
from lightcurve_gp.photometry.ambiguity import ambiguity_group
from lightcurve_gp.photometry.render import Scene

__all__ = ["build_parser", "file_problem", "main"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m lightcurve_gp.invert",
        description="Estimate the attitude and spin of an object from its light curve alone (no initial guess): "
                    "every family of solutions within a likelihood ratio of the best, weighted by evidence.")
    parser.add_argument("config", help="YAML config: shape, surface (F0, n_u, n_v), inertia, dt, fixed geometry")
    parser.add_argument("--light-curve", type=Path, required=True, help="light-curve file (.ecsv, .csv, .fits)")
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
    if not args.max_log_ratio >= 0:
        raise UserError(f"--max-log-ratio: {args.max_log_ratio:g} must be >= 0")
    return InversionSettings(starts=args.starts, seed=args.seed, rate_range_deg_s=(args.rate_min, args.rate_max))


def file_problem(cfg, lc: LightCurve, mag_err: float | None,
                 strict: bool = False) -> tuple[TrajectoryProblem, Scene, torch.Tensor]:
    """The file as a :class:`~lightcurve_gp.inference.trajectory.TrajectoryProblem` (no anchors yet), its scene and
    its sample times (s from the first); a :class:`UserError` names what does not fit (with ``strict``, samples its
    TLE and site say cannot have been observed; without, they are a warning)."""
    dtype, device = cfg.torch_dtype, torch.device(cfg.device)
    dt = float(cfg.scenario.dt_s)
    steps = np.round(lc.t / dt)
    if np.abs(lc.t - steps * dt).max() > 1e-6 * dt:
        k = int(np.argmax(np.abs(lc.t - steps * dt)))
        raise UserError(f"{lc.source}: time, sample {k + 1} ({lc.t[k]:.6g} s after the first) is not on the "
                        f"scenario.dt_s = {dt:g} s grid the propagation uses; set scenario.dt_s to divide the steps")
    if lc.mag_err is None and mag_err is None:
        raise UserError(f"{lc.source}: no mag_err column; give the magnitudes' 1-sigma with --mag-err")
    try:
        geometry = file_geometry(lc, strict=strict, warn=warn)
    except FileGeometryError as exc:
        raise UserError(str(exc)) from None
    scene = Scene.from_config(cfg) if cfg.geometry.kind == "fixed" or geometry is not None else None
    if scene is None:
        raise UserError(f"{lc.source}: the config's geometry is a pass (geometry.kind: orbit) but the file gives no "
                        "per-sample geometry or TLE and site")
    if geometry is not None:
        scene = scene.with_geometry(geometry.sun, geometry.observer, geometry.range_m)
    scene = scene.to(device=device, dtype=dtype)
    sigma = lc.mag_err if lc.mag_err is not None else np.full(lc.t.size, mag_err)
    tensor = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64), dtype=dtype, device=device)  # noqa: E731
    problem = TrajectoryProblem(GroupRenderer(scene), torch.as_tensor(steps.astype(np.int64), device=device),
                                tensor(lc.mag), tensor(sigma), tensor(cfg.shape.inertia_kg_m2), dt,
                                torch.zeros(0, 4, dtype=dtype, device=device))
    return problem, scene, tensor(lc.t)


def _predictions(problem: TrajectoryProblem, fam: Families, top: int = 5) -> np.ndarray:
    """The magnitudes ``(min(top, F), K)`` of the leading families."""
    n = min(top, len(fam))
    x = torch.cat([torch.zeros(n, 3, dtype=fam.q0.dtype), fam.omega0[:n], fam.log_rho[:n, None]], -1)
    r = problem.with_anchors(fam.q0[:n]).residual(x, torch.arange(n))
    return (problem.y - r * problem.sigma).cpu().numpy()


def _figures(folder: Path, t: np.ndarray, problem: TrajectoryProblem, inv: Inversion, fam: Families) -> None:
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


def _summary(ans: Answer, group, settings: InversionSettings, record: dict) -> dict:
    inv, fam = ans.inversion, ans.families
    return {**ans.as_dict(), "verdict_words": ans.words(), "families": len(fam),
            "converged_solutions": int(inv.q0.shape[0]), "images": list(group.labels),
            "ambiguity_images": group.as_dict(), "top_weight": float(fam.weight[0]),
            "rate_candidates_deg_s": [float(r) for r in inv.periodogram.rates_deg_s],
            "periodogram_detection": inv.periodogram.detection,
            "screened_rates": int(inv.rate_grid.shape[0]), "seconds": {**inv.seconds, **ans.seconds},
            "settings": {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(settings).items()},
            "run": record}


def _run(args: argparse.Namespace) -> int:
    apply_threads(args.threads)
    cfg = load_config(args.config, args.overrides)
    settings = _settings(args)
    lc = read_light_curve(args.light_curve)
    problem, scene, t = file_problem(cfg, lc, args.mag_err, args.strict)
    check_output_root(args.out)
    folder = invert_folder(args.out, cfg.name, args.light_curve)
    check_new_folder(folder, args.force)
    show = progress_enabled(args.no_progress)
    say = (lambda message: tqdm.write(message)) if show else None
    group = ambiguity_group(scene, times_s=t, inertia=problem.inertia, rate_known=False, dt_s=problem.dt)
    try:
        ans = answer(problem, group, settings=settings, rate_max_rad_s=math.radians(args.rate_max),
                     max_log_ratio=args.max_log_ratio, progress=say)
    except ValueError as exc:  # the periodogram's one-line errors (e.g. a rate range that excludes it)
        raise UserError(f"{lc.source}: {exc}") from None
    inv, fam = ans.inversion, ans.families
    record = provenance(cfg, config_file=str(args.config), light_curve=str(args.light_curve))
    table = solutions_table(fam, {"light_curve": lc.source, "config": cfg.name, "verdict": ans.verdict,
                                  "chi2_per_dof": ans.fit.chi2_per_dof, "p_value": ans.fit.p_value})
    with RunFolder(folder, force=args.force) as tmp:
        write_solutions(table, tmp / "solutions.ecsv")
        write_json_atomic(_summary(ans, group, settings, record), tmp / "summary.json")
        _figures(tmp, t.cpu().numpy(), problem, inv, fam)
    best = table[0]
    print(f"{lc.source}: {len(fam)} families within {args.max_log_ratio:g} nats (modulo {len(group)} exact images); "
          f"best weight {float(best['weight']):.3f}, rate {math.hypot(*(float(best[f'omega_{a}']) for a in 'xyz')):.4g}"
          f" deg/s, rho {float(best['rho']):.3g}; {sum(ans.seconds.values()):.1f} s")
    print(f"verdict: {ans.words()}")
    print(f"written: {folder}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_command(lambda: _run(args), debug=args.debug)

