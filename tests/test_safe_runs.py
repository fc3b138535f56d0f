"""Safe outputs and checked inputs of the train and estimate commands: one regression test per reproduction of the
safe-outputs issue (numbered as there), each asserting the exact message, the exit code and what was written."""

import hashlib
import json
import os
import signal
import sys
import threading
import time
from pathlib import Path

import pytest
import torch
import yaml

from lightcurve_gp.commands import common as cli
from lightcurve_gp.commands import estimate, train
from lightcurve_gp.config.load import load_config
from lightcurve_gp.evaluation import plots
from lightcurve_gp.training.store import get_or_train, model_key, open_model, store_folder, training_mismatch

ROOT = Path(__file__).resolve().parents[1]
BOXWING = str(ROOT / "configs" / "boxwing.yaml")
TINY = ["data.icosphere_subdivisions=0", "data.phi_step_deg=120", "data.heldout_size=40", "scenario.duration_s=60",
        "evaluation.rmse_window_s=[30, 60]", "model.exact.fast_variance_neighbors=32", "name=tiny"]


def sets(overrides):
    return [arg for o in overrides for arg in ("--set", o)]


def tree(folder: Path) -> dict[str, str]:
    """Every file under ``folder`` with the SHA-256 of its bytes."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def model_file(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("runs")
    assert train.main([BOXWING, "--out", str(out), "--no-progress", *sets(TINY)]) == 0
    return out / "tiny" / "model.pt"


def estimate_args(out: Path, *extra: str) -> list[str]:
    return [BOXWING, "--seeds", "2", "--out", str(out), "--no-progress", *sets(TINY), *extra]


# 1. gpukf without a model, or no estimator at all: one line, exit 2, nothing written
@pytest.mark.parametrize("args, message", [
    (["--estimators", "gpukf"], "error: --model: the gpukf estimator needs a trained model file "
                                "(python -m lightcurve_gp.train)\n"),
    (["--estimators", ","], "error: --estimators: ',' names no estimator; choose from gpukf, ukf, matched_ukf, "
                            "joint_ukf, surface_ukf, surface_ukf_select, map_surface, map_offset, map, matched_map, "
                            "no_update\n"),
])
def test_estimator_list_is_checked_before_anything_is_written(tmp_path, capsys, args, message):
    assert estimate.main(estimate_args(tmp_path, *args)) == 2
    assert capsys.readouterr().err == message
    assert list(tmp_path.iterdir()) == []


# 2. runs never clobber; results.json records the model file, its hash, the config and the command
@pytest.mark.slow  # ~6 s on two loaded cores
def test_estimate_refuses_an_existing_folder_and_records_its_inputs(model_file, tmp_path, capsys):
    args = estimate_args(tmp_path, "--model", str(model_file), "--estimators", "gpukf,no_update")
    assert estimate.main(args) == 0
    folder = tmp_path / "estimates" / "tiny" / "rho0.5"
    before = tree(folder)
    run = json.loads((folder / "results.json").read_text())["run"]
    assert run["model_file"] == str(model_file.resolve())
    assert run["model_sha256"] == hashlib.sha256(model_file.read_bytes()).hexdigest()
    assert run["config"]["data"]["icosphere_subdivisions"] == 0 and run["seeds"] == [0, 1]
    assert run["model_mismatch"] is None and run["torch_threads"] == cli.DEFAULT_THREADS
    capsys.readouterr()
    assert estimate.main(args[:2] + ["1"] + args[3:]) == 2  # one seed now: would silently replace two
    assert capsys.readouterr().err == (f"error: {folder}: already exists (an earlier run); pass --force to replace "
                                       f"it, or choose another --out or name\n")
    assert tree(folder) == before
    assert estimate.main(args[:2] + ["1"] + args[3:] + ["--force"]) == 0
    assert json.loads((folder / "results.json").read_text())["seeds"] == 1
    assert sorted(p.name for p in folder.parent.iterdir()) == ["rho0.5"]  # no temporary left


# 3. a model trained with other settings is refused with the first differing key, unless overridden (recorded)
@pytest.mark.slow  # ~5 s on two loaded cores
def test_a_model_of_another_t_span_past_is_refused_unless_allowed(model_file, tmp_path, capsys):
    args = estimate_args(tmp_path, "--model", str(model_file), "--estimators", "gpukf", "--set",
                         "data.t_span_past=10")
    assert estimate.main(args) == 2
    assert capsys.readouterr().err == (f"error: --model {model_file}: data.t_span_past: the model was trained with "
                                       f"20.0, the config says 10.0; train a model with this config or pass "
                                       f"--allow-model-mismatch\n")
    assert list(tmp_path.iterdir()) == []
    assert estimate.main(args + ["--allow-model-mismatch"]) == 0
    run = json.loads((tmp_path / "estimates" / "tiny" / "rho0.5" / "results.json").read_text())["run"]
    assert run["allow_model_mismatch"] is True
    assert run["model_mismatch"] == "data.t_span_past: the model was trained with 20.0, the config says 10.0"


def test_model_kind_and_hyperparameters_are_compared(model_file):
    model = open_model(model_file)
    assert training_mismatch(model, load_config(BOXWING, TINY)) is None
    sparse = [s for s in TINY if not s.startswith("model.exact.")] + ["model.kind=sparse"]  # exact-only setting
    assert training_mismatch(model, load_config(BOXWING, sparse)) == \
        "model.kind: the model was trained with 'exact', the config says 'sparse'"
    assert training_mismatch(model, load_config(BOXWING, TINY + ["model.theta2=0.5"])) == \
        "model.theta2: the model was trained with 0.25, the config says 0.5"
    # the held-out size only changes the evaluation written beside the model
    assert training_mismatch(model, load_config(BOXWING, TINY + ["data.heldout_size=7"])) is None


# 4. meshes: checked before any work, one line each (the config-level checks are in test_config.py)
def test_a_missing_mesh_is_one_line_and_nothing_is_written(tmp_path, capsys):
    mesh = tmp_path / "missing.obj"
    assert train.main([BOXWING, "--out", str(tmp_path / "out"), *sets(TINY + ["shape.kind=mesh",
                                                                              f"shape.mesh_path={mesh}"])]) == 2
    assert capsys.readouterr().err == f"error: shape.mesh_path: {str(mesh)!r} does not exist or is not a file\n"
    assert not (tmp_path / "out").exists()


# 5. the training-data cache follows the mesh's content (key test in test_config.py); the model store too
def test_the_model_store_trains_once_and_reuses_by_content(tmp_path):
    cfg = load_config(BOXWING, TINY)
    model, path = get_or_train(cfg, tmp_path)
    assert path == store_folder(cfg, tmp_path) / "model.pt" and model.extra["model_key"] == model_key(cfg)
    stamp = path.stat().st_mtime_ns
    again, _ = get_or_train(load_config(BOXWING, TINY + ["name=renamed"]), tmp_path)  # the name is no part of it
    assert path.stat().st_mtime_ns == stamp and again.num_train == model.num_train
    path.write_text("damaged")
    repaired, _ = get_or_train(cfg, tmp_path)
    assert repaired.num_train == model.num_train and open_model(path).extra["model_key"] == model_key(cfg)


# 6. rho_true = 0 is refused (the config's own check is in test_config.py)
def test_rho_true_zero_is_refused(tmp_path, capsys):
    assert estimate.main(estimate_args(tmp_path, "--rho-true", "0")) == 2
    assert capsys.readouterr().err == "error: --rho-true: 0 is outside (0, 1]\n"


# 7. Ctrl-C during a long computation: acted on within a second, one line, exit 130
def blocking() -> int:
    time.sleep(30)  # stands in for a long LAPACK call: it never returns to the interpreter
    return 0


def test_interrupt_reaches_the_command_during_a_blocking_call(capsys, sigint_default):
    # Ctrl-C in a terminal is a real SIGINT to the process, which also wakes the main thread's wait;
    # _thread.interrupt_main only sets the flag that the main thread checks between bytecodes.
    threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT)).start()
    start = time.perf_counter()
    code = cli.run_command(lambda: cli.run_interruptible(blocking), debug=False)
    assert code == 130 and time.perf_counter() - start < 2.0
    assert capsys.readouterr().err == "interrupted; nothing written\n"


def test_interrupt_taken_inside_a_finaliser_still_reaches_the_command(capsys, sigint_default):
    """The garbage collector may run a finaliser (or a gc callback) on the main thread just when Ctrl-C comes; an
    exception raised there is only printed, so a KeyboardInterrupt raised by the default handler would be lost."""
    class Finalised:
        def __del__(self):
            signal.raise_signal(signal.SIGINT)  # handled at once, inside this finaliser

    def collect(signum, frame):  # runs on the main thread, during the command's wait
        Finalised()

    previous = signal.signal(signal.SIGUSR1, collect)
    try:
        threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGUSR1)).start()
        start = time.perf_counter()
        code = cli.run_command(lambda: cli.run_interruptible(blocking), debug=False)
    finally:
        signal.signal(signal.SIGUSR1, previous)
    assert code == 130 and time.perf_counter() - start < 2.0
    assert capsys.readouterr().err == "interrupted; nothing written\n"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


# 8. files that are not model files
@pytest.mark.parametrize("content, reason", [
    (b"just some text\n", "not a PyTorch archive; train one with python -m lightcurve_gp.train"),
    (yaml.safe_dump({"name": "boxwing"}).encode(),
     "not a PyTorch archive; train one with python -m lightcurve_gp.train"),
    ("pickle", "it holds objects other than tensors and plain values"),
])
def test_foreign_files_as_model_are_one_clear_line(tmp_path, capsys, content, reason):
    path = tmp_path / "model.pt"
    if content == "pickle":
        torch.save({"format": "lightcurve-gp-model", "object": threading.Lock}, path)
    else:
        path.write_bytes(content)
    assert estimate.main(estimate_args(tmp_path / "out", "--model", str(path))) == 2
    err = capsys.readouterr().err
    assert err == f"error: {path}: not a lightcurve-gp model file ({reason})\n"
    assert "weights_only" not in err and not (tmp_path / "out").exists()


# 9. one thread policy: --threads sets torch's thread count for the whole command and is recorded
@pytest.mark.slow  # ~3 s on two loaded cores
def test_threads_option_is_applied_and_recorded(model_file, tmp_path):
    try:
        assert estimate.main(estimate_args(tmp_path, "--estimators", "no_update", "--threads", "2")) == 0
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(1)
    run = json.loads((tmp_path / "estimates" / "tiny" / "rho0.5" / "results.json").read_text())["run"]
    assert run["torch_threads"] == 2


def test_threads_below_one_are_refused(tmp_path, capsys):
    assert estimate.main(estimate_args(tmp_path, "--threads", "0")) == 2
    assert capsys.readouterr().err == "error: --threads: 0 must be >= 1\n"


# 10. names that would escape --out
@pytest.mark.parametrize("name", ['""', "../escaped", "a/b"])
def test_unsafe_names_write_nothing(tmp_path, capsys, name):
    out = tmp_path / "out"
    out.mkdir()
    unnamed = [o for o in TINY if not o.startswith("name=")]  # a --set key given twice is refused on its own
    assert train.main([BOXWING, "--out", str(out), *sets(unnamed), "--set", f"name={name}"]) == 2
    shown = yaml.safe_load(name)
    assert capsys.readouterr().err.startswith(f"error: name: {shown!r} is not a safe folder name")
    assert list(tmp_path.rglob("*")) == [out]


# 11. an unusable --out is found before any computation
def test_out_that_is_a_file_fails_up_front(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    start = time.perf_counter()
    assert train.main([BOXWING, "--out", str(blocker / "runs"), *sets(TINY)]) == 2
    assert capsys.readouterr().err == f"error: --out: {str(blocker)!r} is not a folder\n"
    assert time.perf_counter() - start < 5 and sorted(p.name for p in tmp_path.iterdir()) == ["file"]


# 12. train's folder appears whole: an interrupt while writing keeps the old run intact
def test_an_interrupted_forced_train_keeps_the_old_run(model_file, tmp_path, capsys, monkeypatch):
    old = model_file.parent
    out = tmp_path / "runs"
    out.mkdir()
    (out / "tiny").mkdir()
    for name, digest in tree(old).items():
        (out / "tiny" / name).write_bytes((old / name).read_bytes())
    before = tree(out / "tiny")

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(train, "residual_histogram", interrupted)  # model.pt is written by then
    assert train.main([BOXWING, "--out", str(out), "--no-progress", "--force", "--cache", str(old.parent / "cache"),
                       *sets(TINY)]) == 130
    assert capsys.readouterr().err.endswith("interrupted; nothing written\n")
    assert tree(out / "tiny") == before and sorted(p.name for p in out.iterdir()) == ["tiny"]


def test_an_interrupt_says_what_was_kept(tmp_path, capsys, monkeypatch):
    from lightcurve_gp.training.sets import data_cache_key

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(train, "residual_histogram", interrupted)
    assert train.main([BOXWING, "--out", str(tmp_path / "runs"), "--no-progress", *sets(TINY)]) == 130
    cache = tmp_path / "runs" / "cache" / f"data-{data_cache_key(load_config(BOXWING, TINY))}.pt"
    assert capsys.readouterr().err == (f"interrupted; kept the new training-data cache {cache}; "
                                       f"{tmp_path / 'runs' / 'tiny'} not written\n")
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == ["cache"] and cache.is_file()


def test_force_refuses_a_folder_holding_other_runs(model_file, tmp_path, capsys):
    out = tmp_path / "runs"
    (out / "tiny" / "estimate_rho0.7").mkdir(parents=True)
    assert train.main([BOXWING, "--out", str(out), "--force", *sets(TINY)]) == 2
    assert capsys.readouterr().err == (f"error: {out / 'tiny'} holds estimate_rho0.7, not written by train; --force "
                                       f"replaces only a train run folder: move them away or choose another --out "
                                       f"or name\n")


# 13. progress: a status line with the elapsed time for a long step, none when switched off
def test_long_steps_show_a_status_line(capsys):
    assert cli.run_interruptible(lambda: time.sleep(0.35) or 7, status="conditioning", progress=True) == 7
    assert "conditioning: 00:00" in capsys.readouterr().err
    assert cli.run_interruptible(lambda: 7, status="conditioning", progress=False) == 7
    assert capsys.readouterr().err == ""
    assert cli.progress_enabled(no_progress=False) is sys.stderr.isatty()
    assert cli.progress_enabled(no_progress=True) is False


@pytest.mark.slow  # ~17 s on two loaded cores
@pytest.mark.parametrize("command", ["train", "estimate"])
def test_the_module_entry_points_exit_with_the_error_code(tmp_path, command):
    """``python -m lightcurve_gp.<command>`` as a user runs it: one line on stderr, exit 2, no traceback."""
    import os
    import subprocess

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]))
    done = subprocess.run([sys.executable, "-m", f"lightcurve_gp.{command}", BOXWING, "--out", str(tmp_path),
                           "--set", "scenario.rho_true=0"], capture_output=True, text=True, env=env, timeout=120)
    assert (done.returncode, done.stderr) == (2, "error: scenario.rho_true: 0 is outside (0, 1]\n")
    assert list(tmp_path.iterdir()) == []


# 14. readable outputs
def test_estimate_table_explains_its_columns():
    summary = {"rho_true": 0.7, "seeds": 2, "window_s": [400, 600], "nees_band_95": [1.0, 5.0], "estimators": {}}
    table = estimate.format_table(summary)
    for column in ("<10deg: share of seeds", "LC rmse: median over seeds", "NEES: normalised estimation error",
                   "ms/step: wall time"):
        assert column in table


def test_figures_explain_reference_lines_and_never_touch_the_backend(tmp_path, monkeypatch):
    import importlib

    import matplotlib

    backend = matplotlib.get_backend()
    matplotlib.use("svg")  # a user's choice, which importing and plotting must keep
    importlib.reload(plots)
    figures = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: figures.append(fig) or Path(path))
    plots.prediction_scatter(torch.tensor([1.0, 2.0]), torch.tensor([1.1, 2.1]), tmp_path / "s.png")
    plots.euler_errors(torch.arange(3.0), {"ukf": torch.zeros(3, 3)}, tmp_path / "e.png", window=(1, 2))
    labels = [[t.get_text() for t in fig.legends[0].get_texts()] for fig in figures]
    assert "y = x: perfect prediction" in labels[0]
    assert "RMSE scoring window (1-2 s)" in labels[1]
    assert "brighter" in figures[0].axes[0].get_xlabel() and figures[0].axes[0].xaxis_inverted()
    try:
        assert matplotlib.get_backend() == "svg"
    finally:
        matplotlib.use(backend)
