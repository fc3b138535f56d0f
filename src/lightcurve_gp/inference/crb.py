"""The Cramér–Rao bound of a light curve: how well any unbiased estimator can know the initial state.

Model. Samples ``k = 0 … T`` of one object: ``ỹ_k = h(q_k; surface) + b + v_k`` with ``v_k ~ N(0, R_k)``, where
``q_k`` follows the torque-free motion (RK4 on the ``dt`` grid, :func:`lightcurve_gp.attitude.dynamics.propagate`)
from the initial state. The unknowns are a subset of the filter's state (:class:`~lightcurve_gp.filters.state.
StateLayout`, in its order):

* ``attitude`` (always): the rotation vector ``e`` (rad) of ``q_0 = q(e) ⊗ q̄_0``, a body-frame rotation;
* ``omega``: the initial body rate ``ω_0 = ω̄_0 + δω`` (rad/s); without it ω is known;
* ``offset``: a magnitude offset ``b`` (mag) added to every sample;
* ``surface``: the surface state ``θ = (log ρ, logit F0, log n_u, log n_v)`` of
  :mod:`lightcurve_gp.observation.surface_state`; without it the surface is known.

Fisher information ``F = Σ_k J_kᵀ J_k / R_k (+ P0⁻¹)`` with ``J_k = ∂h_k/∂x`` at the truth, and the bound
``cov(x̂) ⪰ F⁻¹`` (with the prior ``P0``: the Bayesian bound of Van Trees). ``J_k`` is exact to rounding, by forward-mode
automatic differentiation: the renderer's derivative ``g_k = ∂h_k/∂φ`` with respect to a body-frame rotation ``φ``
of ``q_k`` (and ``∂h_k/∂θ``) times the sensitivity ``Φ_k = ∂φ_k/∂x`` of the attitude at ``k`` to the initial
state. With ω known ``Φ_k = [A(Δ_k)]`` (``Δ_k = q_k ⊗ q_0⁻¹``: the body-frame error at ``k`` is the initial one
turned by ``A(Δ_k)``); with ω estimated its ω columns are central differences of the propagation
(:data:`RATE_STEP`, relative error ~1e-9).

Scores. The attitude error at sample ``k`` is ``Φ_k x̃``, so its bound is ``Φ_k C Φ_kᵀ``; its small-angle 3-2-1
Euler angles (yaw, pitch, roll) of ``q_true ⊗ q_est⁻¹`` are the rotation vector's ``(z, y, x)`` components (up to
sign). Two bounds per sample: **smoothing** (``C = F⁻¹`` from the whole arc: what a batch estimator over all
samples can reach) and **filtering** (``C_k = F_k⁻¹`` from samples ``≤ k`` only: what a causal filter can reach at
``k``). Their RMS over a scoring window bounds an estimator's expected mean-square Euler error there.

Units: rad, rad/s, mag, the surface coordinates' own; standard deviations are reported in degrees (deg/s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch
import torch.autograd.forward_ad as fwad
from torch import Tensor

from lightcurve_gp.attitude.dynamics import propagate
from lightcurve_gp.attitude.rotations import attitude_matrix, quat_conj, quat_mul, rotvec_to_quat
from lightcurve_gp.config.load import Config
from lightcurve_gp.filters.state import StateLayout
from lightcurve_gp.observation.surface_state import reference_surface, surface_from_state, surface_state_prior
from lightcurve_gp.passes.geometry import pass_geometry
from lightcurve_gp.photometry.brdf import Surface
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.truths import TruthDraw

__all__ = ["UNKNOWNS", "RATE_STEP", "CramerRaoBound", "cramer_rao_bound", "bound_for_truths", "filter_prior",
           "surface_state", "state_layout"]

#: the unknowns a bound may include, in the filter state's order (``attitude`` always)
UNKNOWNS = ("attitude", "omega", "offset", "surface")
#: the rotation vector's components (x, y, z) that are the small-angle Euler errors (yaw, pitch, roll)
_EULER_FROM_ROTVEC = (2, 1, 0)
#: central-difference step of the initial rate (rad/s) for the trajectory's sensitivity to it
RATE_STEP = 1e-7


def state_layout(unknowns: Sequence[str]) -> StateLayout:
    """The :class:`StateLayout` of ``unknowns`` (names of :data:`UNKNOWNS`; ``attitude`` must be one)."""
    unknowns = tuple(unknowns)
    bad = [u for u in unknowns if u not in UNKNOWNS]
    if bad:
        raise ValueError(f"unknowns: {bad[0]!r} is not one of {', '.join(UNKNOWNS)}")
    if "attitude" not in unknowns:
        raise ValueError("unknowns: the bound is of the attitude; 'attitude' must be among the unknowns")
    return StateLayout(offset="offset" in unknowns, omega="omega" in unknowns, parameters=4 * ("surface" in unknowns))


def surface_state(surface: Surface) -> Tensor:
    """The surface-state coordinates ``(B, 4)`` = (log ρ, logit F0, log n_u, log n_v) of ``surface`` (fields
    ``(B,)``): the inverse of :func:`~lightcurve_gp.observation.surface_state.surface_from_state`."""
    return torch.stack([surface.rho.log(), torch.logit(surface.f0), surface.n_u.log(), surface.n_v.log()], -1)


@dataclass
class CramerRaoBound:
    """The bound of ``S`` objects over samples ``k = 0 … T`` (see the module docstring).

    Attributes:
        layout: the unknowns' layout, ``n = layout.dim`` components.
        times: sample times ``(T+1,)`` (s).
        jacobian: ``J_k = ∂h_k/∂x`` ``(S, T+1, n)`` (mag per unit of each component).
        weights: ``1/R_k`` ``(S, T+1)`` (mag⁻²; 0 for a sample left out: unobserved, zero flux or ``k = 0``).
        prior_information: ``P0⁻¹`` ``(S, n, n)`` (zeros without a prior).
        sensitivity: ``Φ_k`` ``(S, T+1, 3, n)``: the body-frame attitude error at ``k`` (rad) per unit of each
            initial component.
    """

    layout: StateLayout
    times: Tensor
    jacobian: Tensor
    weights: Tensor
    prior_information: Tensor
    sensitivity: Tensor

    @property
    def fisher(self) -> Tensor:
        """Information of the whole arc and the prior ``(S, n, n)``."""
        J = self.jacobian
        return torch.einsum("stn,st,stm->snm", J, self.weights, J) + self.prior_information

    @property
    def covariance(self) -> Tensor:
        """The bound ``F⁻¹`` ``(S, n, n)`` (inf where ``F`` is singular: the data do not identify the state)."""
        return _inverse_or_inf(self.fisher)

    def causal_covariance(self) -> Tensor:
        """The filtering bound ``F_k⁻¹`` from samples ``≤ k`` and the prior ``(S, T+1, n, n)`` (inf where ``F_k``
        is singular)."""
        J = self.jacobian
        per_sample = torch.einsum("stn,st,stm->stnm", J, self.weights, J)
        return _inverse_or_inf(per_sample.cumsum(1) + self.prior_information.unsqueeze(1))

    def attitude_std_deg(self) -> tuple[Tensor, Tensor]:
        """Standard deviations ``(S, 3)`` (deg, ascending) of the initial attitude along its principal directions,
        and those directions ``(S, 3, 3)`` (columns, body frame at ``t_0``); the attitude block of ``F⁻¹``, so the
        other unknowns are marginalised. An object whose ``F`` is singular gets ``inf`` and NaN directions."""
        C = self.covariance[:, :3, :3]
        ok = torch.isfinite(C).flatten(-2).all(-1)
        values, vectors = torch.linalg.eigh(torch.where(ok[:, None, None], C, 0.0))
        std = torch.rad2deg(values.clamp_min(0.0).sqrt())
        return torch.where(ok[:, None], std, math.inf), torch.where(ok[:, None, None], vectors, math.nan)

    def std(self) -> Tensor:
        """Standard deviations ``(S, n)`` of every component of the initial state (its own units: rad, rad/s,
        mag, surface coordinates)."""
        return torch.diagonal(self.covariance, dim1=-2, dim2=-1).clamp_min(0.0).sqrt()

    def euler_std_deg(self, *, causal: bool = False) -> Tensor:
        """Bound on the standard deviation of each Euler error (yaw, pitch, roll) at every sample ``(S, T+1, 3)``
        (deg): the smoothing bound, or with ``causal`` the filtering bound."""
        E = self.sensitivity[..., _EULER_FROM_ROTVEC, :]  # (S, T+1, 3, n)
        C = self.causal_covariance() if causal else self.covariance.unsqueeze(1).expand(*E.shape[:2], -1, -1)
        ok = torch.isfinite(C).flatten(-2).all(-1)  # (S, T+1): the state is identified
        var = torch.einsum("stin,stnm,stim->sti", E, torch.where(ok[..., None, None], C, 0.0), E)
        return torch.where(ok.unsqueeze(-1), torch.rad2deg(var.clamp_min(0.0).sqrt()), math.inf)

    def euler_rms_deg(self, window: Sequence[float] = (400.0, 600.0), *, causal: bool = False) -> Tensor:
        """Bound on the RMS over ``window`` (s, inclusive) of each Euler error ``(S, 3)`` (deg):
        ``√(mean_k var_k)``, which no unbiased estimator's expected mean-square error over the window beats."""
        inside = (self.times >= float(window[0])) & (self.times <= float(window[1]))
        if not bool(inside.any()):
            raise ValueError(f"window: no sample lies in [{float(window[0]):g}, {float(window[1]):g}] s")
        std = self.euler_std_deg(causal=causal)[:, inside]
        return std.pow(2).mean(1).sqrt()


