"""The sections of an experiment's configuration: typed dataclasses whose field metadata states each constraint.

:mod:`lightcurve_gp.config.validate` reads a mapping into these classes and checks the constraints; this module only
declares them (names, types, defaults, ranges, allowed strings, list lengths) and, beside each field that has one,
its *hash rule*: when :func:`lightcurve_gp.config.hashing.config_to_dict` leaves the field out. Every cache, model
and case key hashes that dict, so a setting added after those keys were first written is left out while it is off,
and configs that do not use it keep their keys:

* ``omit_default=True``: left out at its default value;
* ``omit_when={key: value, ...}``: left out when every named field has that value;
* ``omit_unless={key: value, ...}``: left out unless every named field has that value.

A key is the name of a field of the same section, or a dotted path from the whole config (``model.inputs``), which
is not known when a section is serialised alone (the field is then kept).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from lightcurve_gp.config.fields import hash_rule as _hash_rule
from lightcurve_gp.config.fields import spec as _spec
from lightcurve_gp.config.searches import ConvexConfig, MapConfig

__all__ = ["ConfigError", "Config", "GeometryConfig", "OrbitElementsConfig", "SiteConfig", "ShapeConfig",
           "SurfaceConfig", "DataConfig", "TrainingSurfacesConfig", "SpinRangeConfig", "ModelConfig",
           "ExactModelConfig", "SparseModelConfig", "TruthSurfaceConfig", "ScenarioConfig", "FilterConfig",
           "MapConfig", "EvaluationConfig", "ConvexConfig", "MODEL_KIND_SECTIONS"]


class ConfigError(ValueError):
    """A configuration value is missing, unknown, of the wrong type or out of range; the message names its key path."""


#: the geometry keys of one ``geometry.kind`` only
_ORBIT_ONLY = {"omit_when": {"kind": "fixed"}}
_FIXED_ONLY = {"omit_when": {"kind": "orbit"}}
#: the keys of the body-rate state, left out while ``filter.estimate_omega`` is off
_RATE_STATE = {"omit_when": {"estimate_omega": False}}
#: the paper's USQUE variant (``sigma_redraw`` true, ``q_placement`` after) was added after Crassidis & Markley's
_DEFAULT_USQUE = {"omit_when": {"sigma_redraw": False, "q_placement": "both"}}


@dataclass(kw_only=True)
class OrbitElementsConfig:
    """Osculating Keplerian elements at ``geometry.start_utc`` in the GCRS axes, propagated as a two-body orbit."""

    a_km: float = _spec(lo=6378.137, doc="semi-major axis (km), above the Earth's equatorial radius")
    e: float = _spec(0.0, lo=0.0, hi=0.99, doc="eccentricity")
    i_deg: float = _spec(0.0, lo=0.0, hi=180.0, doc="inclination (deg)")
    raan_deg: float = _spec(0.0, doc="right ascension of the ascending node (deg)")
    argp_deg: float = _spec(0.0, doc="argument of perigee (deg)")
    mean_anomaly_deg: float = _spec(0.0, doc="mean anomaly at start_utc (deg)")


@dataclass(kw_only=True)
class SiteConfig:
    """An observer on the ground: WGS84 geodetic coordinates."""

    lat_deg: float = _spec(lo=-90.0, hi=90.0, doc="geodetic latitude (deg)")
    lon_deg: float = _spec(lo=-180.0, hi=360.0, doc="longitude, east positive (deg)")
    alt_km: float = _spec(0.0, lo=-0.5, hi=10.0, doc="height above the WGS84 ellipsoid (km)")


@dataclass(kw_only=True)
class GeometryConfig:
    """Object–observer–Sun geometry (:mod:`lightcurve_gp.passes.geometry`).

    ``kind: fixed`` (the paper, Table 3): one Sun and one observer position, object at the origin, for every sample.
    ``kind: orbit``: the object on an orbit (``tle`` or ``elements``), the observer at ``site``, the Sun from astropy,
    per sample from ``start_utc`` at the scenario's cadence (or at ``timestamps_s``), with ``gap_fraction`` of the
    samples dropped at random; samples below ``min_elevation_deg`` or in the Earth's shadow are missing observations.
    """

    kind: str = _spec("fixed", choices=("fixed", "orbit"), omit_default=True)
    observer_km: list[float] | None = _spec(None, length=3, doc="fixed: observer position (km)", **_FIXED_ONLY)
    sun_km: list[float] | None = _spec(None, length=3, doc="fixed: Sun position (km)", **_FIXED_ONLY)
    tle: list[str] | None = _spec(None, length=2, doc="orbit: the two lines of a TLE (propagated with SGP4)",
                                  **_ORBIT_ONLY)
    elements: OrbitElementsConfig | None = _spec(None, doc="orbit: Keplerian elements instead of a TLE",
                                                 **_ORBIT_ONLY)
    site: SiteConfig | None = _spec(None, doc="orbit: the observer's site", **_ORBIT_ONLY)
    start_utc: str | None = _spec(None, doc="orbit: UTC time of the first sample (ISO 8601)", **_ORBIT_ONLY)
    timestamps_s: list[float] | None = _spec(None, lo=0.0, min_length=2,
                                             doc="orbit: sample times after start_utc (s), on the scenario.dt_s "
                                                 "grid; null: every scenario.dt_s up to scenario.duration_s",
                                             **_ORBIT_ONLY)
    gap_fraction: float = _spec(0.0, lo=0.0, hi=0.9, doc="orbit: share of the samples dropped at random (gaps)",
                                **_ORBIT_ONLY)
    gap_seed: int = _spec(0, lo=0, doc="orbit: seed of the dropped samples", **_ORBIT_ONLY)
    min_elevation_deg: float = _spec(10.0, lo=-90.0, hi=90.0, doc="orbit: lowest usable elevation at the site",
                                     **_ORBIT_ONLY)


@dataclass(kw_only=True)
class ShapeConfig:
    """Facet model of the object: the paper's box-wing or any mesh trimesh reads."""

    kind: str = _spec(choices=("box_wing", "mesh"))
    mesh_path: str | None = _spec(None, doc="mesh file; a relative path in a config file is relative to that "
                                            "file's folder, one given by --set to the working directory")
    box_m: list[float] = _spec(lo=0.0, lo_open=True, length=3)
    box_grid: int = _spec(lo=1)
    wing_m: list[float] = _spec(lo=0.0, lo_open=True, length=3)
    wing_grid: int = _spec(lo=1)
    inertia_kg_m2: list[float] = _spec(lo=0.0, lo_open=True, length=3)


