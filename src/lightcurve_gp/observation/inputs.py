"""GP input maps ``x = features(q, m_past)`` (paper section 3.1), kept in a small registry.

The paper's input is ``x = [q1, q2, q3, q4, m_past]`` (kind ``"quaternion"``); ``"attitude_matrix"`` is ``A(q)``;
``"body_geometry"`` the body-frame Sun and observer directions, whose second input is a phase angle
(:mod:`.body_geometry`). Further kinds register a feature function with :func:`register_input_kind`.

:class:`InputMap` applies the feature function and, optionally, a per-dimension standardisation whose
mean/std come from the training inputs and are stored as buffers (so they move with ``.to()`` and are saved).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from lightcurve_gp.attitude.rotations import attitude_matrix, quat_normalize

__all__ = [
    "INPUT_KINDS",
    "InputKind",
    "InputMap",
    "attitude_matrix_features",
    "body_geometry_features",
    "quaternion_features",
    "register_input_kind",
]


@dataclass(frozen=True)
class InputKind:
    """A registered input map: ``fn(q (..., 4), m_past (...)) -> x (..., dim)``."""

    name: str
    dim: int
    fn: Callable[[Tensor, Tensor], Tensor]


INPUT_KINDS: dict[str, InputKind] = {}


def register_input_kind(name: str, dim: int, fn: Callable[[Tensor, Tensor], Tensor]) -> None:
    """Add an input kind; ``fn`` must be batched over leading dimensions and return ``(..., dim)``."""
    if name in INPUT_KINDS:
        raise ValueError(f"input kind {name!r} is already registered")
    INPUT_KINDS[name] = InputKind(name, dim, fn)


def quaternion_features(q: Tensor, m_past: Tensor) -> Tensor:
    """The paper's GP input ``[q1, q2, q3, q4, m_past]`` ``(..., 5)`` (q scalar last, used as given: sign matters)."""
    return torch.cat([q, m_past.unsqueeze(-1).to(q.dtype)], dim=-1)


register_input_kind("quaternion", 5, quaternion_features)


def attitude_matrix_features(q: Tensor, m_past: Tensor) -> Tensor:
    """The attitude matrix ``A(q)`` (inertial → body) flattened row-major ``(..., 9)``; ``m_past`` is not used.

    Sign-invariant (``A(q) = A(−q)``) and attitude-only: the body-frame Sun and observer directions ``A(q) s`` and
    ``A(q) v`` that the light curve depends on (paper Eqs. (8)–(10)) are linear in these features for any geometry, and
    ``‖A(q) − A(q')‖_F² = 4 (1 − cos θ)`` with ``θ`` the angle between the attitudes, so an isotropic kernel on them
    is a kernel on the rotation angle. ``q`` need not be normalised.
    """
    return attitude_matrix(quat_normalize(q)).flatten(-2)


register_input_kind("attitude_matrix", 9, attitude_matrix_features)


def body_geometry_features(q: Tensor, phase_angle: Tensor) -> Tensor:
    """``[s_b, v_b] = [A(q) e_x, A(q) (cos α, sin α, 0)]`` ``(..., 6)``: the body-frame Sun and observer directions
    of the canonical geometry frame (:mod:`lightcurve_gp.observation.body_geometry`); the second input is the phase
    angle ``α`` (rad), not ``m_past``. Sign-invariant in ``q``; ``q`` need not be normalised."""
    a = attitude_matrix(quat_normalize(q))
    s_b = a[..., 0]
    alpha = phase_angle.to(q.dtype).unsqueeze(-1)
    return torch.cat([s_b, torch.cos(alpha) * s_b + torch.sin(alpha) * a[..., 1]], dim=-1)


register_input_kind("body_geometry", 6, body_geometry_features)


class InputMap(nn.Module):
    """Features plus optional standardisation ``(x - shift) / scale``.

    Args:
        kind: a key of :data:`INPUT_KINDS`.
        standardize: fit ``shift``/``scale`` to the training inputs in :meth:`fit`; otherwise they stay 0/1.
    """

    def __init__(self, kind: str = "quaternion", standardize: bool = False):
        super().__init__()
        if kind not in INPUT_KINDS:
            raise ValueError(f"unknown input kind {kind!r} (known: {', '.join(INPUT_KINDS)})")
        self.kind = kind
        self.standardize = bool(standardize)
        dim = INPUT_KINDS[kind].dim
        self.register_buffer("shift", torch.zeros(dim, dtype=torch.float64))
        self.register_buffer("scale", torch.ones(dim, dtype=torch.float64))

    @property
    def dim(self) -> int:
        return INPUT_KINDS[self.kind].dim

    def raw(self, q: Tensor, m_past: Tensor) -> Tensor:
        """Unstandardised features ``(..., dim)``."""
        return INPUT_KINDS[self.kind].fn(q, m_past)

    def fit(self, q: Tensor, m_past: Tensor) -> Tensor:
        """Set the standardisation from training data (when enabled); return the mapped training inputs."""
        x = self.raw(q, m_past)
        if self.standardize:
            flat = x.reshape(-1, x.shape[-1])
            std = flat.std(dim=0) if flat.shape[0] > 1 else torch.ones_like(flat[0])
            # constant columns (std 0) keep scale 1 rather than dividing by zero
            std = torch.where(std > 1e-12 * flat.abs().amax(dim=0).clamp_min(1.0), std, torch.ones_like(std))
            self.shift = flat.mean(dim=0).to(self.shift)
            self.scale = std.to(self.scale)
        return self.transform(x)

    def transform(self, x: Tensor) -> Tensor:
        """Standardise raw features (identity when standardisation is off)."""
        if not self.standardize:
            return x
        return (x - self.shift.to(x.dtype)) / self.scale.to(x.dtype)

    def forward(self, q: Tensor, m_past: Tensor) -> Tensor:
        return self.transform(self.raw(q, m_past))

    def file_state(self) -> dict:
        """Plain-type state for a model file."""
        return {"kind": self.kind, "standardize": self.standardize,
                "shift": self.shift.detach().cpu().clone(), "scale": self.scale.detach().cpu().clone()}

    @classmethod
    def from_file_state(cls, state: dict) -> InputMap:
        m = cls(state["kind"], state["standardize"])
        shift, scale = state["shift"], state["scale"]
        if shift.shape != (m.dim,) or scale.shape != (m.dim,):
            raise ValueError(f"input normalisation has shape {tuple(shift.shape)}/{tuple(scale.shape)}, "
                             f"expected ({m.dim},)")
        m.shift = shift.to(torch.float64)
        m.scale = scale.to(torch.float64)
        return m
