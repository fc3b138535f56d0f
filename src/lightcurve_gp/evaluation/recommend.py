"""The one recommended estimator for the data at hand: what ``estimate`` runs when no ``--estimators`` is given.

The choice follows what was measured at 0.01–0.71 mag (docs/studies/realistic-photometry.md):

* **ω known, the shape known to the renderer** (every simulated scenario; a mesh or the box-wing): ``map`` — the
  surface-state filter, then the whole-arc MAP of the initial attitude and the surface state from the filter's result,
  7 prior starts and 8 surface starts (below 0.1 mag 8 more, all first solved with the noise raised to 0.1 mag, then
  refined; for a seed whose fit fails the misfit test 8 more with unequal lobe exponents and the 8 best of 256 prior
  attitudes × 8 lobe settings; 2 more from the best
  solution along its weakest attitude direction) with its Laplace covariance. On the held-out seeds it is within
  0.5–1.0× of the bound at every noise level, with the surface unknown (paper case and random truths; their NEES in
  docs/studies/realistic-photometry.md). The GP filter pays only at σ ≳ 0.3 mag and on its own training surface (the
  paper case at 0.71 mag: 87 % of the held-out seeds below 10°, as the MAP), which real data do not promise (random
  surfaces at 0.71 mag: 37 % against the MAP's 80 %), so the MAP stays the choice.
* **ω to be estimated** (``filter.estimate_omega``): the whole-arc MAP takes ω as known, so a filter that estimates
  it: ``gpukf`` (R + the GP's held-out excess variance) where a GP is given and σ ≥ :data:`GP_NOISE_MAG`, else
  ``joint_ukf`` (the renderer at the reference surface with an offset).
* **no renderer for the shape** (a GP alone): ``gpukf``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from lightcurve_gp.config.load import Config

__all__ = ["GP_NOISE_MAG", "Recommendation", "recommend_estimator"]

#: the noise (mag) from which the GP filter pays: its error along the truth on its training surface (0.05 mag) and
#: its held-out excess (0.27 mag) stop mattering against the noise
GP_NOISE_MAG = 0.3


@dataclass(frozen=True)
class Recommendation:
    """The recommended estimator's registry name and the one line that says why."""

    name: str
    reason: str

    def line(self) -> str:
        """``"recommended estimator: <name> — <reason>"``."""
        return f"recommended estimator: {self.name} — {self.reason}"


def recommend_estimator(cfg: Config, *, noise_std: float, have_model: bool, shape_known: bool = True
                        ) -> Recommendation:
    """The estimator for data of per-sample noise ``noise_std`` (mag; the median where it varies) under ``cfg``.

    Args:
        noise_std: the measurement noise's standard deviation (mag), finite and > 0.
        have_model: whether a trained GP is given.
        shape_known: whether the renderer knows the shape (``shape`` renders); ``False``: a GP alone.

    Raises:
        ValueError: a bad ``noise_std``, or no estimator fits (neither a renderable shape nor a GP).
    """
    if not (math.isfinite(noise_std) and noise_std > 0):
        raise ValueError(f"noise: {noise_std!r} mag must be finite and > 0")
    sigma = f"σ = {noise_std:.3g} mag"
    if not shape_known:
        if not have_model:
            raise ValueError("--model: without a shape the renderer knows, the only estimator is the GP filter, "
                             "which needs a trained model file")
        return Recommendation("gpukf", f"{sigma}, no renderer for the shape: the GP filter with its held-out "
                                       "excess variance in R")
    if cfg.filter.estimate_omega:
        if have_model and noise_std >= GP_NOISE_MAG:
            return Recommendation("gpukf", f"{sigma} ≥ {GP_NOISE_MAG:g}, ω estimated, a GP given: the GP filter "
                                           "(the whole-arc MAP takes ω as known)")
        return Recommendation("joint_ukf", f"{sigma}, ω estimated: the renderer's filter with an offset (the "
                                           "whole-arc MAP takes ω as known)")
    gp = " (the GP is not needed: it pays only at σ ≳ 0.3 mag on its training surface)" if have_model else ""
    return Recommendation("map", f"{sigma}, the renderer knows the shape ({cfg.shape.kind}), surface unknown, ω "
                                 f"known: the surface-state filter, then the whole-arc MAP of attitude and surface "
                                 f"from 16 starts (24 below 0.1 mag), 8 more and 8 of 2048 screened prior "
                                 f"attitudes and lobes where the fit fails the misfit test, 2 more along each "
                                 f"seed's weakest direction{gp}")
