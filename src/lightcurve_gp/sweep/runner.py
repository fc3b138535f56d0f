"""Running a sweep: the missing models, then each pending case, on an executor; each case stored as it arrives."""

from __future__ import annotations

import hashlib
import json
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import torch

from lightcurve_gp.attitude.metrics import attitude_error_vector
from lightcurve_gp.config.load import ConfigError, config_from_dict, config_to_dict
from lightcurve_gp.evaluation.harness import ScenarioResult, run_estimators
from lightcurve_gp.evaluation.registry import DEFAULT_ESTIMATORS
from lightcurve_gp.evaluation.reporting import CaseRecord, scenario_summary, seed_rows
from lightcurve_gp.files import write_json_atomic
from lightcurve_gp.observation.serialization import load_model
from lightcurve_gp.simulation.scenario import simulate_scenario
from lightcurve_gp.sweep.executors import Executor, SerialExecutor, make_executor
from lightcurve_gp.sweep.grid import Case, make_cases
from lightcurve_gp.sweep.models import ensure_models, model_path
from lightcurve_gp.sweep.store import case_path, failed_rows, read_case, write_case
from lightcurve_gp.sweep.tables import summarize_rows, table_rows, write_sweep_tables

__all__ = ["SweepResult", "run_case", "run_sweep"]


def _traces(result: ScenarioResult) -> dict[str, Any]:
    """Time series of the first seed (for the paper-style figures): errors (deg) and predicted light curves; for
    each filter its GRP attitude error and ±1σ (deg, ≈ rotation vector) and its body-rate error and ±1σ (deg/s)."""
    sc = result.scenario
    filters = {n: r for n, r in result.results.items() if r.history is not None}
    err = {n: torch.rad2deg(attitude_error_vector(sc.q_true[0], r.q_est[0], kind="grp")) for n, r in filters.items()}
    rate = {n: torch.rad2deg(sc.omega_true[0] - (sc.omega_assumed[0] if r.history.omega is None
                                                 else r.history.omega[0]))
            for n, r in filters.items()}
    std = {n: torch.rad2deg(r.history.P_full[0].diagonal(dim1=-2, dim2=-1).clamp_min(0).sqrt())
           for n, r in filters.items()}
    return {"seed": int(sc.seeds[0]), "times": sc.times.tolist(), "observed": sc.observations[0].tolist(),
            "clean": sc.m_clean[0].tolist(),
            "errors_deg": {n: r.errors_deg[0].tolist() for n, r in result.results.items() if r.trajectory},
            "y_pred": {n: r.history.y_pred[0].tolist() for n, r in filters.items()},
            "attitude_error_deg": {n: e.tolist() for n, e in err.items()},
            "attitude_sigma_deg": {n: sd[:, :3].tolist() for n, sd in std.items()},
            "omega_error_deg_s": {n: e.tolist() for n, e in rate.items()},
            "omega_sigma_deg_s": {n: std[n][:, 3:6].tolist() for n, r in filters.items()
                                  if r.history.omega is not None}}


def run_case(spec: dict[str, Any]) -> CaseRecord:
    """Run one case and return its record (``status`` ``"ok"`` or ``"failed"``); never raises for a failing case.

    ``spec`` holds plain values (it crosses process and machine boundaries): ``config`` (dict), ``values``,
    ``case_id``, ``seeds``, ``estimators``, ``model_path`` (or None), ``model_error`` (or None), ``threads`` (None:
    leave torch's). The runner stores the record when it arrives.
    """
    start = time.perf_counter()
    record = CaseRecord(spec["case_id"], spec["values"], list(spec["seeds"]), list(spec["estimators"]))
    try:
        if spec.get("threads"):
            torch.set_num_threads(int(spec["threads"]))
        if spec.get("model_error"):
            raise RuntimeError(spec["model_error"])
        cfg = config_from_dict(spec["config"])
        model = load_model(spec["model_path"]) if spec.get("model_path") else None
        result = run_estimators(cfg, simulate_scenario(cfg, seeds=spec["seeds"]), estimators=spec["estimators"],
                                model=model)
        record.rows, record.summary, record.traces = seed_rows(result), scenario_summary(result), _traces(result)
        record.model_path = spec.get("model_path")
    except Exception as exc:
        record.status, record.error = "failed", f"{type(exc).__name__}: {exc}"
        record.traceback = traceback.format_exc()
        record.rows = failed_rows(spec["seeds"], spec["estimators"], record.error)
    record.seconds = time.perf_counter() - start
    return record


def _failed_record(spec: dict[str, Any], error: str) -> CaseRecord:
    """The record of a case that returned none (its worker died too often, its result did not pickle)."""
    return CaseRecord(spec["case_id"], spec["values"], list(spec["seeds"]), list(spec["estimators"]),
                      status="failed", error=error, rows=failed_rows(spec["seeds"], spec["estimators"], error))


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


def _run_pending(pending: Sequence[Case], root: Path, executor: Executor, records: dict[str, CaseRecord], *,
                 store: Path, seeds: list[int], estimators: Sequence[str], threads: int | None, cache_dir: Path,
                 total: int, progress: bool | None, case_runner) -> None:
    """Get the models the pending cases need from the model store ``store`` (shared with ``train`` and the
    experiments; trained into it when missing), then run the cases on ``executor``, storing each record atomically
    into the case store of ``root`` and into ``records`` the moment it arrives (in completion order)."""
    model_errors = ensure_models(pending, store, cache_dir, executor, progress, threads)
    specs = {c.case_id: {"config": config_to_dict(c.config), "values": c.values, "case_id": c.case_id,
                         "seeds": seeds, "estimators": list(estimators), "threads": threads,
                         "model_path": str(model_path(store, c.model_hash)) if c.model_hash else None,
                         "model_error": model_errors.get(c.model_hash) if c.model_hash else None}
             for c in pending}
    for outcome in executor.run(case_runner, specs, desc="cases", total=total, initial=total - len(specs),
                                progress=progress):
        record = outcome.value if outcome.ok else _failed_record(specs[outcome.key], outcome.error)
        write_case(record, case_path(root, outcome.key))
        records[outcome.key] = record


