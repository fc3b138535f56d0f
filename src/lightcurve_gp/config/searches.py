"""The config sections of the searches: the whole-arc MAP's (``map:``) and the convex inversion's (``convex:``)."""

from __future__ import annotations

from dataclasses import dataclass

from lightcurve_gp.config.fields import spec

__all__ = ["MapConfig", "ConvexConfig"]


@dataclass(kw_only=True)
class MapConfig:
    """The whole-arc MAP's search (:mod:`lightcurve_gp.inference.arc_search`): its starts, the continuation in the
    noise, the misfit test's second search and the weak-direction probe. Every default was chosen on the tuning seeds
    of the random truths (docs/studies/realistic-photometry.md)."""

    screen: int = spec(0, lo=0, omit_default=True, doc="prior draws screened by cost for more starts (0: none)")
    keep: int = spec(4, lo=1, omit_default=True, doc="screened draws that become starts")
    noise_floor_mag: float | None = spec(0.1, lo=0.0, lo_open=True, omit_default=True,
                                          doc="the continuation's noise floor (mag); null: no continuation")
    floor_keep: int = spec(4, lo=1, omit_default=True, doc="the continuation's solutions that start the true-noise "
                                                           "solve")
    floor_iterations: int = spec(10, lo=1, omit_default=True, doc="Levenberg-Marquardt iterations of the "
                                                                   "continuation's first stage")
    lobe_starts: list[float] = spec([10.0, 100.0, 1000.0, 10000.0], lo=0.0, lo_open=True, omit_default=True,
                                     doc="lobe exponents n_u = n_v of the surface starts (surface unknown)")
    misfit_z: float | None = spec(1.0, omit_default=True,
                                   doc="the misfit test: a best cost above nu/2 + z sqrt(nu/2) is searched again; "
                                       "null: no test")
    lobe_pairs: list[list[float]] = spec([[1.0e4, 10.0], [10.0, 1.0e4], [3000.0, 100.0], [100.0, 3000.0]],
                                          lo=0.0, lo_open=True, omit_default=True,
                                          doc="unequal lobe exponents (n_u, n_v) of the second search's starts")
    again_draws: int = spec(256, lo=0, omit_default=True, doc="the second search's screen of prior attitude draws")
    again_keep: int = spec(8, lo=1, omit_default=True, doc="screened draws the second search solves from")
    probe_sigmas: list[float] = spec([2.5], lo=0.0, lo_open=True, omit_default=True,
                                      doc="the weak-direction probe: standard deviations along the weakest attitude "
                                          "direction (empty: no probe)")


@dataclass(kw_only=True)
class ConvexConfig:
    """Convex inversion (``python -m lightcurve_gp.invert`` with this section set runs
    :mod:`lightcurve_gp.commands.invert_convex`): pole, period and a convex shape from relative light curves with
    per-sample Sun and observer directions (e.g. a DAMIT file); the other sections are then not used."""

    law: str = spec("lommel_seeliger", choices=("lommel_seeliger", "ashikhmin_shirley"), omit_default=True,
                    doc="the scattering law: lommel_seeliger (+ c Lambert, with the phase function; asteroids) or "
                        "ashikhmin_shirley (a diffuse basis and one specular lobe per lobe_exponents entry, each "
                        "with its own areas; satellites)")
    lobe_exponents: list[float] = spec([800.0], lo=0.0, lo_open=True, omit_default=True,
                                        doc="ashikhmin_shirley: the fixed exponents n_u = n_v of the specular bases")
    fresnel_f0: float = spec(0.5, lo=0.0, hi=1.0, omit_default=True,
                             doc="ashikhmin_shirley: the lobes' Fresnel reflectance F0")
    ring_normals: int = spec(0, lo=0, omit_default=True,
                             doc="normals on the body equator (faces parallel to the spin axis) and the poles +-z "
                                 "added to every stage's Fibonacci normals (0: none)")
    glint_clip: float | None = spec(None, lo=1.0, lo_open=True, omit_default=True,
                                    doc="samples brighter than this many times their curve's median intensity are "
                                        "dropped as specular glints (null: none dropped)")
    refine_steps: int = spec(0, lo=0, omit_default=True,
                             doc="accelerated projected-gradient steps after every area fit's Newton iteration (for "
                                 "the near-singular fits of close ring normals and several bases; 0: none)")
    lambert: float = spec(0.1, lo=0.0, doc="c of the Lommel-Seeliger + c Lambert law")
    phase_amplitude: float = spec(0.5, doc="a of the phase function a exp(-alpha/d) + k alpha + 1")
    phase_width_rad: float = spec(0.1, lo=0.0, lo_open=True, doc="d of the phase function (rad)")
    phase_slope: float = spec(-0.5, doc="k of the phase function (per rad)")
    period_range_h: list[float] = spec([2.0, 20.0], lo=0.0, lo_open=True, length=2,
                                        doc="shortest and longest period searched (h)")
    harmonics: int = spec(2, lo=1, hi=8, doc="Fourier harmonics of the periodogram per apparition")
    window: float = spec(0.25, lo=0.0, lo_open=True, doc="half-width of each period scan in periodogram peak widths")
    step: float = spec(0.125, lo=0.0, lo_open=True, hi=1.0, doc="period step as a fraction of P^2/T (T the span)")
    coarse_poles: int = spec(24, lo=4, doc="poles of the coarse screen (Fibonacci grid)")
    coarse_normals: int = spec(32, lo=6, doc="facet normals of the coarse screen")
    subsample: int = spec(3, lo=1, doc="the coarse screen uses every n-th sample of each light curve")
    top_periods: int = spec(6, lo=1, doc="periods of the coarse screen passed to the fine one")
    poles: int = spec(200, lo=4, doc="poles of the fine screen (Fibonacci grid)")
    screen_normals: int = spec(60, lo=6, doc="facet normals of the fine screen")
    starts: int = spec(6, lo=1, doc="(pole, period) starts polished by Levenberg-Marquardt")
    normals: int = spec(120, lo=6, doc="facet normals of the polished shape")
    polish_iterations: int = spec(80, lo=1, doc="Levenberg-Marquardt iterations of the polish")
    closure: float = spec(0.1, lo=0.0, doc="weight of |sum a_k n_k|^2 (the Gaussian image closes)")
    separation_deg: float = spec(20.0, lo=0.0, lo_open=True, hi=180.0, doc="poles closer are one family")
    shape_degree: int = spec(0, lo=0, hi=12, doc="polished shape: 0 a free area per normal; else areas exp(real "
                             "spherical-harmonic series) of this degree (6: convexinv's)")
    refine_starts: int = spec(4, lo=0, doc="polish starts on each of two rings about the best pole (0: none)")
    refine_deg: float = spec(7.0, lo=0.0, lo_open=True, hi=45.0, doc="radius of the inner ring (deg); the outer: twice")
    magnitude_weights: bool = spec(False, omit_default=True,
                                   doc="weight every fit's intensity residuals by 1/I (true): they become magnitude "
                                       "residuals to first order, the scale of magnitude noise; false: convexinv's "
                                       "plain relative intensities")
