"""The device a config names, on this machine: whether torch can use it, and how much memory it has free.

``device`` is validated as text (``cpu``, ``cuda``, ``cuda:N``) with the rest of the config; whether this machine
has it is checked once, up front, when a config is loaded for a run (:func:`check_device`), so that a CPU-only torch
refuses ``device: cuda`` in one line naming the key instead of failing inside the first CUDA call.
"""

from __future__ import annotations

import os
from pathlib import Path

import torch

from lightcurve_gp.config.schema import ConfigError

__all__ = ["check_device", "available_memory"]


def check_device(device: str) -> None:
    """Raise :class:`ConfigError` naming ``device`` unless torch can allocate on it here.

    ``cpu`` is always there; ``cuda`` and ``cuda:N`` need a torch built with CUDA and a visible device (of that
    index).
    """
    if device == "cpu":
        return
    if torch.version.cuda is None:
        raise ConfigError(f"device: {device} is not available: this torch has no CUDA (torch {torch.__version__}); "
                          f"use device: cpu or install a CUDA build of torch")
    count = torch.cuda.device_count() if torch.cuda.is_available() else 0
    if count == 0:
        raise ConfigError(f"device: {device} is not available: torch {torch.__version__} finds no CUDA device; "
                          f"use device: cpu")
    index = int(device.partition(":")[2] or 0)
    if index >= count:
        raise ConfigError(f"device: {device} is not available: torch finds {count} CUDA device(s), cuda:0 to "
                          f"cuda:{count - 1}")


def available_memory(device: str) -> int | None:
    """Bytes a new allocation can take on ``device``: for the CPU ``MemAvailable`` of ``/proc/meminfo`` (the free
    physical pages where there is none), for a CUDA device its free memory; ``None`` when unknown."""
    if device != "cpu":
        return int(torch.cuda.mem_get_info(torch.device(device))[0])
    meminfo = Path("/proc/meminfo")
    if meminfo.is_file():
        for line in meminfo.read_text().splitlines():
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) * 1024
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None
