"""Command line of ``benchmarks/gpu_check.py``: its arguments, the checks before a run, the GPU memory cap.

A bad argument, a missing package, a CUDA device torch does not see or results of an earlier run in ``--out`` end
the command before any work with one line on stderr and exit code 2.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

import torch

__all__ = ["REQUIRED", "check_args", "fail", "memory_cap", "parse_args"]

#: import name -> distribution of what a run needs beside torch (the CUDA tests: pytest and scipy)
REQUIRED = {"numpy": "numpy", "trimesh": "trimesh", "yaml": "PyYAML", "tqdm": "tqdm", "pytest": "pytest",
            "scipy": "scipy"}



def parse_args(argv=None, *, description: str = "") -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", required=True, help="folder for gpu_check.md, gpu_check.csv and cuda_tests.*")
    parser.add_argument("--device", default="cuda", help="cuda, cuda:N or cpu (a CPU-only rehearsal; default cuda)")
    parser.add_argument("--quick", action="store_true",
                        help="tiny sizes: 1260 training points, M = 128, B = 10/100/1000, 5 steps")
    parser.add_argument("--time-budget-s", type=float, default=240.0,
                        help="wall-clock budget of the whole run; sections left are skipped (default 240)")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per case, median reported (default 3)")
    parser.add_argument("--case-cap-s", type=float, default=None,
                        help="seconds aimed at per filter case (default 6; --quick 0.5)")
    parser.add_argument("--cpu-threads", type=int, default=0, help="torch CPU threads (default 0: torch's default)")
    parser.add_argument("--tests-timeout-s", type=float, default=150.0, help="limit of the CUDA-test process")
    parser.add_argument("--gpu-chunk-values", type=int, default=1 << 27,
                        help="GP kernel values per block on CUDA (default 2^27: 1 GiB in float64)")
    parser.add_argument("--gpu-render-chunk", type=int, default=1 << 22,
                        help="attitude-facet pairs per renderer chunk on CUDA (default 2^22)")
    parser.add_argument("--overwrite", action="store_true", help="replace the results of an earlier run in --out")
    return parser.parse_args(argv)


def fail(message: str) -> None:
    print(f"gpu_check: error: {message}", file=sys.stderr)
    sys.exit(2)


def _importable(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def check_args(args) -> torch.device:
    try:
        device = torch.device(args.device)
    except RuntimeError:
        fail(f"--device {args.device!r} is not a torch device (cuda, cuda:N or cpu)")
    if device.type not in ("cuda", "cpu"):
        fail(f"--device {args.device!r}: only cuda, cuda:N or cpu")
    if device.type == "cuda" and not torch.cuda.is_available():
        fail(f"--device {args.device}: torch {torch.__version__} sees no CUDA device "
             f"(CUDA build: {torch.version.cuda})")
    if device.type == "cuda" and (device.index or 0) >= torch.cuda.device_count():
        fail(f"--device {args.device}: only {torch.cuda.device_count()} CUDA device(s)")
    missing = [dist for module, dist in REQUIRED.items() if not _importable(module)]
    if missing:
        fail(f"missing Python packages: {', '.join(missing)} (install them first)")
    for name in ("time_budget_s", "repeats", "gpu_chunk_values", "gpu_render_chunk", "tests_timeout_s", "case_cap_s"):
        if getattr(args, name) is not None and not getattr(args, name) > 0:
            fail(f"--{name.replace('_', '-')} must be > 0, got {getattr(args, name)}")
    if args.cpu_threads < 0:
        fail(f"--cpu-threads must be >= 0, got {args.cpu_threads}")
    existing = [p for p in ("gpu_check.md", "gpu_check.csv") if (Path(args.out) / p).exists()]
    if existing and not args.overwrite:
        fail(f"--out {args.out}: {existing[0]} exists from an earlier run (pass --overwrite to replace it)")
    return device


def memory_cap(device: torch.device, cap_gib: float = 60.0) -> float | None:
    """Cap this process's CUDA allocations at ``cap_gib`` (or 90 % of a smaller card); returns the cap."""
    if device.type != "cuda":
        return None
    index = device.index if device.index is not None else torch.cuda.current_device()
    total = torch.cuda.get_device_properties(index).total_memory
    fraction = min(0.9, cap_gib * 2**30 / total)
    torch.cuda.set_per_process_memory_fraction(fraction, index)
    return fraction * total / 2**30
