"""Passes: where the Sun and the observer are, seen from the object, along a real pass.

* :mod:`.orbit` — the object's position from a TLE (SGP4) or Keplerian elements.
* :mod:`.earth` — the Earth's orientation, a WGS84 site and the Sun in the GCRS (astropy / ERFA, no downloads).
* :mod:`.geometry` — :class:`~.geometry.PassGeometry`: per-sample unit vectors, range, elevation and shadow.
"""
