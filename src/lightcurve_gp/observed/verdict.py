"""The bank's verdict on an observed light curve: is the answer unique, or does the posterior spread over attitudes?

The global-start bank (:mod:`lightcurve_gp.filters.bank`) ranks its members by the likelihood of their innovations
and gives them posterior weights ``w_i`` (sum 1). Its best member is always reported, but a best member holding a
small weight is no answer: the light curve then fits many attitudes about as well. Three numbers say how peaked the
posterior is:

* the effective number of members ``1 / Σ w_i²`` (1 when one member holds all the weight, ``N`` for uniform
  weights);
* the top family: the members whose last estimate lies within :data:`FAMILY_RADIUS_DEG` of the best member's or of
  one of its ambiguity images ``q_R ⊗ q̂`` (attitudes that give the same light curve, which no method that sees only
  the light curve can tell apart, :func:`ambiguity_images`), and the weight they hold together;
* the verdict: ``"unique"`` when the top family holds at least :data:`UNIQUE_WEIGHT` of the weight, else
  ``"ambiguous"``.

The last estimate of a member is the bank's own record (``BankResult.bank_history``): the end of the light curve,
or with pruning the end of the first stretch every member ran (the pruned members hold no weight).

A bank too coarse cannot claim a unique answer: when few members start near the truth's basin, the posterior can
pile onto one member because no member started near the other answers. :func:`bank_coverage` measures how far a
random attitude lies from the nearest member's start (the 95th percentile over :data:`COVERAGE_PROBES` fixed random
attitudes) and compares it with the radius of a member's 99 % prior region, ``filter.p0_deg · √χ²₃(0.99)`` (33.7°
for the default 10°): the bank covers SO(3) when 95 % of attitudes lie inside some member's 99 % region. For the
Sobol' banks of :func:`~lightcurve_gp.filters.bank.bank_attitudes` the 95th percentile is 77.6° for 16 members,
39.2° for 128, 30.9° for 256, 19.0° for 1024 (the spacing falls as ``N^(-1/3)`` on the 3-D SO(3)), so with the
default ``p0_deg`` a bank of 256 or more covers it. A coarse bank is warned about and its would-be ``"unique"``
verdict is ``"inconclusive"``.

The ambiguity images are the file's exact ambiguity group (:func:`ambiguity_images`, derived by
:func:`lightcurve_gp.photometry.ambiguity.ambiguity_group` over the file's samples and geometry, never listed): the
images ``q_R ⊗ q ⊗ q_C`` of the shape's body symmetries ``q_R`` and the inertial 180° turns ``q_C`` of the
Sun–observer pair that reproduce the light curve to 1e-9 mag. With the spin known (``filter.estimate_omega: false``)
a body turn would turn the rate too and is no image; along a pass the moving Sun and observer break the inertial
turns. :func:`ambiguity_images` is the one place that chooses them, and the summary names them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from lightcurve_gp.attitude.sampling import random_attitudes
from lightcurve_gp.filters.bank import BankResult
from lightcurve_gp.passes.geometry import PassGeometry
from lightcurve_gp.photometry.ambiguity import AmbiguityGroup, config_ambiguity_group
from lightcurve_gp.photometry.render import Scene

__all__ = ["FAMILY_RADIUS_DEG", "UNIQUE_WEIGHT", "COVERAGE_PROBES", "BankCoverage", "BankVerdict", "ambiguity_images",
           "bank_coverage", "bank_verdict"]

#: members whose last estimates lie within this angle of the best's (or of one of its images) are one family (deg)
FAMILY_RADIUS_DEG = 10.0
#: the answer is unique when the top family holds at least this share of the posterior weight
UNIQUE_WEIGHT = 0.9

#: random attitudes (a fixed seed) a bank's coverage of SO(3) is measured against
COVERAGE_PROBES = 4096
COVERAGE_SEED = 39
#: share of random attitudes that must lie inside a member's prior region, and that region's probability
COVERAGE_SHARE = 0.95
#: χ²₃'s 99 % point (``scipy.stats.chi2.ppf(0.99, 3)``): a member's 99 % prior region has radius ``p0 · √`` of it
PRIOR_REGION_CHI2 = 11.344866730144373


@dataclass
class BankCoverage:
    """How well a bank's starts cover SO(3) (module docstring).

    Attributes:
        size: the number of members.
        nearest_deg: the 95th percentile over random attitudes of the angle to the nearest member's start (deg).
        reach_deg: the radius of a member's 99 % prior region, ``p0_deg · √χ²₃(0.99)`` (deg).
    """

    size: int
    nearest_deg: float
    reach_deg: float

    @property
    def adequate(self) -> bool:
        """Whether 95 % of attitudes lie inside some member's 99 % prior region."""
        return self.nearest_deg <= self.reach_deg

    @property
    def suggested_size(self) -> int:
        """A bank size that would cover SO(3): the spacing falls as ``N^(-1/3)``, rounded up to a power of two."""
        needed = self.size * (self.nearest_deg / self.reach_deg) ** 3
        return max(self.size, 1 << max(0, math.ceil(math.log2(needed))))

    def as_dict(self) -> dict:
        return {"size": self.size, "nearest_member_deg_95": self.nearest_deg, "prior_reach_deg_99": self.reach_deg,
                "adequate": self.adequate}

    def warning(self) -> str:
        """The warning of a coarse bank, in words."""
        return (f"warning: a bank of {self.size} filters is too coarse to claim a unique answer: 5 % of attitudes "
                f"lie more than {self.nearest_deg:.1f} deg from every member's start, beyond the {self.reach_deg:.1f} "
                f"deg a member's prior reaches (filter.p0_deg); use --bank-size {self.suggested_size} or more")


