"""``python -m lightcurve_gp.estimate CONFIG --light-curve FILE [FILE ...]``: the attitude of an observed object.

Files of one object (:mod:`lightcurve_gp.observed.observations_file`: any sample times, gaps of any length, each
file its own light curve with its own geometry; ``--relative``: their zero points are unknown) become one
:class:`~lightcurve_gp.observations.Observations`, and by default the recommended estimator runs on it
(:mod:`lightcurve_gp.observed.arc_run`: the surface-state filter, then the whole-arc MAP of attitude and surface,
the shape known, ω known), from ``--initial-attitude`` (with ``filter.p0_deg`` its 1σ and the config's rate), from
the best family of an inversion's ``--solutions`` (its attitude, body rate and the rate's 1σ), or, given neither,
from the global inversion run here (:mod:`lightcurve_gp.observed.inversion_run`: the three leading families each
polished by the MAP, the best fit kept, the families written to ``solutions.ecsv``). It writes the new folder
``OUT/estimates/<name>/light_curve_<stem>/`` atomically (an existing one is refused unless ``--force``):
``attitude_history.ecsv`` (every sample's attitude with its 1σ over the whole arc, the fit and its residuals,
astropy units), ``summary.json`` (the verdict, χ² against its distribution with its p-value, surface, zero points,
modes, provenance), ``light_curve.png`` (the fit over the data with the residuals) and ``attitude.png``; it prints
the fit and the verdict in words (exit 0 also for ``"no_fit"``).

``--estimators gpukf`` runs the GPUKF instead on one file (``--model``; without a start, the global-start bank of
``--bank-size`` filters over SO(3), its verdict ``"unique"`` or ``"ambiguous"``); other estimators of the registry
that need no truth (``ukf``, ``joint_ukf``, ``surface_ukf``, ``surface_ukf_select``, ``no_update``) run beside ``map``
and write ``attitude_history_<name>.ecsv``.

Options that do not apply are refused before anything is read (:func:`check_options`): ``--seeds`` and
``--rho-true`` with ``--light-curve``; ``--initial-attitude``, ``--solutions`` and the bank options without it; the
bank options with a start or without ``gpukf``.
A file with a TLE and site whose samples cannot have been observed (below the horizon, the site in daylight, the
object in the Earth's shadow) is one warning line on stderr, or refused with ``--strict``.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

import torch
from tqdm.auto import tqdm

from lightcurve_gp.commands.common import (
    STRICT_HELP,
    UserError,
    check_new_folder,
    check_output_root,
    check_unit_quaternion,
    progress_enabled,
    provenance,
    run_interruptible,
    warn,
)
from lightcurve_gp.commands.layout import light_curve_folder
from lightcurve_gp.evaluation.registry import ESTIMATORS, RunContext
from lightcurve_gp.files import RunFolder, write_json_atomic
from lightcurve_gp.inference.inversion import InversionSettings
from lightcurve_gp.observed.arc_run import (
    arc_history_table,
    arc_report,
    arc_summary,
    check_observations,
    estimate_arc,
    estimate_table,
    file_scene,
)
from lightcurve_gp.observed.information import flat_light_curve
from lightcurve_gp.observed.inversion_run import invert_observations
from lightcurve_gp.observed.lightcurve_file import read_light_curve
from lightcurve_gp.observed.observations_file import read_observations
from lightcurve_gp.observed.plots import attitude_with_uncertainty, fit_with_residuals, light_curve_band
from lightcurve_gp.observed.result import finish
from lightcurve_gp.observed.run import (
    FileGeometryError,
    check_light_curve,
    check_model_takes_geometry,
    estimate_light_curve,
    file_geometry,
)
from lightcurve_gp.observed.solutions import (
    SolutionsFileError,
    best_solution,
    rate_sigma,
    read_solutions,
    solutions_table,
    write_solutions,
)
from lightcurve_gp.observed.table_write import write_table
from lightcurve_gp.observed.verdict import ambiguity_images

__all__ = ["BANK_DEFAULTS", "FILE_DEFAULT", "FILE_ESTIMATORS", "add_file_arguments", "check_options", "file_estimators",
           "parse_quaternion", "run_on_file"]

#: the bank options' values when not given
BANK_DEFAULTS = {"bank_size": 1024, "bank_keep": 5, "bank_prune_after_s": None, "bank_prune_keep": 64}
#: options of a simulated scenario, and why a file has no use for them
SCENARIO_OPTIONS = {
    "seeds": "the files are the observations of one object",
    "rho_true": "the file's magnitudes are what they are; the surface (rho with it) is estimated"}
#: what runs on files unless --estimators says otherwise
FILE_DEFAULT = "map"
#: estimators that run on files beside map (the registry's, without the truth)
FILE_ESTIMATORS = ("map", "gpukf", "ukf", "joint_ukf", "surface_ukf", "surface_ukf_select", "no_update")


def add_file_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of a run on a light-curve file."""
    parser.add_argument("--light-curve", type=Path, nargs="+", default=None, metavar="FILE",
                        help="estimate from these light-curve files of one object (.ecsv, .csv, .fits; any sample "
                             "times, each file its own light curve) instead of simulating; by default the whole-arc "
                             "MAP; writes OUT/estimates/<name>/light_curve_<first file's stem>/")
    parser.add_argument("--relative", action="store_true",
                        help="with --light-curve: the files' zero points are unknown (relative photometry); one "
                             "magnitude offset per file is fitted")
    parser.add_argument("--mag-err", type=float, default=None,
                        help="with --light-curve: 1-sigma (mag) of every sample of a file without a mag_err column "
                             "(default: the square root of filter.measurement_noise)")
    parser.add_argument("--initial-attitude", default=None, metavar="Q1,Q2,Q3,Q4",
                        help="with --light-curve: start from this quaternion (scalar last) instead of the bank; write "
                             "--initial-attitude=Q1,... when Q1 is negative")
    parser.add_argument("--solutions", type=Path, default=None,
                        help="with --light-curve: start from the best family of this invert solutions file (its "
                             "attitude and body rate) instead of the bank")
    parser.add_argument("--bank-size", type=int, default=None,
                        help="with --light-curve and no --initial-attitude: filters in the global-start bank "
                             "(default 1024)")
    parser.add_argument("--bank-keep", type=int, default=None,
                        help="bank members rerun with the config's settings and reported (default 5)")
    parser.add_argument("--bank-prune-after-s", type=float, default=None, metavar="SECONDS",
                        help="run every bank member over the first SECONDS of the file, then only the best "
                             "--bank-prune-keep (default: no pruning)")
    parser.add_argument("--bank-prune-keep", type=int, default=None,
                        help="bank members that continue after --bank-prune-after-s (default 64)")
    parser.add_argument("--strict", action="store_true", help=f"with --light-curve: {STRICT_HELP}")


