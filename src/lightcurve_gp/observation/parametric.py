"""The conventional UKF's observation model: the renderer itself with assumed surface parameters (paper Eq. (8))."""

from __future__ import annotations

import torch
from torch import Tensor

from ..brdf import Surface
from ..render import Scene
from .base import ObservationModule, Prediction, Variance

__all__ = ["Parametric"]


class Parametric(ObservationModule):
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

    uses_m_past = False

    def __init__(self, scene: Scene, rho: float | None = None, *, surface: Surface | None = None) -> None:
        super().__init__()
        if (rho is None) == (surface is None):
            raise ValueError("give rho or surface, exactly one")
        if rho is not None and not 0.0 <= float(rho) <= 1.0:
            raise ValueError(f"rho: {float(rho):g} is outside [0, 1]")
        self.scene = scene
        self.rho = None if rho is None else float(rho)
        self.surface = surface

    def _apply(self, fn, recurse=True):
        # nn.Module.to() reaches tensors through _apply: move the scene with a probe tensor
        probe = fn(self.scene.sun)
        self.scene = self.scene.to(device=probe.device, dtype=probe.dtype)
        if self.surface is not None:
            self.surface = self.surface.to(device=probe.device, dtype=probe.dtype)
        return super()._apply(fn, recurse)

    def _predict(self, q: Tensor, m_past: Tensor, variance: Variance) -> Prediction:
        if self.surface is None:
            mean = self.scene.magnitude(q.to(self.scene.sun.dtype), rho=self.rho)
        else:
            mean = self.scene.magnitude(q.to(self.scene.sun.dtype), surface=self.surface)
        return mean, (None if variance == "none" else torch.zeros_like(mean))

    def extra_repr(self) -> str:
        material = f"rho={self.rho:g}" if self.surface is None else f"{self.surface.rho.shape[0]} surfaces"
        return f"{material}, facets={len(self.scene.facets)}"
