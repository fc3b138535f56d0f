"""experiments/nees_reference.py: one row per (σ, case, reported block), the per-seed file agreeing with it, the
case read back on a rerun, and a bad seed block refused in one line."""

import csv

import pytest

from experiments import nees_reference


@pytest.mark.slow
def test_rows_per_block_and_seed_file_agree(tmp_path, capsys):
    args = ["--sigmas", "0.1", "--random-seeds", "2000:2004", "--report", "2000:2002,2000:2004", "--paper-seeds", "",
            "--out", str(tmp_path / "out"), "--runs", str(tmp_path / "runs")]
    assert nees_reference.main(args) == 0
    seeds = list(csv.DictReader((tmp_path / "out" / "seeds.csv").open()))
    assert [int(r["seed"]) for r in seeds] == [2000, 2001, 2002, 2003]
    assert {r["kind"] for r in seeds} <= {"same", "other", "miss"}
    table = [line for line in (tmp_path / "out" / "summary.md").read_text().splitlines() if line.startswith("| 0.1 |")]
    assert [line.split(" | ")[2] for line in table] == ["2000–2001", "2000–2003"]
    for line, n in zip(table, (2, 4)):
        mean = float(line.split(" | ")[6].split(" / ")[0])
        assert mean == pytest.approx(sum(float(r["statistic"]) for r in seeds[:n]) / n, abs=0.006)
        counts = [int(v) for v in line.split(" | ")[8].split(" / ")]
        assert counts == [sum(r["kind"] == k for r in seeds[:n]) for k in ("same", "other", "miss")]
    stored = sorted((tmp_path / "runs" / "nees_reference" / "cases").iterdir())
    assert len(stored) == 1
    before = stored[0].stat().st_mtime_ns
    assert nees_reference.main(args) == 0
    assert stored[0].stat().st_mtime_ns == before  # read back, not rerun
    assert list(csv.DictReader((tmp_path / "out" / "seeds.csv").open())) == seeds


def test_a_bad_seed_block_is_one_line(tmp_path, capsys):
    assert nees_reference.main(["--random-seeds", "2000-2004", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err == "error: seed block '2000-2004': expected FIRST:END, e.g. 2000:2300\n"
    assert not any(tmp_path.iterdir())
