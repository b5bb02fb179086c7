"""``edge bench accuracy``: ranging on a family of simulated conditions, against the physical floor.

Per condition (:mod:`edge.accuracy.conditions`) the simulator records a sweep whose zones carry their
truth and their floor (:mod:`edge.accuracy.truth`) into a scratch folder; the current estimator
ranges it again as ``edge replay`` does; :mod:`edge.accuracy.score` compares. Conditions run in
parallel processes, one per core by default. A benchmark: it prints figures and asserts nothing.

What the estimator is given as the rig (``rig``):

- ``true``: the simulated rig as built, mounting errors and all — the estimator's own accuracy,
  which is what the floor bounds (the default);
- ``calibrated``: the rig fitted, as a user would (``edge calibrate``), from a recording of a white
  board at 0.4–3 m taken by the same camera in the same light; a fit that fails leaves the nominal
  rig, and says so;
- ``nominal``: the rig as configured, as if never calibrated.
"""

from __future__ import annotations

import logging
import math
import multiprocessing
import shutil
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

from edge.accuracy.conditions import Condition
from edge.accuracy.score import (
    BLUNDER_SIGMAS,
    PLACEABLE_FRACTION,
    WITHIN_2SIGMA_LEAST,
    Figures,
    ZoneOutcome,
    failing_by_chance,
    stricter,
    targets,
)
from edge.config import Config, load_config
from edge.ranging import FrameGroup, Ranger, ZoneResult
from edge.recording import Recording, ZoneRecord
from edge.rig import Rig

log = logging.getLogger(__name__)

RIGS = ("true", "calibrated", "nominal")
CALIBRATION_DISTANCES_M = (0.4, 0.6, 0.9, 1.3, 2.0, 3.0)
CALIBRATION_PAIRS = 4  # as cmd/calibrate takes them: nudged, so that speckle averages out


@dataclass(frozen=True)
class Run:
    """What one condition gave."""

    condition: Condition
    outcomes: tuple[ZoneOutcome, ...]
    rig: str  # what ranging was given, in words
    seconds: float
    rows: tuple[dict, ...] = ()  # per zone: result, truth and floor, for a closer look

    @property
    def figures(self) -> Figures:
        return Figures.of(self.outcomes)


def run_condition(config_path: str | None, overrides: Sequence[str], cond: Condition, zones: int,
                  rig: str, folder: Path, oracle: bool = True) -> Run:
    """Record condition `cond` of the configuration (`config_path` with `overrides`), range it with
    the `rig` asked for (one of RIGS) and score it, beside the oracle's ranging unless `oracle` is
    False (it takes about as long as the recording). Recordings go to `folder`."""
    from edge.accuracy.oracle import ZoneOracle
    from edge.accuracy.truth import floor_truth
    from edge.accuracy.unturned import truth_time_s, unturned_groups
    from edge.recording import read_recording
    from edge.sim.record import record_sweep

    began = time.monotonic()
    config = condition_config(config_path, overrides, cond, zones)
    out = folder / cond.name
    _recorded(cond, out, lambda to: record_sweep(config, to, extra_truth=floor_truth(config)))
    recording = read_recording(out)
    if rig == "calibrated":  # (a board is recorded at rest)
        still = replace(config, sim=replace(config.sim, sway=replace(config.sim.sway, jolt_deg=0.0)))
        ranging_rig, said = _calibrated(cond, still, recording.rig, folder / f"{cond.name}-calibration")
    else:
        ranging_rig, said = _given_rig(cond, config, recording.rig, rig)
    zone_oracle = ZoneOracle.of(config, scaled=cond.isp) if oracle or cond.jolt_deg else None

    def seen(zone: ZoneRecord, groups: Sequence[FrameGroup], reference: str) -> tuple[float | None, float | None]:
        # A moving rig's zones are judged on its frames with the motion taken out exactly
        # (edge.accuracy.unturned): what is observable, and what the oracle reaches, are then the
        # camera's and the room's, and what the motion costs whatever takes it out (JPEG's blocks
        # that no longer cancel), not the turn's, which an estimator may find (edge.motion).
        # Judged on the turned frames, the room's edges left in their difference hid spots from
        # the count.
        if cond.jolt_deg:
            assert zone_oracle is not None  # (its renderer made the frames)
            groups = unturned_groups(recording, zone, zone_oracle.renderer, scaled=cond.isp)
        return (_frame_snr(groups, zone, reference),
                zone_oracle.error_m(groups, zone.truth or {}, truth_time_s(zone)) if zone_oracle and oracle else None)

    return _ranged(cond, config, recording, ranging_rig, said, began, seen)


