"""The surface-marginal GP (``model.target: surface_normalised``): its target, its spread model, its invariances."""

import dataclasses
import math
from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.rotations import attitude_matrix
from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.config.load import ConfigError, load_config
from lightcurve_gp.observation import SurfaceMarginalGP, load_model, save_model
from lightcurve_gp.observation.surface_marginal import attitude_spread
from lightcurve_gp.photometry.brdf import Surface
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.training.sets import model_targets, normalised_targets
from lightcurve_gp.training.surfaces import (
    draw_surfaces,
    equivalent_reflectance,
    render_over_surfaces,
)

from helpers import DT

ROOT = Path(__file__).resolve().parents[1]
SURFACE_CONFIG = ROOT / "configs" / "boxwing_surface.yaml"


class DiffuseOnly:
    """The renderer with its specular part removed: ``m = −2.5 log10(diffuse flux)``."""

    def __init__(self, scene: Scene):
        self.scene = scene

    def magnitude(self, q, *, surface):
        diffuse, _ = self.scene.flux_parts(q, surface=surface)
        return -2.5 * torch.log10(diffuse)


def test_diffuse_surfaces_normalise_to_the_reference_curve():
    """For a purely diffuse light curve the normalised target of every surface is the reference surface's curve:
    the renderer's diffuse part scales with ρ (1 − F0) (paper Eqs. (4), (8)), so the offset is exact."""
    cfg = load_config(SURFACE_CONFIG, ["data.num_random=64", "data.surfaces.per_attitude=3"])
    scene = DiffuseOnly(Scene.from_config(cfg, dtype=DT))
    q0 = random_attitudes(64, seed=5, dtype=DT)
    surfaces = draw_surfaces(cfg.data.surfaces, (3, 64), seed=2, dtype=DT)
    ts = model_targets(render_over_surfaces(scene, q0, surfaces, cfg), cfg.model)
    one = torch.ones(64, dtype=DT)
    reference = Surface(cfg.model.rho_reference * one, cfg.surface.f0 * one, 800.0 * one, 30.0 * one)
    m_ref = render_over_surfaces(scene, q0, Surface(*(t.unsqueeze(0) for t in reference)), cfg).y
    assert ts.y.shape == (3 * m_ref.shape[0],) and m_ref.shape[0] > 0
    torch.testing.assert_close(ts.y, m_ref.repeat(3), rtol=0, atol=1e-10)
    # and the raw magnitudes do differ between surfaces: the normalisation is what removes the difference
    assert float((ts.y - normalised_targets(ts.y, ts.rho, cfg.model.rho_reference)).abs().max()) > 0.1


def test_equivalent_reflectance_is_the_diffuse_scale():
    s = Surface(torch.tensor([0.2, 0.8], dtype=DT), torch.tensor([0.5, 0.9], dtype=DT), torch.ones(2, dtype=DT),
                torch.ones(2, dtype=DT))
    torch.testing.assert_close(equivalent_reflectance(s, 0.5), torch.tensor([0.2, 0.8 * 0.1 / 0.5], dtype=DT))


def _synthetic(per_attitude: int, n: int = 400, seed: int = 0):
    """Gaussian spreads with a known smooth law: centre ``A₂₂(q)``, ``log s² = −2 + 1.5 A₀₀(q)``."""
    q = random_attitudes(n, seed=seed, dtype=DT)
    A = attitude_matrix(q)
    centre, log_s2 = A[:, 2, 2], -2.0 + 1.5 * A[:, 0, 0]
    gen = torch.Generator().manual_seed(seed + 1)
    y = centre + (0.5 * log_s2).exp() * torch.randn(per_attitude, n, generator=gen, dtype=DT)
    return q, y, log_s2


def _model(per_attitude: int, q: torch.Tensor, y: torch.Tensor) -> SurfaceMarginalGP:
    cfg = load_config(SURFACE_CONFIG).model
    cfg = dataclasses.replace(cfg, sparse=dataclasses.replace(cfg.sparse, num_inducing=q.shape[0]))
    k = per_attitude
    return SurfaceMarginalGP.from_data(q.repeat(k, 1), torch.zeros(k * q.shape[0], dtype=DT), y.reshape(-1), cfg,
                                       per_attitude=k, spread_inducing=q.shape[0])


def test_spread_model_returns_the_spread_on_its_training_attitudes():
    """Each attitude's corrected log s² estimate has the sampling std √ψ'((K−1)/2) (0.57 for K = 8), and the median
    as centre adds at most log(1 + (π/2 − 1)/(K − 1)) = 0.078 (the mean square of mean − median of K normal
    draws). So the smoothed spread must be no farther from the true law than one attitude's own estimate (RMS),
    and unbiased within that excess plus 3 standard errors of a mean over 400 attitudes."""
    k = 8
    q, y, log_s2 = _synthetic(k)
    model = _model(k, q, y)
    _, _, log_s2_hat, sampling_var = attitude_spread(q.repeat(k, 1), y.reshape(-1), k)
    pred = model.spread(q, torch.zeros(400, dtype=DT)).log()
    err = pred - log_s2
    assert sampling_var == pytest.approx(float(torch.special.polygamma(1, torch.tensor(3.5, dtype=DT))))
    assert float(err.pow(2).mean().sqrt()) < math.sqrt(sampling_var)
    assert float((log_s2_hat - log_s2).pow(2).mean().sqrt()) > float(err.pow(2).mean().sqrt())  # it smooths
    assert abs(float(err.mean())) < math.log(1 + (math.pi / 2 - 1) / (k - 1)) + 3 * math.sqrt(sampling_var / 400)


def test_variance_adds_the_spread_and_predictions_are_sign_invariant(tmp_path):
    k = 6
    q, y, _ = _synthetic(k, n=200)
    model = _model(k, q, y)
    qt = random_attitudes(50, seed=9, dtype=DT)
    m0 = torch.zeros(50, dtype=DT)
    mean, var = model(q=qt, m_past=m0, variance="fast")
    latent = model.mean_gp(q=qt, m_past=m0, variance="fast")[1]
    torch.testing.assert_close(var, latent + model.spread(qt, m0))
    mean_neg, var_neg = model(q=-qt, m_past=m0, variance="fast")
    torch.testing.assert_close(mean_neg, mean, rtol=0, atol=1e-12)
    torch.testing.assert_close(var_neg, var, rtol=0, atol=1e-12)
    assert model(q=qt, m_past=m0, variance="none")[1] is None
    loaded = load_model(save_model(model, tmp_path / "model.pt"))
    assert isinstance(loaded, SurfaceMarginalGP)
    torch.testing.assert_close(loaded(q=qt, m_past=m0, variance="fast"), (mean, var), rtol=0, atol=0)


def test_surface_config_errors_name_the_key():
    with pytest.raises(ConfigError, match=r"^data.surfaces: given exactly when model.target is surface_normalised"):
        load_config(SURFACE_CONFIG, ["model.target=rho_normalised"])
    with pytest.raises(ConfigError, match=r"^data.surfaces.f0: 1 leaves no diffuse light"):
        load_config(SURFACE_CONFIG, ["data.surfaces.f0=[0.1, 1.0]"])
    with pytest.raises(ConfigError, match=r"^data.surfaces.rho: low 0.9 is above high 0.1$"):
        load_config(SURFACE_CONFIG, ["data.surfaces.rho=[0.9, 0.1]"])
    with pytest.raises(ConfigError, match=r"^data.surfaces.per_attitude: "):
        load_config(SURFACE_CONFIG, ["data.surfaces.per_attitude=1"])
