"""benchmarks/gpu_check.py: its CPU-only rehearsal writes the full table; budget, refusals and test verdicts."""

from __future__ import annotations

import csv
import importlib
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "gpu_check.py"


def _benchmark_module(name: str):
    """A module of benchmarks/ (which imports its siblings by plain name, as the scripts run from there)."""
    if str(ROOT / "benchmarks") not in sys.path:
        sys.path.insert(0, str(ROOT / "benchmarks"))
    return importlib.import_module(name)


cuda_tests = _benchmark_module("cuda_tests")
report_mod = _benchmark_module("gpu_report")
NOT_MEASURED, Report, Row = report_mod.NOT_MEASURED, report_mod.Report, report_mod.Row

SECTIONS = ["CUDA tests", "filter", "conditioning", "render", "sparse fit"]
QUICK_BATCHES = [10, 100, 1000]  # gpu_check.QUICK: the CPU column at the two smaller only
CUDA_TESTS = {"tests/test_gp_models.py::test_cuda_matches_cpu[exact]",
              "tests/test_gp_models.py::test_cuda_matches_cpu[sparse]",
              "tests/test_render.py::test_cuda_matches_cpu", "tests/test_ukf.py::test_usque_on_cuda_matches_cpu"}


def _run(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(ROOT), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, str(SCRIPT), *args], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=600, check=False)


def _rows(out: Path) -> list[dict]:
    with open(out / "gpu_check.csv", newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_cpu_rehearsal_writes_every_row(tmp_path):
    proc = _run("--out", str(tmp_path), "--device", "cpu", "--quick", "--cpu-threads", "1")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    rows = _rows(tmp_path)
    by_section = {s: [r for r in rows if r["section"] == s] for s in SECTIONS}
    assert [r["section"] for r in rows] == [s for s in SECTIONS for _ in by_section[s]]  # importance order

    tests = {r["case"]: r for r in by_section["CUDA tests"]}
    summary = tests.pop("summary")
    assert CUDA_TESTS <= set(tests)  # and no test that runs without CUDA, such as those of this module
    assert not any(t.startswith("tests/test_gpu_check.py") for t in tests)
    expect = "skipped: " if not torch.cuda.is_available() else "passed"
    assert all(row["note"].startswith(expect) for row in tests.values())
    assert summary["note"].startswith(f"{len(tests)} CUDA tests:")

    filt = by_section["filter"]
    assert [(r["case"], int(r["batch"])) for r in filt] == [
        (case, b) for case in ("SparseGP mean only", "SparseGP mean + variance", "ExactGP mean only (paper's GPUKF)")
        for b in QUICK_BATCHES]
    for r in filt:
        dev_s = float(r["device_s"])
        assert float(r["device_filter_steps_per_s"]) == pytest.approx(int(r["batch"]) / dev_s)
        if int(r["batch"]) == QUICK_BATCHES[-1]:
            assert r["cpu_s"] == "" and r["cpu_note"] == NOT_MEASURED
        else:  # the same code on the same device: the two columns' filters agree to the bit
            assert float(r["cpu_over_device"]) == pytest.approx(float(r["cpu_s"]) / dev_s)
            assert "max |Δq̂| vs CPU 0 after 2 steps" in r["note"]

    cond = {r["case"]: r for r in by_section["conditioning"]}
    assert "|α_dev − α_CPU| / |α_CPU| = 0" in cond["ExactGP.from_data, float64"]["note"]
    rel32 = float(cond["Cholesky + solves, float32"]["note"].split("|α64| = ")[1].split(";")[0])
    assert 0 < rel32 < 1e-2  # float32 differs from float64, by little
    assert [r["case"] for r in by_section["render"]] == [
        "training-set generation (propagate + render + window)", "render only, float64", "render only, float32"]
    assert all("vs CPU 0" in r["note"] for r in by_section["render"] + by_section["sparse fit"])
    assert all(r["device_s"] and r["cpu_s"] for r in by_section["render"] + by_section["sparse fit"])

    md = (tmp_path / "gpu_check.md").read_text()
    assert "os.cpu_count() =" in md and "torch " + torch.__version__ in md
    assert "* finished after" in md and "0 failure(s)" in md and "Run not finished" not in md
    assert len([ln for ln in md.splitlines() if ln.startswith("| ") and not ln.startswith("| section")]) == len(rows)

    again = _run("--out", str(tmp_path), "--device", "cpu", "--quick")
    assert again.returncode == 2
    assert again.stderr.strip().splitlines() == [
        f"gpu_check: error: --out {tmp_path}: gpu_check.md exists from an earlier run (pass --overwrite to replace it)"]


@pytest.mark.slow  # ~6 s on two loaded cores
def test_spent_budget_skips_every_section(tmp_path):
    proc = _run("--out", str(tmp_path), "--device", "cpu", "--quick", "--time-budget-s", "0.001")
    assert proc.returncode == 0, proc.stderr[-3000:]
    rows = _rows(tmp_path)
    assert [(r["section"], r["note"]) for r in rows] == [(s, "skipped: budget") for s in SECTIONS]
    md = (tmp_path / "gpu_check.md").read_text()
    assert "best not measured" in md and "* finished after" in md


@pytest.mark.slow  # ~4 s on two loaded cores
@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the refusal on a machine without CUDA")
def test_cuda_without_a_device_is_refused(tmp_path):
    proc = _run("--out", str(tmp_path))
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines() == [
        f"gpu_check: error: --device cuda: torch {torch.__version__} sees no CUDA device (CUDA build: None)"]
    assert not (tmp_path / "gpu_check.md").exists()


def test_report_rewrites_table_after_each_row(tmp_path):
    report = Report(tmp_path, "cuda", ["# header"])
    assert "Run not finished" in report.md_path.read_text()
    row = report.add(Row("filter", "a|b", "B = 10", device_s=0.002, cpu_s=0.05, batch=10, unit="s per step"))
    assert row.ratio() == pytest.approx(25.0) and row.rate(row.device_s) == pytest.approx(5000.0)
    md = report.md_path.read_text()
    assert "| filter | a\\|b (s per step) | B = 10 | 2 ms | 50 ms | 25x | 5e+03 | 200 |" in md
    report.add(Row("filter", "c", device_s=1.0, batch=100, cpu_note=NOT_MEASURED))
    assert [r["cpu_note"] for r in _rows(tmp_path)] == ["", NOT_MEASURED]
    report.finish(["* done"])
    assert report.md_path.read_text().rstrip().endswith("* done")


@pytest.mark.parametrize(("test", "expect_cuda", "verdict"), [
    ({"outcome": "passed", "cuda_peak_bytes": 3 * 2**20}, True,
     ("passed; CUDA memory peak 3.00 MiB during the test", 0)),
    ({"outcome": "passed", "cuda_peak_bytes": 0}, True,
     ("FAILED: passed but allocated no CUDA memory (not a CUDA run)", 1)),
    ({"outcome": "skipped", "reason": "needs CUDA"}, True,
     ("FAILED: skipped although CUDA was asked for (needs CUDA)", 1)),
    ({"outcome": "skipped", "reason": "needs CUDA"}, False, ("skipped: needs CUDA", 0)),
    ({"outcome": "failed", "reason": "E   AssertionError"}, True, ("FAILED (failed): E   AssertionError", 1)),
])
def test_cuda_test_verdicts(test, expect_cuda, verdict):
    assert cuda_tests.describe(test, expect_cuda=expect_cuda) == verdict
