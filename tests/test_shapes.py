"""Facet models: the paper's box-wing from the config, mesh loading and its errors, tangent axes."""

from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from lightcurve_gp.config.load import load_config
from lightcurve_gp.photometry.shapes import Facets, facets_from_config, facets_from_mesh, load_mesh, tangent_axes

BOXWING = Path(__file__).resolve().parents[1] / "configs" / "boxwing.yaml"


@pytest.fixture(scope="module")
def cfg():
    return load_config(BOXWING)


@pytest.fixture(scope="module")
def facets(cfg):
    return facets_from_config(cfg, rho=0.5)


def test_box_wing_counts_and_area(facets):
    assert len(facets) == 472
    assert float(facets.total_area) == pytest.approx(16.4, abs=1e-12)


def test_box_wing_normals_are_unit_and_outward(cfg, facets):
    assert torch.allclose(facets.normals.norm(dim=-1), torch.ones(472, dtype=torch.float64), atol=1e-14)
    c = facets.centroids
    # facets come in order: box (192), +y wing (140), -y wing (140); outwardness is measured from each part's centre
    wing_y = cfg.shape.box_m[1] / 2 + cfg.shape.wing_m[1] / 2
    centre = torch.zeros_like(c)
    centre[192:332, 1], centre[332:, 1] = wing_y, -wing_y
    assert bool((c[192:332, 1] > 0).all()) and bool((c[332:, 1] < 0).all())
    assert bool(((facets.normals * (c - centre)).sum(-1) > 0).all())


def test_tangent_axes_orthonormal_and_function_of_normal(facets):
    n, u, v = facets.normals, facets.u, facets.v
    assert float((n * u).sum(-1).abs().max()) < 1e-14
    assert torch.allclose(u.norm(dim=-1), torch.ones(len(n), dtype=n.dtype))
    assert torch.allclose(v, torch.linalg.cross(n, u, dim=-1), atol=1e-15)
    groups, index = facets.grouped()
    assert len(groups) == 6 and torch.allclose(groups.areas[index].new_tensor(
        [float(facets.areas[index == g].sum()) for g in range(6)]), groups.areas)
    assert torch.equal(groups.u[index], u) and torch.equal(groups.normals[index], n)
    rnd = torch.nn.functional.normalize(torch.randn(50, 3, dtype=torch.float64), dim=-1)
    u2, v2 = tangent_axes(rnd)
    assert float((rnd * u2).sum(-1).abs().max()) < 1e-14 and float((u2 * v2).sum(-1).abs().max()) < 1e-14


def test_surface_parameters_replace_and_move(facets):
    f = facets.with_surface(rho=0.3, n_u=100.0)
    assert bool((f.rho == 0.3).all()) and bool((f.n_u == 100.0).all()) and bool((f.f0 == facets.f0).all())
    assert bool((facets.rho == 0.5).all())  # the original is unchanged (frozen)
    g = f.to(dtype=torch.float32)
    assert g.normals.dtype == torch.float32 and len(g) == 472
    with pytest.raises(ValueError, match="areas"):
        Facets(**{**{k: getattr(facets, k) for k in ("normals", "centroids", "u", "v", "rho", "f0", "n_u", "n_v")},
                  "areas": facets.areas[:3]})


def _tetra() -> trimesh.Trimesh:
    return trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]],
                           faces=[[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], process=False)


@pytest.mark.parametrize("suffix", ["obj", "stl", "ply"])
def test_load_mesh_formats(tmp_path, suffix):
    path = tmp_path / f"tetra.{suffix}"
    _tetra().export(path)
    mesh = load_mesh(path)
    f = facets_from_mesh(mesh, rho=0.5, f0=0.5, n_u=800.0, n_v=800.0)
    assert len(f) == 4
    assert float(f.total_area) == pytest.approx(1.5 + np.sqrt(3) / 2, rel=1e-6)
    centre = torch.full((3,), 0.25, dtype=torch.float64)
    assert bool(((f.normals * (f.centroids - centre)).sum(-1) > 0).all())


def test_config_mesh_kind(tmp_path, cfg):
    path = tmp_path / "tetra.obj"
    _tetra().export(path)
    mesh_cfg = load_config(BOXWING, overrides=["shape.kind=mesh", f"shape.mesh_path={path}"])
    assert len(facets_from_config(mesh_cfg, rho=0.1)) == 4


def test_load_mesh_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_mesh(tmp_path / "nothing.obj")
    empty = tmp_path / "empty.obj"
    empty.write_text("# no geometry\n")
    with pytest.raises(ValueError, match="empty"):
        load_mesh(empty)
    degenerate = tmp_path / "degenerate.obj"
    degenerate.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 2 0 0\nf 1 2 3\nf 1 2 4\n")  # second face is a line
    with pytest.raises(ValueError, match="zero-area"):
        load_mesh(degenerate)
    with pytest.raises(ValueError, match="degenerate"):
        facets_from_mesh(trimesh.Trimesh(vertices=[[0, 0, 0], [1, 0, 0], [2, 0, 0]], faces=[[0, 1, 2]],
                                         process=False), rho=0.5, f0=0.5, n_u=1.0, n_v=1.0)
