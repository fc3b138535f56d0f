"""Shared helpers of the benchmark scripts: timing, machine description, a fixed-width table, model caching.

Imported by ``benchmarks/bench_*.py`` (run from the repository root as ``python benchmarks/bench_X.py``), which puts
this folder on ``sys.path``; :data:`ROOT`/``src`` is added too, so the scripts also run without an installed package.
"""

from __future__ import annotations

import json
import math
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any, Callable, Sequence

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "boxwing.yaml"
if str(ROOT / "src") not in sys.path:
    sys.path.insert(0, str(ROOT / "src"))


# ----------------------------------------------------------------------------------------------- timing

def synchronizer(device) -> Callable[[], None]:
    """A function that waits for queued work on ``device`` (CUDA), a no-op on CPU."""
    import torch

    device = torch.device(device)
    if device.type == "cuda":
        return lambda: torch.cuda.synchronize(device)
    return lambda: None


def time_call(fn: Callable[[], Any], *, repeats: int = 5, warmup: int = 1,
              sync: Callable[[], None] | None = None) -> dict:
    """Wall time of ``fn()``: ``warmup`` untimed calls, then ``repeats`` timed ones.

    Returns ``{"median": s, "min": s, "max": s, "repeats": n, "times": [s, ...]}``.
    """
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    sync = sync or (lambda: None)
    for _ in range(warmup):
        fn()
        sync()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        sync()
        times.append(time.perf_counter() - t0)
    return {"median": statistics.median(times), "min": min(times), "max": max(times), "repeats": repeats,
            "times": times}


def timed(fn: Callable[[], Any]) -> tuple[Any, float]:
    """``(fn(), seconds)`` of one call."""
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


# ----------------------------------------------------------------------------------------------- machine

def set_threads(threads: int | None) -> None:
    """``torch.set_num_threads(threads)`` when given (``None`` or 0 keeps torch's default)."""
    import torch

    if threads:
        torch.set_num_threads(int(threads))


def load_average() -> str:
    """The 1/5/15-minute load averages from ``/proc/loadavg`` ("n/a" where there is none)."""
    try:
        return " ".join(Path("/proc/loadavg").read_text().split()[:3])
    except OSError:
        return "n/a"


def machine_info(dtype=None, device: str = "cpu") -> dict:
    """What a timing depends on: cores, torch threads, versions, dtype, device, load average."""
    import torch

    info = {"os_cpu_count": os.cpu_count(), "torch_threads": torch.get_num_threads(), "torch": torch.__version__,
            "dtype": str(dtype).replace("torch.", "") if dtype is not None else None, "device": str(device),
            "loadavg": load_average()}
    if torch.device(device).type == "cuda":
        info["gpu"] = torch.cuda.get_device_name(torch.device(device))
    return info


def machine_line(info: dict) -> str:
    return (f"os.cpu_count() = {info['os_cpu_count']}, torch threads = {info['torch_threads']}, "
            f"torch {info['torch']}, dtype {info['dtype']}, device {info['device']}"
            + (f" ({info['gpu']})" if info.get("gpu") else "") + f", load average {info['loadavg']}")


# ----------------------------------------------------------------------------------------------- tables

def fmt_seconds(s: float | None) -> str:
    """A duration with a unit that keeps 3 significant digits (``"—"`` for None/NaN)."""
    if s is None or (isinstance(s, float) and math.isnan(s)):
        return "—"
    for unit, scale in (("s", 1.0), ("ms", 1e-3), ("µs", 1e-6)):
        if abs(s) >= scale or unit == "µs":
            return f"{s / scale:.3g} {unit}"
    return f"{s:.3g} s"


class Table:
    """Rows of strings under fixed columns, printed as fixed-width text or markdown, kept as JSON records."""

    def __init__(self, title: str, columns: Sequence[str]):
        self.title = title
        self.columns = list(columns)
        self.rows: list[list[str]] = []
        self.records: list[dict] = []
        self.notes: list[str] = []

    def add(self, cells: Sequence[Any], record: dict | None = None) -> None:
        """Append a row (``len(cells) == len(columns)``) and, optionally, its raw numbers for JSON output."""
        if len(cells) != len(self.columns):
            raise ValueError(f"row has {len(cells)} cells, table {self.title!r} has {len(self.columns)} columns")
        self.rows.append(["" if c is None else str(c) for c in cells])
        self.records.append(dict(record or dict(zip(self.columns, self.rows[-1]))))

    def note(self, text: str) -> None:
        self.notes.append(text)

    def _widths(self) -> list[int]:
        return [max([len(c)] + [len(r[i]) for r in self.rows]) for i, c in enumerate(self.columns)]

    def text(self) -> str:
        w = self._widths()
        line = lambda cells: "  ".join(c.ljust(w[i]) if i == 0 else c.rjust(w[i])  # noqa: E731
                                       for i, c in enumerate(cells)).rstrip()
        out = [self.title, line(self.columns), "-" * (sum(w) + 2 * (len(w) - 1))]
        out += [line(r) for r in self.rows]
        out += [f"  note: {n}" for n in self.notes]
        return "\n".join(out)

    def markdown(self) -> str:
        out = [f"### {self.title}", "", "| " + " | ".join(self.columns) + " |",
               "|" + "|".join("---" for _ in self.columns) + "|"]
        out += ["| " + " | ".join(r) + " |" for r in self.rows]
        if self.notes:
            out += [""] + [f"* {n}" for n in self.notes]
        return "\n".join(out) + "\n"

    def print(self) -> None:
        print(self.text() + "\n", flush=True)