def condition_config(config_path: str | None, overrides: Sequence[str], cond: Condition, zones: int) -> Config:
    """The configuration that condition `cond` of `zones` zones is recorded and ranged with."""
    base = load_config(config_path, list(overrides))
    extra = cond.overrides(base.sim.beam.e_per_ms_at_1m, base.sim.ambient.white_e_per_ms, zones,
                           base.camera.frame_rate_hz)
    return load_config(config_path, [*overrides, *extra])


def _recorded(cond: Condition, out: Path, record: Callable[[Path], object]) -> None:
    """`record` condition `cond`'s recording into `out`: straight there, or for an ISP condition
    its 1640 × 1232 sensor's beside it, scaled into `out` as the ISP hands it over and removed."""
    if not cond.isp:
        record(out)
        return
    from edge.sim.isp import scale_recording

    sensor = out.with_name(f"{out.name}-sensor")
    record(sensor)
    scale_recording(sensor, out)
    shutil.rmtree(sensor)


def _given_rig(cond: Condition, config: Config, nominal: Rig, rig: str) -> tuple[Rig, str]:
    from edge.isp import scaled_rig
    from edge.sim.record import true_rig

    if rig == "true":
        built = true_rig(config)  # (an ISP condition's: its sensor's camera, through the ISP)
        return (scaled_rig(built) if cond.isp else built), "true"
    if rig == "nominal":
        return nominal, "nominal"
    raise ValueError(f"rig must be one of {', '.join(RIGS)}, got {rig!r}")


def _ranged(cond: Condition, config: Config, recording: Recording, ranging_rig: Rig, said: str, began: float,
            seen: Callable[[ZoneRecord, Sequence[FrameGroup], str], tuple[float | None, float | None]]) -> Run:
    """Range every zone of `cond`'s `recording` with `ranging_rig` and score it; `seen` tells a
    zone's frame SNR and the oracle's error (measured, or kept from when it was recorded)."""
    from edge.replay import zone_groups

    ranger = Ranger(ranging_rig, config.ranging)
    reference = recording.rig.reference.name
    outcomes, rows = [], []
    for zone in recording.zones:
        # The zone's frames are read once, for the ranging and for what they show (as edge replay
        # reads them: zone_groups).
        groups, _ = zone_groups(recording, zone)
        result = ranger.range_zone(zone.index, zone.pan_deg, zone.tilt_deg, groups)
        frame_snr, oracle_error_m = seen(zone, groups, reference)
        outcome = ZoneOutcome.of(result, zone.truth, reference, frame_snr, oracle_error_m)
        outcomes.append(outcome)
        rows.append(_row(cond, zone.pan_deg, zone.tilt_deg, outcome, result, zone.truth or {}, reference))
    return Run(cond, tuple(outcomes), said, time.monotonic() - began, tuple(rows))


def replay_condition(config_path: str | None, overrides: Sequence[str], cond: Condition, zones: int,
                     rig: str, folder: Path, kept: Sequence[dict]) -> Run:
    """Range condition `cond`'s recording kept in `folder` again, with the estimator as it is now;
    its zones' frame SNR and the oracle's errors are taken from `kept` (their rows as recorded),
    which neither changes. The rig `calibrated` is fitted again from the kept board recording."""
    from edge.errors import UsageError
    from edge.recording import read_recording

    began = time.monotonic()
    config = condition_config(config_path, overrides, cond, zones)
    out = folder / cond.name
    if not (out / "sweep.json").is_file():
        raise UsageError(f"--replay {folder}: {cond.name} has no recording there ({out / 'sweep.json'} is missing)")
    recording = read_recording(out)
    if rig == "calibrated":
        board = folder / f"{cond.name}-calibration"
        if not (board / "sweep.json").is_file():
            raise UsageError(f"--replay {folder}: {cond.name} was not recorded with --rig calibrated "
                             f"({board / 'sweep.json'} is missing)")
        ranging_rig, said = _fitted(board, recording.rig)
    else:
        ranging_rig, said = _given_rig(cond, config, recording.rig, rig)
    by_zone = {int(row["zone"]): row for row in kept}

    def seen(zone: ZoneRecord, groups: Sequence[FrameGroup], reference: str) -> tuple[float | None, float | None]:
        row = by_zone.get(zone.index) or {}
        return row.get("frame_snr"), row.get("oracle_error_m")

    return _ranged(cond, config, recording, ranging_rig, said, began, seen)


