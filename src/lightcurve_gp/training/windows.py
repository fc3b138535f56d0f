"""The paper's training windows (section 3.2) and the pieces every training set shares.

Each training point is one short torque-free trajectory from an initial attitude ``q(0)`` with the config's
``data.omega0_deg_s`` (one rate, a list of rates taken in turn, or a range drawn per attitude:
:func:`training_rates`), sampled every ``dt`` from ``0`` to ``T = t_span_past``, rendered with one reflectance ρ:

* ``q      = q(T)``                          — attitude at the end of the window (GP input);
* ``m_past = mean(m_app(t) for t = 0, dt, …, T − dt)`` — the ``T/dt`` samples strictly *before* the end;
* ``y      = m_app(T)``                      — the magnitude to predict (GP output).

So ``m_past`` summarises the past ``T`` seconds and excludes the predicted sample, as in the filter, whose
``m_past`` (paper Sec. 3.3, Eq. (54)) folds in observation ``k`` only after the update at step ``k``.
The set is the product of the initial attitudes (``data.sampling``) and ``data.rho_grid``
(:func:`window_training_set`). The other training sets (:mod:`.surfaces`, :mod:`.geometry`) are built from the same
pieces: :class:`TrainingSet`, :func:`initial_attitudes`, :func:`training_rates`, :func:`window_steps`,
:func:`shape_inertia`; :mod:`.sets` picks the generator a config needs.
"""


from __future__ import annotations

import math
from dataclasses import dataclass
from dataclasses import replace as _replace

import torch
from torch import Tensor
from tqdm.auto import tqdm

from lightcurve_gp.attitude.dynamics import propagate
from lightcurve_gp.attitude.rotations import quat_canonical
from lightcurve_gp.attitude.sampling import grid_attitudes, icosphere_axes, random_attitudes, sobol_attitudes
from lightcurve_gp.config.schema import Config, DataConfig, SpinRangeConfig
from lightcurve_gp.photometry.render import Scene

__all__ = ["TrainingSet", "initial_attitudes", "drop_duplicate_attitudes", "training_rates", "window_samples",
           "window_steps", "training_scene", "shape_inertia", "window_training_set", "window_heldout_set",
           "attitude_count"]


@dataclass
class TrainingSet:
    """GP training (or evaluation) data; all tensors share the first dimension ``N``.

    Attributes:
        q: attitudes at the end of each window ``(N, 4)``.
        m_past: mean magnitude of the window before the end ``(N,)`` (mag).
        y: magnitude at the end of the window ``(N,)`` (mag).
        rho: diffuse reflectance the trajectory was rendered with ``(N,)``.
        dropped: number of trajectories dropped because some sample had zero flux (no magnitude).
    """

    q: Tensor
    m_past: Tensor
    y: Tensor
    rho: Tensor
    dropped: int = 0

    def __len__(self) -> int:
        return self.q.shape[0]

    def to(self, device=None, dtype=None) -> "TrainingSet":
        """Copy with tensors moved to ``device`` / cast to ``dtype``."""
        move = lambda t: t.to(device=device, dtype=dtype)  # noqa: E731
        return TrainingSet(move(self.q), move(self.m_past), move(self.y), move(self.rho), self.dropped)

    def state_dict(self) -> dict:
        return {"q": self.q, "m_past": self.m_past, "y": self.y, "rho": self.rho, "dropped": self.dropped}


def _sign_unique(q: Tensor, tol: float = 1e-12) -> Tensor:
    """One sign representative per attitude: ``q4 > 0``, or, when ``q4 = 0``, the first non-zero component > 0."""
    nonzero = q.abs() > tol
    first = torch.gather(q, -1, nonzero.float().argmax(-1, keepdim=True))  # first non-zero of (q1, q2, q3, q4)
    lead = torch.where(q[..., 3:].abs() > tol, q[..., 3:], first)
    return torch.where(lead < 0, -q, q)


def drop_duplicate_attitudes(q: Tensor, decimals: int = 9) -> Tensor:
    """Remove repeated attitudes ``(A, 4) → (A', 4)``, treating ``q`` and ``−q`` as one; keeps first occurrences in
    order.

    The paper's grid repeats attitudes: every Φ = 0 entry is the identity, and axis ``e`` with angle Φ equals
    axis ``−e`` with ``360° − Φ`` up to sign, so its 3852 entries hold 1606 distinct attitudes.
    """
    key = torch.round(_sign_unique(q) * 10**decimals)
    _, inverse = torch.unique(key, dim=0, return_inverse=True)
    index = torch.arange(q.shape[0], device=q.device)
    first = torch.full((int(inverse.max()) + 1,), q.shape[0], dtype=torch.long, device=q.device)
    first = first.scatter_reduce(0, inverse, index, reduce="amin")
    return q[torch.sort(first).values]


