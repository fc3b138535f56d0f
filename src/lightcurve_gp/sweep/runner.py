"""``python -m lightcurve_gp.sweep CONFIG --grid KEY=V1,V2,... --seeds N``: resumable parameter sweeps.

A sweep is the cartesian product of its grid axes (any config key, values parsed as YAML). Each grid point is a
*case*: one validated config, run with every seed batched in one filter per estimator
(:func:`~lightcurve_gp.estimation.run_estimators`). Storage under ``<out>/<name>/``:

* ``models/<model-hash>/model.pt`` (+ ``metrics.json``, held-out figures): one GP per distinct ``geometry``,
  ``shape``, ``surface``, ``data``, ``model`` setting (and dtype), trained by :func:`lightcurve_gp.train.train`
  and reused by every case, sweep and rerun that needs it;
* ``cases/<case-id>.json``: one atomic file per finished case, content-addressed — the case id hashes the whole
  config, the seeds and the estimators — so identical cases are shared between sweeps and a rerun skips them.
  It holds the per-(seed, estimator) rows, the estimators' summary and the seed-0 traces for figures. A case
  that raised is stored with ``status = "failed"`` and its error; a rerun retries it.
* ``sweep/<sweep-id>/``: ``sweep.json`` (the definition), ``results.csv`` (one row per case × seed ×
  estimator, :data:`RESULT_COLUMNS` after the grid columns), ``summary.csv`` and ``summary.json`` (median and
  IQR per case and estimator).

Config errors (unknown key, bad value) stop the sweep before any work and name the key; a run-time failure of one
case is recorded and the others go on. Ctrl-C keeps every finished case.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import csv
import io
import itertools
import json
import math
import multiprocessing
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch
import yaml
from tqdm.auto import tqdm

from .config import Config, ConfigError, apply_overrides, config_from_dict, config_hash, config_to_dict
from .estimation import DEFAULT_ESTIMATORS, ESTIMATORS, ScenarioResult, run_estimators
from .io import write_json_atomic, write_text_atomic

__all__ = ["RESULT_COLUMNS", "SUMMARY_COLUMNS", "MODEL_SECTIONS", "Case", "SweepResult", "parse_grid",
           "expand_grid", "make_cases", "model_key", "ensure_models", "run_case", "run_sweep", "read_case",
           "result_rows", "summarize_rows", "build_parser", "main"]

#: columns of ``results.csv`` after ``case_id`` and the grid columns
RESULT_COLUMNS = ("seed", "estimator", "rmse_yaw_deg", "rmse_pitch_deg", "rmse_roll_deg", "lc_rmse_noisy",
                  "lc_rmse_clean", "nees_mean", "seconds_per_step", "status", "error")
#: columns of ``summary.csv`` after ``case_id`` and the grid columns
SUMMARY_COLUMNS = ("estimator", "seeds_ok", "seeds_failed",
                   *(f"{m}_{s}" for m in ("rmse_yaw_deg", "rmse_pitch_deg", "rmse_roll_deg", "lc_rmse_noisy",
                                          "lc_rmse_clean") for s in ("median", "q25", "q75")),
                   "nees_mean", "seconds_per_step")
#: config sections a trained model depends on (with ``dtype``)
MODEL_SECTIONS = ("geometry", "shape", "surface", "data", "model")
CASE_FORMAT = 1


# ----------------------------------------------------------------------------------------------- grid

def parse_grid(text: str) -> tuple[str, list[Any]]:
    """``"data.t_span_past=10,20,30"`` → ``("data.t_span_past", [10, 20, 30])``.

    The value list is read as a YAML flow sequence, so ``"x=[1, 2],[3, 4]"`` gives two list values and
    ``"x=true,null"`` gives ``[True, None]``.

    Raises:
        ConfigError: no ``=``, an empty key or value list, or unparsable values.
    """
    if "=" not in text:
        raise ConfigError(f"--grid {text!r}: expected key.path=value1,value2,...")
    key, _, values = text.partition("=")
    key = key.strip()
    if not key or any(not part for part in key.split(".")):
        raise ConfigError(f"--grid {text!r}: empty key")
    if not values.strip():
        raise ConfigError(f"--grid {text!r}: no values after '='")
    try:
        parsed = yaml.safe_load(f"[{values}]")
    except yaml.YAMLError as exc:
        raise ConfigError(f"{key}: cannot parse grid values {values!r}: {exc}") from None
    if not isinstance(parsed, list) or not parsed:
        raise ConfigError(f"{key}: cannot parse grid values {values!r}")
    return key, parsed


def expand_grid(axes: Sequence[tuple[str, Sequence[Any]]]) -> list[dict[str, Any]]:
    """Cartesian product of the axes ``[(key, values), ...]``: one ``{key: value}`` dict per grid point, the last
    axis varying fastest. No axes give one empty point. A key given twice raises :class:`ConfigError`."""
    keys = [k for k, _ in axes]
    for k in keys:
        if keys.count(k) > 1:
            raise ConfigError(f"{k}: grid axis given more than once")
    for k, values in axes:
        if len(values) == 0:
            raise ConfigError(f"{k}: grid axis without values")
    return [dict(zip(keys, combo)) for combo in itertools.product(*(list(v) for _, v in axes))]


def _override_text(key: str, value: Any) -> str:
    return f"{key}={json.dumps(value)}"  # JSON is YAML: the value round-trips exactly


def _value_text(value: Any) -> str:
    return value if isinstance(value, str) else json.dumps(value)


# ----------------------------------------------------------------------------------------------- cases

@dataclass
class Case:
    """One grid point: its values, validated config, content hash and the hash of the model it needs."""

    values: dict[str, Any]
    config: Config
    case_id: str
    model_hash: str | None


def model_key(cfg: Config) -> str:
    """The model store's key of ``cfg`` (:func:`lightcurve_gp.model_store.model_key`)."""
    from .model_store import model_key as store_key

    return store_key(cfg)