def _frame_snr(groups: Sequence[FrameGroup], zone: ZoneRecord, reference: str) -> float | None:
    """The reference spot's matched-filter SNR in the zone's recorded frames, `groups` (None: not
    visible, or no frame pair)."""
    from edge.accuracy.observe import frame_snr, mean_differences

    lasers = (zone.truth or {}).get("lasers") or {}
    mine = lasers.get(reference) or {}
    if not mine.get("visible") or mine.get("pixel") is None:
        return None
    if not groups:
        return None
    diffs = mean_differences([f for g in groups for f in g.on], [f for g in groups for f in g.off])
    others = [t["pixel"] for n, t in lasers.items() if n != reference and t.get("pixel") is not None]
    return frame_snr(diffs, mine["pixel"], others)


def _calibrated(cond: Condition, config: Config, nominal: Rig, out: Path) -> tuple[Rig, str]:
    """The rig fitted from a simulated white board at CALIBRATION_DISTANCES_M (the room's surfaces
    do not matter: a user calibrates with a matte white board), or the nominal rig if it fails."""
    from edge.sim.record import record_targets
    from edge.sim.settings import SurfacesConfig

    board = replace(config, sim=replace(config.sim, surfaces=SurfacesConfig()))
    _recorded(cond, out, lambda to: record_targets(board, list(CALIBRATION_DISTANCES_M), to, pairs=CALIBRATION_PAIRS))
    return _fitted(out, nominal)


def _fitted(board: Path, nominal: Rig) -> tuple[Rig, str]:
    """The rig fitted from the board recording `board`, or the nominal rig if the fit fails."""
    from edge.calibration.fit import fit_calibration
    from edge.errors import CalibrationError
    from edge.recording import read_recording

    try:
        cal = fit_calibration(read_recording(board), CALIBRATION_DISTANCES_M)
    except CalibrationError as exc:
        return nominal, f"nominal (calibration failed: {exc})"
    return cal.apply(nominal), "calibrated"


def _row(cond: Condition, pan: float, tilt: float, z: ZoneOutcome, result: ZoneResult, truth: dict,
         reference: str) -> dict:
    floor = truth.get("floor") or {}
    mine = result.lasers.get(reference)
    return {
        "condition": cond.name, "zone": z.index, "pan_deg": pan, "tilt_deg": tilt,
        "status": z.status, "detail": result.detail, "range_m": z.range_m, "sigma_m": z.sigma_m,
        "truth_m": z.truth_m, "error_m": z.error_m, "visible": z.visible, "observable": z.observable,
        # (frame_snr unrounded: a replay reads it back to judge the zone observable, at 6.0)
        "wrong": z.wrong, "floor": floor, "frame_snr": z.frame_snr,
        "oracle_error_m": None if z.oracle_error_m is None else round(z.oracle_error_m, 7),
        "spot": None if mine is None else mine.to_json(),
        # The spots an `ok` range was fused from, each (depth m, σ m): which kinds of fusion err how.
        "used": {n: [round(m.depth_m, 5), round(m.sigma_m, 5)] for n, m in result.lasers.items()}
        if z.status == "ok" else None,
    }


def run_family(config_path: str | None, overrides: Sequence[str], conditions: Sequence[Condition], zones: int,
               rig: str = "true", jobs: int = 1, keep: Path | None = None,
               progress: Callable[[Run], None] | None = None) -> list[Run]:
    """Every condition of `conditions`, `jobs` at a time, in condition order. Recordings go to
    `keep` if given, else to a scratch folder removed afterwards."""
    with tempfile.TemporaryDirectory(prefix="edge-accuracy-") as scratch:
        folder = keep if keep is not None else Path(scratch)
        folder.mkdir(parents=True, exist_ok=True)
        return _pooled(run_condition, [(config_path, tuple(overrides), c, zones, rig, folder) for c in conditions],
                       jobs, progress)


