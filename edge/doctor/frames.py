"""What kind of frames the camera delivers, and what ranging will make of them: the `frames` line.

The spot finder adapts to its frames (:mod:`edge.vision`): JPEG's blocks, the channel of a colour
frame it reads (red, or luma where the chroma is at half resolution), a Bayer filter's red pixels
behind a demosaiced frame (spots are then placed by them), the pixel noise and how far it is spread
over neighbouring pixels (a spot's σ grows by it). Each changes how well a spot is placed, and
nothing else shows which of them a camera's frames brought: on a new camera, that is the first
hour's question. The finder ranging builds says what it decides
(:meth:`edge.vision.SpotFinder.frame_kind`) for every pair of a few laser-off frames at one aim,
whose differences are noise alone; the line gives what most pairs say.

It fails where the frames make ranging unreliable and the user can mend it: frames delivered twice
(a laser-on frame could be a laser-off one again), and noise smoothed over neighbours that neither
JPEG nor a colour filter's interpolation spreads (the camera's own denoising: it thresholds and
reshapes a spot by how bright it is, in ways a spot's σ does not follow). A colour camera's frames
are always demosaiced, and their noise spread over 1.5-7 px² by that alone (the simulator's Bayer
frames, red or luma): denoising on top of it cannot be told from it, and is not judged.

Pure: frames and the configuration in, the line out.
"""

from __future__ import annotations

import itertools
import math
import statistics
from collections import Counter
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, TypeVar

from edge.doctor.checklist import Problem

if TYPE_CHECKING:
    import numpy as np

    from edge.config import Config
    from edge.rig import Rig
    from edge.vision import FrameKind

# Noise spread over more than this many px² in frames without JPEG's blocks or a colour filter's
# interpolation was smoothed by the camera. Measured on the simulator's grey frames (office, 3
# seeds × 4 aims, 8- and 16-bit, gamma 1 and 2.2, read noise 3 and 15 e⁻; the median of 6 pairs):
# 1.00-1.39 as delivered; 2.10-2.89 through a Gaussian blur of σ 0.5 px (OpenCV's 5-tap kernel:
# a light denoise), 2.84-3.81 at σ 0.6. (σ 0.4 px, OpenCV's 3-tap kernel with 4 % on either side,
# reads 1.25-1.68 and is left alone: it grows a spot's σ by a fifth at most.)
SMOOTHED_AREA = 1.8

# What the frames line adds for a webcam's JPEG frames: the accuracy family's figures (docs/ranging.md, "A
# sixth evaluation set" and the table by kind of frames) and the setting that mends it.
WEBCAM_JPEG = ("ranging places spots in JPEG frames worse (of the observable zones in the simulated family's "
               "colour frames, 77 % ranged in JPEG frames, 94 % in uncompressed ones): ask the webcam for "
               'YUYV, camera.pixel_format = "YUYV", at a size it streams uncompressed (v4l2-ctl --list-formats-ext)')

T = TypeVar("T")


