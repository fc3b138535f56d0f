"""Surface-marginal GP: the light curve's mean over surfaces and its spread over surfaces (``model.target:
surface_normalised``).

Trained on surface-normalised magnitudes ``y = m + 2.5 log10(ρ (1 − F0) / (ρ0 (1 − F0,0)))`` of attitudes rendered
with K random surfaces each (:mod:`lightcurve_gp.training.surfaces`), it predicts

* mean: an inducing-point GP (:class:`~.sparse_gp.SparseGP`) on each training attitude's median over its K
  surfaces — a diffuse surface's normalised curve is the reference curve, which a minority of glinting surfaces
  does not move (the filter's offset state absorbs any constant part);
* variance: that GP's latent variance plus ``s²(q) = exp(g(q))``, where ``g`` is a second SGPR on the
  bias-corrected ``log s²`` of each training attitude's mean square deviation from the median
  (:func:`attitude_spread`), with its noise the sampling variance
  ``ψ'((K − 1)/2)`` of a log sample variance. So the filter's ``Pyy`` covers how far an unknown surface's specular
  part can move the magnitude at that attitude, where it can (glint geometries), and not where it cannot.

The spread model uses the mean GP's input map and lengthscale; its signal variance is the spread of its targets
less their sampling variance.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import torch
from torch import Tensor

from lightcurve_gp.config.hashing import config_to_dict
from lightcurve_gp.observation.base import ObservationModule, Prediction, Variance
from lightcurve_gp.observation.inputs import InputMap
from lightcurve_gp.observation.sparse_gp import SparseGP

__all__ = ["SurfaceMarginalGP", "spread_model_config", "attitude_spread", "SPREAD_FLOOR"]

#: smallest spread the spread model learns (mag²): 0.01 mag, far below any measurement noise of interest (R = 0.5
#: mag² in the paper), so that the log spread of diffuse attitudes (~1e-12) does not stretch the model's range
SPREAD_FLOOR = 1e-4


def attitude_spread(q: Tensor, y: Tensor, per_attitude: int, *,
                    floor: float = SPREAD_FLOOR) -> tuple[Tensor, Tensor, Tensor, float]:
    """Centre and spread over surfaces of surface-major targets ``y (K·A,)`` at ``q (K·A, 4)``.

    The centre is the median over an attitude's K surfaces: the diffuse curve wherever fewer than half of them
    glint, which a glint's large brightening does not pull. The spread is the mean square deviation from it,
    ``s² = Σ (y_k − ỹ)² / (K − 1)`` (floored at ``floor``), what the filter must add to its variance when it
    predicts the centre for an unknown surface.

    Returns:
        ``q_a (A, 4)``; ``centre (A,)``; ``log_s2 (A,)`` corrected by ``−(ψ(ν/2) − log(ν/2))``, ``ν = K − 1``: the
        mean of ``log(χ²_ν / ν)``, so that it is unbiased for Gaussian spreads (for which the median is near the mean);
        and ``ψ'(ν/2)``, the variance of that estimate there (Bartlett & Kendall 1946).
    """
    k = per_attitude
    if y.shape[0] % k:
        raise ValueError(f"{y.shape[0]} points are not {k} surfaces per attitude")
    qk = q.reshape(k, -1, 4)
    if not torch.equal(qk, qk[:1].expand_as(qk)):
        raise ValueError("points are not surface-major: the attitudes of the K blocks differ")
    yk = y.reshape(k, -1)
    centre = yk.median(0).values if k % 2 else yk.sort(0).values[k // 2 - 1:k // 2 + 1].mean(0)
    s2 = ((yk - centre) ** 2).sum(0).div(k - 1).clamp_min(floor)
    half_nu = torch.tensor((k - 1) / 2.0, dtype=torch.float64)
    bias = float(torch.special.digamma(half_nu) - half_nu.log())
    return qk[0], centre, s2.log() - bias, float(torch.special.polygamma(1, half_nu))


def spread_model_config(cfg: Any, log_s2: Tensor, sampling_var: float, num_inducing: int) -> Any:
    """The :class:`~lightcurve_gp.config.load.ModelConfig` of the spread SGPR on targets ``log_s2 (A,)``: the mean's
    inputs and ``θ2``, ``θ1 = max(var(log_s2) − ψ', ψ'/10)``, noise ``√ψ'``, no fit, ``num_inducing`` points."""
    theta1 = max(float(log_s2.var()) - sampling_var, 0.1 * sampling_var)
    return dataclasses.replace(cfg, theta1=theta1, noise_std=sampling_var**0.5, fit_hyperparameters=False,
                               target="magnitude",
                               sparse=dataclasses.replace(cfg.sparse, num_inducing=num_inducing, iterations=0,
                                                          optimize_inducing=False))


