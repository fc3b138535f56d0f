"""photometry.spin_images: the half turn is exact for a body symmetric under 180° about its spin axis and not for
one that is not; the mirror is exact when every direction lies in one plane; the image poles against the angular
velocity of the image motion (finite differences); the nats against a hand computation."""

import math

import numpy as np
import pytest
import torch
import trimesh

from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.photometry.shapes import box_wing, facets_from_mesh
from lightcurve_gp.photometry.spin_images import (
    half_turn,
    half_turn_nats,
    image_group,
    mirror_nats,
    mirror_pole,
    nearest_plane_normal,
    profiled_nats,
    reflection,
)

SIGMA = 0.05
PERIOD_S = 420.0
SURFACE = dict(rho=0.5, f0=0.5, n_u=800.0, n_v=800.0)


def spin(t: torch.Tensor, axis: torch.Tensor, A0: torch.Tensor) -> torch.Tensor:
    """``R_e(θ) A0`` ``(T, 3, 3)``: the body turned by ``θ = 2π t / P`` about its axis ``e`` (passive form)."""
    theta = 2 * math.pi * t / PERIOD_S
    c, s = torch.cos(theta)[:, None, None], torch.sin(theta)[:, None, None]
    cross = torch.tensor([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]],
                         dtype=torch.float64)
    return (c * torch.eye(3, dtype=torch.float64) + (1 - c) * torch.outer(axis, axis) - s * cross) @ A0


