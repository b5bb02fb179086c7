"""From spots to a range you can trust: assignment, the rules of belief and honest statuses.

Each found spot gives a depth (*triangulation*, `edge.triangulation`); the spots of several lasers
are *fused* into the reference laser's range through a local surface model (`edge.fusion`). This
module decides which spots those are, over the zone's frame groups: candidates that fit no laser,
or give inconsistent depths, are dropped; when the reference laser's spot cannot be told apart from
another blob the zone is ``ambiguous``, never a guess.

Statuses and fields follow ``shared/spec/geometry.md`` ("What a zone's result means").
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import cv2
import numpy as np

from edge.deblend import DEBLEND_PX, Placed, place_pair
from edge.errors import ConfigError
from edge.fusion import (
    Fusion,
    apart,
    best_fusion,
    common_grown,
    fuse,
    level_slopes,
    pair_plausible,
    same_blob,
    scatter_grown,
)
from edge.motion import Steadier
from edge.rig import Laser, Rig
from edge.schema import require
from edge.tone import linear_table, require_gamma
from edge.tracks import FrameGroup, Track, follow, in_every_view, pooled_frames
from edge.triangulation import LaserMeasurement, measure
from edge.vision import Candidate, SpotFinder

OK, NO_SPOT, AMBIGUOUS, OUT_OF_RANGE, FAULT = "ok", "no_spot", "ambiguous", "out_of_range", "fault"
STATUSES = (OK, NO_SPOT, AMBIGUOUS, OUT_OF_RANGE, FAULT)
# A faint reference spot (found by the matched filter alone) must be placed at least this well (px).
FAINT_MAX_SIGMA_PX = 0.5
# Of several blobs on the reference's path, one that a single other laser agrees with must be placed
# at least this well (px); see Ranger.range_zone.
LOOSE_WINNER_PX = 1.0
# A reference spot this bright (peak over noise) that shows in one of the zone's views must show in
# the others with at least this share of its light, or the beam is on an edge (Ranger._comes_and_goes).
EDGE_MIN_SNR = 10.0
EDGE_LIGHT_RATIO = 0.3
# Faint reference blobs that some of the zone's views lack give way to the spot the views pooled
# show where it keeps at least this share of the brightest one's SNR (Ranger.range_zone). Pooled,
# what one frame alone holds (JPEG's blocks changing) sinks to about 1/√2 of its SNR (tuning-691
# zone 5, a blob 82 % off: 0.72); a spot that the other view holds a quarter as bright or more,
# too faint there for the finder (speckle dims a spot from one view to the next), keeps about 0.9
# or more. With 1.0, "no weaker", such spots stayed `ambiguous` (seen in one view): 0.9 ranged 14
# more observable zones of tuning 320-959 (wrong `ok` and zones outside 2σ as before) and 5 more of
# tuning 960-1151 (none wrong; one more outside 2σ, not observable).
POOLED_RISE = 0.9
# A blob on the reference's path this near (px: one JPEG block) to one this many times as bright is
# that spot's shoulder (_no_shoulders). Tuning 448-575: 6-10 px and 3-5 × pick the same zones.
SHOULDER_PX = 8.0
SHOULDER_RATIO = 4.0
# Another laser's spot this near (px) may have merged with a spot and pulled it (the centre and
# parallel spots are 4 px apart at 5 m).
MERGE_PX = 6.0
# ... and one that has not moved by this much (px) between two views has no spot merged into it in
# either that is not in the other (nudged views move spots by a few tenths of a pixel at most).
STILL_PX = 1.0
# Another laser's spot this far from the reference's (m) may be on another surface: the sloped
# laser's is 17 cm per metre of range away, the parallel's 4 cm. A faint reference seen in some
# views is not confirmed by such a far one alone (tuning-75, tuning-111: 11 % and 17 % off).
FAR_LASER_M = 0.1
# A fusion of a reference too loose to range alone with one such far spot must be this share of
# max_sigma_fraction or surer (of tuning 0-319's 20 such fusions, the 3 over 10 % off claimed
# 4.5-4.6 %; 15 of the 17 others 1.6-4.2 %).
FAR_PARTNER_SHARE = 0.8
# Nor is one placed looser than this many times max_sigma_fraction on its own, however sure the
# fusion: its own 2σ then spans ±20 % of its depth, wide enough to hold the range of every known
# surface through the far spot, so it cannot tell whether the far spot lies on its surface at all
# (tuning-431 zone 10: a ± 12 % reference and the sloped laser's spot 0.9 m nearer, on another
# surface, made 1.77 m ± 3.8 % where the reference's spot was 2.21 m away). On five tuning sets
# (5 091 observable zones) it refused 2 observable zones that were right, and that one.
FAR_LOOSE_REFERENCE = 2.0
# A weak reference spot that no other laser's spot confirms is looked for where the others' spots
# should be (Ranger._looked_for): a short stretch of each other path, around the depth a known
# surface through the reference gives that beam, give or take this slope across their separation
# (17°: a wall seen a little askew) and 3 σ of the reference's depth. There, in every view pooled,
# a spot is found at this share of the usual thresholds: a few px of path hold few chances of noise.
LOOK_SLOPE = 0.3
# A spot that misses another laser's by at most this many σ of the two is a little off, not on
# another surface: a reference that no other laser confirms, where the others agree on a surface it
# misses so, is fused with them with its own σ grown by half the miss (two lasers outvote one spot).
NEAR_MISS_SIGMAS = 5.0
# A reference that rests on a far laser alone, beside a near laser's spot placed as surely that
# misses it by at most this many σ of the two, is ranged with its σ grown by half the miss (one of
# the two is off); missed by more (another surface, or a wrong blob), a reference too loose alone
# is refused, and one placed well enough alone keeps the fusion's σ. Fewer σ than NEAR_MISS_SIGMAS:
# two spots placed to their σ miss by 3 σ of the two once in hundreds, but a beam's spot beside an
# edge or on a surface seen aslant misses its neighbour's 4 cm away by far more (tuning-1776 zone
# 15: a counter's top at 0.99 m, the parallel spot 15 cm deeper, 3.1 σ; grown by half that, a
# reference 0.03 % off at ± 3.5 % was refused as ± 9 %). On the ten tuning sets, 5 → 3: 13 zones
# more `ok` (12 of them observable), each the reference and the sloped laser's spot, all within 2σ;
# none fewer, no wrong one.
NEAR_WITNESS_SIGMAS = 3.0
# A reference this faint (peak over noise) and placed to worse than LOOSE_WINNER_PX, that only
# spots as faint agree with, is three blobs of the kind noise and JPEG make as often as lasers do,
# one meeting the others' surface by chance: not ranged. (Tuning-1266 zone 0 and tuning-1509 zone
# 11, 4:2:0 JPEG read in luma: a reference of SNR 6-10 placed to 1.4-1.9 px at the near end of its
# path and a partner of SNR 3.5-5.5, 66 % and 98 % short at ± 3.4 and 4.4 %. On seven tuning sets,
# 7 965 observable zones, it refused those and 2 observable zones that were right.) The partners
# were once held to min_snr (6): one of SNR 6.1 at its path's near end let three blobs make
# tuning-2377 zone 0, 90 % short at ± 0.8 %. Held to this, on fourteen tuning sets (about 10 000
# observable zones) it refused 3 more wrong zones, 87-98 % off (tuning-1907 zone 1, tuning-2156
# zone 9 and that one), and 12 observable zones that were right (15 in all).
FAINT_TRIO_SNR = EDGE_MIN_SNR
NEAR_WITNESS_M = FAR_LASER_M  # (a near laser's spot: within this of the reference's)
LOOK_THRESHOLD = 0.8
# Two spots fitted together (edge.deblend) are fitted in a window of this half-size (px).
DEBLEND_WINDOW_PX = 6
# Two lasers' spots found this near each other (in the larger one's RMS radii) are placed
# together (Ranger._together).
TOGETHER_SIZES = 4.0
# A blob off every path (vision.SpotFinder.find's strays) is fitted as two lasers' spots run
# together only this bright (peak over noise): a faint one is noise fitted as two spots as often.
STRAY_MIN_SNR = 10.0
# Their σ is the fit's, from its residual as if white, grown for the residual's correlation (JPEG's
# blocks, demosaicing), with a floor for the two spots' shapes that the fit takes as one Gaussian:
# on the tuning family the fit's own σ was half the error.
DEBLEND_GROW = 2.0
DEBLEND_FLOOR_PX = 0.25


@dataclass(frozen=True)
class RangingConfig:
    """Tuning of the triangulating estimator (``[ranging]`` in the config)."""

    band_halfwidth_px: float = 3.0  # how far from its ideal path a spot is searched for
    path_tolerance_px: float = 1.5  # how far from it a spot may lie and still be that laser's
    # What colour frames are read from (vision.py): red, luma, or auto (luma for 4:2:0 JPEG frames).
    channel: Literal["red", "luma", "auto"] = "auto"
    min_snr: float = 6.0  # a spot's peak over the difference image's noise
    # The spot position error that laser speckle adds, per distinct view (1 σ, px); averaging views
    # with different speckle divides it by √n. The physical floor puts a pointer's at f/1.8-2.8 at
    # 0.06-0.18 px (tuning 320-959: median 0.11, p90 0.16): 0.17 is near the top, for it cannot be
    # told zone by zone (0.12, the median's order, left 2.0 % of `ok` zones outside 2σ, 0.17 1.3 %).
    speckle_px: float = 0.17
    fuse: bool = True  # fuse the other lasers' depths into the reference's range
    # How much a surface may depart from the fused model between two hit points, as a depth change
    # (1 σ) per metre of their separation: a whiteboard on a wall, a skirting board, a book spine.
    # It weighs far lasers less and keeps the fused σ honest when the model is only nearly right.
    surface_sigma_per_m: float = 0.05
    # A reference spot that the other lasers' spots contradict is only believed this strong
    # (peak over noise): a weak blob on the path is as likely a stray light as the laser.
    lone_min_snr: float = 20.0
    # A reference spot that no other laser's spot confirms, because no other laser's spot was found
    # at all, is only believed this strong: in bright, cluttered rooms noise and glare make blobs
    # up to about 10 × the noise, and a dark surface hides the other lasers just as it dims this one.
    alone_min_snr: float = 12.0
    # A range whose σ is more than this fraction of it is not `ok` but `ambiguous`: at 2σ it could
    # be 10 % off, a wrong range for any user (a spot placed to a pixel on a small camera).
    max_sigma_fraction: float = 0.05
    # The tone curve of the frames (1: linear values, as a Pi camera at camera.gamma = 1 gives;
    # about 2.2 for a webcam's sRGB): ranging undoes it first, for a spot's light then adds to the
    # room's in the values, and noise is as the sensor made it.
    frame_gamma: float = 1.0

    def __post_init__(self) -> None:
        require(0.5 <= self.band_halfwidth_px <= 20, "band_halfwidth_px", "must be 0.5-20 px")
        require(0 < self.path_tolerance_px <= self.band_halfwidth_px, "path_tolerance_px",
                "must be positive and at most band_halfwidth_px")
        require(self.min_snr >= 3, "min_snr", "must be >= 3")
        require(self.speckle_px >= 0, "speckle_px", "must be >= 0")
        require(self.surface_sigma_per_m >= 0, "surface_sigma_per_m", "must be >= 0")
        require(self.alone_min_snr >= self.min_snr, "alone_min_snr", "must be >= min_snr")
        require(0 < self.max_sigma_fraction <= 1, "max_sigma_fraction", "must be in (0, 1]")
        require_gamma(self.frame_gamma, "frame_gamma")


@dataclass(frozen=True)
class ZoneResult:
    index: int
    pan_deg: float
    tilt_deg: float
    status: str
    range_m: float | None = None
    sigma_m: float | None = None
    point_m: np.ndarray | None = None
    point_base_m: np.ndarray | None = None
    normal: np.ndarray | None = None
    lasers: dict[str, LaserMeasurement] = field(default_factory=dict)
    detail: str = ""  # why a zone is not ok, for people
    # A fault's part to blame (a HardwareError's `part`), for health and recovery; not published: the
    # detail says it in words.
    part: str | None = None
    # Every laser whose spot the frames showed on its path, whether or not the range used it (one
    # on a nearer surface, a desk top below a wall, is left out of `lasers` but lit): what the
    # health judges a laser by. Not published: `lasers` says what the range is made of.
    spotted: frozenset[str] = frozenset()

    def to_json(self) -> dict:
        def vec(v: np.ndarray | None, nd: int = 5) -> list[float] | None:
            return None if v is None else [round(float(c), nd) for c in v]

        out: dict = {
            "index": self.index,
            "pan_deg": round(self.pan_deg, 6),
            "tilt_deg": round(self.tilt_deg, 6),
            "status": self.status,
            "range_m": None if self.range_m is None else round(self.range_m, 5),
            "sigma_m": None if self.sigma_m is None else round(self.sigma_m, 5),
            "point_m": vec(self.point_m),
            "point_base_m": vec(self.point_base_m),
        }
        if self.normal is not None:
            out["normal"] = vec(self.normal, 4)
        if self.lasers:
            out["lasers"] = {name: m.to_json() for name, m in self.lasers.items()}
        if self.detail:
            out["detail"] = self.detail
        return out


def _no_shoulders(refs: list[LaserMeasurement], sightings: Mapping[int, tuple[int, int]]) -> list[LaserMeasurement]:
    """Of several blobs on the reference's path, all but the shoulders: a blob within a JPEG block
    (SHOULDER_PX) of one SHOULDER_RATIO times as bright, seen in as many views, is that spot's
    ringing or chroma bleed, not a spot of its own. The other lasers' spots ring alike, so their
    shoulders can agree with it on a surface that is not there (tuning-566 zone 15: a blob of SNR
    11 4 px beside one of 84, confirmed by the parallel laser's shoulder and the sloped laser's spot
    on the floor below, won the most lasers' agreement: 11 % short at ± 1 %)."""
    return [m for m in refs if not any(
        b.snr >= SHOULDER_RATIO * m.snr and sightings[id(b)][0] >= sightings[id(m)][0]
        and math.hypot(*(b.pixel - m.pixel).tolist()) < SHOULDER_PX for b in refs)]


def _steady(refs: list[LaserMeasurement], sightings: Mapping[int, tuple[int, int]],
            others: Mapping[str, Sequence[LaserMeasurement]]) -> list[LaserMeasurement]:
    """Of several blobs on the reference's path, those that may be its spot: a laser's spot shows
    in every view of the zone (the unit is only nudged between them), so a blob that shows in
    fewer, and is fainter than one that shows in all, is a ghost, noise or a flicker. Left in, the
    other lasers' blobs can always be found to agree with it: three points fit a plane (tuning-78,
    a faint blob in one view 4 px beside a spot of SNR 120 in both, 11 % off). A blob that is also
    another laser's, where their paths cross, may be that laser's spot, and counts for nothing."""
    steady = [m.snr for m in refs if sightings[id(m)][0] >= sightings[id(m)][1]
              and not any(same_blob(m, o) for ms in others.values() for o in ms)]
    if not steady:
        return refs
    best = max(steady)
    return [m for m in refs if sightings[id(m)][0] >= sightings[id(m)][1] or m.snr > best]


def _moved_to(spot: LaserMeasurement, refs: Sequence[tuple[Track, LaserMeasurement]],
              tracks: Mapping[str, Sequence[Track]]) -> float | None:
    """How far (px) the reference's bright `spot`, missing from some of the zone's views, sits
    from a bright spot of the reference in just those views; None if there is none. The unit is
    nudged between views, which moves no spot of a beam fixed to the camera unless the surface it
    meets changes: on a depth edge the beam lights a near surface in one view and a far one in the
    next, and neither is the zone's range (tuning-317 zone 3: 1.92 m in one view, 2.41 m in the
    other; the other lasers confirmed the far one, 22 % off). Not where another laser's spot is
    beside the other blob in its view: a spot merged with a neighbour's is placed between them.
    `refs`: the reference's tracks, each with its measurement; `tracks`: every laser's."""
    mine = _track_of(spot, [t for t, _ in refs], [m for _, m in refs])
    if spot.snr < EDGE_MIN_SNR or mine is None:
        return None
    for t, m in refs:
        if m is spot or m.snr < EDGE_MIN_SNR or t.views & mine.views:
            continue
        px = t.pixel()
        if any(o is not t and o.views & t.views and math.dist(o.pixel().tolist(), px.tolist()) < MERGE_PX
               for ts in tracks.values() for o in ts if o.laser != spot.laser):
            continue
        return math.dist(px.tolist(), spot.pixel.tolist())
    return None


def _track_of(spot: LaserMeasurement, tracks: Sequence[Track], measured: Sequence[LaserMeasurement]) -> Track | None:
    """The track `spot` was measured from (`measured`: each of `tracks`' measurement)."""
    return next((t for t, m in zip(tracks, measured) if m is spot), None)


def _stood_still(track: Track, view: tuple[float, float], others: set[tuple[float, float]]) -> bool:
    """Was `track`'s spot found in `view` within STILL_PX of where it was found in one of the views
    `others`: the same spot, not moved by another one merged into it there?"""
    here = [c.pixel for c, v in zip(track.found, track.seen) if v == view]
    there = [c.pixel for c, v in zip(track.found, track.seen) if v in others and v != view]
    return any(math.dist(a.tolist(), b.tolist()) < STILL_PX for a in here for b in there)


def _rests_on_a_far_one(fusion: Fusion) -> bool:
    """Is the reference confirmed by one other laser alone, whose spot is FAR_LASER_M or more
    from it (or by none)?"""
    if len(fusion.used) != 2:
        return len(fusion.used) < 2
    return apart(*fusion.used) > FAR_LASER_M


def _one_answer(fusions: Sequence[Fusion]) -> bool:
    """Whether fusions of different reference blobs all give the same range (each pair within
    2σ of their difference)."""
    return all(abs(a.range_m - b.range_m) <= 2.0 * math.hypot(a.sigma_m, b.sigma_m)
               for i, a in enumerate(fusions) for b in fusions[i + 1:])


def _expected(laser: Laser, reference: LaserMeasurement, slopes_y: Sequence[float]) -> tuple[float, float] | None:
    """The inverse depths (lo, hi; 1/m) at which `laser`'s spot lies if the reference's spot is on
    a surface of one of the known slopes dz/dy (`level_slopes`): where its beam meets that surface
    through the reference's point, give or take LOOK_SLOPE across their separation and 3 σ of the
    reference's depth. None where the beam meets none of them ahead of the camera."""
    (px, py, pz), (ox, oy, oz), (dx, dy, dz) = reference.point_m.tolist(), laser.origin_m, laser.direction
    near, far = math.inf, 0.0
    for g in slopes_y:
        den = dz - g * dy
        if abs(den) < 1e-9:
            continue
        t = (pz + g * (oy - py) - oz) / den
        z = oz + t * dz
        if t <= 0 or z <= 0:
            continue
        give = 3.0 * reference.sigma_m + LOOK_SLOPE * math.hypot(ox + t * dx - px, oy + t * dy - py)
        near, far = min(near, z - give), max(far, z + give)
    if far <= 0.0:
        return None
    return 1.0 / far, 1.0 / max(near, 0.05)


def _miss(spot: LaserMeasurement, other: LaserMeasurement, slopes_y: Sequence[float]) -> float:
    """How far (m) `other`'s depth is from `spot`'s carried to it along the likeliest of the known
    slopes dz/dy (`level_slopes`)."""
    dy = other.point_m.item(1) - spot.point_m.item(1)
    return min(abs(other.depth_m - spot.depth_m - g * dy) for g in slopes_y)


def _agreeing_others(others: Mapping[str, Sequence[LaserMeasurement]]) -> bool:
    """Do at least two of the other lasers have spots that lie on one surface?"""
    found = [ms for ms in others.values() if ms]
    for x, y in itertools.combinations(found, 2):
        if any(pair_plausible(a, b) and not same_blob(a, b) for a in x for b in y):
            return True
    return False


def _spotted(cands: Mapping[str, Sequence[LaserMeasurement]]) -> frozenset[str]:
    return frozenset(name for name, ms in cands.items() if ms)



# --- the estimator -----------------------------------------------------------------------------


class Ranger:
    """Ranges zones with the triangulating estimator for one rig."""

    def __init__(self, rig: Rig, config: RangingConfig = RangingConfig()):
        self.rig = rig
        self.config = config
        self._lasers = {laser.name: laser for laser in rig.lasers}
        self.finder = SpotFinder(
            rig, config.band_halfwidth_px, config.min_snr, channel=config.channel,
            path_tolerance_px=config.path_tolerance_px,
        )
        # Set up once, for _deblend on every frame group: the pixels near each laser's path (with
        # a margin for rounding a spot's pixel), so that most spots need no search of the path.
        self._near_path = {name: self.finder.strips.path_mask(name, DEBLEND_PX + 1.5) for name in self.finder.bands}
        self._inv_depths = self.finder.strips.inv_depth_range()
        self.steadier = Steadier(rig.camera, [b.path for b in self.finder.bands.values()])

    def linear(self, groups: Sequence[FrameGroup]) -> list[FrameGroup]:
        """The frame groups with `frame_gamma`'s curve undone: 16-bit values proportional to light
        (and the finder told the first frame as delivered: JPEG or not, and its values' step)."""
        first = groups[0].off[0] if groups[0].off else groups[0].on[0]
        if first.dtype not in (np.uint8, np.uint16):
            raise ConfigError(f"ranging.frame_gamma: only 8- and 16-bit frames can be made linear, not {first.dtype}")
        self.finder.delivered(first)
        lut = linear_table(first.dtype, self.config.frame_gamma)
        # (cv2.LUT: a quarter of numpy's time for 8-bit frames; it takes no other kind)
        apply = (lambda f: cv2.LUT(f, lut)) if first.dtype == np.uint8 else lut.take
        return [replace(g, on=[apply(f) for f in g.on], off=[apply(f) for f in g.off]) for g in groups]

    def steadied(self, groups: Sequence[FrameGroup]) -> list[FrameGroup]:
        """The frame groups with their laser-off frames turned back onto their laser-on frames where
        the room moved between them (`edge.motion`: a rig that turns, or is carried, while it
        ranges); as they are where it did not."""
        out = []
        for g in groups:
            steady = self.steadier.steady(g.on, g.off)
            if steady is None:
                out.append(g)
                continue
            self.finder.told_by(g.off[0])  # (as delivered: interpolation hides JPEG's blocks)
            out.append(replace(g, off=steady))
        return out

    def range_zone(self, index: int, pan_deg: float, tilt_deg: float, groups: Sequence[FrameGroup]) -> ZoneResult:
        """Range one zone from its frame groups; the result is for the zone's pose."""
        rig = self.rig
        ref = rig.reference.name
        if not groups:
            return ZoneResult(index, pan_deg, tilt_deg, FAULT, detail="no usable frame pair")
        if self.config.frame_gamma != 1.0:
            groups = self.linear(groups)
        groups = self.steadied(groups)
        tracks = self._tracks(groups)
        cands = {name: [self._measure(t) for t in ts] for name, ts in tracks.items()}
        # How many of the frame groups each spot showed in, against how many it could have.
        # (A list, not a generator, to sum: the same count, with less overhead for a group or two.)
        sightings = {id(m): (t.shows_in(), sum([name in g.lasers for g in groups]))
                     for name, ts in tracks.items() for t, m in zip(ts, cands[name])}
        refs = self._believable(cands.get(ref, []))
        if all(m.snr < EDGE_MIN_SNR and sightings[id(m)][0] < sightings[id(m)][1] for m in refs):
            # No spot group by group, or faint blobs none of which is one to believe, or none
            # of which shows in every view: pooled, the views may hold the spot well above them,
            # and a blob of one view's frames alone (noise, a JPEG block's change) fades. (The other
            # lasers are not pooled: their faint pooled blobs, noise among them, confirmed a
            # weak reference blob where nothing was: tuning-33, 0.38 m.) The blobs found view by
            # view stay where pooling finds nothing to believe.
            pooled = self._pooled(groups, ref)
            measured = [self._measure(t) for t in pooled]
            # Pooling raises a spot that every view holds (by up to √views) and lowers one that
            # a view alone holds (to about 1/√views): a faint blob of one view is kept only if
            # pooling left it under POOLED_RISE of its SNR.
            strongest = max((r.snr for r in refs), default=0.0)
            if not refs or any(m.snr >= POOLED_RISE * strongest for m in self._believable(measured)):
                tracks[ref], cands[ref] = pooled, measured
                sightings.update(in_every_view(measured, groups))
                refs = self._believable(measured)
        if not refs and self.finder.channel == "luma":
            # Luma holds a third of a red spot's light: a spot it shows nowhere may stand out in
            # red, which JPEG's half-resolution chroma places less well but which is there.
            refs = self._in_red(groups, ref)
            sightings.update(in_every_view(refs, groups))
        if not refs:
            return self._result(index, pan_deg, tilt_deg, NO_SPOT, cands, detail=f"no spot of {ref}")
        others = {n: ms for n, ms in cands.items() if n != ref}
        if len(refs) > 1:
            refs = _steady(_no_shoulders(refs, sightings), sightings, others)
        to_base = rig.camera_to_base(pan_deg, tilt_deg)  # once a zone: the slopes, then the point
        known = level_slopes(to_base)
        if len(refs) == 1:
            chosen = refs[0]
        else:
            # Several blobs on the reference's path: the one the other lasers agree with.
            support = []
            for r in refs:
                f = (best_fusion(rig, r, others, self.config.surface_sigma_per_m, known)
                     if others else fuse(rig, r, ()))
                support.append((len(f.used) - 1, r, f))  # other lasers that agree with it
            support.sort(key=lambda s: -s[0])
            tied = [s for s in support if s[0] == support[0][0]]
            if support[0][0] == 0 or (len(tied) > 1 and not _one_answer([f for _, _, f in tied])):
                return self._result(
                    index, pan_deg, tilt_deg, AMBIGUOUS, cands,
                    detail=f"{len(refs)} blobs on the {ref} laser's path and nothing to tell them apart",
                )
            # Blobs that the same lasers agree with, and whose ranges agree too, give one answer
            # whichever is the spot (a ghost or shoulder beside it, placed loosely): the surest.
            chosen = min(tied, key=lambda s: s[2].sigma_m)[1]
            if support[0][0] < 2 and chosen.sigma_px > LOOSE_WINNER_PX:
                # One other laser's agreement singles out a blob only if the blob is placed well:
                # a blob known to ±1.5 px on a path with others on it meets the other laser's
                # surface by chance as often as not.
                return self._result(
                    index, pan_deg, tilt_deg, AMBIGUOUS, cands,
                    detail=f"{len(refs)} blobs on the {ref} laser's path; the one another laser agrees with "
                           f"is placed only to {chosen.sigma_px:.1f} px",
                )
        fusion = (
            best_fusion(rig, chosen, others, self.config.surface_sigma_per_m, known)
            if self.config.fuse and others
            else fuse(rig, chosen, ())
        )
        if (len(fusion.used) == 1 and self.config.fuse and chosen.snr >= EDGE_MIN_SNR
                and sightings[id(chosen)][0] >= sightings[id(chosen)][1] and _agreeing_others(others)):
            nearly = self._nearly_confirmed(chosen, others, known)
            if nearly is not None:
                fusion = nearly
        if len(fusion.used) == 1 and self.config.fuse and chosen.snr < (
                self.config.lone_min_snr if any(others.values()) else self.config.alone_min_snr
        ) and not _agreeing_others(others):
            # Weak, and alone: about to be refused. Look where the others' spots should be.
            looked = self._looked_for(groups, chosen, others, known)
            if looked is not None:
                fusion, others, pooled_in = looked
                sightings.update(pooled_in)
        fusion = common_grown(scatter_grown(fusion), chosen, self.finder.common_px)
        if len(fusion.used) == 2 and _rests_on_a_far_one(fusion):
            witness = self._near_witness(chosen, fusion, others, known)
            if witness is not None:
                gap, near = witness
                if gap <= NEAR_WITNESS_SIGMAS * math.hypot(chosen.sigma_m, near.sigma_m):
                    # The near laser's spot, 4 cm from the reference's and placed as surely, nearly
                    # agrees: one of the two is off by more than its σ, and the far laser cannot
                    # tell which (tuning-682 zone 5: 12 % long at ± 3.7 %, the parallel 13.7 % short).
                    fusion = replace(fusion, sigma_m=math.hypot(fusion.sigma_m, 0.5 * gap))
                elif self._too_loose_alone(chosen):
                    return self._result(
                        index, pan_deg, tilt_deg, AMBIGUOUS, cands,
                        detail=f"the {ref} spot is placed too loosely to range alone (± {chosen.sigma_m:.2f} m), "
                               f"and the {near.laser} laser's spot beside it says {near.depth_m:.2f} m",
                    )
        doubt = self._doubt(chosen, fusion, others, sightings, groups, tracks, cands)
        if doubt is not None:
            status, detail = doubt
            return self._result(index, pan_deg, tilt_deg, status, cands, detail=detail)
        base = to_base.apply(fusion.point_m)
        return ZoneResult(
            index, pan_deg, tilt_deg, OK, fusion.range_m, fusion.sigma_m, fusion.point_m, base,
            fusion.normal, {m.laser: m for m in fusion.used}, spotted=_spotted(cands),
        )

    def _doubt(self, chosen: LaserMeasurement, fusion: Fusion, others: Mapping[str, Sequence[LaserMeasurement]],
               sightings: Mapping[int, tuple[int, int]], groups: Sequence[FrameGroup],
               tracks: Mapping[str, Sequence[Track]], cands: Mapping[str, Sequence[LaserMeasurement]]
               ) -> tuple[str, str] | None:
        """Why the zone's range, `fusion` through the reference spot `chosen`, is not to be believed:
        (the status, the detail) of the first rule it breaks, each a way a wrong range looked right
        on the tuning family; None where it breaks none. `others`: the other lasers' spots;
        `sightings`: each spot's (groups it showed in, groups its laser was on in)."""
        ref = self.rig.reference.name
        if len(fusion.used) == 1 and any(others.values()):
            # No other laser agrees with the reference spot. A strong spot may still be right (an
            # edge between the beams), but not if the others agree among themselves elsewhere,
            # and not a weak one: a stray light on the path looks just like that.
            agreeing = _agreeing_others(others)
            if agreeing or chosen.snr < self.config.lone_min_snr:
                why = "the other lasers agree on another surface" if agreeing else f"it is weak (SNR {chosen.snr:.0f})"
                return AMBIGUOUS, f"no other laser confirms the {ref} spot and {why}"
        if len(fusion.used) == 1 and not any(others.values()) and chosen.snr < self.config.alone_min_snr:
            return AMBIGUOUS, f"the {ref} spot is weak (SNR {chosen.snr:.0f}) and no other laser's spot was found"
        if (len(fusion.used) > 1 and chosen.snr < FAINT_TRIO_SNR and chosen.sigma_px > LOOSE_WINNER_PX
                and all(m.snr < FAINT_TRIO_SNR for m in fusion.used[1:])):
            return AMBIGUOUS, (f"the {ref} spot is faint (SNR {chosen.snr:.0f}) and placed only to "
                               f"{chosen.sigma_px:.1f} px, and only fainter spots agree with it")
        if (len(fusion.used) == 2 and _rests_on_a_far_one(fusion) and self._too_loose_alone(chosen)
                and (fusion.sigma_m > FAR_PARTNER_SHARE * self.config.max_sigma_fraction * fusion.range_m
                     or self._too_loose_alone(chosen, FAR_LOOSE_REFERENCE))):
            # Too loose to range alone, the reference takes its range from the one other laser that
            # agrees with it, and from the surface model between them: a spot that far away may be
            # on another surface, which a loose reference cannot tell. Such a fusion must be sure
            # enough to leave room for that (tuning-286 zone 0: the sloped laser's spot 0.44 m
            # below, on a wall behind, made a ±8 % reference ±4.5 % and 14 % off), and the
            # reference placed well enough to say whether it is (FAR_LOOSE_REFERENCE).
            return AMBIGUOUS, (f"the {ref} spot is placed too loosely to range alone (± {chosen.sigma_m:.2f} m), "
                               f"and only the {fusion.used[1].laser} laser's spot, {apart(*fusion.used):.2f} m away, "
                               f"agrees with it: {fusion.range_m:.2f} m ± {fusion.sigma_m:.2f} m")
        seen, shown = sightings[id(chosen)]
        if seen < shown and chosen.snr < EDGE_MIN_SNR and (_rests_on_a_far_one(fusion) or all(
                sightings[id(m)][0] < sightings[id(m)][1] for m in fusion.used[1:])):
            # A faint blob in one view, "confirmed" by others that show in that view alone: JPEG
            # turns a textured block's small change into a blob on every path through it, in
            # the one frame it changed in (tuning-42: at 0.27 m, the path's near end).
            return AMBIGUOUS, (f"the {ref} spot is faint (SNR {chosen.snr:.0f}) and shows, as does what confirms "
                               f"it, in {seen} of the zone's {shown} views")
        if seen < shown and self._comes_and_goes(chosen, groups, tracks, _track_of(chosen, tracks.get(ref, ()),
                                                                               cands.get(ref, ()))):
            return AMBIGUOUS, (f"the {ref} spot shows in some of the zone's views and not in others: "
                               "the beam is on an edge")
        moved = _moved_to(chosen, list(zip(tracks.get(ref, ()), cands.get(ref, ()))), tracks) if seen < shown else None
        if moved is not None:
            return AMBIGUOUS, f"the {ref} spot moved {moved:.1f} px between the zone's views: the beam is on an edge"
        if len(fusion.used) == 1 and chosen.snr < self.config.min_snr:
            # Found by the matched filter alone, and no other laser on its surface: a dim spot
            # must be confirmed, for noise and glare make blobs as faint as it.
            return AMBIGUOUS, f"the {ref} spot is faint (SNR {chosen.snr:.1f}) and no other laser confirms it"
        lo, hi = self.rig.range_limits_m
        if not lo <= fusion.range_m <= hi:
            return OUT_OF_RANGE, f"{fusion.range_m:.2f} m is outside the working range {lo}-{hi} m"
        if fusion.sigma_m > self.config.max_sigma_fraction * fusion.range_m:
            return AMBIGUOUS, (f"the {ref} spot is placed too loosely to range: "
                               f"{fusion.range_m:.2f} m ± {fusion.sigma_m:.2f} m")
        return None

    def _too_loose_alone(self, spot: LaserMeasurement, times: float = 1.0) -> bool:
        """Is `spot` placed too loosely to range on its own (σ over `times` × `max_sigma_fraction` of
        its depth)?"""
        return spot.sigma_m > times * self.config.max_sigma_fraction * spot.depth_m

    def _believable(self, refs: list[LaserMeasurement]) -> list[LaserMeasurement]:
        """The reference laser's spots that may be its spot."""
        if any(m.snr >= self.config.min_snr for m in refs):
            # Faint blobs (found by the matched filter alone) count only where nothing brighter is,
            refs = [m for m in refs if m.snr >= self.config.min_snr]
        # and only where they are a spot's size and shape.
        return [m for m in refs if self._believed(m)]

    def _believed(self, spot: LaserMeasurement) -> bool:
        """Is `spot` bright enough to believe, or faint (found by the matched filter alone) and a
        spot's size and shape? A faint blob placed to worse than half a pixel is noise that the
        filter lined up, or a JPEG ghost."""
        return spot.snr >= self.config.min_snr or spot.sigma_px <= FAINT_MAX_SIGMA_PX

    def _comes_and_goes(self, spot: LaserMeasurement, groups: Sequence[FrameGroup],
                        tracks: Mapping[str, Sequence[Track]], mine: Track | None = None) -> bool:
        """Is a bright spot, missing from some of the zone's frame groups, really not there in
        them? The unit is nudged between groups (for new speckle); a beam on a depth edge then
        lights a near surface in one view and a far one, or nothing the camera sees, in the next.
        Speckle alone can dim a small spot to a fifth from one view to the next, so a dim view
        counts only where the finder saw nothing near the spot either (a spot merged with a
        neighbour's is found as that neighbour's) — unless what it saw is another laser's spot
        that stands where it stood beside this one in the views this one shows in (`mine`, its
        track): merged, it would have moved toward it. (On a 320-px camera the parallel spot lies
        within a spot's reach of the centre's at any depth, and excused every centre spot that
        came and went: tuning-2296 zone 7, a beam past an occluding edge, lit in one view, 14 %
        short.)"""
        if spot.snr < EDGE_MIN_SNR:
            return False  # a weak spot comes and goes with the noise
        ref = self.rig.reference.name
        shown = [g for g in groups if ref in g.lasers]
        light = [self.finder.light_at(g.on, g.off, spot.pixel) for g in shown]
        if len(light) < 2 or min(light) >= EDGE_LIGHT_RATIO * max(light):
            return False
        dim = shown[light.index(min(light))].view
        reach = 2.0 * self.finder.spot_radius_px
        apart = mine.views if mine is not None else set()
        return not any(
            dim in t.views and math.dist(t.pixel().tolist(), spot.pixel.tolist()) < reach
            and not (t.laser != ref and _stood_still(t, dim, apart))
            for ts in tracks.values() for t in ts
        )

    def _result(self, index, pan, tilt, status, cands, detail="") -> ZoneResult:
        lasers = {n: ms[0] for n, ms in cands.items() if len(ms) == 1}
        return ZoneResult(index, pan, tilt, status, lasers=lasers, detail=detail, spotted=_spotted(cands))

    def _tracks(self, groups: Sequence[FrameGroup]) -> dict[str, list[Track]]:
        """Each laser's spots, found in each frame group (and deblended), followed across them."""
        found = []
        for group in groups:
            strays: list[Candidate] = []
            found.append((group, self._deblend(group, self.finder.find(group.on, group.off, group.lasers,
                                                                          strays=strays), strays)))
        return follow(found, self._lasers)

    def _looked_for(self, groups: Sequence[FrameGroup], chosen: LaserMeasurement,
                    others: Mapping[str, Sequence[LaserMeasurement]], known: Sequence[float]
                    ) -> tuple[Fusion, dict[str, list[LaserMeasurement]], dict[int, tuple[int, int]]] | None:
        """The fusion of a weak reference spot `chosen`, which none of the `others`' spots
        confirms, with spots found where the others' should be if it is the reference's: on each
        surface of a known slope through it (`known`: a wall, a floor), each other beam meets the
        surface at a depth that `_expected` gives; a short stretch of that laser's path around it,
        in every view pooled, is searched at LOOK_THRESHOLD of the usual thresholds. With the
        others' lists grown by what was found, and each new spot's sightings (every group: pooled).
        None where nothing found there agrees with the reference (best_fusion's χ²).

        A stray light or noise on the reference's path has no partners at the depths it implies:
        only a spot does. (The others' spots are pooled here only where the reference tells where:
        pooled along their whole paths, their faint blobs, noise among them, confirmed a weak
        reference blob where nothing was; tuning-33, 0.38 m.)"""
        grown = {n: list(ms) for n, ms in others.items()}
        pooled_in: dict[int, tuple[int, int]] = {}
        for name, laser in self._lasers.items():
            span = None if name == chosen.laser else _expected(laser, chosen, known)
            pool = pooled_frames(groups, name)
            if span is None or pool is None:
                continue
            on, off, views, lit = pool
            found = self.finder.find(on, off, lit, near={name: span}, threshold=LOOK_THRESHOLD,
                                     wanted=[name]).get(name, [])
            new = [self._measure(Track(name, [c], set(views))) for c in found]
            if new:
                grown.setdefault(name, []).extend(new)
                pooled_in.update(in_every_view(new, groups))
        if not pooled_in:
            return None
        fusion = best_fusion(self.rig, chosen, grown, self.config.surface_sigma_per_m, known)
        lo, hi = self.rig.range_limits_m
        # A reference too loose to range alone is searched around far more widely (3 σ of its
        # depth), where one faint blob meets it by chance: both other lasers must agree with it
        # (one, 1.2 px beside the parallel's spot, made a 6.4 % reference 3.7 % and 8 % off:
        # tuning-213 zone 12).
        need = 3 if self._too_loose_alone(chosen) else 2
        if len(fusion.used) < need or not lo <= fusion.range_m <= hi:
            # (A weak blob beyond the working range stays unconfirmed: the paths' near ends hold
            # blobs alike at one depth, tuning-42 zone 12's at 0.25 m where a wall was 3.07 m off.)
            return None
        return fusion, grown, pooled_in

    def _near_witness(self, chosen: LaserMeasurement, fusion: Fusion, others: Mapping[str, Sequence[LaserMeasurement]],
                      known: Sequence[float]) -> tuple[float, LaserMeasurement] | None:
        """Of the spots of lasers that `fusion` left out whose beams land within NEAR_WITNESS_M of the
        reference's `chosen` spot, those placed at least as surely and bright enough to believe:
        the one nearest to agreeing, with how far its depth is (m) from the reference's carried
        to it along the likeliest of the `known` slopes. None where there is none."""
        used = {m.laser for m in fusion.used}
        near = [m for name, ms in others.items() if name not in used for m in ms
                if apart(chosen, m) <= NEAR_WITNESS_M and m.sigma_m <= chosen.sigma_m]
        return min(self._misses(chosen, near, known), key=lambda gm: gm[0], default=None)

    def _misses(self, chosen: LaserMeasurement, spots: Iterable[LaserMeasurement],
                known: Sequence[float]) -> list[tuple[float, LaserMeasurement]]:
        """How far (m, `_miss`) `chosen` misses each of `spots` that is bright enough to believe."""
        return [(_miss(chosen, m, known), m) for m in spots if self._believed(m)]

    def _nearly_confirmed(self, chosen: LaserMeasurement, others: Mapping[str, Sequence[LaserMeasurement]],
                          known: Sequence[float]) -> Fusion | None:
        """The fusion of a spot `chosen` that no other laser confirms, while the others agree on a
        surface that it misses by NEAR_MISS_SIGMAS or less, with its σ grown by half that miss
        (in quadrature): both of the others must then agree with it, or the near one (within
        NEAR_WITNESS_M), and then the fusion's σ grows by half the miss too (one of the two is
        off). Two lasers that agree outvote one spot placed a little off (JPEG, speckle,
        demosaicing: tuning-632 zone 0, 2.3 % long at ± 1.1 %, the parallel and sloped spots on
        the wall to 1.4 %). None where it misses by more (another surface, or not the spot), or
        where they do not agree with it even so."""
        near = [miss for miss, m in self._misses(chosen, [m for ms in others.values() for m in ms], known)
                if miss <= NEAR_MISS_SIGMAS * math.hypot(chosen.sigma_m, m.sigma_m)]
        if not near:
            return None
        gap = min(near)
        grown = math.hypot(chosen.sigma_m, 0.5 * gap)
        loosened = replace(chosen, sigma_m=grown, sigma_px=chosen.sigma_px * grown / max(chosen.sigma_m, 1e-12))
        fusion = best_fusion(self.rig, loosened, others, self.config.surface_sigma_per_m, known)
        if len(fusion.used) >= 3:
            return fusion
        if len(fusion.used) == 2 and apart(*fusion.used) <= NEAR_WITNESS_M:
            return replace(fusion, sigma_m=math.hypot(fusion.sigma_m, 0.5 * gap))
        return None

    def _in_red(self, groups: Sequence[FrameGroup], name: str) -> list[LaserMeasurement]:
        """`name`'s spots that red shows, in the zone's frame groups pooled (`_pooled`), where the
        finder reads luma and showed none to believe."""
        if not groups or groups[0].on[0].ndim != 3:
            return []  # (grey frames have no red: the same search again would find the same)
        return self._believable([self._measure(t) for t in self._pooled(groups, name, channel="red")])

    def _pooled(self, groups: Sequence[FrameGroup], name: str, channel: str | None = None) -> list[Track]:
        """`name`'s spots in the zone's frame groups pooled, where no group alone showed one to believe
        (`channel`: read from that channel for this search, vision.SpotFinder.find).

        Camera and lasers turn together, so a spot stays at (nearly) the same pixel in every view
        of a zone while the room behind it shifts. The finder takes the mean of the laser-on
        frames less the mean of the laser-off frames: pooled, that is the mean of each group's own
        difference, in which the room cancels, and a spot too faint for any one group stands
        √groups higher above the noise. Each spot found so is one sighting for all the groups.
        (One group pooled is that group, searched already, unless in another channel.)"""
        pool = pooled_frames(groups, name)
        if pool is None or (channel is None and sum(name in g.lasers for g in groups) < 2):
            return []
        on, off, views, lit = pool
        found = self.finder.find(on, off, lit, channel=channel, wanted=[name]).get(name, [])
        return [Track(name, [c], set(views)) for c in found][:3]

    def _deblend(self, group: FrameGroup, found: dict[str, list[Candidate]],
                 strays: Sequence[Candidate] = ()) -> dict[str, list[Candidate]]:
        """Where a laser's spot was not found but its path runs through another laser's blob, the
        blob may hold both spots (far away, or on a small camera): fit them together, each on its
        own path (:mod:`edge.deblend`), and keep both if both are spots. So too for `strays`, blobs
        of a laser's strip off its path (`SpotFinder.find`): where another's path passes too, two
        spots run together lie between the paths, neither on its own (tuning-538 zone 10: the
        centre and parallel spots one blob of SNR 100 on a 352-px camera, and `no_spot`). Last,
        two lasers' spots found close together are placed together (`_together`)."""
        for name in list(found):
            for c in list(found[name]):
                self._split(group, found, name, c)
        for c in strays:
            # (tuning-1082 zone 1: a stray of SNR 9 on a 320-px camera, split, was 14 % short.)
            if c.laser in found and c.snr >= STRAY_MIN_SNR:
                self._split(group, found, c.laser, c)
        self._together(group, found)
        return found

    def _together(self, group: FrameGroup, found: dict[str, list[Candidate]]) -> None:
        """Two lasers' spots found within TOGETHER_SIZES of the larger one's RMS radius of each
        other are placed again together (:mod:`edge.deblend`). Each one's window takes in the
        other's wing, which the windowed centroid's split of the pixels between them does not
        keep out, and a faint spot is pulled toward a bright neighbour (tuning-384 zone 6: the
        `parallel` spot 3.9 px from the `center`'s on a 320-px camera placed 0.7-1 px toward it,
        16 % far, and the zone, the three fused, 10 % far). Farther apart, the centroid places
        a spot better than the fit of two Gaussians of one width (tuning 320-959, each spot's
        depth against the truth: median 2.4 % and 2.8 % at 4-5 radii apart, 7.5 % and 4.2 % at
        2-3)."""
        for name, other in itertools.combinations([n for n in found if found[n]], 2):
            for a, b in itertools.product(list(found[name]), list(found[other])):
                if math.dist(a.pixel.tolist(), b.pixel.tolist()) >= TOGETHER_SIZES * max(a.size_px, b.size_px):
                    continue
                if not any(o is a for o in found[name]) or not any(o is b for o in found[other]):
                    continue  # (one of them already placed with another spot)
                pair = self._pair_at(group, (a.pixel + b.pixel) / 2, (name, other), (a.along, b.along))
                if pair is None:
                    continue
                for old, placed in ((a, pair[0]), (b, pair[1])):
                    found[placed.laser] = [*(o for o in found[placed.laser] if o is not old),
                                           self._deblended(placed, old.noise)]

    def _split(self, group: FrameGroup, found: dict[str, list[Candidate]], name: str, c: Candidate) -> None:
        """`name`'s blob `c` fitted as two spots with another laser's whose path passes it, where
        that finds two; both then replace what `found` held within DEBLEND_PX of `c`."""
        # Only where `other`'s path passes the blob (`_near_path`: one lookup; most blobs lie on no
        # other laser's path, and each saves a call).
        cu, cv = c.pixel.tolist()  # (plain floats: cheaper than numpy's scalars)
        u, v = int(round(cu)), int(round(cv))
        for other in found:
            if other == name:
                continue
            near = self._near_path[other]
            if not (0 <= v < near.shape[0] and 0 <= u < near.shape[1] and near.item(v, u)):
                continue
            pair = self._blob_pair(group, found, name, c, other)
            if pair is None:
                continue
            for placed in pair:
                kept = [o for o in found[placed.laser] if math.dist(o.pixel.tolist(), (cu, cv)) >= DEBLEND_PX]
                found[placed.laser] = [*kept, self._deblended(placed, c.noise)]
            return

    def _deblended(self, placed: Placed, noise: float) -> Candidate:
        """A spot of a pair fitted together, as a candidate: its σ the fit's, grown (DEBLEND_GROW);
        its SNR its fitted peak over `noise`, the pixel noise of the blob it came from, as the
        finder's spots have theirs. (Over the fit's residual, which JPEG's blocks and speckle
        raise well above the pixels' noise, it was 2–5 × lower, and a faint ghost that showed in one
        view outshone the true spot split out of a blob of SNR 35 in both: tuning-1897 zone 8, the
        ghost and two others on a surface at 83° to the beams, 39 % short.)"""
        # (Demosaiced frames: the fit's red values were interpolated, as the finder's.)
        grid, locked = self.finder.grid_px(placed.size_px)
        sigma = math.sqrt((DEBLEND_GROW * placed.sigma_px) ** 2 + DEBLEND_FLOOR_PX**2 + grid**2)
        snr = placed.peak / noise if noise > 0.0 and placed.peak > 0.0 else placed.snr
        return Candidate(placed.laser, placed.pixel, sigma, snr, placed.size_px, placed.inv_depth, 0.0,
                         snr, locked_px=locked, noise=noise)

    def _blob_pair(self, group: FrameGroup, found: Mapping[str, Sequence[Candidate]], name: str, c: Candidate,
                   other: str) -> tuple[Placed, Placed] | None:
        """`name`'s blob `c`, which `other`'s path passes near (`_deblend` has told so from
        `_near_path`), and `other`'s spot in it, fitted together; None where `other` has a spot of
        its own nearby, its path's nearest sample is too far, or the fit finds no two spots."""
        cu, cv = c.pixel.tolist()  # (plain floats: cheaper than numpy's scalars)
        if any(math.dist(o.pixel.tolist(), (cu, cv)) < 2 * DEBLEND_PX for o in found[other]):
            return None
        gap, w_other = self.finder.strips.nearest_on_path(other, c.pixel)
        if gap > DEBLEND_PX:
            return None
        return self._pair_at(group, c.pixel, (name, other), (c.along, w_other))

    def _pair_at(self, group: FrameGroup, centre: np.ndarray, names: tuple[str, str],
                 alongs: tuple[float, float]) -> tuple[Placed, Placed] | None:
        """Two lasers' spots fitted together in the window about `centre` (`edge.deblend`), each
        started at its inverse depth in `alongs`; None where the window leaves the frame, the fit
        finds no two spots, or either is too faint to be a spot."""
        cut = self.finder.window_difference(group.on, group.off, centre, DEBLEND_WINDOW_PX)
        if cut is None:
            return None
        pair = place_pair(cut[0], cut[1], (self._lasers[names[0]], self._lasers[names[1]]), self.rig.camera,
                          alongs, self._inv_depths)
        # The fit's noise is its residual, which JPEG's blocks and speckle raise well above the
        # pixels' noise: half min_snr, for a blob that was found as a spot.
        if pair is None or min(p.snr for p in pair) < 0.5 * self.config.min_snr:
            return None
        return pair

    def _measure(self, track: Track) -> LaserMeasurement:
        views = len(track.views)
        pixel, sigma_px, cov = track.placed(self.config.speckle_px)
        snr = sum([c.snr for c in track.found]) / len(track.found)
        return measure(self._lasers[track.laser], self.rig.camera, pixel, sigma_px, snr, views, cov)
