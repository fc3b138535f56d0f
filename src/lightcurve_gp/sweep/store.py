"""The case store: one atomic JSON file per finished case, ``<root>/cases/<case-id>.json``, shared by every sweep
whose cases hash alike (the case id hashes the whole config, the seeds and the estimators), and by any study that
keeps its own cases there through :func:`resume_case` (its case id hashes what that case depends on)."""

from __future__ import annotations

import json
import time
import traceback
from pathlib import Path
from typing import Any, Callable, Sequence

from lightcurve_gp.evaluation.reporting import CaseRecord, SeedRow
from lightcurve_gp.files import write_json_atomic

__all__ = ["case_path", "read_case", "write_case", "failed_rows", "resume_case"]


def case_path(root: Path, case_id: str) -> Path:
    """The file of one case under a sweep root."""
    return Path(root) / "cases" / f"{case_id}.json"


def read_case(path: Path) -> CaseRecord | None:
    """A stored case record, or ``None`` when missing, unreadable or of another format (it is then rerun)."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
    return CaseRecord.from_dict(data)


def write_case(record: CaseRecord, path: Path) -> None:
    """Store ``record`` atomically at ``path``."""
    write_json_atomic(record.to_dict(), path)


def failed_rows(seeds: Sequence[int], estimators: Sequence[str], error: str) -> list[SeedRow]:
    """The rows of a case that failed as a whole: one per (seed, estimator), metrics empty."""
    return [SeedRow(int(s), e, status="failed", error=error) for s in seeds for e in estimators]


def resume_case(root: Path, case_id: str, compute: Callable[[], tuple[dict[str, Any], list[SeedRow]]], *,
                values: dict[str, Any], seeds: Sequence[int], estimators: Sequence[str]) -> tuple[CaseRecord, bool]:
    """The finished case ``case_id`` of the case store of ``root``: read back when stored, else computed and stored.

    The caller's ``case_id`` is a content hash of everything the case's result depends on (e.g.
    :func:`lightcurve_gp.config.hashing.config_hash` of the sections it reads with the seeds and the study's
    settings as ``extra``), so a changed input is a new case and an unchanged one is never computed twice.

    Args:
        root: the store's folder (records go to ``root/cases/<case_id>.json``, as a sweep's).
        case_id: the case's content hash.
        compute: runs the case: its summary (any JSON-serialisable mapping, kept as the record's ``summary``) and
            its per-seed rows (:class:`SeedRow`, possibly none).
        values, seeds, estimators: what the record says the case is.

    Returns:
        The record and whether it was computed now. A stored failed record is computed again; a ``compute`` that
        raises is stored as a failed record (the error, its traceback and one failed row per seed and estimator)
        and the exception propagates, so nothing finished is lost and the next run retries the case.
    """
    path = case_path(root, case_id)
    stored = read_case(path)
    if stored is not None and stored.ok:
        return stored, False
    record = CaseRecord(case_id, dict(values), [int(s) for s in seeds], list(estimators))
    start = time.perf_counter()
    try:
        record.summary, record.rows = compute()
    except Exception as exc:
        record.status, record.error = "failed", f"{type(exc).__name__}: {exc}"
        record.traceback = traceback.format_exc()
        record.rows = failed_rows(seeds, estimators, record.error)
        record.seconds = time.perf_counter() - start
        write_case(record, path)
        raise
    record.seconds = time.perf_counter() - start
    write_case(record, path)
    return record, True