def _inverse_or_inf(F: Tensor) -> Tensor:
    """Inverses of symmetric matrices ``(..., n, n)`` by Cholesky; ``inf`` entries where not positive definite."""
    L, info = torch.linalg.cholesky_ex(F)
    ok = info == 0
    safe = torch.where(ok[..., None, None], L, torch.eye(F.shape[-1], dtype=F.dtype, device=F.device))
    return torch.where(ok[..., None, None], torch.cholesky_inverse(safe), math.inf)


def cramer_rao_bound(scene: Scene, *, q0: Tensor, omega0: Tensor, inertia, dt: float, noise_var,
                     n_steps: int | None = None, sample_index: Tensor | None = None, rho: float | None = None,
                     surface: Surface | None = None, unknowns: Sequence[str] = ("attitude",),
                     prior: Tensor | None = None, observed: Tensor | None = None,
                     first_sample: int = 1) -> CramerRaoBound:
    """The Cramér–Rao bound of ``S`` true objects (module docstring), all in one batch (float64 recommended).

    Args:
        scene: the renderer of the known shape: a fixed geometry, or one per sample (``T+1`` samples, a pass).
        q0: true initial attitudes ``(S, 4)`` or ``(4,)``; omega0: true initial body rates ``(S, 3)`` or ``(3,)``
            (rad/s); inertia: principal moments ``(3,)`` (kg m²); dt: the RK4 grid step (s).
        noise_var: ``R`` (mag²): a number, per sample ``(T+1,)`` or per object and sample ``(S, T+1)``; NaN or inf
            leaves a sample out; every finite value must be > 0.
        n_steps: samples every ``dt`` at ``k = 0 … n_steps``; or ``sample_index`` ``(T+1,)``: the increasing grid
            steps of the samples (a pass with gaps).
        rho: the true diffuse reflectance on the scene's material; or ``surface``: the true surfaces (fields
            ``(S,)``), needed when ``surface`` is among the unknowns.
        unknowns: names of :data:`UNKNOWNS`; ``attitude`` always, the others in any order (the state follows
            the filter's order ``[e, δω, b, θ]``).
        prior: the prior covariance ``P0`` ``(n, n)`` or ``(S, n, n)`` of the unknowns in that order (rad², rad²/s²,
            mag², surface coordinates²); ``None``: the data alone.
        observed: which samples have an observation ``(T+1,)`` or ``(S, T+1)`` (bool); zero flux is left out too.
        first_sample: samples before it are left out (1: ``ỹ_1 … ỹ_T``, the samples the filters update with).
    """
    layout = state_layout(unknowns)
    q0, omega0 = torch.atleast_2d(q0), torch.atleast_2d(omega0)
    S = max(q0.shape[0], omega0.shape[0])
    q0, omega0 = q0.expand(S, 4), omega0.expand(S, 3)
    index = _sample_index(n_steps, sample_index, q0.device)
    if (rho is None) == (surface is None):
        raise ValueError("give rho or surface (the truth's), exactly one")
    if layout.parameters and surface is None:
        raise ValueError("unknowns: 'surface' needs the true surface (surface=), not rho")
    q_grid, phi_omega = _trajectory(q0, omega0, inertia, dt, int(index[-1]), layout.omega)
    q = q_grid[:, index]
    m, g = _render_tangents(scene, q, rho=rho, surface=surface, theta=bool(layout.parameters))
    rot = attitude_matrix(q) @ attitude_matrix(q_grid[:, :1]).mT  # A(Δ_k) (S, T+1, 3, 3)
    blocks = [rot] + ([phi_omega[:, index]] if layout.omega else [])
    sensitivity = torch.cat(blocks + [rot.new_zeros(*rot.shape[:-1], layout.dim - 3 - 3 * layout.omega)], -1)
    J = (g[..., None, :3] @ sensitivity).squeeze(-2)  # attitude and rate columns
    if layout.offset:
        J[..., layout.offset_index] = 1.0
    if layout.parameters:
        J[..., layout.parameter_slice] = g[..., 3:]
    weights = _weights(noise_var, observed, m, J, S=S, first_sample=first_sample)
    J = torch.where(weights.unsqueeze(-1) > 0, J, 0.0)
    return CramerRaoBound(layout, index.to(q.dtype) * float(dt), J, weights, _prior_information(prior, layout, S, q),
                          sensitivity)


