"""Batched USQUE: the unscented quaternion estimator of the GPUKF and the conventional UKF.

Paper sections 2.5 (UKF) and 3.3 (GPUKF); USQUE after Crassidis & Markley (2003), "Unscented filtering for
spacecraft attitude estimation". Many independent filters advance together (:func:`run_usque`): every tensor carries
a leading batch dimension ``B`` and one step of all filters is a handful of batched tensor operations.

State layout ``[δp (3, GRP attitude error), ω (3), b (1, magnitude offset), θ (p, model parameters)]`` with a block
present only when it is estimated (:class:`StateLayout`): ``δp`` always, ``b`` with an offset prior
(``y = h(q, m_past) + b``, the bias-state pattern of Crassidis & Markley's gyro-bias filter, here a measurement bias),
``θ`` with a parameter prior (``y = h(q, m_past; θ)``: the model takes each sigma point's ``θ``, e.g. the surface's
reflectance parameters, :mod:`lightcurve_gp.observation.surface_state`), ω with a rate prior.

Step ``k = 1 … T`` (Crassidis & Markley 2003, Q added to the sigma-point covariance and again to ``P⁻``):

1. ``χ_i = x̂⁺ ± cols √((n+λ)(P⁺ + Q))`` with ``x̂⁺ = [0, ω̂, b̂, θ̂]``; 2. ``q_i = grp_to_quat(χ_i) ⊗ q̂``;
3. ``q_i⁻ = normalise(δ_{k−1} ⊗ q_i)`` (ω in the state: ``(q_i⁻, ω_i⁻) = RK4(q_i, ω_i)``);
4. ``χ_i⁻ = [quat_to_grp(q_i⁻ ⊗ (q_0⁻)⁻¹), ω_i⁻]``, ``b_i`` and ``θ_i`` unchanged;
5. ``x̂⁻ = Σ wm χ_i⁻``, ``P⁻ = Σ wc (χ_i⁻ − x̂⁻)(·)ᵀ + Q``;
6. ``Y_i = model(q_i⁻, m_past[, θ_i]) (+ b_i)``, ``ŷ = Σ wm Y_i``, ``Pyy = Σ wc (Y_i − ŷ)² + R (+ Σ wm var_i)``,
   ``Pxy = Σ wc (χ_i⁻ − x̂⁻)(Y_i − ŷ)``;
7. ``K = Pxy / Pyy``, ``x̂⁺ = x̂⁻ + K (ỹ_k − ŷ)``, ``P⁺ = P⁻ − K Pyy Kᵀ``;
8. reset ``q̂ ← grp_to_quat(x̂⁺[:3]) ⊗ q_0⁻``, ``ω̂ ← x̂⁺[ω]``, ``b̂ ← x̂⁺[b]``, ``θ̂ ← x̂⁺[θ]``;
9. ``m_past ← (T m_past + ỹ_k) / (T + 1)``.

The paper's variant (``UsqueParams.q_placement = "after"``, ``sigma_redraw``): step 1 without ``Q`` and, before
step 6, ``χ_i⁻ = x̂⁻ ± cols √((n+λ) P⁻)`` drawn again (paper Sec. 2.5, Eqs. (29)–(42)).

With ω known, steps 2–5 are a rotation, ``χ_i⁻ = A(δ) χ_i`` and ``P⁻ = A (P⁺ + Q) Aᵀ + Q``
(:mod:`lightcurve_gp.filters.step`), optionally compiled (:mod:`lightcurve_gp.filters.compiled`); with ω in the state
every sigma point moves with its own rate (:mod:`lightcurve_gp.filters.rates`): the torque-free Euler equations and
the kinematics by RK4 (``UsqueParams.inertia``, ``dt``), all ``B (2n+1)`` sigma points in one call. Both share the
measurement update (:mod:`lightcurve_gp.filters.update`). With ``adaptive_noise = "innovation"`` the ``R`` of step 6
is each filter's ``R̂_k = max(R, c_k)``, ``c`` the running average of the innovation excess of the steps before
(:func:`adapted_noise`).

A NaN observation skips steps 7 and 9 for that filter only (the prior becomes the posterior). A finite observation
whose prediction is not finite or whose ``Pyy ≤ 0`` is refused the same way and counted in ``rejected``; its
``m_past`` recursion still happens (the observation is real).

Conventions (docs/design.md, paper Sec. 2.3): scalar-last quaternions, paper product ``⊗``, error
``q_err = q_true ⊗ q_est⁻¹``, GRP ``p = f q̄ / (a + q4)``. The sign of ``q̂`` is never canonicalised inside the
filter: it stays continuous along a run, because ``q`` and ``−q`` are different inputs to a GP observation model.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Callable

import torch
from torch import Tensor

from lightcurve_gp.attitude.dynamics import rk4_stepper
from lightcurve_gp.filters.compiled import compiled_stepper
from lightcurve_gp.filters.iterated import step_update
from lightcurve_gp.filters.rates import rate_prior
from lightcurve_gp.filters.state import FilterHistory, FilterState, HistoryBuilder, StateLayout, StepRecord
from lightcurve_gp.filters.step import step_major, step_matrices, usque_step
from lightcurve_gp.filters.unscented import UnscentedWeights, symmetrise, unscented_weights, warn_fallbacks
from lightcurve_gp.filters.update import RunConstants, adapted_noise
from lightcurve_gp.observation.base import ObservationModel, Variance, check_variance

__all__ = ["FilterHistory", "FilterState", "StateLayout", "StepRecord", "UsqueParams", "initial_covariance",
           "model_error_variance", "run_constants", "run_usque", "usque_step", "adapted_noise", "ADAPTIVE_NOISE",
           "Q_PLACEMENTS"]

#: measurement-noise rules of :class:`UsqueParams`: fixed ``R`` or innovation-based covariance matching
ADAPTIVE_NOISE = ("none", "innovation")
#: where the process noise enters: ``both`` — added to ``P⁺`` before the sigma points and again to ``P⁻``
#: (Crassidis & Markley 2003); ``after`` — once, to ``P⁻`` after the propagation (the paper, Sec. 2.5)
Q_PLACEMENTS = ("both", "after")
#: rules for the unscented λ (:class:`UsqueParams`)
LAM_RULES = ("given", "julier")


def model_error_variance(cfg, model) -> float:
    """What ``filter.model_error`` adds to a filter's ``R`` for ``model`` (mag²): 0 with ``none`` or for a model that
    is not trained (the renderers, exact given their inputs, carry no training ``config``); with ``heldout`` the
    excess variance of the trained model's held-out set (:func:`lightcurve_gp.training.fit.heldout_metrics`, stored
    in its file by ``train``): the squared error its own predictive variance does not cover. A trained model without
    those metrics (an older file, or one built in memory) is refused."""
    if cfg.filter.model_error == "none" or getattr(model, "config", None) is None:
        return 0.0
    heldout = (getattr(model, "extra", None) or {}).get("heldout") or {}
    if "excess_variance" not in heldout:
        raise ValueError("filter.model_error: heldout needs the held-out metrics that train stores in the model "
                         "file; this model file has none: train it again")
    return float(heldout["excess_variance"])


@dataclass(frozen=True, eq=False)
class UsqueParams:
    """USQUE tuning (defaults: the paper's filter, ``configs/boxwing.yaml``).

    Attributes:
        alpha, beta, kappa: unscented tuning parameters.
        lam: λ given directly; ``None`` derives ``α² (n + κ) − n``.
        lam_rule: ``"given"`` (``lam`` as above) or ``"julier"``: ``λ = 3 − n`` for every state dimension ``n``
            (Julier and Uhlmann's ``κ = 3 − n``, which matches the fourth moment of a Gaussian along each sigma
            axis; at ``n = 3`` it is the paper's ``λ = 0``, so the attitude-only filter is unchanged).
        grp_a, grp_f: GRP parameters ``a`` and ``f``.
        Q: process noise on the GRP error per step (rad²): scalar (× I), ``(3, 3)`` or ``(B, 3, 3)``.
        R: measurement noise variance (mag²): scalar, ``(B,)`` or per sample ``(B, T+1)`` (e.g. ``mag_err²`` of a
            light-curve file; column ``k`` is used at step ``k``, column 0 is not used).
        variance: what the filter asks of the observation model (``"none"``, ``"fast"``, ``"exact"``); unless
            ``"none"``, the mean predictive variance ``Σ wm var_i`` is added to ``Pyy``.
        t_span_past: ``T`` of the running mean ``m_past ← (T m_past + ỹ) / (T + 1)`` (paper Sec. 3.3, Eq. (54)).
        offset_process_noise: random-walk variance of the offset ``b`` per step (mag²), when ``b`` is estimated.
        parameter_process_noise: random-walk variance of each model parameter ``θ_j`` per step (its units²), when
            ``θ`` is estimated.
        adaptive_noise: ``"none"`` (``R`` fixed) or ``"innovation"``: each filter's ``R̂_k`` by covariance matching
            (:func:`adapted_noise`).
        adaptive_noise_rate: ``λ = dt / τ`` of that rule's exponential average, in ``(0, 1]``.
        omega_process_noise: variance added to each body-rate component per step (rad²/s², a torque noise), when
            ω is estimated.
        inertia: principal moments ``(3,)`` (kg m²) of the rate filter's torque-free dynamics.
        dt: step of the rate filter's RK4 propagation (s).
        sigma_redraw: update with sigma points drawn again from ``(x̂⁻, P⁻)`` (the paper) instead of the
            propagated ones (Crassidis & Markley).
        q_placement: one of :data:`Q_PLACEMENTS`.
        update_iterations: posterior linearisations per measurement update (:mod:`lightcurve_gp.filters.iterated`);
            1: the ordinary unscented update.
        compile: with ω known, run each step as compiled graphs (:mod:`lightcurve_gp.filters.compiled`): the same
            estimates to rounding, a fraction of the per-step dispatch; the first step of each shape compiles
            (seconds: off by default, it pays from thousands of steps on, ``benchmarks/bench_compile.py``).
    """

    alpha: float = 1e-4
    beta: float = 2.0
    kappa: float = 0.0
    lam: float | None = 0.0
    lam_rule: str = "given"
    grp_a: float = 1.0
    grp_f: float = 4.0
    Q: float | Tensor = 1e-4
    R: float | Tensor = 0.5
    variance: Variance = "fast"
    t_span_past: float = 20.0
    offset_process_noise: float = 0.0
    parameter_process_noise: float = 0.0
    adaptive_noise: str = "none"
    adaptive_noise_rate: float = 0.01
    omega_process_noise: float = 0.0
    inertia: tuple[float, float, float] = (55.0, 40.0, 65.0)
    dt: float = 1.0
    sigma_redraw: bool = False
    q_placement: str = "both"
    compile: bool = False
    update_iterations: int = 1

    def __post_init__(self):
        if int(self.update_iterations) < 1:
            raise ValueError(f"update_iterations must be >= 1, got {self.update_iterations!r}")
        if self.compile and int(self.update_iterations) > 1:
            raise ValueError("compile: the compiled step has the ordinary update only (update_iterations 1)")
        if self.lam_rule not in LAM_RULES:
            raise ValueError(f"lam_rule must be one of {', '.join(LAM_RULES)}, got {self.lam_rule!r}")
        if self.q_placement not in Q_PLACEMENTS:
            raise ValueError(f"q_placement must be one of {', '.join(Q_PLACEMENTS)}, got {self.q_placement!r}")
        if not float(self.omega_process_noise) >= 0.0:
            raise ValueError(f"omega_process_noise must be >= 0, got {self.omega_process_noise!r}")
        check_variance(self.variance)
        if self.adaptive_noise not in ADAPTIVE_NOISE:
            raise ValueError(f"adaptive_noise must be one of {', '.join(ADAPTIVE_NOISE)}, got {self.adaptive_noise!r}")
        if not 0.0 < float(self.adaptive_noise_rate) <= 1.0:
            raise ValueError(f"adaptive_noise_rate must be in (0, 1], got {self.adaptive_noise_rate!r}")
        for name in ("offset_process_noise", "parameter_process_noise"):
            if not float(getattr(self, name)) >= 0.0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if not float(self.t_span_past) >= 0:
            raise ValueError(f"t_span_past must be >= 0, got {self.t_span_past}")

    @classmethod
    def from_config(cls, cfg, *, model=None) -> UsqueParams:
        """Parameters of a :class:`~lightcurve_gp.config.load.Config`: its ``filter`` section
        (``Q = process_noise · I``), ``data.t_span_past``, ``model.variance`` (``"none"`` unless
        ``filter.add_model_variance``) and the adaptive noise rule with
        ``λ = min(1, scenario.dt_s / filter.adaptive_noise_time_s)``, the rate filter's ``filter.omega_process_noise``,
        ``filter.inertia_kg_m2`` (default ``shape.inertia_kg_m2``) and ``scenario.dt_s``, the variant
        (``filter.sigma_redraw``, ``filter.q_placement``), ``filter.update_iterations`` and ``filter.compile``. With
        ``filter.model_error: heldout`` ``R`` also holds the trained ``model``'s held-out excess variance
        (:func:`model_error_variance`)."""
        f = cfg.filter
        return cls(
            alpha=float(f.alpha), beta=float(f.beta), kappa=float(f.kappa), lam=None if f.lam is None else float(f.lam),
            lam_rule=f.lam_rule,
            grp_a=float(f.grp_a), grp_f=float(f.grp_f), Q=float(f.process_noise),
            R=float(f.measurement_noise) + model_error_variance(cfg, model),
            variance=cfg.model.variance if f.add_model_variance else "none", t_span_past=float(cfg.data.t_span_past),
            offset_process_noise=float(f.offset_process_noise), adaptive_noise=f.adaptive_noise,
            adaptive_noise_rate=min(1.0, float(cfg.scenario.dt_s) / float(f.adaptive_noise_time_s)),
            omega_process_noise=float(f.omega_process_noise),
            inertia=tuple(float(j) for j in (f.inertia_kg_m2 or cfg.shape.inertia_kg_m2)),
            dt=float(cfg.scenario.dt_s), sigma_redraw=bool(f.sigma_redraw), q_placement=f.q_placement,
            compile=bool(f.compile), update_iterations=int(f.update_iterations),
        )

    def weights(self, n: int = 3, *, dtype: torch.dtype | None = None, device=None) -> UnscentedWeights:
        """Sigma-point weights for an ``n``-dimensional state (3: the GRP error alone)."""
        lam = 3.0 - n if self.lam_rule == "julier" else self.lam
        return unscented_weights(n, self.alpha, self.beta, self.kappa, lam, dtype=dtype, device=device)


def initial_covariance(p0_deg: float, *, dtype: torch.dtype | None = None, device=None) -> Tensor:
    """``P0 = (p0_deg in rad)² I₃`` (config ``filter.p0_deg``)."""
    return math.radians(p0_deg) ** 2 * torch.eye(3, dtype=dtype or torch.get_default_dtype(), device=device)


def _check_run_inputs(q_est0: Tensor, P0: Tensor, offset0: Tensor | None, theta0: Tensor | None,
                      omega0: Tensor | None, observations: Tensor, m_past0: Tensor, increments: Tensor | None,
                      layout: StateLayout) -> tuple[int, int]:
    """Shapes and finiteness of a run's inputs; returns ``(B, T)``."""
    if q_est0.ndim != 2 or q_est0.shape[-1] != 4:
        raise ValueError(f"q_est0 must have shape (B, 4), got {tuple(q_est0.shape)}")
    B = q_est0.shape[0]
    if observations.ndim != 2 or observations.shape[0] != B:
        raise ValueError(f"observations must have shape (B={B}, T+1), got {tuple(observations.shape)}")
    T = observations.shape[1] - 1
    if T < 0:
        raise ValueError("observations must hold at least t_0")
    if (increments is None) == (omega0 is None):
        raise ValueError("give increments (omega known) or omega0 (omega estimated), not both or neither")
    n = layout.dim
    if P0.shape not in ((n, n), (B, n, n)):
        names = ["dp"] + ["omega"] * layout.omega + ["b"] * layout.offset \
            + [f"theta ({layout.parameters})"] * bool(layout.parameters)
        state = f" for the state [{', '.join(names)}]" if len(names) > 1 else ""
        raise ValueError(f"P0 must have shape ({n}, {n}) or (B={B}, {n}, {n}){state}, got {tuple(P0.shape)}")
    if offset0 is not None and offset0.shape not in ((B,), ()):
        raise ValueError(f"offset0 must have shape (B={B},) or (), got {tuple(offset0.shape)}")
    p = layout.parameters
    if theta0 is not None and theta0.shape not in ((B, p), (p,)):
        raise ValueError(f"theta0 must have shape (B={B}, {p}) or ({p},), got {tuple(theta0.shape)}")
    if omega0 is not None and omega0.shape not in ((B, 3), (3,)):
        raise ValueError(f"omega0 must have shape (B={B}, 3) or (3,), got {tuple(omega0.shape)}")
    if m_past0.shape not in ((B,), ()):
        raise ValueError(f"m_past0 must have shape (B={B},), got {tuple(m_past0.shape)}")
    if increments is not None and increments.shape not in ((T, 4), (B, T, 4)):
        raise ValueError(f"increments must have shape (T={T}, 4) or (B={B}, T={T}, 4), got {tuple(increments.shape)}")
    named = [("q_est0", q_est0), ("P0", P0), ("offset0", offset0), ("theta0", theta0), ("omega0", omega0),
             ("m_past0", m_past0), ("increments", increments)]
    for name, t in named:
        if t is not None and not bool(torch.isfinite(t).all()):
            raise ValueError(f"{name} contains non-finite values")
    return B, T


def _process_noise(params: UsqueParams, layout: StateLayout, B: int, like: Tensor) -> Tensor:
    """``Q̄ (B, n, n)``: ``params.Q`` on the attitude block, ``omega_process_noise`` on ω,
    ``offset_process_noise`` on ``b``, ``parameter_process_noise`` on each ``θ_j``."""
    eye = torch.eye(3, dtype=like.dtype, device=like.device)
    Q_att = params.Q.to(like) if isinstance(params.Q, Tensor) else float(params.Q) * eye
    if Q_att.ndim == 0:
        Q_att = Q_att * eye
    if Q_att.shape not in ((3, 3), (B, 3, 3)):
        raise ValueError(f"Q must be a scalar, (3, 3) or (B={B}, 3, 3), got {tuple(Q_att.shape)}")
    Q = torch.zeros(B, layout.dim, layout.dim, dtype=like.dtype, device=like.device)
    Q[:, :3, :3] = symmetrise(Q_att)
    if layout.omega:
        w = layout.omega_slice
        Q[:, w, w] = float(params.omega_process_noise) * eye
    if layout.offset:
        i = layout.offset_index
        Q[:, i, i] = float(params.offset_process_noise)
    j = torch.arange(layout.dim, device=like.device)[layout.parameter_slice]
    Q[:, j, j] = float(params.parameter_process_noise)
    return Q


def run_usque(*, model: ObservationModel, q_est0: Tensor, P0: Tensor, observations: Tensor, m_past0: Tensor,
              increments: Tensor | None = None, params: UsqueParams | None = None,
              offset0: Tensor | None = None, theta0: Tensor | None = None,
              omega0: Tensor | None = None) -> FilterHistory:
    """Run ``B`` independent USQUE filters over ``T`` steps in one set of tensors (the steps: module docstring).

    Args:
        model: observation model, called once per step with ``q (B, 2n+1, 4)`` and ``m_past (B, 2n+1)``: each
            filter's sigma points are one set along the last batch dimension (see
            :mod:`lightcurve_gp.observation.base`). With ``offset0`` it models the reference light curve.
        q_est0: initial estimates ``(B, 4)`` (their sign is kept; the run stays sign-continuous).
        P0: initial covariances ``(n, n)`` or ``(B, n, n)`` of the state (rad², rad²/s² for ω, mag² for ``b``).
        observations: ``ỹ_0 … ỹ_T`` ``(B, T+1)`` in mag (NaN = missing); ``ỹ_0`` is not used by the filter.
        m_past0: running mean at ``t_0`` ``(B,)``, chosen by the caller.
        increments: ω known: ``δ_0 … δ_{T−1}`` ``(T, 4)`` shared by all filters or ``(B, T, 4)``; ``None`` with
            ``omega0``.
        params: :class:`UsqueParams` (default: the paper's filter).
        offset0: initial offset estimates ``(B,)`` or ``()`` (mag) to estimate ``y = h(q, m_past) + b``
            (:func:`lightcurve_gp.filters.offset.initial_offset`); ``None``: no offset in the state.
        theta0: initial estimates ``(B, p)`` or ``(p,)`` of ``p`` model parameters carried as states; the model is
            then called with ``theta (B, 2n+1, p)`` too (each sigma point's parameters, e.g.
            :class:`lightcurve_gp.observation.surface_state.SurfaceStateRenderer`); ``None``: no parameters in the
            state.
        omega0: initial body-rate estimates ``(B, 3)`` or ``(3,)`` (rad/s) to estimate ω; ``None``: ω known.

    Returns:
        :class:`FilterHistory`. Emits :class:`~lightcurve_gp.filters.unscented.SqrtFallbackWarning` once when any
        filter needed the square-root fallback (counts in ``fallbacks``).
    """
    params = params or UsqueParams()
    layout = StateLayout(offset=offset0 is not None, omega=omega0 is not None,
                         parameters=0 if theta0 is None else int(theta0.shape[-1]))
    B, T = _check_run_inputs(q_est0, P0, offset0, theta0, omega0, observations, m_past0, increments, layout)
    with torch.no_grad():
        run, R_steps = run_constants(params, layout, model, B, T, q_est0)
        obs = observations.to(dtype=q_est0.dtype, device=q_est0.device)
        observed = torch.isfinite(obs)
        y_steps = step_major(torch.where(observed, obs, torch.zeros_like(obs)))
        observed_steps = step_major(observed)
        state = _initial_state(layout, run, q_est0=q_est0, P0=P0, m_past0=m_past0, offset0=offset0, theta0=theta0,
                               omega0=omega0)
        history = HistoryBuilder(layout)
        history.add(state, _initial_record(state))
        step = _stepper(run, increments, compile_=params.compile)
        for k in range(1, T + 1):
            run_k = run if R_steps is None else dataclasses.replace(run, R=R_steps[k])
            state, record = step(run_k, state, k, y_k=y_steps[k], observed_k=observed_steps[k])
            history.add(state, record)
        out = history.build(observed, state)
    n_fb = int((out.fallbacks > 0).sum())
    if n_fb:
        warn_fallbacks(n_fb, B, "run_usque")
    return out


def _initial_state(layout: StateLayout, run: RunConstants, *, q_est0: Tensor, P0: Tensor, m_past0: Tensor,
                   offset0: Tensor | None, theta0: Tensor | None, omega0: Tensor | None) -> FilterState:
    """The state at ``t_0`` of ``B`` filters: copies of the (checked) inputs, broadcast over ``B``, ``q̂``
    normalised, ``P`` symmetrised, the adaptive rule's running average at ``R``."""
    dtype, device, B = q_est0.dtype, q_est0.device, q_est0.shape[0]
    q_hat = q_est0.to(dtype=dtype).clone()
    return FilterState(
        q_hat=q_hat / torch.linalg.vector_norm(q_hat, dim=-1, keepdim=True),
        offset=None if offset0 is None else offset0.to(dtype=dtype, device=device).expand(B).clone(),
        P=symmetrise(P0.to(dtype=dtype, device=device).expand(B, layout.dim, layout.dim)).clone(),
        m_past=m_past0.to(dtype=dtype, device=device).expand(B).clone(memory_format=torch.contiguous_format),
        noise_excess=None if run.adaptive_rate is None else run.R.clone(),
        theta=None if theta0 is None else theta0.to(dtype=dtype, device=device).expand(B, -1).clone(),
        omega=None if omega0 is None else omega0.to(dtype=dtype, device=device).expand(B, 3).clone())


def _initial_record(state: FilterState) -> StepRecord:
    """The record of ``t_0``: no prediction (NaN), no update."""
    B = state.q_hat.shape[0]
    nan_b = torch.full((B,), math.nan, dtype=state.q_hat.dtype, device=state.q_hat.device)
    no = torch.zeros(B, dtype=torch.bool, device=state.q_hat.device)
    return StepRecord(nan_b, nan_b, nan_b, nan_b, state.m_past, no, no, no)


def _stepper(run: RunConstants, increments: Tensor | None, *,
             compile_: bool) -> Callable[..., tuple[FilterState, StepRecord]]:
    """``step(run_k, state, k, *, y_k, observed_k)``: step ``k`` of the run. With ``increments`` (ω known) the
    rotation step (:func:`~lightcurve_gp.filters.step.usque_step`, compiled with ``compile_``) on the step's
    matrices; without, the rate prediction (:func:`~lightcurve_gp.filters.rates.rate_prior`) and the update."""
    if increments is None:
        def rate_step(run_k: RunConstants, state: FilterState, k: int, **obs: Tensor):
            return step_update(run_k)(run_k, state, rate_prior(run_k, state), **obs)

        return rate_step
    like = run.Q
    B = like.shape[0]
    L_steps, G_steps = step_matrices(increments.to(dtype=like.dtype, device=like.device), run.layout, B, run.scale)
    inner = compiled_stepper() if compile_ else usque_step

    def rotation_step(run_k: RunConstants, state: FilterState, k: int, **obs: Tensor):
        return inner(run_k, state, L_k=L_steps[k - 1], G_k=G_steps[k - 1], **obs)

    return rotation_step


def run_constants(params: UsqueParams, layout: StateLayout, model: ObservationModel, B: int, T: int,
                  like: Tensor) -> tuple[RunConstants, tuple[Tensor, ...] | None]:
    """The run's weights, noises and variant (with ω in the state its RK4 stepper) for ``B`` filters over ``T``
    steps, in ``like``'s dtype and device, and with a per-sample ``R`` ``(B, T+1)`` its columns (step ``k`` uses
    column ``k``; the constants hold column 0), else ``None``."""
    dtype, device = like.dtype, like.device
    lam, wm, wc = params.weights(layout.dim, dtype=dtype, device=device)
    R = torch.as_tensor(params.R, dtype=dtype, device=device)
    if R.shape not in ((), (B,), (B, T + 1)):
        raise ValueError(f"R must be a scalar, (B={B},) or (B={B}, T+1={T + 1}), got {tuple(R.shape)}")
    R_steps = step_major(R) if R.ndim == 2 else None
    stepper = None
    if layout.omega:
        stepper = rk4_stepper(torch.tensor(params.inertia, dtype=dtype, device=device), params.dt, like=like)
    return RunConstants(
        model=model, layout=layout, wm=wm, wc=wc, scale=layout.dim + lam, Q=_process_noise(params, layout, B, like),
        R=R[:, 0] if R.ndim == 2 else R.expand(B), grp=(float(params.grp_a), float(params.grp_f)),
        variance=params.variance, t_span_past=float(params.t_span_past),
        adaptive_rate=float(params.adaptive_noise_rate) if params.adaptive_noise == "innovation" else None,
        sigma_redraw=bool(params.sigma_redraw), q_in_sigma=params.q_placement == "both", stepper=stepper,
        update_iterations=int(params.update_iterations)), R_steps