def write_report(path: str | Path, info: dict, tables: Sequence[Table], extra: dict | None = None) -> Path:
    """Write the tables to ``path``: JSON when it ends in ``.json``, markdown otherwise."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix == ".json":
        blob = {"machine": info, "tables": [{"title": t.title, "columns": t.columns, "rows": t.records,
                                              "notes": t.notes} for t in tables], **(extra or {})}
        path.write_text(json.dumps(blob, indent=2, default=str) + "\n")
    else:
        head = f"Machine: {machine_line(info)}\n\n"
        path.write_text(head + "\n".join(t.markdown() for t in tables))
    return path


# ----------------------------------------------------------------------------------------------- data and models

def load_cfg(overrides: Sequence[str] = ()):
    """The paper's config (``configs/boxwing.yaml``) with ``key=value`` overrides."""
    from lightcurve_gp.config.load import load_config

    return load_config(CONFIG, overrides=list(overrides))


def quick_overrides(quick: bool) -> list[str]:
    """``--quick``: a 42-axis icosphere (1260 training points instead of 19260)."""
    return ["data.icosphere_subdivisions=1"] if quick else []


def cached_gp(cfg, data, kind: str, *, num_inducing: int | None = None, cache_dir: str | Path = "runs/bench",
              refit: bool = False, after_fit: Callable[[Any], dict] | None = None):
    """An ExactGP / SparseGP of ``cfg`` (with ``kind`` and ``num_inducing``) from the model store ``cache_dir``
    (:func:`lightcurve_gp.training.store.get_or_train`), trained there with ``os.cpu_count()`` threads when missing or
    with ``refit``. ``data`` is the training set the caller uses (the store trains on the same set of ``cfg``).

    ``extra`` holds ``fit_s`` (training seconds, from the store entry's ``metrics.json``), ``n_train`` and whatever
    ``after_fit(model)`` returned, computed once per store entry and kept in its ``bench_extra.json``.

    Returns ``(model, extra, loaded)``.
    """
    import dataclasses

    import torch

    from lightcurve_gp.files import write_json_atomic
    from lightcurve_gp.training.store import get_or_train, store_folder

    sparse = dataclasses.replace(cfg.model.sparse, num_inducing=num_inducing or cfg.model.sparse.num_inducing)
    mcfg = dataclasses.replace(cfg.model, kind=kind, sparse=sparse)
    cfg_m = dataclasses.replace(cfg, model=mcfg)
    folder = store_folder(cfg_m, cache_dir)
    loaded = (folder / "model.pt").is_file() and not refit
    threads = torch.get_num_threads()
    torch.set_num_threads(os.cpu_count() or 1)  # training is timed with every core, whatever the latency setting
    try:
        model, _ = get_or_train(cfg_m, cache_dir, retrain=refit)
    finally:
        torch.set_num_threads(threads)
    metrics = json.loads((folder / "metrics.json").read_text())
    extra = {"key": metrics["model_key"], "fit_s": metrics["timings_s"]["fit_s"], "n_train": metrics["train_points"],
             "fit_threads": metrics["torch_threads"]}
    side = folder / "bench_extra.json"
    if after_fit is not None:
        if not side.is_file() or not loaded:
            write_json_atomic(after_fit(model), side)
        extra.update(json.loads(side.read_text()))
    model.extra = {**model.extra, **extra}
    return model, extra, loaded


def sigma_like_inputs(data, sets: int, per_set: int, seed: int, spread_deg: float = 3.0, offset_deg: float = 5.0):
    """``q (sets, per_set, 4)``, ``m_past (sets, per_set)``: each set's first point lies ``offset_deg`` from a random
    training attitude, the others within ``spread_deg`` of it (like a filter's sigma points); ``m_past`` of that
    training point."""
    import torch

    from lightcurve_gp.attitude.rotations import quat_mul, quat_normalize, rotvec_to_quat

    gen = torch.Generator().manual_seed(seed)
    dtype = data.q.dtype
    idx = torch.randint(len(data), (sets,), generator=gen)

    def small(shape, max_deg):
        axis = torch.randn(*shape, 3, generator=gen, dtype=dtype)
        axis = axis / axis.norm(dim=-1, keepdim=True)
        angle = torch.rand(*shape, 1, generator=gen, dtype=dtype) * math.radians(max_deg)
        return rotvec_to_quat(axis * angle)

    centre = quat_normalize(quat_mul(small((sets,), offset_deg), data.q[idx]))
    delta = small((sets, per_set), spread_deg)
    delta[:, 0] = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=dtype)
    q = quat_normalize(quat_mul(delta, centre.unsqueeze(1).expand(sets, per_set, 4)))
    return q, data.m_past[idx].unsqueeze(1).expand(sets, per_set).clone()


def exact_variance_check(data, seed: int = 1):
    """``after_fit`` for the exact GP: fast-vs-exact variance error on 50 sigma-like sets of 13 points."""
    from lightcurve_gp.observation.exact_gp import fast_variance_error

    def check(model) -> dict:
        q, m = sigma_like_inputs(data, 50, 13, seed)
        err, seconds = timed(lambda: fast_variance_error(model, q, m))
        return {"variance_error": err, "variance_check_s": seconds}

    return check
