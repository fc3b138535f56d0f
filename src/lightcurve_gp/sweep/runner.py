"""Running a sweep: each pending case in this process or in spawned workers, stored as soon as it finishes."""

from __future__ import annotations

import concurrent.futures as cf
import hashlib
import json
import multiprocessing
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import torch
from tqdm.auto import tqdm

from ..config import ConfigError, config_from_dict, config_to_dict
from ..estimation import DEFAULT_ESTIMATORS, ScenarioResult, run_estimators
from ..io import write_json_atomic
from ..reporting import CaseRecord, seed_rows
from .grid import Case, make_cases
from .models import ensure_models, model_path
from .store import case_path, failed_rows, read_case, write_case
from .tables import summarize_rows, table_rows, write_sweep_tables

__all__ = ["SweepResult", "run_case", "run_sweep"]


def _traces(result: ScenarioResult) -> dict[str, Any]:
    """Time series of the first seed (for the paper-style figures): errors (deg) and predicted light curves."""
    sc = result.scenario
    return {"seed": int(sc.seeds[0]), "times": sc.times.tolist(), "observed": sc.observations[0].tolist(),
            "clean": sc.m_clean.tolist(),
            "errors_deg": {n: r.errors_deg[0].tolist() for n, r in result.results.items()},
            "y_pred": {n: r.history.y_pred[0].tolist() for n, r in result.results.items() if r.history is not None}}


def run_case(spec: dict[str, Any]) -> CaseRecord:
    """Run one case and store its record atomically at ``spec["path"]``; never raises for a failing case.

    ``spec`` holds plain values (it crosses process boundaries): ``config`` (dict), ``values``, ``case_id``,
    ``seeds``, ``estimators``, ``model_path`` (or None), ``model_error`` (or None), ``threads``, ``path``.
    Returns the record (``status`` ``"ok"`` or ``"failed"``).
    """
    from ..observation.serialization import load_model

    start = time.perf_counter()
    record = CaseRecord(spec["case_id"], spec["values"], list(spec["seeds"]), list(spec["estimators"]))
    try:
        if spec.get("threads"):
            torch.set_num_threads(int(spec["threads"]))
        if spec.get("model_error"):
            raise RuntimeError(spec["model_error"])
        cfg = config_from_dict(spec["config"])
        model = load_model(spec["model_path"]) if spec.get("model_path") else None
        result = run_estimators(cfg, model, seeds=spec["seeds"], estimators=spec["estimators"])
        record.rows, record.summary, record.traces = seed_rows(result), result.summary(), _traces(result)
        record.model_path = spec.get("model_path")
    except Exception as exc:
        record.status, record.error = "failed", f"{type(exc).__name__}: {exc}"
        record.traceback = traceback.format_exc()
        record.rows = failed_rows(spec["seeds"], spec["estimators"], record.error)
    record.seconds = time.perf_counter() - start
    write_case(record, spec["path"])
    return record


@dataclass
class SweepResult:
    """What :func:`run_sweep` wrote: the sweep folder, the per-case records, the rows and the summary."""

    folder: Path
    cases: list[Case]
    records: dict[str, CaseRecord]
    rows: list[dict[str, Any]]
    summary: list[dict[str, Any]]
    ran: list[str] = field(default_factory=list)
    interrupted: bool = False

    @property
    def failed(self) -> list[str]:
        """Case ids whose record has status failed."""
        return [cid for cid, r in self.records.items() if not r.ok]

    def record(self, **values: Any) -> CaseRecord:
        """The record of the case whose grid values include ``values`` (exactly one must match)."""
        found = [c for c in self.cases if all(c.values.get(k) == v for k, v in values.items())]
        if len(found) != 1:
            raise KeyError(f"{len(found)} cases match {values}")
        return self.records[found[0].case_id]


def _sweep_id(raw: dict, axes, seeds, estimators) -> str:
    blob = json.dumps({"config": raw, "axes": [[k, list(v)] for k, v in axes], "seeds": list(seeds),
                       "estimators": list(estimators)}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:12]


