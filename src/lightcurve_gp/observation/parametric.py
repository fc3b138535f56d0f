"""The conventional UKF's observation model: the renderer itself, with assumed surface parameters (paper Eq. (8)) or
with the surface as an input carried by the filter (:mod:`lightcurve_gp.observation.surface_state`)."""

from __future__ import annotations

import torch
from torch import Tensor

from lightcurve_gp.observation.base import ObservationModule, Prediction, Variance, check_inputs, check_variance
from lightcurve_gp.observation.surface_state import PARAMETERS, surface_from_state
from lightcurve_gp.photometry.brdf import Surface
from lightcurve_gp.photometry.render import Scene

__all__ = ["RendererModel", "Parametric", "SurfaceStateRenderer"]


class RendererModel(ObservationModule):
    """A model holding a :class:`Scene`, moved with the module by ``.to()``; the renderer ignores ``m_past``."""

    uses_m_past = False

    def __init__(self, scene: Scene) -> None:
        super().__init__()
        self.scene = scene

    def _apply(self, fn, recurse=True):
        # nn.Module.to() reaches tensors through _apply: move the scene (and a surface) with a probe tensor
        probe = fn(self.scene.sun)
        self.scene = self.scene.to(device=probe.device, dtype=probe.dtype)
        if getattr(self, "surface", None) is not None:
            self.surface = self.surface.to(device=probe.device, dtype=probe.dtype)
        return super()._apply(fn, recurse)


class Parametric(RendererModel):
    """``m_app = −26.7 − 2.5 log10(f_obs(q; ρ) / r_obs²)`` with an assumed ρ; ignores ``m_past``.

    The renderer is exact given its parameters, so the predictive variance (``"fast"`` or ``"exact"``) is zero.
    Magnitudes of attitudes with zero flux are NaN (the renderer's policy); the filter refuses such an update and
    counts it.

    Args:
        scene: renderer holding the facets (material ``f0``, ``n_u``, ``n_v``) and the Sun/observer geometry.
        rho: the diffuse reflectance the estimator assumes.
        surface: instead of ``rho``, one whole surface per filter (fields ``(B,)``; the facets' material is
            replaced, see :meth:`Scene.flux_parts`): the model then takes ``q (B, ..., 4)`` of exactly ``B`` filters.
    """

    def __init__(self, scene: Scene, rho: float | None = None, *, surface: Surface | None = None) -> None:
        super().__init__(scene)
        if (rho is None) == (surface is None):
            raise ValueError("give rho or surface, exactly one")
        if rho is not None and not 0.0 <= float(rho) <= 1.0:
            raise ValueError(f"rho: {float(rho):g} is outside [0, 1]")
        self.rho = None if rho is None else float(rho)
        self.surface = surface

    def _predict(self, q: Tensor, m_past: Tensor, variance: Variance) -> Prediction:
        if self.surface is None:
            mean = self.scene.magnitude(q.to(self.scene.sun.dtype), rho=self.rho)
        else:
            mean = self.scene.magnitude(q.to(self.scene.sun.dtype), surface=self.surface)
        return mean, (None if variance == "none" else torch.zeros_like(mean))

    def extra_repr(self) -> str:
        material = f"rho={self.rho:g}" if self.surface is None else f"{self.surface.rho.shape[0]} surfaces"
        return f"{material}, facets={len(self.scene.facets)}"


class SurfaceStateRenderer(RendererModel):
    """The renderer with the surface as an input: ``m_app = h(q; surface_from_state(θ))`` (paper Eq. (8)).

    Called as ``model(q=, m_past=, variance=, theta=)`` with ``q (B, S, 4)`` and ``theta (B, S, 4)``: every point
    is rendered with its own surface (the filter's sigma points, each with its own ``θ``). Exact given ``θ``, so
    its variance is zero; ``m_past`` is ignored. Zero flux gives NaN (the filter refuses that update).

    Args:
        scene: renderer of the known shape and geometry (its facets' material is replaced per point).
    """

    def forward(self, *, q: Tensor, m_past: Tensor, variance: Variance = "fast", theta: Tensor) -> Prediction:
        """``q (..., 4)``, ``theta (..., 4)`` → ``mean (...)`` (mag), variance zeros (or ``None``)."""
        check_variance(variance)
        q, _ = check_inputs(q, m_past)
        if theta.shape[:-1] != q.shape[:-1] or theta.shape[-1] != len(PARAMETERS):
            raise ValueError(f"theta must have shape {tuple(q.shape[:-1]) + (len(PARAMETERS),)} against q of shape "
                             f"{tuple(q.shape)}, got {tuple(theta.shape)}")
        batch = q.shape[:-1]
        flat_q = q.reshape(-1, 1, 4).to(self.scene.sun.dtype)
        surface = surface_from_state(theta.reshape(-1, len(PARAMETERS)).to(flat_q))
        mean = self.scene.magnitude(flat_q, surface=surface).reshape(batch)
        return mean, (None if variance == "none" else torch.zeros_like(mean))

    def extra_repr(self) -> str:
        return f"surface state {', '.join(PARAMETERS)}, facets={len(self.scene.facets)}"
