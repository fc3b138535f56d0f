"""Measuring for ``benchmarks/gpu_check.py``: one case timed on the device and on the CPU, failures kept as notes.

:class:`Context` carries what every section shares — arguments, the device, the time budget, the report, the
failure count and objects built once per run (:meth:`Context.once`). :meth:`Context.case` times one case on both
and appends its row; every failure, skip or budget stop becomes the row's note instead of an exception.
"""

from __future__ import annotations

import dataclasses
import statistics
import time
import traceback
from collections.abc import Callable
from pathlib import Path
from typing import Any

import common as C
import torch
from gpu_report import NOT_MEASURED, Budget, Report, Row

__all__ = ["Context", "Part", "Skip", "cpu_gemm_gflops", "first_line", "median_time"]


class Skip(Exception):
    """A part left out on purpose; the message says why."""


@dataclasses.dataclass
class Part:
    """One device's result of a case: seconds (``None`` when not run), a note, and an output to compare."""

    seconds: float | None = None
    note: str = ""
    output: Any = None


def median_time(fn: Callable[[], Any], sync: Callable[[], None], *, repeats: int, warmup: int = 1):
    """``(median seconds, last output)`` of ``repeats`` calls of ``fn`` after ``warmup`` calls, each synchronised."""
    out = None
    for _ in range(warmup):
        out = fn()
        sync()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        sync()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def cpu_gemm_gflops(dtype: torch.dtype, n: int = 1024) -> float:
    """GFLOP/s of an ``n × n`` matrix product on the CPU (median of 3 after a warm-up)."""
    a = torch.randn(n, n, dtype=dtype)
    seconds, _ = median_time(lambda: a @ a, lambda: None, repeats=3)
    return 2 * n**3 / seconds / 1e9


def first_line(error: BaseException) -> str:
    text = str(error).strip().splitlines()
    return (text[0] if text else "")[:200]


class Context:
    """Arguments, device, budget, report and objects built once, shared by the sections of a run."""

    def __init__(self, args, budget: Budget, sizes: dict, cfg, out: Path):
        self.args, self.budget, self.sizes, self.cfg, self.out = args, budget, sizes, cfg, Path(out)
        self.test_packages: list[str] = []  # "name version" imported by the CUDA-test process
        self.device, self.cpu = torch.device(args.device), torch.device("cpu")
        self.report: Report | None = None
        self.failures = 0
        self.gflops = {dt: cpu_gemm_gflops(dt) for dt in (torch.float64, torch.float32)}
        self._built: dict[str, tuple[Any, BaseException | None]] = {}

    @property
    def cuda(self) -> bool:
        return self.device.type == "cuda"

    def log(self, text: str) -> None:
        print(f"[{self.budget.elapsed():7.1f} s] {text}", flush=True)

    def once(self, key: str, build: Callable[[], Any]) -> Any:
        """``build()`` the first time ``key`` is asked for; later calls return it (or raise its error again)."""
        if key not in self._built:
            t0 = time.perf_counter()
            try:
                self._built[key] = (build(), None)
                self.log(f"built {key} in {time.perf_counter() - t0:.2f} s")
            except Exception as error:  # noqa: BLE001 - kept: each case that needs it says why, no rebuild
                self._built[key] = (None, error)
                self.log(f"could not build {key}: {type(error).__name__}: {first_line(error)}")
        value, error = self._built[key]
        if error is not None:
            raise error
        return value

    def sync(self, device: torch.device) -> Callable[[], None]:
        return C.synchronizer(device)

    def timed(self, device: torch.device, fn: Callable[[], Any], *, heavy: bool = False):
        """``(median seconds, output)`` of ``fn`` on ``device``: on the run's device one warm-up and ``--repeats``
        runs; on the CPU beside it ``--repeats`` runs, or for a ``heavy`` case ``cpu_heavy_repeats`` runs."""
        if device != self.device and heavy:
            return median_time(fn, lambda: None, repeats=self.sizes["cpu_heavy_repeats"], warmup=0)
        return median_time(fn, self.sync(device), repeats=self.args.repeats, warmup=1 if device == self.device else 0)

    def check_cholesky(self, n: int, dtype: torch.dtype, *, runs: int) -> None:
        """Raise :class:`Skip` when ``runs`` CPU Cholesky factorisations of ``n × n`` (``n³/3`` flops each at half
        the measured matrix-product rate) are projected to outlast the budget left."""
        projected = n**3 / 3 / (0.5 * self.gflops[dtype] * 1e9) * runs
        if projected > self.budget.left():
            raise Skip(f"projected {projected:.3g} s > {self.budget.left():.0f} s of budget left")

    def gpu_reset(self) -> None:
        if self.cuda:
            torch.cuda.synchronize(self.device)
            torch.cuda.reset_peak_memory_stats(self.device)

    def gpu_peak_gib(self) -> float | None:
        return torch.cuda.max_memory_allocated(self.device) / 2**30 if self.cuda else None

    def part(self, label: str, fn: Callable[[], tuple]) -> Part:
        """One device's measurement ``fn() -> (seconds, note, output)``; budget, skips and failures become notes."""
        if self.budget.left() <= 0:
            return Part(note=f"{label} skipped: budget")
        try:
            seconds, note, output = fn()
            return Part(seconds, f"{label}: {note}" if note else "", output)
        except Skip as why:
            return Part(note=f"{label} skipped: {why}")
        except Exception as error:  # noqa: BLE001 - any failure is the row's note; the run goes on
            traceback.print_exc()
            self.failures += 1
            if self.cuda:
                torch.cuda.empty_cache()
            return Part(note=f"{label} FAILED: {type(error).__name__}: {first_line(error)}")

    def case(self, section: str, name: str, size: str, device_fn: Callable[[], tuple],
             cpu_fn: Callable[[], tuple] | None = None, *, unit: str = "s per call", batch: int | None = None,
             compare: Callable[[Any, Any], str] | None = None) -> Row:
        """Time one case on the device and, given ``cpu_fn``, on the CPU (else "not measured"), and add its row;
        ``compare(device output, CPU output)`` adds a consistency note."""
        self.gpu_reset()
        dev = self.part(self.device.type, device_fn)
        cpu = self.part("CPU", cpu_fn) if cpu_fn is not None else Part()
        notes = [dev.note, cpu.note]
        if compare is not None and dev.output is not None and cpu.output is not None:
            try:
                notes.append(compare(dev.output, cpu.output))
            except Exception as error:  # noqa: BLE001 - a failed check is a note too
                self.failures += 1
                notes.append(f"check FAILED: {type(error).__name__}: {first_line(error)}")
        peak = self.gpu_peak_gib()
        if peak:
            notes.append(f"GPU peak {peak:.2f} GiB")
        row = self.report.add(Row(section, name, size, dev.seconds, cpu.seconds, batch, unit,
                                  "; ".join(n for n in notes if n), "" if cpu_fn is not None else NOT_MEASURED))
        self.log(f"{section}: {name} [{size}] {self.device.type} {_fmt(row.device_s)}, CPU {_fmt(row.cpu_s)}"
                 + (f", {row.rate(row.device_s):.3g} filter-steps/s" if row.rate(row.device_s) else "")
                 + (f" ({row.note})" if row.note else ""))
        return row


def _fmt(seconds: float | None) -> str:
    return C.fmt_seconds(seconds) if seconds is not None else "-"
