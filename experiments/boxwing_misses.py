"""Where does the box-wing search lose a seed whose truth's basin fits better (a search miss)?

For one seed of ``experiments.boxwing_convex`` (tuning seeds only: < 200), the search is run with its stages
reported, then the stages are replayed at the truth: at each image's period (the truth's ``P`` and, the half turn
being exact, ``P/2``), the fine stage's screen (its normals, float32, the same area fit) over its pole grid and at
the true pole — where the true pole's screen rms ranks among the grid's and against the polish starts the search
took — and the polish started from the grid poles nearest the truth (what the screen could have handed on) and from
rings of 10° and 20° about the true pole: how far from the truth a start still ends in its basin.

    python -m experiments.boxwing_misses --seed 102
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np
import torch

from experiments.boxwing_convex import NOISE_MAG, SETTINGS, polish_from, separation_deg, simulate
from lightcurve_gp.inference.convex_fit import convex_data, design, fit_areas, magnitude_rss
from lightcurve_gp.inference.convex_search import ConvexSettings, convex_search, pole_grid, ring_poles, search_normals

F64 = torch.float64


def screen(data, settings: ConvexSettings, lam: torch.Tensor, beta: torch.Tensor, period_h: float) -> np.ndarray:
    """The fine stage's screen rms ``(B,)`` (its normals, float32 design, the search's area fit) at one period."""
    normals = search_normals(settings.fine_normals, settings.ring)
    out = []
    for s in range(0, lam.numel(), settings.chunk):
        sl = slice(s, s + settings.chunk)
        G = design(data, normals, settings.scattering, lam=lam[sl], beta=beta[sl],
                   period_s=torch.full((lam[sl].numel(),), period_h * 3600.0, dtype=F64), dtype=torch.float32)
        out.append(fit_areas(G, data, normals, closure=settings.closure, iterations=settings.area_iterations,
                             refine=settings.area_refine).rms.numpy())
    return np.concatenate(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    if args.seed >= 200:
        parser.error("--seed: held-out seeds (>= 200) are not diagnosed; use a tuning seed")
    torch.set_num_threads(args.threads)
    settings = ConvexSettings(**SETTINGS)
    obs, truth, _ = simulate(args.seed, nights=2, hours=2.5, cadence=15.0)
    data = convex_data(obs, glint_clip=4.0)
    search = convex_search(data, settings, progress=lambda m: print("  search:", m, flush=True))
    fam = search.families
    best_rss = float(magnitude_rss(data, search.normals, settings.scattering,
                                   lam=torch.tensor([math.radians(fam.lam_deg[0])], dtype=F64),
                                   beta=torch.tensor([math.radians(fam.beta_deg[0])], dtype=F64),
                                   period_s=torch.tensor([fam.period_h[0] * 3600.0], dtype=F64),
                                   areas=torch.as_tensor(fam.areas[:1], dtype=F64))[0])
    print(f"seed {args.seed}: truth {truth['lam_deg']:.1f}/{truth['beta_deg']:.1f} deg, P {truth['period_min']:.4f} "
          f"min; best {fam.lam_deg[0]:.1f}/{fam.beta_deg[0]:.1f} deg {fam.period_h[0] * 60:.4f} min, rss "
          f"{best_rss:.3f} mag^2")
    lam_g, beta_g = pole_grid(settings.fine_poles)
    sep = np.array([separation_deg(math.degrees(float(a)), math.degrees(float(b)), truth["lam_deg"],
                                   truth["beta_deg"]) for a, b in zip(lam_g, beta_g)])
    near = np.argsort(sep)[:3]
    for image in truth["images"]:
        period_h = image["period_min"] / 60.0
        rms = screen(data, settings, lam_g, beta_g, period_h)
        lam_t = torch.tensor([math.radians(image["lam_deg"])], dtype=F64)
        beta_t = torch.tensor([math.radians(image["beta_deg"])], dtype=F64)
        at_truth = float(screen(data, settings, lam_t, beta_t, period_h)[0])
        print(f"{image['name']} ({image['period_min']:.4f} min): screen rms at the true pole {at_truth:.4f}, grid "
              f"best {rms.min():.4f} at {sep[rms.argmin()]:.0f} deg from the truth; the true pole would rank "
              f"{int((rms < at_truth).sum()) + 1} of {rms.size + 1}; the grid poles nearest the truth "
              + ", ".join(f"{sep[k]:.0f} deg: rms {rms[k]:.4f} (rank {int((rms < rms[k]).sum()) + 1})"
                          for k in near), flush=True)
        starts = [(f"grid {sep[k]:.0f} deg", math.degrees(float(lam_g[k])), math.degrees(float(beta_g[k])))
                  for k in near]
        for radius in (10.0, 20.0):
            lr, br = ring_poles(math.radians(image["lam_deg"]), math.radians(image["beta_deg"]),
                                math.radians(radius), 4)
            starts += [(f"ring {radius:.0f} deg", math.degrees(float(a)), math.degrees(float(b)))
                       for a, b in zip(lr, br)]
        starts.append(("truth", image["lam_deg"], image["beta_deg"]))
        for name, lam, beta in starts:
            p = polish_from(data, search.normals, settings, lam_deg=lam, beta_deg=beta, period_h=period_h)
            off = separation_deg(p["lam_deg"], p["beta_deg"], image["lam_deg"], image["beta_deg"])
            gain = (best_rss - p["rss_mag"]) / (2 * NOISE_MAG ** 2)
            print(f"  polish from {name}: ends {off:.1f} deg from the truth, period {p['period_h'] * 60:.4f} min, "
                  f"{gain:+.1f} nats better than the search's best", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
