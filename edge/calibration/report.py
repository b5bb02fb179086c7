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
    if (cal.camera.fx, cal.camera.fy) != (nominal.camera.fx, nominal.camera.fy):
        lines.append(f"focal length: fx {cal.camera.fx:.2f} px, fy {cal.camera.fy:.2f} px (nominal fx "
                     f"{nominal.camera.fx:g}: {100 * (cal.camera.fx / nominal.camera.fx - 1):+.2f} %)")
    return lines