def _option(name: str) -> str:
    return "--" + name.replace("_", "-")


def check_options(args: argparse.Namespace) -> None:
    """Refuse an option the run would ignore (module docstring), naming it; then fill in :data:`BANK_DEFAULTS`."""
    given = lambda name: getattr(args, name) is not None  # noqa: E731
    if args.light_curve is not None:
        for name, why in SCENARIO_OPTIONS.items():
            if given(name):
                raise UserError(f"{_option(name)}: does not apply with --light-curve ({why})")
    for name in ("initial_attitude", "solutions", "mag_err", *BANK_DEFAULTS):
        if given(name) and args.light_curve is None:
            raise UserError(f"{_option(name)}: applies only with --light-curve")
        for start in ("initial_attitude", "solutions"):
            if given(name) and name in BANK_DEFAULTS and given(start):
                raise UserError(f"{_option(name)}: does not apply with {_option(start)} (no bank runs)")
    if args.relative and args.light_curve is None:
        raise UserError("--relative: applies only with --light-curve")
    if args.strict and args.light_curve is None:
        raise UserError("--strict: applies only with --light-curve")
    if given("bank_prune_keep") and not given("bank_prune_after_s"):
        raise UserError("--bank-prune-keep: applies only with --bank-prune-after-s")
    for name, value in BANK_DEFAULTS.items():
        if not given(name):
            setattr(args, name, value)


