"""A calibration told to people: per laser its fitted ray, its change from nominal, its residuals."""

from __future__ import annotations

import math

from edge.calibration.file import Calibration
from edge.rig import Rig


def report(cal: Calibration, nominal: Rig) -> list[str]:
    """Lines for people: per laser the fitted ray, its change from nominal and its residuals."""
    lines = [f"{'laser':<10} {'origin mm':<22} {'direction':<27} {'change':>8} {'rms px':>7} "
             f"{'max px':>7} {'points':>6}"]
    for laser in cal.lasers:
        nom = {ln.name: ln for ln in nominal.lasers}.get(laser.name)
        angle = math.degrees(math.acos(min(1.0, float(laser.d @ nom.d)))) if nom else math.nan
        o = "(" + ", ".join(f"{1000 * c:.1f}" for c in laser.origin_m) + ")"
        d = "(" + ", ".join(f"{c:.5f}" for c in laser.direction) + ")"
        r = cal.residuals_px.get(laser.name, {})
        lines.append(f"{laser.name:<10} {o:<22} {d:<27} {angle:7.3f}° {r.get('rms', math.nan):7.3f} "
                     f"{r.get('max', math.nan):7.3f} {r.get('n', 0):>3}/{len(cal.distances_m)}")
    lines += range_error_lines(cal)
    if (cal.camera.fx, cal.camera.fy) != (nominal.camera.fx, nominal.camera.fy):
        lines.append(f"focal length: fx {cal.camera.fx:.2f} px, fy {cal.camera.fy:.2f} px (nominal fx "
                     f"{nominal.camera.fx:g}: {100 * (cal.camera.fx / nominal.camera.fx - 1):+.2f} %)")
    return lines


# Above this share of a range's error variance at a reported depth, the calibration is worth
# improving: a user should record more distances.
CALIBRATION_SHARE = 0.25


def range_error_lines(cal: Calibration) -> list[str]:
    """What the calibration's uncertainty means for ranging: per laser and combined, the 1-σ range
    error it adds at 1, 2 and 4 m, and that of one range taken as its frames were (a board at rest:
    one view); and whether more
    distances would help."""
    errors = cal.range_errors()
    if not errors:
        return ["range error: unknown (this calibration keeps no covariance: an older file, or "
                "--fit-focal)"]
    depths = next(iter(errors.values())).depths_m

    def mm(xs) -> str:
        return "".join(f"{'-':>8}" if x is None else f"{1000 * x:8.1f}" for x in xs)

    head = "".join(f"{f'{d:g} m':>8}" for d in depths)
    width = len(head)
    lines = [f"{'range error, 1 σ (mm)':<22}{'from the calibration':>{width}}   {'one range, as recorded':>{width}}",
             f"{'':<22}{head}   {head}"]
    for name, e in errors.items():
        lines.append(f"{name:<22}{mm(e.calibration)}   {mm(e.one_range)}")
    lines += _scatter_lines(cal)
    combined = errors.get("combined")
    if combined is not None:
        worst = [(d, c * c / o / o) for d, c, o in zip(depths, combined.calibration, combined.one_range)
                 if c is not None and o]
        big = [(d, share) for d, share in worst if share > CALIBRATION_SHARE]
        if big:
            d, share = max(big, key=lambda x: x[1])
            lines.append(f"at {d:g} m the calibration makes {100 * share:.0f} % of a range's error variance: "
                         "record the board at more distances (farther ones above all) to lower it")
        else:
            lines.append("the calibration adds little to a range's error: more distances would not help much")
    return lines


def _scatter_lines(cal: Calibration) -> list[str]:
    """One spot's scatter as the fit saw it: of a spot that clipped the sensor and of one that did
    not; and whether the latter rests on one distance only."""
    if len(cal.spot_sigma_px) != 2:
        return []
    u, v = cal.spot_sigma_px
    why = "speckle and noise that these frames do not average (a board at rest: one view per distance)"
    if len(cal.clipped_spot_sigma_px) != 2 or cal.clipped_within_m <= 0:
        return [f"one spot scatters {u:.3f} px (u), {v:.3f} px (v) about its line as recorded: {why}"]
    cu, cv = cal.clipped_spot_sigma_px
    within = cal.clipped_within_m
    lines = [f"one spot scatters {cu:.3f} px (u), {cv:.3f} px (v) about its line as recorded where the "
             f"spots clipped the sensor (up to {within:g} m), {u:.3f} px, {v:.3f} px where they did not "
             f"(clipping hides some speckle): {why}"]
    beyond = sorted(d for d in set(cal.distances_m) if d > within)
    if len(beyond) <= 1:
        where = f"the spots at {beyond[0]:g} m" if beyond else "no spot"
        lines.append(f"only {where} did not clip: the range error beyond {within:g} m rests on "
                     "them; record the board at more distances beyond that (or nudged) to know it")
    return lines