@dataclass(kw_only=True)
class SurfaceConfig:
    """Ashikhmin–Shirley surface parameters shared by every rendering (paper Table 4).

    The diffuse reflectance ρ is not here: it is what varies (``data.rho_grid``, ``scenario.rho_true``,
    ``filter.rho_assumed``).
    """

    f0: float = _spec(lo=0.0, hi=1.0, doc="Fresnel reflectance at normal incidence")
    n_u: float = _spec(lo=0.0, doc="specular lobe exponent along u")
    n_v: float = _spec(lo=0.0, doc="specular lobe exponent along v")


@dataclass(kw_only=True)
class TrainingSurfacesConfig:
    """Surfaces the training set is rendered with (``data.surfaces``; ``model.target: surface_normalised``).

    Every training attitude is rendered with ``per_attitude`` surfaces of its own, drawn from ``seed``:
    ρ ~ U(rho), F0 ~ U(f0), n_u and n_v independently log-uniform in ``n``. The spread of the normalised magnitude
    over an attitude's surfaces is what the model's variance learns (``spread_inducing`` inducing points).
    """

    per_attitude: int = _spec(6, lo=2, doc="surfaces per training attitude (K)")
    rho: list[float] = _spec([0.1, 0.9], lo=0.0, lo_open=True, hi=1.0, length=2, doc="range of rho (uniform)")
    f0: list[float] = _spec([0.05, 0.95], lo=0.0, hi=1.0, length=2, doc="range of F0 (uniform); F0 < 1")
    n: list[float] = _spec([10.0, 1.0e4], lo=0.0, lo_open=True, length=2, doc="range of n_u, n_v (log-uniform)")
    seed: int = _spec(1, lo=0, doc="seed of the surface draws (the attitudes use data.seed)")
    spread_inducing: int = _spec(500, lo=1, doc="inducing points of the spread model (SGPR on log s^2)")


