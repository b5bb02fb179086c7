"""How well `edge.motion`'s steadier finds the turns of a kept accuracy family's moving rigs.

Each moving zone's laser-off frames carry their true turn in the zone's truth (`off_turn_deg`,
recorded since the family judged moving rigs on their frames turned back). Per laser-on/laser-off
pair, the steadier's turn is compared with the true one where it matters, at the reference spot's
true pixel: how far each maps that pixel (px). A turn the steadier refused (or found none) leaves
the pair as it came, so its error is the whole true shift there. Prints the pairs by kind of frames:
the share of turns taken, and the median and 90th percentile of the error, taken or not.

    .venv/bin/python tools/turn_errors.py /tmp/k/t2368            # a folder of --keep
    .venv/bin/python tools/turn_errors.py /tmp/k/t2368 --json out.json

It asserts nothing; families kept before the turns were recorded are refused by name.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np


def condition_pairs(folder: str, doc: dict, zones: int) -> list[dict]:
    """The pairs of one kept moving condition (`doc`: its Condition's JSON), each as a row."""
    from edge import isp
    from edge.accuracy.bench import condition_config
    from edge.accuracy.conditions import Condition
    from edge.accuracy.oracle import ZoneOracle
    from edge.accuracy.unturned import TURNS_KEY
    from edge.ranging import Ranger
    from edge.recording import read_recording

    cond = Condition.from_json(doc)
    config = condition_config(None, [], cond, zones)
    renderer = ZoneOracle.of(config, scaled=cond.isp).renderer
    recording = read_recording(Path(folder) / cond.name)
    steadier = Ranger(recording.rig).steadier
    reference = recording.rig.reference.name
    rows = []
    for zone in recording.zones:
        truth = zone.truth or {}
        pixel = ((truth.get("lasers") or {}).get(reference) or {}).get("pixel")
        turns = truth.get(TURNS_KEY)
        if pixel is None or not turns:
            continue
        dark = iter(turns)
        for i, frame in enumerate(zone.frames):  # (the recorder's order: each laser-off frame, then its lit one)
            if frame.lasers_on:
                continue
            turn = next(dark)
            lit = zone.frames[i + 1]
            on, off = recording.load_image(zone, lit), recording.load_image(zone, frame)
            pan = zone.pan_deg if frame.pan_deg is None else frame.pan_deg
            u, v = pixel
            if cond.isp:
                u, v = isp.sensor_pixel(u, v)
            seen = renderer.turned_pixels(pan, zone.tilt_deg, (turn[0], turn[1]), np.array([[u, v]]))[0]
            if cond.isp:
                seen = np.array(isp.scaled_pixel(seen[0], seen[1]))
            found, back = steadier.steadied(on, off)
            taken = back is not None
            mapped = steadier._mapped(found.rotation, np.array([pixel], np.float64))[0]
            rows.append({"condition": cond.name, "zone": zone.index, "frames": cond.frames,
                         "true_px": float(np.hypot(*(seen - pixel))), "fit_px": float(np.hypot(*(mapped - seen))),
                         "taken": taken})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path, help="a folder that `edge bench accuracy --keep` wrote")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--json", type=Path, help="write every pair's row here")
    args = parser.parse_args()
    doc = json.loads((args.folder / "accuracy.json").read_text())
    moving = [c for c in doc["conditions"] if c.get("jolt_deg")]
    from edge.accuracy.unturned import TURNS_KEY
    if not moving:
        sys.exit(f"{args.folder}: no moving rig")
    with ProcessPoolExecutor(args.jobs) as pool:
        rows = [r for rs in pool.map(condition_pairs, [str(args.folder)] * len(moving), moving,
                                     [doc["zones"]] * len(moving)) for r in rs]
    if not rows:
        sys.exit(f"{args.folder}: its moving zones keep no turns in truth.{TURNS_KEY} (recorded before they were)")
    if args.json:
        args.json.write_text(json.dumps(rows))
    kinds: dict[str, list[dict]] = defaultdict(list)
    for row in rows:
        kinds[row["frames"]].append(row)
        kinds["all"].append(row)
    print(f"{'frames':20s} {'pairs':>5s} {'true px':>8s} {'taken':>6s} {'error px, taken':>16s} {'error px, all':>14s}")
    for kind, rs in sorted(kinds.items(), key=lambda kv: (kv[0] == "all", kv[0])):
        true = np.array([r["true_px"] for r in rs])
        taken = np.array([r["taken"] for r in rs])
        error = np.where(taken, [r["fit_px"] for r in rs], true)
        fit = error[taken]
        print(f"{kind:20s} {len(rs):5d} {np.median(true):8.2f} {taken.mean():6.0%} "
              f"{(f'{np.median(fit):.3f} / {np.percentile(fit, 90):.3f}' if fit.size else '-'):>16s} "
              f"{np.median(error):.3f} / {np.percentile(error, 90):.3f}")


if __name__ == "__main__":
    main()
