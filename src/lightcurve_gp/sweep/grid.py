"""Sweep grids: parsing ``--grid KEY=V1,V2,...``, the cartesian product of the axes and one validated case per point."""

from __future__ import annotations

import itertools
import json
from dataclasses import dataclass
from typing import Any, Sequence

import yaml

from lightcurve_gp.config.load import (
    Config,
    ConfigError,
    apply_overrides,
    check_device,
    check_mesh,
    config_from_dict,
    config_hash,
    config_to_dict,
)
from lightcurve_gp.evaluation.registry import DEFAULT_ESTIMATORS, ESTIMATORS
from lightcurve_gp.evaluation.reporting import CASE_FORMAT
from lightcurve_gp.training.store import MODEL_SECTIONS, model_key

__all__ = ["MODEL_SECTIONS", "Case", "parse_grid", "expand_grid", "make_cases", "model_key", "value_text"]



def parse_grid(text: str) -> tuple[str, list[Any]]:
    """``"data.t_span_past=10,20,30"`` → ``("data.t_span_past", [10, 20, 30])``.

    The value list is read as a YAML flow sequence, so ``"x=[1, 2],[3, 4]"`` gives two list values and
    ``"x=true,null"`` gives ``[True, None]``.

    Raises:
        ConfigError: no ``=``, an empty key or value list, or unparsable values.
    """
    if "=" not in text:
        raise ConfigError(f"--grid {text!r}: expected key.path=value1,value2,...")
    key, _, values = text.partition("=")
    key = key.strip()
    if not key or any(not part for part in key.split(".")):
        raise ConfigError(f"--grid {text!r}: empty key")
    if not values.strip():
        raise ConfigError(f"--grid {text!r}: no values after '='")
    try:
        parsed = yaml.safe_load(f"[{values}]")
    except yaml.YAMLError as exc:
        raise ConfigError(f"{key}: cannot parse grid values {values!r}: {exc}") from None
    if not isinstance(parsed, list) or not parsed:
        raise ConfigError(f"{key}: cannot parse grid values {values!r}")
    return key, parsed


def expand_grid(axes: Sequence[tuple[str, Sequence[Any]]]) -> list[dict[str, Any]]:
    """Cartesian product of the axes ``[(key, values), ...]``: one ``{key: value}`` dict per grid point, the last
    axis varying fastest. No axes give one empty point. A key given twice raises :class:`ConfigError`."""
    keys = [k for k, _ in axes]
    for k in keys:
        if keys.count(k) > 1:
            raise ConfigError(f"{k}: grid axis given more than once")
    for k, values in axes:
        if len(values) == 0:
            raise ConfigError(f"{k}: grid axis without values")
    return [dict(zip(keys, combo)) for combo in itertools.product(*(list(v) for _, v in axes))]


def _override_text(key: str, value: Any) -> str:
    return f"{key}={json.dumps(value)}"  # JSON is YAML: the value round-trips exactly


def value_text(value: Any) -> str:
    """A grid value as written in tables: strings as they are, anything else as JSON."""
    return value if isinstance(value, str) else json.dumps(value)


@dataclass
class Case:
    """One grid point: its values, validated config, content hash and the model-store key
    (:func:`lightcurve_gp.training.store.model_key`) of the model it needs."""

    values: dict[str, Any]
    config: Config
    case_id: str
    model_hash: str | None


def _case_key(cfg: Config, seeds: Sequence[int], estimators: Sequence[str]) -> str:
    sections = [k for k in config_to_dict(cfg) if k != "name"]
    return config_hash(cfg, *sections, extra={"seeds": list(seeds), "estimators": list(estimators),
                                              "format": CASE_FORMAT})


def make_cases(raw: dict, axes: Sequence[tuple[str, Sequence[Any]]], seeds: Sequence[int],
               estimators: Sequence[str] = DEFAULT_ESTIMATORS) -> list[Case]:
    """Validate every grid point of ``axes`` applied to the raw config mapping ``raw`` (a mesh and the device are
    checked as :func:`~lightcurve_gp.config.load.load_config` checks them).

    Raises:
        ConfigError: an unknown key or invalid value; the message names the key (and the grid point).
    """
    unknown = [e for e in estimators if e not in ESTIMATORS]
    if unknown:
        raise ConfigError(f"estimators: unknown estimator {unknown[0]!r}; choose from {', '.join(ESTIMATORS)}")
    cases, meshes_checked = [], set()
    for values in expand_grid(axes):
        try:
            cfg = config_from_dict(apply_overrides(raw, [_override_text(k, v) for k, v in values.items()]))
            if cfg.shape.kind == "mesh" and cfg.shape.mesh_path not in meshes_checked:
                check_mesh(cfg.shape.mesh_path)
                meshes_checked.add(cfg.shape.mesh_path)
            check_device(cfg.device)
        except ConfigError as exc:
            where = ", ".join(f"{k}={value_text(v)}" for k, v in values.items())
            raise ConfigError(f"{exc} (grid point {where})" if where else str(exc)) from None
        needs_model = "gpukf" in estimators
        cases.append(Case(values, cfg, _case_key(cfg, seeds, estimators), model_key(cfg) if needs_model else None))
    return cases
