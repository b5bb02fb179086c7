"""`cmd/calibrate`: an interactive flat-target calibration, guided over MQTT.

Someone holds a flat, matte target squarely in front of the unit (pan 0, tilt 0) at each requested
distance in turn, in the order given, measured from the camera's optical centre along its axis.
There is no button to press: after the command, the target is brought to the first distance, and
the unit takes it once the target has come to rest there (the spots still for `steady_s`); then it
waits for the next. `state` says which distance it waits for, and every pair is ranged and
published on `range` as usual, so whoever holds the target can follow.

An uncalibrated rig cannot be trusted to find its own spots (they may lie outside the narrow bands
the ranger searches) nor to tell 2 m from 1.3 m (half a degree of laser error shifts a spot as much
as that step does), so the session follows the spots themselves, anywhere in the picture, and takes
the target's *rests* in order. A rest is taken for distance k only when:
- its spots moved since the last rest taken (for the first distance: since what the unit saw when
  the command came — so send the command first, then bring the target);
- for the first distance, a spot lies where the nominal rig expects one, within the fit's own
  first gate (about 2.5° of laser error);
- from the second distance on, a spot moved from where one was at distance k−1 the way the nominal
  rig says the reference spot should (the errors shift a spot about as much at both distances),
  within half that move or 2 px: a target held still half-way, or moved the wrong way, is not
  taken.
So: move the target straight from one distance to the next and hold it still at each for a couple
of seconds. Should a wrong rest still slip through, the fit refuses residuals over half a pixel,
and nothing changes.

The frames of each distance (a sweep zone's pairs, nudged for fresh speckle) go into an
``edge-sweep/1`` recording (zone k = distance k) in the state folder, so that the same fit can be
run again offline with ``edge calibrate``.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from edge.calibration.file import Calibration
from edge.calibration.fit import FIRST_GATE_PX, fit_calibration
from edge.calibration.spots import find_spots
from edge.capture import Capture
from edge.errors import CalibrationError, HardwareError
from edge.ranging import FAULT, FrameGroup, Ranger, ZoneResult
from edge.recording import RecordingWriter, read_recording
from edge.rig import Rig

MOVED_PX = 1.5  # a spot this far from every spot seen before has moved


@dataclass(frozen=True)
class Outcome:
    """How a session ended: a calibration, or why not."""

    calibration: Calibration | None
    error: str | None = None


class RestWatcher:
    """The pure half of a session: from the spots of each laser-off/on pair, when the target rests
    at the distance awaited (see the module notes). Knows nothing of cameras or files."""

    def __init__(self, nominal: Rig, distances_m: Sequence[float], *, steady_s: float = 1.5,
                 still_px: float = 0.7, min_pairs: int = 4) -> None:
        self.nominal = nominal
        self.distances = tuple(float(d) for d in distances_m)
        self.steady_s = steady_s
        self.still_px = still_px
        self.min_pairs = min_pairs
        self.taken: list[list[np.ndarray]] = []  # the resting spots at each distance taken
        self._recent: deque[tuple[float, list[np.ndarray]]] = deque()  # (time, spots) of each pair
        self._start: list[np.ndarray] | None = None  # the resting spots when the session began

    @property
    def waiting_for(self) -> float | None:
        k = len(self.taken)
        return self.distances[k] if k < len(self.distances) else None

    def add(self, t_s: float, spots: list[np.ndarray]) -> bool:
        """One pair's spots at time `t_s`; True when the target is to be taken now for
        :attr:`waiting_for` (it then waits for the next distance)."""
        if self.waiting_for is None:
            return False
        self._recent.append((t_s, [np.asarray(p, dtype=np.float64) for p in spots]))
        while self._recent and self._recent[0][0] < t_s - self.steady_s:
            self._recent.popleft()
        resting = self._resting(t_s)
        if resting is None:
            return False
        if self._start is None:
            self._start = resting  # what was there when the command came
            return False
        if not self._accept(resting):
            return False
        self.taken.append(resting)
        self._recent.clear()
        return True

    def forget_last(self) -> None:
        """Undo the last take (its frames could not be recorded): wait for that distance again."""
        if self.taken:
            self.taken.pop()
            self._recent.clear()

    def _resting(self, now: float) -> list[np.ndarray] | None:
        """The spots' mean positions when every pair of the last `steady_s` showed the same spots
        within `still_px` (or none at all); else None (something moves, or not watched long enough)."""
        if len(self._recent) < self.min_pairs or now - self._recent[0][0] < 0.8 * self.steady_s:
            return None
        first = self._recent[0][1]
        if any(len(spots) != len(first) for _, spots in self._recent):
            return None
        tracks = [[p] for p in first]
        for _, spots in list(self._recent)[1:]:
            for track in tracks:
                nearest = min(spots, key=lambda q: float(np.linalg.norm(q - track[0])))
                if np.linalg.norm(nearest - track[0]) > self.still_px:
                    return None
                track.append(nearest)
        return [np.mean(track, axis=0) for track in tracks]

    def _accept(self, spots: list[np.ndarray]) -> bool:
        """Whether resting `spots` show the target at the awaited distance (see the module notes)."""
        if not spots:
            return False
        before = self.taken[-1] if self.taken else self._start or []  # the last rest taken, or the start
        moved = len(spots) != len(before) or any(
            min(float(np.linalg.norm(p - q)) for q in before) > MOVED_PX for p in spots)
        if not moved:
            return False
        want = self.waiting_for
        assert want is not None  # checked on entry; nothing since has taken a rest
        cam = self.nominal.camera
        if not self.taken:
            # Where the nominal rig expects the spots, give or take the fit's own first gate.
            expected = [cam.project(laser.point_at_depth(want)) for laser in self.nominal.lasers]
            return any(float(np.linalg.norm(p - e)) <= FIRST_GATE_PX for p in spots for e in expected)
        previous = self.distances[len(self.taken) - 1]
        # How the reference spot should have moved since the last distance: the lasers' errors
        # shift their spots by about as much at both distances, so the change is well predicted.
        ref = self.nominal.reference
        shift = cam.project(ref.point_at_depth(want)) - cam.project(ref.point_at_depth(previous))
        tolerance = max(2.0, 0.5 * float(np.linalg.norm(shift)))
        return any(min(float(np.linalg.norm(q - (p + shift))) for q in spots) <= tolerance
                   for p in self.taken[-1])


class TargetCalibration:
    """One calibration session on opened parts; the service calls :meth:`step` between commands."""

    def __init__(self, distances_m: Sequence[float], ranger: Ranger, nominal: Rig, capture: Capture,
                 folder: Path, record_zone: Callable[[int, float, float, RecordingWriter], ZoneResult], *,
                 pan_deg: float = 0.0, tilt_deg: float = 0.0, timeout_s: float = 600.0, device: str = "",
                 clock: Callable[[], float] = time.monotonic) -> None:
        """`record_zone(k, pan, tilt, writer)` takes and records zone k's frames there — with a
        sweep's pan nudges between pairs, so that each pair sees fresh speckle: a target at rest
        shows the same speckle in every frame, and the fit would inherit its bias."""
        self.watcher = RestWatcher(nominal, distances_m)
        self.record_zone = record_zone
        self.distances = self.watcher.distances
        self.ranger = ranger
        self.capture = capture
        self.folder = Path(folder)
        self.pan_deg, self.tilt_deg = pan_deg, tilt_deg
        self.clock = clock
        self.started = clock()
        self.deadline = self.started + timeout_s
        self.last: ZoneResult | None = None  # the latest pair's range, for whoever holds the target
        self.recorded: ZoneResult | None = None  # the latest distance taken, as the rig in use ranged it
        # (The curve its frames came through, as the ranger is told it: a replay undoes the same.)
        # (And where a focus motor holds the lens: the calibration holds for that position alone.)
        self._writer = RecordingWriter(self.folder, nominal, device=device, frame_gamma=ranger.config.frame_gamma,
                                       lens_dioptres=getattr(capture.camera, "lens_dioptres", None))
        self._writer.__enter__()
        self._open = True

    # ---- progress ----

    @property
    def waiting_for(self) -> float | None:
        return self.watcher.waiting_for

    @property
    def complete(self) -> bool:
        return self.waiting_for is None

    def state(self) -> dict:
        """For `state` while the session runs."""
        return {
            "distances_m": list(self.distances),
            "taken_m": list(self.distances[: len(self.watcher.taken)]),
            "waiting_for_m": self.waiting_for,
            "ranged_m": None if self.last is None or self.last.range_m is None else round(self.last.range_m, 4),
            "elapsed_s": round(self.clock() - self.started, 1),
        }

    # ---- the loop's step ----

    def step(self) -> float | None:
        """Take one laser-off/on pair, range it and look at its spots; returns the distance taken
        with it, if any. Raises HardwareError like any capture."""
        shots = self.capture.zone(pairs=1)
        off, on = shots
        group = FrameGroup([on.frame.image], [off.frame.image], on.lasers_on, (self.pan_deg, self.tilt_deg))
        self.last = self.ranger.range_zone(-1, self.pan_deg, self.tilt_deg, [group])
        distance = self.waiting_for
        if not self.watcher.add(self.clock(), find_spots([on.frame.image], [off.frame.image])):
            return None
        k = len(self.watcher.taken) - 1
        result = self.record_zone(k, self.pan_deg, self.tilt_deg, self._writer)
        if result.status == FAULT:  # a part failed while recording: wait for the next rest
            self.watcher.forget_last()
            raise HardwareError(result.detail, part=result.part)
        self.recorded = result
        return distance

    @property
    def timed_out(self) -> bool:
        return self.clock() >= self.deadline

    # ---- the end ----

    def finish(self) -> Outcome:
        """Fit the rig from the distances taken (all of them), or say why not."""
        try:
            self._writer.__exit__(None, None, None)
        finally:
            self._open = False
        try:
            recording = read_recording(self.folder)
            return Outcome(fit_calibration(recording, self.distances))
        except CalibrationError as exc:
            return Outcome(None, f"the fit failed: {exc}; nothing changed (frames kept in {self.folder})")

    def abandon(self) -> None:
        """End without a fit; what was recorded so far is dropped."""
        if self._open:
            self._open = False
            self._writer.__exit__(RuntimeError, RuntimeError("abandoned"), None)

    def missing(self) -> str:
        left = self.distances[len(self.watcher.taken):]
        return ", ".join(f"{d:g}" for d in left)


def summary(cal: Calibration, nominal: Rig) -> dict:
    """What `cmd/calibrate`'s result says of a new calibration: per laser, how far its ray turned
    from the nominal one and how well the points fit."""
    nominal_by_name = {laser.name: laser for laser in nominal.lasers}
    lasers = {}
    for laser in cal.lasers:
        nom = nominal_by_name[laser.name]
        angle = math.degrees(math.acos(min(1.0, float(laser.d @ nom.d))))
        res = cal.residuals_px.get(laser.name, {})
        lasers[laser.name] = {"angle_from_nominal_deg": round(angle, 4),
                              "rms_px": round(float(res.get("rms", math.nan)), 4),
                              "max_px": round(float(res.get("max", math.nan)), 4)}
    return {"created": cal.created, "distances_m": list(cal.distances_m), "lasers": lasers}