def _case_key(cfg: Config, seeds: Sequence[int], estimators: Sequence[str]) -> str:
    sections = [k for k in config_to_dict(cfg) if k != "name"]
    return config_hash(cfg, *sections, extra={"seeds": list(seeds), "estimators": list(estimators),
                                              "format": CASE_FORMAT})


def make_cases(raw: dict, axes: Sequence[tuple[str, Sequence[Any]]], seeds: Sequence[int],
               estimators: Sequence[str] = DEFAULT_ESTIMATORS) -> list[Case]:
    """Validate every grid point of ``axes`` applied to the raw config mapping ``raw``.

    Raises:
        ConfigError: an unknown key or invalid value; the message names the key (and the grid point).
    """
    unknown = [e for e in estimators if e not in ESTIMATORS]
    if unknown:
        raise ConfigError(f"estimators: unknown estimator {unknown[0]!r}; choose from {', '.join(ESTIMATORS)}")
    points = expand_grid(axes)
    cases = []
    for values in points:
        try:
            cfg = config_from_dict(apply_overrides(raw, [_override_text(k, v) for k, v in values.items()]))
        except ConfigError as exc:
            where = ", ".join(f"{k}={_value_text(v)}" for k, v in values.items())
            raise ConfigError(f"{exc} (grid point {where})" if where else str(exc)) from None
        needs_model = "gpukf" in estimators
        cases.append(Case(values, cfg, _case_key(cfg, seeds, estimators), model_key(cfg) if needs_model else None))
    return cases


# ----------------------------------------------------------------------------------------------- models

def _model_path(root: Path, model_hash: str) -> Path:
    return root / "models" / model_hash / "model.pt"


def ensure_models(cases: Sequence[Case], root: Path, cache_dir: Path, progress: bool = True,
                  threads: int | None = None) -> dict[str, str | None]:
    """Get every model the cases need from the model store ``root/models``
    (:func:`lightcurve_gp.model_store.get_or_train`), training the missing ones.

    Returns ``{model_hash: error or None}``; a failed training is reported, not raised, so that the cases that
    need it fail with its error and the others go on.
    """
    from .model_store import get_or_train

    errors: dict[str, str | None] = {}
    wanted = {c.model_hash: c.config for c in cases if c.model_hash is not None}
    old_threads = torch.get_num_threads()
    for model_hash, cfg in wanted.items():
        try:
            if threads:
                torch.set_num_threads(threads)
            get_or_train(cfg, root / "models", cache_dir=cache_dir, progress=progress)
            errors[model_hash] = None
        except Exception as exc:  # recorded on every case that needs this model
            errors[model_hash] = f"model training failed: {type(exc).__name__}: {exc}"
        finally:
            torch.set_num_threads(old_threads)
    return errors


# ----------------------------------------------------------------------------------------------- one case

def _finite(x: float) -> float | None:
    return x if math.isfinite(x) else None


