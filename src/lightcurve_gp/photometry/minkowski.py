"""The convex polyhedron of a Gaussian image (Minkowski's problem), for a picture of a convex inversion's shape.

A convex polyhedron with outward unit normals ``n_k`` is ``P(h) = {x : n_k·x ≤ h_k}`` for support distances ``h``
``(K,)``. By Minkowski's theorem the facet areas ``a_k ≥ 0`` (with ``Σ_k a_k n_k = 0``, not all on a hemisphere)
fix ``P`` up to translation. It is found by minimising

    F(h) = Σ_k a_k h_k − A log V(h),     A = Σ_k a_k,

which is convex (``V^{1/3}`` is concave in ``h`` by Brunn–Minkowski) with the gradient
``∂F/∂h_k = a_k − A F_k(h) / V(h)``, ``F_k(h)`` the area of the facet on ``n_k`` (the volume's derivative in
``h_k``): at the minimum the facet areas are proportional to ``a``, and a scale makes them equal. Each evaluation
intersects the half-spaces (:class:`scipy.spatial.HalfspaceIntersection`, the origin inside while every
``h_k > 0``) and takes the hull of the vertices (:class:`scipy.spatial.ConvexHull`) for ``V`` and the triangles,
each assigned to the normal it lies on. Areas whose sum ``Σ a_k n_k`` is not zero (a fit's Gaussian image closes
only approximately) are first moved to the nearest non-negative closed areas (:func:`close_areas`).

Shapes: ``(K, 3)`` unit normals, ``(K,)`` areas and support distances; lengths in the areas' unit's square root.
NumPy in and out (a figure's helper, not a differentiable model).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize, nnls
from scipy.spatial import ConvexHull, HalfspaceIntersection

__all__ = ["Polytope", "close_areas", "polytope", "minkowski_polytope"]


@dataclass(frozen=True)
class Polytope:
    """A convex polyhedron ``{x : n_k·x ≤ h_k}``.

    Attributes:
        support: support distances ``h`` ``(K,)``.
        vertices: ``(V, 3)``; triangles: ``(T, 3)`` vertex indices, outward (counter-clockwise seen from outside).
        facet_normal: the normal index ``k`` of each triangle ``(T,)``.
        facet_areas: the area of the facet on each normal ``(K,)`` (0 where the plane only touches or misses).
        volume: the enclosed volume.
    """

    support: np.ndarray
    vertices: np.ndarray
    triangles: np.ndarray
    facet_normal: np.ndarray
    facet_areas: np.ndarray
    volume: float


def close_areas(normals: np.ndarray, areas: np.ndarray, *, weight: float = 1e3) -> np.ndarray:
    """The non-negative areas nearest to ``areas`` ``(K,)`` whose Gaussian image closes, ``Σ a_k n_k ≈ 0``
    (the closure rows weighted by ``weight`` relative to the area rows, solved by NNLS): ``(K,)``."""
    K = areas.size
    design = np.vstack([np.eye(K), weight * normals.T])
    target = np.concatenate([areas, np.zeros(3)])
    return nnls(design, target, maxiter=50 * K)[0]


def polytope(normals: np.ndarray, support: np.ndarray) -> Polytope:
    """``P(h)`` of ``normals`` ``(K, 3)`` and ``support`` ``(K,)`` (every ``h_k > 0``, so the origin is inside;
    the polyhedron must be bounded: normals not all on a hemisphere)."""
    if not np.all(support > 0):
        raise ValueError("polytope: every support distance must be > 0 (the origin inside)")
    halfspaces = np.hstack([normals, -support[:, None]])                      # n·x − h ≤ 0
    vertices = HalfspaceIntersection(halfspaces, np.zeros(3)).intersections
    hull = ConvexHull(vertices)
    tri = vertices[hull.simplices]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    outward = hull.equations[:, :3]
    simplices = np.where((np.einsum("ti,ti->t", cross, outward) < 0)[:, None], hull.simplices[:, ::-1],
                         hull.simplices)
    # each hull triangle lies in one of the planes: the one it is normal to and at whose distance it lies
    score = outward @ normals.T - np.abs(-hull.equations[:, 3:4] - support[None, :])
    owner = score.argmax(1)
    facet = np.bincount(owner, weights=area, minlength=normals.shape[0])
    return Polytope(support=support, vertices=vertices, triangles=simplices, facet_normal=owner, facet_areas=facet,
                    volume=float(hull.volume))


def minkowski_polytope(normals: np.ndarray, areas: np.ndarray, *, tolerance: float = 1e-10,
                       iterations: int = 2000) -> Polytope:
    """The convex polyhedron whose facet on each normal ``n_k`` has the area ``a_k`` (module docstring), centred
    on its vertices' mean.

    Args:
        normals: ``(K, 3)`` unit outward normals, not all on a hemisphere.
        areas: ``(K,)`` non-negative facet areas (closed first by :func:`close_areas`).
        tolerance: L-BFGS-B's projected-gradient tolerance on ``F / A``.
        iterations: its iteration limit.
    """
    normals = np.asarray(normals, dtype=np.float64)
    areas = np.asarray(areas, dtype=np.float64)
    if areas.shape != (normals.shape[0],) or np.any(areas < 0) or not areas.sum() > 0:
        raise ValueError(f"minkowski_polytope: areas must be {normals.shape[0]} non-negative numbers, not all 0")
    a = close_areas(normals, areas)
    a = a / a.sum()                                                        # A = 1: F = Σ a h − log V

    def objective(h: np.ndarray) -> tuple[float, np.ndarray]:
        p = polytope(normals, h)
        return float(a @ h - np.log(p.volume)), a - p.facet_areas / p.volume

    start = np.ones_like(a)
    result = minimize(objective, start, jac=True, method="L-BFGS-B", bounds=[(1e-6, None)] * a.size,
                      options={"gtol": tolerance, "ftol": 1e-15, "maxiter": iterations})
    p = polytope(normals, result.x)
    scale = np.sqrt(areas.sum() / p.facet_areas.sum())                     # areas ∝ length²
    centre = p.vertices.mean(0)
    h = scale * (result.x - normals @ centre)
    return polytope(normals, h)
