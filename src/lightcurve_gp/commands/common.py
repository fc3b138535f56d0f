"""What every command shares: common options, the thread policy, progress, errors, interrupts and provenance.

Error policy. A user error (a bad config value, a bad model file, an existing output folder, an unwritable
``--out``...) is one line on stderr, ``error: <key or file>: <what is wrong>``, and exit code 2; it is found by
the up-front checks before any computation. ``--debug`` shows the traceback instead. Ctrl-C prints one line
(``interrupted; nothing written`` or what was kept) and exits with 130.

Thread policy (``--threads``, default :data:`DEFAULT_THREADS` = 1). Every command sets torch's intra-op thread
count once, from this option. One thread is the default because the filter's per-step tensors are small, so a
second thread adds dispatch and synchronisation and, when the other core is busy (another job, a parallel
sweep worker), waits for it: ``benchmarks/bench_threads.py`` measures 100 filter steps of the README's library
snippet with 1 and 2 threads, idle and with one core busy (README, Performance). Pass ``--threads 2`` to speed up
the one-off exact conditioning of ``train`` on an otherwise idle machine.

Long steps run through :func:`run_interruptible`: the work runs in a daemon worker thread while the main thread
waits in short slices, so Ctrl-C acts within a fraction of a second even while LAPACK factorises a large matrix,
and a status line with the elapsed time is shown when progress is on. While it waits, SIGINT only notes the
interrupt and the wait itself raises :class:`KeyboardInterrupt`: Python's default handler raises it wherever the
main thread is at that moment, which may be a finaliser or a garbage-collector callback (where an exception is
only printed, so the Ctrl-C would be lost) or the middle of ``Thread.join`` (which then reports the still-running
worker as finished).
"""

from __future__ import annotations

import argparse
import math
import os
import shlex
import shutil
import signal
import sys
import tempfile
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterator

import torch
from tqdm.auto import tqdm

from lightcurve_gp import __version__
from lightcurve_gp.commands.progress import has_descriptor, progress_output
from lightcurve_gp.config.load import ConfigError, config_to_dict
from lightcurve_gp.observation.serialization import ModelFileError
from lightcurve_gp.observed.lightcurve_file import LightCurveFileError

__all__ = ["DEFAULT_THREADS", "UserError", "Interrupted", "add_common_arguments", "apply_threads",
           "progress_enabled", "check_output_root", "check_new_folder", "check_overrides", "check_unit_quaternion",
           "available_memory", "format_bytes", "warn", "STRICT_HELP", "run_interruptible", "run_command",
           "exit_process", "provenance"]

#: torch intra-op threads of every command unless ``--threads`` says otherwise (see the module docstring)
DEFAULT_THREADS = 1


class UserError(Exception):
    """A problem with the command's input: reported as one line, exit code 2."""


@dataclass
class Interrupted(Exception):
    """Ctrl-C, with what the command kept on disk (empty: nothing written)."""

    kept: str = ""


FORCE_HELP = "replace an existing output folder (the old one is removed only when the new one is complete)"


def add_common_arguments(parser: argparse.ArgumentParser, *, force: bool = True, force_help: str = FORCE_HELP) -> None:
    """Add ``--threads``, ``--no-progress``, ``--debug``, ``--version`` and (with ``force``) ``--force``, described
    by ``force_help``, to ``parser``."""
    parser.add_argument("--threads", type=int, default=DEFAULT_THREADS,
                        help=f"torch threads (default {DEFAULT_THREADS}: the filter's small per-step tensors run "
                             f"fastest on one thread, and one thread stays fast when other jobs share the cores)")
    parser.add_argument("--no-progress", action="store_true",
                        help="hide progress bars and status lines (also hidden when stderr is not a terminal)")
    parser.add_argument("--debug", action="store_true", help="show the traceback of an error instead of one line")
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}",
                        help="print the package's version and exit")
    if force:
        parser.add_argument("--force", action="store_true", help=force_help)


