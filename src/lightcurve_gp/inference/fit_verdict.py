"""Whether a least-squares fit is an answer: its χ² against the distribution the given noise allows.

With residuals whitened by the given 1σ (``r_k = (ỹ_k − m_k) / σ_k``) and ``p`` free parameters, the best fit's
``χ² = Σ r_k² = 2 c`` (``c = ½ Σ r²``, the solvers' cost) of a right model is ``χ²_ν``-distributed, ``ν = N − p``.
Its p-value (the probability of a χ² at least as large) below :data:`P_NO_FIT` says that no state of the model
explains the light curve within its noise (a wrong shape, a wrong noise level, or a search that never reached the
right basin): the fit is no answer. A fit that passes is ``"unique"`` when its leading answer holds at least
:data:`UNIQUE_WEIGHT` of the probability — the global inversion's top family its ``p_right`` (the probability of
being within the tolerances of "right", :mod:`.families`), the file estimator's leading mode its evidence weight —
and ``"ambiguous"`` otherwise (:func:`verdict`).

These constants are the one definition for every estimator that judges its fit this way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from scipy.stats import chi2 as chi2_distribution

__all__ = ["P_NO_FIT", "UNIQUE_WEIGHT", "INVERSION_PARAMETERS", "VERDICTS", "FitTest", "fit_test", "verdict", "judged"]

#: a fit whose χ² has a p-value below this is no answer
P_NO_FIT = 1e-3
#: a fit is unique when its leading answer holds at least this probability (module docstring)
UNIQUE_WEIGHT = 0.9
#: the global inversion's free parameters: attitude 3, body rate 3, ln ρ
INVERSION_PARAMETERS = 7
#: the verdicts of :func:`verdict`
VERDICTS = ("unique", "ambiguous", "no_fit")


@dataclass(frozen=True)
class FitTest:
    """A fit's χ² against ``χ²_ν``.

    Attributes:
        chi2: ``Σ r²`` of the whitened residuals; dof: ``ν = N − p``; p_value: ``P(χ²_ν ≥ chi2)``.
    """

    chi2: float
    dof: int
    p_value: float

    @property
    def fits(self) -> bool:
        """Whether the p-value is at least :data:`P_NO_FIT` (a NaN χ² does not fit)."""
        return self.p_value >= P_NO_FIT

    @property
    def chi2_per_dof(self) -> float:
        return self.chi2 / self.dof

    def as_dict(self) -> dict:
        return {"chi2": self.chi2, "dof": self.dof, "chi2_per_dof": self.chi2_per_dof, "p_value": self.p_value,
                "p_no_fit": P_NO_FIT, "fits": self.fits}


def fit_test(cost: float, *, samples: int, parameters: int = INVERSION_PARAMETERS) -> FitTest:
    """The fit test of a best cost ``c = ½ Σ r²`` (whitened residuals) over ``samples`` samples with ``parameters``
    free parameters: ``χ² = 2 c`` against ``χ²_ν``, ``ν = samples − parameters``.

    Raises:
        ValueError: no degree of freedom left (``samples <= parameters``).
    """
    dof = int(samples) - int(parameters)
    if dof < 1:
        raise ValueError(f"fit test: {samples} samples leave no degree of freedom for {parameters} parameters")
    value = 2.0 * float(cost)
    p = float(chi2_distribution.sf(value, dof)) if math.isfinite(value) else 0.0
    return FitTest(chi2=value, dof=dof, p_value=p)


def verdict(test: FitTest, top_weight: float, *, ridge: bool = False) -> str:
    """``"no_fit"`` when the fit fails its test, else ``"unique"`` when the heaviest family's weight (for the global
    inversion its probability of being right, ``Families.p_right``) is at least :data:`UNIQUE_WEIGHT` and it is on
    no ridge (a rate its profile does not fix), else ``"ambiguous"`` (module docstring; :func:`judged`)."""
    return judged(fits=test.fits, top_weight=top_weight, ridge=ridge)


def judged(*, fits: bool, top_weight: float, ridge: bool = False) -> str:
    """:func:`verdict`'s rule from whether the fit passed its test (e.g. a kept answer's verdict)."""
    if not fits:
        return "no_fit"
    return "unique" if top_weight >= UNIQUE_WEIGHT and not ridge else "ambiguous"
