"""Run estimators of the registry side by side on one scenario, all seeds batched in each, and score them.

    sc = simulate_scenario(cfg, seeds=range(20), rho_true=0.7)            # or simulate_truths(cfg, draw_truths(...))
    result = run_estimators(cfg, sc, estimators=("gpukf", "ukf", "no_update"), model=gp)
    result.results["gpukf"].rmse_deg                                      # (20, 3), deg

Estimators: :data:`lightcurve_gp.evaluation.registry.ESTIMATORS`; scores:
:func:`lightcurve_gp.evaluation.scoring.score` over ``evaluation.rmse_window_s``, "modulo symmetry" against the
scenario's exact ambiguity group derived by :func:`scenario_ambiguity_group` (kept in
:attr:`ScenarioResult.group`). Tables are built from the result
by :mod:`lightcurve_gp.evaluation.reporting` (the estimate command and the sweeps) and
:mod:`lightcurve_gp.evaluation.suite_summary` (the generalisation suite).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Sequence

import torch

from lightcurve_gp.attitude.metrics import chi2_band
from lightcurve_gp.config.load import Config
from lightcurve_gp.evaluation.bounds import ScenarioBounds
from lightcurve_gp.evaluation.registry import DEFAULT_ESTIMATORS, ESTIMATORS, RunContext
from lightcurve_gp.evaluation.scoring import EstimatorResult, score
from lightcurve_gp.observation.base import ObservationModel
from lightcurve_gp.photometry.ambiguity import AmbiguityGroup, config_ambiguity_group
from lightcurve_gp.photometry.render import Scene
from lightcurve_gp.simulation.scenario import Scenario

__all__ = ["ScenarioResult", "check_estimators", "run_estimators", "scenario_ambiguity_group"]


@dataclass
class ScenarioResult:
    """Estimators on one scenario: ``steps`` filter steps of ``len(scenario.seeds)`` filters each."""

    scenario: Scenario
    window: tuple[float, float]
    results: dict[str, EstimatorResult] = field(default_factory=dict)
    #: the images the scores "modulo symmetry" were taken against (:func:`scenario_ambiguity_group`)
    group: AmbiguityGroup | None = None

    @property
    def steps(self) -> int:
        return self.scenario.steps

    def nees_band(self) -> tuple[float, float]:
        """95 % band of the seed-mean of time-averaged NEES (treats each seed's average as one χ²(3) draw)."""
        return chi2_band(3, len(self.scenario.seeds))


def scenario_ambiguity_group(cfg: Config, scenario: Scenario, scene: Scene | None = None) -> AmbiguityGroup:
    """The exact ambiguity group of a simulated scenario (:func:`~lightcurve_gp.photometry.ambiguity.ambiguity_group`):
    the facet model's body symmetries (:func:`~lightcurve_gp.photometry.symmetry.symmetry_rotations`) × the inertial
    180° turns of the first sample's Sun–observer pair, each kept when it reproduces probe light curves over the
    scenario's sample times and geometry (``scene``, default ``Scene.from_config(cfg)``: fixed, or per sample along
    the pass) to 1e-9 mag. The rate is known unless ``filter.estimate_omega`` (then a body turn turns it too). Derived
    in float64 on the CPU whatever the run's dtype and device (a float32 render cannot show 1e-9 mag)."""
    return config_ambiguity_group(cfg, scene=scene or Scene.from_config(cfg), times_s=scenario.times)


def check_estimators(cfg: Config, estimators: Sequence[str], model: ObservationModel | None, *,
                     along_pass: bool = False) -> None:
    """Refuse, before anything runs, an unknown name, a GP estimator without a GP or with one trained on another
    target, and an estimator that cannot run with ``filter.estimate_omega`` or along a pass; a ``ValueError``."""
    unknown = [e for e in estimators if e not in ESTIMATORS]
    if unknown:
        raise ValueError(f"unknown estimator {unknown[0]!r}; choose from {', '.join(ESTIMATORS)}")
    chosen = [ESTIMATORS[e] for e in estimators]
    needs_model = [e.name for e in chosen if e.needs_model]
    if needs_model and model is None:
        raise ValueError(f"the {needs_model[0]} estimator needs a trained GP model (train one with python -m "
                         f"lightcurve_gp.train)")
    trained_on = getattr(model, "config", {}).get("target", "magnitude") if model is not None else None
    if needs_model and trained_on != cfg.model.target:
        raise ValueError(f"model.target: the GP was trained on target {trained_on!r}, the config says "
                         f"{cfg.model.target!r}; train a model with this config")
    omega_known = [e.name for e in chosen if not e.estimates_omega]
    if omega_known and cfg.filter.estimate_omega:
        raise ValueError(f"{omega_known[0]}: this estimator takes ω as known; run it with filter.estimate_omega "
                         f"false")
    fixed = [e.name for e in chosen if not e.along_pass]
    if fixed and along_pass:
        raise ValueError(f"{fixed[0]}: this estimator runs under a fixed geometry only, not along a pass "
                         f"(geometry.kind: orbit)")


def run_estimators(cfg: Config, scenario: Scenario, *, estimators: Sequence[str] = DEFAULT_ESTIMATORS,
                   model: ObservationModel | None = None, scene: Scene | None = None,
                   map_every_s: float = 50.0, bounds: bool = True) -> ScenarioResult:
    """Run the chosen estimators on every seed of ``scenario`` and score them over ``evaluation.rmse_window_s``.

    Args:
        cfg: validated config; ``filter`` gives the USQUE tuning, ``data.t_span_past`` the ``m_past`` recursion.
        scenario: from :func:`~lightcurve_gp.simulation.scenario.simulate_scenario` or
            :func:`~lightcurve_gp.simulation.scenario.simulate_truths`.
        estimators: names of :data:`~lightcurve_gp.evaluation.registry.ESTIMATORS`.
        model: the trained GP observation model (needed by ``gpukf``).
        scene: the renderer of the scenario (default ``Scene.from_config(cfg)``: fixed, or per sample along the
            pass).
        map_every_s: checkpoint spacing of the checkpoint MAP estimators inside the window (s).
        bounds: put each estimator's Cramér–Rao bound beside its scores (``crb_deg``,
            :mod:`lightcurve_gp.evaluation.bounds`; computed once per scenario and set of unknowns, not timed).
    """
    check_estimators(cfg, estimators, model, along_pass=scenario.geometry is not None)
    scene = (scene or Scene.from_config(cfg)).to(device=torch.device(cfg.device), dtype=cfg.torch_dtype)
    context = RunContext(cfg, scenario.problem(), scene, model, map_every_s)
    window = tuple(cfg.evaluation.rmse_window_s)
    group = scenario_ambiguity_group(cfg, scenario, scene)
    grp = (float(cfg.filter.grp_a), float(cfg.filter.grp_f))
    out = ScenarioResult(scenario, window, group=group)
    crb = ScenarioBounds(cfg, scene, scenario) if bounds else None
    for name in estimators:
        start = time.perf_counter()
        estimate = ESTIMATORS[name].run(context)
        out.results[name] = score(scenario, estimate, window=window, group=group, grp=grp,
                                  seconds=time.perf_counter() - start)
        if crb is not None:
            out.results[name].crb_deg = crb.for_estimator(name)
    return out
