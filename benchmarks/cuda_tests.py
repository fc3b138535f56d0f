"""The project's CUDA tests, run by pytest in a process of their own, with evidence that each one used the GPU.

A CUDA test is a test that skips without a CUDA device: it carries a ``skipif(not torch.cuda.is_available())``
mark whose reason mentions CUDA (today ``tests/test_gp_models.py::test_cuda_matches_cpu[exact|sparse]``,
``tests/test_render.py::test_cuda_matches_cpu`` and ``tests/test_ukf.py::test_usque_on_cuda_matches_cpu``). The
plugin deselects every
other test and records, per CUDA test, its outcome, its duration and the peak CUDA memory allocated while its body
ran (``torch.cuda.max_memory_allocated`` after a reset): a passed test with a peak of 0 bytes never put a tensor on
the GPU. Collection errors in unrelated modules (a missing optional package) do not stop the run.

    python benchmarks/cuda_tests.py RESULT.json      # from the repository root; writes RESULT.json

:func:`run` starts that process from ``benchmarks/gpu_check.py``; :func:`describe` and :func:`summary` word its
result for the table.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def needs_cuda(item, cuda_available: bool) -> bool:
    """Whether a collected test item skips exactly when CUDA is absent: a ``skipif`` whose reason names CUDA and
    whose condition is ``not torch.cuda.is_available()`` (a test that skips *with* CUDA is not one)."""
    for mark in item.iter_markers("skipif"):
        condition = mark.args[0] if mark.args else mark.kwargs.get("condition")
        if "cuda" in str(mark.kwargs.get("reason", "")).lower() and bool(condition) is not cuda_available:
            return True
    return False


def _reason(report) -> str:
    """One line of why a test was skipped or failed."""
    if report.skipped and isinstance(report.longrepr, tuple):
        return str(report.longrepr[2]).removeprefix("Skipped: ")
    text = getattr(report, "longreprtext", "") or ""
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("E ")]
    return (errors or lines or [""])[-1][:300]


class CudaTestProbe:
    """pytest plugin: keep the CUDA tests, record outcome, duration and peak CUDA memory of each."""

    def __init__(self):
        import torch

        self.torch = torch
        self.cuda = torch.cuda.is_available()
        self.tests: dict[str, dict] = {}
        self.collection_errors: list[str] = []

    def _entry(self, nodeid: str) -> dict:
        return self.tests.setdefault(nodeid, {"outcome": "passed", "duration_s": 0.0, "cuda_peak_bytes": None,
                                              "reason": ""})

    def pytest_collectreport(self, report):
        if report.failed:
            self.collection_errors.append(f"{report.nodeid}: {_reason(report)}")

    def pytest_collection_modifyitems(self, config, items):
        keep = [item for item in items if needs_cuda(item, self.cuda)]
        dropped = [item for item in items if not needs_cuda(item, self.cuda)]
        if dropped:
            config.hook.pytest_deselected(items=dropped)
        items[:] = keep

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_call(self, item):
        if self.cuda:
            self.torch.cuda.synchronize()
            self.torch.cuda.reset_peak_memory_stats()
        yield
        if self.cuda:
            self.torch.cuda.synchronize()
            self._entry(item.nodeid)["cuda_peak_bytes"] = int(self.torch.cuda.max_memory_allocated())

    def pytest_runtest_logreport(self, report):
        entry = self._entry(report.nodeid)
        entry["duration_s"] += float(report.duration)
        if report.outcome != "passed" and entry["outcome"] == "passed":
            entry["outcome"] = report.outcome if report.when == "call" or report.skipped else f"error in {report.when}"
            entry["reason"] = _reason(report)


def run(out_dir: Path, timeout: float) -> dict | str:
    """Run the CUDA tests in a subprocess writing ``out_dir/cuda_tests.json`` and ``out_dir/cuda_tests.log``.

    Returns the parsed result, or a one-line reason when there is none (timeout, crash)."""
    result, log_path = Path(out_dir) / "cuda_tests.json", Path(out_dir) / "cuda_tests.log"
    result.unlink(missing_ok=True)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(ROOT), os.environ.get("PYTHONPATH", "")]))
    try:
        with open(log_path, "w") as log_file:
            proc = subprocess.run([sys.executable, __file__, str(result)], check=False, cwd=ROOT, env=env,
                                  stdout=log_file, stderr=subprocess.STDOUT, timeout=timeout)
    except subprocess.TimeoutExpired:
        return f"timed out after {timeout:.0f} s (see cuda_tests.log)"
    if not result.exists():
        return f"pytest exit code {proc.returncode} and no result (see cuda_tests.log)"
    return json.loads(result.read_text())


def describe(test: dict, *, expect_cuda: bool) -> tuple[str, int]:
    """The table note of one CUDA test's result and 1 when it counts as a failure (a skip does when CUDA was
    asked for; so does a pass that allocated no CUDA memory)."""
    peak = test.get("cuda_peak_bytes")
    if test["outcome"] == "passed":
        if peak:
            return f"passed; CUDA memory peak {peak / 2**20:.2f} MiB during the test", 0
        if not expect_cuda:
            return "passed (no CUDA)", 0
        return "FAILED: passed but allocated no CUDA memory (not a CUDA run)", 1
    if test["outcome"] == "skipped":
        if expect_cuda:
            return f"FAILED: skipped although CUDA was asked for ({test['reason']})", 1
        return f"skipped: {test['reason']}", 0
    return f"FAILED ({test['outcome']}): {test['reason']}", 1


def summary(result: dict) -> str:
    """One line: counts per outcome, pytest's exit code, whether torch saw CUDA, unrelated collection errors."""
    counts: dict[str, int] = {}
    for test in result["tests"].values():
        counts[test["outcome"]] = counts.get(test["outcome"], 0) + 1
    text = ", ".join(f"{n} {outcome}" for outcome, n in sorted(counts.items())) or "none found"
    errors = result.get("collection_errors") or []
    return (f"{len(result['tests'])} CUDA tests: {text}; pytest exit code {result['exit_code']}; torch sees CUDA: "
            f"{result['cuda_available']}" + (f"; {len(errors)} other test modules failed to import" if errors else ""))


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: python benchmarks/cuda_tests.py RESULT.json", file=sys.stderr)
        return 2
    probe = CudaTestProbe()
    code = pytest.main(["-q", "-p", "no:cacheprovider", "--continue-on-collection-errors", "tests"],
                       plugins=[probe])
    from gpu_report import imported_packages

    device = probe.torch.cuda.get_device_name() if probe.cuda else None
    Path(argv[1]).write_text(json.dumps({"exit_code": int(code), "cuda_available": probe.cuda, "device": device,
                                         "tests": probe.tests, "collection_errors": probe.collection_errors,
                                         "packages": imported_packages()}, indent=2) + "\n")
    return int(code)


if __name__ == "__main__":
    sys.exit(main(sys.argv))
