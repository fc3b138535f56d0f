"""Initial attitudes of the training trajectories (paper section 3.2).

* :func:`icosphere_axes` + :func:`grid_attitudes`: the paper's grid, rotation axes at the vertices of an
  icosahedron subdivided three times (642 unit vectors) × rotation angles Φ ∈ {0, 60, …, 300}° = 3852 quaternions.
* :func:`random_attitudes` / :func:`sobol_attitudes`: ``n`` attitudes uniform on SO(3) (Shoemake's method),
  from pseudo-random or scrambled Sobol' numbers.

Quaternions are scalar last, ``q = [e sin(Φ/2), cos(Φ/2)]``. Random draws are made in float64 on the CPU and
then cast/moved, so a seed gives the same attitudes on every device.
"""

from __future__ import annotations

import math
from numbers import Integral, Real

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import axis_angle_to_quat

__all__ = ["icosphere_axes", "grid_attitudes", "random_attitudes", "sobol_attitudes", "shoemake_quaternions"]


def icosphere_axes(subdivisions: int = 3, dtype: torch.dtype | None = None, device=None) -> Tensor:
    """Unit rotation axes at the vertices of a subdivided icosahedron (``trimesh.creation.icosphere``).

    Args:
        subdivisions: number of subdivisions (3 gives the paper's 642 axes; ``10 · 4^s + 2`` in general).
        dtype, device: of the result (default dtype: torch's default).

    Returns:
        ``(10 · 4^subdivisions + 2, 3)`` unit vectors, in trimesh's vertex order.
    """
    if isinstance(subdivisions, bool) or not isinstance(subdivisions, Integral) or subdivisions < 0:
        raise ValueError(f"subdivisions must be an integer >= 0, got {subdivisions!r}")
    import trimesh  # 1.3 s to import: only the training grid needs it

    verts = torch.as_tensor(trimesh.creation.icosphere(subdivisions=int(subdivisions), radius=1.0).vertices,
                            dtype=torch.float64)
    verts = verts / torch.linalg.vector_norm(verts, dim=-1, keepdim=True)
    return verts.to(dtype=dtype or torch.get_default_dtype(), device=device)


def grid_attitudes(axes: Tensor, phi_step_deg: float) -> Tensor:
    """Every axis combined with every rotation angle ``Φ ∈ {0, step, 2·step, …} < 360°``.

    Args:
        axes: unit rotation axes ``(M, 3)``.
        phi_step_deg: angle step in degrees, in ``(0, 360]``.

    Returns:
        ``(M · n_phi, 4)`` quaternions, **axis-major**: row ``i · n_phi + j`` is axis ``i`` rotated by
        ``Φ = j · step``; dtype and device follow ``axes``. With the paper's 642 axes and a 60° step,
        3852 rows, ``n_phi = 6``. The ``Φ = 0`` rows (``j = 0``) are all the identity ``[0, 0, 0, 1]``,
        one per axis: drop duplicates downstream if they are not wanted.
    """
    if not isinstance(axes, Tensor) or axes.ndim != 2 or axes.shape[-1] != 3:
        raise ValueError(f"axes must be a (M, 3) tensor, got {getattr(axes, 'shape', type(axes).__name__)}")
    if isinstance(phi_step_deg, bool) or not isinstance(phi_step_deg, Real) or not math.isfinite(phi_step_deg) \
            or not 0.0 < phi_step_deg <= 360.0:
        raise ValueError(f"phi_step_deg must be in (0, 360] degrees, got {phi_step_deg!r}")
    step = float(phi_step_deg)
    n_phi = math.ceil(360.0 / step - 1e-9)  # Φ = j·step < 360 (a tolerance so that 360/step integral is exact)
    phi = torch.deg2rad(torch.arange(n_phi, dtype=torch.float64) * step).to(dtype=axes.dtype, device=axes.device)
    n_axes = axes.shape[0]
    ax = axes.unsqueeze(1).expand(n_axes, n_phi, 3)
    q = axis_angle_to_quat(ax, phi.expand(n_axes, n_phi))
    return q.reshape(n_axes * n_phi, 4)


def _check_n_seed(n, seed) -> None:
    if isinstance(n, bool) or not isinstance(n, Integral) or n < 0:
        raise ValueError(f"n must be an integer >= 0, got {n!r}")
    if isinstance(seed, bool) or not isinstance(seed, Integral):
        raise ValueError(f"seed must be an integer, got {seed!r}")


def shoemake_quaternions(u: Tensor) -> Tensor:
    """Uniform unit quaternions from ``u`` ``(n, 3)`` uniform on ``[0, 1)³`` (Shoemake 1992)."""
    u1, u2, u3 = u.unbind(-1)
    r1, r2 = torch.sqrt(1.0 - u1), torch.sqrt(u1)
    t2, t3 = 2.0 * math.pi * u2, 2.0 * math.pi * u3
    return torch.stack([r1 * torch.sin(t2), r1 * torch.cos(t2), r2 * torch.sin(t3), r2 * torch.cos(t3)], dim=-1)


def random_attitudes(n: int, seed: int, dtype: torch.dtype | None = None, device=None) -> Tensor:
    """``n`` attitudes uniform on SO(3): Shoemake's method with a seeded ``torch.Generator``.

    Returns:
        ``(n, 4)`` unit quaternions (both signs occur; the sign is not canonicalised).
    """
    _check_n_seed(n, seed)
    gen = torch.Generator(device="cpu").manual_seed(int(seed))
    u = torch.rand(int(n), 3, generator=gen, dtype=torch.float64)
    return shoemake_quaternions(u).to(dtype=dtype or torch.get_default_dtype(), device=device)


def sobol_attitudes(n: int, seed: int, dtype: torch.dtype | None = None, device=None) -> Tensor:
    """``n`` quasi-random attitudes on SO(3): a scrambled 3-D Sobol' sequence (``torch.quasirandom.SobolEngine``,
    scrambled with ``seed``) mapped through Shoemake's method. Balance is best when ``n`` is a power of two.

    Returns:
        ``(n, 4)`` unit quaternions.
    """
    _check_n_seed(n, seed)
    engine = torch.quasirandom.SobolEngine(dimension=3, scramble=True, seed=int(seed))
    u = engine.draw(int(n), dtype=torch.float64) if n > 0 else torch.empty(0, 3, dtype=torch.float64)
    return shoemake_quaternions(u).to(dtype=dtype or torch.get_default_dtype(), device=device)
