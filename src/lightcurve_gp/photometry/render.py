"""Light curves of a facet model: reflected flux and apparent magnitude for batches of attitudes.

For an attitude ``q`` (inertial → body), body-frame unit vectors to the Sun ``s = A(q) ŝ`` and to the observer
``v = A(q) v̂`` (paper Secs. 2.1–2.2; docs/design.md)::

    f_obs = Σ_facets (c_d + c_s) A (n·s)(n·v)     over facets with n·s > 0 and n·v > 0 (no shadowing)
    m_app = −26.7 − 2.5 log10(f_obs / r_obs²)     r_obs in metres

Speed. Without shadowing, facets with the same normal, tangent axes and material have identical BRDF terms, so
:class:`Scene` merges them once (``grouped=True``, the default; the paper's box-wing has 6 groups for 472
facets) and evaluates one term per group and attitude. ``grouped=False`` evaluates every facet (the
straightforward baseline; both agree to rounding). Attitude batches are processed in chunks of about
``chunk_elements`` (attitude, facet) pairs, so memory stays bounded for any batch size.

Reflectance override. ``rho=`` (a number or a tensor broadcasting against the attitude batch shape) gives every
facet that ρ. ``c_d`` is linear in ρ, so the ρ = 1 diffuse flux is computed once per attitude and scaled: a
ρ grid costs no more than one rendering (``rho`` of shape ``(R, 1, …)`` adds a leading ρ dimension).

Per-object surfaces. ``surface=`` (:class:`~lightcurve_gp.photometry.brdf.Surface`, every field ``(B,)``) gives every
facet of
batch element ``b`` of ``q (B, ..., 4)`` the material ``(ρ_b, F0_b, n_u,b, n_v,b)``: many objects of one shape with
different surfaces render in one call (the facet groups stay valid, they share one material per element).

Zero flux. Where no facet is both lit and visible, ``f_obs = 0`` and there is no magnitude. Policy:
:meth:`Scene.magnitude` returns NaN there (never ``inf``, and with zero, not NaN, gradients elsewhere),
and ``return_visible=True`` also returns the boolean mask ``f_obs > 0``; ``zero_flux="raise"`` raises
``ValueError`` instead. Consumers must drop or reject those samples explicitly (training-set generation drops
such trajectories and counts them; the scenario refuses a truth trajectory with one).
"""

from __future__ import annotations

import copy
import math

import torch
from torch import Tensor

from lightcurve_gp.attitude.rotations import attitude_matrix
from lightcurve_gp.config.schema import Config
from lightcurve_gp.passes.geometry import pass_geometry
from lightcurve_gp.photometry.brdf import Surface, ashikhmin_shirley_projected
from lightcurve_gp.photometry.shapes import Facets, facets_from_config

__all__ = ["Scene", "apparent_magnitude", "SUN_MAGNITUDE"]

#: apparent magnitude of the Sun used by the paper's magnitude formula
SUN_MAGNITUDE = -26.7


def apparent_magnitude(flux: Tensor, r_obs: float | Tensor) -> Tensor:
    """``−26.7 − 2.5 log10(flux / r_obs²)`` with ``r_obs`` in metres (a number, or a tensor broadcasting against
    ``flux``, e.g. ``(T,)`` per sample); zero flux gives ``+inf`` (see :class:`Scene`)."""
    if isinstance(r_obs, Tensor) and r_obs.ndim:
        return SUN_MAGNITUDE - 2.5 * (torch.log10(flux) - 2.0 * torch.log10(r_obs.to(flux)))
    return SUN_MAGNITUDE - 2.5 * (torch.log10(flux) - 2.0 * math.log10(float(r_obs)))


