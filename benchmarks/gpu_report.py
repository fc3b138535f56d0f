"""The table of ``benchmarks/gpu_check.py``: rows of device-vs-CPU timings, rewritten atomically after every row.

Each row is one case: seconds on the device and on the CPU of the same run (per call, or per filter step), their
ratio, filter-steps per second for filter rows, and a note (status, checks, peak GPU memory). ``gpu_check.md``
(header + Markdown table + footer) and ``gpu_check.csv`` (raw numbers) are replaced as a whole after each row, so
a run killed half-way leaves every finished row on disk and a footer that says the run did not finish.
"""

from __future__ import annotations

import csv
import io
import math
import os
import platform
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from common import fmt_seconds, load_average

__all__ = ["NOT_MEASURED", "Budget", "Report", "Row", "best_rate", "footer_lines", "imported_packages",
           "machine_header", "workload_lines"]

#: the CPU cell of a case the CPU is not asked to run (e.g. B = 10⁵ filters)
NOT_MEASURED = "not measured"


class Budget:
    """A wall-clock allowance for the whole run, counted from construction (seconds)."""

    def __init__(self, seconds: float):
        self.seconds = float(seconds)
        self.start = time.perf_counter()

    def elapsed(self) -> float:
        return time.perf_counter() - self.start

    def left(self) -> float:
        return self.seconds - self.elapsed()


@dataclass
class Row:
    """One case. ``device_s``/``cpu_s``: seconds (per call, or per step for filter rows; ``None`` when not run);
    ``cpu_note`` replaces an absent CPU number in the table (e.g. :data:`NOT_MEASURED`); ``batch``: filters per
    step (filter rows only), which turns seconds per step into filter-steps per second."""

    section: str
    case: str
    size: str = ""
    device_s: float | None = None
    cpu_s: float | None = None
    batch: int | None = None
    unit: str = "s per call"
    note: str = ""
    cpu_note: str = ""

    def ratio(self) -> float | None:
        """CPU seconds / device seconds (how many times faster the device is)."""
        if self.device_s and self.cpu_s:
            return self.cpu_s / self.device_s
        return None

    def rate(self, seconds: float | None) -> float | None:
        """Filter-steps per second of a filter row."""
        return self.batch / seconds if self.batch and seconds else None


def _fmt_rate(rate: float | None) -> str:
    return "" if rate is None else f"{rate:.3g}"