def apply_threads(threads: int) -> int:
    """Set torch's intra-op thread count (the one thread policy of every command); returns it."""
    if threads < 1:
        raise UserError(f"--threads: {threads} must be >= 1")
    torch.set_num_threads(threads)
    return threads


def progress_enabled(no_progress: bool) -> bool:
    """Progress output is on unless ``--no-progress`` is given or stderr is neither a terminal (bars) nor a file or
    pipe (plain lines, :class:`~lightcurve_gp.commands.progress.ProgressLines`): an in-memory stream gets none."""
    return not no_progress and (sys.stderr.isatty() or has_descriptor(sys.stderr))


def check_output_root(out: Path) -> None:
    """``out`` is a writable folder or can be created as one: a temporary folder is made (and removed) in its
    deepest existing ancestor, so nothing is left behind; raises :class:`UserError` naming ``--out``."""
    out = Path(out)
    probe = out
    while not probe.exists() and probe.parent != probe:
        probe = probe.parent
    if not probe.is_dir():
        raise UserError(f"--out: {str(probe)!r} is not a folder")
    try:
        shutil.rmtree(tempfile.mkdtemp(prefix=".lightcurve-gp-probe-", dir=probe))
    except OSError as exc:
        reason = exc.strerror or str(exc)
        if probe == out:
            raise UserError(f"--out: cannot write in {out} ({reason})") from None
        raise UserError(f"--out: cannot create {out} (cannot write in {probe}: {reason})") from None


def check_new_folder(folder: Path, force: bool) -> None:
    """Refuse to write over an existing run folder unless ``force``."""
    if folder.exists() and not force:
        raise UserError(f"{folder}: already exists (an earlier run); pass --force to replace it, or choose another "
                        f"--out or name")
    if folder.exists() and not folder.is_dir():
        raise UserError(f"{folder} exists and is not a folder")


def check_overrides(overrides: list[str]) -> None:
    """Refuse a ``--set`` key given twice (the last would win without a word): :class:`UserError` naming both."""
    seen: dict[str, str] = {}
    for text in overrides:
        key = text.partition("=")[0].strip()
        if key in seen:
            raise UserError(f"--set: {key} given twice ({seen[key]!r}, then {text!r}); give it once")
        seen[key] = text


#: how far a given quaternion's norm may be off 1 (rounding in a copied value), beyond which it is refused
UNIT_TOLERANCE = 1e-3


def check_unit_quaternion(values: list[float], *, option: str) -> None:
    """Refuse a quaternion whose norm is off 1 by more than :data:`UNIT_TOLERANCE` (a typo, or not a rotation
    at all), naming ``option`` and the norm; a :class:`UserError`."""
    norm = math.sqrt(sum(v * v for v in values))
    if abs(norm - 1.0) > UNIT_TOLERANCE:
        text = ",".join(f"{v:g}" for v in values)
        raise UserError(f"{option}: {text} has norm {norm:.6g}, not 1 (a unit quaternion q1,q2,q3,q4, scalar last, "
                        f"within {UNIT_TOLERANCE:g}); divide by its norm if that is the attitude meant")


def available_memory(device: str) -> float:
    """Bytes the run can still allocate on ``device``: free device memory on a CUDA device, else the system's
    ``MemAvailable`` (Linux), else its physical memory."""
    if str(device).startswith("cuda") and torch.cuda.is_available():
        return float(torch.cuda.mem_get_info(torch.device(device))[0])
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024.0
    except OSError:
        pass
    return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


#: the help of ``--strict`` on the commands that read a light-curve file
STRICT_HELP = ("refuse a file whose TLE and site put samples where they cannot have been observed (the object below "
               "the horizon, the site in daylight, the object in the Earth's shadow) instead of warning")


def format_bytes(n: float) -> str:
    """``n`` bytes in decimal units: ``512 B``, ``2.0 kB``, ``3.5 GB``..."""
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if n < 1000.0:
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000.0
    return f"{n:.1f} PB"