class Scene:
    """A facet model under a Sun and an observer (object at the inertial origin), fixed or per sample.

    Args:
        facets: the object's facets (body frame).
        sun: inertial direction (or position) of the Sun ``(3,)``, or one per sample ``(T, 3)``; normalised here.
        observer: inertial direction (or position) of the observer, shaped like ``sun``; normalised here.
        r_obs: object–observer distance in metres: a number, or ``(T,)`` with per-sample directions.
        grouped: merge facets with identical BRDF terms (see the module docstring).
        chunk_elements: attitudes are processed in chunks of about this many (attitude, facet) pairs
            (the default keeps the per-chunk temporaries in the CPU cache: ~3× faster than 1M-pair chunks).

    Per-sample geometry (a pass, :class:`~lightcurve_gp.passes.geometry.PassGeometry`): attitudes ``q (..., T, 4)`` are
    rendered with the geometry of their sample along the last batch dimension (broadcast like any batch
    dimension); :meth:`sample` gives the fixed scene of one sample.
    """

    def __init__(self, facets: Facets, sun: Tensor, observer: Tensor, r_obs: float | Tensor, *, grouped: bool = True,
                 chunk_elements: int = 1 << 16) -> None:
        self.facets = facets
        self.grouped = bool(grouped)
        self.chunk_elements = int(chunk_elements)
        self._facets_eval = facets.grouped()[0] if grouped else facets
        self._set_geometry(sun, observer, r_obs)

    def _set_geometry(self, sun, observer, r_obs) -> None:
        as_t = lambda x: torch.as_tensor(x, dtype=self.facets.normals.dtype,  # noqa: E731
                                         device=self.facets.normals.device)
        sun, observer = as_t(sun), as_t(observer)
        if sun.ndim == 2:
            self._set_sample_geometry(sun, observer, as_t(r_obs))
            return
        if not float(r_obs) > 0.0:
            raise ValueError(f"r_obs: {float(r_obs):g} m must be > 0")
        for name, vec in (("sun", sun), ("observer", observer)):
            if vec.shape != (3,) or not float(torch.linalg.vector_norm(vec)) > 0.0:
                raise ValueError(f"{name}: expected a non-zero vector of shape (3,), got {vec.tolist()}")
        self.sun = sun / torch.linalg.vector_norm(sun)
        self.observer = observer / torch.linalg.vector_norm(observer)
        half = self.sun + self.observer
        if not float(torch.linalg.vector_norm(half)) > 0.0:
            raise ValueError("sun and observer are in opposite directions: no facet can be lit and visible")
        self.half = half / torch.linalg.vector_norm(half)
        self.r_obs = float(r_obs)

    def _set_sample_geometry(self, sun: Tensor, observer: Tensor, r_obs: Tensor) -> None:
        T = sun.shape[0]
        if sun.shape != (T, 3) or observer.shape != (T, 3) or r_obs.shape != (T,):
            raise ValueError(f"per-sample geometry: expected sun and observer (T, 3) and r_obs (T,), got "
                             f"{tuple(sun.shape)}, {tuple(observer.shape)}, {tuple(r_obs.shape)}")
        if not bool((r_obs > 0).all()):
            raise ValueError("r_obs: every per-sample range must be > 0 m")
        norm = lambda x: torch.linalg.vector_norm(x, dim=-1, keepdim=True)  # noqa: E731
        if not bool((norm(sun) > 0).all() & (norm(observer) > 0).all()):
            raise ValueError("sun, observer: every per-sample vector must be non-zero")
        self.sun, self.observer = sun / norm(sun), observer / norm(observer)
        half = self.sun + self.observer
        if not bool((norm(half) > 0).all()):
            raise ValueError("sun and observer are in opposite directions at some sample: nothing lit and visible")
        self.half = half / norm(half)
        self.r_obs = r_obs

    @property
    def chunk_attitudes(self) -> int:
        """Attitudes rendered per chunk: about ``chunk_elements`` (attitude, facet term) pairs."""
        return max(1, self.chunk_elements // max(1, len(self._facets_eval)))

    @property
    def per_sample(self) -> bool:
        """Whether the geometry is given per sample (``sun (T, 3)``)."""
        return self.sun.ndim == 2

    # ------------------------------------------------------------------------------------------ construction

    @classmethod
    def from_config(cls, cfg: Config, *, rho: float | None = None, grouped: bool = True,
                    dtype: torch.dtype | None = None, device=None) -> "Scene":
        """Scene of ``cfg.shape``, ``cfg.surface`` and ``cfg.geometry`` (km converted to metres): fixed for
        ``geometry.kind: fixed``, per sample along the pass (:func:`~lightcurve_gp.passes.geometry.pass_geometry`) for
        ``orbit``.

        ``rho`` defaults to ``cfg.scenario.rho_true`` (the surface section holds no ρ; pass ``rho=`` to the
        rendering methods to use another); ``dtype``/``device`` default to the config's.
        """
        facets = facets_from_config(cfg, rho=rho, dtype=dtype, device=device)
        if cfg.geometry.kind == "orbit":
            return cls.from_geometry(facets, pass_geometry(cfg), grouped=grouped)
        obs_m = torch.tensor(cfg.geometry.observer_km, dtype=torch.float64) * 1e3
        sun_m = torch.tensor(cfg.geometry.sun_km, dtype=torch.float64) * 1e3
        return cls(facets, sun_m, obs_m, float(torch.linalg.vector_norm(obs_m)), grouped=grouped)

    @classmethod
    def from_geometry(cls, facets: Facets, geometry, *, grouped: bool = True) -> "Scene":
        """Per-sample scene of a :class:`~lightcurve_gp.passes.geometry.PassGeometry`."""
        return cls(facets, geometry.sun, geometry.observer, geometry.range_m, grouped=grouped)

    def with_geometry(self, sun: Tensor, observer: Tensor, r_obs: float | Tensor) -> "Scene":
        """The same facets (and facet groups) under another geometry (fixed or per sample)."""
        scene = copy.copy(self)
        scene._set_geometry(sun, observer, r_obs)
        return scene

    def sample(self, k: int) -> "Scene":
        """The fixed scene of sample ``k`` of a per-sample scene."""
        if not self.per_sample:
            raise ValueError("sample(k) needs a per-sample scene")
        return self.with_geometry(self.sun[k], self.observer[k], float(self.r_obs[k]))

    def to(self, device=None, dtype=None) -> "Scene":
        """Copy on another device and/or dtype (directions are renormalised in the new dtype)."""
        r_obs = self.r_obs.to(device=device, dtype=dtype) if isinstance(self.r_obs, Tensor) else self.r_obs
        return Scene(self.facets.to(device=device, dtype=dtype), self.sun.to(device=device, dtype=dtype),
                     self.observer.to(device=device, dtype=dtype), r_obs, grouped=self.grouped,
                     chunk_elements=self.chunk_elements)

    def with_grouping(self, grouped: bool) -> "Scene":
        """The same scene with facet grouping switched on or off."""
        return Scene(self.facets, self.sun, self.observer, self.r_obs, grouped=grouped,
                     chunk_elements=self.chunk_elements)

    @property
    def phase_angle_deg(self) -> float | Tensor:
        """Sun–object–observer angle in degrees (a tensor ``(T,)`` for a per-sample scene)."""
        if self.per_sample:
            return torch.rad2deg(torch.acos((self.sun * self.observer).sum(-1).clamp(-1.0, 1.0)))
        return math.degrees(math.acos(float(torch.dot(self.sun, self.observer).clamp(-1.0, 1.0))))

    # ------------------------------------------------------------------------------------------ rendering

    def frame(self) -> Tensor:
        """The inertial Sun, observer and half-angle directions as columns ``[ŝ, v̂, ĥ]``: ``(3, 3)``, or ``(T, 3, 3)``
        per sample."""
        return torch.stack([self.sun, self.observer, self.half], -1)

    def body_vectors(self, q: Tensor) -> Tensor:
        """The Sun, observer and half-angle directions in the body frame of attitudes ``q (..., 4)``, as rows
        ``[s_b, v_b, h_b]``: ``(..., 3, 3)`` (``(A(q) [ŝ, v̂, ĥ])ᵀ``; per sample along the last batch dimension of a
        per-sample scene). :meth:`magnitude` of ``q`` equals :meth:`magnitude_of_body` of these."""
        if q.shape[-1] != 4:
            raise ValueError(f"q must have shape (..., 4), got {tuple(q.shape)}")
        return _body_vectors(q, self.frame())

    def _sums(self, q: Tensor | None, unit_rho: bool, surface: Surface | None = None, *,
              body: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Diffuse and specular flux sums ``(batch,)`` of ``q (batch..., 4)`` or of body vectors ``body (batch..., 3,
        3)`` (:meth:`body_vectors`); diffuse at ρ = 1 if ``unit_rho``.

        With ``surface`` (fields ``(B,)``, ``B = batch[0]``) every facet of batch element ``b`` takes that
        element's (F0, n_u, n_v) and the diffuse sum is scaled by its ρ (unless ``unit_rho``).
        """
        fac = self._facets_eval
        given = q if body is None else body
        if body is None and q.shape[-1] != 4:
            raise ValueError(f"q must have shape (..., 4), got {tuple(q.shape)}")
        if body is not None and body.shape[-2:] != (3, 3):
            raise ValueError(f"body vectors must have shape (..., 3, 3), got {tuple(body.shape)}")
        if given.dtype != fac.normals.dtype or given.device != fac.normals.device:
            raise ValueError(f"{'q' if body is None else 'body'} is {given.dtype} on {given.device} but the scene is "
                             f"{fac.normals.dtype} on {fac.normals.device}; use scene.to(...)")
        batch = given.shape[:-1] if body is None else given.shape[:-2]
        flat = q.reshape(-1, 4) if body is None else body.reshape(-1, 3, 3)
        rows = None if surface is None else _surface_rows(surface, batch, given)  # (N, 1) each, or None
        frame = self.frame()  # (3, 3) | (T, 3, 3): columns ŝ, v̂, ĥ
        normals_t, u_t, w_t = fac.normals.T, fac.u.T, fac.v.T  # (3, G)
        area_d = fac.areas if unit_rho or rows is not None else fac.areas * fac.rho
        if self.per_sample:  # v·h does not depend on the attitude; body vectors given need no frame
            frame, vh = self._per_attitude(frame if body is None else None, (self.observer * self.half).sum(-1),
                                           batch)
        else:
            vh = torch.dot(self.observer, self.half)
        chunk = self.chunk_attitudes
        diffuse, specular = [], []
        for start in range(0, flat.shape[0], chunk):
            part = slice(start, start + chunk)
            f0, n_u, n_v = (fac.f0, fac.n_u, fac.n_v) if rows is None else (r[part] for r in rows[1:])
            frame_c, vh_c = (frame if frame is None else frame[part], vh[part]) if self.per_sample else (frame, vh)
            b = flat[part] if body is not None else _body_vectors(flat[part], frame_c)
            s_b, v_b, h_b = b.unbind(-2)  # (N, 3) each
            hn = h_b @ normals_t
            d, c = ashikhmin_shirley_projected(s_b @ normals_t, v_b @ normals_t, hn, vh_c, h_b @ u_t, h_b @ w_t,
                                               1.0, f0, n_u, n_v)  # diffuse at ρ = 1, (N, G)
            d_sum = d @ area_d
            diffuse.append(d_sum if rows is None or unit_rho else d_sum * rows[0][part, 0])
            specular.append(c @ fac.areas)
        if not diffuse:
            empty = flat.new_zeros(0)
            return empty.reshape(batch), empty.reshape(batch)
        return torch.cat(diffuse).reshape(batch), torch.cat(specular).reshape(batch)

    def _per_attitude(self, frame: Tensor | None, vh: Tensor, batch: torch.Size) -> tuple[Tensor | None, Tensor]:
        """Per-sample ``frame (T, 3, 3)`` (or ``None``: not needed) and ``v·h (T,)`` broadcast over
        ``batch = (..., T)`` and flattened to ``(N, 3, 3)`` and ``(N, 1)``."""
        T = vh.shape[0]
        if not len(batch) or batch[-1] != T:
            raise ValueError(f"q of batch shape {tuple(batch)}: a per-sample scene of {T} samples needs them along "
                             f"the last batch dimension")
        frame = None if frame is None else frame.expand(*batch, 3, 3).reshape(-1, 3, 3)
        return frame, vh.expand(batch).reshape(-1, 1)

    def _rho(self, rho, like: Tensor) -> Tensor:
        return torch.as_tensor(rho, dtype=like.dtype, device=like.device)

    def flux_parts(self, q: Tensor, rho=None, *, surface: Surface | None = None) -> tuple[Tensor, Tensor]:
        """Diffuse and specular parts of ``f_obs`` (m²·sr⁻¹ weighted), shapes ``broadcast(q.shape[:-1], rho.shape)``.

        Args:
            q: unit quaternions ``(..., 4)``, scalar last (inertial → body).
            rho: ``None`` for the facets' own ρ, else a number or tensor every facet's ρ is replaced by.
            surface: per-batch-element material (:class:`~lightcurve_gp.photometry.brdf.Surface`, fields ``(B,)``)
            replacing
                every facet's (ρ, F0, n_u, n_v); ``B`` is ``q``'s leading dimension (or 1) and broadcasts against
                ``q (B, ..., 4)``. Exclusive with ``rho``.
        """
        if surface is not None:
            if rho is not None:
                raise ValueError("give rho or surface, not both")
            return self._sums(q, unit_rho=False, surface=surface)
        if rho is None:
            return self._sums(q, unit_rho=False)
        diffuse1, specular = self._sums(q, unit_rho=True)
        rho = self._rho(rho, diffuse1)
        diffuse = rho * diffuse1
        return diffuse, specular.expand_as(diffuse) if specular.shape != diffuse.shape else specular

    def flux(self, q: Tensor, rho=None, *, surface: Surface | None = None) -> Tensor:
        """``f_obs`` of attitudes ``q (..., 4)``, shaped as :meth:`flux_parts`'s parts."""
        diffuse, specular = self.flux_parts(q, rho, surface=surface)
        return diffuse + specular

    def magnitude(self, q: Tensor, rho=None, *, surface: Surface | None = None, zero_flux: str = "nan",
                  return_visible: bool = False):
        """Apparent magnitude ``m_app`` of attitudes ``q (..., 4)`` (see :meth:`flux_parts` for ``rho``, ``surface``).

        Args:
            zero_flux: ``"nan"``: NaN where ``f_obs = 0`` (nothing lit and visible); ``"raise"``: ``ValueError``.
            return_visible: also return the mask ``f_obs > 0``.

        Returns:
            ``m_app`` (mag), or ``(m_app, visible)`` when ``return_visible``. Gradients are finite wherever
            ``visible``.
        """
        if zero_flux not in ("nan", "raise"):
            raise ValueError(f"zero_flux: {zero_flux!r} is not 'nan' or 'raise'")
        return self._magnitude_of_flux(self.flux(q, rho, surface=surface), zero_flux, return_visible)

    def magnitude_of_body(self, body: Tensor, *, surface: Surface | None = None) -> Tensor:
        """Apparent magnitude ``(...)`` (mag; NaN where nothing is lit and visible) from the body-frame directions
        ``body (..., 3, 3)`` of :meth:`body_vectors` — for a caller that composes them more cheaply than from
        quaternions (e.g. ``A(Δ_k q_0) = A(Δ_k) A(q_0)`` along a known motion). ``surface`` as in
        :meth:`flux_parts`; equal to :meth:`magnitude` of the attitudes the vectors came from."""
        diffuse, specular = self._sums(None, unit_rho=False, surface=surface, body=body)
        return self._magnitude_of_flux(diffuse + specular, "nan", False)

    def _magnitude_of_flux(self, f: Tensor, zero_flux: str, return_visible: bool):
        visible = f > 0
        # inside a compiled step (lightcurve_gp.filters.compiled) no read-back: the masked form below
        all_visible = False if torch.compiler.is_compiling() and zero_flux == "nan" else bool(visible.all())
        if not all_visible and zero_flux == "raise":
            raise ValueError(f"{int((~visible).sum())} of {visible.numel()} attitudes have zero flux "
                             "(no facet both lit and visible): no magnitude")
        if all_visible:
            m = apparent_magnitude(f, self.r_obs)
        else:
            m = apparent_magnitude(torch.where(visible, f, torch.ones_like(f)), self.r_obs)
            m = torch.where(visible, m, torch.full_like(m, math.nan))
        return (m, visible) if return_visible else m


def _body_vectors(q: Tensor, frame: Tensor) -> Tensor:
    """``(A(q) [ŝ, v̂, ĥ])ᵀ`` ``(..., 3, 3)``: rows ``s_b, v_b, h_b`` of attitudes ``q (..., 4)`` under the inertial
    directions ``frame`` (columns, ``(3, 3)`` or broadcasting per attitude)."""
    return (attitude_matrix(q) @ frame).transpose(-1, -2)


def _surface_rows(surface: Surface, batch: torch.Size, like: Tensor) -> list[Tensor]:
    """The fields of ``surface`` ``(B,)`` broadcast over ``batch = (B, ...)`` and flattened to ``(N, 1)`` each."""
    lead = batch[0] if len(batch) else 1
    rows = []
    for name, t in zip(Surface._fields, surface):
        t = torch.as_tensor(t, dtype=like.dtype, device=like.device)
        if t.ndim != 1 or t.shape[0] not in (1, lead) or not len(batch):
            raise ValueError(f"surface.{name}: expected shape ({lead},) or (1,) against q of batch shape "
                             f"{tuple(batch)}, got {tuple(t.shape)}")
        rows.append(t.reshape(-1, *([1] * (len(batch) - 1))).expand(batch).reshape(-1, 1))
    return rows