def result_rows(result: ScenarioResult) -> list[dict[str, Any]]:
    """One row per (seed, estimator) of a scenario result, with the :data:`RESULT_COLUMNS` metrics (NaN → None)."""
    rows = []
    steps = result.steps
    for name, r in result.results.items():
        for i, seed in enumerate(result.scenario.seeds):
            yaw, pitch, roll = (float(v) for v in r.rmse_deg[i])
            rows.append({"seed": int(seed), "estimator": name, "rmse_yaw_deg": _finite(yaw),
                         "rmse_pitch_deg": _finite(pitch), "rmse_roll_deg": _finite(roll),
                         "lc_rmse_noisy": _finite(float(r.lc_rmse_noisy[i])),
                         "lc_rmse_clean": _finite(float(r.lc_rmse_clean[i])),
                         "nees_mean": _finite(float(r.nees_mean[i])), "seconds_per_step": r.seconds / steps,
                         "status": "ok", "error": ""})
    return rows


def _traces(result: ScenarioResult) -> dict[str, Any]:
    """Time series of the first seed (for the paper-style figures): errors (deg) and predicted light curves."""
    sc = result.scenario
    return {"seed": int(sc.seeds[0]), "times": sc.times.tolist(), "observed": sc.observations[0].tolist(),
            "clean": sc.m_clean.tolist(),
            "errors_deg": {n: r.errors_deg[0].tolist() for n, r in result.results.items()},
            "y_pred": {n: r.history.y_pred[0].tolist() for n, r in result.results.items() if r.history is not None}}


def _failed_rows(seeds: Sequence[int], estimators: Sequence[str], error: str) -> list[dict[str, Any]]:
    empty = {k: None for k in RESULT_COLUMNS}
    return [{**empty, "seed": int(s), "estimator": e, "status": "failed", "error": error}
            for s in seeds for e in estimators]


def run_case(spec: dict[str, Any]) -> dict[str, Any]:
    """Run one case and write its record atomically to ``spec["path"]``; never raises for a failing case.

    ``spec`` holds plain values (it crosses process boundaries): ``config`` (dict), ``values``, ``case_id``,
    ``seeds``, ``estimators``, ``model_path`` (or None), ``model_error`` (or None), ``threads``, ``path``.
    Returns the record (``status`` ``"ok"`` or ``"failed"``).
    """
    from .observation.serialization import load_model

    start = time.perf_counter()
    record: dict[str, Any] = {"format": CASE_FORMAT, "case_id": spec["case_id"], "values": spec["values"],
                              "seeds": list(spec["seeds"]), "estimators": list(spec["estimators"])}
    try:
        if spec.get("threads"):
            torch.set_num_threads(int(spec["threads"]))
        if spec.get("model_error"):
            raise RuntimeError(spec["model_error"])
        cfg = config_from_dict(spec["config"])
        model = load_model(spec["model_path"]) if spec.get("model_path") else None
        result = run_estimators(cfg, model, seeds=spec["seeds"], estimators=spec["estimators"])
        record.update(status="ok", error="", rows=result_rows(result), summary=result.summary(),
                      traces=_traces(result), model_path=spec.get("model_path"))
    except Exception as exc:
        error = f"{type(exc).__name__}: {exc}"
        record.update(status="failed", error=error, traceback=traceback.format_exc(),
                      rows=_failed_rows(spec["seeds"], spec["estimators"], error))
    record["seconds"] = time.perf_counter() - start
    write_json_atomic(record, spec["path"])
    return record


def read_case(path: Path) -> dict[str, Any] | None:
    """A stored case record, or ``None`` when missing or unreadable (it is then rerun)."""
    try:
        record = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
    return record if isinstance(record, dict) and record.get("format") == CASE_FORMAT else None


# ----------------------------------------------------------------------------------------------- tables

def _grid_columns(axes: Sequence[tuple[str, Sequence[Any]]]) -> list[str]:
    return [k for k, _ in axes]


def _csv_text(rows: Sequence[dict[str, Any]], columns: Sequence[str]) -> str:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(columns), extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: ("" if row.get(k) is None else row[k]) for k in columns})
    return buf.getvalue()


def _quantiles(values: list[float | None]) -> tuple[float, float, float]:
    x = np.array([v for v in values if v is not None], dtype=float)
    if x.size == 0:
        return (math.nan,) * 3
    q25, med, q75 = np.quantile(x, [0.25, 0.5, 0.75])
    return float(med), float(q25), float(q75)