def random_rotation(seed: int) -> torch.Tensor:
    q, r = np.linalg.qr(np.random.default_rng(seed).standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    return torch.as_tensor(q * np.linalg.det(q), dtype=torch.float64)


def geometry(T: int, *, tilt_deg: float) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Per-sample Sun and observer directions: the Sun drifting, the observer turning at 15°/h, both
    ``tilt_deg`` out of the x–y plane at the extremes; ranges of 36 000 km."""
    t = torch.linspace(0.0, 1.0, T, dtype=torch.float64)
    a, b = 0.3 + 0.05 * t, 1.0 + 0.8 * t
    z = math.sin(math.radians(tilt_deg)) * torch.cos(3 * t)
    sun = torch.stack([torch.cos(a), torch.sin(a), z], -1)
    observer = torch.stack([torch.cos(b), torch.sin(b), -z], -1)
    return sun, observer, torch.full((T,), 3.6e7, dtype=torch.float64)


def boxwing_scene(tilt_deg: float, T: int = 240) -> Scene:
    facets = box_wing((1.0, 1.0, 1.3), 2, (1.0, 2.0, 0.1), 2, **SURFACE)
    return Scene(facets, *geometry(T, tilt_deg=tilt_deg))


def lumpy_scene(T: int = 240) -> Scene:
    points = np.random.default_rng(3).standard_normal((40, 3)) * np.array([1.0, 0.7, 0.5])
    return Scene(facets_from_mesh(trimesh.convex.convex_hull(points), **SURFACE), *geometry(T, tilt_deg=5.0))


def test_profiled_nats_by_hand():
    rng = np.random.default_rng(0)
    curve = torch.as_tensor(np.repeat([0, 1, 2], [5, 7, 4]))
    residual = rng.standard_normal(16) * 0.03
    reference = torch.as_tensor(rng.uniform(8, 12, 16))
    mag = reference + torch.as_tensor(residual) + torch.as_tensor([0.3, -1.0, 2.0])[curve]
    mag[3] = math.nan                                               # left out
    r = [residual[curve.numpy() == c][[k for k in range(int((curve == c).sum())) if (c, k) != (0, 3)]]
         for c in range(3)]
    expected = sum(float(((v - v.mean()) ** 2).sum()) for v in r) / (2 * SIGMA ** 2)
    assert profiled_nats(mag=mag, reference=reference, curve=curve, sigma_mag=SIGMA) == pytest.approx(expected,
                                                                                                      rel=1e-12)
    with pytest.raises(ValueError, match="no sample where both magnitudes are finite"):
        profiled_nats(mag=torch.full((3,), math.nan), reference=torch.zeros(3), curve=torch.zeros(3), sigma_mag=1.0)


def test_half_turn_is_the_phase_advanced_by_half_a_period():
    e = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    t = torch.linspace(0.0, 900.0, 50, dtype=torch.float64)
    A0 = random_rotation(1)
    assert torch.allclose(half_turn(e) @ spin(t, e, A0), spin(t + PERIOD_S / 2, e, A0), atol=1e-12)


@pytest.mark.parametrize("axis", [2, 1])
def test_half_turn_exact_for_the_box_wing_and_not_for_a_lumpy_body(axis):
    e = torch.eye(3, dtype=torch.float64)[axis]
    t = torch.linspace(0.0, 3600.0, 240, dtype=torch.float64)
    A = spin(t, e, random_rotation(2))
    curve = (t > 1800.0).long()
    assert half_turn_nats(boxwing_scene(5.0), A=A, axis=e, curve=curve, sigma_mag=SIGMA) < 1e-12
    assert half_turn_nats(lumpy_scene(), A=A, axis=e, curve=curve, sigma_mag=SIGMA) > 100.0


def test_mirror_exact_only_when_every_direction_is_in_one_plane():
    e = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    t = torch.linspace(0.0, 3600.0, 240, dtype=torch.float64)
    A = spin(t, e, random_rotation(4))
    curve = torch.zeros(240, dtype=torch.long)
    flat, tilted = boxwing_scene(0.0), boxwing_scene(8.0)
    normal = nearest_plane_normal(torch.cat([flat.sun, flat.observer]))
    assert abs(float(normal[2])) == pytest.approx(1.0, abs=1e-12)
    assert mirror_nats(flat, A=A, normal=normal, curve=curve, sigma_mag=SIGMA) < 1e-12
    tilted_normal = nearest_plane_normal(torch.cat([tilted.sun, tilted.observer]))
    assert mirror_nats(tilted, A=A, normal=tilted_normal, curve=curve, sigma_mag=SIGMA) > 10.0


def test_mirror_pole_is_the_rotation_axis_of_the_mirror_motion():
    e = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    A0 = random_rotation(5)
    normal = torch.tensor([0.3, -0.5, 0.8], dtype=torch.float64)
    M = reflection(normal)
    t, h = torch.tensor([100.0, 300.0], dtype=torch.float64), 1e-3
    for k in range(3):
        S = reflection(torch.eye(3, dtype=torch.float64)[k])
        image = lambda s: S @ spin(s, e, A0) @ M                            # noqa: E731
        Adot = (image(t + h) - image(t - h)) / (2 * h)
        cross = -image(t).transpose(-1, -2) @ Adot                         # [ω×] of the inertial angular velocity
        omega = torch.stack([cross[:, 2, 1], cross[:, 0, 2], cross[:, 1, 0]], -1)
        expected = 2 * math.pi / PERIOD_S * mirror_pole(A0.T @ e, normal)
        assert torch.allclose(omega, expected.expand(2, 3), atol=1e-9)


def test_nearest_plane_containing_a_vector():
    c = torch.tensor([1.0, 2.0, 2.0], dtype=torch.float64) / 3.0
    n_true = torch.linalg.cross(c, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
    n_true = n_true / n_true.norm()
    rng = np.random.default_rng(6)
    in_plane = torch.as_tensor(rng.standard_normal((30, 3)))
    in_plane = in_plane - (in_plane @ n_true)[:, None] * n_true
    n = nearest_plane_normal(in_plane, containing=c)
    assert float(n @ c) == pytest.approx(0.0, abs=1e-12) and abs(float(n @ n_true)) == pytest.approx(1.0, abs=1e-12)
    assert float(mirror_pole(c, n) @ c) == pytest.approx(-1.0, abs=1e-12)    # the spin reversed


def test_image_group_of_the_box_wing_in_a_plane_and_of_a_lumpy_body():
    e = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    t = torch.linspace(0.0, 3600.0, 240, dtype=torch.float64)
    A = spin(t, e, random_rotation(7))
    curve = torch.zeros(240, dtype=torch.long)
    pole = A[0].T @ e
    flat = boxwing_scene(0.0)
    normal = nearest_plane_normal(torch.cat([flat.sun, flat.observer]))
    images, nats = image_group(flat, A=A, axis=e, curve=curve, sigma_mag=SIGMA, mirror_normals={"mirror": normal})
    assert [im.name for im in images] == ["identity", "mirror", "half turn", "half turn + mirror"]
    assert [im.period_divisor for im in images] == [1, 1, 2, 2]
    assert torch.allclose(images[1].pole, -reflection(normal) @ pole) and torch.allclose(images[2].pole, pole)
    assert max(nats.values()) < 1e-12
    images, nats = image_group(lumpy_scene(), A=A, axis=e, curve=curve, sigma_mag=SIGMA,
                               mirror_normals={"mirror": normal})
    assert [im.name for im in images] == ["identity"] and min(nats.values()) > 1.0


def test_image_group_refuses_mirrors_about_an_oblique_axis():
    e = torch.tensor([0.6, 0.8, 0.0], dtype=torch.float64)
    A = spin(torch.linspace(0.0, 600.0, 20, dtype=torch.float64), e, random_rotation(8))
    with pytest.raises(ValueError, match=r"image_group: the spin axis \[0\.6.* is not a body coordinate axis"):
        image_group(boxwing_scene(0.0, T=20), A=A, axis=e, curve=torch.zeros(20, dtype=torch.long), sigma_mag=SIGMA,
                    mirror_normals={"mirror": torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)})
