"""A family of simulated conditions: what real cameras and rooms vary, drawn per recording.

One simulator setting says little about a device in someone else's room, with someone else's camera.
A condition draws, from its seed, everything the simulator can vary that real set-ups do:

- the camera: resolution (320 × 240 to 1280 × 720), field of view (50–75°), principal point and
  barrel distortion; the sensor's full well, read noise and ADC; grey or colour, with an ideal
  3-colour sensor or a Bayer filter and one of OpenCV's demosaicing methods; lossless frames
  (8- or 16-bit) or JPEG of quality 50–95 with 4:2:0 or 4:4:4 chroma; JPEG colour frames (a
  webcam's) through a colour matrix like a real sensor's, which a webcam's ISP applies and nobody
  can turn off (lossless colour frames stand for the Pi camera, whose matrix edge turns off); and,
  for half of the lossless colour cameras at 640 × 480, the default rig's own pipeline
  (:mod:`edge.isp`, :mod:`edge.sim.isp`): a Bayer sensor read out at 1640 × 1232, demosaiced there and scaled by its
  ISP to 640 × 480;
- the light: laser power and room light each ¼–4 × the configured, and the exposure someone (or an
  auto-exposure) chose for the room: a white wall under its light fills 25–80 % of the full well,
  within 0.5–30 ms (a fixed exposure in a bright room would clip every wall: nothing to measure);
- the room: the scene (office, kitchen), every surface's albedo ×0.1–1.2 (so about 0.03–0.9 for the
  usual materials) and texture contrast ×0.3–3, extra gloss on half of the rooms;
- the optics: f-number, focus distance (defocus), lens blur; the speckle's contrast and grain and
  how far a spot must move for a new pattern;
- how the rig was built (``sim.rig_error``): lasers tilted up to 0.3° and shifted up to 1 mm, the
  focal length off by up to 1 %;
- where the zones look: pans all round, tilts from 30° down to 15° up;
- whether the rig moves between its frames: for 30 % of the rigs (on a robot, worn, or ringing
  after a move) a turn of 0.02–1° between each laser-on frame and the laser-off frame after it
  (``sim.sway.jolt_deg``); the bench judges such a rig on its frames with each true turn taken out
  (:mod:`edge.accuracy.unturned`);
- how the sensor samples the room: for half of the rigs each pixel averages it over its area
  (``sim.optics.pixel_area``), for the rest it is sampled at each pixel's centre.

Ranging is configured as the base configuration says; a condition changes only the simulator, the
camera model and the sweep's poses. A condition is a set of ``--set`` overrides, so any of them can
be recorded again by hand: ``edge sim record --out DIR --set …``.

**Tuning and evaluation seeds are disjoint by construction.** Condition i of the ``tuning`` family
has seed 1 000 000 + i, of the ``evaluation`` family 2 000 000 + i (i < 1 000 000): tune estimators
on ``tuning`` only, and report ``evaluation``, which no tuning may ever see.

Pure: numbers in, strings out.
"""

from __future__ import annotations

import json
import math
from dataclasses import MISSING, dataclass, fields, replace
from typing import Any, Literal

import numpy as np

from edge import isp
from edge.rig import CameraModel

