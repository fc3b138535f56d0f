"""Devices and sizes a run is checked for up front: a device this torch cannot use, and a fit larger than the free
memory, are refused in one line naming the key, before anything is allocated or written."""

import time
from pathlib import Path

import pytest
import torch

from lightcurve_gp.commands import estimate, simulate, train
from lightcurve_gp.config import devices
from lightcurve_gp.config.load import ConfigError, load_config
from lightcurve_gp.sweep import cli as sweep_cli
from lightcurve_gp.training import fit
from lightcurve_gp.training.fit import check_fit_memory, fit_memory
from lightcurve_gp.training.sets import generate_training_set, training_set_size

ROOT = Path(__file__).resolve().parents[1]
BOXWING = str(ROOT / "configs" / "boxwing.yaml")
TINY = ["data.icosphere_subdivisions=0", "data.phi_step_deg=120", "data.heldout_size=40", "scenario.duration_s=60",
        "evaluation.rmse_window_s=[30, 60]", "model.exact.fast_variance_neighbors=32", "name=tiny"]
SETS = [arg for o in TINY for arg in ("--set", o)]


# ----------------------------------------------------------------------------------------------- devices

def test_check_device_names_the_key_and_why(monkeypatch):
    devices.check_device("cpu")
    monkeypatch.setattr(torch.version, "cuda", None)
    with pytest.raises(ConfigError) as info:
        devices.check_device("cuda")
    assert str(info.value) == (f"device: cuda is not available: this torch has no CUDA (torch {torch.__version__}); "
                               f"use device: cpu or install a CUDA build of torch")
    monkeypatch.setattr(torch.version, "cuda", "12.4")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(ConfigError, match=r"^device: cuda:0 is not available: torch \S+ finds no CUDA device; "):
        devices.check_device("cuda:0")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    devices.check_device("cuda:1")
    with pytest.raises(ConfigError) as info:
        devices.check_device("cuda:2")
    assert str(info.value) == "device: cuda:2 is not available: torch finds 2 CUDA device(s), cuda:0 to cuda:1"


def _no_cuda_message() -> str:
    if torch.version.cuda is None:
        return (f"error: device: cuda is not available: this torch has no CUDA (torch {torch.__version__}); use "
                f"device: cpu or install a CUDA build of torch\n")
    return f"error: device: cuda is not available: torch {torch.__version__} finds no CUDA device; use device: cpu\n"


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA: device: cuda is honoured")
@pytest.mark.parametrize("command", ["train", "estimate", "simulate", "sweep"])
def test_every_stage_refuses_cuda_without_it_in_one_line(command, tmp_path, capsys):
    main = {"train": train.main, "estimate": estimate.main, "simulate": simulate.main, "sweep": sweep_cli.main}[command]
    out = tmp_path / ("obs.ecsv" if command == "simulate" else "runs")
    start = time.perf_counter()
    assert main([BOXWING, "--out", str(out), "--no-progress", *SETS, "--set", "device=cuda"]) == 2
    assert capsys.readouterr().err == _no_cuda_message()
    assert time.perf_counter() - start < 10 and list(tmp_path.iterdir()) == []


def test_train_fits_on_the_config_device_and_records_it(tmp_path, monkeypatch):
    asked = []
    build = fit.build_model

    def recording(*args, **kwargs):
        asked.append(kwargs["device"])
        return build(*args, **kwargs)

    monkeypatch.setattr(fit, "build_model", recording)
    run = fit.train(load_config(BOXWING, TINY), tmp_path / "tiny", tmp_path / "cache")
    assert asked == ["cpu"] and run.metrics["device"] == "cpu"
    assert next(run.model.buffers()).device.type == "cpu"


# ----------------------------------------------------------------------------------------------- sizes

@pytest.mark.parametrize("overrides", [
    [],
    ["data.sampling=random", "data.num_random=50"],
    ["data.quaternion_sign=both"],
    ["model.inputs=body_geometry", "data.num_random=64"],
])
def test_the_size_from_the_config_is_the_size_generated(overrides):
    cfg = load_config(BOXWING, TINY + overrides)
    points, conditioned = training_set_size(cfg)
    ts = generate_training_set(cfg, progress=False)
    assert points == conditioned == len(ts) + ts.dropped * (2 if "data.quaternion_sign=both" in overrides else 1)


def test_the_surface_set_is_counted_per_surface_and_conditioned_per_attitude():
    cfg = load_config(ROOT / "configs" / "boxwing_surface.yaml",
                      ["data.sampling=random", "data.num_random=20", "data.surfaces.per_attitude=3"])
    points, conditioned = training_set_size(cfg)
    ts = generate_training_set(cfg, progress=False)
    assert (points, conditioned) == (60, 20) and len(ts) + ts.dropped == 60


def test_the_papers_exact_gp_needs_one_n_by_n_matrix():
    need, what = fit_memory(load_config(BOXWING))
    assert need == 8 * 19260**2 + 8 * 16 * 19260 and "Cholesky" in what  # 2.97 GB
    need, what = fit_memory(load_config(BOXWING, ["model.kind=sparse"]))
    assert need == 8 * (4 * 512 * 19260 + 4 * 512**2) + 8 * 16 * 19260 and "num_inducing 512" in what


def test_a_fit_larger_than_the_free_memory_is_refused_with_the_number_and_the_key():
    cfg = load_config(BOXWING, ["data.icosphere_subdivisions=4"])
    with pytest.raises(ConfigError) as info:
        check_fit_memory(cfg, available=24 * 10**9)
    assert str(info.value) == ("data.icosphere_subdivisions: 4 gives up to 76860 training points (N); the exact GP's "
                               "Cholesky factor (N^2 float64) needs 47.3 GB and cpu has 24.0 GB free: lower "
                               "data.icosphere_subdivisions (or data.rho_grid's length) or use model.kind: sparse")
    check_fit_memory(cfg, available=48 * 10**9)  # fits
    sparse = load_config(BOXWING, ["data.sampling=random", "data.num_random=10000000", "model.kind=sparse"])
    with pytest.raises(ConfigError, match=r"^data\.num_random: 10000000 gives up to 50000000 training points .* "
                                          r"or lower model.sparse.num_inducing$"):
        check_fit_memory(sparse, available=24 * 10**9)


def test_train_refuses_before_anything_is_allocated_or_written(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(fit, "available_memory", lambda device: 24 * 10**9)
    start = time.perf_counter()
    assert train.main([BOXWING, "--out", str(tmp_path), "--set", "data.icosphere_subdivisions=4"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: data.icosphere_subdivisions: 4 gives up to 76860 training points (N); ")
    assert "needs 47.3 GB" in err and err.count("\n") == 1
    assert time.perf_counter() - start < 10 and list(tmp_path.iterdir()) == []
