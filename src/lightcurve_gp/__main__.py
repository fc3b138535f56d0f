"""``lightcurve-gp COMMAND …`` (and ``python -m lightcurve_gp COMMAND …``): one entry point for every command.

``COMMAND`` is one of :data:`COMMANDS`; the rest of the line goes to that command unchanged, so
``lightcurve-gp train configs/boxwing.yaml`` is ``python -m lightcurve_gp.train configs/boxwing.yaml``. The command's
module (and torch with it: seconds) is imported only once the command is known, inside the interrupt handler, so a
Ctrl-C while it loads is the one line and exit code 130 of every interrupt, not a traceback.
"""

from __future__ import annotations

import importlib
import signal
import sys
import threading
from pathlib import Path

from lightcurve_gp import __version__

__all__ = ["COMMANDS", "ENTRY", "main", "run", "usage", "import_deferring_interrupts"]

#: the console script's name (pyproject.toml's ``[project.scripts]``)
ENTRY = "lightcurve-gp"

#: command name -> (the module whose ``main(argv) -> exit code`` runs it, one line of help)
COMMANDS: dict[str, tuple[str, str]] = {
    "train": ("lightcurve_gp.commands.train", "generate the training set, fit the GP observation model, evaluate it"),
    "estimate": ("lightcurve_gp.commands.estimate", "run the estimators on simulated seeds or on a light-curve file"),
    "simulate": ("lightcurve_gp.commands.simulate", "write a synthetic light curve in the light-curve file format"),
    "invert": ("lightcurve_gp.commands.invert", "attitude and spin from a light curve alone, every ambiguity family"),
    "sweep": ("lightcurve_gp.sweep.cli", "run the estimators over a grid of config values, resumable"),
}


def usage(prog: str = ENTRY) -> str:
    """The one-screen help: the commands and how to get each one's options, as called by ``prog``."""
    width = max(map(len, COMMANDS))
    lines = [f"usage: {prog} COMMAND [options]", f"       {prog} --version", "", "commands:"]
    lines += [f"  {name:<{width}}  {text}" for name, (_, text) in COMMANDS.items()]
    lines += ["", f"{prog} COMMAND --help lists the options of COMMAND."]
    return "\n".join(lines)


def main(argv: list[str] | None = None, *, prog: str = ENTRY, command_prog: str | None = None) -> int:
    """Dispatch ``argv`` (default ``sys.argv[1:]``) to the named command; exit code 2 for an unknown one.

    ``prog`` is how the entry point was called (``lightcurve-gp`` or ``python -m lightcurve_gp``), shown in the usage
    and version lines; the command's own usage shows ``command_prog`` (default ``"<prog> <command>"``; the
    ``python -m lightcurve_gp.<command>`` shims pass theirs)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage(prog))
        return 0 if argv else 2
    if argv[0] in ("-V", "--version"):
        print(f"{prog} {__version__}")
        return 0
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"error: {name!r} is not a command; choose from {', '.join(COMMANDS)}", file=sys.stderr)
        return 2
    return import_deferring_interrupts(COMMANDS[name][0]).main(rest, prog=command_prog or f"{prog} {name}")


def import_deferring_interrupts(name: str):
    """Import module ``name`` with Ctrl-C deferred to the end of the import; then raise :class:`KeyboardInterrupt`
    if one came.

    A SIGINT that lands inside torch's C++ initialisation, raised there as a Python exception, aborts the process
    (``terminate called after throwing an instance of 'pybind11::error_already_set'``, no exit code 130); noted by a
    handler and answered after the import, it is the one line of every interrupt. Off the main thread (where no
    handler can be set), or where SIGINT is ignored (a script's background job: Ctrl-C is not meant for it), the
    import is plain.
    """
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is signal.SIG_IGN):
        return importlib.import_module(name)
    hits: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: hits.append(signum))
    try:
        module = importlib.import_module(name)
    finally:
        signal.signal(signal.SIGINT, previous)
    if hits:
        raise KeyboardInterrupt
    return module


def run(argv: list[str] | None = None, *, prog: str | None = None, command_prog: str | None = None) -> None:
    """The ``lightcurve-gp`` console script (and ``python -m lightcurve_gp``, and the ``python -m
    lightcurve_gp.<command>`` shims): :func:`main` of ``argv`` (default ``sys.argv[1:]``), then the process ends the
    way every command ends. ``prog`` defaults to the name the process was started as (the console script's)."""
    try:
        code = main(argv, prog=prog or Path(sys.argv[0]).name or ENTRY, command_prog=command_prog)
    except KeyboardInterrupt:  # only while a command's module loads: a running command handles its own
        print("interrupted; nothing written", file=sys.stderr)
        sys.exit(130)
    common = sys.modules.get("lightcurve_gp.commands.common")  # loaded by every command; not by --help, --version
    if common is None:
        sys.exit(code)
    common.exit_process(code)


if __name__ == "__main__":
    run(prog="python -m lightcurve_gp")