@dataclass(kw_only=True)
class SpinRangeConfig:
    """A range of initial body rates for the training set (``data.omega0_deg_s: {low: [...], high: [...]}``): each
    training attitude gets its own rate, uniform per axis between ``low`` and ``high`` (deg/s), drawn from
    ``data.seed``."""

    low: list[float] = _spec(length=3, doc="lower bound per body axis (deg/s)")
    high: list[float] = _spec(length=3, doc="upper bound per body axis (deg/s)")


@dataclass(kw_only=True)
class DataConfig:
    """Training set of the GP observation model (paper section 3.2)."""

    rho_grid: list[float] = _spec(lo=0.0, lo_open=True, hi=1.0, min_length=1)
    sampling: str = _spec(choices=("grid", "random", "sobol"))
    icosphere_subdivisions: int = _spec(lo=0, hi=7)
    phi_step_deg: float = _spec(lo=0.0, lo_open=True, hi=360.0)
    num_random: int = _spec(3852, lo=1)
    seed: int = _spec(0, lo=0)
    drop_duplicates: bool = _spec(False)
    quaternion_sign: str = _spec("as_is", choices=("as_is", "canonical", "both"))
    omega0_deg_s: list[float] | list[list[float]] | SpinRangeConfig = _spec(
        doc="initial body rate of the training trajectories (deg/s): one rate [x, y, z]; a list of rates, attitude i "
            "taking rate i mod K; or a range {low: [...], high: [...]}, one uniform draw per attitude")
    dt_s: float = _spec(lo=0.0, lo_open=True)
    t_span_past: float = _spec(lo=0.0, lo_open=True, doc="seconds averaged into m_app_past")
    heldout_size: int = _spec(2000, lo=1)
    phase_angle_deg: list[float] = _spec([0.0, 120.0], lo=0.0, hi=179.0, length=2,
                                         doc="model.inputs body_geometry: range of training phase angles (deg)",
                                         omit_unless={"model.inputs": "body_geometry"})
    surfaces: TrainingSurfacesConfig | None = _spec(None, doc="render each attitude with many surfaces "
                                                              "(model.target: surface_normalised); null: the "
                                                              "surface section and rho_grid", omit_default=True)


@dataclass(kw_only=True)
class ExactModelConfig:
    """Settings of the exact GP only (``model.kind: exact``)."""

    fit_iterations: int = _spec(100, lo=0, doc="Adam steps of the hyperparameter fit on the exact evidence")
    fit_subset: int = _spec(2000, lo=1, doc="points the evidence is fitted on (seeded random subset)")
    fast_variance_neighbors: int = _spec(256, lo=1, doc="training points each fast variance is conditioned on")


