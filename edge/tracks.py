"""A zone's frame groups, and each laser's spot followed across them.

A zone is ranged from one or more frame groups: laser-on and laser-off frames of one view (the unit
is nudged between views, for new speckle). The finder places spots group by group; `follow` joins
the sightings of one spot into a `Track`, which knows where the spot is over its views and how
surely (`Track.placed`: pixel noise is each sighting's own, speckle is shared within a view).
Pure: `edge.ranging.Ranger` measures and fuses the tracks.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from edge.triangulation import LaserMeasurement
from edge.vision import Candidate

# Sightings in different frame groups are one spot if they are this many σ of their placing apart
# (and at least 1.5 px, at most TRACK_JOIN_MAX_PX).
TRACK_JOIN_SIGMAS = 2.5
TRACK_JOIN_MAX_PX = 3.0


@dataclass(frozen=True)
class FrameGroup:
    """Frames of one pose: laser-on frames (all with the same lasers on) and laser-off frames."""

    on: Sequence[np.ndarray]
    off: Sequence[np.ndarray]
    lasers: tuple[str, ...]
    view: tuple[float, float] = (0.0, 0.0)  # (pan, tilt) the frames were taken at


@dataclass
class Track:
    """One spot of one laser followed across frame groups."""

    laser: str
    found: list[Candidate]
    views: set[tuple[float, float]]
    seen: list[tuple[float, float]] = field(default_factory=list)  # each sighting's view, where told
    # The frame groups it was found in (their indices in the zone), where told: two blobs of one
    # group that join one track are one sighting, not two.
    groups: set[int] = field(default_factory=set)

    def shows_in(self) -> int:
        """In how many of the zone's frame groups the spot was found."""
        return len(self.groups) if self.groups else len(self.found)

    def pixel(self, speckle_px: float = 0.0) -> np.ndarray:
        """Weighted mean position; each sighting's weight counts its speckle too, which dominates
        a bright spot's error and is the same for every sighting."""
        if len(self.found) == 1:
            return self.found[0].pixel
        return self._mean(self._weights(speckle_px))

    def _weights(self, speckle_px: float) -> list[float]:
        return [1.0 / (max(c.sigma_px, 1e-4) ** 2 + speckle_px**2) for c in self.found]

    def _mean(self, w: list[float]) -> np.ndarray:
        total = sum(w)
        return np.array([
            sum(wi * float(c.pixel[0]) for wi, c in zip(w, self.found)) / total,
            sum(wi * float(c.pixel[1]) for wi, c in zip(w, self.found)) / total,
        ])

    def placed(self, speckle_px: float) -> tuple[np.ndarray, float, tuple[float, float, float] | None]:
        """Where the spot is (`pixel`), its σ (px) and its covariance (None where no sighting has
        one): pixel noise is each sighting's own, speckle (`speckle_px` a view) is shared by the
        sightings of one view and averages only over distinct views.

        The variance is that of `pixel`'s weighted mean, not of a plain mean: a sighting that JPEG
        placed only to its 8 px block weighs next to nothing in the mean, and must not loosen what
        the other views placed well (tuning-81 zone 15: σ 5.3 % of the range instead of 2.7 %)."""
        views = len(self.views)
        if len(self.found) == 1:  # (one view, or views pooled into one sighting: `Ranger._pooled`)
            c = self.found[0]
            spread = speckle_px**2 / views
            cov = None if c.cov_px is None else (c.cov_px[0] + spread, c.cov_px[1] + spread, c.cov_px[2])
            return c.pixel, math.sqrt(c.sigma_px**2 + spread), cov
        shared = speckle_px if views > 1 else 0.0  # (one view: speckle moves every sighting alike)
        w = self._weights(shared)
        total = sum(w)
        by_view: dict[tuple[float, float], float] = {}
        for wi, view in zip(w, self.seen):
            by_view[view] = by_view.get(view, 0.0) + wi
        # (Lists, not generators: the same sums, with less overhead for a sighting or two.)
        spread = speckle_px**2 * sum([x * x for x in by_view.values()]) / total**2
        # Where the spot falls on the pixel grid moves every sighting alike (Candidate.locked_px):
        # that part is the weighted mean's of it, not averaged down.
        locked = [min(c.locked_px, c.sigma_px) for c in self.found]
        spread += (sum([wi * lk for wi, lk in zip(w, locked)]) / total) ** 2
        noise = sum([wi * wi * (c.sigma_px**2 - lk * lk) for wi, c, lk in zip(w, self.found, locked)]) / total**2
        cov = None
        if any([c.cov_px is not None for c in self.found]):
            # Each axis on its own: speckle moves a spot alike in every direction.
            parts = [c.cov_px or (c.sigma_px**2, c.sigma_px**2, 0.0) for c in self.found]
            uu, vv, uv = [sum([wi * wi * (p[k] - (lk * lk if k < 2 else 0.0)) for wi, p, lk in zip(w, parts, locked)])
                          / total**2 for k in range(3)]
            cov = (uu + spread, vv + spread, uv)
        return self._mean(w), math.sqrt(noise + spread), cov