Family = Literal["tuning", "evaluation"]
FAMILIES: dict[str, int] = {"tuning": 1_000_000, "evaluation": 2_000_000}
FAMILY_SIZE = 1_000_000
SCENES = ("office", "kitchen")
# (width, height) of the cameras drawn, and how often: Pi cameras binned, webcams, an HD webcam.
RESOLUTIONS = ((320, 240), (352, 288), (640, 480), (800, 600), (1280, 720))
RESOLUTION_WEIGHTS = (0.15, 0.15, 0.4, 0.15, 0.15)
_SALT = 0xACC  # separates the conditions' draws from any other use of their seed
# Real sensors' colour matrices at their tuning's lowest and highest colour temperature (about 2500-3000 K
# and 7400-8000 K), rows R', G', B' of columns R, G, B: libcamera's Raspberry Pi tuning files
# (src/ipa/rpi/vc4/data/<sensor>.json, rpi.ccm), rounded. A webcam's ISP mixes its channels as
# strongly; a JPEG colour condition takes one sensor's matrix at a colour temperature between the two.
SENSOR_COLOUR_MATRICES: dict[str, tuple[tuple[float, ...], tuple[float, ...]]] = {
    "imx219": ((2.121, -0.525, -0.596, -0.853, 2.804, -0.951, -0.269, -1.148, 2.417),
               (2.212, -0.532, -0.679, -0.579, 3.079, -1.5, -0.277, -0.733, 2.01)),
    "imx477": ((1.975, -0.714, -0.26, -0.435, 2.098, -0.662, -0.048, -0.846, 1.895),
               (2.307, -0.973, -0.334, -0.309, 2.328, -1.019, -0.178, -0.559, 1.737)),
    "ov5647": ((1.882, -0.262, -0.619, -0.638, 2.115, -0.477, -0.135, -0.997, 2.133),
               (2.066, -0.392, -0.674, -0.509, 2.275, -0.766, -0.14, -0.661, 1.801)),
    "imx708": ((1.721, -0.46, -0.262, -0.3, 1.569, -0.269, 0.151, -1.133, 1.982),
               (1.414, -0.211, -0.203, -0.176, 1.717, -0.541, 0.013, -0.631, 1.618)),
    "imx296": ((1.951, -0.574, -0.376, -0.469, 1.867, -0.397, 0.08, -1.141, 2.061),
               (2.375, -0.831, -0.545, -0.483, 2.843, -1.36, -0.212, -0.665, 1.877)),
    "imx378": ((1.426, -0.205, -0.221, -0.477, 1.82, -0.343, 0.019, -0.86, 1.842),
               (1.546, -0.204, -0.342, -0.317, 2.226, -0.908, -0.1, -0.659, 1.759)),
}
_POSES_SALT = 0x9053
ISP_SHARE = 0.5  # of the lossless colour cameras at 640 × 480: the Pi camera's ISP-scaled frames
ISP_DEMOSAICS = ("bilinear", "vng", "ea")  # for an ISP condition drawn as a 3-colour sensor
# Of the rigs, this share moves between its frames (on a robot, worn, or ringing after a move), by
# a turn in this range (degrees): the rest are still, on a shelf or a tripod.
MOVING_SHARE = 0.3
JOLT_DEG = (0.02, 1.0)
# Of the rigs, this share's sensor sees the room averaged over each pixel's area
# (sim.optics.pixel_area); the rest sample it at each pixel's centre, as the simulator first did.
# Real sensors lie between: a pixel integrates over its area, and without an anti-aliasing filter
# (the Pi camera has none) a texture finer than it still folds into its frames.
AREA_SHARE = 0.5


