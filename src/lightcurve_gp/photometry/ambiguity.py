"""The exact ambiguity group of a scenario: the states no light curve of it can tell apart, derived numerically.

A light curve sees an attitude only through the body-frame Sun and observer directions ``A(q) ŝ``, ``A(q) v̂``
(:mod:`lightcurve_gp.photometry.render`). Two kinds of rotation can leave it unchanged:

* a **body** rotation ``R`` that maps the facets onto themselves (:mod:`lightcurve_gp.photometry.symmetry`):
  ``q ↦ q_R ⊗ q`` (``A(q_R) = R``, so ``A(q_R ⊗ q) = R A(q)``);
* an **inertial** rotation ``C`` that maps the Sun–observer pair onto itself for the reflectance: ``q ↦ q ⊗ q_C``
  (``A(q ⊗ q_C) = A(q) C``, so the body sees ``A(q) C ŝ``). Three 180° turns are candidates: about the bisector
  ``ĥ`` (it swaps ``ŝ`` and ``v̂``: the BRDF is reciprocal), about the normal ``n̂`` of the Sun–observer plane (it
  negates both: a shape whose facets come in opposite pairs of equal area and material renders the same) and about
  the in-plane perpendicular ``p̂ = n̂ × ĥ`` (both at once).

Along a trajectory the image of a state ``(q_0, ω_0)`` is ``(q_R ⊗ q_0 ⊗ q_C, R ω_0)``: with ``q(t) = Δ(t) ⊗ q_0``
(torque-free kinematics ``q̇ = ½ [ω; 0] ⊗ q``, ω the body rate), right products commute with the propagation, and
``q'(t) = q_R ⊗ q(t)`` has ``Ȧ' = R Ȧ = −[Rω ×] A'``, i.e. the body rate ``R ω(t)`` — a torque-free rate history
again when ``Rᵀ J R = J`` (the 180° turns about the principal axes of a diagonal inertia). So

* with ω **unknown** the candidates are every (body, inertial) pair: 16 for the box-wing under a fixed geometry;
* with ω **known** the image must keep ``ω_0``: only ``R = I`` survives (unless ω lies on the turn's axis), the
  four inertial images;
* along a **pass** the Sun and observer move: an inertial rotation that maps the first sample's pair onto itself
  does not map the later ones, and only the body images survive.

Nothing is listed: :func:`ambiguity_group` tests every candidate (the 24 axis rotations of the body × the four
inertial turns of the first sample's geometry) by rendering a few random probe trajectories and their images over
the scenario's sample times, and keeps a pair when every magnitude agrees to ``tol_mag`` (1e-9 mag).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import attitude_matrix, matrix_to_quat, quat_mul
from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.attitude.torque_free import torque_free_motion
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.photometry.spin_images import half_turn
from lightcurve_gp.photometry.symmetry import cube_rotations, symmetry_rotations

__all__ = ["INERTIAL_TURNS", "GROUP_SOURCE", "AmbiguityGroup", "inertial_turns", "near_image_turns",
           "ambiguity_group", "config_ambiguity_group"]

#: names of the inertial candidates, in the order of :func:`inertial_turns`
INERTIAL_TURNS = ("identity", "plane normal", "bisector", "in-plane perpendicular")
#: where the images of :class:`AmbiguityGroup` come from, in words (for reports)
GROUP_SOURCE = ("derived by lightcurve_gp.photometry.ambiguity.ambiguity_group: body rotations x inertial 180 deg "
                "turns of the Sun-observer pair, each kept when it reproduces probe light curves of the scenario to "
                "1e-9 mag")


def inertial_turns(sun: Tensor, observer: Tensor) -> Tensor:
    """The identity and the 180° turns about the normal of the Sun–observer plane, the bisector and the in-plane
    perpendicular ``(4, 3, 3)`` (:data:`INERTIAL_TURNS`) for unit inertial directions ``sun``, ``observer (3,)``.

    A 180° turn about the unit axis ``a`` is ``2 a aᵀ − I`` (:func:`.spin_images.half_turn`). Sun and observer
    must not be (anti)parallel."""
    h = sun + observer
    n = torch.linalg.cross(sun, observer, dim=-1)
    if not float(torch.linalg.vector_norm(h)) > 1e-12 or not float(torch.linalg.vector_norm(n)) > 1e-12:
        raise ValueError("inertial_turns: the Sun and the observer are (anti)parallel; no Sun-observer plane")
    h, n = h / torch.linalg.vector_norm(h), n / torch.linalg.vector_norm(n)
    p = torch.linalg.cross(n, h, dim=-1)
    eye = torch.eye(3, dtype=sun.dtype, device=sun.device)
    return torch.stack([eye, *(half_turn(a) for a in (n, h, p))])


def near_image_turns(scene: Scene) -> Tensor:
    """The 180° inertial turns that make near-exact images along a pass, as quaternions ``q_C (C, 4)``: under a
    moving geometry the three turns of the first sample's Sun–observer pair (:func:`inertial_turns` less the
    identity), whose images ``q_0 ⊗ q_C`` are exact at the first sample and near-exact while the geometry moves
    little — not in the exact group, but a state's image under them starts close to another basin (the inversion's
    image probe); under a fixed geometry none, ``(0, 4)`` (its turns are exact images, in the group, or no images at
    all)."""
    if not scene.per_sample:
        return scene.sun.new_zeros(0, 4)
    return matrix_to_quat(inertial_turns(scene.sun[0], scene.observer[0])[1:])


@dataclass(frozen=True)
class AmbiguityGroup:
    """The exact images of a scenario's states, the identity first.

    Attributes:
        body: body rotations as quaternions ``q_R (K, 4)`` (scalar last, ``A(q_R) = R``).
        inertial: inertial rotations as quaternions ``q_C (K, 4)``.
        labels: one name per image, e.g. ``"body 180° x · inertial bisector"``.
        rate_known: whether the images keep the body rate (ω known) or turn it with the body (ω unknown).
    """

    body: Tensor
    inertial: Tensor
    labels: tuple[str, ...]
    rate_known: bool

    def __len__(self) -> int:
        return self.body.shape[0]

    def to(self, device=None, dtype=None) -> AmbiguityGroup:
        """The same images on another device and/or dtype."""
        return AmbiguityGroup(body=self.body.to(device=device, dtype=dtype),
                              inertial=self.inertial.to(device=device, dtype=dtype), labels=self.labels,
                              rate_known=self.rate_known)

    def attitudes(self, q: Tensor) -> Tensor:
        """The images ``q_R ⊗ q ⊗ q_C`` ``(K, ..., 4)`` of attitudes ``q (..., 4)`` (at any time of a trajectory)."""
        shape = (len(self),) + (1,) * (q.ndim - 1) + (4,)
        return quat_mul(quat_mul(self.body.reshape(shape), q.unsqueeze(0)), self.inertial.reshape(shape))

    def rates(self, omega: Tensor) -> Tensor:
        """The images ``R ω`` ``(K, ..., 3)`` of body rates ``ω (..., 3)``."""
        rot = attitude_matrix(self.body).reshape((len(self),) + (1,) * (omega.ndim - 1) + (3, 3))
        return (rot @ omega.unsqueeze(0).unsqueeze(-1)).squeeze(-1)

    def describe(self) -> list[str]:
        """The labels, for reports ("modulo which images")."""
        return list(self.labels)

    def as_dict(self) -> dict:
        """The images for a summary: where they come from, whether the rate is known, their names and quaternions
        (``body``: ``q_R``, ``inertial``: ``q_C``; the image of ``q`` is ``q_R ⊗ q ⊗ q_C``)."""
        return {"source": GROUP_SOURCE, "rate_known": self.rate_known, "labels": list(self.labels),
                "body": self.body.tolist(), "inertial": self.inertial.tolist()}


def _body_label(rotation: Tensor) -> str:
    """A short name of an axis rotation: ``"identity"``, ``"180° x"``, or the signed permutation's rows."""
    if torch.allclose(rotation, torch.eye(3, dtype=rotation.dtype)):
        return "identity"
    diag = torch.diagonal(rotation)
    if bool((rotation - torch.diag(diag)).abs().max() < 1e-12) and int((diag > 0).sum()) == 1:
        return f"180° {'xyz'[int(diag.argmax())]}"
    rows = [" ".join(f"{int(v):+d}" for v in row.round()) for row in rotation]
    return "rows [" + "; ".join(rows) + "]"