def replay_family(config_path: str | None, overrides: Sequence[str], kept: KeptFamily, rig: str, jobs: int = 1,
                  progress: Callable[[Run], None] | None = None) -> list[Run]:
    """Every condition of a family kept by `run_family` (`kept`), ranged again from its recordings."""
    args = [(config_path, tuple(overrides), c, kept.zones, rig, kept.folder, kept.rows_of(c.name))
            for c in kept.conditions]
    return _pooled(replay_condition, args, jobs, progress)


def _pooled(work: Callable[..., Run], args: Sequence[tuple], jobs: int,
            progress: Callable[[Run], None] | None) -> list[Run]:
    """`work` on each of `args`, `jobs` at a time, in their order."""
    runs: list[Run] = []
    if jobs <= 1:
        for a in args:
            runs.append(work(*a))
            if progress:
                progress(runs[-1])
        return runs
    # Fresh interpreters: the parent may hold threads (logging, a progress bar) that fork copies badly.
    with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = [pool.submit(work, *a) for a in args]
        for f in futures:
            runs.append(f.result())
            if progress:
                progress(runs[-1])
    return runs


KEPT_FILE = "accuracy.json"


def software() -> dict[str, str]:
    """The libraries a family's figures rest on: OpenCV's JPEG codec, demosaicing and resizing make
    the simulated frames, and numpy the noise (the same seeds on the same library versions give the
    same frames; evaluation 464-527, recorded again under numpy 2.4 and OpenCV 5.1, moved one zone)."""
    import platform

    import cv2
    import numpy

    return {"python": platform.python_version(), "numpy": numpy.__version__, "opencv": cv2.__version__}


def family_document(runs: Sequence[Run], family_name: str, zones: int, rig: str,
                    config_path: str | None, overrides: Sequence[str],
                    rendered_with: Mapping[str, str] | None = None) -> dict:
    """What `--json` writes, and `--keep` beside its recordings (KEPT_FILE): every zone's row, and
    what the family was run with: the software that rendered its frames (`rendered_with`; default:
    this one's, as for a family just recorded) and that ranged them."""
    here = software()
    return {"family": family_name, "zones": zones, "rig": rig, "config": config_path, "set": list(overrides),
            "rendered_with": dict(rendered_with or here), "ranged_with": here,
            "conditions": [r.condition.to_json() | {"rig": r.rig} for r in runs],
            "rows": [row for r in runs for row in r.rows]}


def software_line(rendered_with: Mapping[str, str] | None) -> str:
    """The report's line on the software: what rendered the frames (None: not kept, a family kept
    before it was) and what ranged them, where the two differ."""
    here = software()

    def said(s: Mapping[str, str]) -> str:
        return ", ".join(f"{name} {s[name]}" for name in ("numpy", "opencv", "python") if name in s)

    if rendered_with is None:
        return f"  software: ranged with {said(here)}; what rendered the frames was not kept"
    if dict(rendered_with) == here:
        return f"  software: {said(here)}"
    return f"  software: rendered with {said(rendered_with)}; ranged with {said(here)}"


