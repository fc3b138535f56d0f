"""How fast Ctrl-C acts during ``train``'s exact conditioning: start the command on a pseudo-terminal (so that its
status lines show), send SIGINT a few seconds after "fitting the exact GP" appears, and time the exit.

``python benchmarks/bench_interrupt.py [--delay 5] [--set key=value ...]`` prints the exit code, the seconds from
SIGINT to exit and the command's last output line; nothing is kept (the run folder is a temporary one).
"""

from __future__ import annotations

import argparse
import os
import pty
import select
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _read_until(fd: int, marker: bytes, limit_s: float) -> bytes:
    seen = b""
    end = time.monotonic() + limit_s
    while marker not in seen and time.monotonic() < end:
        ready, _, _ = select.select([fd], [], [], 0.5)
        if ready:
            try:
                chunk = os.read(fd, 4096)
            except OSError:  # the command has exited and closed the terminal
                break
            seen += chunk
    return seen


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--delay", type=float, default=5.0, help="seconds into the fit at which SIGINT is sent")
    p.add_argument("--set", dest="overrides", action="append", default=[])
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as out:
        master, slave = pty.openpty()
        cmd = [sys.executable, "-m", "lightcurve_gp.train", str(ROOT / "configs" / "boxwing.yaml"), "--out", out,
               "--cache", str(ROOT / "runs" / "cache"), *(a for o in args.overrides for a in ("--set", o))]
        proc = subprocess.Popen(cmd, stdin=slave, stdout=slave, stderr=slave, cwd=ROOT)
        os.close(slave)
        head = _read_until(master, b"fitting the exact GP", 600)
        if proc.poll() is not None:
            print(head.decode(errors="replace"))
            return 1
        time.sleep(args.delay)
        sent = time.perf_counter()
        proc.send_signal(signal.SIGINT)
        proc.wait()
        reaction = time.perf_counter() - sent
        tail = _read_until(master, b"\n\n", 1.0).decode(errors="replace").strip().splitlines()
        left = sorted(os.listdir(out))
    print(f"exit code {proc.returncode}, {reaction:.2f} s from SIGINT to exit, last line: "
          f"{tail[-1].strip() if tail else ''!r}, left in --out: {left}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
