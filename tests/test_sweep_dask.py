"""Sweeps on dask.distributed: a 2-worker LocalCluster writes the same result store as the local executor, a worker
killed mid-case still leaves a complete store, resume skips finished cases whichever executor wrote them, and the
command line's executor errors.

One tiny grid (two GP models, four cases, two seeds) is run once in this process (the reference) and on one
LocalCluster shared by the tests of this module.
"""

import functools
import json
import os
import shutil
import sys
from pathlib import Path

import pytest
import yaml

from lightcurve_gp.config.load import apply_overrides
from lightcurve_gp.sweep.cli import main
from lightcurve_gp.sweep.executors import CLUSTER_EXTRA, make_executor
from lightcurve_gp.sweep.runner import run_case, run_sweep

BOXWING = Path(__file__).resolve().parents[1] / "configs" / "boxwing.yaml"
TINY = ["name=tiny", "data.icosphere_subdivisions=0", "data.phi_step_deg=120", "data.heldout_size=10",
        "scenario.duration_s=30", "evaluation.rmse_window_s=[10, 30]"]
AXES = [("data.t_span_past", [10, 20]), ("scenario.rho_true", [0.3, 0.7])]
SEEDS = range(2)
#: timing columns: the only ones allowed to differ between two runs of the same case
TIMING = ("seconds_per_step",)


def tiny_raw() -> dict:
    return apply_overrides(yaml.safe_load(BOXWING.read_text()), TINY)


def table(folder: Path, name: str) -> list[dict]:
    """A sweep table (``results`` or ``summary``) from its JSON/CSV file, timing columns removed."""
    import csv

    with open(folder / f"{name}.csv", newline="") as fh:
        return [{k: v for k, v in row.items() if k not in TIMING} for row in csv.DictReader(fh)]


def die_once_then_run(spec: dict, *, marker: str) -> dict:
    """The first case to run kills its worker process (no marker yet); every later run is a normal case."""
    if not os.path.exists(marker):
        Path(marker).touch()
        os._exit(1)
    return run_case(spec)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The tiny sweep run by the local executor in this process."""
    out = tmp_path_factory.mktemp("local")
    return run_sweep(tiny_raw(), AXES, SEEDS, out=out, sweep_id="s", progress=False)


@pytest.fixture(scope="module")
def cluster():
    """A LocalCluster of 2 single-threaded worker processes, a worker death retried twice."""
    with make_executor("dask", workers=2, retries=2) as executor:
        yield executor


@pytest.mark.slow
def test_dask_writes_the_same_store_as_the_local_executor(reference, cluster, tmp_path):
    result = run_sweep(tiny_raw(), AXES, SEEDS, out=tmp_path, sweep_id="s", progress=False, executor=cluster)
    assert not reference.failed and not result.failed and len(result.ran) == 4
    assert sorted(result.ran) == sorted(reference.ran)
    for name in ("results", "summary"):
        mine, theirs = table(result.folder, name), table(reference.folder, name)
        assert len(mine) == len(theirs) == (4 * 4 * 2 if name == "results" else 4 * 4)
        assert sorted(mine, key=json.dumps) == sorted(theirs, key=json.dumps)  # bit-identical numbers as text
    # one model per distinct t_span_past, and the same case files
    assert len(list((tmp_path / "models").glob("*/model.pt"))) == 2
    assert sorted(p.name for p in (tmp_path / "tiny" / "cases").glob("*.json")) == sorted(
        f"{cid}.json" for cid in reference.ran)


@pytest.mark.slow
def test_a_worker_killed_mid_case_still_leaves_a_complete_store(reference, cluster, tmp_path):
    marker = tmp_path / "died"
    shutil.copytree(reference.folder.parents[2] / "models", tmp_path / "models")  # cases only
    result = run_sweep(tiny_raw(), AXES, SEEDS, out=tmp_path, sweep_id="s", progress=False, executor=cluster,
                       case_runner=functools.partial(die_once_then_run, marker=str(marker)))
    assert marker.exists()  # one case did kill its worker
    assert not result.failed and not result.interrupted and len(result.ran) == 4
    assert json.loads((result.folder / "summary.json").read_text())["complete"] is True
    assert sorted(table(result.folder, "summary"), key=json.dumps) == sorted(
        table(reference.folder, "summary"), key=json.dumps)


@pytest.mark.slow
def test_dask_resumes_a_store_of_the_local_executor_running_only_what_is_missing(reference, cluster, tmp_path):
    shutil.copytree(reference.folder.parents[1], tmp_path / "tiny")  # the cases of the local run
    shutil.copytree(reference.folder.parents[2] / "models", tmp_path / "models")  # and its models
    cases = tmp_path / "tiny" / "cases"
    missing = sorted(reference.ran)[:2]
    for cid in missing:
        (cases / f"{cid}.json").unlink()
    stamps = {p.name: p.stat().st_mtime_ns for p in cases.glob("*.json")}
    result = run_sweep(tiny_raw(), AXES, SEEDS, out=tmp_path, sweep_id="s", progress=False, executor=cluster)
    assert sorted(result.ran) == missing
    assert {p.name: p.stat().st_mtime_ns for p in cases.glob("*.json") if p.name in stamps} == stamps
    assert table(result.folder, "summary") == table(reference.folder, "summary")


def test_cli_executor_errors_are_one_line_and_nothing_runs(tmp_path, capsys, monkeypatch):
    args = [str(BOXWING), "--out", str(tmp_path), "--seeds", "1", "--no-progress"]
    assert main([*args, "--scheduler", "tcp://127.0.0.1:8786"]) == 2
    assert capsys.readouterr().err == "error: --scheduler: a scheduler address needs --executor dask\n"
    monkeypatch.setitem(sys.modules, "distributed", None)  # as if the cluster extra were not installed
    assert main([*args, "--executor", "dask", "--workers", "2"]) == 2
    assert capsys.readouterr().err == ("error: --executor dask needs dask.distributed, which is not installed: "
                                       f"install the cluster extra with {CLUSTER_EXTRA}\n")
    assert not (tmp_path / "boxwing").exists()
    with pytest.raises(SystemExit):
        main([*args, "--executor", "ray"])
    assert "invalid choice: 'ray'" in capsys.readouterr().err