@dataclass(frozen=True)
class KeptFamily:
    """A family's recordings kept by `--keep` (folder), and what `family_document` said of them."""

    folder: Path
    family: str
    zones: int
    rig: str
    config: str | None
    overrides: tuple[str, ...]
    conditions: tuple[Condition, ...]
    rows: tuple[dict, ...]
    rendered_with: dict[str, str] | None = None  # `software()` when the frames were rendered (None: not kept)

    def rows_of(self, name: str) -> list[dict]:
        return [row for row in self.rows if row.get("condition") == name]

    @classmethod
    def read(cls, folder: Path) -> KeptFamily:
        """The family kept in `folder`; a UsageError that names the file and what is wrong with it."""
        import json

        from edge.accuracy.conditions import FAMILIES
        from edge.errors import UsageError

        file = folder / KEPT_FILE
        try:
            doc = json.loads(file.read_text())
        except FileNotFoundError:
            raise UsageError(f"--replay {folder}: no {KEPT_FILE} there (it is written by edge bench accuracy "
                             f"--keep {folder})") from None
        except (OSError, ValueError) as exc:
            raise UsageError(f"--replay {folder}: {file} cannot be read: {exc}") from None
        try:
            family_name = doc["family"]
            if family_name not in FAMILIES:
                raise ValueError(f"family {family_name!r} is not one of {', '.join(FAMILIES)}")
            conditions = tuple(Condition.from_json(c) for c in doc["conditions"])
            rendered = doc.get("rendered_with")
            if rendered is not None and not isinstance(rendered, dict):
                raise ValueError(f"rendered_with must be a table of versions, got {rendered!r}")
            return cls(folder, family_name, int(doc["zones"]), str(doc["rig"]), doc.get("config"),
                       tuple(str(s) for s in doc.get("set") or ()), conditions, tuple(doc["rows"]),
                       None if rendered is None else {str(k): str(v) for k, v in rendered.items()})
        except (KeyError, TypeError, ValueError) as exc:
            raise UsageError(f"--replay {folder}: {file} is not what --keep writes: {exc!r}") from None


# --- the report ---------------------------------------------------------------------------------


def _mm(x: float) -> str:
    return "-" if math.isnan(x) else f"{1000 * x:.1f}"


def _num(x: float, fmt: str = ".2f") -> str:
    return "-" if math.isnan(x) else format(x, fmt)


def _share(part: int, whole: int) -> float:
    return part / whole if whole else math.nan


def _pct(x: float) -> str:
    return "-" if math.isnan(x) else f"{100 * x:.0f}%"


HEADER = (f"{'condition':<14} {'covered':>8} {'ok':>3} {'mean|e|':>8} {'med|e|':>7} {'mean%':>6} "
          f"{'e/floor':>7} {'med':>5} {'e/orc':>5} {'≤2σ':>5} {'wrong':>5} {'σ/floor':>7}  set-up")


def condition_line(run: Run) -> str:
    f = run.figures
    return (f"{run.condition.name:<14} {f.covered:>3}/{f.observable:<4} {f.ok:>3} {_mm(f.mean_abs_m):>8} "
            f"{_mm(f.median_abs_m):>7} {_num(100 * f.mean_rel):>6} {_num(f.mean_ratio):>7} "
            f"{_num(f.median_ratio, '.1f'):>5} {_num(f.over_oracle, '.1f'):>5} {_pct(f.within_2sigma):>5} "
            f"{f.wrong_ok:>5} "
            f"{_num(f.sigma_over_floor):>7}  {run.condition.describe()}")


def _by_kind(runs: Sequence[Run]) -> list[str]:
    """The family's figures by kind of frames (:attr:`Condition.frames`): where the estimator
    stands furthest from the floor and from the oracle; then still rigs beside moving ones, and
    sensors that sample the room at their pixels' centres beside those that average it over their
    area."""
    return (_by(runs, lambda c: c.frames, "by kind of frames")
            + _by(runs, lambda c: "moving" if c.jolt_deg else "still", "by the rig's motion between its frames")
            + _by(runs, lambda c: "pixel's area" if c.pixel_area else "pixel's centre",
                  "by where the sensor samples the room"))


def _by(runs: Sequence[Run], kind_of: Callable[[Condition], str], title: str) -> list[str]:
    """The family's figures for each kind of condition `kind_of` tells."""
    kinds: dict[str, list[ZoneOutcome]] = {}
    for r in runs:
        kinds.setdefault(kind_of(r.condition), []).extend(r.outcomes)
    lines = [f"  {title} (conditions):"]
    for kind, outcomes in sorted(kinds.items()):
        f = Figures.of(outcomes)
        lines.append(
            f"    {kind:<19} ({sum(kind_of(r.condition) == kind for r in runs)}): coverage "
            f"{_pct(f.coverage)} ({f.covered} of {f.observable}), {f.wrong_ok} wrong, |error| ÷ floor mean "
            f"{_num(f.mean_ratio)}, {_num(f.over_oracle)} × the oracle's")
    return lines


