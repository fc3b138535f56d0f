"""``python -m lightcurve_gp.estimate CONFIG --model M --light-curve obs.ecsv``: the GPUKF on a light-curve file.

Writes the new folder ``OUT/estimates/<name>/light_curve_<file stem>/`` atomically (an existing one is refused unless
``--force``): ``attitude_history.ecsv`` (:func:`lightcurve_gp.observed.run.history_table`), ``summary.json`` (the NIS
against its χ² band, the bank's size, time and best members with their posterior weights, the run's provenance),
``bank.ecsv`` (every bank member, ranked) when the global start ran, ``light_curve.png`` and ``attitude.png``.
Without ``--initial-attitude`` the run starts from the global-start bank (``--bank-size`` filters over SO(3); with
``--bank-prune-after-s`` only the best ``--bank-prune-keep`` run past that time), and the bank's posterior is judged
(:mod:`lightcurve_gp.observed.verdict`): ``summary.json``'s ``verdict`` is ``"unique"``, ``"ambiguous"`` or, for a
bank too coarse to cover SO(3), ``"inconclusive"`` (``null`` without a bank); an ambiguous answer or a coarse bank is
printed as a warning in words, as is a flat light curve; the exit code stays 0.

Options that do not apply are refused before anything is read (:func:`check_options`): ``--seeds``, ``--rho-true``
and ``--estimators`` with ``--light-curve``; ``--initial-attitude``, ``--solutions`` and the bank options without
it; the bank options with ``--initial-attitude`` or ``--solutions`` (no bank runs then). A light curve too short
for the filter's state, or too long for the known-spin propagation, is refused before the filter runs
(:func:`lightcurve_gp.observed.run.check_light_curve`).

A file with per-sample geometry or a TLE and site runs along its pass
(:func:`lightcurve_gp.observed.run.file_geometry`) with a model that takes geometry.
``--solutions solutions.ecsv`` (from ``python -m lightcurve_gp.invert``) starts the filter from the best family of the
inversion instead: its attitude at the first sample and its body rate (which replaces ``scenario.omega0_deg_s``).
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path

import torch

from lightcurve_gp.commands.common import (
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
from lightcurve_gp.files import RunFolder, write_json_atomic
from lightcurve_gp.observed.information import flat_light_curve
from lightcurve_gp.observed.lightcurve_file import read_light_curve, write_table
from lightcurve_gp.observed.plots import attitude_with_uncertainty, light_curve_band
from lightcurve_gp.observed.result import finish
from lightcurve_gp.observed.run import (
    FileGeometryError,
    check_light_curve,
    check_model_takes_geometry,
    estimate_light_curve,
    file_geometry,
)
from lightcurve_gp.observed.solutions import SolutionsFileError, best_solution, read_solutions
from lightcurve_gp.observed.verdict import ambiguity_images

__all__ = ["BANK_DEFAULTS", "add_file_arguments", "check_options", "parse_quaternion", "run_on_file"]

#: the bank options' values when not given
BANK_DEFAULTS = {"bank_size": 1024, "bank_keep": 5, "bank_prune_after_s": None, "bank_prune_keep": 64}
#: options of a simulated scenario, and why a file has no use for them
SCENARIO_OPTIONS = {
    "seeds": "the file is one observed light curve",
    "rho_true": "the file's magnitudes are what they are; filter.estimate_offset estimates their offset",
    "estimators": "a file runs the GPUKF alone"}


def add_file_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of a run on a light-curve file."""
    parser.add_argument("--light-curve", type=Path, default=None,
                        help="run the GPUKF on this light-curve file (.ecsv, .csv, .fits) instead of simulating; "
                             "writes OUT/estimates/<name>/light_curve_<file stem>/")
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


def _option(name: str) -> str:
    return "--" + name.replace("_", "-")


def check_options(args: argparse.Namespace) -> None:
    """Refuse an option the run would ignore (module docstring), naming it; then fill in :data:`BANK_DEFAULTS`."""
    given = lambda name: getattr(args, name) is not None  # noqa: E731
    if args.light_curve is not None:
        for name, why in SCENARIO_OPTIONS.items():
            if given(name):
                raise UserError(f"{_option(name)}: does not apply with --light-curve ({why})")
    for name in ("initial_attitude", "solutions", *BANK_DEFAULTS):
        if given(name) and args.light_curve is None:
            raise UserError(f"{_option(name)}: applies only with --light-curve")
        for start in ("initial_attitude", "solutions"):
            if given(name) and name in BANK_DEFAULTS and given(start):
                raise UserError(f"{_option(name)}: does not apply with {_option(start)} (no bank runs)")
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


def _check_arguments(args: argparse.Namespace) -> torch.Tensor | None:
    if args.model is None:
        raise UserError("--model: --light-curve runs the GPUKF, which needs a trained model file")
    if args.bank_size < 1 or not 1 <= args.bank_keep <= args.bank_size:
        raise UserError(f"--bank-size/--bank-keep: need bank size >= 1 and 1 <= keep <= size, got "
                        f"{args.bank_size} and {args.bank_keep}")
    if args.bank_prune_after_s is not None and (not args.bank_prune_after_s > 0 or
                                                 args.bank_prune_keep < args.bank_keep):
        raise UserError(f"--bank-prune-after-s/--bank-prune-keep: need a time > 0 and at least --bank-keep "
                        f"({args.bank_keep}) members kept, got {args.bank_prune_after_s:g} and {args.bank_prune_keep}")
    return None if args.initial_attitude is None else parse_quaternion(args.initial_attitude)


def _from_solutions(args: argparse.Namespace, cfg):
    """The config with the best family's body rate and that family's attitude ``(4,)`` (module docstring)."""
    if args.initial_attitude is not None:
        raise UserError("--solutions: give --initial-attitude or --solutions, not both")
    try:
        q, w, _ = best_solution(read_solutions(args.solutions))
    except SolutionsFileError as exc:
        raise UserError(str(exc)) from None
    rate = [math.degrees(float(v)) for v in w]
    return dataclasses.replace(cfg, scenario=dataclasses.replace(cfg.scenario, omega0_deg_s=rate)), q


def run_on_file(args: argparse.Namespace, cfg, model, model_info: dict) -> int:
    """The command's body for ``--light-curve`` (module docstring); everything is checked before the filter runs."""
    q0 = _check_arguments(args)
    if getattr(args, "solutions", None) is not None:
        cfg, q0 = _from_solutions(args, cfg)
    lc = read_light_curve(args.light_curve)
    check_light_curve(cfg, lc)
    try:
        check_model_takes_geometry(model, lc)
        geometry = file_geometry(lc)
    except FileGeometryError as exc:
        raise UserError(str(exc)) from None
    check_output_root(args.out)
    folder = light_curve_folder(args.out, cfg.name, args.light_curve)
    check_new_folder(folder, args.force)
    warn(flat_light_curve(lc, noise_std=math.sqrt(cfg.filter.measurement_noise)))
    record = provenance(cfg, config_file=str(args.config), light_curve=str(args.light_curve),
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
