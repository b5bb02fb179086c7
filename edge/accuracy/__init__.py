"""Ranging accuracy on a family of conditions, against the physical floor (``edge bench accuracy``).

- :mod:`edge.accuracy.conditions`: seeded conditions — camera, sensor, JPEG, light, surfaces, optics,
  speckle, mounting errors — as configuration overrides; tuning and evaluation seeds disjoint.
- :mod:`edge.accuracy.floor`: the Cramér–Rao bound of a spot's position and the speckle floor, as a
  range σ (pure).
- :mod:`edge.accuracy.truth`: the floor of each zone of a simulated recording, from the renderer.
- :mod:`edge.accuracy.score`: zone results against truth and floor, per condition and family (pure).
- :mod:`edge.accuracy.bench`: record, replay and score a family.
"""
