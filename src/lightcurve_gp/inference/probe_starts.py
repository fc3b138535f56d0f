"""Where the answer's probes restart the search: states near the leading families that the continuation may not
have visited (:mod:`.answer` runs them, polishes them on the whole light curve and joins them to the solutions).

* **ridge** (:func:`ridge_starts`): a family whose rate turns less than once over the arc
  (:func:`below_one_turn`), at its rate's axis and axes tilted by :data:`RIDGE_TILTS_DEG`, each at the rate's
  magnitude and times :data:`RIDGE_FACTORS`;
* **local** (:func:`local_starts`): every leading family itself (polished further), at its rate times
  :data:`LOCAL_FACTORS` about the same axis, and at its axis tilted by :data:`LOCAL_TILTS_DEG`: the neighbouring
  basins in rate and axis that the last continuation stage, a few Levenberg–Marquardt iterations from a shorter arc,
  can stop short of;
* **image** (:func:`image_starts`): a family under inertial turns (e.g. the first sample's, along a pass);
* **body turn** (:func:`body_turn_starts`): a family under the axis rotations of the body frame that are not exact
  images (:func:`near_body_turns`): where the shape nearly maps onto itself they start near another basin;
* **harmonic** (:func:`harmonic_starts`): a family at its rate times :data:`HARMONIC_FACTORS`, about its axis and
  axes tilted by :data:`HARMONIC_TILTS_DEG`: a light curve of ``k`` brightness cycles per turn can be fitted nearly
  as well by a spin of ``k ± 1`` cycles per turn, its rate times ``k / (k ± 1)`` (½, ⅔, 3/2 and 2 for ``k ≤ 3``).

A restart at another rate keeps the attitude at the middle of the arc (``q(t) ≈ exp(ω t) ⊗ q0`` for a constant
body rate): the light curve pins the attitude best where it has samples on both sides. Every function returns
initial attitudes ``(M, 4)`` and states ``(M, 7)`` (``θ = 0``, rate in rad/s, ln ρ), ``M = 0`` when there is no
start.
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import attitude_matrix, matrix_to_quat, quat_conj, quat_mul, rotvec_to_quat
from lightcurve_gp.inference.families import Families
from lightcurve_gp.photometry.ambiguity import AmbiguityGroup
from lightcurve_gp.photometry.symmetry import cube_rotations

__all__ = ["RIDGE_FACTORS", "RIDGE_FAMILIES", "RIDGE_TILTS_DEG", "RIDGE_AZIMUTHS", "LOCAL_FACTORS",
           "LOCAL_TILTS_DEG", "LOCAL_FAMILIES", "LOCAL_ITERATIONS", "IMAGE_FAMILIES", "HARMONIC_FACTORS",
           "HARMONIC_TILTS_DEG", "HARMONIC_FAMILIES", "BODY_TURN_FAMILIES", "below_one_turn", "tilted_rates",
           "restarted_at", "ridge_starts", "local_starts", "image_starts", "near_body_turns", "body_turn_starts",
           "harmonic_starts"]

#: the ridge probe's rate factors
RIDGE_FACTORS = (0.25, 0.5, 0.71, 1.41, 2.0)
#: leading families the ridge probe restarts
RIDGE_FAMILIES = 3
#: the ridge probe's tilts of the rate's axis (deg), each towards this many directions about it
RIDGE_TILTS_DEG = (30.0, 60.0)
RIDGE_AZIMUTHS = 6
#: the local probe's rate factors (about the family's own axis) and axis tilts (deg, at its own magnitude)
LOCAL_FACTORS = (0.92, 0.96, 0.98, 0.99, 1.01, 1.02, 1.04, 1.08)
LOCAL_TILTS_DEG = (2.0, 5.0, 10.0)
#: leading families the local probe restarts, and its Levenberg–Marquardt iterations
LOCAL_FAMILIES = 4
LOCAL_ITERATIONS = 30
#: leading families the image probe restarts at their images
IMAGE_FAMILIES = 4
#: the harmonic probe's rate factors, its axis tilts (deg, each towards :data:`RIDGE_AZIMUTHS` directions) and the
#: leading families it restarts
HARMONIC_FACTORS = (0.5, 2.0 / 3.0, 1.5, 2.0)
HARMONIC_TILTS_DEG = (10.0, 20.0)
HARMONIC_FAMILIES = 4
#: leading families the body-turn probe restarts
BODY_TURN_FAMILIES = 4


def below_one_turn(rate_rad_s, *, span_s: float):
    """Whether a rate (rad/s; a number or a tensor) turns less than once over ``span_s`` seconds: where the
    periodogram has no resolution and the answer is a ridge."""
    return rate_rad_s * span_s < 2.0 * math.pi


def tilted_rates(omega: Tensor, *, tilts_deg=RIDGE_TILTS_DEG, azimuths: int = RIDGE_AZIMUTHS) -> Tensor:
    """Rates ``(n, 1 + len(tilts_deg) · azimuths, 3)`` of the magnitudes of ``omega (n, 3)`` (rad/s): the rate
    itself first, then its axis tilted by each angle of ``tilts_deg`` towards ``azimuths`` directions spread about
    it."""
    size = torch.linalg.vector_norm(omega, dim=-1, keepdim=True)
    n = omega / size
    basis = torch.eye(3, dtype=omega.dtype, device=omega.device)[n.abs().argmin(-1)]  # the axis least along n
    a = torch.linalg.cross(n, basis, dim=-1)
    a = a / torch.linalg.vector_norm(a, dim=-1, keepdim=True)
    b = torch.linalg.cross(n, a, dim=-1)
    out = [omega]
    for tilt in tilts_deg:
        t = math.radians(tilt)
        for k in range(azimuths):
            phi = 2.0 * math.pi * k / azimuths
            out.append(size * (math.cos(t) * n + math.sin(t) * (math.cos(phi) * a + math.sin(phi) * b)))
    return torch.stack(out, 1)


def restarted_at(omega: Tensor, *, q0: Tensor, omega0: Tensor, log_rho: Tensor,
                 span_s: float) -> tuple[Tensor, Tensor]:
    """Starts at the rates ``omega (n, D, 3)`` (rad/s) of the states ``q0 (n, 4)``, ``omega0 (n, 3)``,
    ``log_rho (n,)``: each keeps its state's attitude at ``span_s / 2`` and ln ρ; ``(n·D, 4)``, ``(n·D, 7)``."""
    per = omega.shape[1]
    omega = omega.reshape(-1, 3)
    half = 0.5 * span_s
    kept = quat_mul(rotvec_to_quat(omega0 * half), q0).repeat_interleave(per, 0)
    moved = quat_mul(quat_conj(rotvec_to_quat(omega * half)), kept)
    rho = log_rho.repeat_interleave(per, 0)
    return moved, torch.cat([torch.zeros_like(omega), omega, rho[:, None]], -1)


