"""The Cramér–Rao bound beside every RMSE: per seed of a scenario, with the unknowns of each estimator.

An estimator's RMSE is compared with the bound of the same problem (:mod:`lightcurve_gp.inference.crb`): the truth of
each seed, its noise variance, the filters' prior (``σ0`` of the seed, ``filter.p0_omega_deg_s``,
``filter.offset_prior_std``, the surface-state prior) and the unknowns the estimator has (:func:`estimator_bound`).
A filter, and a MAP that uses the samples up to each checkpoint, is causal: its bound at sample ``k`` is the
**filtering** bound from the samples ``≤ k``; the whole-arc MAP's is the **smoothing** bound of all samples. The
number reported is the RMS over the scoring window of each Euler angle's bound (yaw, pitch, roll; deg), the unit of
the RMSE. :class:`ScenarioBounds` computes each (unknowns, causal) pair once per scenario; for the config's truth
(every seed the same truth, the seeds differing by noise alone) once for one seed.
"""

from __future__ import annotations

from typing import Sequence

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import quat_normalize
from lightcurve_gp.config.load import Config
from lightcurve_gp.inference.crb import bound_for_truths
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import Scenario
from lightcurve_gp.simulation.truths import TruthDraw

__all__ = ["BOUND_UNKNOWNS", "SMOOTHING", "estimator_bound", "ScenarioBounds"]

#: the unknowns of each estimator's bound, beyond those the config adds (ω with ``filter.estimate_omega`` for the
#: estimators that estimate it; the offset for ``gpukf`` with ``filter.estimate_offset``); ``None``: no bound
BOUND_UNKNOWNS: dict[str, tuple[str, ...] | None] = {
    "gpukf": ("attitude",), "ukf": ("attitude",), "matched_ukf": ("attitude",),
    "joint_ukf": ("attitude", "offset"), "surface_ukf": ("attitude", "surface"),
    "surface_ukf_select": ("attitude", "surface"), "map_surface": ("attitude", "surface"),
    "map_offset": ("attitude", "offset"), "map": ("attitude", "surface"), "matched_map": ("attitude",),
    "no_update": None,
}
#: the estimators scored against the smoothing bound (every sample at once)
SMOOTHING = frozenset({"map", "matched_map"})
#: estimators whose rate follows ``filter.estimate_omega``
_RATE_FOLLOWS_CONFIG = frozenset({"gpukf", "ukf", "matched_ukf", "joint_ukf"})


def estimator_bound(name: str, cfg: Config) -> tuple[tuple[str, ...], bool] | None:
    """``(unknowns, causal)`` of estimator ``name``'s bound under ``cfg``, or ``None`` (the no-update baseline, a
    name without a bound)."""
    base = BOUND_UNKNOWNS.get(name)
    if base is None:
        return None
    unknowns = list(base)
    if name in _RATE_FOLLOWS_CONFIG and cfg.filter.estimate_omega:
        unknowns.insert(1, "omega")
    if name == "gpukf" and cfg.filter.estimate_offset:
        unknowns.append("offset")
    return tuple(unknowns), name not in SMOOTHING


class ScenarioBounds:
    """The bounds of one scenario's seeds, computed on first use per (unknowns, causal) and kept.

    Args:
        cfg: the config (geometry, time grid, the filters' prior); scene: the scenario's renderer; sc: the scenario.
    """

    def __init__(self, cfg: Config, scene: Scene, sc: Scenario) -> None:
        self.cfg, self.scene, self.sc = cfg, scene.to(dtype=torch.float64), sc
        self._cache: dict[tuple[tuple[str, ...], bool], Tensor] = {}
        shared = sc.rho_true is not None  # the config's truth: every seed the same truth
        rows = [0] if shared else list(range(len(sc.seeds)))
        f64 = lambda t: t[rows].to(dtype=torch.float64, device="cpu")  # noqa: E731
        q0, omega0 = f64(sc.q_true[:, 0]), f64(sc.omega_true[:, 0])
        if sc.geometry is not None:  # along a pass the bound propagates from the grid's start, the config's state
            q0 = quat_normalize(torch.tensor(cfg.scenario.q0, dtype=torch.float64)).expand(len(rows), 4)
            omega0 = torch.deg2rad(torch.tensor(cfg.scenario.omega0_deg_s, dtype=torch.float64)).expand(len(rows), 3)
        self._draw = TruthDraw([sc.seeds[i] for i in rows], q0, omega0, type(sc.surface)(*(f64(t) for t in sc.surface)),
                               f64(sc.error), f64(sc.sigma0))
        self._seeds = len(sc.seeds)

    def rms_deg(self, unknowns: Sequence[str], *, causal: bool) -> Tensor:
        """The RMS over ``evaluation.rmse_window_s`` of each Euler angle's bound ``(S, 3)`` (deg)."""
        key = (tuple(unknowns), bool(causal))
        if key not in self._cache:
            bound = bound_for_truths(self.cfg, self._draw, unknowns=key[0], with_prior=True,
                                     noise_var=self.sc.noise_var, scene=self.scene)
            rms = bound.euler_rms_deg(tuple(self.cfg.evaluation.rmse_window_s), causal=causal)
            self._cache[key] = rms.expand(self._seeds, 3) if rms.shape[0] == 1 else rms
        return self._cache[key]

    def for_estimator(self, name: str) -> Tensor | None:
        """The bound ``(S, 3)`` (deg) of estimator ``name`` (:func:`estimator_bound`), or ``None``."""
        spec = estimator_bound(name, self.cfg)
        return None if spec is None else self.rms_deg(spec[0], causal=spec[1])
