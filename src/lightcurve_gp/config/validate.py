"""A mapping (YAML as read) validated into a :class:`~lightcurve_gp.config.schema.Config`, every error naming its key.

Two passes: each value is converted to its field's type and checked against the field's metadata (ranges, allowed
strings, list lengths), then the settings that constrain each other are checked together (the model
kind's own section, the geometry's keys, the training spins and surfaces, the sparse fit's options, the filter's
states). The first violation is raised as ``ConfigError("surface.rho: 1.4 is outside [0, 1]")``.
"""

from __future__ import annotations

import dataclasses
import math
import re
import types
import typing
from typing import Any

from lightcurve_gp.config.parsing import check_tle, parse_utc
from lightcurve_gp.config.schema import MODEL_KIND_SECTIONS, Config, ConfigError, SparseModelConfig, SpinRangeConfig

__all__ = ["config_from_dict"]


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
    if cfg.filter.compile and cfg.filter.update_iterations > 1:
        raise ConfigError(f"filter.update_iterations: {cfg.filter.update_iterations} is not supported with "
                          "filter.compile true (the compiled step has the ordinary update only)")
    _check_training_surfaces(cfg)
    _check_geometry(cfg)
    if cfg.model.inputs == "body_geometry" and cfg.data.surfaces is not None:
        raise ConfigError("model.inputs: body_geometry is not supported with data.surfaces")
    lo_phase, hi_phase = cfg.data.phase_angle_deg
    if not lo_phase < hi_phase:
        raise ConfigError(f"data.phase_angle_deg: low {lo_phase:g} must be below high {hi_phase:g}")
    if cfg.convex is not None and not cfg.convex.period_range_h[0] < cfg.convex.period_range_h[1]:
        lo_p, hi_p = cfg.convex.period_range_h
        raise ConfigError(f"convex.period_range_h: shortest {lo_p:g} must be below longest {hi_p:g}")




def _check_geometry(cfg: Config) -> None:
    """The keys of ``geometry.kind``: a fixed Sun and observer, or an orbit, a site and a start time."""
    geo = cfg.geometry
    if geo.kind == "fixed":
        for key in ("observer_km", "sun_km"):
            if getattr(geo, key) is None:
                raise ConfigError(f"geometry.{key}: required when geometry.kind is fixed")
        return
    if (geo.tle is None) == (geo.elements is None):
        raise ConfigError("geometry.tle: give exactly one of geometry.tle and geometry.elements for an orbit")
    for key in ("site", "start_utc"):
        if getattr(geo, key) is None:
            raise ConfigError(f"geometry.{key}: required when geometry.kind is orbit")
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