def parse_quaternion(text: str) -> torch.Tensor:
    """``"q1,q2,q3,q4"`` → a float64 unit quaternion ``(4,)``; a :class:`UserError` names ``--initial-attitude``
    (and the norm, when it is off 1: :func:`~lightcurve_gp.commands.common.check_unit_quaternion`)."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise UserError(f"--initial-attitude: {text!r} is not four numbers q1,q2,q3,q4") from None
    q = torch.tensor(values, dtype=torch.float64)
    if q.numel() != 4 or not bool(torch.isfinite(q).all()) or float(q.norm()) < 1e-6:
        raise UserError(f"--initial-attitude: {text!r} must be four finite numbers q1,q2,q3,q4 (scalar last), "
                        f"not all zero")
    check_unit_quaternion(values, option="--initial-attitude")
    return q


def file_estimators(text: str | None) -> list[str]:
    """The estimators ``--estimators`` names for files (default :data:`FILE_DEFAULT`); a :class:`UserError` names one
    that cannot run on a file."""
    if text is None:
        return [FILE_DEFAULT]
    names = [n.strip() for n in text.split(",") if n.strip()]
    if not names:
        raise UserError("--estimators: empty list")
    for name in names:
        if name not in FILE_ESTIMATORS:
            why = "it needs the truth of a simulation" if name in ESTIMATORS else "no such estimator"
            raise UserError(f"--estimators: {name!r} cannot run on a light-curve file ({why}); choose from "
                            f"{', '.join(FILE_ESTIMATORS)}")
    if "gpukf" in names and len(names) > 1:
        raise UserError("--estimators: gpukf runs alone on a light-curve file (its own start and bank)")
    return names


def _check_bank(args: argparse.Namespace) -> None:
    if args.bank_size < 1 or not 1 <= args.bank_keep <= args.bank_size:
        raise UserError(f"--bank-size/--bank-keep: need bank size >= 1 and 1 <= keep <= size, got "
                        f"{args.bank_size} and {args.bank_keep}")
    if args.bank_prune_after_s is not None and (not args.bank_prune_after_s > 0 or
                                                 args.bank_prune_keep < args.bank_keep):
        raise UserError(f"--bank-prune-after-s/--bank-prune-keep: need a time > 0 and at least --bank-keep "
                        f"({args.bank_keep}) members kept, got {args.bank_prune_after_s:g} and {args.bank_prune_keep}")


def _from_solutions(args: argparse.Namespace, cfg):
    """The config with the best family's body rate, that family's attitude ``(4,)`` and its rate's 1σ ``(3,)``
    (rad/s, ``None`` when the file has none) (module docstring)."""
    if args.initial_attitude is not None:
        raise UserError("--solutions: give --initial-attitude or --solutions, not both")
    try:
        table = read_solutions(args.solutions)
        q, w, _ = best_solution(table)
    except SolutionsFileError as exc:
        raise UserError(str(exc)) from None
    if table.meta.get("verdict") == "no_fit":
        warn(f"{args.solutions}: the inversion found no solution that fits (chi2/dof "
             f"{float(table.meta.get('chi2_per_dof', float('nan'))):.2f}); its best family is a start, not an answer")
    rate = [math.degrees(float(v)) for v in w]
    return dataclasses.replace(cfg, scenario=dataclasses.replace(cfg.scenario, omega0_deg_s=rate)), q, \
        rate_sigma(table)


def _folder(args: argparse.Namespace, cfg) -> Path:
    first = Path(args.light_curve[0])
    stem = first if len(args.light_curve) == 1 else first.with_name(f"{first.stem}_and_{len(args.light_curve) - 1}"
                                                                     f"_more{first.suffix}")
    return light_curve_folder(args.out, cfg.name, stem)


def run_on_file(args: argparse.Namespace, cfg, model, model_info: dict) -> int:
    """The command's body for ``--light-curve`` (module docstring); everything is checked before anything runs."""
    names = file_estimators(args.estimators)
    if names == ["gpukf"]:
        return _run_gpukf(args, cfg, model, model_info)
    for name in BANK_DEFAULTS:
        if getattr(args, name) != BANK_DEFAULTS[name]:
            raise UserError(f"{_option(name)}: applies only with --estimators gpukf (the bank of filters)")
    if args.mag_err is not None and not args.mag_err > 0:
        raise UserError(f"--mag-err: {args.mag_err:g} must be > 0 mag")
    q0 = None if args.initial_attitude is None else parse_quaternion(args.initial_attitude)
    omega_sigma = None
    if getattr(args, "solutions", None) is not None:
        cfg, q0, omega_sigma = _from_solutions(args, cfg)
    mag_err = args.mag_err if args.mag_err is not None else math.sqrt(cfg.filter.measurement_noise)
    try:
        obs = read_observations(args.light_curve, mag_err=mag_err, relative=args.relative, strict=args.strict,
                                warn=warn)
        check_observations(obs)
        scene = file_scene(cfg, obs)
    except (FileGeometryError, ValueError) as exc:
        raise UserError(str(exc)) from None
    check_output_root(args.out)
    folder = _folder(args, cfg)
    check_new_folder(folder, args.force)
    record = provenance(cfg, config_file=str(args.config), light_curves=[str(p) for p in args.light_curve],
                        initial_attitude=args.initial_attitude, relative=args.relative, mag_err_default=mag_err,
                        solutions=None if getattr(args, "solutions", None) is None else str(args.solutions),
                        estimators=names, **model_info)
    omega0 = torch.deg2rad(torch.tensor(cfg.scenario.omega0_deg_s, dtype=torch.float64))
    sigma0 = math.radians(cfg.filter.p0_deg)
    show = progress_enabled(args.no_progress)
    inversion = None
    if q0 is None:  # no start: the global inversion, then the MAP from its leading families
        say = (lambda message: tqdm.write(message, file=sys.stderr)) if show else None
        try:
            inversion = run_interruptible(lambda: invert_observations(cfg, obs, settings=InversionSettings(),
                                                                      progress=say),
                                          status="the global inversion (no start given)", progress=show)
        except ValueError as exc:
            raise UserError(f"{obs.curves[0].source}: {exc}") from None
        run = min(inversion.polished, key=lambda arc: arc.chi2)
    else:
        run = run_interruptible(lambda: estimate_arc(cfg, obs, q0=q0, sigma0=sigma0, omega0=omega0,
                                                     omega_sigma=omega_sigma),
                                status="running the surface-state filter, then the whole-arc MAP", progress=show)
    others = {}
    for name in (n for n in names if n != "map"):
        context = RunContext(cfg, run.problem, scene, model)
        others[name] = run_interruptible(lambda n=name: ESTIMATORS[n].run(context), status=f"running {name}",
                                         progress=progress_enabled(args.no_progress))
    summary = arc_summary(run, record)
    if inversion is not None:
        summary["start"] = {"from": "the global inversion (no start given)", "verdict": inversion.answer.verdict,
                            "verdict_words": inversion.answer.words(), "families": len(inversion.families),
                            "polished": len(inversion.polished),
                            "chosen_family": 1 + inversion.polished.index(run),
                            "weights": [float(w) for w in inversion.families.weight[:len(inversion.polished)]]}
    with RunFolder(folder, force=args.force) as tmp:
        history = arc_history_table(run)
        write_table(history, tmp / "attitude_history.ecsv", fmt="ascii.ecsv")
        for name, estimate in others.items():
            write_table(estimate_table(run.problem, estimate), tmp / f"attitude_history_{name}.ecsv",
                        fmt="ascii.ecsv")
        if inversion is not None:
            ans = inversion.answer
            write_solutions(solutions_table(inversion.families, {
                "light_curve": obs.curves[0].source, "config": cfg.name, "verdict": ans.verdict,
                "chi2_per_dof": ans.fit.chi2_per_dof, "p_value": ans.fit.p_value}), tmp / "solutions.ecsv")
        write_json_atomic(summary, tmp / "summary.json")
        title = f"{Path(args.light_curve[0]).name}{' …' if len(args.light_curve) > 1 else ''}: whole-arc MAP " \
                f"({summary['verdict'].replace('_', ' ')})"
        fit_with_residuals(history, tmp / "light_curve.png", title=title)
        attitude_with_uncertainty(history, tmp / "attitude.png", title=title)
    if inversion is not None:
        chosen = summary["start"]["chosen_family"]
        print(f"start: the global inversion's family {chosen} of {len(inversion.families)} (weight "
              f"{summary['start']['weights'][chosen - 1]:.3f}), the best fit of the {len(inversion.polished)} "
              f"polished; the families are in solutions.ecsv; the inversion's verdict: {inversion.answer.words()}")
    print("\n".join(arc_report(run)))
    print(f"written: {folder}")
    return 0


