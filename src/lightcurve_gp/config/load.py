"""Typed configuration loaded from YAML, validated with key paths in every error.

One YAML file (``configs/boxwing.yaml`` reproduces the paper) holds every number of an experiment. It is
read into the dataclass tree :class:`Config` (declared in :mod:`lightcurve_gp.config.schema` and re-exported
here); each field's metadata states its constraint, and :func:`load_config` reports the first violation as
``ConfigError("surface.rho: 1.4 is outside [0, 1]")``.

Typical use::

    cfg = load_config("configs/boxwing.yaml", overrides=["data.t_span_past=10", "model.kind=sparse"])
    cfg.surface.rho            # 0.5
    config_hash(cfg, "data")   # stable key for caches that depend on the data section only
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import re
import types
import typing
from pathlib import Path
from typing import Any

import yaml

from lightcurve_gp.config import schema as config_schema
from lightcurve_gp.config.schema import *  # noqa: F403 (the typed sections are importable from here)
from lightcurve_gp.config.schema import (
    MODEL_KIND_SECTIONS,
    Config,
    ConfigError,
    DataConfig,
    FilterConfig,
    GeometryConfig,
    ModelConfig,
    ScenarioConfig,
    SparseModelConfig,
    SpinRangeConfig,
)

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
    "apply_overrides",
    "parse_override",
]


def _fmt(value: Any) -> str:
    if isinstance(value, str):
        return repr(value)
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def _check_number(path: str, value: Any, meta: dict, want_int: bool) -> float | int:
    if isinstance(value, str):  # PyYAML reads exponents without a dot or sign ("1e-4") as strings
        try:
            value = float(value)
        except ValueError:
            pass
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        kind = "an integer" if want_int else "a number"
        raise ConfigError(f"{path}: expected {kind}, got {_fmt(value)}")
    if want_int and isinstance(value, float):
        if not value.is_integer():
            raise ConfigError(f"{path}: expected an integer, got {_fmt(value)}")
        value = int(value)
    if not math.isfinite(value):
        raise ConfigError(f"{path}: {_fmt(value)} is not finite")
    lo, hi = meta.get("lo"), meta.get("hi")
    if lo is not None and hi is not None and not (lo <= value <= hi and not (meta["lo_open"] and value == lo)):
        bracket = "(" if meta["lo_open"] else "["
        raise ConfigError(f"{path}: {_fmt(value)} is outside {bracket}{_fmt(lo)}, {_fmt(hi)}]")
    if lo is not None and hi is None:
        if meta["lo_open"] and value <= lo:
            raise ConfigError(f"{path}: {_fmt(value)} must be > {_fmt(lo)}")
        if value < lo:
            raise ConfigError(f"{path}: {_fmt(value)} must be >= {_fmt(lo)}")
    return float(value) if not want_int else int(value)


def _convert(path: str, annotation: Any, value: Any, meta: dict) -> Any:
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _convert(path, _union_member(inner, value), value, meta)
    if value is None:
        raise ConfigError(f"{path}: a value is required, got null")
    if dataclasses.is_dataclass(annotation):
        return _build(annotation, value, path)
    if origin is list:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{path}: expected a list, got {_fmt(value)}")
        if meta.get("length") is not None and len(value) != meta["length"]:
            raise ConfigError(f"{path}: expected {meta['length']} values, got {len(value)}")
        if meta.get("min_length") is not None and len(value) < meta["min_length"]:
            raise ConfigError(f"{path}: expected at least {meta['min_length']} values, got {len(value)}")
        return [_convert(f"{path}[{i}]", args[0], v, meta) for i, v in enumerate(value)]
    if annotation is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{path}: expected true or false, got {_fmt(value)}")
        return value
    if annotation in (int, float):
        return _check_number(path, value, meta, want_int=annotation is int)
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"{path}: expected a string, got {_fmt(value)}")
        choices = meta.get("choices")
        if choices and value not in choices:
            raise ConfigError(f"{path}: {value!r} is not one of {', '.join(choices)}")
        return value
    raise TypeError(f"unsupported annotation {annotation!r} at {path}")  # a bug in this module, not user input


def _union_member(inner: list, value: Any) -> Any:
    """The member of a union a value is read as: a dataclass for a mapping, a list of lists for a list whose first
    element is a list, else the first member."""
    if isinstance(value, dict):
        return next((a for a in inner if dataclasses.is_dataclass(a)), inner[0])
    nested = isinstance(value, (list, tuple)) and bool(value) and isinstance(value[0], (list, tuple))
    if nested:
        return next((a for a in inner if typing.get_args(a) and typing.get_origin(typing.get_args(a)[0]) is list),
                    inner[0])
    return inner[0]


def _check_training_spins(cfg: Config) -> None:
    """``data.omega0_deg_s``: three numbers, a non-empty list of three-number rates, or a range with low <= high."""
    spins = cfg.data.omega0_deg_s
    if isinstance(spins, SpinRangeConfig):
        for axis, (lo, hi) in enumerate(zip(spins.low, spins.high)):
            if not lo <= hi:
                raise ConfigError(f"data.omega0_deg_s.low[{axis}]: {lo:g} is above high {hi:g}")
    elif spins and isinstance(spins[0], list):
        for i, rate in enumerate(spins):
            if len(rate) != 3:
                raise ConfigError(f"data.omega0_deg_s[{i}]: expected 3 values, got {len(rate)}")
    elif len(spins) != 3:
        raise ConfigError(f"data.omega0_deg_s: expected 3 values (or a list of rates, or a range), got {len(spins)}")


def _build(cls: type, raw: Any, prefix: str = "") -> Any:
    where = prefix or "config"
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: expected a mapping, got {_fmt(raw)}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(raw) - set(fields))
    if unknown:
        key = f"{prefix}.{unknown[0]}" if prefix else unknown[0]
        raise ConfigError(f"{key}: unknown key (known keys: {', '.join(fields)})")
    values = {}
    for name, f in fields.items():
        path = f"{prefix}.{name}" if prefix else name
        if name not in raw:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise ConfigError(f"{path}: missing key")
            continue
        values[name] = _convert(path, hints[name], raw[name], dict(f.metadata))
    return cls(**values)


_SAFE_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._-]*")


def _check_name(name: str) -> None:
    if not _SAFE_NAME.fullmatch(name) or len(name) > 100:
        raise ConfigError(f"name: {name!r} is not a safe folder name (1-100 letters, digits, '.', '_' or '-', "
                          f"not starting with '.')")


def _cross_check(cfg: Config) -> None:
    _check_name(cfg.name)
    if cfg.shape.kind == "mesh" and not cfg.shape.mesh_path:
        raise ConfigError("shape.mesh_path: required when shape.kind is 'mesh'")
    lo, hi = cfg.evaluation.rmse_window_s
    if not lo < hi:
        raise ConfigError(f"evaluation.rmse_window_s: start {lo:g} must be before end {hi:g}")
    if hi > cfg.scenario.duration_s:
        raise ConfigError(f"evaluation.rmse_window_s: end {hi:g} is after scenario.duration_s "
                          f"{cfg.scenario.duration_s:g}")
    if cfg.data.t_span_past < cfg.data.dt_s:
        raise ConfigError(f"data.t_span_past: {cfg.data.t_span_past:g} is shorter than data.dt_s {cfg.data.dt_s:g}")
    if not (cfg.device == "cpu" or cfg.device == "cuda" or cfg.device.startswith("cuda:")):
        raise ConfigError(f"device: {cfg.device!r} is not cpu, cuda or cuda:N")
    if all(v == 0 for v in cfg.scenario.q0):
        raise ConfigError("scenario.q0: the zero quaternion is not an attitude")
    # a GP of the rho-normalised curve needs the offset in the filter state, and the offset needs that GP: either
    # alone would count rho twice or not at all
    if cfg.filter.estimate_offset != (cfg.model.target != "magnitude"):
        raise ConfigError(f"filter.estimate_offset: {str(cfg.filter.estimate_offset).lower()} needs model.target: "
                          f"{'rho_normalised or surface_normalised' if cfg.filter.estimate_offset else 'magnitude'} "
                          f"(got {cfg.model.target})")
    _check_training_spins(cfg)
    _check_sparse_fit(cfg.model.sparse, ard=cfg.model.ard)
    single_spin = not isinstance(cfg.data.omega0_deg_s, SpinRangeConfig) and not isinstance(cfg.data.omega0_deg_s[0],
                                                                                           list)
    if cfg.filter.estimate_omega and cfg.model.inputs == "quaternion" and single_spin:
        raise ConfigError("filter.estimate_omega: true needs an attitude-only GP (model.inputs: attitude_matrix) or a "
                          "[q, m_app_past] GP trained over many spins (data.omega0_deg_s a list or a range): this one "
                          "learned m_app_past at the one spin data.omega0_deg_s")
    if cfg.filter.estimate_omega and cfg.geometry.kind == "orbit":
        raise ConfigError("filter.estimate_omega: not supported along a pass (geometry.kind: orbit) yet: the rate "
                          "filter steps a fixed scenario.dt_s")
    _check_training_surfaces(cfg)
    _check_geometry(cfg)
    if cfg.model.inputs == "body_geometry" and cfg.data.surfaces is not None:
        raise ConfigError("model.inputs: body_geometry is not supported with data.surfaces")
    lo_phase, hi_phase = cfg.data.phase_angle_deg
    if not lo_phase < hi_phase:
        raise ConfigError(f"data.phase_angle_deg: low {lo_phase:g} must be below high {hi_phase:g}")


_FIXED_ONLY = ("observer_km", "sun_km")
_ORBIT_ONLY = ("tle", "elements", "site", "start_utc", "timestamps_s", "gap_fraction", "gap_seed", "min_elevation_deg")


def _check_geometry(cfg: Config) -> None:
    """The keys of ``geometry.kind``: a fixed Sun and observer, or an orbit, a site and a start time."""
    geo = cfg.geometry
    if geo.kind == "fixed":
        for key in _FIXED_ONLY:
            if getattr(geo, key) is None:
                raise ConfigError(f"geometry.{key}: required when geometry.kind is fixed")
        return
    if (geo.tle is None) == (geo.elements is None):
        raise ConfigError("geometry.tle: give exactly one of geometry.tle and geometry.elements for an orbit")
    for key in ("site", "start_utc"):
        if getattr(geo, key) is None:
            raise ConfigError(f"geometry.{key}: required when geometry.kind is orbit")
    from lightcurve_gp.passes.orbit import check_tle, parse_utc

    try:
        parse_utc(geo.start_utc)
    except ValueError as exc:
        raise ConfigError(f"geometry.start_utc: {exc}") from None
    if geo.tle is not None:
        for i, line in enumerate(geo.tle):
            try:
                check_tle(line, i + 1)
            except ValueError as exc:
                raise ConfigError(f"geometry.tle[{i}]: {exc}") from None
    if geo.timestamps_s is not None:
        _check_timestamps(geo.timestamps_s, cfg.scenario.dt_s, cfg.scenario.duration_s)


def _check_timestamps(times: list[float], dt: float, duration: float) -> None:
    for i in range(1, len(times)):
        if not times[i] > times[i - 1]:
            raise ConfigError(f"geometry.timestamps_s[{i}]: {times[i]:g} is not after {times[i - 1]:g}")
    for i, t in enumerate(times):
        if abs(t / dt - round(t / dt)) > 1e-9:
            raise ConfigError(f"geometry.timestamps_s[{i}]: {t:g} is not a multiple of scenario.dt_s ({dt:g})")
    if times[-1] > duration:
        raise ConfigError(f"geometry.timestamps_s[{len(times) - 1}]: {times[-1]:g} is after scenario.duration_s "
                          f"({duration:g})")


def _check_training_surfaces(cfg: Config) -> None:
    """``data.surfaces`` and ``model.target: surface_normalised`` need each other; the surfaces' ranges."""
    surfaces = cfg.data.surfaces
    if (surfaces is not None) != (cfg.model.target == "surface_normalised"):
        raise ConfigError("data.surfaces: given exactly when model.target is surface_normalised "
                          f"(model.target: {cfg.model.target}, data.surfaces: {'set' if surfaces else 'null'})")
    if surfaces is None:
        return
    for key in ("rho", "f0", "n"):
        lo, hi = getattr(surfaces, key)
        if not lo <= hi:
            raise ConfigError(f"data.surfaces.{key}: low {lo:g} is above high {hi:g}")
    if surfaces.f0[1] >= 1.0:
        raise ConfigError(f"data.surfaces.f0: {surfaces.f0[1]:g} leaves no diffuse light (F0 must stay below 1)")
    if cfg.surface.f0 >= 1.0:
        raise ConfigError("surface.f0: the reference surface of surface_normalised needs F0 < 1")
    if cfg.data.quaternion_sign != "as_is":
        raise ConfigError(f"data.quaternion_sign: {cfg.data.quaternion_sign} is not supported with data.surfaces "
                          f"(as_is only: the spread groups each attitude's surfaces)")


