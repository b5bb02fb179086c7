"""The camera's tone curve, measured: is what it delivers proportional to light, as ranging assumes?

Ranging adds a spot's light to the room's and weighs pixels by the sensor's noise: both hold in
linear light. A Pi camera's ISP applies its tuning file's curve unless edge replaced it
(``camera.gamma``), a webcam delivers sRGB; ranging undoes the curve ``ranging.frame_gamma`` names.
If the two differ, spots in dark parts of the picture are read several times too faint or bright
and their noise wrongly, and nothing else would say so: the first hour on a new camera should.

The doctor takes the laser-off scene at the configured exposure and at another (4 × as long where
the frame period allows, else a quarter), and :func:`edge.tone.measure_gamma` finds the curve that
carries the one to the other. Pure: mean frames and the configuration in, the line out.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

from edge.doctor.checklist import NotRun, Problem

if TYPE_CHECKING:
    import numpy as np

    from edge.config import Config
    from edge.hw.camera import CameraSettings

EXPOSURE_RATIO = 4.0  # the second exposure's to the configured one's, where the frame period allows
LONGEST_SHARE = 0.9  # of the frame period: the longest exposure asked for
GAMMA_TOLERANCE = 0.15  # a measured gamma this near the one ranging undoes is that one
BRIGHT_TARGET = 0.25  # a too dark picture is measured again with its brightest values lifted to this
MAX_GAIN = 8.0  # (a Pi camera v2's sensor reaches 10.7)
UNTOLD_SPAN = 0.5  # gammas this far apart fitting the values alike: the picture cannot tell the curve
POWER_LAW_LEVELS = 4.0  # a median difference this many levels over twice the noise's: a curve of another shape
MISFIT_LEVELS = 12.0  # a median difference left over this many 8-bit levels: the scene changed (noise
# leaves 1-3 at a 4 × ratio)


class TooDark(NotRun):
    """The frames are too dark to tell the curve (more gain may make them bright enough)."""


def brighter_gain(means: Sequence[np.ndarray], settings: CameraSettings) -> float | None:
    """An analogue gain that lifts the brightest of a too dark picture (`means`: its mean frames at
    the configured exposure, 0-1 of full scale) to about BRIGHT_TARGET, at most MAX_GAIN; None if
    that is not half as much again as the configured gain. A sensor's analogue gain multiplies the
    light before the camera's curve, as a longer exposure does, so the curve is read as well."""
    import numpy as np

    brightest = float(np.percentile(means[-1], 95.0))
    gain = min(settings.analogue_gain * BRIGHT_TARGET / max(brightest, 1e-3), MAX_GAIN)
    return gain if gain >= 1.5 * settings.analogue_gain else None


def other_exposure_us(settings: CameraSettings) -> float:
    """The exposure to compare the configured one with: EXPOSURE_RATIO × as long where the frame
    period leaves room for 1.5 × or more, else EXPOSURE_RATIO × as short."""
    longest = LONGEST_SHARE * 1e6 / settings.frame_rate_hz
    longer = min(EXPOSURE_RATIO * settings.exposure_us, longest)
    if longer >= 1.5 * settings.exposure_us:
        return longer
    return settings.exposure_us / EXPOSURE_RATIO


def judge(configured: Sequence[np.ndarray], configured_us: float, other: Sequence[np.ndarray], other_us: float,
          config: Config) -> str:
    """The tone curve's line from laser-off frames at the configured exposure and at the other
    (both in µs, as the frames reported them): for each, the mean of its frames (0-1 of full
    scale), or the means of two halves of them, of which the first chooses the values the second's
    are measured by (:func:`edge.tone.measure_gamma`). Problem if it is not the curve ranging
    undoes, NotRun if the frames cannot tell."""
    from edge.tone import measure_gamma

    (short, short_us), (long, long_us) = sorted([(configured, configured_us), (other, other_us)], key=lambda p: p[1])
    # (One mean chooses its own values.)
    measured = measure_gamma(short[-1], long[-1], long_us / short_us, chosen_by=(short[0], long[0]))
    exposures = f"{short_us / 1e3:g} and {long_us / 1e3:g} ms"
    if measured is None:
        raise TooDark(f"the picture is too dark to tell at {exposures}: light the room, or aim the unit at a "
                      "lit wall ([rangefinder] pan_deg, tilt_deg), and run the doctor again")
    if measured.high - measured.low > UNTOLD_SPAN:
        raise TooDark(f"the picture is too dark to tell the curve at {exposures}: its values fit gammas "
                      f"{measured.low:.1f}-{measured.high:.1f} alike; light the room, or aim the unit at a "
                      "lit, pale wall ([rangefinder] pan_deg, tilt_deg), and run the doctor again")
    if measured.misfit * 255.0 > MISFIT_LEVELS:
        raise NotRun(f"the picture changed between the exposures of {exposures} (a median "
                     f"{measured.misfit * 255.0:.0f} levels off any curve): keep the room still, lights "
                     "steady, and run the doctor again")
    expected = config.ranging.frame_gamma
    linear = " (values proportional to light)" if abs(measured.gamma - 1.0) <= GAMMA_TOLERANCE else ""
    # A misfit well over what the frames' noise leaves: the curve has another shape.
    off_law = (measured.misfit - 2.0 * measured.noise) * 255.0 > POWER_LAW_LEVELS
    shape = f", and no power law (a median {measured.misfit * 255.0:.0f} levels off the nearest)" if off_law else ""
    found = f"gamma {measured.gamma:.2f}{linear}{shape} from {measured.values} values at {exposures}"
    if abs(measured.gamma - expected) <= GAMMA_TOLERANCE:
        return f"{found}; ranging undoes {expected:g} (ranging.frame_gamma)"
    backend = config.camera.backend
    detail = f"frames come through a tone curve of {found}, but ranging undoes {expected:g} (ranging.frame_gamma)"
    if backend == "picamera2":
        raise Problem(detail, f"the ISP did not take edge's curve (camera.gamma = {config.camera.gamma:g}): "
                              "`edge doctor -v` shows the camera's warning about its tuning file; update "
                              "picamera2 and libcamera (sudo apt full-upgrade)")
    if backend == "opencv":
        raise Problem(detail, f"set ranging.frame_gamma = {measured.gamma:.1f} (a webcam's sRGB is about 2.2)")
    raise Problem(detail, f"set ranging.frame_gamma = {measured.gamma:.1f}, or sim.sensor.gamma = {expected:g}")
