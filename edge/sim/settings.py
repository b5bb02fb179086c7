"""The simulator's settings (``[sim]``): the scene, the virtual sensor, optics, beam and room light,
how the simulated rig was built, and the faults it plays on demand. The simulated parts own them,
as each driver of :mod:`edge.hw` owns its own; :mod:`edge.config` only gathers them."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from edge.schema import require
from edge.tone import require_gamma


@dataclass(frozen=True)
class SensorConfig:
    """The simulated sensor: photo-electrons to digital numbers."""

    full_well_e: float = 10000.0
    read_noise_e: float = 3.0
    adc_bits: int = 10
    output_bits: Literal[8, 16] = 8
    colour: bool = True
    jpeg_quality: int = 0  # 0: lossless PNG; 1-100: what a webcam's JPEG stream does to frames
    # JPEG's colour resolution: "4:2:0" halves it both ways (MJPEG webcams; OpenCV's default),
    # "4:4:4" keeps it whole. A small red spot lives mostly in the chroma.
    jpeg_chroma: Literal["4:2:0", "4:4:4"] = "4:2:0"
    # A webcam's uncompressed stream: YUYV (YUV 4:2:2), one chroma pair for each two pixels of a
    # row, as OpenCV's V4L2 backend asks a UVC webcam for first, and decodes as it does
    # (cv2.COLOR_YUV2BGR_YUYV). 8-bit colour frames only, and not with JPEG; grey frames pass
    # unchanged (so that one `--set` serves a whole family, as colour_matrix does).
    yuyv: bool = False
    # A colour sensor sees one colour per pixel through its Bayer filter (RGGB) and the camera
    # interpolates the other two: "none" is an ideal sensor that sees all three everywhere;
    # "bilinear", "vng" and "ea" (edge-aware) are OpenCV's demosaicing methods.
    bayer: Literal["none", "bilinear", "vng", "ea"] = "none"
    # Rolling shutter: row 0's exposure start to the last row's. The IMX219's 640×480 mode runs at
    # up to 206 fps, so it reads out in under 5 ms; a webcam takes most of its frame period.
    readout_ms: float = 5.0
    # The tone curve of the delivered values: 1 is linear (values proportional to light);
    # 1.8-2.4 is a camera's display gamma (an ISP's, a webcam's), value ∝ light^(1/gamma) with a
    # linear toe. A Pi camera's ISP applies one unless its tuning file says otherwise.
    gamma: float = 1.0
    # The colour correction matrix an ISP applies after demosaicing, rows R', G', B' of columns
    # R, G, B (libcamera's rpi.ccm order, 9 numbers); empty: none. A camera's own mixes the channels
    # with large negative terms (the IMX219's at 2860 K takes 2.12 R − 0.52 G − 0.60 B for red), and a
    # webcam applies one that nobody can turn off; edge turns the Pi's off (edge.hw.camera). Grey
    # frames have no colours to mix and pass unchanged (so that one `--set` serves a whole family).
    colour_matrix: tuple[float, ...] = ()
    # Defective-pixel correction on a Bayer sensor's raw values, as an ISP runs it before
    # demosaicing: a pixel that differs from all 8 of its same-colour neighbours (2 px away) by over
    # this share of full scale is taken for a hot or dead pixel and replaced by the median of the 4
    # nearest of them; 0: none. (A generic rule, as open ISPs write it; the Pi's own is in its
    # hardware. edge turns the Pi's off: edge.hw.camera.)
    dpc: float = 0.0
    # The Pi camera as it is: its 1640 × 1232 sensor rendered (with `bayer`'s demosaicing), a row
    # cropped off the top and the bottom and the rest scaled by area to the rig's 640 × 480, as its
    # ISP hands frames over (edge.isp). The room's light, the well, the lens blur and the speckle
    # grain stay those of the 640 × 480 camera (each sensor pixel gets its share: per area). False:
    # frames rendered at the rig camera's own size, as a sensor of that size would make them.
    isp: bool = False

    def __post_init__(self) -> None:
        require(self.full_well_e > 0, "full_well_e", "must be positive")
        require(len(self.colour_matrix) in (0, 9), "colour_matrix",
                f"must be 9 numbers (rows R', G', B' of columns R, G, B) or empty, got {len(self.colour_matrix)}")
        require(all(math.isfinite(x) for x in self.colour_matrix), "colour_matrix", "must be finite numbers")
        require(0.0 <= self.dpc < 1.0, "dpc", "must be in [0, 1): a share of full scale (0: no correction)")
        require_gamma(self.gamma, "gamma")
        require(self.read_noise_e >= 0, "read_noise_e", "must be >= 0")
        require(8 <= self.adc_bits <= 16, "adc_bits", f"must be 8-16, got {self.adc_bits}")
        require(0 <= self.jpeg_quality <= 100, "jpeg_quality", "must be 0-100")
        require(self.readout_ms >= 0, "readout_ms", "must be >= 0")
        require(
            not (self.jpeg_quality and self.output_bits == 16),
            "jpeg_quality",
            "JPEG frames are 8-bit; set output_bits = 8",
        )
        require(not (self.yuyv and self.jpeg_quality), "yuyv",
                "a webcam streams YUYV or JPEG, not both; set jpeg_quality = 0")
        require(not (self.yuyv and self.output_bits == 16), "yuyv", "YUYV frames are 8-bit; set output_bits = 8")
        require(self.bayer == "none" or self.colour, "bayer", "a grey sensor has no colour filter; set colour = true")
        require(self.bayer != "vng" or self.output_bits == 8, "bayer", "OpenCV's vng demosaics 8-bit frames only")
        require(not (self.isp and (self.jpeg_quality or self.yuyv)), "isp",
                "the Pi camera's ISP hands over uncompressed frames; set jpeg_quality = 0 and yuyv = false")
        require(not self.isp or self.colour, "isp", "the Pi camera's sensor is a colour one; set colour = true")


@dataclass(frozen=True)
class OpticsConfig:
    focal_length_mm: float = 3.04  # Pi Camera v2
    f_number: float = 2.0
    focus_m: float = 1.2  # fixed-focus distance
    psf_sigma_px: float = 0.5  # lens + pixel blur of a point in focus
    vignetting: bool = True
    # Each pixel sees the room averaged over its area, as a sensor's pixel integrates light: the
    # texture filtered by the pixel's footprint on the surface, and a pixel that an edge crosses
    # given some of each side. False (the default, which everything here was first measured on):
    # the room is sampled at each pixel's centre, which folds a texture finer than a pixel into
    # coarse false patterns and moves edges in whole pixels; what a turned camera's frames then
    # show cannot be resampled into what the pose would have shown. (Movers are sampled at
    # pixels' centres either way.)
    pixel_area: bool = False

    def __post_init__(self) -> None:
        require(self.focal_length_mm > 0, "focal_length_mm", "must be positive")
        require(self.f_number > 0, "f_number", "must be positive")
        require(self.focus_m > 0, "focus_m", "must be positive")
        require(self.psf_sigma_px >= 0.2, "psf_sigma_px", "must be >= 0.2")


@dataclass(frozen=True)
class BeamConfig:
    """The laser pointers as the simulator sees them."""

    # Photo-electrons per ms of exposure that a spot on a white (albedo 1) matte wall squarely at 1 m
    # sends to the sensor, all pixels together, before vignetting.
    e_per_ms_at_1m: float = 20000.0
    waist_m: float = 0.0012  # 1/e² beam radius at the aperture
    divergence_mrad: float = 0.6  # half-angle
    # Relative response of the B, G, R pixels to 650 nm light (Bayer filters leak a little).
    response_bgr: tuple[float, float, float] = (0.03, 0.10, 1.0)
    speckle: float = 1.0  # 0: no speckle; 1: the modelled speckle of a pointer at f/2
    speckle_cell_m: float = 0.0002  # how far the spot must move on the surface for new speckle
    # Speckle grain relative to that of a 650 nm pointer seen at f/2 by the Pi camera's pixels
    # (the grain grows with the f-number and the wavelength, and shrinks with bigger pixels).
    speckle_grain: float = 1.0

    def __post_init__(self) -> None:
        require(self.e_per_ms_at_1m >= 0, "e_per_ms_at_1m", "must be >= 0")
        require(self.waist_m > 0, "waist_m", "must be positive")
        require(self.divergence_mrad >= 0, "divergence_mrad", "must be >= 0")
        require(self.speckle >= 0, "speckle", "must be >= 0")
        require(self.speckle_cell_m > 0, "speckle_cell_m", "must be positive")
        require(0.1 <= self.speckle_grain <= 10, "speckle_grain", "must be 0.1-10")


@dataclass(frozen=True)
class AmbientConfig:
    # Photo-electrons per ms that a white (albedo 1) wall sends to one pixel under room light.
    white_e_per_ms: float = 600.0
    # Relative amplitude of the light level's change from frame to frame (mains or LED-driver flicker
    # beating with the frame rate): each frame's ambient level is uniform in 1 ± flicker.
    flicker: float = 0.03

    def __post_init__(self) -> None:
        require(self.white_e_per_ms >= 0, "white_e_per_ms", "must be >= 0")
        require(0 <= self.flicker < 1, "flicker", "must be in [0, 1)")


@dataclass(frozen=True)
class SurfacesConfig:
    """Every surface of the scene changed at once (``[sim.surfaces]``): rooms darker, brighter,
    plainer or shinier than their scene file, without writing another."""

    albedo_scale: float = 1.0  # diffuse reflectance × this (capped at 1)
    texture_scale: float = 1.0  # the procedural texture's contrast × this
    extra_gloss: float = 0.0  # added to every material's specular fraction (capped at 1)

    def __post_init__(self) -> None:
        require(0 < self.albedo_scale <= 100, "albedo_scale", "must be in (0, 100]")
        require(0 <= self.texture_scale <= 10, "texture_scale", "must be 0-10")
        require(0 <= self.extra_gloss <= 1, "extra_gloss", "must be 0-1")


@dataclass(frozen=True)
class SwayConfig:
    """The rig's platform turning under it while it works (``[sim.sway]``): a robot that turns, a
    wearer's walk, a head still ringing. The camera and its lasers turn together, by `deg` in pan
    at `hz` (a sine of the rig's time) and by half that in tilt at 1.618 × `hz`, so that no two
    frames see the room from quite the same way."""

    deg: float = 0.0  # 0: the platform is still
    hz: float = 1.0
    # Each frame with every laser off taken with the camera turned this much more (degrees), in a
    # direction drawn afresh for each: a head that rings or a hand that shakes between the lit
    # frame and the dark one, while the lit frames keep the pose (so that the truth is the pose's).
    jolt_deg: float = 0.0

    def __post_init__(self) -> None:
        require(0 <= self.deg <= 30, "deg", "must be 0-30 degrees")
        require(0 < self.hz <= 50, "hz", "must be in (0, 50] Hz")
        require(0 <= self.jolt_deg <= 10, "jolt_deg", "must be 0-10 degrees")

    def turn(self, t_s: float) -> tuple[float, float]:
        """(pan, tilt) the platform has turned by at the rig's time `t_s` (degrees)."""
        phase = 2.0 * math.pi * self.hz * t_s
        return self.deg * math.sin(phase), 0.5 * self.deg * math.sin(1.618 * phase + 1.0)


@dataclass(frozen=True)
class RigErrorConfig:
    """How the simulated rig differs from the nominal one (seeded): real rigs are never exact."""

    laser_angle_deg: float = 0.0  # 1-σ tilt of each laser's direction
    laser_offset_m: float = 0.0  # 1-σ offset of each laser's origin, per axis
    focal_scale: float = 0.0  # 1-σ relative error of the focal length
    seed: int = 0

    def __post_init__(self) -> None:
        for key in ("laser_angle_deg", "laser_offset_m", "focal_scale"):
            require(getattr(self, key) >= 0, key, "must be >= 0")


@dataclass(frozen=True)
class CameraFault:
    """A fault the simulated camera plays at a time after it starts (``[[sim.camera_faults]]``):
    ``stall`` delivers no frames for `seconds`; ``corrupt`` delivers `count` frames of the wrong
    size; ``hang`` blocks the caller for `seconds` (a driver stuck without a timeout)."""

    kind: Literal["stall", "corrupt", "hang"] = "stall"
    at_s: float = 0.0
    seconds: float = 3.0
    count: int = 2

    def __post_init__(self) -> None:
        require(self.at_s >= 0, "at_s", "must be >= 0")
        require(self.seconds > 0, "seconds", "must be positive")
        require(self.count >= 1, "count", "must be >= 1")


@dataclass(frozen=True)
class LaserFault:
    """A broken simulated laser (``[[sim.laser_faults]]``): ``dead`` never lights, ``stuck``
    never goes off (a shorted driver), ``slow`` switches `lag_ms` after its GPIO edge, whatever
    ``lasers.settle_ms`` says (a driver's soft start; for the frames, the same as a camera whose
    timestamps are late)."""

    laser: str = ""
    kind: Literal["dead", "stuck", "slow"] = "dead"
    lag_ms: float = 10.0

    def __post_init__(self) -> None:
        require(0 < self.lag_ms <= 1000, "lag_ms", "must be more than 0 and at most 1000 ms")


@dataclass(frozen=True)
class PtuFault:
    """A broken emulated pan-tilt unit from the start (``[[sim.ptu_faults]]``): ``silent`` never
    answers (no power, a cut cable, the wrong port); ``garbled`` answers with line noise (a wrong
    ``ptu.baudrate``)."""

    kind: Literal["silent", "garbled"] = "silent"


@dataclass(frozen=True)
class SimConfig:
    scene: str = "office"
    seed: int = 1
    # The virtual rig's time (edge.clock): "simulated" makes a run a function of its configuration
    # and seed alone, as fast as the computer renders; "paced" is simulated time never ahead of
    # real time (a person or a tool talking to it live); "real" runs on the wall clock, for what
    # must be real (systemd's watchdog, a hang). A rig with any real part runs on real time.
    clock: Literal["simulated", "paced", "real"] = "simulated"
    # "paced" only: at most this many simulated seconds to a real second (2.0: twice as fast as a
    # real rig, if the computer renders that fast).
    pace: float = 1.0
    sensor: SensorConfig = field(default_factory=SensorConfig)
    optics: OpticsConfig = field(default_factory=OpticsConfig)
    beam: BeamConfig = field(default_factory=BeamConfig)
    ambient: AmbientConfig = field(default_factory=AmbientConfig)
    surfaces: SurfacesConfig = field(default_factory=SurfacesConfig)
    rig_error: RigErrorConfig = field(default_factory=RigErrorConfig)
    sway: SwayConfig = field(default_factory=SwayConfig)
    camera_faults: tuple[CameraFault, ...] = ()  # for trying the service's fault handling
    laser_faults: tuple[LaserFault, ...] = ()  # broken lasers, for trying fault reporting
    ptu_faults: tuple[PtuFault, ...] = ()  # a unit that does not answer, for trying `edge doctor`

    def __post_init__(self) -> None:
        require(self.pace > 0 and math.isfinite(self.pace), "pace", "must be a positive number")
