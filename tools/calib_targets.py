"""Calibration from a board at rest, measured against the simulator's truth (issue 15).

For each seed: a rig built with every laser tilted 0.2–0.4° about a random axis and shifted by up to
2 mm; a recording of a board at rest (one pose a distance, 2 laser-off + 2 laser-on frames, no
nudges) at the calibration distances, fitted as ``edge calibrate`` does; then

- each fitted ray against the true one (angle, and origin: the beams' gap at z = 0);
- a second, independent at-rest board recording (another seed, other distances) ranged with the
  calibration as ``edge calibrate --check`` does: measured range error per distance beside the error
  the calibration predicts there;
- a sweep of the office ranged with the fitted and with the true rig: the ratio of their mean
  |relative error| over the zones both range.

    nice -n 19 .venv/bin/python tools/calib_targets.py --seeds 20     # after ./dev has made .venv
    .venv/bin/python tools/calib_targets.py --seeds 10 --first 11 --json out.json
    .venv/bin/python tools/calib_targets.py --seeds 20 --no-sweep --speckle 0   # below speckle
    .venv/bin/python tools/calib_targets.py --seeds 10 --set sim.sensor.gamma=2.2   # a display gamma

Per check distance it also looks rig by rig: each laser's error over its own predicted 1 σ (z), and
the rig whose errors are the most over their prediction.

It asserts nothing: it prints figures (and writes them as JSON with --json).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

CAL_DISTANCES = (0.4, 0.6, 1.0, 1.5, 2.0, 3.0)
CHECK_DISTANCES = (1.0, 2.0, 4.0)


def mis_built(rig, seed: int, angle_deg=(0.2, 0.4), offset_m: float = 0.002):
    """`rig` with each laser tilted by an angle uniform in `angle_deg` about a random axis ⟂ to its
    beam, and its origin shifted by a random vector of length up to `offset_m`."""
    rng = np.random.default_rng([seed, 0xCA1B])
    lasers = []
    for laser in rig.lasers:
        d = laser.d
        axis = np.cross(d, rng.normal(size=3))
        axis /= np.linalg.norm(axis)
        a = math.radians(rng.uniform(*angle_deg))
        d_new = d * math.cos(a) + np.cross(axis, d) * math.sin(a)
        shift = rng.normal(size=3)
        o_new = laser.o + shift / np.linalg.norm(shift) * rng.uniform(0.0, offset_m)
        lasers.append(replace(laser, origin_m=(float(o_new[0]), float(o_new[1]), float(o_new[2])),
                              direction=(float(d_new[0]), float(d_new[1]), float(d_new[2]))))
    return replace(rig, lasers=tuple(lasers))


def ray_errors(cal, truth) -> dict[str, dict[str, float]]:
    """Per laser: angle and origin (gap at z = 0) from the truth; where the calibration keeps its
    covariance, also their predicted 1 σ and the error's χ² (4 parameters: 9.5 at 95 %)."""
    out = {}
    for laser in cal.lasers:
        true = truth.laser(laser.name)
        angle = math.degrees(math.acos(min(1.0, float(laser.d @ true.d))))
        origin = float(np.linalg.norm(laser.point_at_depth(0.0) - true.point_at_depth(0.0)))
        out[laser.name] = {"angle_deg": angle, "origin_mm": 1000 * origin}
        cov = getattr(cal, "ray_covariance", {}).get(laser.name)
        if cov is not None:
            from edge.calibration.uncertainty import ray_parameters

            c = np.array(cov)
            delta = ray_parameters(laser) - ray_parameters(true)
            out[laser.name].update(sigma_angle_deg=math.degrees(math.sqrt(c[0, 0] + c[2, 2])),
                                   sigma_origin_mm=1000 * math.sqrt(c[1, 1] + c[3, 3]),
                                   chi2=float(delta @ np.linalg.solve(c, delta)))
    return out


