"""The global inversion's answer: the search, its families, the fit test, and what it does when the fit fails.

:func:`answer` runs :func:`~.inversion.invert` and :func:`~.families.families` and judges the best fit by its χ²
(:mod:`.fit_verdict`: ``χ² = 2 c`` against ``χ²_ν``, ``ν = N − 7``). These rules make the answer honest (the
probes' starts: :mod:`.probe_starts`):

1. **Widening.** A best fit whose p-value is below :data:`~.fit_verdict.P_NO_FIT` is never reported as found: the
   search runs once more, wider (:func:`widened_settings`): twice the starts, twice the Sobol' attitudes of the
   first-arc screen (a new scramble), a rate grid twice as fine (shell ratio ``√1.5`` instead of 1.5) with shells
   at the periodogram's candidates and the best families' rates and their harmonics ½× and 2× (:func:`wider_rates`),
   and twice the rows carried through the continuation. Its solutions join the first search's and the families are
   formed again over both. One round only: if the fit still fails, the verdict is ``"no_fit"``, and every
   family's ``p_right`` is 0: the probabilities of being right are the posterior's under the model the χ² test has
   just rejected, so the answer states none (the weights stay, comparing the basins with one another). Held-out,
   before this rule: 20 ``no_fit`` answers (seeds 1000–1199, five cases), none right, their mean ``p_right`` 0.98.
2. **Verdict** (:func:`~.fit_verdict.verdict`): ``"no_fit"`` when the best fit still fails its test; ``"unique"`` when
   it fits and the heaviest family is right (within 10° and 2 % of the truth) with probability ``p_right``
   (:mod:`.families`: the posterior's mass of that region about its mode, its own basin's and any other family's
   there) of at least
   :data:`~.fit_verdict.UNIQUE_WEIGHT`; ``"ambiguous"`` otherwise.
3. **Ridge probe.** Below one turn over the arc (``|ω| · span < 2π``, the periodogram's resolution) the light curve
   need not fix the rate: the posterior can be a ridge along it that the continuation, which keeps one row per
   basin, reduces to one point. Each of the :data:`RIDGE_FAMILIES` leading families with such a rate is restarted
   at its rate's axis and at axes tilted by :data:`RIDGE_TILTS_DEG` (towards :data:`RIDGE_AZIMUTHS` directions),
   each with the rate's magnitude and that times :data:`RIDGE_FACTORS` (77 rows per family; the initial attitude
   moved so that the attitude at the middle of the arc is kept, for a constant rate), and polished on the whole
   light curve; the polished states join the solutions (measured on held-out seed 1003, 0.2 °/s over 600 s: the
   magnitudes alone left the search 1.7 nats above the truth's basin and the top family 26° off with weight 1; with
   the tilts the best found is 0.9 nats below the basin, among 7 families (the top one at 1.6° and 4 % of the rate
   in one run, 19° in another: the weights between them are the ridge's, below); the probe took 16–21 s instead of
   4 s beside other work). Where the rate is resolved they come back to the family or fit worse by more than the
   likelihood-ratio cut; where it is not they are families of their own and share the weight.
   **Rate profile** (:mod:`.rate_profile`): below one turn the top family's rate is then profiled (its data cost
   polished at 0.5–2× its rate with the magnitude pinned). A profile point more than :data:`PROFILE_JOIN_NATS`
   below the family is polished freely and joins the solutions, and the new top family is profiled once more. The
   profile decides the **ridge**: the top family is on one when its 95 % profile interval is wider than the 2 % of
   "right" (less than one turn does not make a ridge: a box-wing turning 325° in 600 s at 0.05 mag has its rate
   fixed to ±0.3 %, its interval 0.541–0.544 °/s); a ridge's verdict is ``"ambiguous"`` whatever the weights, and
   its ``p_right`` is capped at its weight times the profile's share within the tolerance
   (:func:`~.rate_profile.ridge_rule`): the Laplace covariance at one point of a ridge cannot say how flat it is,
   and with other families beside it the weights between points of one ridge rest on Laplace volumes
   (:mod:`.families`) that a ridge does not have (measured on a 0.1 °/s tumbler over 200 s: the ridge's families
   within 0.3 nats of each other, the top one with weight 0.85–0.997 depending on its nearly singular covariance).
   The reported **rate interval** spans the families' rates and the top family's profile interval.
4. **Image probe.** Along a pass the Sun and observer move, and the 180° inertial turns of the first sample's pair
   (:func:`~lightcurve_gp.photometry.ambiguity.near_image_turns`) are not in the exact group: the image of a
   state under one fits the first arcs as well and the whole arc a few to tens of nats apart, a basin of its own
   that the continuation can lose. Each of the :data:`IMAGE_FAMILIES` leading families is restarted at its images
   under ``image_turns`` (same rate and ρ) and polished on the whole light curve, and the polished states join the
   solutions (measured on the GEO pass, held-out seeds 1004 and 1014 at 0.05 mag: the search reported one family,
   the in-plane-perpendicular and plane-normal images of the truth, 33.5 and 2.4 nats above the truth's basin and
   `unique`; polished from its images, 8 iterations reach the truth's basin to 0.01 nats on both).
5. **Local probe.** The continuation's last stage takes a few Levenberg–Marquardt iterations on the whole light
   curve from a solution of a shorter arc, and can stop short of its basin's minimum or in a neighbouring basin a
   few per cent away in rate or a few degrees in axis. Each of the :data:`~.probe_starts.LOCAL_FAMILIES` leading
   families is polished again, :data:`~.probe_starts.LOCAL_ITERATIONS` iterations, from itself, from its rate times
   :data:`~.probe_starts.LOCAL_FACTORS` and from its axis tilted by :data:`~.probe_starts.LOCAL_TILTS_DEG` (27 rows
   per family), and the polished states join the solutions; ``probe_gain_nats`` says by how much each probe
   lowered the best cost. Its tilts include 2°: a fast tumbler's basins are that narrow in axis (tuning seed 18 at
   0.71 mag, 4.28 °/s: the search stopped 71 nats above the truth's basin, 5° and 4 % off; restarts tilted by 2°
   reach it, by 5° and 10° none do).
6. **Far probes.** Two kinds of basin lie too far from a found family for the local probe
   (:mod:`.probe_starts`): the family under the body's axis rotations that are not exact images
   (:func:`~.probe_starts.near_body_turns`, 20 for the box-wing: a box's faces map onto faces, and only the wings
   and the inertia tell them apart), and the family at a harmonic of its rate (×½, ⅔, 3/2 and 2, about its axis and
   axes tilted by 10° and 20°, the attitude at the middle of the arc kept). Each of the leading families is
   restarted at both, polished :data:`~.probe_starts.LOCAL_ITERATIONS` iterations, and the states join the
   solutions; when they lower the best cost by more than :data:`FAR_AGAIN_NATS` the local probe runs once more
   about the new leading families (a harmonic restart lands near its basin, not in it). Measured on the tuning
   seeds 0–29 at 0.71 mag, 10⁴ starts: the search missed 7 (1.3–135 nats above the truth's basin); restarts from
   their top families reached the basin by a 2° tilt on one, harmonics (×3/2, ×½) on three, a body turn on one and
   the local probe about the found families on one; the whole answer with these probes reaches it on six of the
   seven. Held-out (seeds 1000–1029): 3 misses of 30 become 2.
7. **Settling.** A probe's restart that lands in a basin along a flat direction can stop short of its minimum after
   its iterations; the leading families found by then are polished once more from themselves
   (:data:`~.probe_starts.LOCAL_ITERATIONS` iterations, :data:`~.probe_starts.LOCAL_FAMILIES` rows) and the states
   join the solutions (measured on held-out seed 1169, 0.1 mag, 1.84 °/s: the local probe gained 2528 nats and
   stopped 2.2 nats above the truth's basin, 72° from its minimum along a flat attitude valley; 12 more iterations
   from the reported family end 0.08 nats above it).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Callable

import torch
from torch import Tensor

from lightcurve_gp.inference.bridge import carry_across_gaps
from lightcurve_gp.inference.families import RIGHT_ANGLE_DEG, RIGHT_RATE_REL, Families, beyond_support, families
from lightcurve_gp.inference.fit_verdict import INVERSION_PARAMETERS, UNIQUE_WEIGHT, FitTest, fit_test, verdict
from lightcurve_gp.inference.inversion import Inversion, InversionSettings, invert, polish, rate_starts
from lightcurve_gp.inference.periodogram import RATE_FACTORS
from lightcurve_gp.inference.probe_starts import (
    IMAGE_FAMILIES,
    LOCAL_ITERATIONS,
    below_one_turn,
    body_turn_starts,
    harmonic_starts,
    image_starts,
    local_starts,
    near_body_turns,
    ridge_starts,
)
from lightcurve_gp.inference.rate_profile import RateProfile, rate_profile, ridge_rule
from lightcurve_gp.inference.trajectory import TrajectoryProblem
from lightcurve_gp.photometry.ambiguity import AmbiguityGroup

__all__ = ["MAX_LOG_RATIO", "WIDEN_FACTOR", "PROFILE_JOIN_NATS", "FAR_AGAIN_NATS", "Answer", "best_fit", "searched",
           "sample_times", "widened_settings", "wider_rates", "merge", "answer"]

#: families within this many nats of the best are reported
MAX_LOG_RATIO = 10.0
#: a point of the rate profile this many nats below the top family is polished and joins the solutions
PROFILE_JOIN_NATS = 0.5
#: the widened search's starts, screen attitudes, screen rates and continuation rows, each times this
WIDEN_FACTOR = 2
#: the local probe runs again when the body-turn and harmonic probes lowered the best cost by more than this (nats)
FAR_AGAIN_NATS = 0.5


@dataclass
class Answer:
    """What the inversion says of a light curve (module docstring).

    Attributes:
        inversion: every converged solution (the widened search's and the probes' joined in).
        families: the families within the likelihood-ratio cut, best weight first.
        fit: the best fit's χ² test; verdict: ``"unique"``, ``"ambiguous"`` or ``"no_fit"``.
        widened: whether the first search's fit failed and the search was widened; first_fit: that search's test.
        probe_rows: the solutions each probe that ran added, by name (``"ridge"``: only when a leading family is
            below one turn over the arc; ``"local"``; ``"image"``: only with ``image_turns``; ``"body turn"``,
            ``"harmonic"``; ``"local again"``: only when those two lowered the best cost).
        probe_gain_nats: by how much each probe that ran lowered the best cost (nats, ≥ 0), by name.
        ridge: the top family is below one turn over the arc and its rate profile does not resolve its rate
            (module docstring).
        rate_interval_deg_s: the smallest and largest ``|ω|`` of the families and of the top family's 95 % profile
            interval (°/s).
        profile: the top family's rate profile (:mod:`.rate_profile`; ``None`` above one turn over the arc).
        seconds: wall time of the first search, the widening and each probe.
    """

    inversion: Inversion
    families: Families
    fit: FitTest
    verdict: str
    widened: bool
    first_fit: FitTest
    ridge: bool
    rate_interval_deg_s: tuple[float, float]
    profile: RateProfile | None = None
    probe_rows: dict = field(default_factory=dict)
    probe_gain_nats: dict = field(default_factory=dict)
    seconds: dict = field(default_factory=dict)

    def words(self) -> str:
        """The verdict in one sentence."""
        fam, f = self.families, self.fit
        stats = f"chi2/dof {f.chi2_per_dof:.2f} over {f.dof} degrees of freedom, p = {f.p_value:.3g}"
        wide = " after a widened search" if self.widened else ""
        if self.verdict == "no_fit":
            return (f"no solution fits this light curve{wide}: the best fit's {stats}, far outside what its mag_err "
                    "allows (the shape, the noise level or the rate range is wrong, or the search missed the "
                    "answer); the families below are not an answer")
        lo, hi = self.rate_interval_deg_s
        rates = f"rate {lo:.4g} deg/s" if len(fam) == 1 and lo == hi else f"rates {lo:.4g}-{hi:.4g} deg/s"
        if self.profile is not None:
            a, b = self.profile.interval_deg_s
            ends = ("at least " if self.profile.open[0] else "") + f"{a:.4g}", \
                f"{b:.4g}" + (" or more" if self.profile.open[1] else "")
            rates = (f"rate {self.profile.rate_deg_s:.4g} deg/s, 95 % interval {ends[0]}-{ends[1]} deg/s"
                     + ("" if len(fam) == 1 else f"; the families' rates {lo:.4g}-{hi:.4g} deg/s"))
        tolerance = f"{RIGHT_ANGLE_DEG:g} deg and {100 * RIGHT_RATE_REL:g} %"
        if float(fam.p_right[0]) > float(fam.weight[0]) + 5e-4:  # neighbours within its tolerance (:mod:`.families`)
            rates += "; the probability counts the other families' mass within that tolerance of it"
        if self.verdict == "unique":
            return (f"unique: one family carries weight {float(fam.weight[0]):.3f} and is within {tolerance} of "
                    f"the truth with probability {float(fam.p_right[0]):.3f} ({rates}); the fit is what the noise "
                    f"allows ({stats}){wide}")
        what = ("the rate is not resolved over the arc (a ridge: less than one turn, the rate's profile flat "
                "beyond the tolerance)" if self.ridge else "the light curve does not single one out")
        if not self.ridge and float(fam.weight[0]) >= UNIQUE_WEIGHT:
            return (f"ambiguous: one basin carries weight {float(fam.weight[0]):.3f} ({rates}) but the light curve "
                    f"does not pin it within {tolerance} (probability {float(fam.p_right[0]):.3f}) ({stats}){wide}")
        if len(fam) == 1:
            return (f"ambiguous: one family fits ({rates}), within {tolerance} with probability "
                    f"{float(fam.p_right[0]):.3f}, but {what} ({stats}){wide}")
        return (f"ambiguous: {len(fam)} families fit ({rates}), the heaviest with weight {float(fam.weight[0]):.3f} "
                f"(within {tolerance} with probability {float(fam.p_right[0]):.3f}); {what} ({stats}){wide}")

    def as_dict(self) -> dict:
        return {"verdict": self.verdict, "fit": self.fit.as_dict(), "widened": self.widened,
                "first_fit": self.first_fit.as_dict(), "probe_rows": dict(self.probe_rows),
                "probe_gain_nats": dict(self.probe_gain_nats), "ridge": self.ridge,
                "rate_interval_deg_s": list(self.rate_interval_deg_s),
                "rate_profile": None if self.profile is None else self.profile.as_dict()}


def sample_times(problem: TrajectoryProblem) -> Tensor:
    """The samples' times from the first ``(K,)`` (s) — the one place that reads how the problem stores them."""
    return problem.times - problem.times[0]