def _sample_index(n_steps: int | None, sample_index: Tensor | None, device) -> Tensor:
    """The samples' grid steps ``(T+1,)`` (long) from exactly one of ``n_steps`` and ``sample_index``."""
    if (n_steps is None) == (sample_index is None):
        raise ValueError("give n_steps or sample_index, exactly one")
    if sample_index is None:
        if int(n_steps) < 1:
            raise ValueError(f"n_steps: {n_steps!r} must be >= 1")
        return torch.arange(int(n_steps) + 1, device=device)
    index = torch.as_tensor(sample_index, device=device).long()
    if index.ndim != 1 or index.numel() < 2 or bool((index[1:] <= index[:-1]).any()) or int(index[0]) < 0:
        raise ValueError("sample_index: expected increasing grid steps >= 0, at least two")
    return index


def _trajectory(q0: Tensor, omega0: Tensor, inertia, dt: float, n_grid: int,
                rate: bool) -> tuple[Tensor, Tensor | None]:
    """The true attitudes on the grid ``(S, n_grid+1, 4)`` and, with ``rate``, the attitude's sensitivity to the
    initial rate ``∂φ_k/∂ω_0`` ``(S, n_grid+1, 3, 3)`` (rad per rad/s): central differences of the RK4 propagation
    (``q' = q(δφ) ⊗ q`` gives ``[δφ; 0] = 2 dq ⊗ q⁻¹``), all seven trajectories in one call. Their relative error
    is ~1e-9 (step :data:`RATE_STEP`; forward-mode differentiation agrees to that but costs ~30× more through the
    rate equations' ``roll``; the tests check the sensitivity against perturbed propagations)."""
    S = q0.shape[0]
    if not rate:
        return propagate(q0, omega0, inertia, dt, n_grid)[0], None
    shifts = RATE_STEP * torch.eye(3, dtype=omega0.dtype, device=omega0.device)
    omegas = torch.cat([omega0.unsqueeze(0), omega0 + shifts[:, None], omega0 - shifts[:, None]])  # (7, S, 3)
    q = propagate(q0.expand(7, S, 4), omegas, inertia, dt, n_grid)[0]
    dq = (q[1:4] - q[4:7]) / (2.0 * RATE_STEP)
    dphi = 2.0 * quat_mul(dq, quat_conj(q[:1]))[..., :3]  # (3 [δω_j], S, n+1, 3 [φ])
    return q[0], dphi.permute(1, 2, 3, 0)