def ranging_ratio(config, truth, cal, folder: Path, seed: int) -> dict[str, float]:
    from edge.calibration.file import Calibration
    from edge.recording import read_recording
    from edge.replay import Replayer, ranging_for
    from edge.sim.record import record_sweep

    sweep = replace(config, sim=replace(config.sim, seed=seed + 5000))
    rec = read_recording(record_sweep(sweep, folder / "sweep", zones=16, rig=truth))
    errors = {}
    for name, rig in (("true", Calibration.from_rig(truth).apply(rec.rig)), ("calibrated", cal.apply(rec.rig))):
        errs = {}
        for zone, result in zip(rec.zones, Replayer(rig, config=ranging_for(rec, config.ranging)).zones(rec)):
            t = (zone.truth or {}).get("range_m")
            if result.status == "ok" and t:
                errs[zone.index] = abs(result.range_m / t - 1)
        errors[name] = errs
    both = sorted(set(errors["true"]) & set(errors["calibrated"]))
    true = float(np.mean([errors["true"][i] for i in both]))
    calibrated = float(np.mean([errors["calibrated"][i] for i in both]))
    return {"zones": len(both), "true": true, "calibrated": calibrated, "ratio": calibrated / true}


def one_seed(seed: int, folder: Path, sweep: bool, speckle: float = 1.0, extra: tuple[str, ...] = ()) -> dict:
    from edge.calibration.check import check_calibration
    from edge.calibration.fit import fit_calibration
    from edge.config import load_config
    from edge.recording import read_recording
    from edge.sim.record import record_targets

    config = load_config(None, ["sweep.nudge_deg=0", f"sim.seed={seed}", f"sim.beam.speckle={speckle}", *extra])
    truth = mis_built(config.rig.build(), seed)
    rec = read_recording(record_targets(config, list(CAL_DISTANCES), folder / "cal", pairs=2, rig=truth))
    cal = fit_calibration(rec, CAL_DISTANCES)
    row: dict = {"seed": seed, "rays": ray_errors(cal, truth)}
    errors = cal.range_errors(CHECK_DISTANCES) if hasattr(cal, "range_errors") else {}
    if errors:
        row["predicted"] = {n: {"total": list(e.one_range), "calibration": list(e.calibration)}
                            for n, e in errors.items()}
    second = replace(config, sim=replace(config.sim, seed=seed + 1000))
    check = read_recording(record_targets(second, list(CHECK_DISTANCES), folder / "check", pairs=2, rig=truth))
    row["check"] = [{"distance_m": z.distance_m, "errors_m": {n: z.error(n) for n in z.depth_m},
                     "combined_m": z.combined_error} for z in check_calibration(check, CHECK_DISTANCES, cal)]
    if sweep:
        row["ranging"] = ranging_ratio(load_config(None, [f"sim.seed={seed}", *extra]), truth, cal, folder, seed)
    return row


def per_rig(rows: list[dict], names: list[str], j: int) -> str:
    """The check against the prediction rig by rig at the j-th check distance: each laser's error
    over its own predicted 1 σ (z; an honest prediction gives rms 1, |z| > 2 one time in 20), and the
    rig whose lasers' rms error is the most over their rms prediction. Three lasers a rig scatter
    that ratio widely even when the prediction is right (90 % of rigs within 0.34-1.61)."""
    z, worst = [], (0.0, 0)
    combined = []
    for r in rows:
        got = [(e, r["predicted"][n]["total"][j]) for n in names
               if (e := r["check"][j]["errors_m"][n]) is not None and r["predicted"][n]["total"][j]]
        z += [e / p for e, p in got]
        if got:
            ratio = math.sqrt(sum(e * e for e, _ in got) / sum(p * p for _, p in got))
            worst = max(worst, (ratio, r["seed"]))
        c, p = r["check"][j]["combined_m"], r["predicted"]["combined"]["total"][j]
        if c is not None and p:
            combined.append(abs(c) / p)
    zs = np.array(z)
    rms, beyond = math.sqrt(float(np.mean(zs**2))), 100 * float(np.mean(np.abs(zs) > 2))
    return (f"per rig: z rms {rms:.2f}, |z| > 2 {beyond:.0f} % "
            f"(5 % expected); worst rig {worst[0]:.2f} (seed {worst[1]}); combined |z| max {max(combined):.2f}")


