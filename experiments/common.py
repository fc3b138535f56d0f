"""What the experiments share: the repository root, the argument tables, the model lookup, seed ranges, the goal
check, the output writer, the generalisation suite's truth modes and the spin study's cases and table rows.

Each experiment is one script on top of the library; what two of them need lives here, so that no script imports
another. Finished cases are kept through the sweep's case store (:func:`lightcurve_gp.sweep.store.resume_case`).
"""

from __future__ import annotations

import argparse
import json
import math
import operator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

from lightcurve_gp.config.load import ConfigError
from lightcurve_gp.evaluation.reporting import CaseRecord, format_quantiles, quantiles
from lightcurve_gp.files import write_json_atomic, write_text_atomic
from lightcurve_gp.simulation.truths import draw_truths, paper_case_draw
from lightcurve_gp.sweep.executors import CLUSTER_EXTRA, EXECUTORS
from lightcurve_gp.training.store import get_or_train

__all__ = ["ROOT", "ROBUST_CONFIG", "sweep_arguments", "robust_arguments", "trained_model", "command_line",
           "seed_range", "seed_block", "floats", "GoalCheck", "goal_check", "write_outputs", "SUITE_ESTIMATORS",
           "registry_name", "truth_mode_label", "truth_draw", "SPIN_HEADER", "case_overrides", "spin_table_row"]

ROOT = Path(__file__).resolve().parents[1]
ROBUST_CONFIG = ROOT / "configs" / "boxwing_robust.yaml"


# ----------------------------------------------------------------------------------------------- arguments

