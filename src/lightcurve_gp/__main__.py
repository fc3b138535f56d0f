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

__all__ = ["COMMANDS", "main", "run", "usage", "import_deferring_interrupts"]

#: command name -> (the module whose ``main(argv) -> exit code`` runs it, one line of help)
COMMANDS: dict[str, tuple[str, str]] = {
    "train": ("lightcurve_gp.commands.train", "generate the training set, fit the GP observation model, evaluate it"),
    "estimate": ("lightcurve_gp.commands.estimate", "run the estimators on simulated seeds or on a light-curve file"),
    "simulate": ("lightcurve_gp.commands.simulate", "write a synthetic light curve in the light-curve file format"),
    "invert": ("lightcurve_gp.commands.invert", "attitude and spin from a light curve alone, every ambiguity family"),
    "sweep": ("lightcurve_gp.sweep.cli", "run the estimators over a grid of config values, resumable"),
}


def usage() -> str:
    """The one-screen help: the commands and how to get each one's options."""
    width = max(map(len, COMMANDS))
    lines = ["usage: lightcurve-gp COMMAND [options]", "", "commands:"]
    lines += [f"  {name:<{width}}  {text}" for name, (_, text) in COMMANDS.items()]
    lines += ["", "lightcurve-gp COMMAND --help lists the options of COMMAND."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Dispatch ``argv`` (default ``sys.argv[1:]``) to the named command; exit code 2 for an unknown one."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(f"error: {name!r} is not a command; choose from {', '.join(COMMANDS)}", file=sys.stderr)
        return 2
    return import_deferring_interrupts(COMMANDS[name][0]).main(rest)


def import_deferring_interrupts(name: str):
    """Import module ``name`` with Ctrl-C deferred to the end of the import; then raise :class:`KeyboardInterrupt`
    if one came.

    A SIGINT that lands inside torch's C++ initialisation, raised there as a Python exception, aborts the process
    (``terminate called after throwing an instance of 'pybind11::error_already_set'``, no exit code 130); noted by a
    handler and answered after the import, it is the one line of every interrupt. Off the main thread (where no
    handler can be set) the import is plain.
    """
    if threading.current_thread() is not threading.main_thread():
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


def run(argv: list[str] | None = None) -> None:
    """The ``lightcurve-gp`` console script (and the ``python -m lightcurve_gp.<command>`` shims): :func:`main` of
    ``argv`` (default ``sys.argv[1:]``), then the process ends the way every command ends."""
    try:
        code = main(argv)
    except KeyboardInterrupt:  # only while a command's module loads: a running command handles its own
        print("interrupted; nothing written", file=sys.stderr)
        sys.exit(130)
    importlib.import_module("lightcurve_gp.commands.common").exit_process(code)  # loaded already by the command


if __name__ == "__main__":
    run()