def _render_tangents(scene: Scene, q: Tensor, *, rho: float | None, surface: Surface | None,
                     theta: bool) -> tuple[Tensor, Tensor]:
    """Magnitudes ``(S, T+1)`` of attitudes ``q (S, T+1, 4)`` and their derivatives ``(S, T+1, 3 | 7)`` with
    respect to a body-frame rotation ``φ`` of each ``q_k`` (``q(φ) ⊗ q_k``) and, with ``theta``, the surface-state
    coordinates — by forward-mode differentiation, one tangent per direction, all in one rendering call."""
    S, T1 = q.shape[:2]
    k = 3 + 4 * theta
    eye = torch.eye(k, dtype=q.dtype, device=q.device)
    with fwad.dual_level():
        x = fwad.make_dual(q.new_zeros(k, S, k), eye[:, None, :].expand(k, S, k).contiguous())
        q_all = quat_mul(rotvec_to_quat(x[..., :3]).unsqueeze(2), q.unsqueeze(0)).reshape(k * S, T1, 4)
        if surface is None:
            m = scene.magnitude(q_all, rho=rho)
        elif theta:
            state = surface_state(surface.to(dtype=q.dtype, device=q.device)) + x[..., 3:]
            m = scene.magnitude(q_all, surface=surface_from_state(state.reshape(k * S, 4)))
        else:
            m = scene.magnitude(q_all, surface=Surface(*(t.to(q).expand(S).repeat(k) for t in surface)))
        primal, tangent = fwad.unpack_dual(m)
    return primal[:S], tangent.reshape(k, S, T1).permute(1, 2, 0)


