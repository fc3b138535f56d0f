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

The ambiguity images are today the shape's body rotations of :mod:`lightcurve_gp.photometry.symmetry` (the box-wing
has four: the identity and the 180° turns about the body x, y and z axes); :func:`ambiguity_images` is the one place
that chooses them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import quat_mul
from lightcurve_gp.filters.bank import BankResult
from lightcurve_gp.photometry.shapes import facets_from_config
from lightcurve_gp.photometry.symmetry import symmetry_quaternions

__all__ = ["FAMILY_RADIUS_DEG", "UNIQUE_WEIGHT", "IMAGES_SOURCE", "BankVerdict", "ambiguity_images",
           "bank_verdict"]

#: members whose last estimates lie within this angle of the best's (or of one of its images) are one family (deg)
FAMILY_RADIUS_DEG = 10.0
#: the answer is unique when the top family holds at least this share of the posterior weight
UNIQUE_WEIGHT = 0.9
#: what :func:`ambiguity_images` returns, in words
IMAGES_SOURCE = "the shape's symmetry rotations (lightcurve_gp.photometry.symmetry)"


@dataclass
class BankVerdict:
    """How peaked a bank's posterior is (module docstring).

    Attributes:
        effective_members: ``1 / Σ w_i²``.
        top_family_weight: the weight of the best member's family (``0 … 1``).
        top_family_members: how many members the family has.
        images: the ambiguity images used ``(K, 4)`` (scalar last, the identity first).
        verdict: ``"unique"`` or ``"ambiguous"``.
    """

    effective_members: float
    top_family_weight: float
    top_family_members: int
    images: Tensor
    verdict: str

    def as_dict(self) -> dict:
        """The verdict for ``summary.json``."""
        return {"verdict": self.verdict, "effective_members": self.effective_members,
                "top_family_weight": self.top_family_weight, "top_family_members": self.top_family_members,
                "family_radius_deg": FAMILY_RADIUS_DEG, "unique_weight": UNIQUE_WEIGHT,
                "ambiguity_images": {"source": IMAGES_SOURCE, "quaternions": self.images.tolist()}}

    def sentences(self, size: int) -> list[str]:
        """The verdict in words for a bank of ``size`` members: a line of numbers and, when ambiguous, a warning."""
        n = self.top_family_members
        family = (f"the top family ({n} member{'s' if n != 1 else ''} within {FAMILY_RADIUS_DEG:g} deg of the best "
                  f"estimate or of its {self.images.shape[0] - 1} symmetric attitudes) holds "
                  f"{100 * self.top_family_weight:.1f} % of the posterior weight")
        lines = [f"posterior: effective number of members {self.effective_members:.1f} of {size}; {family}"]
        if self.verdict == "unique":
            lines.append("verdict: unique (one attitude, up to the shape's symmetries, explains the light curve)")
        else:
            lines.append(f"warning: the answer is not unique: {100 * (1 - self.top_family_weight):.1f} % of the "
                         f"posterior weight lies on other attitudes, so the reported attitude may be far from the "
                         f"truth; try a longer light curve, a larger --bank-size, or --initial-attitude if one is "
                         f"known")
        return lines


def ambiguity_images(cfg) -> Tensor:
    """The attitudes' images ``q_R (K, 4)`` (float64, CPU, identity first) that give the same light curve as
    ``q`` under ``cfg``: ``q_R ⊗ q`` for the shape's symmetry rotations (module docstring)."""
    return symmetry_quaternions(facets_from_config(cfg, dtype=torch.float64, device="cpu"))


def _angle_deg(a: Tensor, b: Tensor) -> Tensor:
    """Rotation angle between unit quaternions ``a (..., 4)`` and ``b (..., 4)`` (deg; sign-blind)."""
    dot = (a * b).sum(-1).abs().clamp(max=1.0)
    return torch.rad2deg(2.0 * torch.acos(dot))


def bank_verdict(bank: BankResult, images: Tensor, *, radius_deg: float = FAMILY_RADIUS_DEG,
                 unique_weight: float = UNIQUE_WEIGHT) -> BankVerdict:
    """The verdict of ``bank`` with the ambiguity ``images (K, 4)`` (module docstring)."""
    w = bank.weights.detach().double().cpu()
    last = bank.bank_history.q_est[:, -1].detach().double().cpu()  # (N, 4)
    last = last / last.norm(dim=-1, keepdim=True)
    best = last[int(bank.order[0])]
    targets = quat_mul(images.to(best), best.expand_as(images))  # (K, 4)
    distance = _angle_deg(last.unsqueeze(1), targets.unsqueeze(0)).amin(1)  # (N,)
    family = distance <= radius_deg
    weight = float(w[family].sum())
    effective = float(1.0 / w.pow(2).sum()) if float(w.sum()) > 0 else math.nan
    return BankVerdict(effective_members=effective, top_family_weight=weight,
                       top_family_members=int(family.sum()), images=images.detach().double().cpu(),
                       verdict="unique" if weight >= unique_weight else "ambiguous")
