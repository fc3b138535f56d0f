"""Hash rules: the keys of caches, stored models and cases stay what they were, and each rule in the schema's field
metadata leaves its field out exactly when it says."""

import dataclasses
from pathlib import Path

import pytest

from lightcurve_gp.config import schema
from lightcurve_gp.config.hashing import config_hash, config_to_dict
from lightcurve_gp.config.load import load_config
from lightcurve_gp.config.validate import config_from_dict
from lightcurve_gp.training.sets import data_cache_key
from lightcurve_gp.training.store import model_key

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = ROOT / "configs"

#: (config, overrides) -> (config_hash, model_key, data_cache_key), as written by the code before the rules moved
#: into the schema: a changed value here orphans every stored model, training set and case of that config
PINNED = [
    ("boxwing.yaml", [], ("1f1142a17ea833d2", "bc738a4a4cb14cfa", "3be039178bb18c57")),
    ("leo_pass.yaml", [], ("e8475a7985161e0f", "fc4c40fd4666ced6", "e16683e4c2c13c23")),
    ("boxwing_robust.yaml", [], ("e37ad63aff736543", "508ca86371288c96", "52e864d1add54d87")),
    ("boxwing_surface.yaml", [], ("526cd1b06c14f3b4", "939acbebd192f284", "e45868064215f74e")),
    ("boxwing.yaml", ["model.inputs=body_geometry"], ("7c4e5b29b4d2df53", "b166bec94c0a9e18", "ae7a1612c020514a")),
    ("boxwing.yaml", ["model.inputs=attitude_matrix", "filter.estimate_omega=true"],
     ("0705e347e9937d13", "7e7f32ddd7193517", "3be039178bb18c57")),
    ("boxwing.yaml", ["filter.sigma_redraw=true", "filter.q_placement=after"],
     ("d7765f6b707f826c", "bc738a4a4cb14cfa", "3be039178bb18c57")),
]


@pytest.mark.parametrize("name, overrides, keys", PINNED)
def test_keys_are_those_written_before(name, overrides, keys):
    cfg = load_config(CONFIGS / name, overrides)
    assert (config_hash(cfg), model_key(cfg), data_cache_key(cfg)) == keys


#: (overrides, key path, whether config_to_dict keeps it)
RULES = [
    ([], "filter.compile", False),
    (["filter.compile=true"], "filter.compile", True),
    ([], "filter.adaptive_noise_time_s", False),
    (["filter.adaptive_noise_time_s=50"], "filter.adaptive_noise_time_s", False),  # omit_when adaptive_noise none
    (["filter.adaptive_noise=innovation"], "filter.adaptive_noise_time_s", True),
    ([], "filter.sigma_redraw", False),
    (["filter.q_placement=after"], "filter.sigma_redraw", True),  # both fields of one rule come back together
    (["filter.sigma_redraw=true"], "filter.q_placement", True),
    (["filter.p0_omega_deg_s=0.1"], "filter.p0_omega_deg_s", False),
    ([], "model.reference_range_km", False),
    (["model.inputs=body_geometry"], "model.reference_range_km", True),
    ([], "data.phase_angle_deg", False),  # a rule that names another section's key
    (["model.inputs=body_geometry"], "data.phase_angle_deg", True),
    ([], "model.sparse", False),
    (["model.kind=sparse"], "model.exact", False),
    (["model.kind=sparse"], "model.sparse.fit_form", False),
    (["model.kind=sparse", "model.sparse.fit_form=gram"], "model.sparse.fit_form", True),
    ([], "geometry.kind", False),
    ([], "geometry.tle", False),
    ([], "scenario.initial_omega_error_deg_s", False),
    (["scenario.initial_omega_error_deg_s=[0, 0.1, 0]"], "scenario.initial_omega_error_deg_s", True),
]


def _has(tree: dict, path: str) -> bool:
    *parents, last = path.split(".")
    for part in parents:
        tree = tree[part]
    return last in tree


@pytest.mark.parametrize("overrides, path, kept", RULES)
def test_each_rule_leaves_its_field_out_as_the_schema_says(overrides, path, kept):
    raw = config_to_dict(load_config(CONFIGS / "boxwing.yaml", overrides))
    assert _has(raw, path) is kept
    assert config_to_dict(config_from_dict(raw)) == raw  # what is left out reads back as its default


def test_a_section_alone_keeps_a_field_whose_rule_names_another_section():
    cfg = load_config(CONFIGS / "boxwing.yaml")
    assert "phase_angle_deg" not in config_to_dict(cfg)["data"]
    assert config_to_dict(cfg.data)["phase_angle_deg"] == [0.0, 120.0]


def test_every_rule_names_fields_that_exist():
    sections = [c for c in vars(schema).values() if isinstance(c, type) and dataclasses.is_dataclass(c)]
    root = {f.name: f.type for f in dataclasses.fields(schema.Config)}
    checked = 0
    for cls in sections:
        names = {f.name for f in dataclasses.fields(cls)}
        for f in dataclasses.fields(cls):
            for rule in ("omit_when", "omit_unless"):
                for key in f.metadata.get(rule) or {}:
                    head = key.split(".")[0]
                    assert (head in root) if "." in key else (key in names), f"{cls.__name__}.{f.name}: {key}"
                    checked += 1
    assert checked >= 15
