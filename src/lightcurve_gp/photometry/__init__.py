"""Photometry: how bright a facet model looks — shapes, reflectance, rendering and what it cannot tell apart.

* :mod:`.shapes` — facet models (the paper's box-wing, trimesh meshes).
* :mod:`.brdf` — Ashikhmin–Shirley and Lambert reflectance per facet.
* :mod:`.render` — :class:`~.render.Scene`: flux and apparent magnitude for batches of attitudes, fixed geometry or
  one per sample.
* :mod:`.symmetry` — body rotations mapping a facet model onto itself; :mod:`.ambiguity` — the exact ambiguity group
  of a scenario (body × inertial images), derived by rendering; :mod:`.spin_images` — the images of a principal-axis
  spin (pole, period): the half turn and mirror motions, in nats at the noise.
"""
