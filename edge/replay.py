"""Ranging recorded sweeps again (``edge replay``), and scoring them against their truth.

This module reads frames from a recording and hands them, as arrays, to the pure estimators in
:mod:`edge.ranging` (``triangulate``, the default) and :mod:`edge.thesis` (``thesis``).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace

import numpy as np

from edge import thesis
from edge.ranging import (
    FAULT,
    NO_SPOT,
    OK,
    OUT_OF_RANGE,
    STATUSES,
    FrameGroup,
    Ranger,
    RangingConfig,
    ZoneResult,
)
from edge.recording import FrameRecord, Recording, ZoneRecord
from edge.rig import Rig

log = logging.getLogger(__name__)

ESTIMATORS = ("triangulate", "thesis")


def straddles_switch(frame: FrameRecord) -> bool:
    """True when the lasers changed state after this frame's exposure began (recording.md's
    optional timing): such a frame is half lit and must not be used."""
    return (
        frame.laser_switch_ns is not None
        and frame.t_start_ns is not None
        and frame.laser_switch_ns > frame.t_start_ns
    )


def zone_groups(recording: Recording, zone: ZoneRecord,
                image: Callable[[ZoneRecord, FrameRecord], np.ndarray] | None = None) -> tuple[list[FrameGroup], int]:
    """The zone's frames as groups of one pose and one set of lasers; and how many were dropped.
    `image` reads a frame (default: as recorded, `Recording.load_image`)."""
    image = image or recording.load_image
    dropped = 0
    by_view: dict[tuple[float, float], dict[tuple[str, ...], list[np.ndarray]]] = {}
    for frame in zone.frames:
        if straddles_switch(frame):
            dropped += 1
            continue
        view = (
            zone.pan_deg if frame.pan_deg is None else frame.pan_deg,
            zone.tilt_deg if frame.tilt_deg is None else frame.tilt_deg,
        )
        key = tuple(sorted(frame.lasers_on))
        by_view.setdefault(view, {}).setdefault(key, []).append(image(zone, frame))
    all_off = [img for sets in by_view.values() for img in sets.get((), [])]
    groups = []
    for view, sets in by_view.items():
        off = sets.get(()) or all_off  # no background at this pose: the zone's others
        if not off:
            continue
        for lasers, on in sets.items():
            if lasers:
                groups.append(FrameGroup(on, off, lasers, view))
    return groups, dropped


def ranging_for(recording: Recording, config: RangingConfig) -> RangingConfig:
    """`config` for ranging `recording`: with the tone curve its frames came through, where the
    recording says it (its `frame_gamma`), whatever the configuration says."""
    if recording.frame_gamma is None or recording.frame_gamma == config.frame_gamma:
        return config
    return replace(config, frame_gamma=recording.frame_gamma)


class Replayer:
    """Ranges the zones of recordings with one estimator and rig."""

    def __init__(self, rig: Rig, estimator: str = "triangulate",
                 config: RangingConfig = RangingConfig()) -> None:
        if estimator not in ESTIMATORS:
            raise ValueError(estimator)
        self.rig = rig
        self.estimator = estimator
        if estimator == "triangulate":
            self.ranger = Ranger(rig, config)
        else:
            self.thesis = thesis.thesis_rig(rig)
            self.boxes = thesis.masks(rig)

    def zones(self, recording: Recording, progress: Callable[[int, int], None] | None = None) -> Iterator[ZoneResult]:
        for i, zone in enumerate(recording.zones):
            groups, dropped = zone_groups(recording, zone)
            if dropped:
                log.info("zone %d: dropped %d frame(s) exposed across a laser switch", zone.index, dropped)
            if self.estimator == "triangulate":
                result = self.ranger.range_zone(zone.index, zone.pan_deg, zone.tilt_deg, groups)
            else:
                result = self._thesis_zone(zone, groups)
            if progress:
                progress(i + 1, len(recording.zones))
            yield result

    def _thesis_zone(self, zone: ZoneRecord, groups: list[FrameGroup]) -> ZoneResult:
        t = self.thesis
        if not groups:
            return ZoneResult(zone.index, zone.pan_deg, zone.tilt_deg, FAULT, detail="no usable frame pair")
        g = groups[0]  # the thesis took one picture with and one without the lasers
        scale = 65535.0 if g.on[0].dtype == np.uint16 else 255.0
        pos = thesis.spot_positions(g.on[0], g.off[0], self.boxes, 0.08 * scale)
        pc, pp, ps = pos.get(t.center.name), pos.get(t.parallel.name), pos.get(t.sloped.name)
        if pc is None or pp is None or ps is None:
            return ZoneResult(zone.index, zone.pan_deg, zone.tilt_deg, NO_SPOT, detail="a spot is missing")
        r = thesis.thesis_range(t, pc, pp, ps)
        lo, hi = self.rig.range_limits_m
        if not lo <= r <= hi:
            return ZoneResult(zone.index, zone.pan_deg, zone.tilt_deg, OUT_OF_RANGE, detail=f"{r:.2f} m")
        point = t.center.point_at_depth(r)
        base = self.rig.camera_to_base(zone.pan_deg, zone.tilt_deg).apply(point)
        sigma = thesis.thesis_sigma(t, pc, pp, ps)
        return ZoneResult(zone.index, zone.pan_deg, zone.tilt_deg, OK, r, sigma, point, base)


def replay_document(recording: Recording, results: list[ZoneResult]) -> dict:
    """The `edge-ranges/1` document of recording.md."""
    return {"format": "edge-ranges/1", "recording": str(recording.path), "zones": [r.to_json() for r in results]}


# --- scoring ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ZoneScore:
    result: ZoneResult
    truth_m: float | None
    error_m: float | None  # measured − true, for ok zones with truth

    @property
    def relative(self) -> float | None:
        return None if self.error_m is None or not self.truth_m else self.error_m / self.truth_m


@dataclass(frozen=True)
class Score:
    zones: list[ZoneScore]

    @property
    def scored(self) -> list[ZoneScore]:
        return [z for z in self.zones if z.error_m is not None]

    def summary(self) -> dict:
        relative: list[float] = []
        within: list[bool] = []
        for z in self.scored:
            # A true range of 0 m, or an ok zone without a sigma, cannot be scored on that count.
            if z.relative is not None:
                relative.append(abs(z.relative))
            if z.error_m is not None and z.result.sigma_m is not None:
                within.append(abs(z.error_m) <= 2 * z.result.sigma_m)
        rel = np.array(relative)
        counts = {s: sum(z.result.status == s for z in self.zones) for s in STATUSES}
        lo_hi_missed = sum(
            1 for z in self.zones if z.truth_m is not None and z.result.status == NO_SPOT and z.truth_m < 5.0
        )
        return {
            "zones": len(self.zones),
            "statuses": counts,
            "scored": len(rel),
            "median_rel_error": float(np.median(rel)) if rel.size else None,
            "mean_rel_error": float(rel.mean()) if rel.size else None,
            "p95_rel_error": float(np.percentile(rel, 95)) if rel.size else None,
            "max_rel_error": float(rel.max()) if rel.size else None,
            "wrong_ok": int((rel > 0.10).sum()),
            "within_2sigma": float(np.mean(within)) if within else None,
            "no_spot_with_truth_in_range": lo_hi_missed,
        }


def score(recording: Recording, results: list[ZoneResult]) -> Score:
    return score_ranges(results, [(zone.truth or {}).get("range_m") for zone in recording.zones])


def score_ranges(results: list[ZoneResult], truths_m: list) -> Score:
    """Zone results against the true range of each (None where unknown)."""
    out = []
    for result, truth in zip(results, truths_m):
        truth_m = float(truth) if isinstance(truth, (int, float)) and math.isfinite(truth) else None
        error = None
        if result.status == OK and truth_m is not None and result.range_m is not None:
            error = result.range_m - truth_m
        out.append(ZoneScore(result, truth_m, error))
    return Score(out)


def format_score(s: Score) -> str:
    lines = [f"{'zone':>4} {'pan':>8} {'status':<12} {'range m':>8} {'truth m':>8} {'err %':>7} {'sigma m':>8}"
             f" {'err/σ':>6}"]
    for z in s.zones:
        r = z.result
        rng = f"{r.range_m:8.3f}" if r.range_m is not None else f"{'-':>8}"
        tru = f"{z.truth_m:8.3f}" if z.truth_m is not None else f"{'-':>8}"
        err = f"{100 * z.relative:7.2f}" if z.relative is not None else f"{'':>7}"
        sig = f"{r.sigma_m:8.4f}" if r.sigma_m is not None else f"{'':>8}"
        ratio = f"{abs(z.error_m) / r.sigma_m:6.2f}" if z.error_m is not None and r.sigma_m else f"{'':>6}"
        lines.append(f"{r.index:>4} {r.pan_deg:8.2f} {r.status:<12} {rng} {tru} {err} {sig} {ratio}")
    m = s.summary()
    statuses = ", ".join(f"{k} {v}" for k, v in m["statuses"].items() if v)
    lines.append("")
    lines.append(f"zones {m['zones']}: {statuses}")
    if m["scored"]:
        lines.append(
            f"|relative error| over {m['scored']} ok zones: median {100 * m['median_rel_error']:.2f} %, "
            f"mean {100 * m['mean_rel_error']:.2f} %, p95 {100 * m['p95_rel_error']:.2f} %, "
            f"max {100 * m['max_rel_error']:.2f} %"
        )
        lines.append(
            f"wrong ok (>10 %): {m['wrong_ok']}; |error| <= 2 sigma: {100 * m['within_2sigma']:.0f} %; "
            f"no_spot where truth is within 5 m: {m['no_spot_with_truth_in_range']}"
        )
    return "\n".join(lines)
