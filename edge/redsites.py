"""A Bayer filter that colour frames' noise does not show, told by bright spots' red bends.

JPEG at high quality keeps too little of a dim room's noise for a filter's pattern to show in it
(`edge.framenoise.noise_texture` looks there first); the spots themselves still show it, for
demosaicing interpolates red linearly between the filter's red pixels. Pure numpy: the finder
hands its bright spots and the frames to a `SiteLook` it keeps.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Protocol

import numpy as np

# A Bayer filter that the noise does not show (JPEG at high quality keeps too little of a dim room's
# noise for its pattern) shows in bright spots: demosaicing interpolates red linearly between the
# red pixels, so a spot's red bends at them and runs straight between them. Spots of SITE_SPOT_SNR
# or more, each SITE_SPOT_APART_PX from every one counted before, are summed, and looked at when
# SITE_LOOKS' counts of them are in: where their bends along rows and along columns are each that
# look's ratio × or more at one parity than at the other, red is read, and spots are placed by its
# red pixels as behind a filter that the noise shows. (Tuning 0-383's colour frames without a
# filter came to at most 2.4, 2.2, 1.8 and 1.4 at 6, 12, 24 and 48 spots; behind a bilinear filter
# at JPEG quality 87-94 with 4:4:4 chroma, 4-15. JPEG's 4:2:0 chroma, which keeps no pixel's own
# red, came to 2-4, and fitting its red pixels placed spots worse: the looks leave it be.)
SITE_SPOT_SNR = 20.0
SITE_SPOT_APART_PX = 1.0  # (a sampled spot bends most at its nearest pixel: one spot counted again passes for a filter)
SITE_LOOKS = ((6, 5.0), (12, 4.0), (24, 3.5), (48, 3.0))
SITE_SPOTS = SITE_LOOKS[-1][0]


class Spot(Protocol):
    """What a look needs of a spot (`edge.vision.Candidate` has it)."""

    pixel: np.ndarray  # (2,) sub-pixel (u, v)
    snr: float


def curvature_by_parity(window: np.ndarray, u0: int, v0: int) -> np.ndarray | None:
    """Where a spot's red bends: the shares of its second differences' energy along rows at even
    and at odd columns, and along columns at even and at odd rows (4,), from a (2r + 3)² window of
    red (laser-on minus laser-off) centred on pixel (u0, v0); None where it is flat. Demosaicing
    interpolates red linearly between a Bayer filter's red pixels 2 px apart: it bends only at them."""
    r = (window.shape[0] - 3) // 2
    core = window[1:-1, 1:-1]
    along_u = window[1:-1, :-2] - 2.0 * core + window[1:-1, 2:]
    along_v = window[:-2, 1:-1] - 2.0 * core + window[2:, 1:-1]
    odd_col = (u0 - r + np.arange(2 * r + 1)) % 2 == 1
    odd_row = (v0 - r + np.arange(2 * r + 1)) % 2 == 1
    cols = along_u * along_u
    rows = along_v * along_v
    by_col = (float(cols[:, ~odd_col].sum()), float(cols[:, odd_col].sum()))
    by_row = (float(rows[~odd_row, :].sum()), float(rows[odd_row, :].sum()))
    cols_total, rows_total = sum(by_col), sum(by_row)
    if cols_total <= 0.0 or rows_total <= 0.0:
        return None
    return np.array([by_col[0] / cols_total, by_col[1] / cols_total, by_row[0] / rows_total, by_row[1] / rows_total])


class SiteLook:
    """Whether colour frames whose noise shows no Bayer filter come from behind one, and at which
    parity its red pixels lie: told by bright spots' red bends, summed over the spots a finder
    places until SITE_SPOTS of them are in (see SITE_LOOKS)."""

    def __init__(self) -> None:
        self._curvature = np.zeros(4)  # the spots' second differences by parity (curvature_by_parity), summed
        self.spots = 0  # how many are summed
        self._at: list[tuple[float, float]] = []  # where they were (px)
        self.parity: int | None = None  # the red pixels' (row, column) parity, 2·row + column; None: none seen

    @property
    def looking(self) -> bool:
        return self.spots < SITE_SPOTS

    def look(self, spots: Sequence[Spot], on: Sequence[np.ndarray], off: Sequence[np.ndarray], gain: float) -> bool:
        """Sum the red bends of bright `spots` (laser-on minus `gain` × laser-off frames); True when
        this look told the red pixels' parity."""
        height, width = on[0].shape[:2]
        before = self.spots
        for c in spots:
            if c.snr < SITE_SPOT_SNR or self.spots >= SITE_SPOTS:
                continue
            u, v = c.pixel.tolist()
            # (The same spot again, a unit aimed at one wall, tells nothing new.)
            if any(math.hypot(u - a, v - b) < SITE_SPOT_APART_PX for a, b in self._at):
                continue
            u0, v0 = int(round(u)), int(round(v))
            r = 3
            if u0 - r - 1 < 0 or v0 - r - 1 < 0 or u0 + r + 2 > width or v0 + r + 2 > height:
                continue
            rows, cols = slice(v0 - r - 1, v0 + r + 2), slice(u0 - r - 1, u0 + r + 2)
            red = np.asarray(sum([f[rows, cols, 2].astype(np.float64) for f in on]) / len(on))
            red -= gain * sum([f[rows, cols, 2].astype(np.float64) for f in off]) / len(off)
            shares = curvature_by_parity(red, u0, v0)
            if shares is not None:
                self._curvature += shares
                self.spots += 1
                self._at.append((u, v))
        ratio = next((told for count, told in SITE_LOOKS if before < count <= self.spots), None)
        if ratio is None:
            return False
        col_even, col_odd, row_even, row_odd = self._curvature.tolist()
        cols_told = max(col_even, col_odd) >= ratio * max(min(col_even, col_odd), 1e-12)
        rows_told = max(row_even, row_odd) >= ratio * max(min(row_even, row_odd), 1e-12)
        if not (cols_told and rows_told):
            return False
        self.parity = 2 * int(row_odd > row_even) + int(col_odd > col_even)
        return True
