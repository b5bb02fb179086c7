"""What a camera's pipeline adds to a spot's position error: demosaicing's shift and snap behind a
Bayer filter, JPEG's blocks (their snap, their pull shared by the lasers' spots, the misfit their
rounding leaves). Numbers and three small functions that :class:`edge.vision.SpotFinder` applies
to the σ it measures from the noise; each constant says where its value was measured.
"""

from __future__ import annotations

import math

# A spot's position error from demosaicing (1 σ, px) that red read from a demosaiced frame carries,
# and what it grows to for a spot hardly bigger than one red pixel (demosaiced RMS radius
# DEMOSAIC_SNAP_SIZE_PX or less): such a spot snaps to the red pixel it falls on, anywhere within
# ±1 px of it (red pixels are 2 px apart: RMS 0.58 px); a site fit cannot undo that, for the red
# pixels beside it saw nothing. On the tuning family, spots of radius 0.6 px were off by 0.4-0.85
# px, radius 1 px by 0.2-0.45 px.
DEMOSAIC_PX = 0.25
DEMOSAIC_SNAP_PX = 0.55
DEMOSAIC_SNAP_SIZE_PX = 0.6
# Colour frames read in luma (JPEG 4:2:0, and 4:4:4 whose chroma JPEG quantised coarsely: `auto`)
# come from behind a Bayer filter, as every colour webcam's and Pi camera's do, though JPEG keeps too
# little of the noise for `noise_texture` to show it. The luma of a red spot is mostly its red,
# interpolated between the filter's red pixels, and carries red's shift: LUMA_DEMOSAIC_PX, all of
# it locked to the pixel grid (a nudged view keeps it). That explains part of what JPEG_COMMON_PX
# stood for in such frames, whose lasers' spots then share LUMA_JPEG_COMMON_PX. On the tuning
# family's JPEG colour frames (tuning 320-959, 280 conditions; the rest do not change): `ok` zones
# outside 2σ 25 → 18, conditions under 90 % within 2σ 12 → 10, wrong `ok` 4 → 3, |error| ÷ floor
# 2.41 → 2.28, coverage 2140 → 2148 of 2747; tuning 960-1151: 6 → 5 conditions, 2.43 → 2.27,
# coverage 613 → 611 of 783. The term alone, with JPEG_COMMON_PX kept, cost coverage (2086, 598);
# with a common term of 0.10 and 0.12 px: 2130 and 2120, 9 and 7 conditions. Red's own term for
# small spots' snap (`demosaic_px`) cost more coverage and caught no more; the term unlocked, or
# locked and not added, did not catch them.
LUMA_DEMOSAIC_PX = DEMOSAIC_PX
LUMA_JPEG_COMMON_PX = 0.08
# A spot placed by its pixels' own values behind a Bayer filter, red's and green's (raw frames;
# `fit_sites`), keeps this share of DEMOSAIC_PX, and all of the snap: no interpolation moves those
# values, but a small spot's wings on them still pull it. On tuning 0-95's raw Bayer frames, such
# spots' errors along the rows were 0.35-0.7 of their σ (RMS) with all of the term, 0.9-1.2
# without it, and 0.56-0.88 with this (97-99 % within 2σ, brightest to faintest); the whole
# term's share at 0.4 or 0.6 made a zone 11 % off `ok` (tuning-292 zone 3), this did not.
SITE_GRID_SHARE = 0.4
# A spot placed within this of a block's centre line (px) is taken as snapped there, and placed only
# to the block's width: 8/√12 px. (Uncompressed, a spot lands there by chance once in 200.)
SNAP_PX = 0.02
BLOCK_SIGMA_PX = 8.0 / math.sqrt(12.0)
# What JPEG's blocks pull a spot by in common with the other lasers' spots (1 σ, px): the lasers sit
# in one column of the image, so in one column of blocks, and their errors along the rows correlate
# (0.2-0.36 on the tuning family, about 0.1-0.18 px in common); lossless frames' do not (below 0.02).
JPEG_COMMON_PX = 0.15
# A spot's misfit (χ² per degree of freedom of a Gaussian fitted to it) grows its variance as it is
# up to this, and by its square root beyond, in JPEG frames: there the misfit is mostly the blocks'
# rounding of the spot's shape, which moves its centre far less than it distorts it. Per spot on
# tuning seeds 128-191, JPEG spots of misfit 1.5-4 and 4-10 were off by 0.88 and 0.79 of their σ
# (RMS), of misfit 10-30 and over 30 by 0.59 and 0.36: σ 2-3 × too large, so that such a reference
# came out `ambiguous` (placed too loosely) or let a far laser on another surface pass the χ² test.
JPEG_MISFIT_KNEE = 4.0


def demosaic_px(size: float, own_values: bool = False) -> tuple[float, float]:
    """What demosaicing adds to the σ of a spot of RMS radius `size` (px), and the part of it
    that is locked to the pixel grid (see edge.vision.Candidate.locked_px); `own_values`: for a spot that
    the pixels keeping their own values placed (`fit_sites`, lossless frames), which no
    interpolation moves: SITE_GRID_SHARE of the DEMOSAIC_PX base, and all of the snap.

    Red interpolated from a Bayer filter's red pixels 2 px apart: the interpolation shifts a
    small spot by up to a few tenths of a pixel, depending on the method and where the spot
    falls (OpenCV's edge-aware one by 0.2-0.4 px on average), and a spot of about one red
    pixel's size snaps to it. The snap is where the spot falls on the red pixels' grid, which
    a nudged view keeps: its part is common to the zone's views (measured on tuning 0-191
    behind a Bayer filter: 0.24 px common at a spot size of 0.75 px, 0.15 at 0.9, 0.08 at
    1.1, none at 1.4; this gives 0.23, 0.15, 0.08, 0)."""
    snap = min(max((2.0 * DEMOSAIC_SNAP_SIZE_PX - size) / DEMOSAIC_SNAP_SIZE_PX, 0.0), 1.0)
    shift = DEMOSAIC_PX + snap * (DEMOSAIC_SNAP_PX - DEMOSAIC_PX)
    if own_values:
        shift -= (1.0 - SITE_GRID_SHARE) * DEMOSAIC_PX
    return shift, snap * (DEMOSAIC_SNAP_PX - DEMOSAIC_PX)


def misfit_grow(misfit: float, jpeg: bool | None) -> float:
    """What a spot's variance is multiplied by for its fit's `misfit` (see JPEG_MISFIT_KNEE), in
    JPEG frames (`jpeg`; None: not told yet, taken as not)."""
    if not jpeg or misfit <= JPEG_MISFIT_KNEE:
        return misfit
    return JPEG_MISFIT_KNEE * math.sqrt(misfit / JPEG_MISFIT_KNEE)


def block_snapped(pixel: tuple[float, float] | list[float]) -> list[bool]:
    """Per axis (u, v): does a JPEG frame's spot at `pixel` lie on an 8 × 8 block's centre line
    (within SNAP_PX), where JPEG kept its light only as the block's mean?"""
    return [abs((x - 3.5 + 4.0) % 8.0 - 4.0) < SNAP_PX for x in pixel]
