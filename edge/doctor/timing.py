"""Are the frames taken as lit (or dark) wholly lit (or dark)? The lasers' timing, measured.

Capture takes the first frame whose first row starts after a switch has taken effect: the GPIO
write plus ``lasers.settle_ms`` (driver and diode), on the camera's timestamps. Both are beliefs: a
laser module with a soft start lights later than that, and a camera whose timestamps mark another
moment of the frame than the driver assumes (a Pi camera's SensorTimestamp) starts its frames at
another time than they say. Either way the frames taken as lit saw the laser for part of their
exposure only, and its spot comes out dimmer or not at all, in every zone, silently.

So the doctor switches each laser on just before a frame starts (the tightest timing a sweep
meets), takes the frame Capture takes as lit, one a few frames later (lit all through), and the
frame Capture takes as dark after switching it off again; and compares the spot's light in them.
Pure: frames in, a line or a Problem out.
"""

from __future__ import annotations

import math

import numpy as np

from edge.doctor.checklist import Problem
from edge.vision import SpotFinder

LIT_SHARE = 0.85  # the first lit frame must hold this much of the spot's full light
DARK_SHARE = 0.15  # and the first dark frame no more than this
WINDOW_PX = 4  # the spot's light is weighed in a (2·4 + 1)² window about it


def _difference(frame: np.ndarray, off: np.ndarray, box: tuple[slice, slice]) -> np.ndarray:
    """The laser channel of `frame` less the laser-off frame `off` in `box`, `off` scaled to
    `frame`'s room light first (flicker: a few percent of a textured wall is as much light as a dim
    spot), less the box border's median; full-scale units."""
    a, b = SpotFinder.laser_channel(frame), SpotFinder.laser_channel(off)
    sample = (slice(None, None, 4), slice(None, None, 4))
    level = float(np.median(b[sample]))
    gain = float(np.median(a[sample])) / level if level > 0 else 1.0
    diff = (a[box].astype(np.float64) - gain * b[box].astype(np.float64)) / SpotFinder.full_scale(frame)
    border = np.concatenate([diff[0], diff[-1], diff[1:-1, 0], diff[1:-1, -1]])
    return diff - np.median(border)


def light_shares(first: np.ndarray, full: np.ndarray, after: np.ndarray, off: np.ndarray,
                 pixel: tuple[float, float]) -> tuple[float, float] | None:
    """The spot's light at `pixel` in the frames `first` and `after` as shares of its light in
    `full` (lit all through), each against the laser-off frame `off`: by the spot's own shape in
    `full` as a matched filter, whose weight on the spot's core keeps the room's noise out. None
    where the window leaves the picture or `full` shows no spot there."""
    u, v, r = int(round(pixel[0])), int(round(pixel[1])), WINDOW_PX
    h, w = full.shape[:2]
    if u - r < 0 or v - r < 0 or u + r >= w or v + r >= h:
        return None
    box = (slice(v - r, v + r + 1), slice(u - r, u + r + 1))
    shape = np.maximum(_difference(full, off, box), 0.0)
    norm = float((shape * shape).sum())
    if norm <= 0.0:
        return None
    return (float((_difference(first, off, box) * shape).sum()) / norm,
            float((_difference(after, off, box) * shape).sum()) / norm)


def judge_timing(share: float, left: float, slack_ms: float, exposure_ms: float, settle_ms: float) -> str:
    """The timing line from a spot's light (:func:`light_shares`) in the first frame taken as lit
    (`share`) and in the first taken as dark after it (`left`); `slack_ms` is how long after the
    switch took effect (by the lasers' timing) the spot's row started its exposure in the first lit
    frame. Problem if either frame saw the laser switch."""
    if share < LIT_SHARE:
        # The row's exposure began `slack_ms` after the switch was believed done and saw
        # `share` of the light: it came on `slack + (1 − share)·exposure` after that.
        if share > 0.1:
            late = f"about {slack_ms + (1.0 - share) * exposure_ms:.1f} ms"
            need = settle_ms + slack_ms + (1.0 - share) * exposure_ms
        else:
            late = f"more than {slack_ms + exposure_ms:.0f} ms"
            need = settle_ms + slack_ms + exposure_ms
        raise Problem(
            f"the first frame taken as lit holds {100 * share:.0f} % of its spot's light: the light "
            f"comes {late} after lasers.settle_ms ({settle_ms:g} ms) says it has",
            f"set lasers.settle_ms = {math.ceil(need + 1.0):d} or more (a slow laser module or driver); if "
            "every laser says so, the camera's frame timestamps are late: `edge doctor -v` and the README's "
            "hardware tests")
    if left > DARK_SHARE:
        raise Problem(
            f"the first frame taken as dark after switching it off still holds {100 * left:.0f} % of its "
            f"spot's light: it goes off later than lasers.settle_ms ({settle_ms:g} ms) says",
            "raise lasers.settle_ms until this line is ok (a slow laser module or driver)")
    return f"lit frames wholly lit ({100 * share:.0f} % of the light {slack_ms:.1f} ms after the switch), " \
           f"dark ones dark ({100 * left:.0f} %)"