def run_sweep(raw: dict, axes: Sequence[tuple[str, Sequence[Any]]], seeds: Sequence[int], *,
              out: str | Path = "runs", store: str | Path | None = None, sweep_id: str | None = None,
              estimators: Sequence[str] = DEFAULT_ESTIMATORS,
              workers: int = 1, threads: int = 1, cache_dir: str | Path | None = None,
              progress: bool | None = None, rerun_failed: bool = True, executor: str | Executor = "local",
              scheduler: str | None = None, retries: int = 2,
              case_runner: Callable[[dict[str, Any]], CaseRecord] = run_case) -> SweepResult:
    """Run (or resume) a sweep; see :mod:`lightcurve_gp.sweep` for what is written where.

    Args:
        raw: the base config as a plain mapping (YAML as read, base overrides applied).
        axes: grid axes ``[(key.path, [values...]), ...]``.
        seeds: noise seeds, all batched in each filter run.
        out: output root; cases and tables go to ``out/<config name>/``.
        store: the model store (default ``out/models``, shared with ``train`` and the experiments, keyed by
            :func:`~lightcurve_gp.training.keys.model_key`).
        sweep_id: folder name of this sweep's tables (default: a hash of the definition).
        estimators: subset of :data:`~lightcurve_gp.evaluation.registry.ESTIMATORS`.
        workers: worker processes of the local pool (1: this process) or of the dask LocalCluster.
        threads: torch threads of each worker process (its trainings and cases); training and the cases run in
            this process use the caller's thread count (the library leaves torch's global settings alone).
        cache_dir: training-data cache (default ``out/cache``).
        rerun_failed: retry cases stored as failed (otherwise their stored failure is reported again).
        executor: ``"local"`` or ``"dask"`` (:mod:`lightcurve_gp.sweep.executors`), or an open
            :class:`~lightcurve_gp.sweep.executors.Executor` (left open, e.g. shared by several sweeps).
        scheduler: address of a running dask scheduler (``executor="dask"``; default: a LocalCluster).
        retries: times a case or training whose worker process died is run again.
        case_runner: the function that runs one case spec (default :func:`run_case`); it must pickle on a pool
            or a cluster.

    Raises:
        ConfigError: an invalid grid key or value, or an executor that cannot start, before any work is done.
    """
    seeds = _checked(seeds, workers)
    cases = make_cases(raw, axes, seeds, estimators)
    out = Path(out)
    root = out / cases[0].config.name
    sweep_id = sweep_id or _sweep_id(raw, axes, seeds, estimators)
    folder = root / "sweep" / sweep_id
    owned = isinstance(executor, str)
    ex = make_executor(executor, workers=workers, address=scheduler, retries=retries) if owned else executor
    _write_definition(folder, raw, axes, seeds, estimators, cases)
    records, pending = _pending(cases, root, rerun_failed)
    interrupted = False
    try:
        _run_pending(pending, root, ex, records, store=Path(store) if store else out / "models", seeds=seeds,
                     estimators=estimators,
                     threads=None if isinstance(ex, SerialExecutor) else threads,
                     cache_dir=Path(cache_dir) if cache_dir else out / "cache", total=len(cases), progress=progress,
                     case_runner=case_runner)
    except KeyboardInterrupt:
        interrupted = True
    finally:
        if owned:
            ex.close()
    pending_ids = {c.case_id for c in pending}
    ran = [cid for cid in records if cid in pending_ids]  # in completion order
    rows, summary = _write_tables(folder, sweep_id, axes, cases, records)
    return SweepResult(folder, cases, records, rows, summary, ran, interrupted)


def _checked(seeds: Sequence[int], workers: int) -> list[int]:
    """The seeds as a list of ints; at least one seed and one worker, else :class:`ConfigError`."""
    seeds = [int(s) for s in seeds]
    if not seeds:
        raise ConfigError("seeds: at least one seed is needed")
    if workers < 1:
        raise ConfigError(f"workers: {workers} must be >= 1")
    return seeds


def _write_definition(folder: Path, raw: dict, axes, seeds: list[int], estimators: Sequence[str],
                      cases: Sequence[Case]) -> None:
    """``sweep.json``: the base config, the axes, the seeds, the estimators and each case's id, values and model."""
    write_json_atomic({"config": raw, "axes": [[k, list(v)] for k, v in axes], "seeds": seeds,
                       "estimators": list(estimators),
                       "cases": [{"case_id": c.case_id, "values": c.values, "model_hash": c.model_hash}
                                 for c in cases]}, folder / "sweep.json")


def _write_tables(folder: Path, sweep_id: str, axes, cases: Sequence[Case],
                  records: dict[str, CaseRecord]) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Write the sweep's tables (:func:`~lightcurve_gp.sweep.tables.write_sweep_tables`); its rows and summary."""
    keys = ["case_id", *(k for k, _ in axes)]
    rows = table_rows(cases, records)
    summary = summarize_rows(rows, keys)
    failed = [cid for cid, r in records.items() if not r.ok]
    write_sweep_tables(folder, sweep_id, keys, rows, summary, len(records) == len({c.case_id for c in cases}), failed)
    return rows, summary