def summarize_rows(rows: Sequence[dict[str, Any]], keys: Sequence[str]) -> list[dict[str, Any]]:
    """Median, 25 % and 75 % quantiles of each metric per (case, estimator) over the seeds with status ok.

    ``keys`` are the columns copied from the first row of each group (``case_id`` and the grid columns).
    Quantiles are numpy's linear ones (as :meth:`ScenarioResult.summary`'s torch quantiles).
    """
    groups: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault((row["case_id"], row["estimator"]), []).append(row)
    out = []
    for (_, estimator), group in groups.items():
        ok = [r for r in group if r["status"] == "ok"]
        entry = {k: group[0].get(k) for k in keys}
        entry.update(estimator=estimator, seeds_ok=len(ok), seeds_failed=len(group) - len(ok))
        for metric in ("rmse_yaw_deg", "rmse_pitch_deg", "rmse_roll_deg", "lc_rmse_noisy", "lc_rmse_clean"):
            med, q25, q75 = _quantiles([r[metric] for r in ok])
            entry.update({f"{metric}_median": med, f"{metric}_q25": q25, f"{metric}_q75": q75})
        nees = [r["nees_mean"] for r in ok if r["nees_mean"] is not None]
        entry["nees_mean"] = float(np.mean(nees)) if nees else math.nan
        entry["seconds_per_step"] = ok[0]["seconds_per_step"] if ok else math.nan
        out.append(entry)
    return out


# ----------------------------------------------------------------------------------------------- the sweep

@dataclass
class SweepResult:
    """What :func:`run_sweep` wrote: the sweep folder, the per-case records, the rows and the summary."""

    folder: Path
    cases: list[Case]
    records: dict[str, dict[str, Any]]
    rows: list[dict[str, Any]]
    summary: list[dict[str, Any]]
    ran: list[str] = field(default_factory=list)
    interrupted: bool = False

    @property
    def failed(self) -> list[str]:
        """Case ids whose record has status failed."""
        return [cid for cid, r in self.records.items() if r.get("status") != "ok"]

    def record(self, **values: Any) -> dict[str, Any]:
        """The record of the case whose grid values include ``values`` (exactly one must match)."""
        found = [c for c in self.cases if all(c.values.get(k) == v for k, v in values.items())]
        if len(found) != 1:
            raise KeyError(f"{len(found)} cases match {values}")
        return self.records[found[0].case_id]


def _sweep_id(raw: dict, axes, seeds, estimators) -> str:
    import hashlib

    blob = json.dumps({"config": raw, "axes": [[k, list(v)] for k, v in axes], "seeds": list(seeds),
                       "estimators": list(estimators)}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:12]