class SurfaceMarginalGP(ObservationModule):
    """Mean GP + spread GP (module docstring). ``mean_gp`` and ``spread_gp`` are :class:`SparseGP`\\ s."""

    kind = "surface_marginal"

    def __init__(self, mean_gp: SparseGP, spread_gp: SparseGP, *, config: dict | None = None):
        super().__init__()
        self.mean_gp = mean_gp
        self.spread_gp = spread_gp
        self.config = dict(config or {})

    @property
    def inputs(self) -> InputMap:
        return self.mean_gp.inputs

    @classmethod
    def from_data(cls, q: Tensor, m_past: Tensor, y: Tensor, cfg: Any, *, per_attitude: int,
                  spread_inducing: int, seed: int = 0, device: torch.device | str | None = None,
                  progress: bool = False) -> SurfaceMarginalGP:
        """Fit both GPs to surface-major targets ``y (K·A,)`` at ``q (K·A, 4)`` (``m_past (K·A,)``; with
        attitude-matrix inputs it is not used).

        ``cfg`` is the ``model`` section (kind ``sparse``); ``per_attitude`` is K, ``spread_inducing`` the spread
        model's inducing points.
        """
        q_a, centre, log_s2, sampling_var = attitude_spread(q, y, per_attitude)
        m_a = m_past.reshape(per_attitude, -1)[0]
        mean_gp = SparseGP.from_data(q_a, m_a, centre, cfg, seed=seed, device=device, progress=progress)
        spread_cfg = spread_model_config(cfg, log_s2, sampling_var, spread_inducing)
        spread_gp = SparseGP.from_data(q_a, m_a, log_s2, spread_cfg, seed=seed, device=device)
        return cls(mean_gp, spread_gp, config=config_to_dict(cfg))

    def spread(self, q: Tensor, m_past: Tensor) -> Tensor:
        """``s²(q) (...)`` (mag²): the predicted variance of the normalised magnitude over surfaces."""
        return self.spread_gp(q=q, m_past=m_past, variance="none")[0].exp()

    def _predict(self, q: Tensor, m_past: Tensor, variance: Variance) -> Prediction:
        mean, var = self.mean_gp(q=q, m_past=m_past, variance=variance)
        if variance == "none":
            return mean, None
        return mean, var + self.spread(q, m_past).to(var)

    def file_state(self) -> dict[str, Any]:
        """Both GPs' inputs, configs and states (plain values, see :mod:`.serialization`)."""
        return {part: {"inputs": gp.inputs.file_state(), "config": dict(gp.config), "state": gp.file_state()}
                for part, gp in (("mean", self.mean_gp), ("spread", self.spread_gp))}

    @classmethod
    def from_file_state(cls, inputs: InputMap, state: dict[str, Any], config: dict) -> SurfaceMarginalGP:
        gps = {part: SparseGP.from_file_state(InputMap.from_file_state(s["inputs"]), s["state"], s["config"])
               for part, s in state.items()}
        return cls(gps["mean"], gps["spread"], config=config)