#: settings that belonged to the flat ``model`` section before it was split by kind: their place now
_MOVED_MODEL_KEYS = {"fit_iterations": "exact.fit_iterations", "fit_subset": "exact.fit_subset",
                     "fast_variance_neighbors": "exact.fast_variance_neighbors", "num_inducing": "sparse.num_inducing",
                     "optimize_inducing": "sparse.optimize_inducing", "sparse_iterations": "sparse.iterations"}


def _check_model_kinds(raw_model: Any) -> None:
    """A setting given to a model kind it does not apply to is an error (before the generic validation)."""
    if not isinstance(raw_model, dict):
        return
    for key, moved in _MOVED_MODEL_KEYS.items():
        if key in raw_model:
            section = moved.split(".")[0]
            raise ConfigError(f"model.{key}: a setting of the {section} GP only; give it as model.{moved}")
    kind = raw_model.get("kind")
    for section in MODEL_KIND_SECTIONS:
        given = raw_model.get(section)
        if given is not None and kind in MODEL_KIND_SECTIONS and section != kind:
            keys = ", ".join(sorted(given)) if isinstance(given, dict) else _fmt(given)
            raise ConfigError(f"model.{section}: settings of the {section} GP ({keys}) do not apply to "
                              f"model.kind {kind}")


def _check_sparse_fit(sp: SparseModelConfig, *, ard: bool) -> None:
    """The options of the sparse fit that do not go together (``ard``: ``model.ard``)."""
    if sp.fit_inducing is not None and sp.optimize_inducing:
        raise ConfigError("model.sparse.fit_inducing: cannot be combined with model.sparse.optimize_inducing (the "
                          "fitted inducing inputs would be replaced by num_inducing new ones)")
    if sp.fit_form == "gram" and sp.fit_objective == "exact_subset":
        raise ConfigError("model.sparse.fit_form: gram computes the collapsed bound, which model.sparse.fit_objective "
                          "exact_subset does not use")
    if sp.fit_form == "gram" and ard:
        raise ConfigError("model.sparse.fit_form: gram fits one shared lengthscale; it cannot be combined with "
                          "model.ard true")
    if sp.fit_form == "gram" and sp.optimize_inducing:
        raise ConfigError("model.sparse.fit_form: gram keeps the inducing inputs fixed; it cannot be combined with "
                          "model.sparse.optimize_inducing")
    if sp.fit_form == "gram" and sp.fit_dtype != "float64":
        raise ConfigError("model.sparse.fit_form: gram needs model.sparse.fit_dtype float64 (K_uu + K_uf K_fu / "
                          "sigma^2 rounded to float32 is not positive definite)")
    if sp.fit_objective != "exact_subset":
        return
    if sp.fit_subset is None:
        raise ConfigError("model.sparse.fit_subset: needed by model.sparse.fit_objective exact_subset (the points the "
                          "exact evidence is fitted on)")
    if sp.fit_inducing is not None or sp.optimize_inducing:
        key = "fit_inducing" if sp.fit_inducing is not None else "optimize_inducing"
        raise ConfigError(f"model.sparse.{key}: not used by model.sparse.fit_objective exact_subset (the exact "
                          "evidence has no inducing inputs)")


