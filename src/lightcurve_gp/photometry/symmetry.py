"""Symmetries of a facet model: body rotations that leave every light curve unchanged.

Without shadowing the reflected flux is a sum over facets of a term that depends only on the facet's normal, tangent
axes, area and material and on the body-frame Sun and observer directions ``A(q) ŝ``, ``A(q) v̂``
(:mod:`lightcurve_gp.photometry.render`). A rotation ``R`` of the body that maps the facets' normals (with their
summed areas
and materials) onto themselves therefore maps that sum onto itself: with ``A' = R A``,
``n · (R A ŝ) = (Rᵀ n) · (A ŝ)`` and ``Rᵀ n`` runs over the same facets. The attitudes ``q`` and ``q_R ⊗ q`` (with
``A(q_R) = R``, paper Eq. (13): ``A(q_R ⊗ q) = R A(q)``) give the same magnitude for every Sun and observer, so no
method that sees only the light curve can tell them apart. The box-wing of ``configs/boxwing.yaml`` (box
1 × 1 × 1.3 m, wings along ±y) has four: the identity and the 180° turns about the body x, y and z axes.

Along a trajectory with known body rates ``ω(t)`` the two are not interchangeable forever: ``q_R ⊗ q(t)`` turns at
``R ω(t)``. With a loose process noise (or rates in the state) a filter can follow either.

Candidates are the 24 proper rotations of the coordinate axes (:func:`cube_rotations`); a shape whose symmetry axes
are not body axes needs its own candidates.
"""

from __future__ import annotations

import itertools

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import matrix_to_quat
from lightcurve_gp.photometry.shapes import Facets

__all__ = ["cube_rotations", "symmetry_rotations", "symmetry_quaternions"]


def cube_rotations(*, dtype: torch.dtype = torch.float64, device=None) -> Tensor:
    """The 24 proper rotations of the coordinate axes ``(24, 3, 3)``: signed permutation matrices with det +1
    (the identity first)."""
    mats = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = torch.zeros(3, 3, dtype=dtype, device=device)
            m[range(3), perm] = torch.tensor(signs, dtype=dtype, device=device)
            if torch.linalg.det(m) > 0:
                mats.append(m)
    return torch.stack(mats)


def _facet_keys(facets: Facets, rotation: Tensor) -> Tensor:
    """One row per facet group ``(G, 15)``: rotated normal, summed area, material and, where the lobe is
    anisotropic (``n_u ≠ n_v``), the rotated ``u uᵀ`` (the lobe depends on ``(h·u)²`` only), else zeros."""
    n = facets.normals @ rotation.T
    u = facets.u @ rotation.T
    aniso = (facets.n_u != facets.n_v).to(u.dtype).unsqueeze(-1)
    uu = (u.unsqueeze(-1) * u.unsqueeze(-2)).flatten(-2)[:, [0, 1, 2, 4, 5, 8]] * aniso
    material = torch.stack([facets.areas, facets.rho, facets.f0, facets.n_u, facets.n_v], -1)
    return torch.cat([n, material, uu], -1)


def symmetry_rotations(facets: Facets, *, candidates: Tensor | None = None, rtol: float = 1e-9) -> Tensor:
    """The rotations ``R (S, 3, 3)`` among ``candidates (C, 3, 3)`` (default :func:`cube_rotations`) that map the
    facets onto themselves for the renderer: every facet group (:meth:`Facets.grouped`: equal normal, tangent axes
    and material, areas summed) rotated by ``R`` matches a group with the same area and material, to a relative
    tolerance ``rtol`` of each key column's scale. The identity is always among them (when a candidate)."""
    groups, _ = facets.grouped()
    if candidates is None:
        candidates = cube_rotations(dtype=groups.normals.dtype, device=groups.normals.device)
    reference = _facet_keys(groups, torch.eye(3, dtype=groups.normals.dtype, device=groups.normals.device))
    scale = reference.abs().amax(0).clamp_min(1.0)
    keep = []
    for rotation in candidates:
        rotated = _facet_keys(groups, rotation.to(reference))
        distance = ((rotated.unsqueeze(1) - reference.unsqueeze(0)).abs() / scale).amax(-1)  # (G, G)
        match = distance < rtol
        keep.append(bool(match.any(1).all()) and bool(match.any(0).all()))
    return candidates[torch.tensor(keep, dtype=torch.bool, device=candidates.device)]


def symmetry_quaternions(facets: Facets, *, candidates: Tensor | None = None, rtol: float = 1e-9) -> Tensor:
    """The symmetry rotations of :func:`symmetry_rotations` as quaternions ``q_R (S, 4)`` (scalar last,
    ``A(q_R) = R``): the attitudes ``q_R ⊗ q`` all give the light curve of ``q``."""
    return matrix_to_quat(symmetry_rotations(facets, candidates=candidates, rtol=rtol))