def run_sweep(raw: dict, axes: Sequence[tuple[str, Sequence[Any]]], seeds: Sequence[int], *,
              out: str | Path = "runs", sweep_id: str | None = None, estimators: Sequence[str] = DEFAULT_ESTIMATORS,
              workers: int = 1, threads: int = 1, train_threads: int | None = None, cache_dir: str | Path | None = None,
              progress: bool = True, rerun_failed: bool = True,
              case_runner: Callable[[dict[str, Any]], dict[str, Any]] = run_case) -> SweepResult:
    """Run (or resume) a sweep; see the module docstring for what is written where.

    Args:
        raw: the base config as a plain mapping (YAML as read, base overrides applied).
        axes: grid axes ``[(key.path, [values...]), ...]``.
        seeds: noise seeds, all batched in each filter run.
        out: output root; files go to ``out/<config name>/``.
        sweep_id: folder name of this sweep's tables (default: a hash of the definition).
        estimators: subset of :data:`~lightcurve_gp.estimation.ESTIMATORS`.
        workers: parallel processes for the cases (spawned); 1 runs them in this process.
        threads: torch threads per case; ``train_threads``: torch threads while training (default: torch's).
        cache_dir: training-data cache (default ``out/cache``).
        rerun_failed: retry cases stored as failed (otherwise their stored failure is reported again).
        case_runner: the function that runs one case spec (default :func:`run_case`).

    Raises:
        ConfigError: an invalid grid key or value, before any work is done.
    """
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ConfigError("seeds: at least one seed is needed")
    if workers < 1:
        raise ConfigError(f"workers: {workers} must be >= 1")
    cases = make_cases(raw, axes, seeds, estimators)
    out = Path(out)
    root = out / cases[0].config.name
    sweep_id = sweep_id or _sweep_id(raw, axes, seeds, estimators)
    folder = root / "sweep" / sweep_id
    write_json_atomic({"config": raw, "axes": [[k, list(v)] for k, v in axes], "seeds": seeds,
                       "estimators": list(estimators),
                       "cases": [{"case_id": c.case_id, "values": c.values, "model_hash": c.model_hash}
                                 for c in cases]}, folder / "sweep.json")

    records: dict[str, dict[str, Any]] = {}
    pending: list[Case] = []
    for case in cases:
        if case.case_id in records:
            continue
        stored = read_case(root / "cases" / f"{case.case_id}.json")
        if stored is not None and (stored["status"] == "ok" or not rerun_failed):
            records[case.case_id] = stored
        elif case not in pending:
            pending.append(case)
    pending = list({c.case_id: c for c in pending}.values())

    model_errors = ensure_models(pending, root, Path(cache_dir) if cache_dir else out / "cache", progress,
                                 train_threads) if pending else {}
    specs = [{"config": config_to_dict(c.config), "values": c.values, "case_id": c.case_id, "seeds": seeds,
              "estimators": list(estimators), "threads": threads,
              "model_path": str(_model_path(root, c.model_hash)) if c.model_hash else None,
              "model_error": model_errors.get(c.model_hash) if c.model_hash else None,
              "path": str(root / "cases" / f"{c.case_id}.json")} for c in pending]
    ran: list[str] = []
    interrupted = False
    bar = tqdm(total=len(cases), initial=len(cases) - len(specs), desc="cases", unit="case", disable=not progress)
    try:
        if workers == 1:
            for spec in specs:
                records[spec["case_id"]] = case_runner(spec)
                ran.append(spec["case_id"])
                bar.update()
        else:
            with cf.ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as ex:
                futures = {ex.submit(case_runner, spec): spec for spec in specs}
                try:
                    for fut in cf.as_completed(futures):
                        spec = futures[fut]
                        try:
                            records[spec["case_id"]] = fut.result()
                        except Exception as exc:  # the worker process itself died
                            error = f"{type(exc).__name__}: {exc}"
                            records[spec["case_id"]] = {"status": "failed", "error": error,
                                                        "rows": _failed_rows(seeds, estimators, error)}
                        ran.append(spec["case_id"])
                        bar.update()
                except KeyboardInterrupt:
                    ex.shutdown(wait=False, cancel_futures=True)
                    raise
    except KeyboardInterrupt:
        interrupted = True
    finally:
        bar.close()

    keys = ["case_id", *_grid_columns(axes)]
    rows = []
    for case in cases:
        record = records.get(case.case_id)
        if record is None:
            continue
        for row in record["rows"]:
            rows.append({"case_id": case.case_id, **{k: _value_text(v) for k, v in case.values.items()}, **row})
    summary = summarize_rows(rows, keys)
    write_text_atomic(_csv_text(rows, [*keys, *RESULT_COLUMNS]), folder / "results.csv")
    write_text_atomic(_csv_text(summary, [*keys, *SUMMARY_COLUMNS]), folder / "summary.csv")
    write_json_atomic({"sweep_id": sweep_id, "complete": len(records) == len({c.case_id for c in cases}),
                       "failed_cases": [cid for cid, r in records.items() if r.get("status") != "ok"],
                       "summary": [{k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in e.items()}
                                   for e in summary]}, folder / "summary.json")
    return SweepResult(folder, cases, records, rows, summary, ran, interrupted)


# ----------------------------------------------------------------------------------------------- CLI

