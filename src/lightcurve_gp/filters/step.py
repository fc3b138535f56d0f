"""The ω-known USQUE step of ``B`` filters: the prediction as a rotation, then the shared measurement update.

With the body rate known, the prediction model enters only through per-step kinematic increments ``δ_k`` with
``q_{k+1} = normalise(δ_k ⊗ q_k)`` for every attitude (torque-free ω(t) does not depend on ``q``). Propagating a
sigma point ``q_i = δq(χ_i) ⊗ q̂`` to ``δ ⊗ q_i`` and re-expressing it about the propagated centre ``δ ⊗ q̂``
conjugates ``δq(χ_i)`` by ``δ``: its scalar part is kept and its vector part rotated by ``A(δ)``, so the GRP of
the propagated sigma point is ``A(δ) χ_i`` and ``P⁻ = A (P⁺ + Q) Aᵀ + Q`` exactly (Crassidis & Markley 2003).
:func:`usque_prior` computes the prior that way (steps 1–5 of :func:`lightcurve_gp.filters.usque.run_usque`, a
fraction of the work of propagating every sigma quaternion) and :func:`usque_step` adds the measurement update
(:func:`lightcurve_gp.filters.update.measurement_update`, or the iterated one of
:mod:`lightcurve_gp.filters.iterated`). :func:`step_matrices` builds the per-step matrices once
per run; :mod:`lightcurve_gp.filters.compiled` compiles the same step.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import attitude_matrix, quat_left_matrix
from lightcurve_gp.filters.iterated import step_update
from lightcurve_gp.filters.state import FilterState, StateLayout, StepRecord
from lightcurve_gp.filters.unscented import sqrt_psd
from lightcurve_gp.filters.update import Prior, RunConstants, redrawn_sigma_points, sigma_set

__all__ = ["step_major", "step_matrices", "usque_prior", "usque_step"]


def step_major(m: Tensor, *, copy: bool = True) -> tuple[Tensor, ...]:
    """The steps of ``m (1 | B, T, ...)`` as ``T`` tensors ``(1 | B, ...)``, with ``copy`` laid out step-major so that
    their strides do not depend on ``T`` (a compiled step is specialised to its inputs' strides, those of size-1
    dimensions included); without, views of ``m``."""
    return m.transpose(0, 1).clone(memory_format=torch.contiguous_format).unbind(0) if copy else m.unbind(1)


def step_matrices(increments: Tensor, layout: StateLayout, B: int, scale: float) -> tuple[list, list]:
    """Per-step ``L(δ_k) (B, 4, 4)`` and ``√(n+λ) G(δ_k) (B, n, n)`` of increments ``(T, 4)`` or ``(B, T, 4)``, with
    ``G = A(δ)`` on the attitude block and the identity elsewhere (stride 0 over ``B`` when the increments are
    shared). ``normalise(δ ⊗ q) = (δ/|δ|) ⊗ q``: the increments are normalised once."""
    inc = increments / torch.linalg.vector_norm(increments, dim=-1, keepdim=True)
    inc = inc.unsqueeze(0) if inc.ndim == 2 else inc  # (1 | B, T, 4)
    G = torch.eye(layout.dim, dtype=inc.dtype, device=inc.device).repeat(*inc.shape[:-1], 1, 1)
    G[..., :3, :3] = attitude_matrix(inc)
    shared = inc.shape[0] == 1  # per-filter increments are not copied again (B T (4² + n²) values)
    L_steps = [m.expand(B, -1, -1) for m in step_major(quat_left_matrix(inc), copy=shared)]
    G_steps = [m.expand(B, -1, -1) for m in step_major(G * math.sqrt(scale), copy=shared)]
    return L_steps, G_steps


def usque_prior(run: RunConstants, state: FilterState, *, L_k: Tensor, G_k: Tensor) -> Prior:
    """Steps 1–5 with ω known: the prior of ``B`` filters (arguments as :func:`usque_step`'s)."""
    # 1-5. sigma offsets ±√(n+λ) cols √(P⁺ + Q) about x̂⁺ = [0, b̂]; propagated, they are the columns of
    # S⁻ = √(n+λ) G S, x̂⁻ = x̂⁺ and P⁻ = S⁻ S⁻ᵀ/(n+λ) + Q (module docstring); with Q after the propagation only (the
    # paper) S = √P⁺
    s, failed = sqrt_psd(state.P + run.Q if run.q_in_sigma else state.P)
    S_m = torch.bmm(G_k, s)  # (B, n, n): column j = propagated sigma offset j
    P_m = torch.baddbmm(run.Q, S_m, S_m.mT, alpha=1.0 / run.scale)
    q_m = torch.bmm(L_k, state.q_hat.unsqueeze(-1)).squeeze(-1)
    if run.sigma_redraw:
        chi, failed_again = redrawn_sigma_points(run, None, P_m)
        failed = failed | failed_again
    else:
        chi = sigma_set(None, S_m.mT)
    return Prior(q_m, None, None, P_m, chi, failed)


def usque_step(run: RunConstants, state: FilterState, *, L_k: Tensor, G_k: Tensor, y_k: Tensor,
               observed_k: Tensor) -> tuple[FilterState, StepRecord]:
    """One USQUE step of ``B`` filters with ω known (:func:`lightcurve_gp.filters.usque.run_usque` lists the steps
    1–9): :func:`usque_prior`, then the measurement update.

    Args:
        run: the run's constants; state: the posterior at ``k − 1``.
        L_k: ``L(δ_{k−1}) (B, 4, 4)``; G_k: ``√(n+λ) G(δ_{k−1}) (B, n, n)`` (:func:`step_matrices`).
        y_k: observation ``ỹ_k (B,)`` with missing values filled by 0; observed_k: where it is finite ``(B,)``.
    """
    prior = usque_prior(run, state, L_k=L_k, G_k=G_k)
    return step_update(run)(run, state, prior, y_k=y_k, observed_k=observed_k)