def initial_attitudes(data: DataConfig, dtype=torch.float64, device=None) -> Tensor:
    """Initial attitudes ``(A, 4)`` of the training trajectories, per ``data.sampling``.

    ``grid``: icosphere axes (``icosphere_subdivisions``) × Φ ∈ {0, step, …} (the paper: 642 × 6 = 3852);
    ``random`` / ``sobol``: ``num_random`` attitudes uniform on SO(3) from ``data.seed``.
    """
    if data.sampling == "grid":
        axes = icosphere_axes(data.icosphere_subdivisions, dtype=dtype, device=device)
        q = grid_attitudes(axes, data.phi_step_deg)
    elif data.sampling == "random":
        q = random_attitudes(data.num_random, seed=data.seed, dtype=dtype, device=device)
    else:
        q = sobol_attitudes(data.num_random, seed=data.seed, dtype=dtype, device=device)
    if data.drop_duplicates:
        q = drop_duplicate_attitudes(q)
    return q


def attitude_count(data: DataConfig) -> int:
    """How many attitudes :func:`initial_attitudes` gives, from the config alone (before any is made): ``(10 · 4^s +
    2)`` icosphere axes × ``⌈360° / step⌉`` angles for ``grid``, ``num_random`` otherwise; with
    ``drop_duplicates`` an upper bound."""
    if data.sampling == "grid":
        return (10 * 4**data.icosphere_subdivisions + 2) * math.ceil(360.0 / data.phi_step_deg - 1e-9)
    return data.num_random


def training_rates(data: DataConfig, count: int, *, dtype=None, device=None) -> Tensor:
    """Initial body rates (rad/s) of ``count`` training trajectories from ``data.omega0_deg_s``: ``(3,)`` for one
    rate (shared), else ``(count, 3)``: attitude ``i`` takes rate ``i mod K`` of a list, or a uniform draw per axis
    in a range (generator seeded with ``data.seed``, so the draws are reproducible)."""
    spins = data.omega0_deg_s
    if isinstance(spins, SpinRangeConfig):
        low, high = (torch.tensor(b, dtype=torch.float64) for b in (spins.low, spins.high))
        u = torch.rand(count, 3, generator=torch.Generator().manual_seed(int(data.seed)), dtype=torch.float64)
        deg = low + (high - low) * u
    elif isinstance(spins[0], list):
        rates = torch.tensor(spins, dtype=torch.float64)
        deg = rates[torch.arange(count) % rates.shape[0]]
    else:
        deg = torch.tensor(spins, dtype=torch.float64)
    return torch.deg2rad(deg).to(dtype=dtype, device=device)


def window_samples(scene: Scene, q0: Tensor, rho: Tensor, data: DataConfig, inertia: Tensor,
                   chunk: int = 4096, progress: bool | None = False) -> TrainingSet:
    """Propagate, render and window trajectories into training points (see the module docstring).

    Args:
        scene: renderer with the object's facets and the Sun/observer geometry.
        q0: initial attitudes ``(A, 4)``; each starts with its rate of :func:`training_rates`.
        rho: reflectances, ``(R, 1)`` to render every attitude with every ρ (``N = R · A`` points, ρ-major),
            or ``(A,)`` to render attitude ``i`` with ``rho[i]`` (``N = A``).
        data: the ``data`` config section (ω0 in deg/s, dt, t_span_past, quaternion_sign).
        inertia: principal moments of inertia ``(3,)`` (kg m²).
        chunk: attitudes per rendering chunk (bounds memory).
        progress: show a progress bar (``None``: only when stderr is a terminal).

    Trajectories with a zero-flux sample (no magnitude) are dropped and counted in ``dropped``.
    """
    n_steps = window_steps(data)
    omega0 = training_rates(data, q0.shape[0], dtype=q0.dtype, device=q0.device)
    paired = rho.ndim == 1
    parts: list[TrainingSet] = []
    starts = range(0, q0.shape[0], chunk)
    bar_off = None if progress is None else not progress  # None: tqdm shows the bar on a terminal only
    for start in tqdm(starts, desc="rendering training trajectories", disable=bar_off, unit="chunk"):
        qc = q0[start:start + chunk]
        rc = rho[start:start + chunk] if paired else rho
        wc = omega0 if omega0.ndim == 1 else omega0[start:start + chunk]
        q_hist, _ = propagate(qc, wc, inertia, data.dt_s, n_steps)
        m = scene.magnitude(q_hist, rho=rc.unsqueeze(-1))  # (A, n_steps + 1) or (R, A, n_steps + 1)
        y = m[..., -1]
        ok = torch.isfinite(m).all(-1)
        q_end = q_hist[:, -1].expand(*y.shape, 4)
        parts.append(TrainingSet(q_end[ok], m[..., :-1].mean(-1)[ok], y[ok], rc.expand_as(y)[ok], int((~ok).sum())))
    out = TrainingSet(*(torch.cat([getattr(p, k) for p in parts]) for k in ("q", "m_past", "y", "rho")),
                      dropped=sum(p.dropped for p in parts))
    return _apply_sign_policy(out, data.quaternion_sign)


