"""Facet models of space objects: the paper's box-wing and any triangle mesh trimesh reads.

A :class:`Facets` holds one row per planar facet — outward unit normal, area, centroid, tangent axes and the
Ashikhmin–Shirley material (ρ, F0, n_u, n_v) — as torch tensors, on any device and floating dtype.

Tangent axes. The lobe exponents ``n_u``/``n_v`` act along per-facet tangent axes ``u`` and ``v = n × u``.
``u`` is a deterministic function of the normal alone (:func:`tangent_axes`)::

    e = the coordinate axis with the smallest |n_i| (ties: the lowest index i)
    u = (e × n) / |e × n|,   v = n × u

so facets that share a normal share ``u`` and ``v`` (the renderer groups such facets, see ``render``), and
``(u, v, n)`` is a right-handed orthonormal frame. With ``n_u = n_v`` (the paper) the BRDF does not depend
on the choice.

Typical use::

    cfg = load_config("configs/boxwing.yaml")
    facets = facets_from_config(cfg, rho=0.5)        # 472 facets, 16.4 m^2
    facets = facets.with_surface(rho=0.3).to(dtype=torch.float32)
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch
import trimesh
from torch import Tensor

from lightcurve_gp.config.parsing import load_mesh
from lightcurve_gp.config.schema import Config

__all__ = ["Facets", "tangent_axes", "facets_from_mesh", "load_mesh", "box_wing", "facets_from_config"]

_SURFACE = ("rho", "f0", "n_u", "n_v")


@dataclass(frozen=True)
class Facets:
    """Planar facets of an object, body frame, SI units; every field has the facet count ``F`` first.

    Attributes:
        normals: outward unit normals ``(F, 3)``.
        areas: facet areas ``(F,)`` (m²).
        centroids: facet centroids ``(F, 3)`` (m); not used by the shadow-free renderer, kept for models and plots.
        u: first tangent axis ``(F, 3)``, see :func:`tangent_axes`.
        v: second tangent axis ``n × u`` ``(F, 3)``.
        rho: diffuse reflectance ``(F,)``.
        f0: Fresnel reflectance at normal incidence ``(F,)``.
        n_u, n_v: specular lobe exponents along ``u`` and ``v`` ``(F,)``.
    """

    normals: Tensor
    areas: Tensor
    centroids: Tensor
    u: Tensor
    v: Tensor
    rho: Tensor
    f0: Tensor
    n_u: Tensor
    n_v: Tensor

    def __post_init__(self) -> None:
        n = self.normals.shape[0] if self.normals.ndim == 2 else -1
        for name in ("normals", "centroids", "u", "v"):
            t = getattr(self, name)
            if t.ndim != 2 or t.shape != (n, 3):
                raise ValueError(f"Facets.{name}: expected shape (F, 3) with F = {n}, got {tuple(t.shape)}")
        for name in ("areas",) + _SURFACE:
            t = getattr(self, name)
            if t.shape != (n,):
                raise ValueError(f"Facets.{name}: expected shape ({n},), got {tuple(t.shape)}")

    def __len__(self) -> int:
        return self.normals.shape[0]

    @property
    def total_area(self) -> Tensor:
        """Sum of the facet areas (m²), a 0-d tensor."""
        return self.areas.sum()

    def to(self, device=None, dtype=None) -> "Facets":
        """Copy with every tensor moved to ``device`` and/or cast to ``dtype``."""
        return Facets(**{f.name: getattr(self, f.name).to(device=device, dtype=dtype)
                         for f in dataclasses.fields(self)})

    def with_surface(self, *, rho=None, f0=None, n_u=None, n_v=None) -> "Facets":
        """Copy with surface parameters replaced; each is a number (all facets) or an ``(F,)`` tensor."""
        new = {}
        for name, value in zip(_SURFACE, (rho, f0, n_u, n_v)):
            if value is not None:
                old = getattr(self, name)
                new[name] = torch.as_tensor(value, dtype=old.dtype, device=old.device).expand(len(self)).clone()
        return dataclasses.replace(self, **new)

    def grouped(self, decimals: int = 9) -> tuple["Facets", Tensor]:
        """Merge facets with equal normal, tangent axes and material (to ``decimals`` places).

        Without shadowing such facets have identical BRDF terms for every attitude, so a group is one facet
        whose area is the sum of its members' (centroid: their area-weighted mean).

        Returns:
            ``(groups, index)``: the merged facets (in order of first occurrence) and, per original facet,
            the index of its group ``(F,)``.
        """
        key = torch.cat([self.normals, self.u, self.v, torch.stack([getattr(self, k) for k in _SURFACE], -1)], -1)
        key = torch.round(key.detach().to(torch.float64) * 10**decimals)
        _, inverse = torch.unique(key, dim=0, return_inverse=True)
        n_groups = int(inverse.max()) + 1 if len(self) else 0
        idx = torch.arange(len(self), device=inverse.device)
        first = torch.full((n_groups,), len(self), dtype=torch.long, device=inverse.device)
        first = first.scatter_reduce(0, inverse, idx, reduce="amin")
        order = torch.argsort(first)  # groups in order of first occurrence
        rank = torch.empty_like(order)
        rank[order] = torch.arange(n_groups, device=order.device)
        group = rank[inverse]
        first = first[order]
        areas = torch.zeros(n_groups, dtype=self.areas.dtype, device=self.areas.device).index_add(0, group, self.areas)
        weighted = torch.zeros(n_groups, 3, dtype=self.centroids.dtype, device=self.centroids.device)
        weighted = weighted.index_add(0, group, self.centroids * self.areas.unsqueeze(-1))
        merged = {f.name: getattr(self, f.name)[first] for f in dataclasses.fields(self)}
        merged.update(areas=areas, centroids=weighted / areas.clamp_min(torch.finfo(areas.dtype).tiny).unsqueeze(-1))
        return Facets(**merged), group


def tangent_axes(normals: Tensor) -> tuple[Tensor, Tensor]:
    """Tangent axes ``(u, v)`` of unit normals ``(..., 3)``, a deterministic function of the normal alone.

    ``u = (e × n)/|e × n|`` with ``e`` the coordinate axis of smallest ``|n_i|`` (lowest index on ties),
    ``v = n × u``; ``(u, v, n)`` is right-handed and orthonormal.
    """
    axis = torch.argmin(normals.abs(), dim=-1)  # argmin returns the first minimum: ties go to the lowest index
    e = torch.nn.functional.one_hot(axis, 3).to(normals.dtype)
    u = torch.linalg.cross(e, normals, dim=-1)
    u = u / torch.linalg.vector_norm(u, dim=-1, keepdim=True)
    return u, torch.linalg.cross(normals, u, dim=-1)


def facets_from_mesh(mesh: trimesh.Trimesh, *, rho: float, f0: float, n_u: float, n_v: float,
                     dtype: torch.dtype = torch.float64, device=None, min_area: float = 0.0) -> Facets:
    """One facet per mesh triangle; normals from the triangles' winding (counter-clockwise seen from outside).

    Args:
        mesh: triangle mesh, body frame, metres.
        rho, f0, n_u, n_v: Ashikhmin–Shirley parameters given to every facet (see :meth:`Facets.with_surface`).
        min_area: triangles with area ``<= min_area`` are an error (they have no normal).

    Raises:
        ValueError: an empty mesh or degenerate (zero-area) triangles.
    """
    if len(mesh.faces) == 0:
        raise ValueError("mesh has no faces")
    triangles = np.asarray(mesh.triangles, dtype=np.float64)
    cross = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    areas = 0.5 * np.linalg.norm(cross, axis=1)
    bad = np.flatnonzero(~(areas > min_area))
    if bad.size:
        raise ValueError(f"mesh has {bad.size} degenerate face(s) with area <= {min_area:g} m^2 "
                         f"(first: face {int(bad[0])}); remove them before rendering")
    as_t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=dtype, device=device)  # noqa: E731
    normals = as_t(cross / (2.0 * areas[:, None]))
    u, v = tangent_axes(normals)
    count = len(areas)
    full = lambda x: torch.full((count,), float(x), dtype=dtype, device=device)  # noqa: E731
    return Facets(normals=normals, areas=as_t(areas), centroids=as_t(triangles.mean(axis=1)), u=u, v=v,
                  rho=full(rho), f0=full(f0), n_u=full(n_u), n_v=full(n_v))


def _box_faces(center, size, grid) -> tuple[np.ndarray, np.ndarray]:
    """Triangulated surface of an axis-aligned box with outward winding.

    ``grid[k][i]`` is the number of squares along axis ``i`` on the two faces normal to axis ``k``.
    Returns ``(vertices (V, 3), faces (T, 3))``.
    """
    center, size = np.asarray(center, float), np.asarray(size, float)
    vertices, faces = [], []
    for k in range(3):
        i, j = (k + 1) % 3, (k + 2) % 3  # e_i × e_j = e_k
        ni, nj = grid[k][i], grid[k][j]
        a, b = np.meshgrid(np.linspace(-0.5, 0.5, ni + 1), np.linspace(-0.5, 0.5, nj + 1), indexing="ij")
        for sign in (1.0, -1.0):
            pts = np.zeros((ni + 1, nj + 1, 3))
            pts[..., k] = center[k] + sign * 0.5 * size[k]
            pts[..., i] = center[i] + a * size[i]
            pts[..., j] = center[j] + b * size[j]
            base = sum(len(v) for v in vertices)
            vid = base + np.arange((ni + 1) * (nj + 1)).reshape(ni + 1, nj + 1)
            p00, p10, p11, p01 = vid[:-1, :-1], vid[1:, :-1], vid[1:, 1:], vid[:-1, 1:]
            tri = np.concatenate([np.stack([p00, p10, p11], -1).reshape(-1, 3),
                                  np.stack([p00, p11, p01], -1).reshape(-1, 3)])
            if sign < 0:
                tri = tri[:, ::-1]  # reverse winding: the normal points along -e_k
            vertices.append(pts.reshape(-1, 3))
            faces.append(tri)
    return np.concatenate(vertices), np.concatenate(faces)


def box_wing_mesh(box_m, box_grid: int, wing_m, wing_grid: int) -> trimesh.Trimesh:
    """The paper's box-wing as one triangle mesh (not merged: each box and wing face keeps its own vertices).

    * box ``box_m = (x, y, z)`` centred at the origin, each face a ``box_grid × box_grid`` grid of squares;
    * two wings of extent ``wing_m = (x, y, z)`` against the ±y box faces (``|y|`` from ``box_y/2`` to
      ``box_y/2 + wing_y``, centred in x and z); their ±z faces are ``wing_grid × wing_grid`` grids, their
      ±x faces ``wing_grid`` squares along y and their ±y faces ``wing_grid`` along x, one across the thickness.

    Every square is two triangles; the wing face against the box is kept (the paper counts it). Faces come in
    order: the box's, the +y wing's, the −y wing's.
    """
    bx, by, bz = (float(s) for s in box_m)
    wx, wy, wz = (float(s) for s in wing_m)
    g, w = int(box_grid), int(wing_grid)
    parts = [_box_faces((0.0, 0.0, 0.0), (bx, by, bz), [[g] * 3] * 3)]
    # wing grid per face normal axis k: along x and y `wing_grid` squares, across the thickness (z) one
    wing_grid_axes = [[0, w, 1], [w, 0, 1], [w, w, 0]]
    for side in (1.0, -1.0):
        parts.append(_box_faces((0.0, side * (0.5 * by + 0.5 * wy), 0.0), (wx, wy, wz), wing_grid_axes))
    vertices, faces, offset = [], [], 0
    for vert, face in parts:
        vertices.append(vert)
        faces.append(face + offset)
        offset += len(vert)
    return trimesh.Trimesh(vertices=np.concatenate(vertices), faces=np.concatenate(faces), process=False)


def box_wing(box_m, box_grid: int, wing_m, wing_grid: int, *, rho: float, f0: float, n_u: float, n_v: float,
             dtype: torch.dtype = torch.float64, device=None) -> Facets:
    """Facets of the paper's box-wing (see :func:`box_wing_mesh`); the paper's sizes give 472 facets, 16.4 m²."""
    return facets_from_mesh(box_wing_mesh(box_m, box_grid, wing_m, wing_grid), rho=rho, f0=f0, n_u=n_u, n_v=n_v,
                            dtype=dtype, device=device)


def facets_from_config(cfg: Config, *, rho: float | None = None, dtype: torch.dtype | None = None,
                       device=None) -> Facets:
    """Facets of ``cfg.shape`` with the material of ``cfg.surface``.

    The config's surface section has no ρ (it varies per use); ``rho`` defaults to ``cfg.scenario.rho_true``.
    ``dtype``/``device`` default to the config's.
    """
    dtype = dtype or cfg.torch_dtype
    device = device if device is not None else cfg.device
    rho = cfg.scenario.rho_true if rho is None else float(rho)
    surface = dict(rho=rho, f0=cfg.surface.f0, n_u=cfg.surface.n_u, n_v=cfg.surface.n_v)
    shape = cfg.shape
    if shape.kind == "box_wing":
        return box_wing(shape.box_m, shape.box_grid, shape.wing_m, shape.wing_grid, **surface,
                        dtype=dtype, device=device)
    return facets_from_mesh(load_mesh(shape.mesh_path), **surface, dtype=dtype, device=device)