@dataclass(kw_only=True)
class SparseModelConfig:
    """Settings of the inducing-point GP only (``model.kind: sparse``)."""

    num_inducing: int = _spec(512, lo=1)
    optimize_inducing: bool = _spec(False, doc="move the inducing inputs to maximise the collapsed bound")
    iterations: int = _spec(200, lo=0, doc="evaluations of the fit's objective (inducing inputs and/or "
                                           "hyperparameters): Adam steps, or the most L-BFGS evaluations")
    optimizer: str = _spec("adam", choices=("adam", "lbfgs"), omit_default=True,
                           doc="adam: model.fit_lr steps; lbfgs: L-BFGS with a strong-Wolfe line search")
    fit_dtype: str = _spec("float64", choices=("float64", "float32"), omit_default=True,
                           doc="precision of the fit; the final conditioning is float64 either way")
    fit_objective: str = _spec("sparse_bound", choices=("sparse_bound", "exact_subset"), omit_default=True,
                               doc="sparse_bound: the collapsed SGPR bound; exact_subset: the exact GP evidence on "
                                   "fit_subset points (hyperparameters only), then the SGPR conditioned on all")
    fit_subset: int | None = _spec(None, lo=1, omit_default=True,
                                   doc="fit on this seeded random subset of the training points, then condition on "
                                       "all of them; null: fit on all")
    fit_inducing: int | None = _spec(None, lo=1, omit_default=True,
                                     doc="fit with this many k-means inducing inputs, then condition with "
                                         "num_inducing; null: num_inducing")
    fit_form: str = _spec("gpytorch", choices=("gpytorch", "gram"), omit_default=True,
                          doc="how the collapsed bound is computed: gpytorch (its InducingPointKernel); gram: from "
                              "K_uf K_fu (the same bound and Adam path, half the arithmetic; float64, fixed "
                              "inducing inputs and model.ard false only)")


#: the sections of ``model`` that hold the settings of one model kind
MODEL_KIND_SECTIONS = ("exact", "sparse")


@dataclass(kw_only=True)
class ModelConfig:
    """Observation model: the paper's GP (exact or inducing-point) and its prediction options.

    The settings here apply to both GP kinds; those of one kind live in its section (``model.exact``,
    ``model.sparse``), which may only be given when ``model.kind`` is that kind. The parametric model of the
    conventional UKF has no settings here: it is the renderer with ``filter.rho_assumed`` (or ``rho_reference``
    for the offset filter).
    """

    kind: str = _spec(choices=("exact", "sparse"))
    inputs: str = _spec("quaternion", choices=("quaternion", "attitude_matrix", "body_geometry"),
                        doc="GP input map: quaternion = [q, m_past] (paper); attitude_matrix = A(q), sign-invariant; "
                            "body_geometry = [A(q) s, A(q) v], trained over geometries (data.phase_angle_deg)")
    reference_range_km: float = _spec(36000.0, lo=0.0, lo_open=True, omit_unless={"inputs": "body_geometry"},
                                      doc="body_geometry: range the target is normalised to, "
                                          "y = m + 5 log10(r_ref / r)")
    target: str = _spec("magnitude", choices=("magnitude", "rho_normalised", "surface_normalised"),
                        doc="GP output: m_app as rendered (paper), m_app + 2.5 log10(rho / rho_reference), or "
                            "m_app + 2.5 log10(rho (1 - F0) / (rho_reference (1 - surface.f0))) over data.surfaces "
                            "with the spread over surfaces in the variance")
    rho_reference: float = _spec(0.5, lo=0.0, lo_open=True, hi=1.0,
                                 doc="reflectance the rho_normalised target refers to")
    theta1: float = _spec(lo=0.0, lo_open=True)
    theta2: float = _spec(lo=0.0, lo_open=True)
    noise_std: float = _spec(lo=0.0, lo_open=True)
    standardize_inputs: bool = _spec(False)
    ard: bool = _spec(False)
    fit_hyperparameters: bool = _spec(False, doc="fit (theta1, lengthscale, sigma): exact GP on its evidence over "
                                                 "exact.fit_subset points, sparse GP on sparse.fit_objective")
    fit_lr: float = _spec(0.05, lo=0.0, lo_open=True, doc="Adam learning rate of either fit")
    variance: str = _spec("fast", choices=("fast", "exact", "none"),
                          doc="variance the filter asks of the model: fast differs from exact for the exact GP only")
    exact: ExactModelConfig = field(default_factory=ExactModelConfig,
                                    metadata=_hash_rule(omit_unless={"kind": "exact"}))
    sparse: SparseModelConfig = field(default_factory=SparseModelConfig,
                                      metadata=_hash_rule(omit_unless={"kind": "sparse"}))


