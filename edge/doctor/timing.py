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
import statistics
from dataclasses import dataclass

import numpy as np

from edge.doctor.checklist import Problem
from edge.tone import linear_table
from edge.vision import SpotFinder

LIT_SHARE = 0.85  # the first lit frame must hold this much of the spot's full light
DARK_SHARE = 0.15  # and the first dark frame no more than this
SURE_SIGMAS = 3.0  # and only a shortfall (or excess) this many times the frames' noise counts
WINDOW_PX = 4  # the spot's light is weighed in a (2·4 + 1)² window about it


@dataclass(frozen=True)
class Shares:
    """A spot's light in the first frame taken as lit (`lit`) and in the first taken as dark after
    it (`left`), as shares of its light in a frame lit all through; `sigma` is either's 1 σ from
    the frames' own noise about the spot."""

    lit: float
    left: float
    sigma: float

    @staticmethod
    def mean(each: list[Shares]) -> Shares:
        """The shares of several switchings, averaged; their σ the pixels' noise (independent from
        one switching to the next), or the shares' own scatter where it says more: JPEG rounds a
        spot's blocks anew in every frame, which no noise beside the spot shows."""
        n = len(each)
        noise = math.sqrt(sum(s.sigma**2 for s in each)) / n
        scatter = 0.0
        if n > 1:
            spread = max(statistics.stdev([s.lit for s in each]), statistics.stdev([s.left for s in each]))
            scatter = spread / math.sqrt(n)
        return Shares(sum(s.lit for s in each) / n, sum(s.left for s in each) / n, max(noise, scatter))


def _linear(frame: np.ndarray, gamma: float) -> tuple[np.ndarray, float]:
    """The laser channel of `frame` in values proportional to light (the tone curve `gamma` undone,
    as ranging undoes it), and its full scale."""
    plane = SpotFinder.laser_channel(frame)
    if gamma == 1.0:
        return plane, SpotFinder.full_scale(frame)
    return linear_table(frame.dtype, gamma).take(plane), 65535.0


_SAMPLE = (slice(None, None, 4), slice(None, None, 4))  # every 4th pixel each way: a picture's room light


def _difference(a: np.ndarray, b: np.ndarray, b_level: float, scale: float, box: tuple[slice, slice]
                ) -> tuple[np.ndarray, float]:
    """Plane `a` less plane `b` in `box` (full-scale units), `b` scaled to `a`'s room light first
    (flicker: a few percent of a textured wall is as much light as a dim spot; `b_level`: the
    median of `b`'s sample), less the box border's median; and the border's robust spread (the
    pixels' noise there)."""
    gain = float(np.median(a[_SAMPLE])) / b_level if b_level > 0 else 1.0
    diff = (a[box].astype(np.float64) - gain * b[box].astype(np.float64)) / scale
    border = np.concatenate([diff[0], diff[-1], diff[1:-1, 0], diff[1:-1, -1]])
    centre = float(np.median(border))
    return diff - centre, 1.4826 * float(np.median(np.abs(border - centre)))


def light_shares(first: np.ndarray, full: np.ndarray, again: np.ndarray, after: np.ndarray, off: np.ndarray,
                 pixel: tuple[float, float], gamma: float = 1.0) -> Shares | None:
    """The spot's light at `pixel` in the frames `first` and `after` as shares of its light in
    `full` (lit all through), each against the laser-off frame `off`, in linear light (`gamma`:
    the frames' tone curve). Weighed by the spot's own shape in `again`, another frame lit all
    through, as a matched filter, whose weight on the spot's core keeps the room's noise out: a
    shape taken from `full` itself would hold `full`'s noise, which it alone would match (a faint
    spot's share read 75 % so). None where the window leaves the picture or `again` shows no spot
    there."""
    u, v, r = int(round(pixel[0])), int(round(pixel[1])), WINDOW_PX
    h, w = full.shape[:2]
    if u - r < 0 or v - r < 0 or u + r >= w or v + r >= h:
        return None
    box = (slice(v - r, v + r + 1), slice(u - r, u + r + 1))
    dark, scale = _linear(off, gamma)
    dark_level = float(np.median(dark[_SAMPLE]))
    diffs = [_difference(_linear(f, gamma)[0], dark, dark_level, scale, box) for f in (again, full, first, after)]
    shape = np.maximum(diffs[0][0], 0.0)
    whole = float((diffs[1][0] * shape).sum())
    if whole <= 0.0:
        return None
    # Each share's noise: the pixels' (at least a level's rounding, which JPEG can leave alone on a
    # flat wall) through the filter, in both the frame's light and the whole light it is divided by.
    level = 1.0 / (SpotFinder.full_scale(full) * math.sqrt(6.0))
    if gamma != 1.0:  # a level's step in linear light where the spot is
        table = linear_table(full.dtype, gamma)
        q = min(int(np.median(SpotFinder.laser_channel(full)[box])), table.size - 2)
        level = (int(table[q + 1]) - int(table[q])) / 65535.0 / math.sqrt(6.0)
    noise = max(float(np.median([spread for _, spread in diffs])), level)
    return Shares(float((diffs[2][0] * shape).sum()) / whole, float((diffs[3][0] * shape).sum()) / whole,
                  noise * math.sqrt(2.0 * float((shape * shape).sum())) / whole)


def judge_timing(shares: Shares, slack_ms: float, exposure_ms: float, settle_ms: float) -> str:
    """The timing line from a spot's light (:func:`light_shares`) in the first frame taken as lit
    and in the first taken as dark after it; `slack_ms` is how long after the switch took effect
    (by the lasers' timing) the spot's row started its exposure in the first lit frame. Problem if
    either frame saw the laser switch: by more than LIT_SHARE or DARK_SHARE allow, and by more than
    SURE_SIGMAS of the frames' noise (a faint spot in JPEG frames reads ±20 %)."""
    share, left, sigma = shares.lit, shares.left, shares.sigma
    if share < LIT_SHARE and 1.0 - share > SURE_SIGMAS * sigma:
        # The row's exposure began `slack_ms` after the switch was believed done and saw
        # `share` of the light: it came on `slack + (1 − share)·exposure` after that.
        if share > 0.1:
            late = f"about {slack_ms + (1.0 - share) * exposure_ms:.1f} ms"
            need = settle_ms + slack_ms + (1.0 - share) * exposure_ms
        else:
            late = f"more than {slack_ms + exposure_ms:.0f} ms"
            need = settle_ms + slack_ms + exposure_ms
        raise Problem(
            f"the first frame taken as lit holds {_pct(share)} % of its spot's light: the light "
            f"comes {late} after lasers.settle_ms ({settle_ms:g} ms) says it has",
            f"set lasers.settle_ms = {math.ceil(need + 1.0):d} or more (a slow laser module or driver); if "
            "every laser says so, the camera's frame timestamps are late: `edge doctor -v` and the README's "
            "hardware tests")
    if left > DARK_SHARE and left > SURE_SIGMAS * sigma:
        raise Problem(
            f"the first frame taken as dark after switching it off still holds {_pct(left)} % of its "
            f"spot's light: it goes off later than lasers.settle_ms ({settle_ms:g} ms) says",
            "raise lasers.settle_ms until this line is ok (a slow laser module or driver)")
    return (f"lit frames wholly lit ({_pct(share)} % of the light {slack_ms:.1f} ms after the switch), "
            f"dark ones dark ({_pct(left)} %; ±{_pct(sigma)} % as measured)")


def _pct(share: float) -> int:
    """A share in whole percent (never "-0")."""
    return int(round(100.0 * share))
