"""The one entry point ``lightcurve-gp COMMAND …`` (``python -m lightcurve_gp``) and the per-command modules."""

from __future__ import annotations

import importlib
import os
import signal
import subprocess
import sys
import types

import pytest

from lightcurve_gp.__main__ import COMMANDS, import_deferring_interrupts, main, usage


def test_usage_lists_every_command(capsys):
    assert main([]) == 2
    out = capsys.readouterr().out
    assert out.strip() == usage()
    for name in ("train", "estimate", "simulate", "sweep"):
        assert f"  {name} " in out


def test_help_exits_zero(capsys):
    assert main(["--help"]) == 0
    assert "lightcurve-gp COMMAND --help" in capsys.readouterr().out


def test_unknown_command_is_one_line(capsys):
    assert main(["trian"]) == 2
    assert capsys.readouterr().err == (f"error: 'trian' is not a command; choose from {', '.join(COMMANDS)}\n")


@pytest.mark.parametrize("name", ["train", "estimate", "simulate", "sweep"])
def test_command_help_is_the_command_s_own(name, capsys):
    with pytest.raises(SystemExit) as stop:
        main([name, "--help"])
    assert stop.value.code == 0
    assert capsys.readouterr().out.startswith(f"usage: lightcurve-gp {name} [-h]")


@pytest.mark.slow  # ~8 s on two loaded cores
def test_python_dash_m_package_dispatches():
    done = subprocess.run([sys.executable, "-m", "lightcurve_gp", "simulate", "--help"], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0
    assert done.stdout.startswith("usage: python -m lightcurve_gp simulate [-h]")


def test_an_interrupt_during_a_command_s_import_is_answered_once_the_import_is_done(monkeypatch, sigint_default):
    """A SIGINT inside the import (in torch's C++ initialisation it would abort the process) waits for its end."""
    finished = []

    def slow_import(name):
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(10_000):  # the handler runs between these bytecodes
            pass
        finished.append(name)
        return types.SimpleNamespace(name=name)

    before = signal.getsignal(signal.SIGINT)
    monkeypatch.setattr(importlib, "import_module", slow_import)
    with pytest.raises(KeyboardInterrupt):
        import_deferring_interrupts("lightcurve_gp.commands.train")
    assert finished == ["lightcurve_gp.commands.train"]
    assert signal.getsignal(signal.SIGINT) is before
    monkeypatch.setattr(importlib, "import_module", lambda name: types.SimpleNamespace(name=name))
    assert import_deferring_interrupts("x").name == "x"