def _probe_curves(scene: Scene, q0: Tensor, omega0: Tensor, *, inertia: Tensor, times: Tensor) -> Tensor:
    """Magnitudes ``(..., T)`` of the trajectories from ``(q0, ω0)`` ``(..., 4)``, ``(..., 3)`` at ``times (T,)``
    (s from the first sample; the closed-form torque-free motion)."""
    delta, _ = torque_free_motion(omega0, inertia=inertia, times=times)
    return scene.magnitude(quat_mul(delta, q0.unsqueeze(-2)))


def ambiguity_group(scene: Scene, *, times_s: Tensor, inertia, rate_known: bool, probes: int = 4,
                    probe_rate_deg_s: float = 2.0, seed: int = 0, tol_mag: float = 1e-9,
                    body_candidates: Tensor | None = None) -> AmbiguityGroup:
    """Derive the exact ambiguity group of a scenario (module docstring).

    Args:
        scene: the renderer with the scenario's geometry (fixed, or per sample with ``T`` samples).
        times_s: sample times ``(T,)`` (s, increasing, any spacing; taken from the first).
        inertia: principal moments ``(3,)`` (kg m²).
        rate_known: whether the body rate is known (the image keeps ``ω_0``) or estimated (it becomes ``R ω_0``).
        probes: random probe trajectories (uniform attitude, rate of ``probe_rate_deg_s`` about a uniform axis).
        seed: of the probes.
        tol_mag: the largest magnitude difference (mag) an image may show at any sample of any probe.
        body_candidates: body rotations ``(C, 3, 3)`` to test (default: the 24 axis rotations).

    Returns:
        The images whose light curves agree with every probe's, the identity first.
    """
    times_s = torch.as_tensor(times_s, dtype=torch.float64)
    if times_s.ndim != 1 or not len(times_s) or bool((times_s[1:] <= times_s[:-1]).any()):
        raise ValueError(f"times_s: expected strictly increasing sample times (s), got {times_s.tolist()}")
    dtype, device = scene.facets.normals.dtype, scene.facets.normals.device
    times = (times_s - times_s[0]).to(dtype=dtype, device=device)
    inertia = torch.as_tensor(inertia, dtype=dtype, device=device)
    sun, observer = (scene.sun[0], scene.observer[0]) if scene.per_sample else (scene.sun, scene.observer)
    turns = inertial_turns(sun, observer)
    bodies = cube_rotations(dtype=dtype, device=device) if body_candidates is None else body_candidates.to(sun)
    gen = torch.Generator().manual_seed(int(seed))
    axes = torch.randn(probes, 3, generator=gen, dtype=torch.float64)
    omega0 = (torch.deg2rad(torch.tensor(probe_rate_deg_s)) * axes / axes.norm(dim=-1, keepdim=True)).to(sun)
    q0 = random_attitudes(probes, seed=seed, dtype=dtype, device=device)
    reference = _probe_curves(scene, q0, omega0, inertia=inertia, times=times)  # (P, T)
    q_body, q_inertial = matrix_to_quat(bodies), matrix_to_quat(turns)
    nb, ni = len(bodies), len(turns)
    q_img = quat_mul(quat_mul(q_body[:, None, None], q0), q_inertial[None, :, None])  # (B, I, P, 4)
    w_img = omega0.expand(nb, ni, -1, 3) if rate_known else \
        (bodies[:, None, None] @ omega0.unsqueeze(-1)).squeeze(-1).expand(nb, ni, -1, 3)
    curves = _probe_curves(scene, q_img, w_img, inertia=inertia, times=times)  # (B, I, P, T)
    same_nan = (torch.isnan(curves) == torch.isnan(reference)).flatten(-2).all(-1)
    diff = (curves - reference).nan_to_num(0.0).abs().flatten(-2).amax(-1)
    keep = same_nan & (diff <= tol_mag)  # (B, I)
    keep_body, keep_inertial, labels = [], [], []
    for i, j in keep.nonzero().tolist():
        keep_body.append(q_body[i])
        keep_inertial.append(q_inertial[j])
        labels.append(f"body {_body_label(bodies[i])} · inertial {INERTIAL_TURNS[j]}")
    if not labels:
        raise ValueError("ambiguity_group: not even the identity reproduced the probes' light curves "
                         "(check body_candidates and tol_mag)")
    return AmbiguityGroup(body=torch.stack(keep_body), inertial=torch.stack(keep_inertial), labels=tuple(labels),
                          rate_known=bool(rate_known))


def config_ambiguity_group(cfg, *, scene: Scene, times_s: Tensor) -> AmbiguityGroup:
    """:func:`ambiguity_group` of a config's object seen through ``scene`` (fixed, or per sample along a pass) at the
    sample times ``times_s (T,)`` (s): the facet model's body symmetries as candidates, ``shape.inertia_kg_m2``,
    the rate known unless ``filter.estimate_omega``; derived in float64 on the CPU whatever the
    run's dtype and device (a float32 render cannot show 1e-9 mag)."""
    scene = scene.to(device="cpu", dtype=torch.float64)
    return ambiguity_group(scene, times_s=times_s.detach().to(device="cpu", dtype=torch.float64),
                           inertia=cfg.shape.inertia_kg_m2, rate_known=not cfg.filter.estimate_omega,
                           body_candidates=symmetry_rotations(scene.facets))
