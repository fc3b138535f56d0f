"""The images of a principal-axis spin (pole, period) under a scenario's geometry, derived by rendering.

A body spinning uniformly about its body axis ``e`` has inertial → body matrices ``A(t) = R_e(θ(t)) A_0`` (the
body turns by ``θ = 2π t / P + φ0`` about the inertial pole ``p = A_0ᵀ e``). A search that reports a pole and a
period is right modulo the states whose light curves no data of *this* scenario tell apart; which those are
depends on the body and on the geometry, so each candidate is rendered over the scenario's own samples and compared
with the truth in nats at the noise σ (:func:`profiled_nats`: ``Σ (d − d̄_c)² / (2σ²)``, ``d`` the magnitude
difference, ``d̄_c`` its mean over each relative curve ``c``: an unknown zero point is profiled). Candidates, each a
rigid motion of the same body:

* **half turn** ``R_e(180°) A(t)``: the body turned half a turn about its spin axis, i.e. its rotation phase
  advanced by ``P/2``. When it renders the truth's curves, the light curves are ``P/2``-periodic over the data, and
  the state ``(p, P/2)`` is counted as an image: the light curves fix the period only up to that factor. (The true
  body turning at ``P/2`` does not render them; a different shape at ``P/2`` may, and the period the data show
  is ``P/2``.)
* **mirror** through the plane of unit normal ``n`` (:func:`reflection` ``M = I − 2 n nᵀ``): ``S A(t) M`` with
  ``S`` a body reflection through a coordinate plane — the one of the three that renders closest. With ``e`` a
  body coordinate axis (``S e = ±e``; the principal axes of a diagonal inertia), ``S A(t) M =
  R_e(∓θ) S A_0 M`` is a uniform rotation about the body axis ``e`` again, of pole ``−M p`` and period ``P``
  (:func:`mirror_pole`). It renders the truth's curves when ``S`` maps the body onto itself and every Sun and
  observer direction lies in the plane (``M ŝ = ŝ``); :func:`nearest_plane_normal` gives the plane nearest every
  direction, optionally constrained to contain a given vector (the pole: the image ``−p``, the spin reversed).

The group (:func:`image_group`): ``{identity, half turn if exact} × {identity, each exact mirror}``, an image exact
when its misfit is below ``tol_nats`` (1 nat: the data cannot prefer the truth to it by more than that).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import matrix_to_quat
from lightcurve_gp.photometry.render import Scene

__all__ = ["SpinImage", "profiled_nats", "half_turn", "reflection", "nearest_plane_normal", "mirror_pole",
           "render_matrices", "half_turn_nats", "mirror_nats", "image_group"]


@dataclass(frozen=True)
class SpinImage:
    """One image of a spin state: its ``name`` (the candidates it is made of, e.g. ``"half turn + mirror"``), its
    ``pole (3,)`` (unit, inertial), its period ``P / period_divisor`` and ``nats``, the largest misfit of its
    candidates (0 for the identity)."""

    name: str
    pole: Tensor
    period_divisor: int
    nats: float


def profiled_nats(*, mag: Tensor, reference: Tensor, curve: Tensor, sigma_mag: float) -> float:
    """``Σ_i (d_i − d̄_c(i))² / (2σ²)`` with ``d = mag − reference`` (mag, ``(T,)`` each; samples where either is
    not finite are left out), ``d̄_c`` the mean of ``d`` over relative curve ``c`` (``curve (T,)`` integer labels):
    the nats by which the data's likelihood at the noise ``sigma_mag`` (mag) prefers ``reference`` to ``mag``, each
    curve's zero point profiled."""
    d = (mag - reference).to(torch.float64)
    keep = torch.isfinite(d)
    d, labels = d[keep], torch.as_tensor(curve)[keep].long()
    if d.numel() == 0:
        raise ValueError("profiled_nats: no sample where both magnitudes are finite")
    _, labels = torch.unique(labels, return_inverse=True)
    count = torch.zeros(int(labels.max()) + 1, dtype=d.dtype).index_add_(0, labels, torch.ones_like(d))
    mean = torch.zeros_like(count).index_add_(0, labels, d) / count
    r = d - mean[labels]
    return float((r * r).sum()) / (2.0 * sigma_mag ** 2)


def half_turn(axis: Tensor) -> Tensor:
    """The 180° rotation ``2 e eᵀ − I`` ``(3, 3)`` about the unit vector ``axis`` (normalised here)."""
    e = axis / torch.linalg.vector_norm(axis)
    return 2.0 * torch.outer(e, e) - torch.eye(3, dtype=e.dtype, device=e.device)


def reflection(normal: Tensor) -> Tensor:
    """The reflection ``I − 2 n nᵀ`` ``(3, 3)`` through the plane of unit normal ``normal`` (normalised here)."""
    n = normal / torch.linalg.vector_norm(normal)
    return torch.eye(3, dtype=n.dtype, device=n.device) - 2.0 * torch.outer(n, n)


