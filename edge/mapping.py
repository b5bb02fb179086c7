"""The 2D map of a sweep: zone points in the base frame, drawn as a picture, and its error against
a known room (the thesis' step 8).

Pure: zone results (and, when known, the true room's floor plan in the base frame) in, arrays and
numbers out. Writing the files is the caller's business.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from edge.ranging import OK, ZoneResult

Segment = tuple[tuple[float, float], tuple[float, float]]

_BG = (24, 24, 24)
_GRID = (55, 55, 55)
_ROOM = (150, 150, 150)
_RAY = (70, 90, 70)
_POINT = (80, 220, 80)
_MISS = (60, 60, 140)
_TEXT = (220, 220, 220)


@dataclass(frozen=True)
class MapError:
    """Range error of the ok zones against the truth (the thesis reported the mean)."""

    zones: int  # ok zones with a truth
    mean_rel: float
    median_rel: float
    max_rel: float


def map_error(results: Sequence[ZoneResult], truths_m: Sequence[float | None]) -> MapError | None:
    rel = [
        abs(r.range_m - t) / t
        for r, t in zip(results, truths_m)
        if r.status == OK and r.range_m is not None and t
    ]
    if not rel:
        return None
    return MapError(len(rel), float(np.mean(rel)), float(np.median(rel)), float(np.max(rel)))


def draw_map(
    results: Sequence[ZoneResult],
    room: Sequence[Segment] = (),
    size_px: int = 800,
    range_limit_m: float = 5.0,
    title: str = "",
) -> np.ndarray:
    """The map as a BGR image: 1 m grid, the true room (grey, when known), a ray per zone (to its
    point when ok, faint to the range limit when not), the points, and the rig at the centre with
    its pan-0 direction. Base frame: x forward (up in the picture), y left (left in the picture)."""
    pts = [r.point_base_m for r in results if r.status == OK and r.point_base_m is not None]
    reach = max([math.hypot(p[0], p[1]) for p in pts] + [abs(c) for s in room for p in s for c in p] + [1.0])
    half = min(max(reach * 1.1, 1.5), range_limit_m * 1.5)
    scale = (size_px / 2 - 20) / half
    img = np.full((size_px, size_px, 3), _BG, np.uint8)
    c = size_px / 2

    def px(x: float, y: float) -> tuple[int, int]:
        return int(round(c - y * scale)), int(round(c - x * scale))

    for k in range(-int(half), int(half) + 1):
        cv2.line(img, px(k, -half), px(k, half), _GRID, 1)
        cv2.line(img, px(-half, k), px(half, k), _GRID, 1)
    for a, b in room:
        cv2.line(img, px(*a), px(*b), _ROOM, 2, cv2.LINE_AA)
    for r in results:
        pan = math.radians(r.pan_deg)
        if r.status == OK and r.point_base_m is not None:
            end = px(float(r.point_base_m[0]), float(r.point_base_m[1]))
            cv2.line(img, px(0, 0), end, _RAY, 1, cv2.LINE_AA)
        else:
            far = (range_limit_m * math.cos(pan), range_limit_m * math.sin(pan))
            cv2.line(img, px(0, 0), px(*far), _MISS, 1, cv2.LINE_AA)
    for p in pts:
        cv2.circle(img, px(float(p[0]), float(p[1])), 3, _POINT, -1, cv2.LINE_AA)
    # The rig: a small triangle pointing along base x (pan 0).
    tri = np.array([px(0.18, 0), px(-0.08, 0.08), px(-0.08, -0.08)], np.int32)
    cv2.fillPoly(img, [tri], (0, 200, 255), cv2.LINE_AA)
    ok = sum(r.status == OK for r in results)
    lines = [title] if title else []
    lines.append(f"{ok}/{len(results)} zones ok; grid 1 m" + ("; grey: true room" if room else ""))
    for i, text in enumerate(lines):
        cv2.putText(img, text, (10, 22 + 20 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.5, _TEXT, 1, cv2.LINE_AA)
    return img


def room_in_base_frame(segments: Sequence[Segment], base_to_world) -> list[Segment]:
    """World floor-plan segments (e.g. ``Scene.floor_plan``) in the base frame's x, y."""
    to_base = base_to_world.inverse()
    out = []
    for a, b in segments:
        pa = to_base.apply([a[0], a[1], base_to_world.t[2]])
        pb = to_base.apply([b[0], b[1], base_to_world.t[2]])
        out.append(((float(pa[0]), float(pa[1])), (float(pb[0]), float(pb[1]))))
    return out


def results_document(results: Sequence[ZoneResult], **extra) -> dict:
    """Zone results as the JSON saved beside the map (the `edge-ranges/1` shape, plus extras)."""
    return {"format": "edge-ranges/1", **extra, "zones": [r.to_json() for r in results]}
