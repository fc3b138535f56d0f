"""Typed configuration loaded from YAML, with overrides, validated with key paths in every error.

One YAML file (``configs/boxwing.yaml`` reproduces the paper) holds every number of an experiment. It is
read into the dataclass tree :class:`Config` (declared in :mod:`lightcurve_gp.config.schema`); each field's
metadata states its constraint, and :func:`load_config` reports the first violation as
``ConfigError("surface.rho: 1.4 is outside [0, 1]")``.

The config layer, one concept per module: :mod:`.schema` (the sections, their constraints and hash rules),
:mod:`.parsing` (UTC times, TLE lines, mesh files as a user writes them), :mod:`.validate` (a mapping into a
:class:`Config`), :mod:`.hashing` (the plain dict and the cache keys), :mod:`.devices` (the named device on this
machine) and this module (files and overrides). This
module re-exports the public names of all of them, so ``from lightcurve_gp.config.load import ...`` reaches the
whole layer.

Typical use::

    cfg = load_config("configs/boxwing.yaml", overrides=["data.t_span_past=10", "model.kind=sparse"])
    cfg.surface.rho            # 0.5
    config_hash(cfg, "data")   # stable key for caches that depend on the data section only
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import yaml

from lightcurve_gp.config import schema as config_schema
from lightcurve_gp.config.devices import check_device
from lightcurve_gp.config.hashing import config_hash, config_to_dict, content_dict, content_hash
from lightcurve_gp.config.parsing import check_mesh
from lightcurve_gp.config.schema import *  # noqa: F403 (the typed sections are importable from here)
from lightcurve_gp.config.schema import Config, ConfigError
from lightcurve_gp.config.validate import config_from_dict

__all__ = [
    *config_schema.__all__,
    "load_config",
    "load_raw_config",
    "config_from_dict",
    "config_to_dict",
    "config_hash",
    "content_dict",
    "content_hash",
    "check_mesh",
    "check_device",
    "apply_overrides",
    "parse_override",
]


def parse_override(text: str) -> tuple[list[str], Any]:
    """Split ``"a.b.c=value"`` into the key path and the YAML-parsed value (``"x=[1, 2]"`` gives a list)."""
    if "=" not in text:
        raise ConfigError(f"override {text!r}: expected key.path=value")
    key, _, value = text.partition("=")
    key = key.strip()
    if not key:
        raise ConfigError(f"override {text!r}: empty key")
    try:
        parsed = yaml.safe_load(value) if value.strip() else None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{key}: cannot parse override value {value!r}: {exc}") from None
    return key.split("."), parsed


def apply_overrides(raw: dict, overrides: list[str] | None) -> dict:
    """Return a copy of ``raw`` with each ``key.path=value`` override set (paths must name existing sections)."""
    out = json.loads(json.dumps(raw))
    for text in overrides or []:
        keys, value = parse_override(text)
        node = out
        for i, k in enumerate(keys[:-1]):
            child = node.get(k)
            if child is None:
                child = node[k] = {}
            if not isinstance(child, dict):
                raise ConfigError(f"{'.'.join(keys[: i + 1])}: is a value, not a section (override {text!r})")
            node = child
        node[keys[-1]] = value
    return out


def load_config(path: str | Path, overrides: list[str] | None = None) -> Config:
    """Read, override and validate a YAML config.

    A relative ``shape.mesh_path`` written in the file resolves against the file's folder, one given in
    ``overrides`` against the working directory; the mesh must exist, be readable by trimesh and hold triangles.
    The ``device`` must be there on this machine (:func:`~lightcurve_gp.config.devices.check_device`).

    Args:
        path: YAML file.
        overrides: ``["section.key=value", ...]``; values are parsed as YAML.

    Raises:
        ConfigError: missing file, invalid YAML, unknown key, wrong type or out-of-range value, a bad mesh, a
            device this machine does not have.
    """
    cfg = config_from_dict(load_raw_config(path, overrides))
    if cfg.shape.mesh_path:
        check_mesh(cfg.shape.mesh_path)
    check_device(cfg.device)
    return cfg


def load_raw_config(path: str | Path, overrides: list[str] | None = None) -> dict:
    """The YAML mapping of ``path`` with ``overrides`` applied and a relative ``shape.mesh_path`` made absolute (as
    :func:`load_config` resolves it), not yet validated: what a sweep varies before validating each grid point.

    Raises:
        ConfigError: missing file, invalid YAML, a malformed override.
    """
    path = Path(path)
    raw = _read_yaml(path)
    mesh_base = Path.cwd() if any(o.partition("=")[0].strip() == "shape.mesh_path" for o in overrides or []) \
        else path.resolve().parent
    out = apply_overrides(raw, overrides)
    shape = out.get("shape") if isinstance(out, dict) else None
    if isinstance(shape, dict) and isinstance(shape.get("mesh_path"), str) and shape["mesh_path"]:
        shape["mesh_path"] = str(mesh_base / Path(shape["mesh_path"]).expanduser())
    return out


def _read_yaml(path: Path) -> dict:
    if path.is_dir():
        raise ConfigError(f"config file {str(path)!r} is a folder, not a YAML file")
    if not path.is_file():
        raise ConfigError(f"config file {str(path)!r} does not exist")
    try:
        raw = yaml.safe_load(path.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: invalid YAML: {' '.join(str(exc).split())}") from None
    except OSError as exc:
        raise ConfigError(f"config file {str(path)!r}: {exc.strerror}") from None
    if raw is None:
        raise ConfigError(f"config file {str(path)!r} is empty (expected the sections of configs/boxwing.yaml)")
    return raw