@contextmanager
def _sigint_noted() -> Iterator[list[int]]:
    """While open, a SIGINT is appended to the yielded list instead of raising :class:`KeyboardInterrupt` wherever
    the main thread happens to be (see the module docstring). Only on the main thread and only over Python's
    default handler; anywhere else the list stays empty and interrupts behave as before."""
    hits: list[int] = []
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler):
        yield hits
        return
    signal.signal(signal.SIGINT, lambda signum, frame: hits.append(signum))
    try:
        yield hits
    finally:
        signal.signal(signal.SIGINT, signal.default_int_handler)


def run_interruptible(fn: Callable[[], Any], *, status: str = "", progress: bool = False) -> Any:
    """Run ``fn()`` in a daemon worker thread and return its result (or raise its exception).

    The caller waits in 0.1 s slices and raises ``KeyboardInterrupt`` itself within a slice of a Ctrl-C (SIGINT),
    even while the worker is inside a long LAPACK call; the abandoned worker dies with the process. With
    ``progress``, a status line ``<status>: <elapsed>`` is shown until ``fn`` returns.
    """
    box: dict[str, Any] = {}

    def work() -> None:
        try:
            box["value"] = fn()
        except BaseException as exc:  # handed to the caller's thread unchanged
            box["error"] = exc

    worker = threading.Thread(target=work, daemon=True, name=status or "lightcurve-gp worker")
    bar = tqdm(desc=status, bar_format="{desc}: {elapsed}", disable=not progress, leave=False)
    with _sigint_noted() as interrupts:
        worker.start()
        try:
            while worker.is_alive() and not interrupts:
                worker.join(0.1)
                bar.refresh()
        finally:
            bar.close()
        if interrupts:
            raise KeyboardInterrupt
    if "error" in box:
        raise box["error"]
    return box["value"]


def warn(message: str | None) -> None:
    """One warning line on stderr, ``warning: <message>``; nothing for ``None``. A warning never changes the exit
    code."""
    if message:
        print(f"warning: {message}", file=sys.stderr, flush=True)


def run_command(body: Callable[[], int], *, debug: bool) -> int:
    """Run a command's body with the error policy of the module docstring, its progress as lines when stderr is a
    file or pipe (:func:`progress_output`); returns the exit code."""
    with progress_output():
        return _run_with_policy(body, debug=debug)


def _run_with_policy(body: Callable[[], int], *, debug: bool) -> int:
    try:
        return body()
    except (UserError, ConfigError, ModelFileError, LightCurveFileError) as exc:
        if debug:
            raise
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        if debug:
            raise
        where = f"{exc.filename}: " if exc.filename else ""
        print(f"error: {where}{exc.strerror or exc}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, Interrupted) as exc:
        if debug:
            raise
        kept = exc.kept if isinstance(exc, Interrupted) else ""
        print(f"interrupted; {kept or 'nothing written'}", file=sys.stderr)
        return 130


def exit_process(code: int) -> None:
    """End a command's process with ``code``. When a worker abandoned by Ctrl-C is still inside torch, the
    interpreter's normal shutdown would tear torch's thread pool down under it (``terminate called without an
    active exception``, SIGABRT), so the process then ends at once with ``os._exit`` after flushing the streams;
    every file was already written atomically or not at all."""
    if any(t is not threading.main_thread() and t.is_alive() for t in threading.enumerate()):
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    sys.exit(code)


def provenance(cfg, seeds: list[int] | None = None, **extra: Any) -> dict:
    """What a run's ``results.json`` / ``metrics.json`` records to be repeated: the command line, the exact config
    (as a dict), the package, torch and Python versions, the thread count, the seeds and ``extra``."""
    return {"command": shlex.join([Path(sys.orig_argv[0]).name, *sys.orig_argv[1:]]),
            "working_directory": os.getcwd(), "config": config_to_dict(cfg), "package_version": __version__,
            "torch_version": torch.__version__, "python_version": sys.version.split()[0],
            "torch_threads": torch.get_num_threads(), "seeds": seeds,
            "started_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), **extra}