def config_from_dict(raw: dict) -> Config:
    """Validate a plain mapping (as read from YAML) into a :class:`Config`; raises :class:`ConfigError`."""
    if isinstance(raw, dict):
        _check_model_kinds(raw.get("model"))
    cfg = _build(Config, raw)
    _cross_check(cfg)
    return cfg


def config_to_dict(cfg: Any) -> dict:
    """Plain nested ``dict`` of a config or one of its sections (YAML/JSON serialisable) that
    :func:`config_from_dict` reads back: the model section keeps only the settings of its own kind, and options
    that are off (``data.surfaces`` null, ``filter.adaptive_noise`` none, ``filter.estimate_omega`` false, a null
    ``filter.surface_measurement_noise``, ``filter.model_error`` none, the default USQUE variant, a zero
    ``scenario.initial_omega_error_deg_s``, the sparse fit's default objective, optimizer, precision, subset,
    inducing count and form) are left out."""
    out = dataclasses.asdict(cfg)
    model = out.get("model") if isinstance(cfg, Config) else out if isinstance(cfg, ModelConfig) else None
    for section in MODEL_KIND_SECTIONS if model is not None else ():
        if section != model["kind"]:
            del model[section]
    # options that are off are absent, not null: configs without them keep their cache, model and case keys
    data = out.get("data") if isinstance(cfg, Config) else out if isinstance(cfg, DataConfig) else None
    if data is not None and data.get("surfaces") is None:
        del data["surfaces"]
    filt = out.get("filter") if isinstance(cfg, Config) else out if isinstance(cfg, FilterConfig) else None
    if filt is not None and filt.get("adaptive_noise") == "none":
        del filt["adaptive_noise"], filt["adaptive_noise_time_s"]
    geo = out.get("geometry") if isinstance(cfg, Config) else out if isinstance(cfg, GeometryConfig) else None
    if geo is not None:
        for key in _ORBIT_ONLY + ("kind",) if geo["kind"] == "fixed" else _FIXED_ONLY:
            del geo[key]
    body_geometry = model is not None and model["inputs"] == "body_geometry"
    if model is not None and not body_geometry:
        del model["reference_range_km"]
    if data is not None and not (body_geometry or (isinstance(cfg, DataConfig))):
        del data["phase_angle_deg"]
    if filt is not None and filt.get("inertia_kg_m2", 0) is None:
        del filt["inertia_kg_m2"]
    if filt is not None and filt.get("surface_measurement_noise", 0) is None:
        del filt["surface_measurement_noise"]
    if filt is not None and filt.get("model_error") == "none":
        del filt["model_error"]
    if filt is not None and not filt.get("estimate_omega", True):
        del filt["estimate_omega"], filt["p0_omega_deg_s"], filt["omega_process_noise"]
    if filt is not None and not filt.get("sigma_redraw", True) and filt.get("q_placement") == "both":
        del filt["sigma_redraw"], filt["q_placement"]
    if filt is not None and not filt.get("compile", True):
        del filt["compile"]
    scen = out.get("scenario") if isinstance(cfg, Config) else out if isinstance(cfg, ScenarioConfig) else None
    if scen is not None and not any(scen.get("initial_omega_error_deg_s", [1.0])):
        del scen["initial_omega_error_deg_s"]
    sparse = model.get("sparse") if model is not None else None
    for key, default in _SPARSE_FIT_DEFAULTS.items() if sparse is not None else ():
        if sparse[key] == default:
            del sparse[key]
    return out