@dataclass(kw_only=True)
class TruthSurfaceConfig:
    """The surface the simulated object is made of (``scenario.surface``), apart from the ``surface`` section (the
    surface the models assume and the GP is trained with): ``--set scenario.surface.f0=0.9`` simulates another
    material and leaves every model key as it was. A key left null takes the model's value (``rho``:
    ``scenario.rho_true``)."""

    rho: float | None = _spec(None, lo=0.0, lo_open=True, hi=1.0, omit_default=True,
                              doc="the truth's diffuse reflectance; null: scenario.rho_true")
    f0: float | None = _spec(None, lo=0.0, hi=1.0, omit_default=True,
                             doc="the truth's Fresnel reflectance at normal incidence; null: surface.f0")
    n_u: float | None = _spec(None, lo=0.0, lo_open=True, omit_default=True,
                              doc="the truth's specular lobe exponent along u; null: surface.n_u")
    n_v: float | None = _spec(None, lo=0.0, lo_open=True, omit_default=True,
                              doc="the truth's specular lobe exponent along v; null: surface.n_v")


@dataclass(kw_only=True)
class ScenarioConfig:
    """Truth trajectory and its noisy light curve (paper section 4)."""

    q0: list[float] = _spec(length=4)
    omega0_deg_s: list[float] = _spec(length=3)
    dt_s: float = _spec(lo=0.0, lo_open=True)
    duration_s: float = _spec(lo=0.0, lo_open=True)
    rho_true: float = _spec(lo=0.0, lo_open=True, hi=1.0, doc="the truth's diffuse reflectance (unless "
                                                                 "scenario.surface.rho); 0 renders no diffuse light")
    noise_var: float = _spec(lo=0.0, lo_open=True, doc="variance of the magnitude noise (mag^2), > 0")
    initial_error_deg: list[float] = _spec(length=3)
    initial_omega_error_deg_s: list[float] = _spec([0.0, 0.0, 0.0], length=3, omit_default=True,
                                                   doc="body-rate error of the filters' initial rate (deg/s): "
                                                       "omega_est,0 = omega0 + this; the omega-known filters "
                                                       "propagate with it")
    seeds: int = _spec(lo=1)
    surface: TruthSurfaceConfig = field(default_factory=TruthSurfaceConfig, metadata=_hash_rule(omit_default=True))


