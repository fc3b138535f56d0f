"""``lightcurve-gp COMMAND …`` (and ``python -m lightcurve_gp COMMAND …``): one entry point for every command.

``COMMAND`` is one of :data:`COMMANDS`; the rest of the line goes to that command unchanged, so
``lightcurve-gp train configs/boxwing.yaml`` is ``python -m lightcurve_gp.train configs/boxwing.yaml``.
"""

from __future__ import annotations

import sys
from typing import Callable

from lightcurve_gp.commands import estimate, simulate, train
from lightcurve_gp.commands.common import exit_process
from lightcurve_gp.sweep import cli as sweep

__all__ = ["COMMANDS", "main", "run"]

#: command name -> (its ``main(argv) -> exit code``, one line of help)
COMMANDS: dict[str, tuple[Callable[[list[str] | None], int], str]] = {
    "train": (train.main, "generate the training set, fit the GP observation model, evaluate it"),
    "estimate": (estimate.main, "run the estimators on simulated seeds or on a light-curve file"),
    "simulate": (simulate.main, "write a synthetic light curve in the light-curve file format"),
    "sweep": (sweep.main, "run the estimators over a grid of config values, resumable"),
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
    return COMMANDS[name][0](rest)


def run() -> None:
    """The ``lightcurve-gp`` console script: :func:`main`, then the process ends the way every command ends."""
    exit_process(main())


if __name__ == "__main__":
    run()