def summary(rows: list[dict]) -> list[str]:
    lines = []
    names = list(rows[0]["rays"])
    angle = np.array([[r["rays"][n]["angle_deg"] for n in names] for r in rows])
    origin = np.array([[r["rays"][n]["origin_mm"] for n in names] for r in rows])
    lines.append(f"rays ({len(rows)} rigs × {len(names)} lasers): angle error max {angle.max():.4f}° "
                 f"mean {angle.mean():.4f}°; origin error max {origin.max():.2f} mm mean {origin.mean():.2f} mm")
    for k, n in enumerate(names):
        lines.append(f"  {n:<9} angle " + " ".join(f"{a:.4f}" for a in angle[:, k])
                     + "  origin mm " + " ".join(f"{o:.2f}" for o in origin[:, k]))
    if "chi2" in rows[0]["rays"][names[0]]:
        sa = np.array([[r["rays"][n]["sigma_angle_deg"] for n in names] for r in rows])
        so = np.array([[r["rays"][n]["sigma_origin_mm"] for n in names] for r in rows])
        chi2 = np.array([[r["rays"][n]["chi2"] for n in names] for r in rows])
        lines.append(f"  predicted 1 σ: angle {sa.mean():.4f}° (max {sa.max():.4f}°), origin {so.mean():.2f} mm; "
                     f"error χ² (4 parameters) mean {chi2.mean():.2f} (expected 4), "
                     f"{int((chi2 > 9.49).sum())} of {chi2.size} over its 95 % point")
    lines.append("check (a second at-rest recording): RMS range error over rigs in mm, measured/predicted "
                 "(predicted from the calibration alone)")
    for j, dist in enumerate(CHECK_DISTANCES):
        parts = []
        for n in [*names, "combined"]:
            errs = [r["check"][j]["combined_m"] if n == "combined" else r["check"][j]["errors_m"][n]
                    for r in rows]
            errs = [e for e in errs if e is not None]
            meas = math.sqrt(float(np.mean(np.square(errs)))) if errs else math.nan
            pred = [r["predicted"][n]["total"][j] for r in rows if "predicted" in r]
            p = math.sqrt(float(np.mean(np.square(pred)))) if pred else math.nan
            cal = [r["predicted"][n]["calibration"][j] for r in rows if "predicted" in r]
            c = math.sqrt(float(np.mean(np.square(cal)))) if cal else math.nan
            parts.append(f"{n} {1000 * meas:.1f}/{1000 * p:.1f} ({1000 * c:.1f})")
        lines.append(f"  {dist:g} m: " + ", ".join(parts))
        if all("predicted" in r for r in rows):
            lines.append("        " + per_rig(rows, names, j))
    ranging = [r["ranging"] for r in rows if "ranging" in r]
    if ranging:
        true = float(np.mean([g["true"] for g in ranging]))
        calibrated = float(np.mean([g["calibrated"] for g in ranging]))
        lines.append(f"sweep ranging (office, 16 zones × {len(ranging)}): mean |error| true rig "
                     f"{100 * true:.2f} %, calibrated {100 * calibrated:.2f} %, ratio {calibrated / true:.2f} "
                     "(per rig " + " ".join(f"{g['ratio']:.2f}" for g in ranging) + ")")
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=6, help="how many mis-built rigs (seeds 1..N)")
    p.add_argument("--first", type=int, default=1, help="first seed")
    p.add_argument("--no-sweep", action="store_true", help="skip the sweep ranging (faster)")
    p.add_argument("--json", metavar="FILE", help="also write every figure here")
    p.add_argument("--speckle", type=float, default=1.0,
                   help="the simulator's speckle (0: none; the rays then show what the frames' noise and the "
                        "spot finder leave, the floor below speckle's)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="a configuration override for every recording (e.g. sim.sensor.gamma=2.2)")
    args = p.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory(prefix="calib-targets-") as tmp:
        for seed in range(args.first, args.first + args.seeds):
            folder = Path(tmp) / f"seed-{seed}"
            folder.mkdir()
            rows.append(one_seed(seed, folder, not args.no_sweep, args.speckle, tuple(args.set)))
            print(f"seed {seed}: " + ", ".join(f"{n} {e['angle_deg']:.4f}° {e['origin_mm']:.2f} mm"
                                               for n, e in rows[-1]["rays"].items()), file=sys.stderr)
    print("\n".join(summary(rows)))
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
