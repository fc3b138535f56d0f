"""Progress when stderr is not a terminal: tqdm's bars as plain lines, with the time left where tqdm knows it.

On a terminal the commands show tqdm's bars. Written to a file or pipe (a log, ``2> run.log``, a batch job), a bar's
redraws (``\\r`` + the bar, cursor moves for nested bars) would pile up as one unreadable line, so
:func:`progress_output` (opened by every command, :func:`lightcurve_gp.commands.common.run_command`) puts
:class:`ProgressLines` in front of such a stderr: each bar's first state, then at most one line every
:data:`PROGRESS_LINE_INTERVAL` seconds, its completion, and a status line's last state when it is cleared, each as
plain text (:func:`progress_line`: ``estimators: 50% 2/4 01:03 elapsed, about 01:03 left, 31.50s/filter``). Every
other write passes through unchanged. An in-memory stderr (no file descriptor) gets no progress at all.
"""

from __future__ import annotations

import math
import re
import sys
import threading
import time
from contextlib import contextmanager, redirect_stderr
from typing import Callable, Iterator

__all__ = ["PROGRESS_LINE_INTERVAL", "has_descriptor", "progress_line", "ProgressLines", "progress_output"]


def has_descriptor(stream) -> bool:
    """Whether ``stream`` is backed by a file descriptor (a terminal, file or pipe; not an in-memory stream)."""
    try:
        stream.fileno()
    except (AttributeError, OSError, ValueError):  # io.UnsupportedOperation is an OSError and a ValueError
        return False
    return True


#: seconds between two progress lines of one bar when stderr is a file or pipe
PROGRESS_LINE_INTERVAL = 10.0
_ESCAPES = re.compile(r"\x1b\[[0-9;]*[A-Za-z]")
_BAR_GRAPHIC = re.compile(r"\|[^|]*\|")
_TIMES = re.compile(r"\[(?P<elapsed>[^<\],]+)(?:<(?P<left>[^,\]]+))?(?:, (?P<rate>[^\]]+))?\]")


def progress_line(text: str) -> str:
    """A tqdm bar's text as a plain line: the bar graphic dropped, ``[elapsed<left, rate]`` in words (``about …
    left`` only where tqdm knows it)."""
    def words(m: re.Match) -> str:
        left = m["left"] if m["left"] and "?" not in m["left"] else None
        rate = m["rate"] if m["rate"] and "?" not in m["rate"] else None
        return ", ".join(filter(None, (f"{m['elapsed']} elapsed", left and f"about {left} left", rate)))
    return " ".join(_TIMES.sub(words, _BAR_GRAPHIC.sub(" ", text)).split())


class ProgressLines:
    """Stands in for stderr when it is a file or pipe: tqdm's redraws (``\\r`` + the bar, cursor moves) become plain
    lines (:func:`progress_line`): each bar's first state, then at most one every ``interval`` seconds, its
    completion (100 %) and the last state of a status line when it is cleared; every other write (errors, warnings,
    messages) passes through unchanged."""

    def __init__(self, stream, *, interval: float = PROGRESS_LINE_INTERVAL,
                 clock: Callable[[], float] = time.monotonic):
        self.stream, self.interval, self.clock = stream, interval, clock
        self._lock = threading.Lock()
        self._pending: dict[str, str] = {}  # per bar (its description): the latest state, not yet written
        self._shown: dict[str, str] = {}  # per bar: the last line written
        self._last: dict[str, float] = {}  # per bar: when it was written
        self._current = ""  # the bar redrawn last
        self._in_bar = False  # the last write was part of a redraw

    def write(self, text: str) -> int:
        with self._lock:
            plain = _ESCAPES.sub("", text)
            if "\r" not in plain:
                if not (self._in_bar and plain.strip("\n") == ""):  # a bar's cursor move or closing newline
                    self.stream.write(plain)
                    self._in_bar = False
                return len(text)
            self._in_bar = True
            head, *parts = plain.split("\r")
            if head.strip("\n"):
                self.stream.write(head)
            for part in parts:
                state = progress_line(part)
                if not state:  # a status line cleared (leave=False): its last state
                    self._emit(self._current, self._pending.get(self._current, "") != self._shown.get(self._current))
                    continue
                bar = part.partition(":")[0].strip()
                self._pending[bar], self._current = state, bar
                if self.clock() - self._last.get(bar, -math.inf) >= self.interval:
                    self._emit(bar, state != self._shown.get(bar))
                elif " 100% " in f" {state} ":  # done: once, whatever tqdm redraws at its close
                    self._emit(bar, _count(state) != _count(self._shown.get(bar, "")))
            return len(text)

    def _emit(self, bar: str, show: bool) -> None:
        """Write ``bar``'s pending state when ``show``; it is no longer pending either way."""
        state = self._pending.pop(bar, "")
        if state and show:
            self.stream.write(state + "\n")
            self.stream.flush()
            self._shown[bar], self._last[bar] = state, self.clock()

    def flush(self) -> None:
        self.stream.flush()

    def isatty(self) -> bool:
        return False

    def fileno(self) -> int:
        return self.stream.fileno()

    def __getattr__(self, name: str):
        return getattr(self.stream, name)


def _count(line: str) -> str:
    """A progress line without its times and rate: its description, share and count."""
    return line.partition(" elapsed")[0].rsplit(" ", 1)[0]


@contextmanager
def progress_output() -> Iterator[None]:
    """While open, progress bars written to a stderr that is a file or pipe come out as plain lines
    (:class:`ProgressLines`); on a terminal, or an in-memory stream, stderr is left as it is."""
    if sys.stderr.isatty() or not has_descriptor(sys.stderr) or isinstance(sys.stderr, ProgressLines):
        yield
        return
    with redirect_stderr(ProgressLines(sys.stderr)):
        yield