def _weights(noise_var, observed: Tensor | None, m: Tensor, J: Tensor, *, S: int, first_sample: int) -> Tensor:
    """``1/R_k`` ``(S, T+1)``, 0 where a sample is left out (see :func:`cramer_rao_bound`)."""
    T1 = m.shape[1]
    R = torch.as_tensor(noise_var, dtype=m.dtype, device=m.device)
    if R.shape not in ((), (T1,), (S, T1)):
        raise ValueError(f"noise_var: expected a number, ({T1},) or ({S}, {T1}), got {tuple(R.shape)}")
    finite = torch.isfinite(R)
    if bool((finite & ~(R > 0)).any()):
        raise ValueError("noise_var: every finite noise variance must be > 0 mag^2")
    use = (finite & torch.isfinite(m) & torch.isfinite(J).all(-1)).expand(S, T1).clone()
    if observed is not None:
        use &= torch.as_tensor(observed, device=m.device).bool().expand(S, T1)
    use[:, :first_sample] = False
    return torch.where(use, 1.0 / torch.where(finite, R, 1.0).expand(S, T1), 0.0)


def _prior_information(prior: Tensor | None, layout: StateLayout, S: int, like: Tensor) -> Tensor:
    """``P0⁻¹`` ``(S, n, n)``, zeros without a prior."""
    n = layout.dim
    if prior is None:
        return like.new_zeros(S, n, n)
    prior = torch.as_tensor(prior, dtype=like.dtype, device=like.device)
    if prior.shape not in ((n, n), (S, n, n)):
        raise ValueError(f"prior: expected ({n}, {n}) or ({S}, {n}, {n}) for the unknowns of {layout}, got "
                         f"{tuple(prior.shape)}")
    info = _inverse_or_inf(prior.expand(S, n, n))
    if not bool(torch.isfinite(info).all()):
        raise ValueError("prior: the prior covariance must be positive definite")
    return info


