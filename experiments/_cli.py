"""The command-line arguments every experiment on the robust config shares."""

from __future__ import annotations

import argparse
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

__all__ = ["ROOT", "robust_arguments"]


def robust_arguments(description: str, *, seeds: int, seed_start: int, seed_help: str) -> argparse.ArgumentParser:
    """``--config``, ``--seeds``, ``--seed-start``, ``--out`` (committed summaries) and ``--runs`` (trained
    models)."""
    p = argparse.ArgumentParser(description=description)
    p.add_argument("--config", default=str(ROOT / "configs/boxwing_robust.yaml"))
    p.add_argument("--seeds", type=int, default=seeds, help=f"noise seeds (default {seeds})")
    p.add_argument("--seed-start", type=int, default=seed_start,
                   help=f"first noise seed (default {seed_start}: {seed_help})")
    p.add_argument("--out", default=str(ROOT / "experiments/results/robust"), type=Path)
    p.add_argument("--runs", default=str(ROOT / "runs"), type=Path, help="where trained models are kept")
    return p
