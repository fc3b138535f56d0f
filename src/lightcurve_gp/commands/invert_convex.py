"""``python -m lightcurve_gp.invert CONFIG --light-curve FILE`` with a ``convex:`` section: convex inversion.

Pole, sidereal period and convex shape of an object from relative light curves with per-sample Sun and observer
directions, nothing given (:func:`lightcurve_gp.inference.convex_search.convex_search`). The light-curve file is a
DAMIT/convexinv file (:mod:`lightcurve_gp.observed.damit`); ``--mag-err`` sets every sample's 1σ (default
0.01 mag; the format has none) for ``chi2_per_sample``, ``--max-log-ratio`` which families are reported. Writes the
new folder ``OUT/estimates/<name>/invert_<file stem>/`` atomically (refused if it exists, unless ``--force``):

* ``solutions.ecsv`` and ``areas.ecsv`` (:mod:`lightcurve_gp.observed.convex_solutions`);
* ``summary.json`` — the periodogram's minima, candidates screened and seconds per stage, settings, provenance;
* ``periodogram.png`` (the periodogram and the coarse screen's best rms per period), ``light_curves.png`` (six
  light curves with the best family's fit) and ``shape.png`` (the best family's convex solid rebuilt from its
  areas, :func:`~lightcurve_gp.photometry.minkowski.minkowski_polytope`, in two views, and its Gaussian image).

Prints each family's pole, period and rms, and the time of each stage.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
import torch
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d.art3d import Poly3DCollection
from tqdm.auto import tqdm

from lightcurve_gp.commands.common import (
    UserError,
    apply_threads,
    check_new_folder,
    check_output_root,
    progress_enabled,
    provenance,
)
from lightcurve_gp.commands.layout import invert_folder
from lightcurve_gp.evaluation.plots import save_figure
from lightcurve_gp.files import RunFolder, write_json_atomic
from lightcurve_gp.inference.convex_fit import ConvexData, convex_data, relative_residuals
from lightcurve_gp.inference.convex_search import ConvexSearch, ConvexSettings, convex_search
from lightcurve_gp.observed.convex_solutions import areas_table, convex_solutions_table, write_convex_tables
from lightcurve_gp.observed.damit import DEFAULT_SIGMA_MAG, is_damit_file, read_damit
from lightcurve_gp.photometry.convex import SatelliteScattering, Scattering, folded_pole
from lightcurve_gp.photometry.minkowski import minkowski_polytope

__all__ = ["settings_from_config", "run"]


def settings_from_config(cfg, max_log_ratio: float) -> ConvexSettings:
    """The search's settings from the config's ``convex:`` section."""
    c = cfg.convex
    if c.law == "ashikhmin_shirley":
        scattering = SatelliteScattering(f0=c.fresnel_f0, exponents=tuple(float(n) for n in c.lobe_exponents))
    else:
        scattering = Scattering(lambert=c.lambert, amplitude=c.phase_amplitude, width_rad=c.phase_width_rad,
                                slope=c.phase_slope)
    return ConvexSettings(
        scattering=scattering, ring=c.ring_normals, area_refine=c.refine_steps,
        period_range_h=(float(c.period_range_h[0]), float(c.period_range_h[1])), harmonics=c.harmonics,
        window=c.window, step=c.step, coarse_poles=c.coarse_poles, coarse_normals=c.coarse_normals,
        subsample=c.subsample, top_periods=c.top_periods, fine_poles=c.poles, fine_normals=c.screen_normals,
        starts=c.starts, separation_deg=c.separation_deg, polish_normals=c.normals,
        polish_iterations=c.polish_iterations, closure=c.closure, shape_degree=c.shape_degree,
        refine_starts=c.refine_starts, refine_deg=c.refine_deg, max_log_ratio=max_log_ratio,
        magnitude_weights=c.magnitude_weights)


def _shaded(level: np.ndarray) -> np.ndarray:
    """RGBA rows ``(T, 4)`` of a light grey-blue scaled by ``level`` ``(T,)`` in [0, 1] (a facet's shading)."""
    base = np.array([0.75, 0.8, 0.9])
    return np.hstack([base[None, :] * level[:, None], np.ones((level.size, 1))])


def _figures(folder: Path, data: ConvexData, search: ConvexSearch, settings: ConvexSettings) -> None:
    pg = search.periodogram
    order = np.argsort(search.coarse_periods_h)
    periods, rms = search.coarse_periods_h[order], search.coarse_rms[order]
    windows = np.split(np.arange(periods.size), np.nonzero(np.diff(periods) > 0.01 * periods[1:])[0] + 1)
    fig = Figure(figsize=(9.0, 6.0), layout="constrained")
    grid = fig.add_gridspec(2, len(windows))
    top = fig.add_subplot(grid[0, :])
    top.plot(pg.period_h, pg.chi2, color="black", lw=0.6)
    for p in pg.minima_h[:1]:
        top.axvline(p, color="tab:red", lw=0.8, ls=":")
    top.set_xscale("log")
    top.set_xlabel("period [h] (red: the deepest minimum)")
    top.set_ylabel("χ² of per-apparition\nFourier series")
    for k, idx in enumerate(windows):
        ax = fig.add_subplot(grid[1, k])
        ax.plot(periods[idx], rms[idx], ".-", color="black", ms=2, lw=0.4)
        for q in search.families.period_h:
            if periods[idx[0]] <= q <= periods[idx[-1]]:
                ax.axvline(q, color="tab:red", lw=0.8, ls=":")
        ax.set_xlabel(f"period [h], window {k + 1} (red: families)")
        ax.ticklabel_format(axis="x", useOffset=True)
        if k == 0:
            ax.set_ylabel("coarse screen:\nbest rms over poles")
    save_figure(fig, folder / "periodogram.png")

    fam = search.families
    p = lambda x: torch.as_tensor(np.asarray([x], dtype=np.float64))  # noqa: E731
    residual = relative_residuals(data, search.normals, settings.scattering, lam=p(math.radians(fam.lam_deg[0])),
                                  beta=p(math.radians(fam.beta_deg[0])), period_s=p(fam.period_h[0] * 3600.0),
                                  areas=torch.as_tensor(fam.areas[:1]))[0].numpy()
    counts = data.counts.numpy()
    shown = np.sort(np.argsort(-counts)[:6])
    fig = Figure(figsize=(10.0, 6.0), layout="constrained")
    for ax, c in zip(fig.subplots(2, 3).ravel(), shown):
        idx = np.nonzero(data.curve.numpy() == c)[0]
        hours = (data.t_s.numpy()[idx] - data.t_s.numpy()[idx[0]]) / 3600.0
        y = data.y.numpy()[idx]
        ax.plot(hours, y, ".", color="black", ms=3, label="observed")
        ax.plot(hours, y - residual[idx], color="tab:red", lw=1.2, label="family 1")
        ax.set_title(f"curve {c + 1} ({idx.size} points)", fontsize=9)
        ax.set_xlabel("hours from its first point")
        ax.set_ylabel("relative intensity")
    fig.legend(*fig.axes[0].get_legend_handles_labels(), loc="outside lower center", ncols=2, frameon=False)
    save_figure(fig, folder / "light_curves.png")

    n = search.normals.numpy()
    a = fam.areas[0].reshape(-1, n.shape[0]).sum(0)                      # every basis's areas on a normal
    solid = minkowski_polytope(n, a)
    fig = Figure(figsize=(13.0, 4.5), layout="constrained")
    light = np.array([0.5, -0.6, 0.6]) / np.linalg.norm([0.5, -0.6, 0.6])
    shade = 0.35 + 0.65 * np.clip(n[solid.facet_normal] @ light, 0.0, 1.0)
    reach = np.abs(solid.vertices).max()
    for k, (elev, azim, title) in enumerate(((0.0, 0.0, "equator-on (spin axis z up)"),
                                             (90.0, -90.0, "pole-on (from +z)"))):
        ax3 = fig.add_subplot(1, 3, k + 1, projection="3d")
        faces = Poly3DCollection(solid.vertices[solid.triangles], facecolors=_shaded(shade), edgecolors="none")
        ax3.add_collection3d(faces)
        ax3.set_xlim(-reach, reach)
        ax3.set_ylim(-reach, reach)
        ax3.set_zlim(-reach, reach)
        ax3.set_box_aspect((1, 1, 1))
        ax3.view_init(elev=elev, azim=azim)
        (ax3.set_xticks if k == 0 else ax3.set_zticks)([])           # the axis along the line of sight
        ax3.set_xlabel("x")
        ax3.set_ylabel("y")
        ax3.set_zlabel("z (spin axis)")
        ax3.set_title(f"convex solid of the areas (Minkowski), {title}", fontsize=9)
    ax = fig.add_subplot(1, 3, 3)
    lon = np.degrees(np.arctan2(n[:, 1], n[:, 0]))
    lat = np.degrees(np.arcsin(np.clip(n[:, 2], -1, 1)))
    sc = ax.scatter(lon, lat, c=a, s=30 + 400 * a / a.max(), cmap="viridis")
    fig.colorbar(sc, ax=ax, label="relative area")
    ax.set_xlabel("normal's body longitude [deg]")
    ax.set_ylabel("normal's body latitude [deg]")
    lam, beta, _ = folded_pole(fam.lam_deg[:1], fam.beta_deg[:1])
    ax.set_title(f"family 1: pole ({lam[0]:.1f}°, {beta[0]:.1f}°), P {fam.period_h[0]:.7f} h",
                 fontsize=9)
    save_figure(fig, folder / "shape.png")


def run(cfg, args: argparse.Namespace) -> int:
    """The convex inversion of ``args.light_curve`` under ``cfg`` (module docstring); exit code 0."""
    apply_threads(args.threads)
    if args.mag_err is not None and not args.mag_err > 0:
        raise UserError(f"--mag-err: {args.mag_err:g} must be > 0 mag")
    if not args.max_log_ratio >= 0:
        raise UserError(f"--max-log-ratio: {args.max_log_ratio:g} must be >= 0")
    if len(args.light_curve) != 1:
        raise UserError("--light-curve: the convex inversion reads one DAMIT file (it holds every light curve)")
    path = Path(args.light_curve[0])
    if not is_damit_file(path):
        raise UserError(f"{path}: convex inversion (the config's convex: section) reads DAMIT light-curve files "
                        f"(first line: the number of light curves; see lightcurve_gp.observed.damit)")
    sigma_mag = args.mag_err if args.mag_err is not None else DEFAULT_SIGMA_MAG
    obs = read_damit(path, sigma_mag=sigma_mag)
    check_output_root(args.out)
    folder = invert_folder(args.out, cfg.name, path)
    check_new_folder(folder, args.force)
    settings = settings_from_config(cfg, args.max_log_ratio)
    show = progress_enabled(args.no_progress)
    say = (lambda message: tqdm.write(message)) if show else None
    data = convex_data(obs, glint_clip=cfg.convex.glint_clip)
    if len(data) < len(obs):
        print(f"{path.name}: {len(obs) - len(data)} of {len(obs)} samples brighter than {cfg.convex.glint_clip:g} "
              f"times their curve's median dropped as glints (convex.glint_clip)")
    start = time.perf_counter()
    search = convex_search(data, settings, progress=say)
    total = time.perf_counter() - start
    record = provenance(cfg, config_file=str(args.config), light_curve=str(path))
    table = convex_solutions_table(search, sigma_mag=sigma_mag, samples=len(data), light_curves=data.curves,
                                   meta={"light_curve": path.name, "config": cfg.name})
    summary = {"families": len(search.families), "periodogram_minima_h": [float(p) for p in
                                                                          search.periodogram.minima_h],
               "periodogram_groups": search.periodogram.groups, "screened": search.screened,
               "seconds": {**search.seconds, "total": total}, "threads": torch.get_num_threads(),
               "residual_correlation": search.residual_correlation,
               "effective_samples": search.effective_samples,
               "settings": {k: (list(v) if isinstance(v, tuple) else v) for k, v in vars(settings).items()
                            if k != "scattering"},
               "scattering": {"law": type(settings.scattering).__name__, **vars(settings.scattering)},
               "run": record}
    with RunFolder(folder, force=args.force) as tmp:
        write_convex_tables(tmp, table, areas_table(search))
        write_json_atomic(summary, tmp / "summary.json")
        _figures(tmp, data, search, settings)
    fam = search.families
    lam, beta, _ = folded_pole(fam.lam_deg, fam.beta_deg)  # the axis as readers write it (β within ±90°)
    count = int(fam.within_ratio.sum())
    print(f"{path.name}: {len(data)} samples in {data.curves} light curves; {count} pole/period "
          f"famil{'y' if count == 1 else 'ies'} within {settings.max_log_ratio:g} nats")
    for k in range(len(fam)):
        if not fam.within_ratio[k]:
            print(f"  beyond the ratio, the mirror pole: ({lam[k]:.1f}°, {beta[k]:+.1f}°), "
                  f"P = {fam.period_h[k]:.8f} h, rms {fam.rms[k]:.4f}, {fam.log_ratio[k]:.1f} nats below the best")
            continue
        print(f"  family {k + 1}: pole (λ, β) = ({lam[k]:.1f}°, {beta[k]:+.1f}°), "
              f"P = {fam.period_h[k]:.8f} ± {fam.period_sigma_h[k]:.1e} h, rms {fam.rms[k]:.4f}, "
              f"{fam.log_ratio[k]:.1f} nats below the best, weight {fam.weight[k]:.3f}")
    stages = ", ".join(f"{k} {v:.1f} s" + (f" ({search.screened[k]} candidates)" if k in search.screened else "")
                       for k, v in search.seconds.items())
    print(f"time: {stages}; total {total:.1f} s on {torch.get_num_threads()} thread(s)")
    print(f"written: {folder}")
    return 0