def filter_prior(cfg: Config, draw: TruthDraw, layout: StateLayout, *, scene: Scene) -> Tensor:
    """The filters' prior covariance ``(S, n, n)`` in ``layout``: ``σ0² I`` on the attitude (the draw's
    ``sigma0``), ``filter.p0_omega_deg_s²`` on ω, ``filter.offset_prior_std²`` on ``b`` and the surface-state
    filter's prior variances (:func:`~lightcurve_gp.observation.surface_state.surface_state_prior`) on ``θ``.
    ``scene`` is a fixed scene (the first sample's along a pass)."""
    S, n = len(draw.seeds), layout.dim
    variances = [draw.sigma0.pow(2).unsqueeze(-1).expand(S, 3)]
    if layout.omega:
        variances.append(torch.full((S, 3), math.radians(cfg.filter.p0_omega_deg_s) ** 2, dtype=torch.float64))
    if layout.offset:
        variances.append(torch.full((S, 1), cfg.filter.offset_prior_std ** 2, dtype=torch.float64))
    if layout.parameters:
        _, std = surface_state_prior(scene=scene, q_est0=draw.q0, y0=torch.zeros(S, dtype=torch.float64),
                                     reference=reference_surface(cfg), offset_std=cfg.filter.offset_prior_std)
        variances.append(std.pow(2).expand(S, 4))
    return torch.diag_embed(torch.cat(variances, -1)).reshape(S, n, n)


def bound_for_truths(cfg: Config, draw: TruthDraw, *, unknowns: Sequence[str] = ("attitude",),
                     with_prior: bool = True, noise_var: float | None = None,
                     scene: Scene | None = None) -> CramerRaoBound:
    """The bound of the truths ``draw`` (:func:`~lightcurve_gp.simulation.truths.draw_truths`, or the paper's case
    from :func:`~lightcurve_gp.simulation.truths.paper_case_draw`) under ``cfg``'s shape, geometry (fixed or the
    pass, its unobservable samples left out), time grid and noise (``noise_var`` overrides ``scenario.noise_var``),
    samples ``1 … T``; with ``with_prior`` the filters' prior (:func:`filter_prior`). Float64 on the CPU."""
    sc = cfg.scenario
    scene = (scene or Scene.from_config(cfg)).to(dtype=torch.float64)
    timing: dict = {"n_steps": int(round(sc.duration_s / sc.dt_s))}
    observed = None
    if scene.per_sample:
        geometry = pass_geometry(cfg)
        timing = {"sample_index": torch.round(geometry.times_s / sc.dt_s).long()}
        observed = geometry.observable
    layout = state_layout(unknowns)
    prior = filter_prior(cfg, draw, layout, scene=scene.sample(0) if scene.per_sample else scene) \
        if with_prior else None
    return cramer_rao_bound(scene, q0=draw.q0, omega0=draw.omega0, inertia=cfg.shape.inertia_kg_m2, dt=sc.dt_s,
                            noise_var=sc.noise_var if noise_var is None else float(noise_var), surface=draw.surface,
                            unknowns=unknowns, prior=prior, observed=observed, **timing)
