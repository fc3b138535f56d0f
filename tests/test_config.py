"""Config loading: the paper's numbers come from the YAML, and every bad value is reported with its key path."""

from pathlib import Path

import pytest
import yaml

from lightcurve_gp.config.load import ConfigError, apply_overrides, config_from_dict, config_hash, load_config

ROOT = Path(__file__).resolve().parents[1]
BOXWING = ROOT / "configs" / "boxwing.yaml"


def raw_config() -> dict:
    return yaml.safe_load(BOXWING.read_text())


def test_default_config_holds_the_papers_setup():
    cfg = load_config(BOXWING)
    assert cfg.shape.inertia_kg_m2 == [55.0, 40.0, 65.0]
    assert cfg.data.rho_grid == [0.1, 0.3, 0.5, 0.7, 0.9]
    assert cfg.geometry.sun_km == pytest.approx([1.2975e8, -0.3461e8, -0.6592e8])
    assert (cfg.model.theta1, cfg.model.theta2, cfg.model.noise_std) == (1.0, 0.25, 0.1)
    assert (cfg.filter.alpha, cfg.filter.beta, cfg.filter.lam, cfg.filter.kappa) == (1e-4, 2.0, 0.0, 0.0)
    assert cfg.scenario.initial_error_deg == [-10.0, 5.0, -10.0]
    assert cfg.evaluation.rmse_window_s == [400.0, 600.0]


@pytest.mark.parametrize(
    "override, message",
    [
        ("scenario.rho_true=1.4", "scenario.rho_true: 1.4 is outside (0, 1]"),
        ("scenario.rho_true=0", "scenario.rho_true: 0 is outside (0, 1]"),
        ("filter.rho_assumed=0", "filter.rho_assumed: 0 is outside (0, 1]"),
        ("data.rho_grid=[0, 0.5]", "data.rho_grid[0]: 0 is outside (0, 1]"),
        ("name=\"\"", "name: '' is not a safe folder name"),
        ("name=../escaped", "name: '../escaped' is not a safe folder name"),
        ("name=.hidden", "name: '.hidden' is not a safe folder name"),
        ("surface.f0=-0.1", "surface.f0: -0.1 is outside [0, 1]"),
        ("shape.box_m=[1, -1, 1]", "shape.box_m[1]: -1 must be > 0"),
        ("scenario.noise_var=-0.5", "scenario.noise_var: -0.5 must be > 0"),
        ("data.dt_s=0", "data.dt_s: 0 must be > 0"),
        ("scenario.dt_s=-1", "scenario.dt_s: -1 must be > 0"),
        ("model.kind=fancy", "model.kind: 'fancy' is not one of exact, sparse"),
        ("model.noise_std=-1", "model.noise_std: -1 must be > 0"),
        ("filter.bogus=1", "filter.bogus: unknown key"),
        ("scenario.seeds=2.5", "scenario.seeds: expected an integer, got 2.5"),
        ("data.drop_duplicates=3", "data.drop_duplicates: expected true or false, got 3"),
        ("geometry.sun_km=[1, 2]", "geometry.sun_km: expected 3 values, got 2"),
        ("filter.rho_assumed=abc", "filter.rho_assumed: expected a number, got 'abc'"),
        ("surface.f0=.nan", "surface.f0: nan is not finite"),
        ("evaluation.rmse_window_s=[600, 400]", "evaluation.rmse_window_s: start 600 must be before end 400"),
        ("shape.kind=mesh", "shape.mesh_path: required when shape.kind is 'mesh'"),
        ("device=gpu", "device: 'gpu' is not cpu, cuda or cuda:N"),
    ],
)
def test_bad_values_name_their_key_path(override, message):
    with pytest.raises(ConfigError) as info:
        load_config(BOXWING, overrides=[override])
    assert message in str(info.value)


def test_missing_key_is_reported():
    raw = raw_config()
    del raw["surface"]["f0"]
    with pytest.raises(ConfigError, match=r"^surface\.f0: missing key$"):
        config_from_dict(raw)
    raw = raw_config()
    del raw["filter"]
    with pytest.raises(ConfigError, match=r"^filter: missing key$"):
        config_from_dict(raw)


def test_overrides_parse_yaml_values_and_create_nothing_silently():
    cfg = load_config(BOXWING, overrides=["data.t_span_past=10", "data.rho_grid=[0.2, 0.4]", "model.kind=sparse"])
    assert cfg.data.t_span_past == 10.0 and isinstance(cfg.data.t_span_past, float)
    assert cfg.data.rho_grid == [0.2, 0.4]
    assert cfg.model.kind == "sparse"
    with pytest.raises(ConfigError, match="expected key.path=value"):
        apply_overrides({}, ["data.t_span_past"])
    with pytest.raises(ConfigError, match="surface.f0: is a value, not a section"):
        apply_overrides(raw_config(), ["surface.f0.x=1"])


