"""Where runs go: estimate and sweep write beside the training run, never inside it, so ``train --force`` works after
the README's steps; train and sweep share one model store, so a sweep finds the model train made."""

import json
from pathlib import Path

import pytest

from lightcurve_gp.commands import estimate, invert, train
from lightcurve_gp.commands.layout import invert_folder, light_curve_folder
from lightcurve_gp.config.load import load_config
from lightcurve_gp.sweep import cli as sweep_cli
from lightcurve_gp.training import store
from lightcurve_gp.training.keys import model_key

ROOT = Path(__file__).resolve().parents[1]
BOXWING = str(ROOT / "configs" / "boxwing.yaml")
TINY = ["data.icosphere_subdivisions=0", "data.phi_step_deg=120", "data.heldout_size=40", "scenario.duration_s=60",
        "evaluation.rmse_window_s=[30, 60]", "model.exact.fast_variance_neighbors=32", "name=tiny"]
SETS = [arg for o in TINY for arg in ("--set", o)]


@pytest.mark.slow  # ~7 s on two loaded cores
def test_train_estimate_sweep_then_train_force_and_the_sweep_trains_nothing(tmp_path, monkeypatch, capsys):
    out = tmp_path / "runs"
    assert train.main([BOXWING, "--out", str(out), "--no-progress", *SETS]) == 0
    run, entry = out / "tiny", out / "models" / model_key(load_config(BOXWING, TINY))
    assert (run / "model.pt").stat().st_ino == (entry / "model.pt").stat().st_ino  # one model, two names
    assert json.loads((run / "metrics.json").read_text())["device"] == "cpu"

    assert estimate.main([BOXWING, "--model", str(run / "model.pt"), "--seeds", "1", "--estimators", "gpukf",
                          "--out", str(out), "--no-progress", *SETS]) == 0
    assert (out / "estimates" / "tiny" / "rho0.5" / "results.json").is_file()

    def trained_again(*args, **kwargs):
        raise AssertionError("the sweep trained a model train had made")

    monkeypatch.setattr(store, "train", trained_again)
    assert sweep_cli.main([BOXWING, "--out", str(out), "--seeds", "1", "--estimators", "gpukf", "--no-progress",
                           *SETS]) == 0
    (case,) = (out / "sweeps" / "tiny" / "cases").glob("*.json")
    assert json.loads(case.read_text())["model_path"] == str(entry / "model.pt")
    assert sorted(p.name for p in run.iterdir()) == sorted(train.TRAIN_FILES)  # nothing else in the training run
    monkeypatch.undo()

    capsys.readouterr()
    assert train.main([BOXWING, "--out", str(out), "--no-progress", "--force", *SETS]) == 0
    assert "model store" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["cache", "estimates", "models", "sweeps", "tiny"]
    assert [p.name for p in (out / "models").iterdir()] == [entry.name]
    assert (run / "model.pt").stat().st_ino == (entry / "model.pt").stat().st_ino  # the store has the new model


def test_a_run_named_like_a_shared_folder_is_refused(tmp_path, capsys):
    sets = [arg for o in TINY if not o.startswith("name=") for arg in ("--set", o)]
    assert train.main([BOXWING, "--out", str(tmp_path), *sets, "--set", "name=models"]) == 2
    assert capsys.readouterr().err == ("error: name: 'models' is the name of a shared folder of --out (models, "
                                       "cache, estimates, sweeps); choose another (--set name=...)\n")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", ["train", "estimate", "invert"])
def test_the_help_says_where_estimates_and_sweeps_go(command, capsys):
    with pytest.raises(SystemExit):
        {"train": train, "estimate": estimate, "invert": invert}[command].main(["--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "OUT/estimates/<name>/" in text and ("OUT/sweeps/<name>/" in text or command != "train")


def test_invert_writes_beside_the_estimates_of_the_same_file():
    assert invert_folder(Path("OUT"), "boxwing", Path("data/obs.ecsv")) == Path("OUT/estimates/boxwing/invert_obs")
    assert invert_folder(Path("OUT"), "boxwing", Path("obs.ecsv")).parent == \
        light_curve_folder(Path("OUT"), "boxwing", Path("obs.ecsv")).parent