@dataclass(kw_only=True)
class FilterConfig:
    """USQUE parameters (paper section 2.5; Crassidis & Markley 2003)."""

    alpha: float = _spec(lo=0.0, lo_open=True)
    beta: float = _spec()
    kappa: float = _spec()
    lam: float | None = _spec(doc="lambda given directly; null derives alpha^2 (n + kappa) - n")
    lam_rule: str = _spec("given", choices=("given", "julier"),
                          doc="given: lam as written; julier: lambda = 3 - n for a state of dimension n (the paper's "
                              "0 at n = 3; -1 with the offset, -4 with the surface states)")
    grp_a: float = _spec(lo=0.0, hi=1.0)
    grp_f: float = _spec(lo=0.0, lo_open=True)
    process_noise: float = _spec(lo=0.0)
    measurement_noise: float = _spec(lo=0.0, lo_open=True, doc="R: the noise variance the filters assume (mag^2), > 0")
    surface_measurement_noise: float | None = _spec(
        None, lo=0.0, lo_open=True, omit_default=True,
        doc="R of the surface-state filters surface_ukf and surface_ukf_select (mag^2); null: measurement_noise")
    p0_deg: float = _spec(lo=0.0, lo_open=True)
    add_model_variance: bool = _spec(True)
    model_error: str = _spec("none", choices=("none", "heldout"), omit_default=True,
                             doc="GP filters: none = R as given; heldout = R plus the GP's held-out excess variance "
                                 "(the mean squared error its predictive variance misses, stored with the model)")
    rho_assumed: float = _spec(lo=0.0, lo_open=True, hi=1.0)
    estimate_offset: bool = _spec(False, doc="carry a magnitude offset b in the state: y = h(q) + b")
    offset_prior_std: float = _spec(1.0, lo=0.0, lo_open=True, doc="prior std of b around y_0 - h(q_0) (mag)")
    offset_process_noise: float = _spec(0.0, lo=0.0, doc="random-walk variance of b per step (mag^2)")
    adaptive_noise: str = _spec("none", choices=("none", "innovation"), omit_default=True,
                                doc="measurement noise: none = R fixed; innovation = R_k = max(R, EMA of "
                                    "nu^2 - (Pyy - R)), from past innovations only")
    adaptive_noise_time_s: float = _spec(100.0, lo=0.0, lo_open=True, omit_when={"adaptive_noise": "none"},
                                         doc="forgetting time tau of the innovation average (s); rate dt / tau")
    estimate_omega: bool = _spec(False, omit_default=True,
                                 doc="carry the body rate omega in the state: [GRP error, omega, b?], every sigma "
                                     "point propagated with its own rate (RK4, torque-free)")
    p0_omega_deg_s: float = _spec(0.03, lo=0.0, doc="prior std of each omega component (deg/s)", **_RATE_STATE)
    omega_process_noise: float = _spec(0.0, lo=0.0, doc="variance added to each omega component per step "
                                                        "((rad/s)^2, a torque noise)", **_RATE_STATE)
    inertia_kg_m2: list[float] | None = _spec(None, lo=0.0, lo_open=True, length=3, omit_default=True,
                                              doc="principal moments the rate filter assumes; null: "
                                                  "shape.inertia_kg_m2 (the truth's)")
    sigma_redraw: bool = _spec(False, **_DEFAULT_USQUE,
                               doc="update with sigma points drawn again from the prior (the paper) instead of the "
                                   "propagated ones (Crassidis & Markley)")
    q_placement: str = _spec("both", choices=("both", "after"), **_DEFAULT_USQUE,
                             doc="process noise added to P+ before the sigma points and to P- (both; Crassidis & "
                                 "Markley) or once to P- after the propagation (after; the paper)")
    update_iterations: int = _spec(1, lo=1, omit_default=True,
                                   doc="posterior linearisations per measurement update (iterated posterior "
                                       "linearisation); 1: the ordinary unscented update (more is worse here: "
                                       "filters/iterated.py)")
    compile: bool = _spec(False, omit_default=True,
                          doc="run each omega-known filter step as compiled graphs (inductor): the same estimates to "
                              "rounding, faster per step; the first step of a shape compiles (seconds)")


@dataclass(kw_only=True)
class EvaluationConfig:
    """Scoring windows and evaluation options."""

    rmse_window_s: list[float] = _spec(lo=0.0, length=2)


@dataclass(kw_only=True)
class Config:
    """The whole experiment; see ``configs/boxwing.yaml`` for the paper's values."""

    name: str = _spec(doc="run name: one safe folder name (letters, digits, '.', '_', '-'; no leading '.')")
    dtype: str = _spec("float64", choices=("float64", "float32"))
    device: str = _spec("cpu")
    geometry: GeometryConfig
    shape: ShapeConfig
    surface: SurfaceConfig
    data: DataConfig
    model: ModelConfig
    scenario: ScenarioConfig
    filter: FilterConfig
    evaluation: EvaluationConfig
    map: MapConfig = field(default_factory=MapConfig, metadata=_hash_rule(omit_default=True))
    convex: ConvexConfig | None = _spec(None, omit_default=True,
                                        doc="convex inversion settings; set: invert runs the convex search")

    @property
    def torch_dtype(self) -> torch.dtype:
        """The ``torch.dtype`` named by :attr:`dtype`."""
        return getattr(torch, self.dtype)
