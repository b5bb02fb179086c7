"""A contact sheet of a recording: each zone's difference image, for a person to look at.

Each tile is the zone's mean laser-on frame minus its mean laser-off frame in the laser's channel
(red, or grey), stretched so that faint far spots still show, with the true spot positions circled
when the recording carries truth (one colour per laser) and the zone's pose and true range written
underneath.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from edge.recording import Recording, ZoneRecord
from edge.vision import SpotFinder

# Circle colours (BGR) for the 1st, 2nd, 3rd … laser.
_LASER_COLOURS = [(0, 255, 255), (255, 200, 0), (255, 0, 255), (0, 255, 0), (0, 128, 255)]
_LABEL_HEIGHT = 18


def difference_image(recording: Recording, zone: ZoneRecord) -> np.ndarray:
    """Mean of the zone's laser-on frames minus the mean of its laser-off frames, (H, W) float32."""
    def mean(frames) -> np.ndarray:
        channels = [SpotFinder.laser_channel(recording.load_image(zone, f)).astype(np.float32) for f in frames]
        return np.mean(channels, axis=0)

    return mean(zone.on_frames) - mean(zone.off_frames)


def _display_difference(diff: np.ndarray) -> np.ndarray:
    """Stretch a difference image to uint8 so that a person sees the spots, not the noise.

    Flicker leaves a copy of the scene in the difference; the median removes its offset and a
    robust noise floor (3 × MAD) hides the rest, then a square root keeps both saturated near spots
    and faint far ones visible.
    """
    d = diff - float(np.median(diff))
    floor = 3.0 * 1.4826 * float(np.median(np.abs(d))) + 1e-6
    d = np.clip(d - floor, 0.0, None)
    top = float(d.max()) or 1.0
    return (np.sqrt(d / top) * 255.0).astype(np.uint8)


def _tile(recording: Recording, zone: ZoneRecord, width: int) -> np.ndarray:
    grey = _display_difference(difference_image(recording, zone))
    # Spots are a few pixels wide: dilate before shrinking so that they survive it.
    h, w = grey.shape
    scale = width / w
    if scale < 1.0:
        k = max(1, int(round(1.0 / scale)))
        grey = cv2.dilate(grey, np.ones((k, k), np.uint8))
    tile = cv2.cvtColor(
        cv2.resize(grey, (width, int(round(h * scale))), interpolation=cv2.INTER_AREA),
        cv2.COLOR_GRAY2BGR,
    )
    truth = zone.truth or {}
    names = list(recording.rig.laser_names)
    for name, spot in (truth.get("lasers") or {}).items():
        pixel = spot.get("pixel") if isinstance(spot, dict) else None
        if not pixel:
            continue
        colour = _LASER_COLOURS[names.index(name) % len(_LASER_COLOURS)] if name in names else (0, 0, 255)
        centre = (int(round(pixel[0] * scale)), int(round(pixel[1] * scale)))
        # Solid ring: visible spot; thin ring: where it falls but the camera cannot see it.
        cv2.circle(tile, centre, 9, colour, 2 if spot.get("visible") else 1, cv2.LINE_AA)
    label = f"z{zone.index} pan {zone.pan_deg:.1f}"
    if truth.get("range_m") is not None:
        label += f"  {truth['range_m']:.2f} m"
    band = np.zeros((_LABEL_HEIGHT, tile.shape[1], 3), np.uint8)
    cv2.putText(band, label, (3, 13), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (230, 230, 230), 1, cv2.LINE_AA)
    return np.vstack([tile, band])


def contact_sheet(recording: Recording, columns: int = 8, tile_width: int = 200) -> np.ndarray:
    """One BGR uint8 image with a tile per zone, in zone order, `columns` per row."""
    tiles = [_tile(recording, zone, tile_width) for zone in recording.zones]
    rows = math.ceil(len(tiles) / columns)
    th, tw = tiles[0].shape[:2]
    gap = 2
    sheet = np.full((rows * (th + gap) + gap, columns * (tw + gap) + gap, 3), 40, np.uint8)
    for i, tile in enumerate(tiles):
        r, c = divmod(i, columns)
        y, x = gap + r * (th + gap), gap + c * (tw + gap)
        sheet[y : y + th, x : x + tw] = tile
    return sheet
