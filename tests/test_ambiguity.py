"""The exact ambiguity group: every image reproduces a light curve to 1e-9 mag on trajectories the derivation never
saw, a non-image does not, the body images fall away when ω is known and the inertial ones along a moving pass."""

from pathlib import Path

import pytest
import torch

from lightcurve_gp.attitude.dynamics import propagate
from lightcurve_gp.attitude.rotations import attitude_matrix, axis_angle_to_quat, quat_mul
from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.config.load import load_config
from lightcurve_gp.passes.geometry import pass_geometry
from lightcurve_gp.photometry.ambiguity import INERTIAL_TURNS, ambiguity_group, inertial_turns
from lightcurve_gp.photometry.render import Scene

ROOT = Path(__file__).resolve().parents[1]
T = 300


@pytest.fixture(scope="module")
def fixed():
    cfg = load_config(ROOT / "configs" / "boxwing.yaml")
    scene = Scene.from_config(cfg, rho=0.5)
    times = torch.arange(T + 1, dtype=torch.float64)
    inertia = torch.tensor(cfg.shape.inertia_kg_m2, dtype=torch.float64)
    return scene, times, inertia


def _curves(scene, q0, omega0, inertia, n=T):
    q, _ = propagate(q0, omega0, inertia, 1.0, n)
    return scene.magnitude(q)


def _fresh_states(n=3, seed=11):
    """Trajectories the derivation's probes never saw: other attitudes, other rates (0.5-4 deg/s)."""
    g = torch.Generator().manual_seed(seed)
    axes = torch.randn(n, 3, generator=g, dtype=torch.float64)
    rates = torch.deg2rad(0.5 + 3.5 * torch.rand(n, 1, generator=g, dtype=torch.float64))
    return random_attitudes(n, seed=seed, dtype=torch.float64), rates * axes / axes.norm(dim=-1, keepdim=True)


def test_inertial_turns_preserve_the_sun_observer_pair():
    sun = torch.nn.functional.normalize(torch.tensor([1.0, 0.2, -0.4], dtype=torch.float64), dim=0)
    obs = torch.nn.functional.normalize(torch.tensor([0.3, 1.0, 0.1], dtype=torch.float64), dim=0)
    identity, normal, bisector, perpendicular = inertial_turns(sun, obs)
    assert INERTIAL_TURNS[2] == "bisector"
    torch.testing.assert_close(identity, torch.eye(3, dtype=torch.float64))
    torch.testing.assert_close(normal @ sun, -sun)  # both negated
    torch.testing.assert_close(normal @ obs, -obs)
    torch.testing.assert_close(bisector @ sun, obs)  # swapped
    torch.testing.assert_close(perpendicular @ sun, -obs)  # swapped and negated
    for m in (normal, bisector, perpendicular):
        torch.testing.assert_close(m @ m, torch.eye(3, dtype=torch.float64))
        assert abs(float(torch.linalg.det(m)) - 1.0) < 1e-12


def test_rate_unknown_sixteen_images_reproduce_fresh_curves(fixed):
    scene, times, inertia = fixed
    group = ambiguity_group(scene, times_s=times, inertia=inertia, rate_known=False)
    assert len(group) == 16 and group.labels[0] == "body identity · inertial identity"
    q0, w0 = _fresh_states()
    reference = _curves(scene, q0, w0, inertia)
    images = _curves(scene, group.attitudes(q0), group.rates(w0), inertia)  # (16, 3, T+1)
    assert float((images - reference).abs().max()) < 1e-9
    # the images of the whole trajectory are the trajectories of the images (right products commute with Δ(t))
    q, _ = propagate(q0, w0, inertia, 1.0, T)
    q_img, _ = propagate(group.attitudes(q0), group.rates(w0), inertia, 1.0, T)
    dot = (q_img * group.attitudes(q)).sum(-1).abs()
    assert float((1.0 - dot).abs().max()) < 1e-12


def test_a_non_image_changes_the_curve(fixed):
    scene, times, inertia = fixed
    q0, w0 = _fresh_states()
    q90 = axis_angle_to_quat(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), torch.tensor(torch.pi / 2))
    r90 = attitude_matrix(q90)
    other = _curves(scene, quat_mul(q90, q0), w0 @ r90.T, inertia)
    assert float((other - _curves(scene, q0, w0, inertia)).pow(2).mean().sqrt()) > 0.05


def test_rate_known_keeps_only_the_inertial_images(fixed):
    scene, times, inertia = fixed
    group = ambiguity_group(scene, times_s=times, inertia=inertia, rate_known=True)
    assert group.labels == tuple(f"body identity · inertial {name}" for name in INERTIAL_TURNS)
    torch.testing.assert_close(group.rates(torch.tensor([0.01, 0.02, 0.03], dtype=torch.float64))[3],
                               torch.tensor([0.01, 0.02, 0.03], dtype=torch.float64))
    # a body turn with the rate kept is not exact: the curves differ by a tenth of a magnitude or more
    q0, w0 = _fresh_states()
    flip = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=torch.float64)  # 180° about body x
    rms = (_curves(scene, quat_mul(flip, q0), w0, inertia) - _curves(scene, q0, w0, inertia)).pow(2).mean(-1).sqrt()
    assert float(rms.min()) > 0.05


def test_a_moving_pass_breaks_the_inertial_images():
    cfg = load_config(ROOT / "configs" / "geo_pass.yaml",
                      overrides=["scenario.duration_s=600", "evaluation.rmse_window_s=[400, 600]"])
    geometry = pass_geometry(cfg)
    scene = Scene.from_config(cfg, rho=0.5).with_geometry(geometry.sun, geometry.observer, geometry.range_m)
    group = ambiguity_group(scene, times_s=geometry.times_s - geometry.times_s[0],
                            inertia=cfg.shape.inertia_kg_m2, rate_known=False)
    assert group.labels == ("body identity · inertial identity", "body 180° x · inertial identity",
                            "body 180° y · inertial identity", "body 180° z · inertial identity")


def test_bad_times_are_refused_and_irregular_ones_taken(fixed):
    scene, _, inertia = fixed
    with pytest.raises(ValueError, match=r"times_s: expected strictly increasing sample times \(s\)"):
        ambiguity_group(scene, times_s=torch.tensor([0.0, 2.0, 2.0]), inertia=inertia, rate_known=True)
    irregular = ambiguity_group(scene, times_s=torch.tensor([3.0, 3.5, 5.0, 10.3, 33.1, 95.0]), inertia=inertia,
                                rate_known=True)
    assert irregular.labels == ambiguity_group(scene, times_s=torch.arange(93.0), inertia=inertia,
                                               rate_known=True).labels