def judge(frames: Sequence[np.ndarray], rig: Rig, config: Config) -> str:
    """The frames line from laser-off frames taken one after another at one aim, as the camera
    delivered them (before ranging undoes ``ranging.frame_gamma``). Problem where two of them are
    the same frame, or where the camera smooths their noise."""
    import numpy as np

    from edge.framenoise import jpeg_blockiness
    from edge.ranging import FrameGroup, Ranger
    from edge.spoterror import LUMA_DEMOSAIC_PX
    from edge.vision import JPEG_BLOCKINESS

    if len(frames) < 2:
        raise ValueError("the frames line needs two laser-off frames or more")
    height, width = frames[0].shape[:2]
    repeated = sum(np.array_equal(a, b) for a, b in zip(frames, frames[1:]))
    if repeated:
        raise _repeated(frames[0], repeated, len(frames) - 1, config)
    ranger = Ranger(rig, config.ranging)  # the finder as ranging builds it, nothing told yet
    finder = ranger.finder
    seen = list(frames)
    blockiness = None
    if config.ranging.frame_gamma != 1.0:  # as ranging: JPEG told by the delivered frame, then made linear
        seen = list(ranger.linear([FrameGroup(seen, [], ())])[0].on)
        blockiness = jpeg_blockiness(frames[0])
    kinds = [finder.frame_kind(a, b) for a, b in itertools.combinations(seen, 2)]
    kind = kinds[0]
    jpeg = _most(k.jpeg for k in kinds)
    if blockiness is None:
        blockiness = statistics.median(k.blockiness for k in kinds)
    area = statistics.median(k.area for k in kinds)
    noise = statistics.median(k.noise for k in kinds)
    # A colour frame whose three channels are one (a monochrome sensor delivered as RGB) has no
    # colour filter to interpolate, as a grey frame has none.
    grey = not kind.colour or all(np.array_equal(f[..., 0], f[..., c]) for f in frames[:2] for c in (1, 2))
    words = [f"{width}x{height} {'grey' if not kind.colour else 'grey in colour frames' if grey else 'colour'}"
             + ("" if frames[0].dtype == np.uint8 else f" ({_depth(frames[0])})"),
             f"JPEG (blockiness {blockiness:.2f} > {JPEG_BLOCKINESS:g})" if jpeg
             else f"not JPEG (blockiness {blockiness:.2f} ≤ {JPEG_BLOCKINESS:g})"]
    if jpeg and config.camera.backend == "opencv":
        words.append(WEBCAM_JPEG)
    channel = _most(k.channel for k in kinds)
    paired = not grey and _most(k.paired for k in kinds)
    if paired:
        words.append("each two pixels of a row share one chroma (a YUYV stream, YUV 4:2:2): no pixel keeps its own "
                     "red, and spots are placed by the interpolated red")
    elif channel == "red" and not grey:
        words.append(_demosaiced(kinds))
    words.append(_channel(channel, config.ranging.channel, [k.chroma_lag2 for k in kinds], paired))
    if channel == "luma" and not grey and _most(k.demosaiced for k in kinds):
        words.append(f"taken as behind a Bayer filter, as colour webcams are: each spot carries its "
                     f"{LUMA_DEMOSAIC_PX:g} px")
    full = finder.full_scale(seen[0])
    level = f"{noise * full:.1f} levels of {full:.0f}" if noise * full >= 0.05 else "under a level"
    if config.ranging.frame_gamma != 1.0:
        level += " in linear light"
    words.append(f"difference noise {level}, spread over {area:.1f} px²")
    line = ", ".join(words[:2]) + "".join(f"; {w}" for w in words[2:])
    if not jpeg and grey and area > SMOOTHED_AREA:
        raise Problem(f"the camera smooths them: their noise is spread over {area:.1f} px² where neither JPEG nor a "
                      f"colour filter spreads it (over {SMOOTHED_AREA:g} is smoothing), which reshapes a spot by how "
                      f"bright it is. {line}", _smoothing_remedy(config))
    return line


def _depth(frame: np.ndarray) -> str:
    """A 16-bit frame's depth, and the sensor's where its values are further apart than 1: a
    sensor's 8-12 bits scaled to 16 (ranging's noise is no finer than that step)."""
    from edge.framenoise import value_step

    bits = frame.dtype.itemsize * 8
    step = value_step(frame)
    if step <= 1.0:
        return f"{bits}-bit"
    sensor = math.log2((2**bits - 1) / step + 1)
    return f"{bits}-bit, its values {step:g} apart: the sensor's {sensor:.0f} bits"


def _most(values: Iterable[T]) -> T:
    """The value most of `values` take (the first of the most common)."""
    return Counter(values).most_common(1)[0][0]


def _demosaiced(kinds: Sequence[FrameKind]) -> str:
    """What the line says of a colour filter, for colour frames whose red is read."""
    from edge.framenoise import RESAMPLED_CHROMA, RESAMPLED_CONTRAST, parity_contrast, resampled

    if sum(k.demosaiced for k in kinds) * 2 <= len(kinds):
        return "every pixel's own red (no demosaicing seen)"
    shares = [k.parity for k in kinds if k.parity is not None]
    chroma = [k.chroma for k in kinds if k.chroma is not None]
    if resampled(shares, chroma):
        return (f"red's noise spread over neighbours, alike at every pixel of a 2 × 2 block (contrast "
                f"{parity_contrast(shares):.2f} < {RESAMPLED_CONTRAST:g}; chroma correlated "
                f"{statistics.median(chroma):.2f} at 2 px, within ±{RESAMPLED_CHROMA:g}): scaled after demosaicing, as "
                "a Pi camera's ISP scales its sensor's 1640 × 1232 to 640 × 480, and no colour filter's pixels at "
                "this size: spots are placed as without one")
    found = Counter(k.bayer_red for k in kinds if k.bayer_red is not None)
    if not found:
        return "demosaiced, no Bayer filter's pattern seen: spots are placed by the interpolated red"
    (row, col), count = found.most_common(1)[0]
    parity = ("even", "odd")
    at = f"red at {parity[row]} rows and " + ("columns" if row == col else f"{parity[col]} columns")
    if count * 2 > len(kinds):
        return f"demosaiced from a Bayer filter, {at}: spots are placed by their red pixels"
    return (f"demosaiced; a Bayer filter's pattern ({at}) shows in {count} of {len(kinds)} pairs only: spots are "
            "placed by their red pixels where it shows, else by the interpolated red")