def _pending(cases: Sequence[Case], root: Path, rerun_failed: bool) -> tuple[dict[str, CaseRecord], list[Case]]:
    """The stored records to reuse and the distinct cases still to run."""
    records: dict[str, CaseRecord] = {}
    pending: dict[str, Case] = {}
    for case in cases:
        stored = read_case(case_path(root, case.case_id))
        if stored is not None and (stored.ok or not rerun_failed):
            records[case.case_id] = stored
        else:
            pending.setdefault(case.case_id, case)
    return records, list(pending.values())


def _run_specs(specs: list[dict[str, Any]], records: dict[str, CaseRecord], case_runner, workers: int,
               bar) -> tuple[list[str], bool]:
    """Run every spec (in ``workers`` spawned processes when > 1) into ``records``; returns (ran, interrupted)."""
    ran: list[str] = []
    try:
        if workers == 1:
            for spec in specs:
                records[spec["case_id"]] = case_runner(spec)
                ran.append(spec["case_id"])
                bar.update()
            return ran, False
        with cf.ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as ex:
            futures = {ex.submit(case_runner, spec): spec for spec in specs}
            try:
                for fut in cf.as_completed(futures):
                    spec = futures[fut]
                    try:
                        records[spec["case_id"]] = fut.result()
                    except Exception as exc:  # the worker process itself died
                        error = f"{type(exc).__name__}: {exc}"
                        records[spec["case_id"]] = CaseRecord(
                            spec["case_id"], spec["values"], list(spec["seeds"]), list(spec["estimators"]),
                            status="failed", error=error, rows=failed_rows(spec["seeds"], spec["estimators"], error))
                    ran.append(spec["case_id"])
                    bar.update()
            except KeyboardInterrupt:
                ex.shutdown(wait=False, cancel_futures=True)
                raise
    except KeyboardInterrupt:
        return ran, True
    return ran, False


def run_sweep(raw: dict, axes: Sequence[tuple[str, Sequence[Any]]], seeds: Sequence[int], *,
              out: str | Path = "runs", sweep_id: str | None = None, estimators: Sequence[str] = DEFAULT_ESTIMATORS,
              workers: int = 1, threads: int = 1, cache_dir: str | Path | None = None,
              progress: bool = True, rerun_failed: bool = True,
              case_runner: Callable[[dict[str, Any]], CaseRecord] = run_case) -> SweepResult:
    """Run (or resume) a sweep; see :mod:`lightcurve_gp.sweep` for what is written where.

    Args:
        raw: the base config as a plain mapping (YAML as read, base overrides applied).
        axes: grid axes ``[(key.path, [values...]), ...]``.
        seeds: noise seeds, all batched in each filter run.
        out: output root; files go to ``out/<config name>/``.
        sweep_id: folder name of this sweep's tables (default: a hash of the definition).
        estimators: subset of :data:`~lightcurve_gp.estimation.ESTIMATORS`.
        workers: parallel processes for the cases (spawned); 1 runs them in this process.
        threads: torch threads of each spawned worker process (``workers`` > 1); training and the cases run in
            this process use the caller's thread count (the library leaves torch's global settings alone).
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

    records, pending = _pending(cases, root, rerun_failed)
    model_errors = ensure_models(pending, root, Path(cache_dir) if cache_dir else out / "cache",
                                 progress) if pending else {}
    specs = [{"config": config_to_dict(c.config), "values": c.values, "case_id": c.case_id, "seeds": seeds,
              "estimators": list(estimators), "threads": threads if workers > 1 else None,
              "model_path": str(model_path(root, c.model_hash)) if c.model_hash else None,
              "model_error": model_errors.get(c.model_hash) if c.model_hash else None,
              "path": str(case_path(root, c.case_id))} for c in pending]
    bar = tqdm(total=len(cases), initial=len(cases) - len(specs), desc="cases", unit="case", disable=not progress)
    try:
        ran, interrupted = _run_specs(specs, records, case_runner, workers, bar)
    finally:
        bar.close()

    keys = ["case_id", *(k for k, _ in axes)]
    rows = table_rows(cases, records)
    summary = summarize_rows(rows, keys)
    failed = [cid for cid, r in records.items() if not r.ok]
    write_sweep_tables(folder, sweep_id, keys, rows, summary, len(records) == len({c.case_id for c in cases}), failed)
    return SweepResult(folder, cases, records, rows, summary, ran, interrupted)
