"""A camera's tone curve: linear light to the values it delivers, and back.

Cameras made to be looked at store x^(1/gamma) of the light, not the light (a Pi camera's ISP unless
its tuning file says otherwise, a webcam's sRGB). Ranging wants values proportional to light: a
spot's light then adds to the room's, and noise is what the sensor made. Pure; no hardware.
"""

from __future__ import annotations

import functools
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