#: options of the sparse fit left out of :func:`config_to_dict` at their defaults (today's fit keeps its keys)
_SPARSE_FIT_DEFAULTS = {"optimizer": "adam", "fit_dtype": "float64", "fit_subset": None, "fit_inducing": None,
                        "fit_objective": "sparse_bound", "fit_form": "gpytorch"}


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

    Args:
        path: YAML file.
        overrides: ``["section.key=value", ...]``; values are parsed as YAML.

    Raises:
        ConfigError: missing file, invalid YAML, unknown key, wrong type or out-of-range value, a bad mesh.
    """
    cfg = config_from_dict(load_raw_config(path, overrides))
    if cfg.shape.mesh_path:
        check_mesh(cfg.shape.mesh_path)
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


def _check_mesh_file(mesh_path: str) -> None:
    if not os.path.isfile(mesh_path):
        raise ConfigError(f"shape.mesh_path: {mesh_path!r} does not exist or is not a file")


def check_mesh(mesh_path: str) -> None:
    """Raise :class:`ConfigError` naming ``shape.mesh_path`` unless the file exists, trimesh reads it and it has
    triangles of positive area."""
    _check_mesh_file(mesh_path)
    from lightcurve_gp.photometry.shapes import load_mesh  # trimesh is only needed when a mesh is named

    try:
        load_mesh(mesh_path)
    except (ValueError, OSError) as exc:
        raise ConfigError(f"shape.mesh_path: {' '.join(str(exc).split())}") from None


def config_hash(cfg: Config, *sections: str, extra: Any = None) -> str:
    """Stable 16-hex-digit hash of the named sections (all of ``cfg`` when none), for on-disk caches.

    Args:
        cfg: a validated config.
        sections: top-level section names, e.g. ``"shape", "surface", "geometry", "data"``.
        extra: any JSON-serialisable value mixed into the hash (a format version, say).
    """
    full = config_to_dict(cfg)
    chosen = {s: full[s] for s in sections} if sections else full
    blob = json.dumps({"sections": chosen, "extra": extra}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def content_dict(cfg: Config, *sections: str) -> dict:
    """The named sections as a plain dict with files replaced by their contents' hash: ``shape.mesh_path`` becomes
    ``shape.mesh_sha256`` (``None`` without a mesh). Two configs with equal content dicts give the same data and
    model wherever the files live; editing a mesh in place changes it."""
    full = config_to_dict(cfg)
    chosen = {s: full[s] for s in sections} if sections else full
    if "shape" in chosen:
        from lightcurve_gp.files import file_sha256

        shape = dict(chosen["shape"])
        path = shape.pop("mesh_path")
        if path and cfg.shape.kind == "mesh":
            _check_mesh_file(path)
            shape["mesh_sha256"] = file_sha256(path)
        else:
            shape["mesh_sha256"] = None
        chosen["shape"] = shape
    return chosen


def content_hash(cfg: Config, *sections: str, extra: Any = None) -> str:
    """:func:`config_hash` of :func:`content_dict`: the cache key of anything computed from these sections."""
    blob = json.dumps({"sections": content_dict(cfg, *sections), "extra": extra}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]
