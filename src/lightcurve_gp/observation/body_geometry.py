"""A GP of the light curve as a function of the body-frame geometry (``model.inputs: body_geometry``).

The light curve of a facet model depends on the attitude and the geometry only through the body-frame Sun and
observer directions ``s_b = A(q) s`` and ``v_b = A(q) v`` (paper Eqs. (2)–(10)) and on the range through
``−5 log10 r`` (Eq. (8)). The GP's input is therefore ``[s_b, v_b]`` (6 numbers, sign-invariant in ``q``) and its
target the magnitude at a reference range, ``y = m + 5 log10(r_ref / r)`` (``model.reference_range_km``): one model
serves every attitude, pass and epoch.

Canonical geometry frame. Every geometry ``(s, v)`` with phase angle ``α`` is a rotation ``C`` of the canonical
one, ``s = C e_x`` and ``v = C (cos α, sin α, 0)``, with ``C = [ŝ, ŵ, ŝ × ŵ]`` and ``ŵ`` the unit part of ``v``
normal to ``s``. So ``[s_b, v_b] = [A(q') e_x, A(q') (cos α, sin α, 0)]`` with ``A(q') = A(q) C``, i.e.
``q' = q ⊗ c`` for ``A(c) = C``. The GP is an ordinary :class:`~.gp_base.CachedGP` whose inputs are ``(q', α)``:
its second input (the ``m_past`` slot of the other input kinds) carries the phase angle in radians. Training
points are drawn in the canonical frame (:mod:`lightcurve_gp.training.geometry`); :class:`GeometryBound` turns a
filter's ``q`` under a real geometry into ``(q', α)`` and adds the range term.
"""

from __future__ import annotations

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import matrix_to_quat, quat_mul
from lightcurve_gp.observation.base import ObservationModel, ObservationModule, Prediction, Variance

__all__ = ["canonical_frame", "GeometryBound", "bound_geometry", "predict_bound"]


def canonical_frame(sun: Tensor, observer: Tensor) -> tuple[Tensor, Tensor]:
    """``(c (..., 4), α (...))``: the quaternion with ``A(c) = [ŝ, ŵ, ŝ × ŵ]`` and the phase angle (rad) of unit
    directions ``sun (..., 3)`` and ``observer (..., 3)``. At ``α = 0`` or ``π`` any ``ŵ ⊥ ŝ`` does."""
    s = sun / torch.linalg.vector_norm(sun, dim=-1, keepdim=True)
    v = observer / torch.linalg.vector_norm(observer, dim=-1, keepdim=True)
    cos_a = (s * v).sum(-1)
    w = v - cos_a.unsqueeze(-1) * s
    w_norm = torch.linalg.vector_norm(w, dim=-1, keepdim=True)
    # degenerate (v ∥ s): the axis of s's smallest component, made normal to s
    axis = torch.nn.functional.one_hot(s.abs().argmin(-1), 3).to(s)
    fallback = axis - (axis * s).sum(-1, keepdim=True) * s
    w = torch.where(w_norm > 1e-12, w, fallback)
    w = w / torch.linalg.vector_norm(w, dim=-1, keepdim=True)
    frame = torch.stack([s, w, torch.linalg.cross(s, w)], -1)  # columns ŝ, ŵ, ŝ × ŵ
    alpha = torch.atan2((torch.linalg.cross(s, v) ** 2).sum(-1).sqrt(), cos_a)
    return matrix_to_quat(frame), alpha


class GeometryBound(ObservationModule):
    """A ``body_geometry`` GP under one geometry: ``m(q) = GP(q ⊗ c, α) − 5 log10(r_ref / r)``.

    Args:
        gp: a model trained with ``model.inputs: body_geometry`` (its ``config`` holds ``reference_range_km``).
        sun, observer: inertial unit directions object → Sun and object → observer ``(3,)``.
        range_m: object–observer distance (m).
    """

    uses_m_past = False

    def __init__(self, gp: ObservationModel, *, sun: Tensor, observer: Tensor, range_m: float | Tensor) -> None:
        super().__init__()
        self.gp = gp
        c, alpha, range_term = bound_geometry(gp, sun=sun, observer=observer, range_m=range_m)
        self.register_buffer("c", c)
        self.register_buffer("alpha", alpha)
        self.register_buffer("range_term", range_term)

    def _predict(self, q: Tensor, m_past: Tensor, variance: Variance) -> Prediction:
        return predict_bound(self.gp, q, c=self.c, alpha=self.alpha, range_term=self.range_term, variance=variance)


def bound_geometry(gp: ObservationModel, *, sun: Tensor, observer: Tensor,
                   range_m: float | Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """``(c (..., 4), α (...), 5 log10(r / r_ref) (...))`` of geometries ``sun``, ``observer`` ``(..., 3)`` and
    ranges (m) for the ``body_geometry`` GP ``gp`` (its ``config`` holds ``reference_range_km``); float64."""
    config = getattr(gp, "config", {})
    if config.get("inputs") != "body_geometry":
        raise ValueError(f"model.inputs: binding a geometry needs a body_geometry GP, this one has "
                         f"{config.get('inputs')!r}")
    f64 = lambda x: torch.as_tensor(x, dtype=torch.float64)  # noqa: E731
    c, alpha = canonical_frame(f64(sun), f64(observer))
    range_term = 5.0 * torch.log10(f64(range_m) / (1e3 * float(config["reference_range_km"])))
    return c, alpha, range_term


def predict_bound(gp: ObservationModel, q: Tensor, *, c: Tensor, alpha: Tensor, range_term: Tensor,
                  variance: Variance) -> Prediction:
    """``GP(q ⊗ c, α) + 5 log10(r / r_ref)`` for ``q (..., 4)`` under one geometry (``c (4,)``, scalars)."""
    mean, var = gp(q=quat_mul(q, c.to(q)), m_past=alpha.to(q).expand(q.shape[:-1]), variance=variance)
    return mean + range_term.to(mean), var
