"""Training sets over attitudes × geometries: the data of the geometry-aware GP (``model.inputs: body_geometry``).

Each point is one attitude under one Sun–observer geometry, drawn in the canonical geometry frame
(:mod:`lightcurve_gp.observation.body_geometry`): Sun along ``e_x``, observer at ``(cos α, sin α, 0)``, so the
attitude alone sets the body-frame directions and α the phase angle. A scrambled 4-D Sobol' sequence
(``data.seed``) gives the attitude (three coordinates, Shoemake's map) and α (uniform in ``data.phase_angle_deg``);
``data.num_random`` points, each rendered with every ρ of ``data.rho_grid`` at the reference range
``model.reference_range_km``, so the target is already range-normalised. Points with zero flux are dropped and
counted. The :class:`~lightcurve_gp.training.windows.TrainingSet` holds ``q`` (canonical-frame attitude),
``m_past`` = α in radians (the GP's second input), ``y`` and ``rho``.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from lightcurve_gp.attitude.sampling import shoemake_quaternions
from lightcurve_gp.config.schema import Config
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.photometry.shapes import facets_from_config
from lightcurve_gp.training.windows import TrainingSet

__all__ = ["canonical_geometry", "geometry_training_set", "geometry_heldout_set"]


def canonical_geometry(alpha: Tensor) -> tuple[Tensor, Tensor]:
    """Sun ``e_x`` and observer ``(cos α, sin α, 0)`` ``(N, 3)`` each for phase angles ``alpha (N,)`` (rad)."""
    sun = torch.zeros(*alpha.shape, 3, dtype=alpha.dtype, device=alpha.device)
    sun[..., 0] = 1.0
    observer = torch.stack([torch.cos(alpha), torch.sin(alpha), torch.zeros_like(alpha)], -1)
    return sun, observer


def _render(cfg: Config, q: Tensor, alpha: Tensor, rho: Tensor) -> TrainingSet:
    """Render ``q (N, 4)`` under canonical geometries ``alpha (N,)`` with ``rho`` ``(R, 1)`` or ``(N,)``."""
    dtype = cfg.torch_dtype
    facets = facets_from_config(cfg, dtype=dtype, device="cpu")
    sun, observer = canonical_geometry(alpha)
    r_ref = torch.full(alpha.shape, cfg.model.reference_range_km * 1e3, dtype=dtype)
    m = Scene(facets, sun, observer, r_ref).magnitude(q, rho=rho)  # (R, N) or (N,)
    ok = torch.isfinite(m)
    expand = lambda t: t.expand_as(m)[ok]  # noqa: E731
    return TrainingSet(q.expand(*m.shape, 4)[ok], expand(alpha), m[ok], expand(rho), int((~ok).sum()))


def _phase_range(cfg: Config) -> tuple[float, float]:
    lo, hi = cfg.data.phase_angle_deg
    return math.radians(lo), math.radians(hi)


def geometry_training_set(cfg: Config) -> TrainingSet:
    """The training set of a ``body_geometry`` GP (module docstring), on the CPU in ``cfg.dtype``."""
    engine = torch.quasirandom.SobolEngine(dimension=4, scramble=True, seed=int(cfg.data.seed))
    u = engine.draw(int(cfg.data.num_random), dtype=torch.float64)
    lo, hi = _phase_range(cfg)
    dtype = cfg.torch_dtype
    q = shoemake_quaternions(u[:, :3]).to(dtype)
    alpha = (lo + (hi - lo) * u[:, 3]).to(dtype)
    rho = torch.tensor(cfg.data.rho_grid, dtype=dtype).unsqueeze(-1)
    return _render(cfg, q, alpha, rho)


def geometry_heldout_set(cfg: Config) -> TrainingSet:
    """``data.heldout_size`` random attitudes, phase angles and ρ (uniform over the training ranges) from the seed
    ``data.seed + 1``, each under its own canonical geometry."""
    gen = torch.Generator().manual_seed(cfg.data.seed + 1)
    n, dtype = cfg.data.heldout_size, cfg.torch_dtype
    u = torch.rand(n, 5, generator=gen, dtype=torch.float64)
    lo, hi = _phase_range(cfg)
    rho_lo, rho_hi = min(cfg.data.rho_grid), max(cfg.data.rho_grid)
    return _render(cfg, shoemake_quaternions(u[:, :3]).to(dtype), (lo + (hi - lo) * u[:, 3]).to(dtype),
                   (rho_lo + (rho_hi - rho_lo) * u[:, 4]).to(dtype))
