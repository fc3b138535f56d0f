"""The global inversion on observed light curves: no start, several light curves sharing one spin state.

:func:`invert_observations` turns :class:`~lightcurve_gp.observations.Observations` (one or several files of one
object, any sample times, each light curve with its own geometry and, when relative, its own unknown zero point)
into the inversion's :class:`~lightcurve_gp.inference.trajectory.TrajectoryProblem` (:func:`trajectory_problem`),
runs the global search and judges it (:func:`lightcurve_gp.inference.answer.answer`: the fit test and the verdict,
one widened search when nothing fits; when later passes follow a gap of more than ten minutes, also each of the
longest passes alone, its best distinct solutions carried across the gaps by :mod:`lightcurve_gp.inference.bridge`),
takes the families modulo the exact ambiguity group, and polishes the ``polish`` leading families with the
whole-arc MAP with the surface unknown (:func:`lightcurve_gp.observed.arc_run.estimate_arc`, the family's rate taken
as known): the inversion fits ρ on the config's F0 and lobe, the MAP the whole surface state, so the polished fit's
χ² is the one to judge it by.

When every light curve is relative, the first one's zero point is carried by ρ (the others are profiled against it):
ρ then sets the first curve's level only and means nothing physical.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import torch

from lightcurve_gp.config.load import Config
from lightcurve_gp.inference.answer import MAX_LOG_RATIO, Answer, answer
from lightcurve_gp.inference.families import Families
from lightcurve_gp.inference.forward import GroupRenderer
from lightcurve_gp.inference.inversion import Inversion, InversionSettings
from lightcurve_gp.inference.trajectory import TrajectoryProblem
from lightcurve_gp.observations.observations import Observations
from lightcurve_gp.observed.arc_run import ArcRun, estimate_arc, file_scene
from lightcurve_gp.photometry.ambiguity import AmbiguityGroup, ambiguity_group, near_image_turns
from lightcurve_gp.photometry.render import Scene

__all__ = ["InversionRun", "trajectory_problem", "invert_observations"]


@dataclass
class InversionRun:
    """The inversion of some observations (module docstring).

    Attributes:
        problem: the least-squares problem of every sample; scene: its renderer; group: the exact ambiguity group.
        answer: the search's survivors, the families within the likelihood ratio (best weight first), the fit test
            and the verdict (:func:`lightcurve_gp.inference.answer.answer`: widened once when nothing fits, the
            passes after a long gap carried from the first, a slow rate's ridge probed).
        polished: the whole-arc MAP of each of the leading families (``[]`` when none was asked for).
        seconds: the polish's wall time (the search's stages are in ``inversion.seconds``).
    """

    problem: TrajectoryProblem
    scene: Scene
    group: AmbiguityGroup
    answer: Answer
    polished: list[ArcRun]
    seconds: float

    @property
    def inversion(self) -> Inversion:
        return self.answer.inversion

    @property
    def families(self) -> Families:
        return self.answer.families


def trajectory_problem(cfg: Config, obs: Observations) -> tuple[TrajectoryProblem, Scene]:
    """The inversion's problem of one object's observations (module docstring) and its renderer; a ``ValueError``
    when the config is a pass and the observations give no geometry."""
    scene = file_scene(cfg, obs)
    dtype, device = cfg.torch_dtype, torch.device(cfg.device)
    zero_points = obs.zero_point_indicator()
    if zero_points is not None and bool(obs.relative.all()):
        zero_points = zero_points[:, 1:] if zero_points.shape[1] > 1 else None  # the first curve's level: ρ
    move = lambda x: x.to(dtype=dtype, device=device)  # noqa: E731
    problem = TrajectoryProblem(GroupRenderer(scene), move(obs.t - obs.t[0]), move(obs.mag), move(obs.sigma),
                                torch.as_tensor(cfg.shape.inertia_kg_m2, dtype=dtype, device=device),
                                torch.zeros(0, 4, dtype=dtype, device=device),
                                zero_points=None if zero_points is None else move(zero_points))
    return problem, scene


def invert_observations(cfg: Config, obs: Observations, *, settings: InversionSettings,
                        max_log_ratio: float = MAX_LOG_RATIO, polish: int = 3,
                        progress: Callable[[str], None] | None = None) -> InversionRun:
    """The global inversion of ``obs`` and the whole-arc MAP of its ``polish`` leading families (module docstring).
    The periodogram's one-line errors come out as ``ValueError``."""
    problem, scene = trajectory_problem(cfg, obs)
    group = ambiguity_group(scene, times_s=problem.times, inertia=problem.inertia, rate_known=False)
    ans = answer(problem, group, settings=settings, rate_max_rad_s=math.radians(settings.rate_range_deg_s[1]),
                 max_log_ratio=max_log_ratio, image_turns=near_image_turns(scene), progress=progress)
    fam = ans.families
    start = time.perf_counter()
    polished = []
    for k in range(min(polish, len(fam))):
        if progress is not None:
            progress(f"polishing family {k + 1} by the whole-arc MAP (surface unknown, its rate known)")
        rate_std = torch.diagonal(fam.covariance[k, 3:6, 3:6]).clamp_min(0).sqrt().cpu()
        polished.append(estimate_arc(cfg, obs, q0=fam.q0[k].cpu(), sigma0=math.radians(cfg.filter.p0_deg),
                                     omega0=fam.omega0[k].cpu(),
                                     omega_sigma=torch.where(torch.isfinite(rate_std), rate_std, 0.0)))
    return InversionRun(problem, scene, group, ans, polished, time.perf_counter() - start)