def sweep_arguments(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add the options of a sweep's executor (see :func:`lightcurve_gp.sweep.make_executor`), threads and progress."""
    parser.add_argument("--executor", choices=EXECUTORS, default="local",
                        help="local (this machine) or dask (a LocalCluster of --workers processes, or --scheduler; "
                             f"needs {CLUSTER_EXTRA}) (default local)")
    parser.add_argument("--scheduler", default=None, metavar="ADDRESS",
                        help="address of a running dask scheduler (with --executor dask)")
    parser.add_argument("--workers", type=int, default=1,
                        help="worker processes of the local pool or the LocalCluster (default 1)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads of the command and of each case process "
                        "(default 1)")
    parser.add_argument("--no-progress", action="store_true", help="hide progress bars")
    return parser


def robust_arguments(description: str, *, seeds: int, seed_start: int, seed_help: str) -> argparse.ArgumentParser:
    """``--config``, ``--seeds``, ``--seed-start``, ``--out`` (committed summaries) and ``--runs`` (trained
    models)."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--config", default=str(ROBUST_CONFIG))
    p.add_argument("--seeds", type=int, default=seeds, help=f"noise seeds (default {seeds})")
    p.add_argument("--seed-start", type=int, default=seed_start,
                   help=f"first noise seed (default {seed_start}: {seed_help})")
    p.add_argument("--out", default=str(ROOT / "experiments/results/robust"), type=Path)
    p.add_argument("--runs", default=str(ROOT / "runs"), type=Path, help="where trained models are kept")
    return p


def trained_model(cfg, runs: Path):
    """The model of ``cfg`` from the model store ``runs/models`` (trained there when missing)."""
    return get_or_train(cfg, runs / "models", cache_dir=runs / "cache")[0]


def command_line(script: str, argv: Sequence[str]) -> str:
    """The command that ran: ``python -m experiments.<script> <argv>``."""
    return " ".join([f"python -m experiments.{script}", *argv])


# ----------------------------------------------------------------------------------------------- seeds and lists

def seed_rows(path: Path, seeds: range | None = None) -> list[dict]:
    """The rows of a resumable JSON-lines file ``path`` (one object with a ``"seed"`` per line; none if it does not
    exist), those of ``seeds`` only when given."""
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.exists() else []
    return rows if seeds is None else [r for r in rows if r["seed"] in seeds]


def append_row(path: Path, row: dict) -> None:
    """One row appended to the JSON-lines file ``path`` and flushed (a run stopped between seeds loses none)."""
    with open(path, "a") as fh:
        fh.write(json.dumps(row) + "\n")
        fh.flush()


def seed_range(text: str) -> range:
    """``"2000:2300"`` → ``range(2000, 2300)``."""
    try:
        lo, hi = (int(v) for v in text.split(":"))
    except ValueError:
        raise ConfigError(f"seed block {text!r}: expected FIRST:END, e.g. 2000:2300") from None
    if hi <= lo:
        raise ConfigError(f"seed block {text!r}: END must exceed FIRST")
    return range(lo, hi)


def seed_block(args: argparse.Namespace) -> range:
    """The ``args.seeds`` noise seeds from ``args.seed_start``."""
    return range(args.seed_start, args.seed_start + args.seeds)


def floats(text: str) -> list[float]:
    """``"0.3,0.7"`` → ``[0.3, 0.7]`` (empty items skipped)."""
    return [float(v) for v in text.split(",") if v.strip()]


# ----------------------------------------------------------------------------------------------- goals and outputs

_COMPARE = {"<=": operator.le, ">=": operator.ge}


@dataclass(frozen=True)
class GoalCheck:
    """Each criterion's verdict (``"<name>_met"``) and one line per criterion (``"<name> <value> <op> <bound>:
    met"``)."""

    flags: dict[str, bool]
    lines: list[str]

    @property
    def met(self) -> bool:
        return all(self.flags.values())


def _holds(value: float, op: str, bound) -> bool:
    if op == "in":
        return bound[0] <= value <= bound[1]
    if op == "within":
        return abs(value - bound[0]) <= bound[1]
    return _COMPARE[op](value, bound)


def _bound_text(op: str, bound) -> str:
    if op == "in":
        return f"in [{bound[0]:.3g}, {bound[1]:.3g}]"
    return f"within {bound[1]:.3g} of {bound[0]:.3g}" if op == "within" else f"{op} {bound:.3g}"


def goal_check(measured: Mapping[str, float | Sequence[float]], goals: Mapping[str, tuple[str, Any]]) -> GoalCheck:
    """Check named criteria against measured values.

    Args:
        measured: per criterion name its value: a number, or one per axis (then every one must hold).
        goals: per criterion name ``(op, bound)``: ``"<="`` or ``">="`` a number, ``"in"`` a closed band
            ``(low, high)``, ``"within"`` ``(centre, tolerance)`` (``|value - centre| <= tolerance``).
    """
    flags, lines = {}, []
    for name, (op, bound) in goals.items():
        value = measured[name]
        values = list(value) if isinstance(value, (list, tuple)) else [value]
        flags[f"{name}_met"] = all(_holds(v, op, bound) for v in values)
        lines.append(f"{name} {', '.join(f'{v:.3g}' for v in values)} {_bound_text(op, bound)}: "
                     + ("met" if flags[f"{name}_met"] else "NOT met"))
    return GoalCheck(flags, lines)


def write_outputs(folder: Path, files: Mapping[str, Any]) -> None:
    """Write each ``name: content`` into ``folder`` atomically: text as it is, anything else as JSON."""
    for name, content in files.items():
        if isinstance(content, str):
            write_text_atomic(content, Path(folder) / name)
        else:
            write_json_atomic(content, Path(folder) / name)


# ----------------------------------------------------------------------------------------------- generalisation suite

#: the suite's estimators by their table names (``robust_gpukf``: the registry's ``gpukf`` of the robust config)
SUITE_ESTIMATORS = ("robust_gpukf", "matched_ukf", "joint_ukf", "surface_ukf", "surface_ukf_select", "map_surface",
                    "map_offset", "no_update")


def registry_name(name: str) -> str:
    """The registry's name of a suite estimator."""
    return "gpukf" if name == "robust_gpukf" else name


def truth_mode_label(mode) -> str:
    """``None`` (random truths) → ``"random"``, an angle → ``"10"``, ``("paper", 0.7)`` → ``"paper rho 0.7"``."""
    if mode is None:
        return "random"
    return f"paper rho {mode[1]:g}" if isinstance(mode, tuple) else f"{mode:g}"


def truth_draw(cfg, seeds: Sequence[int], mode):
    """The truths of one block: random (``None``), random with a fixed initial-error angle, or the paper's case
    (``("paper", rho)``)."""
    if isinstance(mode, tuple):
        return paper_case_draw(cfg, seeds, rho=mode[1])
    return draw_truths(seeds, error_deg=mode)


# ----------------------------------------------------------------------------------------------- spin study

SPIN_HEADER = ("estimator", "yaw", "pitch", "roll", "< 10° all axes",
               "mod symmetry: < 10° all axes (nearest truth a mirror), NEES full",
               "NEES δp (band)", "NEES full (band)",
               "ω RMSE °/s", "final ω error °/s", "ms / step")


def case_overrides(duration: float, sigma: float | None) -> list[str]:
    """The config of one column of spin cases: duration with its scoring window (the last 200 s), and the rate
    prior std σ_ω (deg/s) with a start off by ``σ_ω (1, −1, 1)`` (None: ω known)."""
    out = [f"scenario.duration_s={duration:g}", f"evaluation.rmse_window_s=[{duration - 200:g}, {duration:g}]"]
    if sigma is not None:
        out += ["filter.estimate_omega=true", f"filter.p0_omega_deg_s={sigma:g}",
                f"scenario.initial_omega_error_deg_s=[{sigma:g}, {-sigma:g}, {sigma:g}]"]
    return out


def _band(entry: dict, key: str, band_key: str) -> str:
    lo, hi = entry[band_key]
    return f"{entry[key]:.2f} ({lo:.2f}–{hi:.2f})"


def _mod_symmetry(entry: dict) -> str:
    """The share below 10° modulo the shape's symmetry, the share whose nearest truth is a mirror and the full
    state's mean NEES against that truth ("–" for records scored before)."""
    if "fraction_all_axes_below_10deg_mod_symmetry" not in entry:
        return "–"
    nees = entry["nees_full_mean_mod_symmetry"]
    text = (f"{100 * entry['fraction_all_axes_below_10deg_mod_symmetry']:.0f} % "
            f"({100 * entry['fraction_nearest_symmetric_not_truth']:.0f} %)")
    return text if math.isnan(nees) else f"{text}, {nees:.2f}"


def spin_table_row(label: str, record: CaseRecord, name: str) -> list[str]:
    """Cells of :data:`SPIN_HEADER`: median [IQR] RMSE per axis over seeds and the rest of the case summary."""
    e = record.summary["estimators"][name]
    rmse = record.rmse_deg(name)
    lo, hi = record.summary["nees_band_95"]
    nees = "–" if name == "no_update" else f"{e['nees_mean']:.2f} ({lo:.2f}–{hi:.2f})"
    full = "–" if name == "no_update" else _band(e, "nees_full_mean", "nees_full_band_95")
    omega = quantiles(record.metric(name, "omega_rmse_deg_s"))
    final = quantiles(record.metric(name, "omega_error_final_deg_s"))
    return [label, *(format_quantiles(quantiles(rmse[:, i])) for i in range(3)),
            f"{100 * e['fraction_all_axes_below_10deg']:.0f} %", _mod_symmetry(e), nees, full,
            format_quantiles(omega, 4), format_quantiles(final, 4), f"{1e3 * e['seconds_per_step']:.1f}"]
