"""The edges a new observer hits, round two (issue 39): the tests from a shell that ignores SIGINT, the command
line's version and usage, units on every table written, warnings for inputs that carry little information, progress
without a terminal, and the estimate table's bands; one regression test per row, asserting the exact message."""

from __future__ import annotations

import importlib
import importlib.metadata
import os
import signal
import subprocess
import sys
import types
from pathlib import Path

import pytest

from lightcurve_gp.__main__ import import_deferring_interrupts, main, run

ROOT = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")]))
VERSION = importlib.metadata.version("lightcurve-gp")


def ignore_sigint() -> None:
    """``preexec_fn`` of a child started the way a script starts a background job: SIGINT ignored."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


# 6. the Ctrl-C tests pass from a shell that ignores SIGINT (they restore Python's handler themselves)
@pytest.mark.slow  # ~10 s on two loaded cores: a second pytest imports torch
def test_the_interrupt_tests_pass_when_the_shell_ignores_sigint():
    tests = ["tests/test_safe_runs.py::test_interrupt_reaches_the_command_during_a_blocking_call",
             "tests/test_safe_runs.py::test_interrupt_taken_inside_a_finaliser_still_reaches_the_command",
             "tests/test_entry_points.py::test_an_interrupt_during_a_command_s_import_is_answered_once_the_import_is_done"]
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *tests],
                          capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=300, preexec_fn=ignore_sigint)
    assert done.returncode == 0, done.stdout[-2000:]
    assert "3 passed" in done.stdout


def test_an_ignored_sigint_stays_ignored_while_a_command_loads(monkeypatch):
    """A background job's command is not interrupted by a Ctrl-C meant for the terminal's foreground job."""
    def signalled_import(name):
        os.kill(os.getpid(), signal.SIGINT)
        return types.SimpleNamespace(name=name)

    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        monkeypatch.setattr(importlib, "import_module", signalled_import)
        assert import_deferring_interrupts("lightcurve_gp.commands.train").name == "lightcurve_gp.commands.train"
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, previous)


# 11. a version, and each command's usage in the form it was called
@pytest.mark.parametrize("flag", ["--version", "-V"])
def test_the_entry_point_has_a_version(capsys, flag):
    assert main([flag]) == 0
    assert capsys.readouterr().out == f"lightcurve-gp {VERSION}\n"
    assert main([flag], prog="python -m lightcurve_gp") == 0
    assert capsys.readouterr().out == f"python -m lightcurve_gp {VERSION}\n"


def test_every_command_has_a_version_in_its_own_name(capsys):
    for name in ("train", "estimate", "simulate", "invert", "sweep"):
        with pytest.raises(SystemExit) as stop:
            main([name, "--version"])
        assert stop.value.code == 0
        assert capsys.readouterr().out == f"lightcurve-gp {name} {VERSION}\n"


def test_the_console_script_shows_the_name_it_was_started_as(capsys, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["/somewhere/bin/lightcurve-gp", "train", "--help"])
    with pytest.raises(SystemExit) as stop:
        run()
    assert stop.value.code == 0
    assert capsys.readouterr().out.startswith("usage: lightcurve-gp train [-h] [--set KEY.PATH=VALUE]")


def test_usage_names_the_form_it_was_called_in(capsys):
    assert main([], prog="python -m lightcurve_gp") == 2
    out = capsys.readouterr().out.splitlines()
    assert out[:2] == ["usage: python -m lightcurve_gp COMMAND [options]", "       python -m lightcurve_gp --version"]
    assert out[-1] == "python -m lightcurve_gp COMMAND --help lists the options of COMMAND."
    with pytest.raises(SystemExit):
        main(["estimate", "--help"], prog="python -m lightcurve_gp")
    assert capsys.readouterr().out.startswith("usage: python -m lightcurve_gp estimate [-h]")


@pytest.mark.parametrize("args, first", [
    (["-m", "lightcurve_gp", "--version"], f"python -m lightcurve_gp {VERSION}"),  # imports no torch: fast
])
def test_python_dash_m_says_so_in_its_version(args, first):
    done = subprocess.run([sys.executable, *args], capture_output=True, text=True, env=ENV, timeout=60)
    assert (done.returncode, done.stdout, done.stderr) == (0, first + "\n", "")


@pytest.mark.slow  # ~8 s on two loaded cores: the shim imports torch
def test_the_per_command_module_shows_its_own_form():
    done = subprocess.run([sys.executable, "-m", "lightcurve_gp.train", "--help"], capture_output=True, text=True,
                          env=ENV, timeout=120)
    assert done.returncode == 0
    assert done.stdout.startswith("usage: python -m lightcurve_gp.train [-h] [--set KEY.PATH=VALUE]")