@dataclass(frozen=True)
class Condition:
    """One drawn set-up. Scales (×) are relative to the base configuration's values."""

    family: str
    index: int
    seed: int  # the simulator's seed (noise, speckle, the rig's errors); unique over both families
    scene: str
    width: int
    height: int
    fx: float  # fy = fx
    cx: float
    cy: float
    k1: float  # radial distortion (OpenCV's k1; negative: barrel)
    colour: bool
    bayer: Literal["none", "bilinear", "vng", "ea"]
    jpeg_quality: int  # 0: lossless
    jpeg_chroma: Literal["4:2:0", "4:4:4"]
    output_bits: Literal[8, 16]
    adc_bits: int
    full_well_e: float
    read_noise_e: float
    laser_power: float  # ×
    room_light: float  # ×
    fill: float  # the exposure fills this much of the full well with a white wall's room light
    albedo_scale: float
    texture_scale: float
    extra_gloss: float
    f_number: float
    focus_m: float
    psf_sigma_px: float
    speckle: float  # × the modelled contrast
    speckle_grain: float
    speckle_cell_m: float
    laser_angle_deg: float  # 1 σ, as sim.rig_error takes them
    laser_offset_m: float
    focal_scale: float
    # An ISP's colour matrix (sim.sensor.colour_matrix; empty: none). Drawn last: families kept
    # before it was drawn read as none.
    colour_matrix: tuple[float, ...] = ()
    # The frames are the Pi camera's: its Bayer sensor (`bayer`) read out at 1640 × 1232 and scaled
    # by its ISP to the condition's 640 × 480 (edge.isp); the camera above is the 640 × 480 one.
    # Drawn after the colour matrix: families kept before read as False.
    isp: bool = False
    # The rig turned between each laser-on frame and the laser-off frame after it by this much
    # (degrees), each time in a direction of its own (sim.sway.jolt_deg): a robot that turns, a
    # walker's head, a head still ringing. Drawn last: families kept before read as still (0).
    jolt_deg: float = 0.0
    # The sensor integrates the room over each pixel's area (sim.optics.pixel_area). Drawn last:
    # families kept before read as sampled at pixels' centres (False).
    pixel_area: bool = False

    @property
    def name(self) -> str:
        return f"{self.family}-{self.index}"

    def poses(self, zones: int) -> list[tuple[float, float]]:
        """Where the sweep's `zones` look (pan, tilt in degrees); the first n are the same for any
        `zones` ≥ n, so that a short run is a prefix of a long one."""
        rng = np.random.default_rng([self.seed, _POSES_SALT])
        out = []
        for _ in range(zones):
            pan, tilt = rng.uniform(-180.0, 180.0), rng.uniform(-30.0, 15.0)
            out.append((round(float(pan), 4), round(float(tilt), 4)))
        return out

    def exposure_us(self, white_e_per_ms: float, frame_rate_hz: float = 30.0) -> float:
        """The exposure in a room whose white wall sends `white_e_per_ms` (× the room light)."""
        light = white_e_per_ms * self.room_light
        wanted = 1000.0 * self.fill * self.full_well_e / light if light > 0 else math.inf
        return round(min(max(wanted, 500.0), 30000.0, 0.9e6 / frame_rate_hz), 1)

    def overrides(self, beam_e_per_ms_at_1m: float, white_e_per_ms: float, zones: int,
                  frame_rate_hz: float = 30.0, live: bool = False) -> tuple[str, ...]:
        """``--set`` overrides that make this condition of a base configuration whose beam, room
        light and frame rate are these (the scales multiply them). `live`: for the live simulator,
        which renders an ISP condition's frames through the ISP itself (`sim.sensor.isp`)."""
        poses = json.dumps([list(p) for p in self.poses(zones)])
        # (Recorded, an ISP condition is its 1640 × 1232 sensor, which sees the room as the 640 × 480
        # camera does, per area; its recording is scaled afterwards: edge.sim.isp.scale_recording.
        # That keeps the sensor's own truth, the floor, which the live simulator does not give.)
        sensor = self.isp and not live
        camera = self.camera if not sensor else isp.sensor_camera(self.camera)
        white, well, blur, grain = (white_e_per_ms * self.room_light, self.full_well_e, self.psf_sigma_px,
                                    self.speckle_grain)
        if sensor:
            white, well, blur, grain = isp.per_area(white, well, blur, grain)
        return (
            f"sim.sensor.isp={str(self.isp and live).lower()}",
            f"camera.exposure_us={self.exposure_us(white_e_per_ms, frame_rate_hz)!r}",
            f"sim.scene={json.dumps(self.scene)}",
            f"sim.seed={self.seed}",
            f"rig.camera.width={camera.width}",
            f"rig.camera.height={camera.height}",
            f"rig.camera.fx={camera.fx!r}",
            f"rig.camera.fy={camera.fy!r}",
            f"rig.camera.cx={camera.cx!r}",
            f"rig.camera.cy={camera.cy!r}",
            f"rig.camera.dist=[{self.k1!r}, 0.0, 0.0, 0.0, 0.0]",
            f"sim.sensor.colour={str(self.colour).lower()}",
            f"sim.sensor.bayer={json.dumps(self.bayer)}",
            f"sim.sensor.jpeg_quality={self.jpeg_quality}",
            f"sim.sensor.jpeg_chroma={json.dumps(self.jpeg_chroma)}",
            f"sim.sensor.output_bits={self.output_bits}",
            f"sim.sensor.adc_bits={self.adc_bits}",
            f"sim.sensor.full_well_e={well!r}",
            f"sim.sensor.read_noise_e={self.read_noise_e!r}",
            f"sim.beam.e_per_ms_at_1m={beam_e_per_ms_at_1m * self.laser_power!r}",
            f"sim.ambient.white_e_per_ms={white!r}",
            f"sim.surfaces.albedo_scale={self.albedo_scale!r}",
            f"sim.surfaces.texture_scale={self.texture_scale!r}",
            f"sim.surfaces.extra_gloss={self.extra_gloss!r}",
            f"sim.optics.f_number={self.f_number!r}",
            f"sim.optics.focus_m={self.focus_m!r}",
            f"sim.optics.psf_sigma_px={blur!r}",
            f"sim.beam.speckle={self.speckle!r}",
            f"sim.beam.speckle_grain={grain!r}",
            f"sim.beam.speckle_cell_m={self.speckle_cell_m!r}",
            f"sim.rig_error.laser_angle_deg={self.laser_angle_deg!r}",
            f"sim.rig_error.laser_offset_m={self.laser_offset_m!r}",
            f"sim.rig_error.focal_scale={self.focal_scale!r}",
            f"sim.rig_error.seed={self.seed}",
            # (Only a webcam's own: other cameras keep the configuration's, which a `--set` may give.)
            *([f"sim.sensor.colour_matrix={list(self.colour_matrix)!r}"] if self.colour_matrix else []),
            # (Only a moving rig's own: still ones keep the configuration's, which a `--set` may give.)
            *([f"sim.sway.jolt_deg={self.jolt_deg!r}"] if self.jolt_deg else []),
            *(["sim.optics.pixel_area=true"] if self.pixel_area else []),
            f"sweep.poses_deg={poses}",
        )

    def aimed(self, beam_e_per_ms_at_1m: float, white_e_per_ms: float, frame_rate_hz: float, pose: int
              ) -> tuple[str, ...]:
        """`overrides` for the condition seen from its pose number `pose` alone, its rig built as
        configured (no mounting errors, no sweep) and at rest: the range finder aimed there, and so
        `edge doctor`'s laser checks. (An ISP condition's frames are then the ISP's, made live:
        `sim.sensor.isp`.)"""
        pan, tilt = self.poses(pose + 1)[pose]
        kept = [o for o in self.overrides(beam_e_per_ms_at_1m, white_e_per_ms, 1, frame_rate_hz, live=True)
                if not o.startswith(("sweep.", "sim.rig_error", "sim.sway"))]
        return (*kept, f"rangefinder.pan_deg={pan}", f"rangefinder.tilt_deg={tilt}")

    @property
    def camera(self) -> CameraModel:
        """The camera model whose frames the estimator ranges."""
        return CameraModel(self.width, self.height, self.fx, self.fx, self.cx, self.cy, (self.k1, 0.0, 0.0, 0.0, 0.0))

    @property
    def frames(self) -> str:
        """The kind of frames the camera delivers, as the estimator meets them: the sensor (grey,
        3-colour, Bayer, or a Bayer sensor ISP-scaled) and lossless or JPEG."""
        sensor = "grey" if not self.colour else ("3-colour" if self.bayer == "none" else "ISP-scaled" if self.isp
                                                 else "Bayer")
        return f"{sensor} {'JPEG' if self.jpeg_quality else 'lossless'}"

    def describe(self) -> str:
        """One short line of what matters most to ranging."""
        sensor = "grey" if not self.colour else ("3-colour" if self.bayer == "none" else f"bayer-{self.bayer}")
        if self.isp:
            sensor = f"{isp.RAW.width}x{isp.RAW.height} {sensor} ISP-scaled"
        frames = f"jpeg{self.jpeg_quality} {self.jpeg_chroma}" if self.jpeg_quality else f"png{self.output_bits}"
        if self.colour_matrix:
            frames += f" ccm {self.colour_matrix[0]:.2f}R{self.colour_matrix[1]:+.2f}G{self.colour_matrix[2]:+.2f}B"
        if self.jolt_deg:
            frames += f" turned {self.jolt_deg:.2g}°"
        if self.pixel_area:
            frames += " area-sampled"
        return (f"{self.scene} {self.width}x{self.height} {sensor} {frames}, laser ×{self.laser_power:.2g} "
                f"light ×{self.room_light:.2g} fill {self.fill:.2f} albedo ×{self.albedo_scale:.2g} "
                f"gloss +{self.extra_gloss:.2f} f/{self.f_number:.1f}@{self.focus_m:.1f}m speckle ×{self.speckle:.2g}")

    def to_json(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @classmethod
    def from_json(cls, doc: dict) -> Condition:
        """The condition `to_json` wrote (a KeyError names a field it lacks; a field drawn after it
        was written takes its default, as the family then had it)."""
        given: dict[str, Any] = {f.name: tuple(doc[f.name]) if isinstance(doc.get(f.name), list) else doc[f.name]
                                 for f in fields(cls) if f.name in doc or f.default is MISSING}  # (JSON's lists)
        return cls(**given)


# The picture's farthest corner lies this far inside a barrel lens's fold, at most (see unfolded_k1).
FOLD_MARGIN = 1.1


def unfolded_k1(width: int, height: int, fx: float, cx: float, cy: float) -> float:
    """The strongest barrel (most negative k1, 4 decimals) whose distorted radius still grows out to
    FOLD_MARGIN × the picture's farthest corner. With k1 alone, r(1 + k1 r²) peaks at
    (2/3)/√(−3 k1) and folds back beyond: no real lens does that, and the pixels past the fold have
    no ray. (Drawn from −0.25 regardless, as the family did before this bound, 8 % of its conditions
    folded inside the picture: an 800 × 600 camera at f = 538 px with k1 = −0.2 put 2-3 % of its
    pixels past the fold, which the simulator rendered through rays that do not exist.)"""
    corner = math.hypot(max(cx, width - 1 - cx), max(cy, height - 1 - cy)) / fx
    return math.ceil(-4.0 / (27.0 * (FOLD_MARGIN * corner) ** 2) * 1e4) / 1e4


def _log_uniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def condition(family: Family | str, index: int) -> Condition:
    """Condition `index` of `family` (``tuning`` or ``evaluation``)."""
    if family not in FAMILIES:
        raise ValueError(f"family must be one of {', '.join(FAMILIES)}, got {family!r}")
    if not 0 <= index < FAMILY_SIZE:
        raise ValueError(f"a condition's index must be 0-{FAMILY_SIZE - 1}, got {index}")
    seed = FAMILIES[family] + index
    # The draws below are in a fixed order: a new knob must be drawn after all of them, so that
    # every condition keeps what it was (and figures measured on it stay comparable).
    rng = np.random.default_rng([seed, _SALT])
    width, height = RESOLUTIONS[int(rng.choice(len(RESOLUTIONS), p=RESOLUTION_WEIGHTS))]
    hfov = math.radians(rng.uniform(50.0, 75.0))
    fx = round(width / 2.0 / math.tan(hfov / 2.0), 3)
    cx = round((width - 1) / 2.0 + rng.uniform(-0.02, 0.02) * width, 3)
    cy = round((height - 1) / 2.0 + rng.uniform(-0.02, 0.02) * height, 3)
    k1 = max(round(float(rng.uniform(-0.25, 0.05)), 4), unfolded_k1(width, height, fx, cx, cy))
    colour = bool(rng.random() < 0.9)
    lossless = bool(rng.random() < 0.5)
    output_bits: Literal[8, 16] = 16 if lossless and rng.random() < 0.3 else 8
    bayer_choice = str(rng.choice(["none", "bilinear", "vng", "ea"], p=[0.25, 0.25, 0.25, 0.25]))
    if not colour:
        bayer_choice = "none"
    elif bayer_choice == "vng" and output_bits == 16:
        bayer_choice = "ea"
    bayer: Literal["none", "bilinear", "vng", "ea"] = bayer_choice  # type: ignore[assignment]
    jpeg_quality = 0 if lossless else int(rng.integers(50, 96))
    jpeg_chroma: Literal["4:2:0", "4:4:4"] = "4:2:0" if rng.random() < 0.6 else "4:4:4"
    adc_bits = int(rng.choice([8, 10, 12], p=[0.2, 0.5, 0.3]))
    full_well = round(_log_uniform(rng, 3000.0, 20000.0), 1)
    read_noise = round(_log_uniform(rng, 1.5, 15.0), 2)
    drawn = Condition(
        family=family,
        index=index,
        seed=seed,
        scene=str(rng.choice(SCENES)),
        width=width,
        height=height,
        fx=fx,
        cx=cx,
        cy=cy,
        k1=k1,
        colour=colour,
        bayer=bayer,
        jpeg_quality=jpeg_quality,
        jpeg_chroma=jpeg_chroma,
        output_bits=output_bits,
        adc_bits=adc_bits,
        full_well_e=full_well,
        read_noise_e=read_noise,
        laser_power=round(_log_uniform(rng, 0.25, 4.0), 4),
        room_light=round(_log_uniform(rng, 0.25, 4.0), 4),
        fill=round(float(rng.uniform(0.25, 0.8)), 3),
        albedo_scale=round(_log_uniform(rng, 0.1, 1.2), 4),
        texture_scale=round(_log_uniform(rng, 0.3, 3.0), 4),
        extra_gloss=round(float(rng.uniform(0.0, 0.3)), 4) if rng.random() < 0.5 else 0.0,
        f_number=round(float(rng.uniform(1.8, 2.8)), 2),
        focus_m=round(_log_uniform(rng, 0.5, 3.0), 3),
        psf_sigma_px=round(float(rng.uniform(0.4, 1.0)), 3),
        speckle=round(float(rng.uniform(0.5, 1.5)), 3),
        speckle_grain=round(_log_uniform(rng, 0.7, 1.5), 3),
        speckle_cell_m=round(_log_uniform(rng, 1e-4, 4e-4), 6),
        laser_angle_deg=round(float(rng.uniform(0.0, 0.3)), 4),
        laser_offset_m=round(float(rng.uniform(0.0, 0.001)), 6),
        focal_scale=round(float(rng.uniform(0.0, 0.01)), 5),
        colour_matrix=_colour_matrix(rng, colour and bool(jpeg_quality)),
    )
    drawn = _through_isp(drawn, rng)
    drawn = replace(drawn, jolt_deg=_jolt(rng))
    return replace(drawn, pixel_area=bool(rng.random() < AREA_SHARE))


def _through_isp(drawn: Condition, rng: np.random.Generator) -> Condition:
    """`drawn`, or for ISP_SHARE of the lossless colour cameras at 640 × 480 the Pi camera's
    pipeline in their place: a Bayer sensor (the drawn demosaicing, or one of ISP_DEMOSAICS for a
    3-colour draw) at 1640 × 1232, scaled to 8-bit 640 × 480 frames (as the Pi camera's RGB888).
    (Both draws are made for every condition, so that a knob drawn after them keeps its draws.)"""
    share, demosaic = float(rng.random()), str(rng.choice(ISP_DEMOSAICS))
    if ((drawn.width, drawn.height) != (isp.OUT.width, isp.OUT.height) or not drawn.colour or drawn.jpeg_quality
            or share >= ISP_SHARE):
        return drawn
    bayer: Literal["none", "bilinear", "vng", "ea"] = drawn.bayer
    if bayer == "none":
        bayer = demosaic  # type: ignore[assignment]
    return replace(drawn, isp=True, bayer=bayer, output_bits=8)


def _jolt(rng: np.random.Generator) -> float:
    """How far a moving rig turns between a laser-on frame and the laser-off frame after it
    (degrees): for MOVING_SHARE of the rigs, log-uniform over JOLT_DEG (a head ringing after a move
    to a walker turning 30°/s between two frames at 30 fps); 0 for the rest. (Both draws are made
    for every condition, so that a knob drawn after them keeps its draws.)"""
    moving, jolt = float(rng.random()), _log_uniform(rng, *JOLT_DEG)
    return round(jolt, 4) if moving < MOVING_SHARE else 0.0


def _colour_matrix(rng: np.random.Generator, webcam: bool) -> tuple[float, ...]:
    """A webcam's colour matrix: one sensor's of SENSOR_COLOUR_MATRICES at a colour temperature
    between its two (as libcamera interpolates them); empty for other cameras. (Drawn for every
    condition, so that a knob drawn after it keeps its draws.)"""
    warm, cool = SENSOR_COLOUR_MATRICES[str(rng.choice(sorted(SENSOR_COLOUR_MATRICES)))]
    mix = float(rng.uniform(0.0, 1.0))
    if not webcam:
        return ()
    return tuple(round(a + mix * (b - a), 4) for a, b in zip(warm, cool))


def family(name: Family | str, count: int, start: int = 0) -> list[Condition]:
    """Conditions start … start + count − 1 of family `name`."""
    return [condition(name, i) for i in range(start, start + count)]