def window_steps(data: DataConfig) -> int:
    """Samples per window, ``data.t_span_past / data.dt_s`` (``ValueError`` unless a whole number)."""
    steps = data.t_span_past / data.dt_s
    if abs(steps - round(steps)) > 1e-9:
        raise ValueError(f"data.t_span_past ({data.t_span_past:g}) must be a multiple of data.dt_s ({data.dt_s:g})")
    return int(round(steps))


def _apply_sign_policy(ts: TrainingSet, policy: str) -> TrainingSet:
    if policy == "as_is":
        return ts
    canon = quat_canonical(ts.q)
    if policy == "canonical":
        return TrainingSet(canon, ts.m_past, ts.y, ts.rho, ts.dropped)
    return TrainingSet(torch.cat([canon, -canon]), ts.m_past.repeat(2), ts.y.repeat(2), ts.rho.repeat(2), ts.dropped)


def training_scene(cfg: Config, dtype: torch.dtype) -> Scene:
    """The fixed scene the training trajectories are rendered in: ``geometry.kind: fixed`` as given; along a pass
    (``orbit``) the geometry of its first sample — the paper's fixed-geometry assumption, taken where the pass
    starts (a ``body_geometry`` GP is trained over geometries instead)."""
    scene = Scene.from_config(cfg, dtype=dtype, device="cpu")
    return scene.sample(0) if scene.per_sample else scene


def shape_inertia(cfg: Config) -> Tensor:
    """The principal moments of inertia ``(3,)`` (kg m²) of ``cfg.shape``, in ``cfg.dtype`` on the CPU."""
    return torch.tensor(cfg.shape.inertia_kg_m2, dtype=cfg.torch_dtype)


def window_training_set(cfg: Config, progress: bool | None = None) -> TrainingSet:
    """The paper's training set of ``cfg`` (3852 attitudes × 5 ρ = 19260 points), on the CPU in ``cfg.dtype``."""
    dtype = cfg.torch_dtype
    scene = training_scene(cfg, dtype=dtype)
    q0 = initial_attitudes(cfg.data, dtype=dtype)
    rho = torch.tensor(cfg.data.rho_grid, dtype=dtype).unsqueeze(-1)
    return window_samples(scene, q0, rho, cfg.data, shape_inertia(cfg), progress=progress)


def window_heldout_set(cfg: Config) -> TrainingSet:
    """Evaluation data off the training grid: ``data.heldout_size`` random attitudes, each with its own random ρ.

    ρ is uniform in ``[min(rho_grid), max(rho_grid)]`` (almost surely no grid value); attitudes and ρ come from
    the seed ``data.seed + 1``, independent of the training set. The sign policy of the training set applies.
    """
    dtype = cfg.torch_dtype
    scene = training_scene(cfg, dtype=dtype)
    n = cfg.data.heldout_size
    q0 = random_attitudes(n, seed=cfg.data.seed + 1, dtype=dtype)
    gen = torch.Generator().manual_seed(cfg.data.seed + 1)
    lo, hi = min(cfg.data.rho_grid), max(cfg.data.rho_grid)
    rho = lo + (hi - lo) * torch.rand(n, generator=gen, dtype=dtype)
    data = cfg.data if cfg.data.quaternion_sign != "both" else _replace(cfg.data, quaternion_sign="as_is")
    return window_samples(scene, q0, rho, data, shape_inertia(cfg))
