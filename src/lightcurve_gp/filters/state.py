"""The state and the record of a batched USQUE run: the state's block layout, the posterior carried from step to
step, what each step records, and the history a run returns (:mod:`lightcurve_gp.filters.usque`).

State layout ``[δp (3, GRP attitude error), ω (3, body rate), b (1, magnitude offset), θ (p, observation-model
parameters)]``, a block present only when it is estimated: ω by the rate filter (:mod:`lightcurve_gp.filters.rates`),
``b`` by the offset filter, ``θ`` (e.g. the surface's reflectance parameters) by a filter whose model takes them as
inputs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import torch
from torch import Tensor

__all__ = ["FilterHistory", "FilterState", "HistoryBuilder", "StateLayout", "StepRecord"]


@dataclass(frozen=True)
class StateLayout:
    """Blocks of the filter state ``[δp (3), ω (3), b (1), θ (p)]``, each present only when estimated.

    Attributes:
        offset: whether the magnitude offset ``b`` is in the state.
        omega: whether the body rate ω (rad/s) is in the state.
        parameters: ``p``, the number of observation-model parameters ``θ`` in the state (0: none).
    """

    offset: bool = False
    omega: bool = False
    parameters: int = 0

    @property
    def dim(self) -> int:
        return 3 + 3 * int(self.omega) + int(self.offset) + self.parameters

    @property
    def omega_slice(self) -> slice:
        """Indices of ω in the state (after ``δp``)."""
        return slice(3, 6)

    @property
    def offset_index(self) -> int:
        """Index of ``b`` in the state (after ``δp`` and ω)."""
        return 3 + 3 * int(self.omega)

    @property
    def parameter_slice(self) -> slice:
        """Indices of ``θ`` in the state (after ``δp``, ω and ``b``)."""
        start = 3 + 3 * int(self.omega) + int(self.offset)
        return slice(start, start + self.parameters)


class FilterState(NamedTuple):
    """The posterior of ``B`` filters at one step: ``q̂ (B, 4)``, ``b̂ (B,)`` (``None`` when not estimated),
    ``P (B, n, n)`` of the state about ``[0, ω̂, b̂]``, the running mean ``m_past (B,)`` for the next prediction,
    with adaptive measurement noise the running average ``noise_excess (B,)`` of the innovation excess (mag²;
    ``R̂ = max(R, noise_excess)``, :func:`lightcurve_gp.filters.usque.adapted_noise`), else ``None``; the estimated
    observation-model parameters ``theta (B, p)``, or ``None``; and the body-rate estimate ``omega (B, 3)`` (rad/s)
    when ω is in the state, else ``None``."""

    q_hat: Tensor
    offset: Tensor | None
    P: Tensor
    m_past: Tensor
    noise_excess: Tensor | None = None
    theta: Tensor | None = None
    omega: Tensor | None = None


class StepRecord(NamedTuple):
    """What one step records (all ``(B,)``): prediction ``y_pred``, ``Pyy``, mean model variance, innovation,
    the ``m_past`` used, whether it updated, whether the square root fell back and whether it was refused."""

    y_pred: Tensor
    y_var: Tensor
    model_var: Tensor
    innovation: Tensor
    m_past: Tensor
    updated: Tensor
    fallback: Tensor
    rejected: Tensor


@dataclass
class FilterHistory:
    """Everything a batched USQUE run records, indexed by filter ``b`` and time index ``k = 0 … T``.

    Attributes:
        q_est: posterior attitude estimates ``(B, T+1, 4)`` (``k = 0``: the initial estimate).
        P: posterior GRP-error covariances ``(B, T+1, 3, 3)`` (rad², GRP ≈ rotation vector to first order).
        P_full: posterior covariances of the whole state ``(B, T+1, n, n)`` (:class:`StateLayout`).
        y_pred: predicted magnitude ``ŷ_k`` ``(B, T+1)``; NaN at ``k = 0``.
        y_var: innovation variance ``Pyy`` (incl. R and model variance) ``(B, T+1)``; NaN at ``k = 0``.
        model_var: mean model variance ``Σ wm var_i`` ``(B, T+1)``; NaN at ``k = 0`` or when not requested.
        innovation: ``ỹ_k − ŷ_k`` ``(B, T+1)`` (NaN where ``ỹ_k`` is NaN and at ``k = 0``).
        m_past: the running mean fed to the model at step ``k`` (before ``ỹ_k`` is folded in) ``(B, T+1)``.
        updated: whether step ``k`` applied a measurement update ``(B, T+1)`` (False at ``k = 0``).
        fallbacks: number of steps whose sigma-point square root fell back ``(B,)``.
        rejected: number of steps with a finite observation whose update was refused because the prediction
            was not finite or ``Pyy ≤ 0`` ``(B,)`` (the prior became the posterior).
        m_past_final: the running mean after the last observation ``(B,)``.
        offset: posterior offset estimates ``b_k`` ``(B, T+1)`` (mag; ``k = 0`` the prior mean), or ``None``.
        offset_var: posterior offset variances ``(B, T+1)`` (mag²), or ``None``.
        theta: posterior estimates of the observation-model parameters ``(B, T+1, p)`` (the model's units), or
            ``None``; their variances are the diagonal of ``P_full`` at :attr:`StateLayout.parameter_slice`.
        omega: posterior body-rate estimates ``(B, T+1, 3)`` (rad/s; ``k = 0`` the prior mean) when ω is in the
            state, else ``None``; their covariances are ``P_full[..., 3:6, 3:6]`` (rad²/s²).
    """

    q_est: Tensor
    P: Tensor
    P_full: Tensor
    y_pred: Tensor
    y_var: Tensor
    model_var: Tensor
    innovation: Tensor
    m_past: Tensor
    updated: Tensor
    fallbacks: Tensor
    rejected: Tensor
    m_past_final: Tensor
    offset: Tensor | None = None
    offset_var: Tensor | None = None
    theta: Tensor | None = None
    omega: Tensor | None = None

    def nis(self) -> Tensor:
        """Normalised innovation squared ``ν² / Pyy`` ``(B, T+1)`` (NaN where no innovation)."""
        return self.innovation ** 2 / self.y_var


@dataclass
class HistoryBuilder:
    """Collects the initial state and every step, then stacks them into a :class:`FilterHistory`."""

    layout: StateLayout
    states: list[FilterState] = field(default_factory=list)
    records: list[StepRecord] = field(default_factory=list)

    def add(self, state: FilterState, record: StepRecord) -> None:
        self.states.append(state)
        self.records.append(record)

    def build(self, observed: Tensor, final: FilterState) -> FilterHistory:
        """``observed (B, T+1)``: where the observation was finite; ``final``: the state after the last step."""
        cols = {name: torch.stack([getattr(r, name) for r in self.records], 1) for name in StepRecord._fields}
        P_full = torch.stack([s.P for s in self.states], 1)
        offset = omega = None
        if self.layout.offset:
            offset = torch.stack([s.offset for s in self.states], 1)
        if self.layout.omega:
            omega = torch.stack([s.omega for s in self.states], 1)
        theta = torch.stack([s.theta for s in self.states], 1) if self.layout.parameters else None
        i = self.layout.offset_index
        return FilterHistory(
            q_est=torch.stack([s.q_hat for s in self.states], 1), P=P_full[..., :3, :3], P_full=P_full,
            y_pred=cols["y_pred"], y_var=cols["y_var"], model_var=cols["model_var"],
            innovation=torch.where(observed, cols["innovation"], math.nan), m_past=cols["m_past"],
            updated=cols["updated"], fallbacks=cols["fallback"].sum(1), rejected=cols["rejected"].sum(1),
            m_past_final=final.m_past, offset=offset, offset_var=P_full[..., i, i] if self.layout.offset else None,
            theta=theta, omega=omega)