def bank_coverage(q0: Tensor, *, p0_deg: float) -> BankCoverage:
    """The coverage of SO(3) by a bank whose members start at ``q0 (N, 4)``, each with a prior of ``p0_deg`` per
    axis (module docstring)."""
    probes = random_attitudes(COVERAGE_PROBES, COVERAGE_SEED, dtype=torch.float64)
    starts = q0.detach().double().cpu()
    starts = starts / starts.norm(dim=-1, keepdim=True)
    nearest = torch.rad2deg(2.0 * torch.acos((probes @ starts.T).abs().amax(1).clamp(max=1.0)))
    return BankCoverage(size=int(starts.shape[0]), nearest_deg=float(torch.quantile(nearest, COVERAGE_SHARE)),
                        reach_deg=p0_deg * math.sqrt(PRIOR_REGION_CHI2))


@dataclass
class BankVerdict:
    """How peaked a bank's posterior is (module docstring).

    Attributes:
        effective_members: ``1 / Σ w_i²``.
        top_family_weight: the weight of the best member's family (``0 … 1``).
        top_family_members: how many members the family has.
        group: the ambiguity images used (the identity first; :func:`ambiguity_images`).
        verdict: ``"unique"``, ``"ambiguous"``, or ``"inconclusive"`` (the top family holds the weight a unique
            answer needs, but the bank is too coarse to say so: ``coverage``).
        coverage: the bank's coverage of SO(3) (:func:`bank_coverage`), ``None`` when not measured.
    """

    effective_members: float
    top_family_weight: float
    top_family_members: int
    group: AmbiguityGroup
    verdict: str
    coverage: BankCoverage | None = None

    def as_dict(self) -> dict:
        """The verdict for ``summary.json``."""
        return {"verdict": self.verdict, "effective_members": self.effective_members,
                "top_family_weight": self.top_family_weight, "top_family_members": self.top_family_members,
                "family_radius_deg": FAMILY_RADIUS_DEG, "unique_weight": UNIQUE_WEIGHT,
                "ambiguity_images": self.group.as_dict(),
                "coverage": None if self.coverage is None else self.coverage.as_dict()}

    def sentences(self, size: int) -> list[str]:
        """The verdict in words for a bank of ``size`` members: a line of numbers and, when ambiguous, a warning."""
        n = self.top_family_members
        family = (f"the top family ({n} member{'s' if n != 1 else ''} within {FAMILY_RADIUS_DEG:g} deg of the best "
                  f"estimate or of its {len(self.group) - 1} exact images) holds "
                  f"{100 * self.top_family_weight:.1f} % of the posterior weight")
        lines = [f"posterior: effective number of members {self.effective_members:.1f} of {size}; {family}"]
        if self.coverage is not None and not self.coverage.adequate:
            lines.append(self.coverage.warning())
        if self.verdict == "unique":
            lines.append("verdict: unique (one attitude, up to the exact ambiguities, explains the light curve)")
        elif self.verdict == "inconclusive":
            lines.append("verdict: inconclusive (the top family holds the weight of a unique answer, but a bank this "
                         "coarse may have started no member near the other answers)")
        else:
            lines.append(f"warning: the answer is not unique: {100 * (1 - self.top_family_weight):.1f} % of the "
                         f"posterior weight lies on other attitudes, so the reported attitude may be far from the "
                         f"truth; try a longer light curve, a larger --bank-size, or --initial-attitude if one is "
                         f"known")
        return lines


