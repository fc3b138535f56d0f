"""What a user writes, read and checked: UTC times, TLE lines and mesh files.

The one place these inputs are parsed, wherever they come from (a config key, a light-curve file's metadata): the
config layer checks them when a config is loaded (:mod:`lightcurve_gp.config.validate`, :func:`check_mesh`), and
the layers above read them with the same functions (:mod:`lightcurve_gp.passes.orbit` propagates the TLE,
:mod:`lightcurve_gp.photometry.shapes` turns the mesh into facets). Errors are ``ValueError`` naming what was
written; the config layer adds the key (``geometry.tle[1]: line 2 checksum: ...``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import trimesh

from lightcurve_gp.config.schema import ConfigError

__all__ = ["parse_utc", "check_tle", "load_mesh", "check_closed", "check_mesh_file", "check_mesh"]

_TLE_LENGTH = 69


def parse_utc(text: str):
    """An astropy ``Time`` (scale UTC) from an ISO 8601 string; ``ValueError`` naming the text otherwise."""
    # imported here, not at the top: astropy.time took 2.3 s to import (python -X importtime, load 7 on 2 cores),
    # which every command would pay at start, and only orbits and light-curve files need it
    from astropy.time import Time

    if not isinstance(text, str) or not text.strip():
        raise ValueError(f"{text!r} is not a UTC time (ISO 8601, e.g. 2024-03-20T02:00:00)")
    try:
        t = Time(text.strip(), scale="utc")
    except (ValueError, TypeError):
        raise ValueError(f"astropy cannot parse {text!r} as a UTC time (ISO 8601, e.g. 2024-03-20T02:00:00)") from None
    if not t.isscalar:
        raise ValueError(f"{text!r} is not one time")
    return t


def _checksum(line: str) -> int:
    """The TLE checksum of the first 68 characters: the sum of the digits, each '-' counting 1, modulo 10."""
    return sum(int(c) if c.isdigit() else c == "-" for c in line[:68]) % 10


def check_tle(line: str, number: int) -> None:
    """Check one TLE line (``number`` 1 or 2): 69 characters, its line number first, a valid checksum last."""
    if not isinstance(line, str):
        raise ValueError(f"line {number} must be text, got {line!r}")
    line = line.rstrip()
    if len(line) != _TLE_LENGTH:
        raise ValueError(f"line {number} has {len(line)} characters, a TLE line has {_TLE_LENGTH}")
    if not line.startswith(f"{number} "):
        raise ValueError(f"line {number} must start with '{number} ', got {line[:2]!r}")
    if not line[68].isdigit():
        raise ValueError(f"line {number} ends with {line[68]!r}, not a checksum digit")
    if _checksum(line) != int(line[68]):
        raise ValueError(f"line {number} checksum: the line sums to {_checksum(line)}, its last digit is {line[68]}")


def load_mesh(path: str | Path, *, process: bool = False) -> trimesh.Trimesh:
    """Read any triangle mesh trimesh reads (OBJ, STL, PLY, GLB, OFF …) as one ``Trimesh``, metres, body frame.

    Scenes with several geometries are concatenated. ``process=False`` keeps the faces exactly as written.

    Raises:
        FileNotFoundError: no such file.
        ValueError: unreadable file, an empty mesh, zero-area faces, or a surface that is not closed with outward
            normals (:func:`check_closed`).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh file {str(path)!r} does not exist")
    try:
        mesh = trimesh.load(path, force="mesh", process=process)
    except Exception as exc:  # trimesh raises many types for bad files; report them uniformly
        raise ValueError(f"{path}: cannot read mesh: {exc}") from exc
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"{path}: mesh is empty (no triangles)")
    zero = np.flatnonzero(~(mesh.area_faces > 0.0))
    if zero.size:
        raise ValueError(f"{path}: {zero.size} zero-area face(s) (first: face {int(zero[0])}); "
                         "a degenerate triangle has no normal")
    check_closed(mesh, path)
    return mesh


def _point(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{float(x):.6g}" for x in p) + ")"


def check_closed(mesh: trimesh.Trimesh, path: str | Path) -> None:
    """Refuse a mesh that does not bound a volume with outward normals (``ValueError`` naming ``path``).

    The renderer sums the facets lit by the Sun and seen by the observer, with no self-shadowing, so it needs a
    closed surface whose normals point outward: through a hole (an open box, a lone triangle) there are attitudes
    with no such facet and the light curve has zero flux, an infinite magnitude; a triangle wound against its
    neighbours, or all of them wound inward, lights the wrong side. Checked on a copy with coincident vertices
    merged (a face may keep its own vertices, as the box-wing's do): every edge in exactly two triangles
    (closed), traversed once in each direction (consistent winding), and a positive enclosed volume (outward).
    """
    merged = mesh.copy()
    merged.merge_vertices()
    vertices = np.asarray(merged.vertices)
    edges, counts = np.unique(np.asarray(merged.edges_sorted), axis=0, return_counts=True)
    open_edges = edges[counts == 1]
    if open_edges.size:
        a, b = vertices[open_edges[0]]
        raise ValueError(f"{path}: not closed: {len(open_edges)} of its {len(edges)} edges belong to one triangle "
                         f"only (a hole or a missing face; the first from {_point(a)} to {_point(b)}); the renderer "
                         f"has no self-shadowing and needs a closed surface")
    shared = edges[counts > 2]
    if shared.size:
        a, b = vertices[shared[0]]
        raise ValueError(f"{path}: not a closed surface: {len(shared)} edge(s) belong to more than two triangles "
                         f"(the first from {_point(a)} to {_point(b)}); give each part as its own closed surface")
    directed, counts = np.unique(np.asarray(merged.edges), axis=0, return_counts=True)
    twice = directed[counts > 1]
    if twice.size:
        a, b = vertices[twice[0]]
        raise ValueError(f"{path}: inconsistent normals: {len(twice)} edge(s) are traversed in the same direction "
                         f"by both their triangles (the first from {_point(a)} to {_point(b)}), so one of each pair "
                         f"faces inward; wind every triangle counter-clockwise seen from outside")
    a, b, c = np.moveaxis(np.asarray(merged.triangles, dtype=np.float64), 1, 0)
    volume = float(np.einsum("ij,ij->", a, np.cross(b, c))) / 6.0  # signed: positive when the normals point out
    scale = float(np.ptp(vertices, axis=0).max()) ** 3
    if abs(volume) <= 1e-12 * scale:
        raise ValueError(f"{path}: encloses no volume (its triangles lie back to back, a sheet with two sides); give "
                         f"the sheet a thickness")
    if volume < 0.0:
        raise ValueError(f"{path}: the normals point inward (the triangles wind clockwise seen from outside; the "
                         f"enclosed volume is {volume:.6g} m^3); reverse every triangle's winding")


def check_mesh_file(mesh_path: str) -> None:
    """Raise :class:`ConfigError` naming ``shape.mesh_path`` unless the file exists."""
    if not os.path.isfile(mesh_path):
        raise ConfigError(f"shape.mesh_path: {mesh_path!r} does not exist or is not a file")


def check_mesh(mesh_path: str) -> None:
    """Raise :class:`ConfigError` naming ``shape.mesh_path`` unless the file exists, trimesh reads it and it has
    triangles of positive area that close a volume with outward normals."""
    check_mesh_file(mesh_path)
    try:
        load_mesh(mesh_path)
    except (ValueError, OSError) as exc:
        raise ConfigError(f"shape.mesh_path: {' '.join(str(exc).split())}") from None
