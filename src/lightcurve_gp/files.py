"""Atomic file writes and run folders: a killed run never leaves a half-written artifact that a later run would load.

JSON is written as JSON proper (RFC 8259): a NaN or an infinity, which Python's ``json`` would write as the bare
tokens ``NaN``/``Infinity`` that other parsers (``JSON.parse``, ``jq``) refuse, is written as ``null``.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import torch

__all__ = ["RunFolder", "atomic_path", "file_sha256", "json_ready", "save_torch_atomic", "write_json_atomic",
           "write_text_atomic"]


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path in the target's folder; on success it replaces ``path`` in one ``os.replace``.

    On any exception the temporary file is removed and ``path`` is left as it was.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~_umask())  # mkstemp creates 0600; give the usual permissions of a new file
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def save_torch_atomic(obj: Any, path: str | Path) -> None:
    """``torch.save`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        torch.save(obj, tmp)


def write_text_atomic(text: str, path: str | Path) -> None:
    """Write ``text`` to ``path`` atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def json_ready(obj: Any) -> Any:
    """``obj`` with every non-finite float (NaN, ±inf, in any nesting of dicts, lists and tuples) replaced by
    ``None``, which JSON writes as ``null``; tuples become lists."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: json_ready(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_ready(v) for v in obj]
    return obj


def write_json_atomic(obj: Any, path: str | Path) -> None:
    """Write ``obj`` as indented JSON to ``path`` atomically; NaN and infinities as ``null`` (module docstring)."""
    write_text_atomic(json.dumps(json_ready(obj), indent=2, sort_keys=False, allow_nan=False) + "\n", path)


def file_sha256(path: str | Path, chunk: int = 1 << 20) -> str:
    """Hex SHA-256 of a file's bytes (read in ``chunk``-byte pieces)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(chunk), b""):
            digest.update(block)
    return digest.hexdigest()


class RunFolder:
    """A run's output folder that appears whole or not at all.

    ``with RunFolder(final, force=False) as tmp:`` yields a fresh temporary sibling of ``final``
    (``.<name>.partial-XXXX``); every file goes there. On a normal exit the temporary folder is renamed to ``final``;
    with ``force`` an existing ``final`` is moved aside first and deleted only after the rename, so it is replaced
    at the very end. On any exception (Ctrl-C included) the temporary folder is deleted and ``final`` is untouched.

    Raises:
        FileExistsError: ``final`` exists and ``force`` is false (checked on entry, before any work is written).
    """

    def __init__(self, final: str | Path, *, force: bool = False):
        self.final = Path(final)
        self.force = force
        self.tmp: Path | None = None

    def __enter__(self) -> Path:
        if self.final.exists() and not self.force:
            raise FileExistsError(f"{self.final} already exists; pass --force to replace it or choose another --out")
        self.final.parent.mkdir(parents=True, exist_ok=True)
        self.tmp = Path(tempfile.mkdtemp(prefix=f".{self.final.name}.partial-", dir=self.final.parent))
        os.chmod(self.tmp, 0o777 & ~_umask())
        return self.tmp

    def __exit__(self, exc_type, exc, tb) -> None:
        assert self.tmp is not None
        if exc_type is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
            return
        old = None
        if self.final.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{self.final.name}.old-", dir=self.final.parent))
            os.replace(self.final, old / self.final.name)
        os.replace(self.tmp, self.final)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
