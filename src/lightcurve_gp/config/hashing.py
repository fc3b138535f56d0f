"""A config as a plain dict, and the hashes every cache, model store and case store keys on.

:func:`config_to_dict` is generic: a field is left out when its hash rule in :mod:`lightcurve_gp.config.schema` says
so (``omit_default``, ``omit_when``, ``omit_unless`` in its metadata), so settings added after keys were first
written leave those keys unchanged while they are off. :func:`config_hash` hashes that dict;
:func:`content_hash` the same with the mesh file's content in place of its path.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from typing import Any

from lightcurve_gp.config.parsing import check_mesh_file
from lightcurve_gp.config.schema import Config
from lightcurve_gp.files import file_sha256

__all__ = ["config_to_dict", "config_hash", "content_dict", "content_hash"]


def config_to_dict(cfg: Any) -> dict:
    """Plain nested ``dict`` of a config or one of its sections (YAML/JSON serialisable) that
    :func:`~lightcurve_gp.config.validate.config_from_dict` reads back, without the fields whose hash rule leaves
    them out (the model section keeps only the settings of its own kind; options that are off are absent, not
    null). A rule that names a key of another section applies only when the whole config is given."""
    values = dataclasses.asdict(cfg)
    return _kept(cfg, values, values if isinstance(cfg, Config) else None)


def _kept(section: Any, values: dict, root: dict | None) -> dict:
    """``values`` (the ``asdict`` of ``section``) less the fields left out by their rules, recursively."""
    out = {}
    for f in dataclasses.fields(section):
        if _left_out(f, values, root):
            continue
        value = getattr(section, f.name)
        out[f.name] = _kept(value, values[f.name], root) if dataclasses.is_dataclass(value) else values[f.name]
    return out


def _left_out(f: dataclasses.Field, values: dict, root: dict | None) -> bool:
    meta = f.metadata
    if meta.get("omit_default") and values[f.name] == _default(f):
        return True
    if meta.get("omit_when") and _holds(meta["omit_when"], values, root):
        return True
    return bool(meta.get("omit_unless")) and _holds(meta["omit_unless"], values, root) is False


def _default(f: dataclasses.Field) -> Any:
    """The field's default as ``asdict`` holds it (a section's default as its plain dict)."""
    value = f.default_factory() if f.default_factory is not dataclasses.MISSING else f.default
    return dataclasses.asdict(value) if dataclasses.is_dataclass(value) else value


def _holds(conditions: dict[str, Any], values: dict, root: dict | None) -> bool | None:
    """Whether every named field has its value: a plain name is a field of ``values``' section, a dotted one a path
    from ``root``; ``None`` when it names a path and there is no root (a section serialised alone)."""
    for key, wanted in conditions.items():
        if "." in key:
            if root is None:
                return None
            node: Any = root
            for part in key.split("."):
                node = node[part]
        else:
            node = values[key]
        if node != wanted:
            return False
    return True


def config_hash(cfg: Config, *sections: str, extra: Any = None) -> str:
    """Stable 16-hex-digit hash of the named sections (all of ``cfg`` when none), for on-disk caches.

    Args:
        cfg: a validated config.
        sections: top-level section names, e.g. ``"shape", "surface", "geometry", "data"``.
        extra: any JSON-serialisable value mixed into the hash (a format version, say).
    """
    full = config_to_dict(cfg)
    chosen = {s: full[s] for s in sections} if sections else full
    return _hash(chosen, extra)


def _hash(sections: dict, extra: Any) -> str:
    blob = json.dumps({"sections": sections, "extra": extra}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def content_dict(cfg: Config, *sections: str) -> dict:
    """The named sections as a plain dict with files replaced by their contents' hash: ``shape.mesh_path`` becomes
    ``shape.mesh_sha256`` (``None`` without a mesh). Two configs with equal content dicts give the same data and
    model wherever the files live; editing a mesh in place changes it."""
    full = config_to_dict(cfg)
    chosen = {s: full[s] for s in sections} if sections else full
    if "shape" in chosen:
        shape = dict(chosen["shape"])
        path = shape.pop("mesh_path")
        if path and cfg.shape.kind == "mesh":
            check_mesh_file(path)
            shape["mesh_sha256"] = file_sha256(path)
        else:
            shape["mesh_sha256"] = None
        chosen["shape"] = shape
    return chosen


def content_hash(cfg: Config, *sections: str, extra: Any = None) -> str:
    """:func:`config_hash` of :func:`content_dict`: the cache key of anything computed from these sections."""
    return _hash(content_dict(cfg, *sections), extra)
