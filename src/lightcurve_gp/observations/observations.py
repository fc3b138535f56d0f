"""The observations of one object: the one door from data (simulations, light-curve files) to every estimator.

:class:`Observations` holds ``N`` photometric samples of one object, possibly from several light curves (passes,
nights, stations, apparitions): their times in seconds from one epoch (any spacing, gaps of any length), their
magnitudes and 1σ, the light curve each belongs to and, per sample, the geometry (object → Sun and object →
observer unit vectors, ranges) or none (the config's fixed geometry). A light curve may be *relative*: its zero
point is unknown and every estimator fits one magnitude offset for it (relative photometry, asteroid light
curves). The simulator (:meth:`lightcurve_gp.simulation.scenario.Scenario.observations`) and the file readers
(:mod:`lightcurve_gp.observed.observations_file`) produce it; the filters, the whole-arc MAP and the inversions take
it. Only scoring needs the truth, and it is not here.

Units: seconds, magnitudes, metres; vectors in one inertial frame (GCRS for Earth satellites, ecliptic J2000 for
asteroid data). Tensors are float64 on the CPU until :meth:`Observations.to` moves them.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import torch
from torch import Tensor

__all__ = ["CurveInfo", "Observations", "ObservationsError"]


class ObservationsError(ValueError):
    """Observations that cannot be built: one line naming the field and the problem."""


@dataclass(frozen=True)
class CurveInfo:
    """One light curve of an :class:`Observations`.

    Attributes:
        source: where it came from (a file name, ``"simulation seed 3"``), for messages and tables.
        relative: its zero point is unknown: estimators fit a magnitude offset for it.
        band: the filter band, when known.
    """

    source: str = ""
    relative: bool = False
    band: str | None = None


@dataclass(frozen=True)
class Observations:
    """``N`` samples of one object's brightness (module docstring).

    A batch of ``S`` objects (or noise draws of one) observed at the same times under the same geometry has
    ``mag`` and ``sigma`` of shape ``(S, N)``; a missing sample of one of them is NaN (a file leaves it out).

    Attributes:
        t: sample times ``(N,)`` (s from ``epoch``), non-decreasing, float64.
        mag: magnitudes ``(N,)`` or ``(S, N)``.
        sigma: their 1σ, the shape of ``mag`` (mag, > 0).
        curve: the light curve of each sample ``(N,)`` (int64, indices into ``curves``).
        curves: the light curves (at least one).
        sun: unit vectors object → Sun ``(N, 3)``, or ``None`` for the config's fixed geometry.
        observer: unit vectors object → observer ``(N, 3)``, or ``None``.
        range_m: object–observer distance ``(N,)`` (m), or ``None``.
        sun_range_m: object–Sun distance ``(N,)`` (m), or ``None`` (an Earth satellite: 1 au throughout).
        epoch: ISO UTC time of ``t = 0``, or ``None`` for a simulation on a fixed geometry.
    """

    t: Tensor
    mag: Tensor
    sigma: Tensor
    curve: Tensor
    curves: tuple[CurveInfo, ...] = field(default=(CurveInfo(),))
    sun: Tensor | None = None
    observer: Tensor | None = None
    range_m: Tensor | None = None
    sun_range_m: Tensor | None = None
    epoch: str | None = None

    def __post_init__(self) -> None:
        n = self.t.shape[0] if self.t.ndim == 1 else -1
        if n < 1:
            raise ObservationsError(f"t: expected a 1-D tensor of at least one sample time, got {tuple(self.t.shape)}")
        if self.curve.shape != (n,):
            raise ObservationsError(f"curve: expected shape ({n},), got {tuple(self.curve.shape)}")
        if self.mag.ndim not in (1, 2) or self.mag.shape[-1] != n:
            raise ObservationsError(f"mag: expected shape ({n},) or (S, {n}), got {tuple(self.mag.shape)}")
        if self.sigma.shape != self.mag.shape:
            raise ObservationsError(f"sigma: expected the shape of mag {tuple(self.mag.shape)}, got "
                                    f"{tuple(self.sigma.shape)}")
        if not bool(torch.isfinite(self.t).all()) or (n > 1 and not bool((torch.diff(self.t) >= 0).all())):
            raise ObservationsError("t: sample times must be finite and non-decreasing")
        if bool(torch.isinf(self.mag).any()):
            raise ObservationsError("mag: a magnitude is infinite (a missing sample is NaN or left out)")
        if not bool((self.sigma > 0).all()):
            raise ObservationsError("sigma: every 1-sigma must be > 0 mag")
        if not self.curves:
            raise ObservationsError("curves: at least one light curve")
        if self.curve.dtype != torch.int64 or bool((self.curve < 0).any()) or \
                bool((self.curve >= len(self.curves)).any()):
            raise ObservationsError(f"curve: expected int64 indices into the {len(self.curves)} light curves")
        given = [name for name in ("sun", "observer", "range_m") if getattr(self, name) is not None]
        if given and len(given) != 3:
            missing = next(name for name in ("sun", "observer", "range_m") if getattr(self, name) is None)
            raise ObservationsError(f"{missing}: missing (per-sample geometry needs sun, observer and range_m)")
        for name, shape in (("sun", (n, 3)), ("observer", (n, 3)), ("range_m", (n,)), ("sun_range_m", (n,))):
            value = getattr(self, name)
            if value is not None and value.shape != shape:
                raise ObservationsError(f"{name}: expected shape {shape}, got {tuple(value.shape)}")
        if self.sun_range_m is not None and self.sun is None:
            raise ObservationsError("sun_range_m: given without the per-sample geometry (sun, observer, range_m)")

    # ------------------------------------------------------------------------------------------------ building

    @classmethod
    def single(cls, *, t, mag, sigma, source: str = "", relative: bool = False, band: str | None = None,
               sun=None, observer=None, range_m=None, sun_range_m=None, epoch: str | None = None) -> Observations:
        """One light curve from array-likes (``sigma`` may be a number: every sample's 1σ)."""
        f64 = lambda x: None if x is None else torch.as_tensor(x, dtype=torch.float64).detach().cpu()  # noqa: E731
        t = f64(t)
        n = t.shape[0] if t.ndim == 1 else 0
        sigma = f64(sigma)
        if sigma.ndim == 0:
            sigma = sigma.expand(n).clone()
        return cls(t=t, mag=f64(mag), sigma=sigma, curve=torch.zeros(n, dtype=torch.int64),
                   curves=(CurveInfo(source, relative, band),), sun=f64(sun), observer=f64(observer),
                   range_m=f64(range_m), sun_range_m=f64(sun_range_m), epoch=epoch)

    @classmethod
    def combine(cls, parts: list[Observations], *, offsets_s: list[float] | None = None) -> Observations:
        """Several observations of one object as one: ``parts[i]``'s times shifted by ``offsets_s[i]`` (s from the
        first part's epoch; zeros by default), samples merged in time order, light curves renumbered. Either
        every part has per-sample geometry or none."""
        if not parts:
            raise ObservationsError("combine: no observations given")
        offsets = [0.0] * len(parts) if offsets_s is None else [float(o) for o in offsets_s]
        if len(offsets) != len(parts):
            raise ObservationsError(f"offsets_s: {len(offsets)} offsets for {len(parts)} observations")
        if any(p.batch is not None for p in parts):
            raise ObservationsError("combine: takes the observations of one object each (mag (N,)), not batches")
        with_geometry = [p.has_geometry for p in parts]
        if any(with_geometry) and not all(with_geometry):
            first = parts[with_geometry.index(False)]
            raise ObservationsError(f"{first.curves[0].source or 'observations'}: no per-sample geometry while "
                                    f"the others have it; give every light curve its geometry or none")
        cat = lambda name: None if getattr(parts[0], name) is None else torch.cat(  # noqa: E731
            [getattr(p, name).to(torch.float64).cpu() for p in parts])
        t = torch.cat([p.t.to(torch.float64).cpu() + o for p, o in zip(parts, offsets)])
        shift, curve = 0, []
        for p in parts:
            curve.append(p.curve.cpu() + shift)
            shift += len(p.curves)
        order = torch.sort(t, stable=True).indices
        pick = lambda x: None if x is None else x[order]  # noqa: E731
        sun_range = cat("sun_range_m") if all(p.sun_range_m is not None for p in parts) else None
        return cls(t=t[order], mag=cat("mag")[order], sigma=cat("sigma")[order], curve=torch.cat(curve)[order],
                   curves=tuple(c for p in parts for c in p.curves), sun=pick(cat("sun")),
                   observer=pick(cat("observer")), range_m=pick(cat("range_m")), sun_range_m=pick(sun_range),
                   epoch=parts[0].epoch)

    # ------------------------------------------------------------------------------------------------ views

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def batch(self) -> int | None:
        """``S`` for a batch (``mag (S, N)``), ``None`` for one object."""
        return None if self.mag.ndim == 1 else int(self.mag.shape[0])

    def batched(self) -> Observations:
        """The same samples as a batch (``mag (S, N)``; one object becomes ``S = 1``)."""
        return self if self.batch is not None else replace(self, mag=self.mag[None], sigma=self.sigma[None])

    @property
    def has_geometry(self) -> bool:
        """Per-sample geometry is given (else the config's fixed geometry applies)."""
        return self.sun is not None

    @property
    def relative(self) -> Tensor:
        """Which light curves have an unknown zero point ``(C,)`` (bool)."""
        return torch.tensor([c.relative for c in self.curves], dtype=torch.bool)

    @property
    def span_s(self) -> float:
        """Time from the first to the last sample (s)."""
        return float(self.t[-1] - self.t[0])

    def zero_point_indicator(self) -> Tensor | None:
        """``(N, C')`` indicator (0/1, the magnitudes' dtype) of the samples of each of the ``C'`` relative light
        curves, or ``None`` when every zero point is known."""
        relative = torch.nonzero(self.relative).flatten().to(self.curve.device)
        if relative.numel() == 0:
            return None
        return (self.curve.unsqueeze(-1) == relative).to(self.mag.dtype)

    def counts(self) -> Tensor:
        """Samples per light curve ``(C,)``."""
        return torch.bincount(self.curve.cpu(), minlength=len(self.curves))

    def select(self, index: Tensor) -> Observations:
        """The samples ``index`` (bool mask or increasing integer indices); light curves left empty are dropped and
        the rest renumbered."""
        index = torch.as_tensor(index, device=self.t.device)
        pick = lambda x: None if x is None else x[index]  # noqa: E731
        curve = self.curve[index]
        kept = torch.unique(curve.cpu())
        renumber = torch.full((len(self.curves),), -1, dtype=torch.int64)
        renumber[kept] = torch.arange(kept.numel())
        return replace(self, t=self.t[index], mag=self.mag[..., index], sigma=self.sigma[..., index],
                       curve=renumber.to(curve.device)[curve], curves=tuple(self.curves[int(k)] for k in kept),
                       sun=pick(self.sun), observer=pick(self.observer), range_m=pick(self.range_m),
                       sun_range_m=pick(self.sun_range_m))

    def to(self, *, dtype: torch.dtype | None = None, device=None) -> Observations:
        """The float tensors in ``dtype`` on ``device`` (times stay float64: seconds over years need it)."""
        move = lambda x, d=dtype: None if x is None else x.to(device=device, dtype=d or x.dtype)  # noqa: E731
        return replace(self, t=move(self.t, torch.float64), mag=move(self.mag), sigma=move(self.sigma),
                       curve=self.curve.to(device=device), sun=move(self.sun), observer=move(self.observer),
                       range_m=move(self.range_m), sun_range_m=move(self.sun_range_m))

    def describe(self) -> str:
        """One line: samples, light curves, span and geometry."""
        span = self.span_s
        when = f"{span / 86400:.3g} days" if span >= 86400 else f"{span:.4g} s"
        rel = int(self.relative.sum())
        sigma = torch.median(self.sigma).item()
        return (f"{len(self)} samples in {len(self.curves)} light curve{'s' if len(self.curves) != 1 else ''}"
                f"{f' ({rel} relative)' if rel else ''} over {when}, median 1-sigma {sigma:.3g} mag, "
                f"{'per-sample geometry' if self.has_geometry else 'fixed geometry'}")