def _check_arguments(args: argparse.Namespace) -> torch.Tensor | None:
    if args.model is None:
        raise UserError("--model: the gpukf estimator needs a trained model file (python -m lightcurve_gp.train)")
    if len(args.light_curve) != 1:
        raise UserError("--light-curve: gpukf runs on one light-curve file; the default estimator takes several")
    _check_bank(args)
    return None if args.initial_attitude is None else parse_quaternion(args.initial_attitude)


def _run_gpukf(args: argparse.Namespace, cfg, model, model_info: dict) -> int:
    """The GPUKF on one file, from a start or from the global-start bank."""
    q0 = _check_arguments(args)
    if getattr(args, "solutions", None) is not None:
        cfg, q0, _ = _from_solutions(args, cfg)
    path = Path(args.light_curve[0])
    lc = read_light_curve(path)
    check_light_curve(cfg, lc)
    try:
        check_model_takes_geometry(model, lc)
        geometry = file_geometry(lc, strict=args.strict, warn=warn)
    except FileGeometryError as exc:
        raise UserError(str(exc)) from None
    check_output_root(args.out)
    folder = light_curve_folder(args.out, cfg.name, path)
    check_new_folder(folder, args.force)
    warn(flat_light_curve(lc, noise_std=math.sqrt(cfg.filter.measurement_noise)))
    record = provenance(cfg, config_file=str(args.config), light_curve=str(path),
                        initial_attitude=args.initial_attitude,
                        solutions=None if getattr(args, "solutions", None) is None else str(args.solutions),
                        bank_size=None if q0 is not None else args.bank_size,
                        bank_prune_after_s=None if q0 is not None else args.bank_prune_after_s,
                        bank_prune_keep=None if q0 is not None or args.bank_prune_after_s is None
                        else args.bank_prune_keep, **model_info)
    status = "filter" if q0 is not None else f"bank of {args.bank_size} filters"
    if getattr(args, "solutions", None) is not None:
        status = "filter from the inversion's best family"
    run = run_interruptible(lambda: estimate_light_curve(cfg, model, lc, initial_attitude=q0,
                                                         bank_size=args.bank_size, keep=args.bank_keep,
                                                         prune_after_s=args.bank_prune_after_s,
                                                         prune_keep=args.bank_prune_keep),
                            status=f"running the {status}", progress=progress_enabled(args.no_progress))
    group = None if run.bank is None else ambiguity_images(cfg, samples=len(lc.t), geometry=geometry)
    result = finish(run, record=record, status=status, group=group, p0_deg=cfg.filter.p0_deg,
                    rho_reference=cfg.model.rho_reference if cfg.filter.estimate_offset else None)
    with RunFolder(folder, force=args.force) as tmp:
        write_table(result.history, tmp / "attitude_history.ecsv", fmt="ascii.ecsv")
        if result.bank is not None:
            write_table(result.bank, tmp / "bank.ecsv", fmt="ascii.ecsv")
        write_json_atomic(result.summary, tmp / "summary.json")
        title = f"{lc.source}: {status}"
        light_curve_band(result.history, tmp / "light_curve.png", title=title)
        attitude_with_uncertainty(result.history, tmp / "attitude.png", title=title)
    print("\n".join(result.report()))
    print(f"written: {folder}")
    return 0
