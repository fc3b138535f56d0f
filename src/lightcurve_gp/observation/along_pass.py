"""Observation models along a pass: each filter step predicts with the geometry of its own sample.

:func:`bind_geometry` fixes a model to one sample's geometry: a renderer model (:class:`~.parametric.Parametric`,
:class:`~.parametric.SurfaceStateRenderer`) is re-aimed, a ``body_geometry`` GP is wrapped in
:class:`~.body_geometry.GeometryBound`, and a model that knows no geometry (a GP trained under one fixed geometry,
the paper's assumption) is returned as it is.

:class:`AlongPass` is what the filter gets: :func:`lightcurve_gp.filters.usque.run_usque` calls its model exactly once
per
step ``k = 1 … T`` with all filters' sigma points, so call ``j`` of an ``AlongPass(model, geometry, first=1)``
predicts sample ``k = j + 1``. It is an iterator over the pass and serves one run; a call past the last sample is an
error, never a silent reuse of a geometry.
"""

from __future__ import annotations

import copy

from torch import Tensor

from lightcurve_gp.observation.base import ObservationModel, ObservationModule, Prediction, Variance
from lightcurve_gp.observation.body_geometry import GeometryBound, bound_geometry, predict_bound
from lightcurve_gp.observation.parametric import RendererModel

__all__ = ["bind_geometry", "AlongPass", "pass_models"]


def bind_geometry(model: ObservationModel, *, sun: Tensor, observer: Tensor, range_m: float) -> ObservationModel:
    """``model`` under one geometry: unit directions object → Sun and object → observer ``(3,)``, range in m."""
    if isinstance(model, RendererModel):  # the same renderer model, its scene re-aimed
        bound = copy.copy(model)
        bound.scene = model.scene.with_geometry(sun.to(model.scene.sun), observer.to(model.scene.sun), float(range_m))
        return bound
    if getattr(model, "config", {}).get("inputs") == "body_geometry":
        return GeometryBound(model, sun=sun, observer=observer, range_m=float(range_m))
    return model


class AlongPass(ObservationModule):
    """``model`` at samples ``first, first + 1, …`` of ``geometry`` (a :class:`~lightcurve_gp.passes.geometry.
    PassGeometry`), one sample per call (module docstring)."""

    def __init__(self, model: ObservationModel, geometry, *, first: int = 1) -> None:
        super().__init__()
        self.model = model
        self.geometry = geometry
        self.next_sample = int(first)
        self.uses_m_past = bool(getattr(model, "uses_m_past", True))
        # a body_geometry GP: every sample's canonical frame, phase angle and range term at once
        self._frames = (bound_geometry(model, sun=geometry.sun, observer=geometry.observer, range_m=geometry.range_m)
                        if getattr(model, "config", {}).get("inputs") == "body_geometry" else None)

    def forward(self, *, q: Tensor, m_past: Tensor, variance: Variance = "fast", **inputs: Tensor) -> Prediction:
        """The prediction of the next sample; further model inputs (the filter's ``theta``) are passed on."""
        if inputs:
            return self._bound_model()(q=q, m_past=m_past, variance=variance, **inputs)
        return super().forward(q=q, m_past=m_past, variance=variance)

    def _advance(self) -> int:
        k = self.next_sample
        if k >= len(self.geometry):
            raise RuntimeError(f"AlongPass: called for sample {k} of a pass of {len(self.geometry)} samples")
        self.next_sample += 1
        return k

    def _bound_model(self) -> ObservationModel:
        k, g = self._advance(), self.geometry
        return bind_geometry(self.model, sun=g.sun[k], observer=g.observer[k], range_m=float(g.range_m[k]))

    def _predict(self, q: Tensor, m_past: Tensor, variance: Variance) -> Prediction:
        if self._frames is None:
            return self._bound_model()(q=q, m_past=m_past, variance=variance)
        k = self._advance()
        c, alpha, range_term = (t[k] for t in self._frames)
        return predict_bound(self.model, q, c=c, alpha=alpha, range_term=range_term, variance=variance)


def pass_models(model: ObservationModel, geometry) -> tuple[ObservationModel, ObservationModel]:
    """``(model at sample 0, model of steps 1 … T)`` along a pass ``geometry`` (a
    :class:`~lightcurve_gp.passes.geometry.PassGeometry`): sample 0 bound once (the filter's initial offset), the steps
    through :class:`AlongPass`."""
    g = geometry
    return (bind_geometry(model, sun=g.sun[0], observer=g.observer[0], range_m=float(g.range_m[0])),
            AlongPass(model, g, first=1))
