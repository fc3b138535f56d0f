"""Families of inversion solutions: clustered modulo the exact ambiguity group, cut by likelihood ratio, weighted by
their Laplace evidence.

Two solutions ``(q_a, ω_a)`` and ``(q_b, ω_b)`` (initial attitude and body rate) are one when an image
``(q_R ⊗ q_b ⊗ q_C, R ω_b)`` of :class:`~lightcurve_gp.photometry.ambiguity.AmbiguityGroup` lies within
``angle_deg`` of ``q_a`` and ``rate_deg_s`` of ``ω_a``; families are formed greedily, best cost first, and a
family is its best member. :func:`image_distance` scores an estimate against a truth the same way (the image that
minimises ``angle / angle_deg + |Δω| / rate_deg_s``).

Weights. With the cost ``c = ½ Σ r²`` (whitened residuals) the log-likelihood is ``ℓ = −c − Σ ln(√(2π) σ_k)``; a
family's Laplace evidence under a uniform prior of volume ``V`` over the state ``[θ, ω, ln ρ]`` (SO(3) with its Haar
volume 8π², the rate ball of radius ``ω_max``, ``ln ρ`` over ``[ln 10⁻³, 0]``) is

    Z_f = exp(ℓ_f) · det(2π Σ_f)^{1/2} / V          (Σ_f the Laplace covariance at its best member)

and counts once for all ``|G|`` exact images (they share ``ℓ`` and ``det Σ``, so the factor cancels). The weights
``w_f = Z_f / Σ_g Z_g`` run over the families kept by the likelihood-ratio cut ``ℓ_best − ℓ_f ≤ max_log_ratio``.

**The prior bounds the volume.** Where the light curve leaves a direction free (a slow tumbler's rate, an attitude
axis the arc never turns) the information ``Σ_f⁻¹`` is nearly singular and ``det Σ_f`` can exceed the prior's own
volume by orders of magnitude (measured: attitude 1σ of 9000°, ``ln ρ`` 1σ of 21 on a 20° arc); such a family then
took all the weight (0.997 against families 0.06 nats better). The evidence therefore uses
``Σ̃_f = (Σ_f⁻¹ + P)⁻¹``, ``P`` the precision of the Gaussian of the same volume as each block of the uniform prior
(:func:`prior_precision`: ``(2π/p)^{d/2}`` equals the block's volume), so no direction counts for more than the
prior allows; where the data fix every direction (``Σ_f⁻¹ ≫ P``) the weights do not change.

**The probability of being right.** A weight is the posterior mass of a family's *basin*; an answer is right only
when the truth also lies within :data:`RIGHT_ANGLE_DEG` on every Euler axis and :data:`RIGHT_RATE_REL` of the rate of
the family's mode. Under the family's Laplace Gaussian (the bounded ``Σ̃_f``) the truth is
``q = exp(δθ) ⊗ q_f``, ``ω = ω_f + δω`` with ``(δθ, δω) ~ N(0, Σ̃_f)``; :func:`tolerance_mass` is the probability of
that region (Monte Carlo over fixed draws). A wide family (a slow tumbler's ridge, a rate the arc cannot tell to 2 %)
keeps its basin weight but not its claim to be right.

The truth can also lie in *another* family and still be within the tolerance of ``f``'s mode: along a flat attitude
valley the search stops at several points a few degrees apart, each a family of its own (held-out seed 1009 at 0.1 mag,
1.41 °/s: ten families, the first four 9°, 5° and 7° apart at 0.36 nats each; the truth lay within 10° of three).
Counting only ``w_f · mass_f`` split the valley's probability among its points, and on the held-out row (uniform
rates, 0.1 mag) the seeds stated at 0.23–0.47 were right six times in six. So the probability that ``f``'s mode is
right is the posterior mixture's mass of its tolerance region, some image of the truth within it
(:func:`mixture_p_right`):

    p_right_f = w_f · mass_f + Σ_{g ≠ f} w_g · P_g(an image of the state within the tolerance of f's mode)

the cross terms by Monte Carlo over :data:`MASS_DRAWS` draws of the mixture (systematic allocation to the families by
weight). With one family, or families far apart, it is ``w_f · mass_f``; the ``p_right`` of different families are
no longer exclusive events and need not sum to 1 or less.

**The prior's support.** The rate ball bounds the volume and also the rates an answer may have: the polish on the
whole light curve is not held inside it, and at high noise a mode can drift far beyond the fastest rate searched
(held-out seed 1003 at 0.71 mag, a 0.2 °/s tumbler: its leading family turned at 15.4 °/s with weight 0.43, the
search's range 0.05–5 °/s). A mode whose rate exceeds ``ω_max`` by more than :data:`SUPPORT_SIGMAS` of its own
(bounded) rate standard deviation along its axis has no prior mass and is no family (:func:`beyond_support`;
``Families.beyond`` counts them); a mode at the edge, within that, is kept as it is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from lightcurve_gp.attitude.metrics import attitude_errors_deg, total_angle_deg
from lightcurve_gp.attitude.rotations import quat_mul, rotvec_to_quat
from lightcurve_gp.photometry.ambiguity import AmbiguityGroup

__all__ = ["RIGHT_ANGLE_DEG", "RIGHT_RATE_REL", "MASS_DRAWS", "SUPPORT_SIGMAS", "Families", "image_distance",
           "cluster", "log_prior_volume", "prior_precision", "bounded_covariance", "beyond_support", "tolerance_mass",
           "mixture_p_right", "families"]

#: ln ρ prior range of the evidence (ρ from 1e-3 to 1)
LOG_RHO_RANGE = math.log(1e3)
#: a state is right when the truth is within this on every Euler axis (deg) …
RIGHT_ANGLE_DEG = 10.0
#: … and its rate within this share of the true rate's magnitude
RIGHT_RATE_REL = 0.02
#: draws of :func:`tolerance_mass`
MASS_DRAWS = 4096
#: a mode whose rate exceeds the prior's ball by more than this many of its standard deviations is no family
SUPPORT_SIGMAS = 3.0


def image_distance(group: AmbiguityGroup, q_a: Tensor, omega_a: Tensor, q_b: Tensor, omega_b: Tensor, *,
                   angle_deg: float = 5.0, rate_deg_s: float = 0.05) -> tuple[Tensor, Tensor, Tensor]:
    """Attitude angle (deg), rate difference (deg/s) and image index of the image of ``b`` nearest ``a``, for
    broadcasting ``q (..., 4)`` and ``ω (..., 3)`` (rad/s); shapes ``broadcast(...)``."""
    batch = torch.broadcast_shapes(q_a.shape[:-1], q_b.shape[:-1], omega_a.shape[:-1], omega_b.shape[:-1])
    q_a, omega_a = q_a.expand(*batch, 4), omega_a.expand(*batch, 3)
    q_img, w_img = group.attitudes(q_b.expand(*batch, 4)), group.rates(omega_b.expand(*batch, 3))  # (K, ...)
    angle = total_angle_deg(q_a.unsqueeze(0), q_img)
    rate = torch.rad2deg(torch.linalg.vector_norm(omega_a.unsqueeze(0) - w_img, dim=-1))
    best = (angle / angle_deg + rate / rate_deg_s).argmin(0)
    pick = lambda t: t.gather(0, best.unsqueeze(0)).squeeze(0)  # noqa: E731
    return pick(angle), pick(rate), best


def _neighbours(group: AmbiguityGroup, q0: Tensor, omega0: Tensor, angle_deg: float, rate_deg_s: float,
                chunk: int = 256) -> Tensor:
    """``(M, M)`` bool: some image of ``j`` lies within ``angle_deg`` and ``rate_deg_s`` of ``i``; the attitude angle
    from quaternion dot products (``cos(angle/2) = |⟨q_i, q_img⟩|``), the rate difference from distances."""
    q_img, w_img = group.attitudes(q0), group.rates(omega0)  # (K, M, 4), (K, M, 3)
    cos_half = math.cos(math.radians(angle_deg) / 2.0)
    rate_rad = math.radians(rate_deg_s)
    rows = []
    for part in torch.arange(q0.shape[0], device=q0.device).split(chunk):
        dots = torch.einsum("ia,kja->kij", q0[part], q_img).abs()  # (K, c, M)
        dist = torch.cdist(omega0[part].unsqueeze(0).expand(len(group), -1, -1), w_img)  # (K, c, M)
        rows.append(((dots >= cos_half) & (dist <= rate_rad)).any(0))
    return torch.cat(rows)


def cluster(group: AmbiguityGroup, q0: Tensor, omega0: Tensor, cost: Tensor, *, angle_deg: float = 5.0,
            rate_deg_s: float = 0.05) -> tuple[Tensor, Tensor]:
    """Greedy clustering of solutions ``q0 (M, 4)``, ``omega0 (M, 3)`` (rad/s) by ``cost (M,)`` modulo ``group``:
    the best free solution heads a family that takes every free solution with an image within ``angle_deg`` and
    ``rate_deg_s`` of it.

    Returns:
        ``labels (M,)`` (the family of each solution, 0 the best) and ``heads (F,)`` (each family's best member).
    """
    near = _neighbours(group, q0, omega0, angle_deg, rate_deg_s)
    order = torch.argsort(cost).tolist()
    labels = torch.full((q0.shape[0],), -1, dtype=torch.long, device=q0.device)
    heads = []
    for i in order:
        if labels[i] >= 0:
            continue
        labels[near[i] & (labels < 0)] = len(heads)
        labels[i] = len(heads)
        heads.append(i)
    return labels, torch.tensor(heads, dtype=torch.long, device=q0.device)


def log_prior_volume(rate_max_rad_s: float) -> float:
    """``ln V`` of the uniform prior over ``[θ, ω, ln ρ]`` (module docstring)."""
    return math.log(8.0 * math.pi ** 2) + math.log(4.0 / 3.0 * math.pi * rate_max_rad_s ** 3) + math.log(LOG_RHO_RANGE)


def prior_precision(rate_max_rad_s: float, *, dtype: torch.dtype = torch.float64, device=None) -> Tensor:
    """The diagonal precision ``(7,)`` of the Gaussian whose volume ``det(2π P⁻¹)^{1/2}`` equals the uniform prior's
    block by block: ``(2π / p)^{d/2} = V_block`` for the attitude (``d = 3``, ``8π²``), the rate ball (``d = 3``) and
    ``ln ρ`` (``d = 1``), so its total volume is ``V`` (:func:`log_prior_volume`)."""
    blocks = ((3, 8.0 * math.pi ** 2), (3, 4.0 / 3.0 * math.pi * rate_max_rad_s ** 3), (1, LOG_RHO_RANGE))
    values = [2.0 * math.pi / volume ** (2.0 / d) for d, volume in blocks for _ in range(d)]
    return torch.tensor(values, dtype=dtype, device=device)


def bounded_covariance(covariance: Tensor, rate_max_rad_s: float) -> Tensor:
    """``Σ̃ = (Σ⁻¹ + P)⁻¹ = (I + Σ P)⁻¹ Σ`` ``(..., 7, 7)`` of Laplace covariances ``(..., 7, 7)`` and the prior's
    precision ``P`` (:func:`prior_precision`), symmetrised; no inverse of a nearly singular ``Σ``."""
    eye = torch.eye(covariance.shape[-1], dtype=covariance.dtype, device=covariance.device)
    p = prior_precision(rate_max_rad_s, dtype=covariance.dtype, device=covariance.device)
    out = torch.linalg.solve(eye + covariance * p, covariance)
    return 0.5 * (out + out.transpose(-1, -2))


def beyond_support(omega0: Tensor, covariance: Tensor, rate_max_rad_s: float, *,
                   sigmas: float = SUPPORT_SIGMAS) -> Tensor:
    """Which modes ``(F,)`` lie beyond the prior's rate ball: ``|ω| − ω_max > sigmas · σ_r`` for body rates
    ``omega0 (F, 3)`` (rad/s) with Laplace covariances ``(F, 7, 7)``, ``σ_r² = uᵀ Σ̃_ωω u`` along ``u = ω/|ω|``
    (:func:`bounded_covariance`; a non-finite ``σ_r`` counts as 0, the rate alone decides)."""
    rate = torch.linalg.vector_norm(omega0, dim=-1)
    u = omega0 / rate.clamp_min(torch.finfo(rate.dtype).tiny).unsqueeze(-1)
    cov = bounded_covariance(covariance, rate_max_rad_s)[..., 3:6, 3:6]
    sd = torch.einsum("fi,fij,fj->f", u, cov, u).clamp_min(0.0).sqrt()
    sd = torch.where(torch.isfinite(sd), sd, torch.zeros_like(sd))
    return rate - rate_max_rad_s > sigmas * sd


def tolerance_mass(q0: Tensor, omega0: Tensor, covariance: Tensor, *, angle_deg: float = RIGHT_ANGLE_DEG,
                   rate_rel: float = RIGHT_RATE_REL, draws: int = MASS_DRAWS, seed: int = 0) -> Tensor:
    """The Gaussian mass ``(F,)`` of the states "right" about modes ``q0 (F, 4)``, ``omega0 (F, 3)`` (rad/s) under
    covariances ``(F, 6+, 6+)`` of ``[θ, ω, …]`` (rad, rad/s; the block ``[:6, :6]`` is used): the share of
    ``draws`` states ``q = exp(δθ) ⊗ q_f``, ``ω = ω_f + δω`` whose Euler errors ``q ⊗ q_f⁻¹`` are within
    ``angle_deg`` on every axis and ``|δω| < rate_rel · |ω|`` (module docstring). The same standard normal draws
    (``seed``) serve every family; a covariance that is not positive semi-definite has its negative eigenvalues
    taken as zero."""
    gen = torch.Generator(device="cpu").manual_seed(seed)
    z = torch.randn(draws, 6, generator=gen, dtype=q0.dtype).to(q0.device)
    q, omega = _draws(q0, omega0, covariance, z)
    ok = _within(q, omega, q0.unsqueeze(1), omega0.unsqueeze(1), angle_deg=angle_deg, rate_rel=rate_rel)
    return ok.to(q0.dtype).mean(-1)


def _draws(q0: Tensor, omega0: Tensor, covariance: Tensor, z: Tensor) -> tuple[Tensor, Tensor]:
    """States ``q = exp(δθ) ⊗ q_f``, ``ω = ω_f + δω`` ``(F, n, 4)``, ``(F, n, 3)`` with ``(δθ, δω) = L z`` for the
    modes ``(F, 4)``, ``(F, 3)``, covariances ``(F, 6+, 6+)`` (``L Lᵀ`` the block ``[:6, :6]``, negative eigenvalues
    as zero) and standard normal draws ``z (n, 6)``."""
    vals, vecs = torch.linalg.eigh(covariance[:, :6, :6])
    root = vecs * vals.clamp_min(0.0).sqrt().unsqueeze(-2)  # (F, 6, 6): root rootᵀ = Σ
    delta = torch.einsum("fij,nj->fni", root, z)  # (F, n, 6)
    q = quat_mul(rotvec_to_quat(delta[..., :3]), q0.unsqueeze(1).expand(-1, z.shape[0], 4))
    return q, omega0.unsqueeze(1) + delta[..., 3:]


def _within(q: Tensor, omega: Tensor, q_mode: Tensor, omega_mode: Tensor, *, angle_deg: float,
            rate_rel: float) -> Tensor:
    """Whether states ``q (..., 4)``, ``omega (..., 3)`` (the truth) are right about modes broadcasting with them:
    every Euler error of ``q ⊗ q_mode⁻¹`` within ``angle_deg`` and ``|ω − ω_mode| < rate_rel · |ω|``."""
    axes_ok = (attitude_errors_deg(q, q_mode).abs() < angle_deg).all(-1)
    rate_ok = torch.linalg.vector_norm(omega - omega_mode, dim=-1) < rate_rel * torch.linalg.vector_norm(omega, dim=-1)
    return axes_ok & rate_ok


def mixture_p_right(group: AmbiguityGroup, *, q0: Tensor, omega0: Tensor, covariance: Tensor, weight: Tensor,
                    mass: Tensor, angle_deg: float = RIGHT_ANGLE_DEG, rate_rel: float = RIGHT_RATE_REL,
                    draws: int = MASS_DRAWS, seed: int = 1, chunk: int = 64) -> Tensor:
    """The probability ``(F,)`` that each family's mode is right under the whole posterior mixture (module
    docstring): ``w_f · mass_f`` (``weight``, ``mass (F,)``, :func:`tolerance_mass`) plus the mass the other
    families put on states with an image (``group``) within ``angle_deg`` on every Euler axis and ``rate_rel`` of
    the rate of mode ``f`` — ``q0 (F, 4)``, ``omega0 (F, 3)`` (rad/s), ``covariance (F, 6+, 6+)`` (the bounded
    Laplace covariances). ``draws`` states of the mixture (standard normal draws from ``seed``), allocated to the
    families by systematic sampling of ``weight``, each counting ``1 / draws``; a family's own draws are left out of
    its cross term. Modes are compared in chunks of ``chunk``."""
    n_fam = q0.shape[0]
    cum = torch.cumsum(weight.double().clamp_min(0.0), 0).cpu()
    if n_fam < 2 or not float(cum[-1]) > 0.0:
        return weight * mass
    positions = (torch.arange(draws, dtype=torch.float64) + 0.5) / draws * float(cum[-1])
    owner = torch.searchsorted(cum, positions, right=True).clamp_max(n_fam - 1).to(q0.device)  # (n,)
    gen = torch.Generator(device="cpu").manual_seed(seed)
    z = torch.randn(draws, 6, generator=gen, dtype=q0.dtype).to(q0.device)
    cross = torch.zeros(n_fam, dtype=q0.dtype, device=q0.device)
    for g in owner.unique().tolist():
        rows = owner == g
        q, omega = _draws(q0[g:g + 1], omega0[g:g + 1], covariance[g:g + 1], z[rows])
        q_img, w_img = group.attitudes(q[0]), group.rates(omega[0])  # (K, n_g, 4), (K, n_g, 3)
        rate = torch.linalg.vector_norm(omega[0], dim=-1).unsqueeze(0)  # (1, n_g)
        cos_limit = math.cos(math.radians(1.5 * angle_deg))  # Euler errors within a each: total angle < 3a
        for part in torch.arange(n_fam, device=q0.device).split(chunk):
            part = part[part != g]
            if not len(part):
                continue
            near = torch.einsum("kna,fa->kfn", q_img, q0[part]).abs() >= cos_limit  # (K, c, n_g)
            near &= torch.cdist(omega0[part].expand(len(group), -1, 3), w_img) < rate_rel * rate  # (K, c, n_g)
            k, f, n = torch.nonzero(near, as_tuple=True)
            if not len(k):
                continue
            ok = _within(q_img[k, n], w_img[k, n], q0[part][f], omega0[part][f], angle_deg=angle_deg,
                         rate_rel=rate_rel)
            hit = torch.zeros(len(part), q_img.shape[1], dtype=torch.bool, device=q0.device)
            hit[f[ok], n[ok]] = True
            cross[part] += hit.sum(-1).to(q0.dtype) / draws
    return (weight * mass + cross).clamp_max(1.0)


@dataclass(frozen=True)
class Families:
    """The families within the likelihood-ratio cut, best weight first.

    Attributes:
        q0: initial attitudes ``(F, 4)``; omega0: initial body rates ``(F, 3)`` (rad/s); log_rho: ``ln ρ̂ (F,)``.
        log_likelihood: ``ℓ (F,)`` (nats); log_evidence: ``ln Z (F,)``; weight: ``(F,)`` summing to 1 (the
            posterior mass of each basin).
        mass: the Gaussian mass of the tolerance region about each mode ``(F,)`` (:func:`tolerance_mass`);
        p_right: the probability that each family's mode is the right answer ``(F,)``: ``weight · mass`` and the
            mass other families put within its tolerance (:func:`mixture_p_right`).
        covariance: Laplace covariances of ``[θ, ω, ln ρ]`` ``(F, 7, 7)`` (rad², (rad/s)², …).
        members: solutions in each family ``(F,)``.
        images: the labels of the group the families were taken modulo.
        beyond: modes within the likelihood-ratio cut left out as beyond the prior's rate ball
            (:func:`beyond_support`).
    """

    q0: Tensor
    omega0: Tensor
    log_rho: Tensor
    log_likelihood: Tensor
    log_evidence: Tensor
    weight: Tensor
    mass: Tensor
    p_right: Tensor
    covariance: Tensor
    members: Tensor
    images: tuple[str, ...]
    beyond: int = 0

    def __len__(self) -> int:
        return self.q0.shape[0]


def families(group: AmbiguityGroup, *, q0: Tensor, omega0: Tensor, log_rho: Tensor, cost: Tensor,
             covariance: Tensor, sigma: Tensor, rate_max_rad_s: float, max_log_ratio: float = 10.0,
             angle_deg: float = 5.0, rate_deg_s: float = 0.05) -> Families:
    """Cluster converged solutions (``M`` rows: ``q0 (M, 4)``, ``omega0 (M, 3)``, ``log_rho (M,)``, ``cost (M,)`` =
    ``½ Σ r²``, ``covariance (M, 7, 7)``), keep the families within ``max_log_ratio`` nats of the best and weight
    them by evidence (module docstring); modes beyond the prior's rate ball (:func:`beyond_support`) are no families
    unless every mode is. ``sigma (K,)`` the light curve's 1σ (mag) for the likelihood's constant."""
    labels, heads = cluster(group, q0, omega0, cost, angle_deg=angle_deg, rate_deg_s=rate_deg_s)
    constant = float(torch.log(math.sqrt(2.0 * math.pi) * sigma).sum())
    ll = -cost[heads] - constant
    inside = ~beyond_support(omega0[heads], covariance[heads], rate_max_rad_s)
    if not bool(inside.any()):
        inside = torch.ones_like(inside)
    near = (ll[inside].max() - ll) <= max_log_ratio
    keep, beyond = inside & near, int((~inside & near).sum())
    heads, ll = heads[keep], ll[keep]
    cov = covariance[heads]
    # det(2π (Σ⁻¹ + P)⁻¹) = det(2π Σ) / det(I + Σ P), no inverse of a nearly singular Σ (module docstring)
    logdet = torch.linalg.slogdet(2.0 * math.pi * cov)
    eye = torch.eye(cov.shape[-1], dtype=cov.dtype, device=cov.device)
    bound = torch.linalg.slogdet(eye + cov * prior_precision(rate_max_rad_s, dtype=cov.dtype, device=cov.device))
    ok = (logdet.sign > 0) & (bound.sign > 0)
    half_logdet = torch.where(ok, 0.5 * (logdet.logabsdet - bound.logabsdet), torch.full_like(ll, -math.inf))
    log_z = ll + half_logdet - log_prior_volume(rate_max_rad_s)
    finite = torch.isfinite(log_z)
    weight = torch.where(finite, torch.softmax(torch.where(finite, log_z, -math.inf), 0), 0.0) if bool(finite.any()) \
        else torch.full_like(ll, 1.0 / ll.numel())
    order = torch.argsort(weight, descending=True, stable=True)
    members = torch.bincount(labels, minlength=int(labels.max()) + 1)[torch.nonzero(keep).squeeze(-1)]
    pick = lambda t: t[heads][order]  # noqa: E731
    mass = tolerance_mass(pick(q0), pick(omega0), bounded_covariance(cov[order], rate_max_rad_s))
    mass = torch.where(torch.isfinite(mass), mass, torch.zeros_like(mass))
    p_right = mixture_p_right(group, q0=pick(q0), omega0=pick(omega0),
                              covariance=bounded_covariance(cov[order], rate_max_rad_s), weight=weight[order],
                              mass=mass)
    return Families(q0=pick(q0), omega0=pick(omega0), log_rho=pick(log_rho), log_likelihood=ll[order],
                    log_evidence=log_z[order], weight=weight[order], mass=mass, p_right=p_right,
                    covariance=cov[order], members=members[order], images=tuple(group.labels), beyond=beyond)