def test_exponent_without_dot_is_a_number():
    cfg = load_config(BOXWING, overrides=["filter.process_noise=1e-6"])
    assert cfg.filter.process_noise == 1e-6


def test_missing_file_and_invalid_yaml(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_config(tmp_path / "nope.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("surface: [unclosed\n")
    with pytest.raises(ConfigError, match="invalid YAML"):
        load_config(bad)


def test_config_hash_depends_only_on_named_sections():
    base = load_config(BOXWING)
    other_filter = load_config(BOXWING, overrides=["filter.process_noise=0.5"])
    other_data = load_config(BOXWING, overrides=["data.t_span_past=10"])
    assert config_hash(base, "data") == config_hash(other_filter, "data")
    assert config_hash(base, "data") != config_hash(other_data, "data")
    assert config_hash(base) != config_hash(other_filter)
    assert config_hash(base, "data", extra=1) != config_hash(base, "data", extra=2)


def test_empty_file_and_folder_are_named_as_such(tmp_path):
    empty = tmp_path / "empty.yaml"
    empty.write_text("")
    with pytest.raises(ConfigError) as info:
        load_config(empty)
    assert str(info.value) == (f"config file {str(empty)!r} is empty (expected the sections of "
                               f"configs/boxwing.yaml)")
    with pytest.raises(ConfigError) as info:
        load_config(tmp_path)
    assert str(info.value) == f"config file {str(tmp_path)!r} is a folder, not a YAML file"


def _box_obj(path: Path, size: float = 1.0) -> Path:
    import trimesh

    trimesh.creation.box(extents=[size, size, size]).export(path)
    return path


def test_mesh_path_is_checked_at_load_and_resolves_against_the_config_folder(tmp_path, monkeypatch):
    folder = tmp_path / "configs"
    folder.mkdir()
    _box_obj(folder / "box.obj")
    raw = raw_config()
    raw["shape"].update(kind="mesh", mesh_path="box.obj")
    (folder / "mesh.yaml").write_text(yaml.safe_dump(raw))
    monkeypatch.chdir(tmp_path)  # the mesh is not in the working directory
    cfg = load_config(folder / "mesh.yaml")
    assert Path(cfg.shape.mesh_path) == folder / "box.obj"
    # an override is relative to the working directory
    with pytest.raises(ConfigError) as info:
        load_config(folder / "mesh.yaml", ["shape.mesh_path=box.obj"])
    assert str(info.value) == f"shape.mesh_path: {str(tmp_path / 'box.obj')!r} does not exist or is not a file"


@pytest.mark.parametrize("content, message", [
    (None, "does not exist or is not a file"),
    ("", "mesh is empty (no triangles)"),
    ("this is not a mesh\n", "mesh is empty (no triangles)"),
])
def test_bad_meshes_are_config_errors(tmp_path, content, message):
    mesh = tmp_path / "object.obj"
    if content is not None:
        mesh.write_text(content)
    with pytest.raises(ConfigError) as info:
        load_config(BOXWING, ["shape.kind=mesh", f"shape.mesh_path={mesh}"])
    assert str(info.value).startswith("shape.mesh_path: ") and message in str(info.value)


def test_content_hash_follows_the_mesh_file_not_its_path(tmp_path):
    from lightcurve_gp.config.load import content_hash
    from lightcurve_gp.training.sets import data_cache_key
    from lightcurve_gp.training.store import model_key

    mesh = _box_obj(tmp_path / "object.obj")
    cfg = load_config(BOXWING, ["shape.kind=mesh", f"shape.mesh_path={mesh}"])
    keys = (data_cache_key(cfg), model_key(cfg), content_hash(cfg, "shape"))
    _box_obj(mesh, size=2.0)  # edited in place: same path, other content
    assert all(a != b for a, b in zip(keys, (data_cache_key(cfg), model_key(cfg), content_hash(cfg, "shape"))))
    copy = tmp_path / "copy.obj"
    copy.write_bytes(mesh.read_bytes())  # same content elsewhere: same keys
    moved = load_config(BOXWING, ["shape.kind=mesh", f"shape.mesh_path={copy}"])
    assert (data_cache_key(moved), model_key(moved)) == (data_cache_key(cfg), model_key(cfg))