def ridge_starts(fam: Families, *, span_s: float, factors=RIDGE_FACTORS,
                 leading: int = RIDGE_FAMILIES) -> tuple[Tensor, Tensor]:
    """The ridge probe's starts: for every leading family below one turn over ``span_s``, its rate's axis and the
    tilted ones (:func:`tilted_rates`) times 1 and every factor (the family itself left out)."""
    rate = torch.linalg.vector_norm(fam.omega0[:leading], dim=-1)
    slow = torch.nonzero(below_one_turn(rate, span_s=span_s)).squeeze(-1)
    if slow.numel() == 0:
        return fam.q0.new_zeros(0, 4), fam.q0.new_zeros(0, 7)
    scale = torch.tensor((1.0, *factors), dtype=fam.q0.dtype, device=fam.q0.device)
    axes = tilted_rates(fam.omega0[slow])  # (n, D, 3)
    omega = (axes[:, :, None, :] * scale[:, None]).flatten(1, 2)[:, 1:]  # (n, D·S − 1, 3): not the family itself
    return restarted_at(omega, q0=fam.q0[slow], omega0=fam.omega0[slow], log_rho=fam.log_rho[slow], span_s=span_s)


def local_starts(fam: Families, *, span_s: float, factors=LOCAL_FACTORS, tilts_deg=LOCAL_TILTS_DEG,
                 azimuths: int = RIDGE_AZIMUTHS, leading: int = LOCAL_FAMILIES) -> tuple[Tensor, Tensor]:
    """The local probe's starts: each of the ``leading`` families itself, at its rate times every factor about its
    own axis, and at its axis tilted by each of ``tilts_deg`` towards ``azimuths`` directions (its own magnitude):
    ``1 + len(factors) + len(tilts_deg) · azimuths`` rows per family, the family first."""
    n = min(leading, len(fam))
    if n == 0:
        return fam.q0.new_zeros(0, 4), fam.q0.new_zeros(0, 7)
    w = fam.omega0[:n]
    scale = torch.tensor(factors, dtype=w.dtype, device=w.device)
    tilted = tilted_rates(w, tilts_deg=tilts_deg, azimuths=azimuths)  # (n, 1 + T·A, 3): the rate itself first
    omega = torch.cat([tilted[:, :1], w[:, None, :] * scale[:, None], tilted[:, 1:]], 1)
    return restarted_at(omega, q0=fam.q0[:n], omega0=w, log_rho=fam.log_rho[:n], span_s=span_s)


