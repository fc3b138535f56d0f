"""Unknown zero points of relative light curves, profiled out of whitened residuals exactly.

A relative light curve ``c`` (its zero point unknown) predicts ``m_k + b_c`` for its samples. With whitened
residuals ``r_k = w_k (ỹ_k − m_k − b_c)`` (``w_k = 1/σ_k``) the cost ``½ Σ r_k²`` is quadratic in ``b_c``, minimised
by the weighted mean ``b_c = Σ_{k∈c} w_k² (ỹ_k − m_k) / Σ_{k∈c} w_k²``. Putting it back is the orthogonal
projection of the residual vector away from the columns ``w ⊙ 1_c``, and the same projection of the Jacobian's
columns is the exact Jacobian of the profiled residuals (variable projection: the offsets are linear), so every
solver sees a state without the offsets and the cost it would have had with them at their best. A sample left out
(weight 0 or a residual that is not finite) takes no part in its curve's mean.

Tensors: residuals ``(..., K)``, weights ``(K,)`` or ``(..., K)`` (mag⁻¹), the indicator ``(K, C)`` of the relative
curves' samples (:meth:`lightcurve_gp.observations.Observations.zero_point_indicator`), offsets ``(..., C)`` (mag).
"""

from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["profile_zero_points"]


def profile_zero_points(r: Tensor, weight: Tensor, indicator: Tensor, *, jacobian: Tensor | None = None
                        ) -> tuple[Tensor, Tensor, Tensor | None]:
    """``(r', offsets, J')``: the residuals ``r (..., K)`` with each relative curve's best offset removed, those
    offsets ``(..., C)`` (mag, added to the prediction) and, when given, the Jacobian ``(..., K, n)`` of ``r``
    projected the same way (module docstring)."""
    w = torch.broadcast_to(weight, r.shape)
    ok = torch.isfinite(r) & (w > 0)
    w = torch.where(ok, w, 0.0)
    z = indicator.to(r.dtype)
    denom = (w * w) @ z  # (..., C)
    safe = torch.where(denom > 0, denom, torch.ones_like(denom))
    offsets = torch.where(denom > 0, (w * torch.where(ok, r, 0.0)) @ z / safe, 0.0)  # Σ w² d / Σ w², d = r / w
    projected = r - w * (offsets @ z.T)
    if jacobian is None:
        return projected, offsets, None
    jw = w.unsqueeze(-1) * torch.where(ok.unsqueeze(-1), jacobian, 0.0)  # (..., K, n)
    per_curve = torch.einsum("kc,...kn->...cn", z, jw) / safe.unsqueeze(-1)  # (..., C, n)
    return projected, offsets, jacobian - w.unsqueeze(-1) * torch.einsum("kc,...cn->...kn", z, per_curve)
