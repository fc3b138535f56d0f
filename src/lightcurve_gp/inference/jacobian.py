"""Jacobians of batched residual functions: forward-mode differentiation or finite differences.

A residual function of ``B`` independent problems maps states ``x (A, n)`` of the problems ``rows (A,)`` (int64
indices into ``0 … B−1``; a problem may appear in several rows) to residuals ``(A, m)``, row ``a`` depending on
``x[a]`` alone. Its Jacobian is therefore block-diagonal: one ``(m, n)`` block per row, returned as ``(A, m, n)``.

Methods (every one evaluates the function in a single call, so a batched model sees one large batch):

* ``"forward_mode"`` — ``torch.func.jvp`` along each of the ``n`` coordinate directions at once, vectorised with
  ``torch.func.vmap`` over the directions: exact to rounding, no step to choose. Needs a function built from
  differentiable torch operations (no in-place writes into inputs, no NumPy);
* ``"central"`` — ``(r(x + h_i e_i) − r(x − h_i e_i)) / 2h_i``: ``2n + 1`` evaluations in one call, stacked as
  ``[x, x + h_1 e_1, …, x + h_n e_n, x − h_1 e_1, …, x − h_n e_n]`` (blocks of ``A`` rows);
* ``"forward_difference"`` — ``(r(x + h_i e_i) − r(x)) / h_i``: ``n + 1`` evaluations, stacked as
  ``[x, x + h_1 e_1, …, x + h_n e_n]``;
* ``"provided"`` — the residual function's own ``linearize(x, rows) → (r, J)`` (a model that knows its
  derivatives in closed form, e.g. :class:`~lightcurve_gp.inference.trajectory.TrajectoryProblem`).

The finite-difference steps ``h`` carry the units of the states (rad, rad/s, mag, …), one per coordinate or one
for all.
"""

from __future__ import annotations

from typing import Callable, Literal

import torch
from torch import Tensor

__all__ = ["JACOBIAN_METHODS", "JacobianMethod", "ResidualFunction", "jacobian"]

#: ``residual(x (A, n), rows (A,)) → (A, m)``: see the module docstring
ResidualFunction = Callable[[Tensor, Tensor], Tensor]
JacobianMethod = Literal["forward_mode", "central", "forward_difference", "provided"]
JACOBIAN_METHODS = ("forward_mode", "central", "forward_difference", "provided")


def jacobian(residual: ResidualFunction, x: Tensor, rows: Tensor, *, method: JacobianMethod = "forward_mode",
             step: float | Tensor = 1e-6) -> tuple[Tensor, Tensor]:
    """Residuals ``(A, m)`` at ``x (A, n)`` and their Jacobian ``∂r/∂x`` ``(A, m, n)``.

    Args:
        residual: ``residual(x, rows)`` (module docstring).
        x: states ``(A, n)``.
        rows: the problem of each state ``(A,)`` (int64).
        method: one of :data:`JACOBIAN_METHODS`.
        step: finite-difference step, a number or one per coordinate ``(n,)`` (units of ``x``); ignored by
            ``"forward_mode"``.
    """
    if method == "forward_mode":
        return _forward_mode(residual, x, rows)
    if method == "provided":
        if not callable(getattr(residual, "linearize", None)):
            raise ValueError("jacobian method 'provided': the residual function has no linearize(x, rows) method")
        return residual.linearize(x, rows)
    if method not in JACOBIAN_METHODS:
        raise ValueError(f"jacobian method: {method!r} is not one of {', '.join(JACOBIAN_METHODS)}")
    A, n = x.shape
    steps = torch.as_tensor(step, dtype=x.dtype, device=x.device).expand(n)
    if not bool((steps > 0).all()):
        raise ValueError(f"jacobian step: {steps.tolist()} must be > 0")
    shifts = torch.diag(steps)
    if method == "central":
        shifts = torch.cat([shifts, -shifts])
    stacked = torch.cat([x, (x[None] + shifts[:, None]).reshape(-1, n)])
    r_all = residual(stacked, rows.repeat(shifts.shape[0] + 1))
    r, shifted = r_all[:A], r_all[A:].reshape(shifts.shape[0], A, -1)
    if method == "central":
        diff = (shifted[:n] - shifted[n:]) / (2 * steps[:, None, None])
    else:
        diff = (shifted - r) / steps[:, None, None]
    return r, diff.permute(1, 2, 0)


def _forward_mode(residual: ResidualFunction, x: Tensor, rows: Tensor) -> tuple[Tensor, Tensor]:
    """Forward-mode Jacobian: one ``jvp`` per coordinate direction, vectorised over the directions."""
    A, n = x.shape
    directions = torch.eye(n, dtype=x.dtype, device=x.device)[:, None].expand(n, A, n)

    def along(direction: Tensor) -> tuple[Tensor, Tensor]:
        return torch.func.jvp(lambda states: residual(states, rows), (x,), (direction,))

    r, columns = torch.func.vmap(along, out_dims=(None, 0))(directions)
    return r, columns.permute(1, 2, 0)
