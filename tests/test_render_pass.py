"""Renderer with per-sample geometry: sample by sample equal to the fixed renderer; the fixed limit unchanged."""

from pathlib import Path

import pytest
import torch

from lightcurve_gp.config.load import load_config
from lightcurve_gp.photometry.brdf import Surface
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.photometry.shapes import facets_from_config

BOXWING = Path(__file__).resolve().parents[1] / "configs" / "boxwing.yaml"
F64 = torch.float64


def _unit(x):
    return x / x.norm(dim=-1, keepdim=True)


@pytest.fixture(scope="module")
def per_sample():
    cfg = load_config(BOXWING)
    facets = facets_from_config(cfg, rho=0.5)
    gen = torch.Generator().manual_seed(4)
    T = 40
    sun = torch.randn(T, 3, generator=gen, dtype=F64)
    observer = _unit(sun) + 1.5 * _unit(torch.randn(T, 3, generator=gen, dtype=F64))  # phase angles 0-~120 deg
    r_obs = 3.6e7 + 1e6 * torch.rand(T, generator=gen, dtype=F64)
    q = _unit(torch.randn(3, T, 4, generator=gen, dtype=F64))
    return facets, Scene(facets, sun, observer, r_obs), q


def test_per_sample_equals_fixed_sample_by_sample(per_sample):
    facets, scene, q = per_sample
    m = scene.magnitude(q)  # (3, T)
    for k in range(q.shape[1]):
        fixed = Scene(facets, scene.sun[k] * 7.0, scene.observer[k] * 3.0, float(scene.r_obs[k]))
        assert torch.allclose(m[:, k], fixed.magnitude(q[:, k]), rtol=0, atol=1e-12, equal_nan=True)
        assert torch.allclose(m[:, k], scene.sample(k).magnitude(q[:, k]), rtol=0, atol=1e-12, equal_nan=True)
    assert scene.phase_angle_deg.shape == (q.shape[1],)


def test_per_sample_rho_and_surface_and_chunking(per_sample):
    facets, scene, q = per_sample
    rho = torch.tensor([[0.2], [0.9]], dtype=F64).unsqueeze(-1)  # (2, 1, 1) against (3, T)
    m = scene.magnitude(q, rho=rho)
    small = Scene(facets, scene.sun, scene.observer, scene.r_obs, chunk_elements=100)
    assert torch.allclose(small.magnitude(q, rho=rho), m, rtol=0, atol=1e-12, equal_nan=True)
    surf = Surface(*(torch.tensor(v, dtype=F64) for v in ([0.3, 0.6, 0.9], [0.1, 0.5, 0.8], [10.0, 800, 3e3],
                                                           [20.0, 800, 1e3])))
    m_s = scene.magnitude(q, surface=surf)
    for k in (0, 17):
        fixed = scene.sample(k)
        assert torch.allclose(m_s[:, k], fixed.magnitude(q[:, k], surface=surf), rtol=0, atol=1e-12, equal_nan=True)


def test_per_sample_needs_samples_last(per_sample):
    _, scene, q = per_sample
    with pytest.raises(ValueError, match="needs them along the last batch dimension"):
        scene.magnitude(q[:, :5])


def test_fixed_geometry_limit_is_todays_renderer():
    """A per-sample scene with the paper's geometry at every sample gives today's fixed-scene numbers."""
    cfg = load_config(BOXWING)
    fixed = Scene.from_config(cfg, rho=0.5)
    T = 25
    q = _unit(torch.randn(T, 4, generator=torch.Generator().manual_seed(1), dtype=F64))
    repeated = Scene(fixed.facets, fixed.sun.expand(T, 3), fixed.observer.expand(T, 3),
                     torch.full((T,), fixed.r_obs, dtype=F64))
    assert torch.allclose(repeated.magnitude(q), fixed.magnitude(q), rtol=0, atol=1e-9)
    assert fixed.magnitude(torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=F64)).item() == pytest.approx(13.294, abs=1e-3)
