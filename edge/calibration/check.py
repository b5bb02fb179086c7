"""How well a calibration ranges a recording it was not fitted to (``edge calibrate --check``).

Zone i of the check recording shows a flat target squarely at distances_m[i], as a calibration
recording does. Each laser's spot is found as the fit finds it (:mod:`edge.calibration.spots`) and
assigned as the fit does it (:mod:`edge.calibration.fit`), but predicted by the calibrated rig;
spots the calibrated rig puts within DEBLEND_PX of each other are located together from where it
puts them (as ranging, which knows the rig, does: two spots 2 px apart show as one blob, which the
whole-frame search cannot split, and that blob's centre is half a pixel from either); its depth is
the calibrated beam's point nearest to the camera ray through the spot
(:func:`edge.triangulation.triangulate`), and its error is that depth minus the tape-measured
distance. Pure: a recording and a calibration in, numbers out.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from edge.calibration.file import Calibration
from edge.calibration.fit import assign_spots, one_per_zone
from edge.calibration.spots import DEBLEND_PX, SPLIT_PX, closest_gap, clusters, located_together, zone_blobs
from edge.recording import Recording
from edge.rig import Rig
from edge.triangulation import triangulate


@dataclass(frozen=True)
class CheckedZone:
    """One zone of a check: per laser the measured depth and its error (None: no spot)."""

    distance_m: float
    depth_m: dict[str, float | None]
    combined_m: float | None  # the lasers' depths averaged with the weights ranging gives them

    def error(self, laser: str) -> float | None:
        d = self.depth_m.get(laser)
        return None if d is None else d - self.distance_m

    @property
    def combined_error(self) -> float | None:
        return None if self.combined_m is None else self.combined_m - self.distance_m


def check_calibration(recording: Recording, distances_m: Sequence[float], cal: Calibration
                      ) -> list[CheckedZone]:
    """Range every laser's spot in every zone of `recording` (zone i: a flat target squarely at
    distances_m[i]) with `cal`."""
    zones = len(recording.zones)
    d = one_per_zone(zones, distances_m, "--distances: ")
    rig = cal.apply(recording.rig)
    blobs = [zone_blobs(recording, i) for i in range(zones)]
    points = assign_spots(rig, blobs, d)
    for i, dist in enumerate(d):
        _deblend_predicted(recording, i, rig, dist, points, [b.pixel for b in blobs[i]])
    out = []
    for i, dist in enumerate(d):
        depth: dict[str, float | None] = {}
        weights: dict[str, float] = {}
        for laser in rig.lasers:
            px = points[laser.name].get(i)
            if px is None:
                depth[laser.name] = None
                continue
            depth[laser.name] = float(triangulate(laser, rig.camera, px[None, :])[0, 2])
            # A spot's depth error grows as depth² / baseline: ranging weighs lasers so.
            base = math.hypot(laser.origin_m[0], laser.origin_m[1])
            weights[laser.name] = (base / max(dist, 1e-6) ** 2) ** 2
        total = sum(weights.values())
        combined = (sum(w * float(depth[n] or 0.0) for n, w in weights.items()) / total
                    if total > 0 else None)
        out.append(CheckedZone(dist, depth, combined))
    return out


def _deblend_predicted(recording: Recording, i: int, rig: Rig, dist: float,
                       points: dict[str, dict[int, np.ndarray]], blobs: list[np.ndarray]) -> None:
    """In zone i, the spots of lasers that `rig` puts within DEBLEND_PX of each other at `dist`
    and that were not told apart, located together from where it puts them (moved together onto
    the blob they make, when there is one) into `points`."""
    predicted = [rig.camera.project(laser.point_at_depth(dist)) for laser in rig.lasers]
    for members in clusters(predicted, DEBLEND_PX):
        if len(members) < 2:
            continue
        names = [rig.lasers[k].name for k in members]
        got = [p for n in names if (p := points[n].get(i)) is not None]
        if len(got) == len(names) and closest_gap(got) >= SPLIT_PX:
            continue  # found apart already
        seeds = np.array([predicted[k] for k in members])
        centre = seeds.mean(axis=0)
        near = [b for b in blobs if float(np.linalg.norm(b - centre)) < DEBLEND_PX]
        if near:
            seeds += min(near, key=lambda b: float(np.linalg.norm(b - centre))) - centre
        located = located_together(recording, i, names, list(seeds))
        if located is None:
            continue
        for n, p in zip(names, located):
            points[n][i] = p


def check_lines(zones: Sequence[CheckedZone], cal: Calibration) -> list[str]:
    """The check for people: per distance each laser's error, their mean and RMS, the lasers
    combined, and beside them the 1-σ error the calibration predicts for one range there (taken as
    its own frames were);
    then the RMS over all distances against the prediction."""
    names = [ln.name for ln in cal.lasers]
    predicted = cal.range_errors(tuple(z.distance_m for z in zones)) if zones else {}

    def mm(x: float | None) -> str:
        return f"{'-':>9}" if x is None else f"{1000 * x:+9.1f}"

    head = "".join(f"{n:>9}" for n in names)
    lines = [f"{'m':>8}{head}{'mean':>9}{'rms':>9}{'combined':>10}   predicted 1 σ: combined (per laser)"]
    for k, z in enumerate(zones):
        errs = [z.error(n) for n in names]
        got = [e for e in errs if e is not None]
        mean = sum(got) / len(got) if got else None
        rms = math.sqrt(sum(e * e for e in got) / len(got)) if got else None
        pred = ""
        if predicted:
            pred = f"   {_sigma(predicted, 'combined', k)} ({', '.join(_sigma(predicted, n, k) for n in names)})"
        rms_text = f"{'-':>9}" if rms is None else f"{1000 * rms:9.1f}"
        lines.append(f"{z.distance_m:8g}{''.join(mm(e) for e in errs)}{mm(mean)}{rms_text}"
                     f"{mm(z.combined_error):>10}{pred}")
    lines.append(_summary(zones, names, predicted))
    return lines


def _sigma(predicted: dict, name: str, k: int) -> str:
    v = predicted[name].one_range[k] if name in predicted else None
    return "-" if v is None else f"{1000 * v:.1f}"


def _summary(zones: Sequence[CheckedZone], names: list[str], predicted: dict) -> str:
    errs = [e for z in zones for e in (z.error(n) for n in names) if e is not None]
    if not errs:
        return "no laser's spot was found: nothing to check"
    rel = [abs(e) / z.distance_m for z in zones for e in (z.error(n) for n in names) if e is not None]
    rms = math.sqrt(sum(e * e for e in errs) / len(errs))
    line = (f"{len(errs)} spots at {len(zones)} distances: rms error {1000 * rms:.1f} mm, "
            f"mean |error| {100 * sum(rel) / len(rel):.2f} % of range")
    if predicted:
        pred = [p for z_k in range(len(zones)) for n in names
                if zones[z_k].error(n) is not None
                and (p := predicted[n].one_range[z_k] if n in predicted else None) is not None]
        if pred:
            expected = math.sqrt(sum(p * p for p in pred) / len(pred))
            line += f"; predicted rms {1000 * expected:.1f} mm (measured ÷ predicted {rms / expected:.2f})"
    else:
        line += "; the calibration predicts nothing (it keeps no covariance)"
    return line
