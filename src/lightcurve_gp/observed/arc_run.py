"""The recommended estimator on observed light curves: the surface-state filter, then the whole-arc MAP.

:func:`estimate_arc` takes :class:`~lightcurve_gp.observations.Observations` (one or several files of one object,
any sample times) with a start (an attitude at the first sample and its 1σ) and the body rate, and runs what
``map`` runs on a simulation (:func:`lightcurve_gp.evaluation.registry.map_solution`: the shape known, the
surface unknown, ω known, each sample with its own 1σ and geometry, the unknown zero point of every relative light
curve profiled out). The answer is a smoother's: the attitude at every sample with the whole arc's covariance
``A(Δ_k) Σ A(Δ_k)ᵀ`` (:func:`~lightcurve_gp.evaluation.registry.arc_estimate`), the surface, the zero points and the
fitted light curve.

The fit is judged as any least-squares fit: its ``χ² = Σ r_k²`` over the ``n`` samples it uses (the first sets the
surface prior) against ``χ²_ν``, ``ν = n − 7 − C_rel`` (attitude 3, surface state 4, one offset per relative
curve), with the inversion's rule and words (:mod:`lightcurve_gp.inference.fit_verdict`): ``"no_fit"`` when the
p-value is below ``P_NO_FIT`` (1e-3: the shape, the spin or the start is wrong, and the answer is not one),
``"ambiguous"`` when it fits but the best mode carries less than ``UNIQUE_WEIGHT`` (0.9) of the evidence, else
``"unique"``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np
import torch
from astropy.table import Table
from astropy.time import Time, TimeDelta
from torch import Tensor

from lightcurve_gp.attitude.rotations import quat_to_euler321
from lightcurve_gp.config.load import Config
from lightcurve_gp.evaluation.registry import arc_estimate, map_solution
from lightcurve_gp.evaluation.scoring import Estimate
from lightcurve_gp.inference.arc import ArcSolution
from lightcurve_gp.inference.arc_search import arc_setup
from lightcurve_gp.inference.fit_verdict import P_NO_FIT, FitTest, fit_test, verdict
from lightcurve_gp.inference.forward import rate_sensitivity
from lightcurve_gp.observation.surface_state import surface_from_state
from lightcurve_gp.observations.observations import Observations
from lightcurve_gp.observations.problem import Problem, problem_from_observations
from lightcurve_gp.observed.run import euler321_jacobian
from lightcurve_gp.observed.table_units import ISO_UTC, QUATERNION, set_units
from lightcurve_gp.photometry.render import Scene

__all__ = ["ArcRun", "STATE_SIZE", "estimate_arc", "check_observations", "file_scene", "arc_history_table",
           "estimate_table", "arc_summary", "arc_report"]

#: the 3-2-1 angles of the tables
ANGLES = ("yaw", "pitch", "roll")
#: the unknowns of the whole-arc MAP with the surface unknown (attitude 3, surface state 4)
STATE_SIZE = 7


@dataclass
class ArcRun:
    """The recommended estimator's answer on observations (module docstring).

    Attributes:
        problem: what it ran on (one object, ``S = 1``).
        solution: the whole-arc MAP (its modes, covariance, cost).
        estimate: the attitude at every sample ``(1, N, 4)`` and its covariance ``(1, N, 3, 3)`` (rad²).
        fitted: the fitted magnitudes ``(N,)`` (the relative curves' offsets included).
        offsets: the relative light curves' fitted magnitude offsets ``(C_rel,)`` (mag), or ``None``.
        used: the samples the fit uses ``(N,)`` (bool).
        fit: the fit's χ² against ``χ²_ν`` (:func:`lightcurve_gp.inference.fit_verdict.fit_test`).
        seconds: the run's wall time.
    """

    problem: Problem
    solution: ArcSolution
    estimate: Estimate
    fitted: Tensor
    offsets: Tensor | None
    used: Tensor
    fit: FitTest
    seconds: float

    @property
    def obs(self) -> Observations:
        return self.problem.obs

    @property
    def chi2(self) -> float:
        return self.fit.chi2

    @property
    def dof(self) -> int:
        return self.fit.dof

    @property
    def p_value(self) -> float:
        return self.fit.p_value

    @property
    def verdict(self) -> str:
        """``"unique"``, ``"ambiguous"`` or ``"no_fit"`` (:func:`lightcurve_gp.inference.fit_verdict.verdict`, the best
        mode's evidence weight as the heaviest family's)."""
        return verdict(self.fit, float(self.solution.weight_best[0]))


def check_observations(obs: Observations) -> None:
    """Refuse observations with fewer samples than the whole-arc MAP has unknowns plus one to judge its fit by
    (a ``ValueError`` naming the first file)."""
    unknowns = STATE_SIZE + int(obs.relative.sum())
    if len(obs) < unknowns + 2:
        raise ValueError(f"{obs.curves[0].source}: {len(obs)} sample{'s' if len(obs) != 1 else ''}; the whole-arc "
                         f"MAP needs at least {unknowns + 2}: the first sets the surface prior and the rest must "
                         f"outnumber its {unknowns} unknowns (attitude 3, surface 4"
                         f"{', one zero point per relative light curve' if unknowns > STATE_SIZE else ''})")


def file_scene(cfg: Config, obs: Observations) -> Scene:
    """The renderer of ``cfg``'s shape under the observations' per-sample geometry, or the config's fixed one; a
    ``ValueError`` when the config is a pass and the observations give no geometry."""
    if not obs.has_geometry and cfg.geometry.kind != "fixed":
        raise ValueError("the config's geometry is a pass (geometry.kind: orbit) but the light curve gives no "
                         "per-sample geometry or TLE and site")
    scene = Scene.from_config(cfg)
    if obs.has_geometry:
        scene = scene.with_geometry(obs.sun, obs.observer, obs.range_m)
    return scene.to(device=torch.device(cfg.device), dtype=cfg.torch_dtype)


def estimate_arc(cfg: Config, obs: Observations, *, q0: Tensor, sigma0: float, omega0: Tensor,
                 omega_sigma: Tensor | None = None) -> ArcRun:
    """The recommended estimator on ``obs`` (module docstring): from the attitude ``q0 (4,)`` at the first sample
    with 1σ ``sigma0`` (rad) per axis, the body rate ``omega0 (3,)`` (rad/s) known, the search of ``cfg.map``.

    ``omega_sigma (3,)`` (rad/s): the rate is an estimate with this 1σ per axis (an inversion's): the MAP still takes
    it as known, and the attitude covariance of every sample gets the rate's share added,
    ``P_k + Φ_k diag(σ_ω²) Φ_kᵀ`` with ``Φ_k`` the attitude's sensitivity to the initial rate
    (:func:`lightcurve_gp.inference.forward.rate_sensitivity`): an error in the rate turns into an attitude error
    that grows along the arc, which a covariance of the attitude alone would not admit."""
    start = time.perf_counter()
    problem = problem_from_observations(obs, q_est0=q0, sigma0=sigma0, omega0=omega0,
                                        inertia=cfg.shape.inertia_kg_m2, dtype=cfg.torch_dtype,
                                        device=torch.device(cfg.device))
    scene = file_scene(cfg, obs)
    solution = map_solution(cfg, scene, problem)
    setup = arc_setup(cfg, scene, problem, surface_known=False)
    local = setup.problem.recentred(solution.q0, torch.zeros(1, dtype=torch.int64))
    x = torch.cat([torch.zeros(1, 3, dtype=solution.q0.dtype), solution.theta], -1)
    rows = torch.zeros(1, dtype=torch.int64)
    r, offsets = local.residuals(x, rows)
    fitted = local.magnitudes(x, rows)[0]
    indicator = problem.obs.zero_point_indicator()
    if offsets is not None:
        fitted = fitted + offsets[0] @ indicator.T
    used = setup.problem.weight[0] > 0
    fit = fit_test(0.5 * float(r[0][used].square().sum()), samples=int(used.sum()),
                   parameters=STATE_SIZE + (0 if offsets is None else offsets.shape[-1]))
    estimate = arc_estimate(problem, solution)
    if omega_sigma is not None:
        w0 = problem.omega_est0[0]
        _, phi = rate_sensitivity(w0, inertia=torch.as_tensor(cfg.shape.inertia_kg_m2, dtype=w0.dtype),
                                  times=problem.times.to(w0.dtype))  # (N, 3, 3)
        share = phi @ torch.diag_embed(omega_sigma.to(w0).square()) @ phi.mT
        estimate = replace(estimate, P=estimate.P + share.unsqueeze(0))
    return ArcRun(problem=problem, solution=solution, estimate=estimate, fitted=fitted,
                  offsets=None if offsets is None else offsets[0], used=used, fit=fit,
                  seconds=time.perf_counter() - start)


def _times(run: ArcRun) -> np.ndarray:
    epoch = run.obs.epoch
    t = run.obs.t.cpu().numpy()
    if epoch is None:
        return np.array([""] * t.size)
    return Time(Time(epoch, scale="utc") + TimeDelta(t, format="sec"), precision=6).isot


def arc_history_table(run: ArcRun) -> Table:
    """The attitude history (one row per sample, a unit on every column): UTC time, ``t_s``, the light curve,
    ``q1…q4``, yaw/pitch/roll (3-2-1 of ``A(q)``) and the 1σ of the error about body x, y, z and of yaw, pitch, roll
    (the whole arc's covariance), the observed and fitted magnitudes, the residual and the whitened residual."""
    q = run.estimate.q_est[0].cpu()
    euler_rad = quat_to_euler321(q)
    P = run.estimate.P[0].cpu().to(euler_rad.dtype)
    sigma = torch.rad2deg(torch.diagonal(P, dim1=-2, dim2=-1).clamp_min(0).sqrt()).numpy()
    J = euler321_jacobian(euler_rad)
    sigma_euler = torch.diagonal(J @ P @ J.mT, dim1=-2, dim2=-1).clamp_min(0).sqrt().rad2deg().numpy()
    euler = torch.rad2deg(euler_rad).numpy()
    obs = run.obs
    mag, fit, sig = (x.detach().cpu().numpy() for x in (obs.mag[0], run.fitted, obs.sigma[0]))
    cols = {"time": _times(run), "t_s": obs.t.cpu().numpy(), "curve": obs.curve.cpu().numpy()}
    cols.update({f"q{i + 1}": q[:, i].numpy() for i in range(4)})
    cols.update({f"{name}_deg": euler[:, i] for i, name in enumerate(ANGLES)})
    cols.update({f"sigma_{axis}_deg": sigma[:, i] for i, axis in enumerate("xyz")})
    cols.update({f"sigma_{name}_deg": sigma_euler[:, i] for i, name in enumerate(ANGLES)})
    cols.update({"mag_obs": mag, "mag_err": sig, "mag_fit": fit, "residual": mag - fit,
                 "residual_sigmas": np.where(run.used.cpu().numpy(), (mag - fit) / sig, np.nan)})
    units = {"t_s": "s", "curve": "", **{f"q{i}": QUATERNION for i in range(1, 5)},
             **{f"{n}_deg": "deg" for n in ANGLES}, **{f"sigma_{a}_deg": "deg" for a in (*"xyz", *ANGLES)},
             **{k: "mag" for k in ("mag_obs", "mag_err", "mag_fit", "residual")}, "residual_sigmas": ""}
    return set_units(Table(cols), units, {"time": ISO_UTC, "curve": "light curve (0 = the first file)",
                                          "residual_sigmas": "residual / mag_err (NaN: not in the fit)"})


def estimate_table(problem: Problem, estimate: Estimate) -> Table:
    """Another estimator's attitude history on the same observations: ``t_s``, ``q1…q4``, yaw/pitch/roll and the
    1σ of the error about body x, y, z (deg; NaN without a covariance), one row per sample it estimates."""
    q = estimate.q_est[0].cpu()
    rows = torch.arange(q.shape[0]) if estimate.samples is None else estimate.samples.cpu()
    euler = torch.rad2deg(quat_to_euler321(q)).numpy()
    sigma = np.full((q.shape[0], 3), np.nan) if estimate.P is None else \
        torch.rad2deg(torch.diagonal(estimate.P[0].cpu(), dim1=-2, dim2=-1).clamp_min(0).sqrt()).numpy()
    cols = {"t_s": problem.obs.t.cpu()[rows].numpy()}
    cols.update({f"q{i + 1}": q[:, i].numpy() for i in range(4)})
    cols.update({f"{name}_deg": euler[:, i] for i, name in enumerate(ANGLES)})
    cols.update({f"sigma_{axis}_deg": sigma[:, i] for i, axis in enumerate("xyz")})
    units = {"t_s": "s", **{f"q{i}": QUATERNION for i in range(1, 5)}, **{f"{n}_deg": "deg" for n in ANGLES},
             **{f"sigma_{a}_deg": "deg" for a in "xyz"}}
    return set_units(Table(cols), units)


def arc_summary(run: ArcRun, record: dict) -> dict:
    """``summary.json``: the verdict, the fit's χ² against its distribution, the surface, the zero points, the
    modes, the time and the provenance ``record``."""
    sol = run.solution
    surface = surface_from_state(sol.theta[0].cpu())
    relative = [c.source for c in run.obs.curves if c.relative]
    return {
        "verdict": run.verdict, "estimator": "map (surface-state filter, then the whole-arc MAP)",
        "samples": len(run.obs), "light_curves": [c.source for c in run.obs.curves], "span_s": run.obs.span_s,
        "fit": {"chi2": run.chi2, "dof": run.dof, "chi2_per_dof": run.chi2 / run.dof, "p_value": run.p_value,
                "rms_mag": float(torch.sqrt((run.obs.mag[0] - run.fitted)[run.used].square().mean())),
                "p_no_fit": P_NO_FIT},
        "surface": {"rho": float(surface.rho), "f0": float(surface.f0), "n_u": float(surface.n_u),
                    "n_v": float(surface.n_v)},
        "zero_points_mag": None if run.offsets is None else dict(zip(relative, run.offsets.tolist())),
        "modes": int(sol.modes[0]), "weight_best": float(sol.weight_best[0]),
        "searched_again": None if sol.searched_again is None else bool(sol.searched_again[0]),
        "sigma_end_deg": [float(v) for v in torch.rad2deg(torch.diagonal(run.estimate.P[0, -1]).clamp_min(0).sqrt())],
        "seconds": run.seconds, "run": record}


def arc_report(run: ArcRun) -> list[str]:
    """The lines a command prints: what ran on what, the fit and the verdict in words."""
    obs, sol = run.obs, run.solution
    sigma = torch.rad2deg(torch.diagonal(run.estimate.P[0], dim1=-2, dim2=-1).clamp_min(0).sqrt())  # (N, 3)
    worst = float(sigma.max(-1).values.median())
    lines = [f"{obs.describe()}",
             f"fit: chi2 {run.chi2:.1f} for {run.dof} degrees of freedom (chi2/dof {run.chi2 / run.dof:.2f}, "
             f"p = {run.p_value:.3g}); {int(sol.modes[0])} mode{'s' if int(sol.modes[0]) != 1 else ''}, best weight "
             f"{float(sol.weight_best[0]):.3f}; median 1-sigma of the attitude {worst:.2f} deg (largest axis); "
             f"{run.seconds:.1f} s"]
    v = run.verdict
    if v == "no_fit":
        lines.append(f"verdict: no fit: the best fit's chi2/dof is {run.chi2 / run.dof:.2f}, far outside what "
                     f"{run.dof} degrees of freedom allow (p < {P_NO_FIT:g}); the shape, the spin, the start or the "
                     f"mag_err is wrong, and the attitude written is not an answer")
    elif v == "ambiguous":
        lines.append(f"verdict: ambiguous: the light curve fits, but {int(sol.modes[0])} attitudes fit it; the best "
                     f"carries {float(sol.weight_best[0]):.2f} of the evidence and the 1-sigma written spans them")
    else:
        lines.append("verdict: unique: the residuals are what the given mag_err allows, one attitude carries the "
                     "evidence")
    return lines