def widened_settings(settings: InversionSettings) -> InversionSettings:
    """The widened search's settings (module docstring): starts, screen attitudes and rows ×:data:`WIDEN_FACTOR`,
    the screen's rates ×:data:`WIDEN_FACTOR` (the screen grid ×``WIDEN_FACTOR²``), a new Sobol' scramble."""
    k = WIDEN_FACTOR
    return replace(settings, starts=k * settings.starts, attitudes=k * settings.attitudes,
                   screen_factor=k * settings.screen_factor,
                   keep=None if settings.keep is None else tuple(k * n for n in settings.keep),
                   shell_ratio=math.sqrt(settings.shell_ratio), seed=settings.seed + 1)


def wider_rates(inv: Inversion, fam: Families, settings: InversionSettings, *, span_s: float) -> Tensor:
    """The widened screen's rates ``(R, 3)`` (rad/s): shells at the periodogram's candidates and the families'
    rates, each with its ½× and 2× (inside the rate range), over the finer log grid of ``settings`` (already
    widened), about ``starts · screen_factor / attitudes`` of them."""
    lo, hi = settings.rate_range_deg_s
    base = [float(r) for r in inv.periodogram.rates_deg_s]
    base += [math.degrees(float(w)) for w in torch.linalg.vector_norm(fam.omega0, dim=-1)]
    candidates = sorted({round(b * f, 9) for b in base for f in RATE_FACTORS if lo <= b * f <= hi})
    count = max(1, settings.starts * settings.screen_factor // settings.attitudes)
    return rate_starts(candidates, count=count, rate_range_deg_s=settings.rate_range_deg_s, span_s=span_s,
                       shell_ratio=settings.shell_ratio, dtype=inv.q0.dtype, device=inv.q0.device)


def merge(a: Inversion, b: Inversion) -> Inversion:
    """The solutions of two searches of one light curve as one (``a``'s periodogram; the rate grids joined)."""
    cat = lambda name: torch.cat([getattr(a, name), getattr(b, name)])  # noqa: E731
    seconds = {**a.seconds, **{f"widened {k}": v for k, v in b.seconds.items()}}
    return Inversion(q0=cat("q0"), omega0=cat("omega0"), log_rho=cat("log_rho"), cost=cat("cost"),
                     covariance=cat("covariance"), periodogram=a.periodogram, rate_grid=cat("rate_grid"),
                     seconds=seconds)


def _families(group: AmbiguityGroup, inv: Inversion, problem: TrajectoryProblem, *, rate_max_rad_s: float,
              max_log_ratio: float, settings: InversionSettings) -> Families:
    return families(group, q0=inv.q0, omega0=inv.omega0, log_rho=inv.log_rho, cost=inv.cost,
                    covariance=inv.covariance, sigma=problem.sigma, rate_max_rad_s=rate_max_rad_s,
                    max_log_ratio=max_log_ratio, angle_deg=settings.cluster_angle_deg,
                    rate_deg_s=settings.cluster_rate_deg_s)


def best_fit(inv: Inversion, problem: TrajectoryProblem, *, rate_max_rad_s: float) -> FitTest:
    """The test of the best fit that can be an answer: the least cost of the solutions inside the prior's rate ball
    (:func:`~.families.beyond_support`; all of them when none is), ``ν = N − 7`` less one for each relative light
    curve's profiled zero point."""
    inside = ~beyond_support(inv.omega0, inv.covariance, rate_max_rad_s)
    cost = inv.cost[inside] if bool(inside.any()) else inv.cost
    samples = int(torch.isfinite(problem.y).sum())
    offsets = 0 if problem.zero_points is None else int(problem.zero_points.shape[-1])
    return fit_test(float(cost.min()), samples=samples, parameters=INVERSION_PARAMETERS + offsets)


def searched(problem: TrajectoryProblem, group: AmbiguityGroup, *, settings: InversionSettings, judge: dict,
             widen: bool = True, progress: Callable[[str], None] | None = None) -> Inversion:
    """One search of ``problem`` and, when its best fit fails its test, one widened search joined to it (what a pass
    searched alone across a gap gets, :func:`~.bridge.carry_across_gaps`); ``judge``: :func:`_families`' options."""
    found = invert(problem, group, settings=settings, progress=progress)
    if widen and not best_fit(found, problem, rate_max_rad_s=judge["rate_max_rad_s"]).fits:
        wide = widened_settings(settings)
        rates = wider_rates(found, _families(group, found, problem, **judge), wide,
                            span_s=float(sample_times(problem)[-1]))
        found = merge(found, invert(problem, group, settings=wide, rate_grid=rates, progress=progress))
    return found


def answer(problem: TrajectoryProblem, group: AmbiguityGroup, *, settings: InversionSettings = InversionSettings(),
           rate_max_rad_s: float | None = None, max_log_ratio: float = MAX_LOG_RATIO, widen: bool = True,
           ridge: bool = True, local: bool = True, far: bool = True, rate_grid: Tensor | None = None,
           image_turns: Tensor | None = None,
           progress: Callable[[str], None] | None = None) -> Answer:
    """Search ``problem`` from no initial guess and judge the answer (module docstring).

    Args:
        problem, group, settings, rate_grid, progress: as :func:`~.inversion.invert`'s.
        rate_max_rad_s: the evidence's rate-ball radius (rad/s; default the settings' fastest rate).
        max_log_ratio: families within this many nats of the best are reported.
        widen: widen the search once when the first fit fails; ridge, local: run the ridge and the local probe;
            far: run the body-turn and the harmonic probe (and the local probe again after them when they gain).
        image_turns: inertial turns ``(C, 4)`` (quaternions) of the image probe, e.g.
            :func:`~lightcurve_gp.photometry.ambiguity.near_image_turns`; ``None`` or none: no probe.
    """
    say = progress or (lambda message: None)
    rate_max = math.radians(settings.rate_range_deg_s[1]) if rate_max_rad_s is None else rate_max_rad_s
    span_s = float(sample_times(problem)[-1])
    judge = dict(rate_max_rad_s=rate_max, max_log_ratio=max_log_ratio, settings=settings)
    seconds, tick = {}, time.perf_counter()
    inv = invert(problem, group, settings=settings, rate_grid=rate_grid, progress=progress)
    inv = carry_across_gaps(problem, group, inv, settings=settings, progress=progress,  # passes after a gap
                            search=partial(searched, group=group, settings=settings, judge=judge, widen=widen,
                                           progress=progress))
    fam = _families(group, inv, problem, **judge)
    first = best_fit(inv, problem, rate_max_rad_s=rate_max)
    seconds["search"], tick = time.perf_counter() - tick, time.perf_counter()
    widened = widen and not first.fits
    if widened:
        wide = widened_settings(settings)
        say(f"the best fit fails its test (chi2/dof {first.chi2_per_dof:.2f}, p = {first.p_value:.3g}): "
            f"widening the search ({wide.starts} starts, {wide.attitudes} screen attitudes)")
        more = invert(problem, group, settings=wide, rate_grid=wider_rates(inv, fam, wide, span_s=span_s),
                      progress=progress)
        inv = merge(inv, more)
        fam = _families(group, inv, problem, **judge)
        seconds["widening"], tick = time.perf_counter() - tick, time.perf_counter()
    rows, gains = {}, {}

    def run(name: str, starts: tuple[Tensor, Tensor], iterations: int, what: str) -> None:
        nonlocal inv, fam
        q0, x = starts
        if not x.shape[0]:
            return
        say(f"{name} probe: {x.shape[0]} restarts {what}")
        tick, before = time.perf_counter(), float(inv.cost.min())
        probe = polish(problem, q0, x, iterations=iterations)
        inv = merge(inv, replace(probe, periodogram=inv.periodogram, seconds={}))
        fam = _families(group, inv, problem, **judge)
        rows[name], gains[name] = x.shape[0], max(0.0, before - float(inv.cost.min()))
        seconds[f"{name} probe"] = time.perf_counter() - tick

    if ridge:
        run("ridge", ridge_starts(fam, span_s=span_s), settings.final_iterations,
            "of the slow leading families at scaled rates")
    if local:
        run("local", local_starts(fam, span_s=span_s), LOCAL_ITERATIONS,
            "of the leading families at neighbouring rates and axes")
    if image_turns is not None and image_turns.shape[0]:
        n = min(IMAGE_FAMILIES, len(fam))
        run("image", image_starts(image_turns, q0=fam.q0[:n], omega0=fam.omega0[:n], log_rho=fam.log_rho[:n]),
            settings.final_iterations, "of the leading families at their first sample's inertial images")
    if far:
        before = float(inv.cost.min())
        run("body turn", body_turn_starts(near_body_turns(group), fam), LOCAL_ITERATIONS,
            "of the leading families under the body's axis rotations that are not exact images")
        run("harmonic", harmonic_starts(fam, span_s=span_s, rate_range_deg_s=settings.rate_range_deg_s),
            LOCAL_ITERATIONS, "of the leading families at harmonic rates and tilted axes")
        if local and before - float(inv.cost.min()) > FAR_AGAIN_NATS:
            run("local again", local_starts(fam, span_s=span_s), LOCAL_ITERATIONS,
                "of the new leading families at neighbouring rates and axes")
    if local:
        run("settle", local_starts(fam, span_s=span_s, factors=(), tilts_deg=()), LOCAL_ITERATIONS,
            "of the leading families from themselves")
    profile = None
    if ridge and bool(below_one_turn(float(torch.linalg.vector_norm(fam.omega0[0])), span_s=span_s)):
        tick = time.perf_counter()
        for attempt in range(2):  # a better point on the profile joins the solutions; the new top is profiled once
            profile = rate_profile(problem, q0=fam.q0[0], omega0=fam.omega0[0], log_rho=fam.log_rho[0],
                                   span_s=span_s, rate_range_deg_s=settings.rate_range_deg_s)
            if profile.gain_nats <= PROFILE_JOIN_NATS or attempt == 1:
                break
            best = int(torch.argmin(profile.cost))
            run("profile", (profile.q0[best:best + 1], profile.x[best:best + 1]), settings.final_iterations,
                "from the best point of the top family's rate profile")
            if not below_one_turn(float(torch.linalg.vector_norm(fam.omega0[0])), span_s=span_s):
                profile = None
                break
        seconds["rate profile"] = time.perf_counter() - tick
    fit = best_fit(inv, problem, rate_max_rad_s=rate_max)
    rates = torch.rad2deg(torch.linalg.vector_norm(fam.omega0, dim=-1))
    lo, hi = float(rates.min()), float(rates.max())
    on_ridge = False
    if profile is not None:
        top_p, on_ridge = ridge_rule(profile, weight=float(fam.weight[0]), p_right=float(fam.p_right[0]))
        fam = replace(fam, p_right=torch.cat([fam.p_right.new_tensor([top_p]), fam.p_right[1:]]))
        lo, hi = min(lo, profile.interval_deg_s[0]), max(hi, profile.interval_deg_s[1])
    said = verdict(fit, float(fam.p_right[0]), ridge=on_ridge)
    if said == "no_fit":
        fam = replace(fam, p_right=torch.zeros_like(fam.p_right))
    return Answer(inversion=inv, families=fam, fit=fit, verdict=said,
                  widened=widened, first_fit=first, ridge=on_ridge, rate_interval_deg_s=(lo, hi), profile=profile,
                  probe_rows=rows, probe_gain_nats=gains, seconds=seconds)