def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m lightcurve_gp.sweep",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Run the estimators (GPUKF, conventional UKF, matched-rho UKF, no-update baseline) over the "
                    "cartesian product of grid axes, every case with all seeds batched.",
        epilog="""\
what it does:
  * every grid point is applied to CONFIG (after --set) and validated before anything runs; an unknown key or a bad
    value stops the sweep with an error naming the key
  * one GP per distinct geometry/shape/surface/data/model setting is trained (python -m lightcurve_gp.train's
    job) into OUT/<name>/models/<hash>/ and reused by every case and later sweep that needs it
  * each case is stored when it finishes, atomically, in OUT/<name>/cases/<case-id>.json (the id hashes the
    case's whole config, seeds and estimators); a rerun skips stored cases and retries failed ones, so an
    interrupted sweep (Ctrl-C) resumes where it stopped
  * a case that raises is recorded with its error (status "failed") and the sweep goes on
  * tables in OUT/<name>/sweep/<sweep-id>/: results.csv (one row per case x seed x estimator: case_id, the grid
    values, seed, estimator, rmse_yaw_deg, rmse_pitch_deg, rmse_roll_deg, lc_rmse_noisy, lc_rmse_clean,
    nees_mean, seconds_per_step, status, error), summary.csv / summary.json (median and quartiles per case and
    estimator) and sweep.json (the definition)

example:
  python -m lightcurve_gp.sweep configs/boxwing.yaml --grid data.t_span_past=10,20,30,40 \\
      --grid scenario.rho_true=0.3,0.7 --seeds 20 --set filter.add_model_variance=false
""")
    parser.add_argument("config", help="YAML config, e.g. configs/boxwing.yaml")
    parser.add_argument("--grid", action="append", default=[], metavar="KEY.PATH=V1,V2,...",
                        help="a grid axis (repeatable): any config key and its values, parsed as YAML "
                             "(e.g. scenario.rho_true=0.3,0.7 or scenario.initial_error_deg=[-10,5,-10],[5,5,5])")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY.PATH=VALUE",
                        help="override a config value for every case (repeatable)")
    parser.add_argument("--seeds", type=int, default=None,
                        help="number of noise seeds 0..N-1 per case (default: scenario.seeds)")
    parser.add_argument("--estimators", default=",".join(DEFAULT_ESTIMATORS),
                        help=f"comma-separated subset of {','.join(ESTIMATORS)} (default: "
                             f"{','.join(DEFAULT_ESTIMATORS)})")
    parser.add_argument("--out", default="runs", type=Path, help="output root (default: runs)")
    parser.add_argument("--cache", default=None, type=Path, help="training-data cache (default: OUT/cache)")
    parser.add_argument("--sweep-id", default=None,
                        help="name of the table folder OUT/<name>/sweep/<id> (default: hash of the definition)")
    parser.add_argument("--workers", type=int, default=1, help="parallel case processes (default 1)")
    parser.add_argument("--threads", type=int, default=1,
                        help="torch threads per case (default 1: small per-step tensors run fastest on one)")
    parser.add_argument("--no-retry", action="store_true", help="keep stored failures instead of retrying them")
    parser.add_argument("--no-progress", action="store_true", help="hide progress bars and training messages")
    return parser


def _print_summary(result: SweepResult, axes) -> None:
    keys = _grid_columns(axes)
    head = " ".join(f"{k:>22}" for k in keys) + f" {'estimator':>12} {'yaw':>8} {'pitch':>8} {'roll':>8} {'LC':>6}"
    print(head)
    for e in result.summary:
        cells = " ".join(f"{str(e[k]):>22}" for k in keys)
        print(f"{cells} {e['estimator']:>12} {e['rmse_yaw_deg_median']:8.2f} {e['rmse_pitch_deg_median']:8.2f} "
              f"{e['rmse_roll_deg_median']:8.2f} {e['lc_rmse_noisy_median']:6.3f}")


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        path = Path(args.config)
        if not path.is_file():
            raise ConfigError(f"config file {str(path)!r} does not exist")
        raw = apply_overrides(yaml.safe_load(path.read_text()) or {}, args.overrides)
        axes = [parse_grid(g) for g in args.grid]
        estimators = [e.strip() for e in args.estimators.split(",") if e.strip()]
        seeds = range(args.seeds if args.seeds is not None else config_from_dict(raw).scenario.seeds)
        if args.seeds is not None and args.seeds < 1:
            raise ConfigError(f"--seeds: {args.seeds} must be >= 1")
        result = run_sweep(raw, axes, seeds, out=args.out, sweep_id=args.sweep_id, estimators=estimators,
                           workers=args.workers, threads=args.threads, cache_dir=args.cache,
                           progress=not args.no_progress, rerun_failed=not args.no_retry)
    except (ConfigError, yaml.YAMLError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    _print_summary(result, axes)
    for cid in result.failed:
        print(f"case {cid} failed: {result.records[cid].get('error')}", file=sys.stderr)
    print(f"written: {result.folder}")
    if result.interrupted:
        print("interrupted: finished cases are stored; rerun the same command to resume", file=sys.stderr)
        return 130
    return 1 if result.failed else 0


if __name__ == "__main__":
    sys.exit(main())
