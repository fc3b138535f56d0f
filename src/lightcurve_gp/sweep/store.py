"""The case store: one atomic JSON file per finished case, ``<root>/cases/<case-id>.json``, shared by every sweep
whose cases hash alike (the case id hashes the whole config, the seeds and the estimators)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Sequence

from lightcurve_gp.evaluation.reporting import CaseRecord, SeedRow
from lightcurve_gp.files import write_json_atomic

__all__ = ["case_path", "read_case", "write_case", "failed_rows"]


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
