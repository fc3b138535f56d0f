"""Held-out synthetic convex objects: does the convex search find pole (modulo the mirror) and period blind?

Each object (seeded, never used to tune the search) is a random convex polyhedron: the convex hull of 300 points on
an ellipsoid of random axes (1 : b : c, b in 0.5–0.95, c in 0.35–b) pushed in or out by up to 15 %. Its exact
Gaussian image is its faces' (normal, area), rendered with the search's scattering law (Lommel–Seeliger +
0.1 Lambert, convexinv's phase function). Spin: pole uniform on the sphere, sidereal period log-uniform in
3–15 h. Geometry: the object on a circular orbit of radius 2.2–3.2 au, inclination 0–20°, the Earth on a circular
1 au orbit, both in the ecliptic frame; 3–6 apparitions around oppositions over up to 12 years, 10–40 light curves
of 2–6 h (a sample every 8–15 min) on nights within ±40 days of opposition (``--dense``: every 3–5 min, within
±100 days; :class:`Sampling`). Noise 0.01–0.05 mag Gaussian in
magnitude; every curve relative (its zero point unknown). The search runs with the default settings
(:class:`~lightcurve_gp.inference.convex_search.ConvexSettings`), nothing given.

Success: the best family's pole within 5° of the truth or its mirror (λ + 180°, β), and its period within the
scan's resolution ``0.5 P² / T`` of the truth. Also the pole and period of any reported family.

Every failure is judged against the truth's basin (:func:`basin`: the polish started at the true pole and period,
and at its mirror) in nats with the known noise σ (:func:`judge`): ``dnats = (rss_best − rss_basin) / (2σ²)``, rss
in mag² over all samples with each curve's zero point profiled. More than 1 nat worse: a *search miss*; else, the
basin itself off (pole > 5° or period beyond the resolution): *model-limited*; else *data-limited* (the best fits
as well as the truth's basin, elsewhere).

    python -m experiments.convex_synthetic --seed 1000 --out experiments/results/convex_synthetic/tuning_1000

**The bound** (:func:`bound_columns`): the Cramér–Rao bound of the pole and period at the truth's basin
(:func:`~lightcurve_gp.inference.convex_bound.convex_bound`: the shape's free areas and the curves' zero points
profiled out, the known noise σ), and at the truth itself with its own faces as the shape model. Columns
``pole_crb_deg`` (rms angular error at the bound), ``pole_crb95_deg`` (the radius holding 95 %), ``pole_crb_p5``
(the chance of an error below 5°), ``period_crb_h``, and the same with ``_true``. ``--bound`` adds them to a
folder's stored rows (``bound.jsonl``) without running the search: the basin is polished again from the truth.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import ConvexHull

from experiments.common import append_row, seed_rows
from lightcurve_gp.files import write_json_atomic
from lightcurve_gp.inference.convex_bound import convex_bound
from lightcurve_gp.inference.convex_fit import convex_data, design, fit_areas, magnitude_rss
from lightcurve_gp.inference.convex_search import ConvexSettings, convex_search, polish_starts, search_normals
from lightcurve_gp.observations.observations import CurveInfo, Observations
from lightcurve_gp.photometry.convex import Scattering, body_vectors, brightness, phase_angle

DAY = 86400.0
YEAR = 365.25 * DAY


def random_shape(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Face normals ``(F, 3)`` and areas ``(F,)`` of a random convex polyhedron (module docstring)."""
    b = rng.uniform(0.5, 0.95)
    axes = np.array([1.0, b, rng.uniform(0.35, b)])
    v = rng.standard_normal((300, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    points = v * axes * rng.uniform(0.85, 1.15, (300, 1))
    hull = ConvexHull(points)
    tri = points[hull.simplices]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    normal = cross / (2 * area[:, None])
    centre = points[hull.vertices].mean(0)
    outward = np.sign(((tri.mean(1) - centre) * normal).sum(1))
    return normal * outward[:, None], area


@dataclass(frozen=True)
class Sampling:
    """How the light curves are taken: nights within ``± night_days`` of opposition, a sample every
    ``step_min`` minutes (uniform in the range, per curve). The default is the original set's; ``DENSE`` has dense
    photometry's 24–120 points per 2–6 h curve and nights up to 100 days from opposition (phase angles to ~25°)."""

    night_days: float = 40.0
    step_min: tuple[float, float] = (8.0, 15.0)


DENSE = Sampling(night_days=100.0, step_min=(3.0, 5.0))


def random_observations(rng: np.random.Generator, seed: int,
                        sampling: Sampling = Sampling()) -> tuple[Observations, dict]:
    """One synthetic object's relative light curves and its truth (module docstring)."""
    normals, areas = random_shape(rng)
    lam, beta = rng.uniform(0, 2 * math.pi), math.asin(rng.uniform(-1, 1))
    period_h = math.exp(rng.uniform(math.log(3.0), math.log(15.0)))
    radius, incl, node = rng.uniform(2.2, 3.2), math.radians(rng.uniform(0, 20)), rng.uniform(0, 2 * math.pi)
    n_ast, n_earth = 2 * math.pi / (YEAR * radius ** 1.5), 2 * math.pi / YEAR
    phase0 = rng.uniform(0, 2 * math.pi)
    # oppositions: the Earth's longitude catches the object's every synodic period
    synodic = 2 * math.pi / (n_earth - n_ast)
    first = ((phase0 - 0.0) % (2 * math.pi)) / (n_earth - n_ast)
    apparitions = int(rng.integers(3, 7))
    chosen = np.sort(rng.choice(np.arange(8), size=apparitions, replace=False))
    curves = int(rng.integers(10, 41))
    per_app = np.bincount(rng.integers(0, apparitions, curves), minlength=apparitions)
    noise = rng.uniform(0.01, 0.05)
    t_all, c_all = [], []
    c = 0
    for app, count in zip(chosen, per_app):
        centre = first + app * synodic
        for night in np.sort(rng.uniform(-sampling.night_days, sampling.night_days, count)):
            length, step = rng.uniform(2, 6) * 3600.0, rng.uniform(*sampling.step_min) * 60.0
            t_all.append(centre + night * DAY + np.arange(0.0, length, step))
            c_all.append(np.full(t_all[-1].size, c))
            c += 1
    t, curve = np.concatenate(t_all), np.concatenate(c_all)
    order = np.argsort(t, kind="stable")
    t, curve = t[order], curve[order]

    def ecliptic(r, n, phase, inc):
        u = phase + n * t - node
        x, y = r * np.cos(u), r * np.sin(u)
        return np.stack([x * math.cos(node) - y * math.cos(inc) * math.sin(node),
                         x * math.sin(node) + y * math.cos(inc) * math.cos(node), y * math.sin(inc)], -1)

    ast = ecliptic(radius, n_ast, phase0, incl)
    earth = np.stack([np.cos(n_earth * t), np.sin(n_earth * t), np.zeros_like(t)], -1)
    sun_v, obs_v = -ast, earth - ast
    f64 = lambda a: torch.as_tensor(a, dtype=torch.float64)  # noqa: E731
    sun_u = f64(sun_v / np.linalg.norm(sun_v, axis=1, keepdims=True))
    obs_u = f64(obs_v / np.linalg.norm(obs_v, axis=1, keepdims=True))
    t0 = t[0]
    ts = f64(t - t0)
    spin = dict(lam=f64([lam]), beta=f64([beta]), period_s=f64([period_h * 3600.0]), phi0=f64([rng.uniform(0, 6.3)]),
                t_s=ts)
    L = brightness(f64(areas)[None], f64(normals), body_vectors(sun_u, **spin), body_vectors(obs_u, **spin),
                   phase_angle(sun_u, obs_u), Scattering())[0]
    mag = -2.5 * torch.log10(L) + noise * f64(rng.standard_normal(t.size))
    obs = Observations(t=ts, mag=mag, sigma=torch.full_like(ts, noise), curve=torch.as_tensor(curve),
                       curves=tuple(CurveInfo(f"synthetic {seed} #{k + 1}", True) for k in range(c)), sun=sun_u,
                       observer=obs_u, range_m=f64(np.linalg.norm(obs_v, axis=1) * 1.496e11),
                       epoch="2000-01-01T00:00:00")
    alpha = np.degrees(phase_angle(sun_u, obs_u).numpy())
    truth = {"seed": seed, "phi0": float(spin["phi0"][0]),
             "lam_deg": math.degrees(lam), "beta_deg": math.degrees(beta), "period_h": period_h,
             "noise_mag": noise, "curves": c, "samples": int(t.size), "apparitions": apparitions,
             "span_years": float((t[-1] - t[0]) / YEAR), "max_phase_deg": float(alpha.max()), "faces": len(areas)}
    return obs, truth


def separation_deg(l1, b1, l2, b2) -> float:
    l1, b1, l2, b2 = map(math.radians, (l1, b1, l2, b2))
    c = math.sin(b1) * math.sin(b2) + math.cos(b1) * math.cos(b2) * math.cos(l1 - l2)
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def score(truth: dict, fam, span_s: float) -> dict:
    resolution = 0.5 * truth["period_h"] ** 2 / (span_s / 3600.0)
    pole_err = [min(separation_deg(fam.lam_deg[k], fam.beta_deg[k], truth["lam_deg"], truth["beta_deg"]),
                    separation_deg(fam.lam_deg[k], fam.beta_deg[k], truth["lam_deg"] + 180, truth["beta_deg"]))
                for k in range(len(fam))]
    period_err = [abs(fam.period_h[k] - truth["period_h"]) for k in range(len(fam))]
    hit = [p < 5.0 and q < resolution for p, q in zip(pole_err, period_err)]
    return {"pole_error_deg": pole_err[0], "period_error_h": period_err[0], "resolution_h": resolution,
            "rms": float(fam.rms[0]), "families": len(fam), "best_ok": bool(hit[0]), "any_ok": bool(any(hit)),
            "best_lam_deg": float(fam.lam_deg[0]), "best_beta_deg": float(fam.beta_deg[0]),
            "best_period_h": float(fam.period_h[0])}


def basin(data, truth: dict, normals: torch.Tensor, settings: ConvexSettings) -> dict:
    """The truth's basin: the polish started at the true pole and period and at its mirror (λ + 180°, β), the
    better of the two in magnitude rss (mag², zero points profiled): what this shape model reaches near the truth.
    Its pole and period errors say whether the basin itself is within the goal; ``"state"`` holds its polish (not a
    column: :func:`bound_columns` takes it)."""
    best: dict = {"basin_rss_mag": math.inf}
    for lam in (truth["lam_deg"], truth["lam_deg"] + 180.0):
        spin = dict(lam=torch.tensor([math.radians(lam)], dtype=torch.float64),
                    beta=torch.tensor([math.radians(truth["beta_deg"])], dtype=torch.float64),
                    period_s=torch.tensor([truth["period_h"] * 3600.0], dtype=torch.float64))
        fitted = data.magnitude_weighted() if settings.magnitude_weights else data
        init = fit_areas(design(data, normals, settings.scattering, **spin), fitted, normals, iterations=30)
        p = polish_starts(data, normals, settings, **spin, areas=init.areas)
        rss = float(magnitude_rss(data, normals, settings.scattering, lam=p.lam, beta=p.beta, period_s=p.period_s,
                                  areas=p.areas)[0])
        if math.isfinite(rss) and rss < best["basin_rss_mag"]:
            lam_deg, beta_deg = math.degrees(float(p.lam[0])), math.degrees(float(p.beta[0]))
            best = {"basin_rss_mag": rss, "basin_rms": float(p.rms[0]), "truth_rms": float(p.rms[0]),
                    "basin_pole_error_deg": min(separation_deg(lam_deg, beta_deg, truth["lam_deg"], truth["beta_deg"]),
                                                separation_deg(lam_deg, beta_deg, truth["lam_deg"] + 180,
                                                               truth["beta_deg"])),
                    "basin_period_error_h": abs(float(p.period_s[0]) / 3600.0 - truth["period_h"]),
                    "basin_lam_deg": lam_deg, "basin_beta_deg": beta_deg,
                    "basin_period_h": float(p.period_s[0]) / 3600.0, "state": p}
    return best


def _bound_row(bound, suffix: str) -> dict:
    return {f"pole_crb{suffix}_deg": bound.pole_sigma_deg, f"pole_crb95{suffix}_deg": bound.pole_radius95_deg,
            f"pole_crb_p5{suffix}": bound.within(5.0), f"period_crb{suffix}_h": bound.period_sigma_s / 3600.0,
            f"pole_crb_axes{suffix}_deg": [float(a) for a in bound.pole_axes_deg]}


def bound_columns(data, truth: dict, normals: torch.Tensor, settings: ConvexSettings, state) -> dict:
    """The Cramér–Rao bound's columns (module docstring) at the truth's basin (``state``, a one-row polish on
    ``normals``) and at the truth with its own faces and areas (:func:`random_shape` of the seed)."""
    at_basin = convex_bound(data, normals, settings.scattering, lam=float(state.lam[0]), beta=float(state.beta[0]),
                            period_s=float(state.period_s[0]), areas=state.areas[0], sigma_mag=truth["noise_mag"])
    faces, areas = random_shape(np.random.default_rng(truth["seed"]))
    at_truth = convex_bound(data, torch.as_tensor(faces), settings.scattering, lam=math.radians(truth["lam_deg"]),
                            beta=math.radians(truth["beta_deg"]), period_s=truth["period_h"] * 3600.0,
                            areas=torch.as_tensor(areas), sigma_mag=truth["noise_mag"], phi0=truth["phi0"])
    return {**_bound_row(at_basin, ""), "crb_free_areas": at_basin.free_areas, **_bound_row(at_truth, "_true")}


def add_bounds(folder: Path, settings: ConvexSettings, sampling: Sampling) -> list[dict]:
    """The bound's columns for every stored row of ``folder/rows.jsonl`` (the search not run again: the truth's
    basin polished again, its rss checked against the row's), written to ``folder/bound.jsonl``."""
    out = folder / "bound.jsonl"
    done = {r["seed"] for r in seed_rows(out)}
    for row in sorted(seed_rows(folder / "rows.jsonl"), key=lambda r: r["seed"]):
        if row["seed"] in done:
            continue
        obs, truth = random_observations(np.random.default_rng(row["seed"]), row["seed"], sampling)
        data = convex_data(obs)
        normals = search_normals(settings.polish_normals, settings.ring)
        again = basin(data, truth, normals, settings)
        keep = ("seed", "kind", "best_ok", "pole_error_deg", "period_error_h", "resolution_h", "dnats", "noise_mag",
                "samples", "curves", "apparitions", "basin_pole_error_deg", "basin_rss_mag")
        new = {**{k: row[k] for k in keep}, "basin_rss_mag_again": again["basin_rss_mag"],
               **bound_columns(data, truth, normals, settings, again["state"])}
        append_row(out, new)
        print(f"seed {row['seed']} ({row['kind']}): pole bound {new['pole_crb_deg']:.2f} deg rms, 95 % within "
              f"{new['pole_crb95_deg']:.2f} deg, P(< 5 deg) {new['pole_crb_p5']:.2f}; with the true faces "
              f"{new['pole_crb_true_deg']:.2f} deg; basin rss {again['basin_rss_mag']:.5f} (stored "
              f"{row['basin_rss_mag']:.5f})", flush=True)
    return seed_rows(out)


def judge(row: dict) -> dict:
    """The nat rule: ``dnats = (rss_best − rss_basin) / (2σ²)`` (σ the known noise, mag; rss in mag² over all
    samples, zero points profiled). A success is ``ok``; a failure whose best is worse than the truth's basin by
    more than 1 nat is a ``search_miss``; otherwise, if the basin itself is off (pole > 5° or period beyond the
    resolution) it is ``model_limited`` (the data under this shape model do not lead to the truth even from it),
    else ``data_limited`` (the best fits as well as the truth's basin, elsewhere)."""
    dnats = (row["rss_mag"] - row["basin_rss_mag"]) / (2.0 * row["noise_mag"] ** 2)
    basin_ok = row["basin_pole_error_deg"] < 5.0 and row["basin_period_error_h"] < row["resolution_h"]
    if row["best_ok"]:
        kind = "ok"
    elif dnats > 1.0:
        kind = "search_miss"
    elif not basin_ok:
        kind = "model_limited"
    else:
        kind = "data_limited"
    return {"dnats": dnats, "basin_ok": basin_ok, "kind": kind}


def bound_summary(rows: list[dict]) -> dict:
    """How many seeds the bound alone rules out of "within 5°" (95 % radius > 5°), the expected successes at the
    bound (Σ P(< 5°)), and those per kind of row."""
    kinds = sorted({r["kind"] for r in rows})
    out: dict = {"objects": len(rows), "crb95_over_5deg": sum(r["pole_crb95_deg"] > 5.0 for r in rows),
                 "expected_within_5deg_at_bound": float(sum(r["pole_crb_p5"] for r in rows)),
                 "median_pole_crb_deg": float(np.median([r["pole_crb_deg"] for r in rows])),
                 "median_pole_crb_true_deg": float(np.median([r["pole_crb_true_deg"] for r in rows]))}
    for k in kinds:
        sub = [r for r in rows if r["kind"] == k]
        out[k] = {"objects": len(sub), "crb95_over_5deg": sum(r["pole_crb95_deg"] > 5.0 for r in sub),
                  "median_pole_crb_deg": float(np.median([r["pole_crb_deg"] for r in sub]))}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", type=int, default=24)
    parser.add_argument("--seed", type=int, default=1000, help="first seed (held out: never used for tuning)")
    parser.add_argument("--out", type=Path, default=Path("experiments/results/convex_synthetic"))
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--dense", action="store_true",
                        help="dense sampling: 3-5 min steps and nights up to 100 d from opposition (Sampling)")
    parser.add_argument("--setting", action="append", default=[], metavar="NAME=NUMBER",
                        help="a ConvexSettings field other than its default (repeatable), e.g. polish_normals=60")
    parser.add_argument("--bound", action="store_true",
                        help="add the Cramer-Rao bound's columns to the folder's stored rows (bound.jsonl) without "
                             "running the search")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    settings = ConvexSettings(**{k: (int(v) if v.lstrip("-").isdigit() else float(v))
                                 for k, v in (item.split("=", 1) for item in args.setting)})
    args.out.mkdir(parents=True, exist_ok=True)
    if args.bound:
        rows = add_bounds(args.out, settings, DENSE if args.dense else Sampling())
        print(json.dumps(bound_summary(rows)))
        return 0
    rows_path = args.out / "rows.jsonl"
    done = {r["seed"] for r in seed_rows(rows_path)}
    for seed in range(args.seed, args.seed + args.objects):
        if seed in done:
            continue
        obs, truth = random_observations(np.random.default_rng(seed), seed, DENSE if args.dense else Sampling())
        data = convex_data(obs)
        start = time.perf_counter()
        search = convex_search(data, settings)
        seconds = time.perf_counter() - start
        row = {**truth, **score(truth, search.families, data.span_s), "seconds": seconds,
               "stage_seconds": search.seconds, "settings": args.setting}
        fam = search.families
        row["rss_mag"] = float(magnitude_rss(
            data, search.normals, settings.scattering, lam=torch.tensor([math.radians(fam.lam_deg[0])]),
            beta=torch.tensor([math.radians(fam.beta_deg[0])]), period_s=torch.tensor([fam.period_h[0] * 3600.0]),
            areas=torch.as_tensor(fam.areas[:1]))[0])
        row.update(basin(data, truth, search.normals, settings))
        row.update(bound_columns(data, truth, search.normals, settings, row.pop("state")))
        row.update(judge(row))
        append_row(rows_path, row)
        print(f"seed {seed}: {truth['curves']} curves, {truth['samples']} samples, noise {truth['noise_mag']:.3f}, "
              f"P {truth['period_h']:.4f} h -> pole error {row['pole_error_deg']:.1f} deg, period error "
              f"{row['period_error_h']:.1e} h (resolution {row['resolution_h']:.1e}), ok {row['best_ok']}, rms "
              f"{row['rms']:.4f} (the truth's basin {row['basin_rms']:.4f}, pole error "
              f"{row['basin_pole_error_deg']:.1f} deg), {row['dnats']:+.1f} nats: {row['kind']}, "
              f"{row['seconds']:.0f} s", flush=True)
    rows = seed_rows(rows_path, range(args.seed, args.seed + args.objects))
    ok = sum(r["best_ok"] for r in rows)
    any_ok = sum(r["any_ok"] for r in rows)
    kinds = {k: sum(r["kind"] == k for r in rows) for k in ("ok", "search_miss", "data_limited", "model_limited")}
    period_ok = sum(r["period_error_h"] < r["resolution_h"] for r in rows)
    pole_ok = sum(r["pole_error_deg"] < 5.0 for r in rows)
    summary = {"objects": len(rows), "best_ok": ok, "any_family_ok": any_ok, "period_ok": period_ok,
               "pole_ok": pole_ok, "kinds": kinds,
               "basin_ok": sum(r["basin_ok"] for r in rows),
               "median_basin_pole_error_deg": float(np.median([r["basin_pole_error_deg"] for r in rows])),
               "median_seconds": float(np.median([r["seconds"] for r in rows])),
               "median_pole_error_deg": float(np.median([r["pole_error_deg"] for r in rows]))}
    if all("pole_crb_deg" in r for r in rows):
        summary["bound"] = bound_summary(rows)
    write_json_atomic(summary, args.out / "summary.json")
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