def follow(found: Sequence[tuple[FrameGroup, Mapping[str, Sequence[Candidate]]]], names: Iterable[str]
           ) -> dict[str, list[Track]]:
    """Each laser's spots followed across a zone's frame groups: `found` is each group with the
    spots found in it, per laser. A sighting joins a track where it lies as near the track's
    spot as the two placings' noise allows; a track kept shows in at least half the groups where
    its laser was on. At most three per laser (`names`, in order), the brightest first."""
    tracks: dict[str, list[Track]] = {name: [] for name in names}
    expected: dict[str, int] = {name: 0 for name in tracks}
    for k, (group, spots) in enumerate(found):
        for name, cands in spots.items():
            expected[name] += 1
            for cand in cands:
                cu, cv = cand.pixel.item(0), cand.pixel.item(1)  # (plain floats: cheaper than numpy's)
                for track in tracks[name]:
                    p = track.pixel()
                    # The same spot, if as near as the two placings' noise allows (JPEG can
                    # place a faint spot 1.5 px apart in two views), within a spot's size.
                    sure = min(c.sigma_px for c in track.found)
                    near = min(max(1.5, TRACK_JOIN_SIGMAS * math.hypot(cand.sigma_px, sure)), TRACK_JOIN_MAX_PX)
                    if math.hypot(p.item(0) - cu, p.item(1) - cv) < near:
                        track.found.append(cand)
                        track.views.add(group.view)
                        track.seen.append(group.view)
                        track.groups.add(k)
                        break
                else:
                    tracks[name].append(Track(name, [cand], {group.view}, [group.view], {k}))
    # A laser's spot shows in (nearly) every group where the laser was on; a blob that shows
    # once in several groups is flicker, a blinking light or noise.
    out = {}
    for name, ts in tracks.items():
        need = max(1, math.ceil(expected[name] / 2))
        kept = [t for t in ts if t.shows_in() >= need]
        if len(kept) > 1:
            kept.sort(key=lambda t: -sum(c.snr for c in t.found) / len(t.found))
        out[name] = kept[:3]
    return out


def pooled_frames(groups: Sequence[FrameGroup], name: str
                  ) -> tuple[list[np.ndarray], list[np.ndarray], set[tuple[float, float]], list[str]] | None:
    """The laser-on and laser-off frames of every frame group where `name` was on, their views,
    and every laser that was on in any of them (in the order the groups first name them: the
    others' spots lie in the pooled frames too); None where `name` was on in none."""
    mine = [g for g in groups if name in g.lasers]
    if not mine:
        return None
    lit = list(dict.fromkeys(n for g in mine for n in g.lasers))
    return [f for g in mine for f in g.on], [f for g in mine for f in g.off], {g.view for g in mine}, lit


def in_every_view(spots: Sequence[LaserMeasurement], groups: Sequence[FrameGroup]) -> dict[int, tuple[int, int]]:
    """The sightings (shown, of how many) of `spots` found in the zone's frame groups pooled: one
    sighting of every group where their laser was on."""
    out = {}
    for m in spots:
        shown = sum(m.laser in g.lasers for g in groups)
        out[id(m)] = (shown, shown)
    return out