def nearest_plane_normal(directions: Tensor, *, containing: Tensor | None = None) -> Tensor:
    """The unit normal ``(3,)`` of the plane through the origin nearest the unit ``directions (N, 3)`` (least
    ``Σ (n·d)²``); with ``containing (3,)``, of the nearest plane that contains that vector."""
    d = directions.to(torch.float64)
    if containing is None:
        return torch.linalg.svd(d, full_matrices=False)[2][-1]
    c = containing.to(torch.float64) / torch.linalg.vector_norm(containing.to(torch.float64))
    basis = torch.linalg.svd(torch.eye(3, dtype=d.dtype) - torch.outer(c, c))[0][:, :2]   # (3, 2): span of c's ⟂
    return basis @ torch.linalg.svd(d @ basis, full_matrices=False)[2][-1]


def mirror_pole(pole: Tensor, normal: Tensor) -> Tensor:
    """The pole ``−M p`` ``(3,)`` of the mirror motion ``S A(t) M`` (module docstring) for the pole ``p (3,)``."""
    return -(reflection(normal) @ pole.to(torch.float64))


def render_matrices(scene: Scene, A: Tensor) -> Tensor:
    """Magnitudes ``(T,)`` (NaN where nothing is lit and visible) of inertial → body rotations ``A (T, 3, 3)``
    under the scene's per-sample geometry (``T`` samples)."""
    return scene.magnitude(matrix_to_quat(A.to(torch.float64)))


def half_turn_nats(scene: Scene, *, A: Tensor, axis: Tensor, curve: Tensor, sigma_mag: float) -> float:
    """Misfit (nats, :func:`profiled_nats`) of the body turned 180° about its body spin ``axis (3,)`` against the
    truth ``A (T, 3, 3)``: below 1 nat, the light curves are ``P/2``-periodic over these samples."""
    truth = render_matrices(scene, A)
    return profiled_nats(mag=render_matrices(scene, half_turn(axis.to(A)) @ A), reference=truth, curve=curve,
                         sigma_mag=sigma_mag)


def mirror_nats(scene: Scene, *, A: Tensor, normal: Tensor, curve: Tensor, sigma_mag: float) -> float:
    """Misfit (nats) of the mirror motion ``S A(t) M`` against the truth ``A (T, 3, 3)``, ``M`` the reflection
    through the inertial plane of ``normal (3,)``, ``S`` the body reflection through the coordinate plane (of the
    three) that renders closest."""
    truth = render_matrices(scene, A)
    M = reflection(normal.to(A))
    return min(profiled_nats(mag=render_matrices(scene, reflection(torch.eye(3, dtype=A.dtype)[k]) @ A @ M),
                             reference=truth, curve=curve, sigma_mag=sigma_mag) for k in range(3))


def image_group(scene: Scene, *, A: Tensor, axis: Tensor, curve: Tensor, sigma_mag: float,
                mirror_normals: dict[str, Tensor], tol_nats: float = 1.0) -> tuple[list[SpinImage], dict[str, float]]:
    """The images of the spin about the body ``axis (3,)`` whose truth is ``A (T, 3, 3)`` (module docstring).

    Args:
        scene: the renderer with the scenario's per-sample geometry (``T`` samples).
        A: the truth's inertial → body matrices at the samples; its pole is ``A[0]ᵀ axis``.
        axis: the body spin axis (unit, a principal axis; a body coordinate axis when ``mirror_normals`` are given).
        curve: relative-curve label per sample ``(T,)``; sigma_mag: the noise (mag).
        mirror_normals: the candidate mirror planes by name (inertial unit normals ``(3,)``).
        tol_nats: an image is exact below this misfit.

    Returns:
        ``(images, nats)``: the exact images, the identity first, and every candidate's misfit by name
        (``"half turn"`` and each mirror's).
    """
    axis = axis.to(A) / torch.linalg.vector_norm(axis.to(A))
    if mirror_normals and not bool((axis.abs().max() - 1.0).abs() < 1e-12):
        raise ValueError(f"image_group: the spin axis {axis.tolist()} is not a body coordinate axis; the mirror "
                         "motions keep it only when it is")
    pole = A[0].T @ axis
    nats = {"half turn": half_turn_nats(scene, A=A, axis=axis, curve=curve, sigma_mag=sigma_mag)}
    for name, normal in mirror_normals.items():
        nats[name] = mirror_nats(scene, A=A, normal=normal, curve=curve, sigma_mag=sigma_mag)
    poles = [("identity", pole, 0.0)] + [(name, mirror_pole(pole, n), nats[name]) for name, n in mirror_normals.items()
                                         if nats[name] < tol_nats]
    divisors = [(1, 0.0)] + ([(2, nats["half turn"])] if nats["half turn"] < tol_nats else [])
    images = []
    for divisor, half in divisors:
        for name, p, mirror in poles:
            parts = [part for part in (("half turn" if divisor == 2 else ""), ("" if name == "identity" else name))
                     if part]
            images.append(SpinImage(name=" + ".join(parts) or "identity", pole=p, period_divisor=divisor,
                                    nats=max(half, mirror)))
    return images, nats
