"""A camera's tone curve: linear light to the values it delivers, and back.

Cameras made to be looked at store x^(1/gamma) of the light, not the light (a Pi camera's ISP unless
its tuning file says otherwise, a webcam's sRGB). Ranging wants values proportional to light: a
spot's light then adds to the room's, and noise is what the sensor made. Pure; no hardware.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from edge.schema import require

if TYPE_CHECKING:
    import numpy as np

# (numpy is imported where it is used: configuration checks its curves with require_gamma, and
# `edge doctor` reads configuration where numpy may be missing or broken.)

# Below this fraction of full scale the curve is a straight line (a power law's slope is infinite
# at 0; sRGB's toe is the same idea); at and above it x^(1/gamma), the line meeting it there.
TOE = 0.01


def tone_curve(x: np.ndarray, gamma: float) -> np.ndarray:
    """Linear values `x` (0-1 of full scale) as a camera of display gamma `gamma` delivers them;
    0 and 1 stay put (float32)."""
    import numpy as np

    x = np.asarray(x, dtype=np.float32)
    inv = 1.0 / gamma
    slope = np.float32(TOE ** (inv - 1.0))
    return np.where(x < TOE, x * slope, np.power(np.maximum(x, np.float32(TOE)), np.float32(inv))).astype(np.float32)


def linear_light(y: np.ndarray, gamma: float) -> np.ndarray:
    """The inverse of :func:`tone_curve`: delivered values `y` (0-1 of full scale) back to values
    proportional to light (float64)."""
    import numpy as np

    y = np.asarray(y, dtype=np.float64)
    inv = 1.0 / gamma
    knee = TOE**inv
    return np.where(y < knee, y / TOE ** (inv - 1.0), np.power(np.maximum(y, knee), gamma))


def require_gamma(gamma: float, key: str) -> None:
    """A configured or recorded curve's check: 1 (linear) to 3 (FieldError naming `key`)."""
    require(1.0 <= gamma <= 3.0, key, f"must be 1-3 (1: linear), got {gamma}")


@functools.lru_cache(maxsize=8)
def linear_table(dtype: np.dtype, gamma: float) -> np.ndarray:
    """Every value of an 8- or 16-bit frame delivered through `gamma`'s curve, as 16-bit values
    proportional to light: a lookup table (uint16, read-only), made once a type and curve."""
    import numpy as np

    top = np.iinfo(dtype).max
    table = np.rint(65535.0 * linear_light(np.arange(top + 1, dtype=np.float64) / top, gamma)).astype(np.uint16)
    table.flags.writeable = False
    return table


# --- the curve a camera applies, measured from two exposures of a still scene ------------------
#
# Light doubles with the exposure; a value delivered through a curve grows by 2^(1/gamma). So two
# frames of the same still scene at exposures t and k·t tell the curve: the gamma that carries the
# first's values to the second's. Values near black (the curve's toe, a sensor's black level) and
# near full scale (clipped) tell nothing and are left out.
MEASURE_FLOOR = 0.03  # of full scale, in the shorter exposure's frame (about 8 levels of 8 bits)
MEASURE_CEILING = 0.85  # of full scale, in the longer's: below clipping and a curve's shoulder
MEASURE_MIN_VALUES = 1000  # fewer values between those bounds: the picture is too dark to tell
MEASURE_MAX_VALUES = 20000  # (an even sample of the rest: enough for the median's precision)
MEASURE_GAMMAS = tuple(round(1.0 + 0.02 * i, 2) for i in range(101))  # 1.00 … 3.00
# Curves whose misfit is within a tenth (and a quarter of an 8-bit level) of the best one's fit the
# values alike.
MEASURE_ALIKE = 0.1
MEASURE_ALIKE_LEVELS = 0.25


@dataclass(frozen=True)
class MeasuredCurve:
    """What two exposures of a still scene say of a camera's tone curve."""

    gamma: float  # the display gamma whose curve best carries one exposure's values to the other's
    values: int  # how many values (pixels × colours) between the floor and the ceiling told it
    misfit: float  # the median |difference| left at that gamma (0-1 of full scale)
    # The gammas the values cannot tell from it (a misfit within MEASURE_ALIKE of its): a dim
    # picture's values all lie below the knee of the steeper curves, where every curve is straight.
    low: float = 0.0
    high: float = 0.0
    # The misfit the frames' noise alone would leave (0-1 of full scale), from the differences
    # between the measured frames and those that chose the values; 0 when they are the same.
    noise: float = 0.0


def measure_gamma(short: np.ndarray, long: np.ndarray, ratio: float,
                  chosen_by: tuple[np.ndarray, np.ndarray] | None = None) -> MeasuredCurve | None:
    """The tone curve of a camera from two frames (or means of frames, 0-1 of full scale) of the
    same still scene, `long` exposed `ratio` (> 1) times as long as `short`; None when too few
    values lie between MEASURE_FLOOR and MEASURE_CEILING to tell. The fit is robust (median of
    the differences); a scene that changed between the frames shows as a large misfit.

    `chosen_by`: other frames (short, long) of the same scene, whose values choose the values
    used. Values chosen by their own noise are biased: those just over the floor are mostly the
    ones noise lifted, and in a dim room, where most values are near it, that read a linear
    camera as gamma 2.56. Frames whose noise is not these frames' choose without that bias."""
    import numpy as np

    if not ratio > 1.0:
        raise ValueError(f"the longer exposure must be longer: ratio {ratio}")
    s = np.asarray(short, dtype=np.float64).ravel()
    g = np.asarray(long, dtype=np.float64).ravel()
    if s.shape != g.shape:
        raise ValueError(f"frames of different sizes: {np.shape(short)} and {np.shape(long)}")
    cs, cg = (s, g) if chosen_by is None else (np.asarray(f, dtype=np.float64).ravel() for f in chosen_by)
    if cs.shape != s.shape or cg.shape != s.shape:
        raise ValueError("the frames that choose the values must be the frames' size")
    use = (cs >= MEASURE_FLOOR) & (cg <= MEASURE_CEILING)
    s, g, cs, cg = s[use], g[use], cs[use], cg[use]
    if s.size < MEASURE_MIN_VALUES:
        return None
    step = -(-s.size // MEASURE_MAX_VALUES)
    s, g, cs, cg = s[::step], g[::step], cs[::step], cg[::step]
    # Each value's noise from two independent means of it (their difference has √2 of it), the
    # shorter exposure's carried to the longer by the values' own ratio; as a median |residual|.
    spread_s, spread_g = (1.4826 / math.sqrt(2.0) * float(np.median(np.abs(a - b))) for a, b in ((s, cs), (g, cg)))
    carried = float(np.median(g / np.maximum(s, 1e-9)))
    noise = 0.6745 * math.hypot(spread_g, carried * spread_s)

    @functools.cache
    def cost(gamma: float) -> float:
        predicted = tone_curve(np.minimum(ratio * linear_light(s, gamma), 1.0), gamma)
        return float(np.median(np.abs(g - predicted)))

    # Coarse, then fine about the best.
    coarse = min(MEASURE_GAMMAS[::5], key=cost)
    best = min((x for x in MEASURE_GAMMAS if abs(x - coarse) <= 0.1), key=cost)
    alike = cost(best) + max(MEASURE_ALIKE * cost(best), MEASURE_ALIKE_LEVELS / 255.0)
    alike_gammas = [x for x in MEASURE_GAMMAS[::5] if cost(x) <= alike] + [best]
    return MeasuredCurve(best, int(s.size), cost(best), min(alike_gammas), max(alike_gammas), noise)