def ambiguity_images(cfg, *, samples: int, geometry: PassGeometry | None = None) -> AmbiguityGroup:
    """The exact ambiguity group of a file of ``samples`` samples under ``cfg`` (module docstring): float64, CPU,
    the identity first; ``geometry`` the file's per-sample geometry (``None``: the config's fixed Sun and observer).

    The probe trajectories are sampled once per ``scenario.dt_s`` step, one step per file sample: whether an image
    reproduces a sample's magnitude depends on that sample's geometry, not on its time stamp."""
    scene = Scene.from_config(cfg, dtype=torch.float64, device="cpu")
    if geometry is not None:
        scene = scene.with_geometry(geometry.sun.double().cpu(), geometry.observer.double().cpu(),
                                    torch.as_tensor(geometry.range_m, dtype=torch.float64))
    times = torch.arange(samples, dtype=torch.float64) * cfg.scenario.dt_s
    return config_ambiguity_group(cfg, scene=scene, times_s=times)


def _angle_deg(a: Tensor, b: Tensor) -> Tensor:
    """Rotation angle between unit quaternions ``a (..., 4)`` and ``b (..., 4)`` (deg; sign-blind)."""
    dot = (a * b).sum(-1).abs().clamp(max=1.0)
    return torch.rad2deg(2.0 * torch.acos(dot))


def bank_verdict(bank: BankResult, group: AmbiguityGroup, *, radius_deg: float = FAMILY_RADIUS_DEG,
                 unique_weight: float = UNIQUE_WEIGHT, p0_deg: float | None = None) -> BankVerdict:
    """The verdict of ``bank`` with the file's ambiguity ``group`` (module docstring); with ``p0_deg`` (the members'
    prior, ``filter.p0_deg``) the bank's coverage is measured and a coarse bank's "unique" is "inconclusive"."""
    w = bank.weights.detach().double().cpu()
    last = bank.bank_history.q_est[:, -1].detach().double().cpu()  # (N, 4)
    last = last / last.norm(dim=-1, keepdim=True)
    best = last[int(bank.order[0])]
    group = group.to(device="cpu", dtype=torch.float64)
    targets = group.attitudes(best)  # (K, 4)
    distance = _angle_deg(last.unsqueeze(1), targets.unsqueeze(0)).amin(1)  # (N,)
    family = distance <= radius_deg
    weight = float(w[family].sum())
    effective = float(1.0 / w.pow(2).sum()) if float(w.sum()) > 0 else math.nan
    coverage = None if p0_deg is None else bank_coverage(bank.q0, p0_deg=p0_deg)
    verdict = "unique" if weight >= unique_weight else "ambiguous"
    if verdict == "unique" and coverage is not None and not coverage.adequate:
        verdict = "inconclusive"
    return BankVerdict(effective_members=effective, top_family_weight=weight,
                       top_family_members=int(family.sum()), group=group, verdict=verdict, coverage=coverage)
