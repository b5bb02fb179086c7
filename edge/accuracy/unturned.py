"""A moving rig's frames with its motion taken out exactly: what they hold apart from the motion.

A moving rig of the family (``Condition.jolt_deg``) takes each laser-off frame turned from its
laser-on frame, and the recorder keeps each turn in the zone's truth (``off_turn_deg``: one
(pan, tilt) in degrees per laser-off frame, in the zone's order of frames), which no estimator is
told. Whether the reference spot is observable, and what the oracle reaches, are judged on the frames
as recorded with each laser-off frame turned back by its true turn: through the room's depth (a
camera mounted off the unit's axes sees parallax), and resampled bicubic, in the frame's own type
(``edge.motion`` resamples bilinear: bicubic kept a wall's texture 0.43 DN from the frame at the
pose where bilinear kept it 0.97 DN, the floor being what the frames allow). That is what an
estimator that found every turn without error, and resampled well, would have. It
keeps what the motion costs however well it is taken out: a JPEG camera's blocks, which cancel in
the difference of two frames taken from the same pose and not otherwise, and the room's edges
resampled.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import cv2
import numpy as np

from edge import isp
from edge.errors import RecordingError
from edge.ranging import FrameGroup
from edge.recording import FrameRecord, Recording, ZoneRecord
from edge.rig import CameraModel

if TYPE_CHECKING:
    from edge.sim.render import Renderer

TURNS_KEY = "off_turn_deg"


def unturned_groups(recording: Recording, zone: ZoneRecord, renderer: Renderer,
                    scaled: bool = False) -> list[FrameGroup]:
    """The zone's frame groups (as ``edge.replay.zone_groups``) with each laser-off frame turned
    back by its turn in the zone's truth; as recorded where the truth keeps no turn. `renderer` is
    the one that made the frames (its room and true rig); with `scaled`, its sensor's frames were
    scaled as the Pi camera's ISP does (``edge.sim.isp.scale_recording``)."""
    from edge.replay import zone_groups

    turns = (zone.truth or {}).get(TURNS_KEY)
    if not turns:
        return zone_groups(recording, zone)[0]
    dark = [frame for frame in zone.frames if not frame.lasers_on]
    if len(turns) != len(dark):
        raise RecordingError(f"{recording.path}: zone {zone.index}: truth.{TURNS_KEY} has {len(turns)} turns "
                             f"for {len(dark)} laser-off frames")
    turn_of = {id(frame): (float(turn[0]), float(turn[1])) for frame, turn in zip(dark, turns)}
    t_s = truth_time_s(zone)

    def image(zone: ZoneRecord, frame: FrameRecord) -> np.ndarray:
        picture = recording.load_image(zone, frame)
        turn = turn_of.get(id(frame))
        if turn is None or turn == (0.0, 0.0):
            return picture
        view = (zone.pan_deg if frame.pan_deg is None else frame.pan_deg,
                zone.tilt_deg if frame.tilt_deg is None else frame.tilt_deg)
        return turned_back(picture, renderer, view, turn, t_s, scaled)

    return zone_groups(recording, zone, image)[0]


def truth_time_s(zone: ZoneRecord) -> float:
    """The rig's time (s) a simulated zone's truth is taken at: its first frame's start, as the
    recorder takes it (0 for a zone without frames)."""
    return (zone.frames[0].t_start_ns or 0) / 1e9 if zone.frames else 0.0


def turned_back(picture: np.ndarray, renderer: Renderer, view: tuple[float, float], turn: tuple[float, float],
                t_s: float = 0.0, scaled: bool = False) -> np.ndarray:
    """`picture`, taken from `view` (pan, tilt) turned by `turn` (degrees), as seen from `view`:
    each pixel the value where the room it shows fell in the turned picture (bicubic; the
    picture's edges repeated where the turned camera did not see)."""
    pixels, rays = _grid(renderer.rig.camera, *picture.shape[:2], scaled)
    seen = renderer.turned_pixels(view[0], view[1], turn, pixels, t_s, rays)
    su, sv = seen[..., 0], seen[..., 1]
    if scaled:
        su, sv = isp.scaled_pixel(su, sv)
    return cv2.remap(picture, np.asarray(su, np.float32), np.asarray(sv, np.float32), cv2.INTER_CUBIC,
                     borderMode=cv2.BORDER_REPLICATE)


@functools.lru_cache(maxsize=2)
def _grid(camera: CameraModel, height: int, width: int, scaled: bool) -> tuple[np.ndarray, np.ndarray]:
    """A frame's pixels in `camera`'s (the sensor's, for frames the ISP scaled), and their rays: the
    same for every frame of a recording, and most of a turn-back's cost for a distorted lens
    (20 steps undoing its distortion at each of a 1280 × 720 frame's pixels: 0.3 s a frame)."""
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    if scaled:
        u, v = isp.sensor_pixel(u, v)
    pixels = np.stack([u, v], axis=-1)
    return pixels, camera.rays(pixels)
