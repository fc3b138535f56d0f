"""What the exact and the inducing-point GP share: training-data preparation, hyperparameter buffers, the chunked
prediction loop and the plain-tensor file state (paper sections 2.4 and 3.1–3.2).

Both GPs use the kernel of :mod:`.kernels` with likelihood noise ``σ²`` and a constant mean ``μ = mean(y)`` (outputs
centred); their hyperparameters start at the paper's ``(θ1, θ2, σ)`` and are fitted by :mod:`.fitting`. A subclass
holds only its prediction cache and implements :meth:`CachedGP._predict_sets`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch import Tensor

from lightcurve_gp.observation.base import ObservationModule, Prediction, Variance
from lightcurve_gp.observation.fitting import hyper_start
from lightcurve_gp.observation.inputs import InputMap
from lightcurve_gp.observation.kernels import scaled

__all__ = ["CachedGP", "GPTrainingSet", "cpu64"]


def cpu64(t: Tensor) -> Tensor:
    """A detached float64 CPU copy (what model files store)."""
    return t.detach().to("cpu", torch.float64).clone()


@dataclass
class GPTrainingSet:
    """Checked float64 training data mapped to GP inputs, and the hyperparameters to start from.

    Attributes:
        inputs: the input map, fitted to the data (standardisation when configured).
        x: mapped inputs ``(N, d)``; r: centred outputs ``y − μ`` ``(N,)`` (mag); y_mean: ``μ`` (mag).
        outputscale, lengthscale, noise: start ``θ1``, ``ℓ (d,)``, ``σ²`` (paper values of the config).
    """

    inputs: InputMap
    x: Tensor
    r: Tensor
    y_mean: Tensor
    outputscale: float
    lengthscale: Tensor
    noise: float

    @classmethod
    def prepare(cls, q: Tensor, m_past: Tensor, y: Tensor, cfg: Any,
                device: torch.device | str | None) -> GPTrainingSet:
        """Check ``q (N, 4)``, ``m_past (N,)``, ``y (N,)``, move them to float64 on ``device`` (default: that of
        ``q``) and map them with ``cfg.inputs`` (standardised when ``cfg.standardize_inputs``)."""
        device = torch.device(device) if device is not None else q.device
        f64 = {"dtype": torch.float64, "device": device}
        q, m_past, y = q.to(**f64), m_past.to(**f64), y.to(**f64)
        _check_training(q, m_past, y)
        inputs = InputMap(cfg.inputs, cfg.standardize_inputs).to(device)
        x = inputs.fit(q, m_past)
        y_mean = y.mean()
        outputscale, lengthscale, noise = hyper_start(cfg, x.shape[-1])
        return cls(inputs, x, y - y_mean, y_mean, outputscale, lengthscale.to(device), noise)


def _check_training(q: Tensor, m_past: Tensor, y: Tensor) -> None:
    if q.ndim != 2 or q.shape[1] != 4 or m_past.shape != (q.shape[0],) or y.shape != (q.shape[0],):
        raise ValueError(f"training data must be q (N, 4), m_past (N,), y (N,); got {tuple(q.shape)}, "
                         f"{tuple(m_past.shape)}, {tuple(y.shape)}")
    if q.shape[0] < 2:
        raise ValueError("training data needs at least 2 points")
    for name, t in (("q", q), ("m_past", m_past), ("y", y)):
        if not bool(torch.isfinite(t).all()):
            raise ValueError(f"training {name} contains non-finite values")


class CachedGP(ObservationModule):
    """A GP predicted in plain torch from a cache; buffers ``y_mean``, ``outputscale`` (``θ1``), ``lengthscale``
    (``ℓ (d,)``) and ``noise`` (``σ²``), all float64, move with ``.to()``.

    Subclasses set :attr:`kind`, :attr:`shares_sets`, implement :meth:`_reference_count`, :meth:`_predict_sets`,
    :meth:`_cache_state` and ``from_file_state``.
    """

    kind: str = ""
    #: largest kernel block ``(points × references)`` computed at once by a prediction (8 MB in float64)
    chunk_values: int = 1 << 20
    #: whether the points along the last batch dimension are passed to :meth:`_predict_sets` as one set
    shares_sets: bool = False

    def __init__(self, inputs: InputMap, *, y_mean: float | Tensor, outputscale: float | Tensor, lengthscale: Tensor,
                 noise: float | Tensor, config: dict | None, device: torch.device):
        super().__init__()
        self.inputs = inputs
        self.config = dict(config or {})
        f64 = {"dtype": torch.float64, "device": device}
        self.register_buffer("y_mean", torch.as_tensor(y_mean, **f64))
        self.register_buffer("outputscale", torch.as_tensor(outputscale, **f64))
        self.register_buffer("lengthscale", lengthscale.to(**f64))
        self.register_buffer("noise", torch.as_tensor(noise, **f64))

    @property
    def theta1(self) -> float:
        return float(self.outputscale)

    @property
    def theta2(self) -> Tensor:
        """Per-dimension ``θ2 = 2ℓ²`` ``(d,)``."""
        return 2.0 * self.lengthscale**2

    @property
    def noise_std(self) -> float:
        return float(self.noise) ** 0.5

    def _reference_count(self) -> int:
        """Number of cached inputs each test point is compared with (training or inducing points)."""
        raise NotImplementedError

    def _predict_sets(self, xs_sets: Tensor, variance: Variance) -> Prediction:
        """Mean ``(C·S,)`` and variance ``(C·S,)`` (or ``None``) of scaled test inputs ``(C, S, d)``."""
        raise NotImplementedError

    def _predict(self, q: Tensor, m_past: Tensor, variance: Variance) -> Prediction:
        """Map and scale the inputs, then predict in chunks of at most :attr:`chunk_values` kernel values (a chunk's
        kernel block stays in the CPU cache between its passes)."""
        batch = q.shape[:-1]
        dt, d = self.outputscale.dtype, self.inputs.dim
        set_size = q.shape[-2] if self.shares_sets and q.ndim >= 3 else 1
        x = self.inputs(q.to(dt), m_past.to(dt)).reshape(-1, set_size, d)
        xs_sets = scaled(x, self.lengthscale)
        sets_per_chunk = max(1, self.chunk_values // (set_size * self._reference_count()))
        means, variances = [], []
        for start in range(0, xs_sets.shape[0], sets_per_chunk):
            mean, var = self._predict_sets(xs_sets[start:start + sets_per_chunk], variance)
            means.append(mean)
            variances.append(var)
        mean = (means[0] if len(means) == 1 else torch.cat(means)).reshape(batch)
        if variance == "none":
            return mean, None
        return mean, (variances[0] if len(variances) == 1 else torch.cat(variances)).reshape(batch)

    def _cache_state(self) -> dict[str, Any]:
        """The subclass's prediction cache as plain tensors and python values."""
        raise NotImplementedError

    def file_state(self) -> dict[str, Any]:
        """Plain tensors/python values for :func:`lightcurve_gp.observation.serialization.save_model`."""
        return {"y_mean": float(self.y_mean), "outputscale": float(self.outputscale),
                "lengthscale": cpu64(self.lengthscale), "noise": float(self.noise), **self._cache_state()}

    @staticmethod
    def _hyperparameters(state: dict[str, Any]) -> dict[str, Any]:
        """The constructor keywords of a file state's hyperparameters."""
        return {k: state[k] for k in ("y_mean", "outputscale", "lengthscale", "noise")}