def image_starts(turns: Tensor, *, q0: Tensor, omega0: Tensor, log_rho: Tensor) -> tuple[Tensor, Tensor]:
    """The image probe's starts: initial attitudes ``q_0 ⊗ q_C`` ``(F·C, 4)`` of the states ``q0 (F, 4)``,
    ``omega0 (F, 3)`` (rad/s), ``log_rho (F,)`` under each turn of ``turns (C, 4)`` (quaternions), and states
    ``(F·C, 7)`` (``θ = 0``, each state's rate and ln ρ), the turns of one state together."""
    turns = turns.to(q0)
    per = turns.shape[0]
    starts = quat_mul(q0[:, None, :], turns[None]).reshape(-1, 4)
    omega, log_rho = omega0.repeat_interleave(per, 0), log_rho.repeat_interleave(per, 0)
    return starts, torch.cat([torch.zeros_like(omega), omega, log_rho[:, None]], -1)


def near_body_turns(group: AmbiguityGroup) -> AmbiguityGroup:
    """The axis rotations of the body frame (the 24 rotations mapping ±x, ±y, ±z onto themselves) that are not
    among ``group``'s body images, as images of their own (``B`` body turns, no inertial turn, the rate turned with
    the body): the body-turn probe's turns. A box's faces map onto faces under each; where materials, appendages or
    the inertia break the symmetry the image is another state, whose basin the search can miss while it finds this
    one."""
    rotations = cube_rotations(dtype=group.body.dtype, device=group.body.device)
    exact = attitude_matrix(group.body)  # (K, 3, 3)
    known = ((rotations[:, None] - exact[None]).abs().flatten(-2).amax(-1) < 1e-3).any(-1)  # entries 0 or ±1
    body = matrix_to_quat(rotations[~known])
    identity = torch.zeros_like(body)
    identity[:, 3] = 1.0
    return AmbiguityGroup(body=body, inertial=identity, rate_known=False,
                          labels=tuple(f"near body turn {k + 1}" for k in range(body.shape[0])))


def body_turn_starts(turns: AmbiguityGroup, fam: Families, *,
                     leading: int = BODY_TURN_FAMILIES) -> tuple[Tensor, Tensor]:
    """The body-turn probe's starts: each of the ``leading`` families ``(q_0, ω_0, ln ρ)`` under every image of
    ``turns`` (:func:`near_body_turns`; :meth:`~lightcurve_gp.photometry.ambiguity.AmbiguityGroup.attitudes` and
    ``rates``: ``(q_R ⊗ q_0, R ω_0, ln ρ)``), ``(n·B, 4)`` and ``(n·B, 7)``, the turns of one family together."""
    n = min(leading, len(fam))
    if n == 0 or len(turns) == 0:
        return fam.q0.new_zeros(0, 4), fam.q0.new_zeros(0, 7)
    turns = turns.to(device=fam.q0.device, dtype=fam.q0.dtype)
    per = len(turns)
    q = turns.attitudes(fam.q0[:n]).transpose(0, 1).reshape(-1, 4)  # (B, n, 4) -> (n·B, 4)
    omega = turns.rates(fam.omega0[:n]).transpose(0, 1).reshape(-1, 3)
    rho = fam.log_rho[:n].repeat_interleave(per, 0)
    return q, torch.cat([torch.zeros_like(omega), omega, rho[:, None]], -1)


def harmonic_starts(fam: Families, *, span_s: float, rate_range_deg_s: tuple[float, float],
                    factors=HARMONIC_FACTORS, tilts_deg=HARMONIC_TILTS_DEG, azimuths: int = RIDGE_AZIMUTHS,
                    leading: int = HARMONIC_FAMILIES) -> tuple[Tensor, Tensor]:
    """The harmonic probe's starts: each of the ``leading`` families at its rate times every factor, about its axis
    and its axis tilted by each of ``tilts_deg`` towards ``azimuths`` directions (:func:`tilted_rates`), keeping
    its attitude at the middle of the arc (:func:`restarted_at`); rates outside ``rate_range_deg_s`` (°/s) left
    out. ``(M, 4)``, ``(M, 7)``, the rows of one family together."""
    n = min(leading, len(fam))
    if n == 0:
        return fam.q0.new_zeros(0, 4), fam.q0.new_zeros(0, 7)
    w = fam.omega0[:n]
    scale = torch.tensor(factors, dtype=w.dtype, device=w.device)
    axes = tilted_rates(w, tilts_deg=tilts_deg, azimuths=azimuths)  # (n, D, 3)
    omega = (axes[:, :, None, :] * scale[:, None]).flatten(1, 2)  # (n, D·F, 3)
    q, x = restarted_at(omega, q0=fam.q0[:n], omega0=w, log_rho=fam.log_rho[:n], span_s=span_s)
    rate = torch.rad2deg(torch.linalg.vector_norm(x[:, 3:6], dim=-1))
    inside = (rate >= rate_range_deg_s[0]) & (rate <= rate_range_deg_s[1])
    return q[inside], x[inside]