class Report:
    """Rows plus a header, written to ``out_dir/gpu_check.md`` and ``out_dir/gpu_check.csv`` after every row."""

    def __init__(self, out_dir: Path, device_label: str, header: list[str]):
        self.out_dir = Path(out_dir)
        self.device_label = device_label
        self.header = list(header)
        self.rows: list[Row] = []
        self.footer: list[str] = ["**Run not finished** (killed, or still running)."]
        self.write()

    @property
    def md_path(self) -> Path:
        return self.out_dir / "gpu_check.md"

    @property
    def csv_path(self) -> Path:
        return self.out_dir / "gpu_check.csv"

    def add(self, row: Row) -> Row:
        self.rows.append(row)
        self.write()
        return row

    def finish(self, footer: list[str]) -> None:
        self.footer = list(footer)
        self.write()

    def markdown(self) -> str:
        dev = self.device_label
        cols = ["section", "case", "size", dev, "CPU", f"CPU / {dev}", f"{dev} filter-steps/s",
                "CPU filter-steps/s", "note"]
        lines = self.header + ["", "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
        for r in self.rows:
            cpu = fmt_seconds(r.cpu_s) if r.cpu_s is not None else (r.cpu_note or "")
            dev_cell = fmt_seconds(r.device_s) if r.device_s is not None else ""
            unit = f" ({r.unit})" if r.device_s is not None or r.cpu_s is not None else ""
            ratio = r.ratio()
            cells = [r.section, r.case + unit, r.size, dev_cell, cpu, "" if ratio is None else f"{ratio:.3g}x",
                     _fmt_rate(r.rate(r.device_s)), _fmt_rate(r.rate(r.cpu_s)), r.note]
            lines.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
        return "\n".join(lines + [""] + self.footer) + "\n"

    def csv(self) -> str:
        buf = io.StringIO()
        names = [f.name for f in fields(Row)] + ["cpu_over_device", "device_filter_steps_per_s",
                                                  "cpu_filter_steps_per_s"]
        writer = csv.DictWriter(buf, fieldnames=names, lineterminator="\n")
        writer.writeheader()
        for r in self.rows:
            writer.writerow({**asdict(r), "cpu_over_device": r.ratio(), "device_filter_steps_per_s": r.rate(r.device_s),
                             "cpu_filter_steps_per_s": r.rate(r.cpu_s)})
        return buf.getvalue()

    def write(self) -> None:
        # imported here, so that a run checks the packages the project needs before importing it
        from lightcurve_gp.files import write_text_atomic

        write_text_atomic(self.markdown(), self.md_path)
        write_text_atomic(self.csv(), self.csv_path)


def best_rate(rows: list[Row], section: str, prefix: str) -> float | None:
    """The largest device filter-steps/s among rows of ``section`` whose case starts with ``prefix``."""
    rates = [r.rate(r.device_s) for r in rows if r.section == section and r.case.startswith(prefix)]
    rates = [x for x in rates if x is not None and math.isfinite(x)]
    return max(rates) if rates else None


def imported_packages() -> list[str]:
    """``"name version"`` of each installed distribution (other than this project) that this process imported."""
    from importlib import metadata

    owners = metadata.packages_distributions()
    names = {dist for module in list(sys.modules) for dist in owners.get(module.split(".")[0], [])}
    return sorted(f"{name} {metadata.version(name)}" for name in names if name.lower() != "lightcurve-gp")


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def _driver() -> str:
    """``driver X, compute mode Y`` from nvidia-smi (``unknown`` without it)."""
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=driver_version,compute_mode", "--format=csv,noheader"],
                             check=False, capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return "driver unknown"
    first = out.stdout.strip().splitlines()[0] if out.returncode == 0 and out.stdout.strip() else ""
    driver, _, mode = first.partition(",")
    return f"driver {driver.strip()}, compute mode {mode.strip()}" if first else "driver unknown"


def machine_header(device, gflops: dict, memory_cap_gib: float | None) -> list[str]:
    """Markdown lines naming the card, torch/CUDA versions, the CPU and its measured GEMM rates."""
    import torch

    lines = ["# GPU check of lightcurve-gp (`benchmarks/gpu_check.py`)", ""]
    if device.type == "cuda":
        props = torch.cuda.get_device_properties(device)
        cap = f"; this run's allocation cap {memory_cap_gib:.0f} GiB" if memory_cap_gib else ""
        lines.append(f"* device: **{torch.cuda.get_device_name(device)}** ({props.total_memory / 2**30:.1f} GiB, "
                     f"{props.multi_processor_count} SMs, {_driver()}){cap}")
        lines.append(f"* torch {torch.__version__}, CUDA {torch.version.cuda}, cuDNN {torch.backends.cudnn.version()}")
    else:
        lines.append(f"* device: {device} (a CPU-only rehearsal: both columns run on the CPU)")
        lines.append(f"* torch {torch.__version__} (CUDA build: {torch.version.cuda})")
    lines.append(f"* CPU: {_cpu_model()}, os.cpu_count() = {os.cpu_count()}, "
                 f"torch threads = {torch.get_num_threads()}; "
                 f"1024² matrix product {gflops[torch.float64]:.0f} GFLOP/s (float64), "
                 f"{gflops[torch.float32]:.0f} GFLOP/s (float32)")
    lines.append(f"* started {time.strftime('%Y-%m-%d %H:%M:%S UTC', time.gmtime())}, load average "
                 f"{load_average()}, Python {platform.python_version()}")
    return lines


def workload_lines(sizes: dict, args, dtype: str) -> list[str]:
    """Markdown lines: the sizes, how cases are timed, and the command."""
    return [(f"* workload: configs/boxwing.yaml{' with --quick sizes' if args.quick else ''} ({dtype}); filters: "
             f"B = {', '.join(map(str, sizes['batches']))} USQUE filters × 7 sigma points, CPU at "
             f"B = {', '.join(map(str, sizes['cpu_batches']))} only; sparse GP M = {sizes['num_inducing']}"),
            (f"* timing: device median of {args.repeats} runs after 1 warm-up (synchronised); CPU median of "
             f"{args.repeats} (exact conditioning: {sizes['cpu_heavy_repeats']} run(s), no warm-up); filter rows: "
             f"seconds per step of all B filters; CUDA kernel blocks of {args.gpu_chunk_values} GP kernel values and "
             f"{args.gpu_render_chunk} renderer attitude-facet pairs"),
            f"* command: `python benchmarks/gpu_check.py {' '.join(sys.argv[1:])}`"]


def footer_lines(rows: list[Row], *, device_type: str, aim: float, status: str, elapsed: float, budget: float,
                 failures: int, test_packages: list[str]) -> list[str]:
    """Markdown lines: the sparse filter's best rate against ``aim``, how the run ended, the packages it used."""
    rate = best_rate(rows, "filter", "SparseGP")
    verdict = "not measured" if rate is None else f"{rate:.3g} filter-steps/s: {'met' if rate >= aim else 'missed'}"
    skipped = sum("skipped" in r.note for r in rows if r.section != "CUDA tests")
    return [f"* aim ≥ {aim:,.0f} filter-steps/s with the sparse GP on {device_type}: best {verdict}",
            (f"* {status} after {elapsed:.0f} s (budget {budget:.0f} s); {failures} failure(s); {skipped} timing "
             "row(s) with a part skipped"),
            "* Python packages imported by this process: " + ", ".join(imported_packages()),
            "* and by the CUDA-test process: " + (", ".join(test_packages) or "(did not run)")]
