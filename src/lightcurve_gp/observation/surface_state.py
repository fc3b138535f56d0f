"""The surface as a state: reflectance parameters in unconstrained coordinates, their prior, and the renderer that
takes them per sigma point.

The paper's promise is attitude from a light curve when the surface is unknown. With the shape known, the renderer
(paper Sec. 2.2, Eqs. (1)-(8)) is exact given the surface, so the surface's four Ashikhmin–Shirley parameters can be
estimated beside the attitude, the way the offset is (:mod:`lightcurve_gp.filters.offset`): the filter carries
``θ = (log ρ, logit F0, log n_u, log n_v)`` as states and every sigma point is rendered with its own surface
(:func:`lightcurve_gp.filters.usque.run_usque` with ``theta0`` and
:class:`lightcurve_gp.observation.parametric.SurfaceStateRenderer`). The batch MAP reference
(:mod:`lightcurve_gp.inference.surface`) estimates the same parameters with the same prior.

Coordinates: ``log ρ`` and ``log n`` keep ρ and the lobe exponents positive, ``logit F0`` keeps F0 in (0, 1); the
lobe exponents are held in ``[1, e^LOG_LOBE_MAX]`` when rendered (the suite draws 10 … 10⁴), so a wide sigma point
cannot overflow the lobe.

Prior (per object, from the first observation ``ỹ_0`` and the prior attitude ``q̂_0``):

* ``log ρ``: mean ``log ρ_ref − (ln 10 / 2.5) b_0`` with ``b_0 = ỹ_0 − h_ref(q̂_0)`` the offset of the first sample
  against the renderer at the reference surface (the offset prior of the offset filters, mapped through
  ``b = −2.5 log10(ρ / ρ_ref)``), std ``(ln 10 / 2.5) · offset_std``;
* ``logit F0``, ``log n_u``, ``log n_v``: Gaussian with the mean and standard deviation of the drawing distribution of
  :class:`SurfaceRanges` in those coordinates (uniform F0 mapped to logit, log-uniform ``n`` to log: the mean and the
  std ``width/√12`` of the interval's ends in those coordinates).

:data:`SURFACE_RANGES` are the surfaces this prior expects; the random truths of the generalisation suite
(:mod:`lightcurve_gp.simulation.truths`) draw their surfaces from the same ranges.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from lightcurve_gp.config.schema import Config
from lightcurve_gp.photometry.brdf import Surface
from lightcurve_gp.photometry.render import Scene

__all__ = ["LOG_LOBE_MAX", "PARAMETERS", "SurfaceRanges", "SURFACE_RANGES", "reference_surface", "surface_from_state",
           "surface_state_prior"]

#: lobe exponents are held in [1, e^12 ≈ 1.6e5] when rendered (the truths draw 10 … 10⁴)
LOG_LOBE_MAX = 12.0
#: the state's coordinates, in order
PARAMETERS = ("log_rho", "logit_f0", "log_n_u", "log_n_v")
#: ``d log ρ / d b`` of ``b = −2.5 log10(ρ / ρ_ref)`` (up to sign)
_LOG_RHO_PER_MAG = math.log(10.0) / 2.5


@dataclass(frozen=True)
class SurfaceRanges:
    """Ranges of the Ashikhmin–Shirley parameters of an unknown surface: ρ and F0 uniform, each lobe exponent
    log-uniform."""

    rho: tuple[float, float] = (0.1, 0.9)
    f0: tuple[float, float] = (0.05, 0.95)
    lobe_exponent: tuple[float, float] = (10.0, 1.0e4)


#: the surfaces the prior expects (and the generalisation suite draws)
SURFACE_RANGES = SurfaceRanges()


def surface_from_state(theta: Tensor) -> Surface:
    """The surface of states ``theta (..., 4)`` = (log ρ, logit F0, log n_u, log n_v); every field ``(...)``."""
    log_rho, logit_f0, log_nu, log_nv = theta.unbind(-1)
    n_u, n_v = (v.clamp(0.0, LOG_LOBE_MAX).exp() for v in (log_nu, log_nv))
    return Surface(log_rho.exp(), torch.sigmoid(logit_f0), n_u, n_v)


def reference_surface(cfg: Config) -> Surface:
    """The reference surface of ``cfg``, fields ``(1,)`` (float64): ``model.rho_reference`` and the ``surface``
    section's F0, n_u, n_v (the GP's training surface)."""
    values = (cfg.model.rho_reference, cfg.surface.f0, cfg.surface.n_u, cfg.surface.n_v)
    return Surface(*(torch.tensor([float(v)], dtype=torch.float64) for v in values))


def surface_state_prior(*, scene: Scene, q_est0: Tensor, y0: Tensor, reference: Surface, offset_std: float,
                        ranges: SurfaceRanges = SURFACE_RANGES) -> tuple[Tensor, Tensor]:
    """Prior mean ``(S, 4)`` and standard deviation ``(4,)`` of the surface state (module docstring).

    Args:
        scene: renderer of the known shape and geometry.
        q_est0: prior attitudes ``(S, 4)``; y0: first observations ``(S,)`` (mag; a non-finite one, or a
            non-finite reference prediction, gives ``b_0 = 0``).
        reference: the reference surface, fields ``(1,)``.
        offset_std: prior std of the magnitude offset (mag), mapped to ``log ρ``.
        ranges: the drawing ranges of F0 and the lobe exponents (any object with ``f0`` and ``lobe_exponent``
            pairs, e.g. :class:`~lightcurve_gp.simulation.truths.TruthRanges`).
    """
    S = q_est0.shape[0]
    ref = Surface(*(t.to(q_est0).expand(S) for t in reference))
    b0 = y0.to(q_est0) - scene.magnitude(q_est0.unsqueeze(1), surface=ref)[:, 0]
    b0 = torch.where(torch.isfinite(b0), b0, torch.zeros_like(b0))
    lo_n, hi_n = (math.log(v) for v in ranges.lobe_exponent)
    lo_f, hi_f = (math.log(v / (1.0 - v)) for v in ranges.f0)
    fixed = torch.tensor([(lo_f + hi_f) / 2, (lo_n + hi_n) / 2, (lo_n + hi_n) / 2], dtype=q_est0.dtype)
    mean = torch.cat([(math.log(float(reference.rho[0])) - _LOG_RHO_PER_MAG * b0).unsqueeze(-1),
                      fixed.expand(S, 3)], -1)
    std = torch.tensor([offset_std * _LOG_RHO_PER_MAG, (hi_f - lo_f) / math.sqrt(12), (hi_n - lo_n) / math.sqrt(12),
                        (hi_n - lo_n) / math.sqrt(12)], dtype=q_est0.dtype)
    return mean, std