def _channel(channel: str, configured: str, chroma: Sequence[float | None], paired: bool = False) -> str:
    """What the line says of the channel read (`chroma`: each pair's chroma correlation, if measured;
    `paired`: pixels that share their chroma in pairs)."""
    if channel == "grey":
        return "ranging reads grey"
    if configured != "auto":
        return f"ranging reads {channel} (ranging.channel)"
    told = [c for c in chroma if c is not None]
    if not told:  # (`auto` keeps looking, group by group, until it has measured AUTO_GROUPS)
        return f"ranging reads {channel} (auto: no chroma noise yet to tell the chroma's resolution by)"
    rho = round(statistics.median(told), 2) + 0.0  # (+ 0.0: no "-0.00")
    if channel == "luma":
        return (f"ranging reads luma (auto: the chroma at half resolution, as JPEG 4:2:0 keeps it: its noise "
                f"correlated {rho:.2f} at 2 px)")
    if paired:  # (a pair's chroma repeated over both pixels leaves no correlation 2 px apart)
        return (f"ranging reads red (auto: the chroma's noise correlated {rho:.2f} at 2 px: shared in pairs, not "
                "interpolated as JPEG 4:2:0's is)")
    return f"ranging reads red (auto: the chroma at full resolution, its noise correlated {rho:.2f} at 2 px)"


def _repeated(frame: np.ndarray, repeated: int, pairs: int, config: Config) -> Problem:
    """The Problem of frames delivered twice (`repeated` of `pairs` consecutive pairs the same)."""
    blank = int(frame.min()) == int(frame.max())
    detail = (f"{repeated} of {pairs} pairs of consecutive laser-off frames are the same frame, pixel for pixel"
              + (f", and blank (every value {int(frame.min())})" if blank else "")
              + ": the camera delivers a frame more than once, and a laser-on frame may be a laser-off one again")
    backend = config.camera.backend
    if backend == "picamera2":
        remedy = ("the camera must deliver a fresh frame to each request: update picamera2 and libcamera (sudo apt "
                  "full-upgrade), and stop anything else that uses the camera")
    elif backend == "opencv":
        remedy = (f"the webcam hands out its last buffer again: set camera.frame_rate_hz to a rate it delivers at "
                  f"this size (v4l2-ctl -d {_device(config)} --list-formats-ext); one whose driver ignores a "
                  "one-frame buffer (OpenCV's CAP_PROP_BUFFERSIZE) needs another webcam")
    else:
        remedy = "the simulated sensor makes no noise: check [sim.sensor]"
    if blank:
        remedy = f"take the cap off the lens and light the scene; else {remedy}"
    return Problem(detail, remedy)


def _smoothing_remedy(config: Config) -> str:
    backend = config.camera.backend
    if backend == "picamera2":
        return ("edge asks libcamera for NoiseReductionMode off and Sharpness 0 (edge/hw/camera.py): update "
                "picamera2 and libcamera (sudo apt full-upgrade) so that the ISP takes them")
    if backend == "opencv":
        dev = _device(config)
        return (f"turn the webcam's own processing off: v4l2-ctl -d {dev} -c sharpness=0, and any noise "
                f"reduction control that v4l2-ctl -d {dev} -l lists")
    return "the simulator smooths nothing: the frames were changed after it"


def _device(config: Config) -> str:
    device = config.camera.device
    return f"/dev/video{device}" if device.isdigit() else device