def report(runs: Sequence[Run], family_name: str, zones: int, rig: str) -> list[str]:
    """The benchmark's printout: a line per condition, the family's figures and the targets."""
    if not runs:
        return ["no conditions"]
    seeds = f"{runs[0].condition.seed}-{runs[-1].condition.seed}"
    lines = [
        f"ranging accuracy on {len(runs)} conditions of the {family_name} family (seeds {seeds}), "
        f"{zones} zones each, ranged with the {rig} rig",
        "  covered: ok / observable zones (reference spot's matched-filter SNR ≥ 6 in its frames); |e| in mm over "
        "covered zones; e/floor: |error| ÷ the floor's σ (0.80 at the floor); e/orc: that ÷ the oracle's on the "
        "same zones; σ/floor: median claimed σ ÷ floor",
        HEADER,
    ]
    lines += [condition_line(r) for r in runs]
    notes = [f"  {r.condition.name}: ranged with the {r.rig} rig" for r in runs if r.rig not in RIGS]
    lines += notes
    per = [r.figures for r in runs]
    outcomes = [z for r in runs for z in r.outcomes]
    pooled = Figures.of(outcomes)
    scored = [f for f in per if f.scored]  # conditions with ok zones to judge their σ by
    missed = ", ".join(f"{s} {n}" for s, n in sorted(pooled.missed.items(), key=lambda kv: -kv[1])) or "none"
    lines += [
        "",
        f"family: {pooled.zones} zones, {pooled.observable} observable, {pooled.covered} of them ok "
        f"(coverage {_pct(pooled.coverage)}); {pooled.ok} ok in all, {pooled.wrong_ok} wrong"
        + (f" ({pooled.blunders} of them over {BLUNDER_SIGMAS:g}σ off)" if pooled.wrong_ok else ""),
        f"  |error| over covered zones: mean {_mm(pooled.mean_abs_m)} mm, median {_mm(pooled.median_abs_m)} mm, "
        f"mean {_num(100 * pooled.mean_rel)} % of range",
        f"  |error| ÷ floor: mean {_num(pooled.mean_ratio)}, median {_num(pooled.median_ratio)}; "
        f"claimed σ ÷ floor: median {_num(pooled.sigma_over_floor)}",
        f"  beside the oracle (a fit told each spot's true pixel and shape) on {pooled.oracle_scored} covered zones: "
        f"|error| ÷ floor mean {_num(pooled.ratio_beside_oracle)}, the oracle's {_num(pooled.oracle_ratio)}: "
        f"{_num(pooled.over_oracle)} × the oracle's",
        f"  within 2σ: {_pct(pooled.within_2sigma)} of {pooled.scored} ok zones with truth "
        f"(worst condition {_pct(min((f.within_2sigma for f in scored), default=math.nan))}); "
        f"{sum(f.within_2sigma < WITHIN_2SIGMA_LEAST for f in scored)} of {len(scored)} conditions under 90 %, "
        f"where honest Gaussian σ would leave {failing_by_chance([f.scored for f in scored]):.1f} by chance",
        f"  observable zones not ok: {missed}",
        "  a surer `ok` (σ at most this share of the range) would have left: " + "; ".join(
            f"{100 * x.fraction:g} %: coverage {_pct(x.coverage)}, {x.wrong_ok} wrong"
            for x in stricter(outcomes)),
        *([f"  observable zones the oracle places to {PLACEABLE_FRACTION:.0%} of their range in the same frames: "
           f"{pooled.placeable}, {pooled.covered_placeable} of them ok (coverage "
           f"{_pct(_share(pooled.covered_placeable, pooled.placeable))}; the others JPEG or demosaicing left "
           "unplaceable)"] if pooled.placeable else []),
        f"  observable by the renderer's SNR, before the camera's JPEG and demosaicing: {pooled.observable_model}, "
        f"{pooled.covered_model} of them ok (coverage {_pct(_share(pooled.covered_model, pooled.observable_model))})",
        *_by_kind(runs),
        f"  time: {sum(r.seconds for r in runs):.0f} s of work",
        "targets (to be met on the evaluation family):",
    ]
    for t in targets(per, pooled):
        value = _pct(t.value) if "%" in t.what else _num(t.value, "g" if t.what.startswith("wrong") else ".2f")
        lines.append(f"  [{'met' if t.met else 'not met'}] {t.what}: {value}")
    return lines
