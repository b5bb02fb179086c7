"""The blind aid: a fan of zones ahead, and the nearest obstacle in it as a sound a walker can follow.

The unit scans a small fan ahead (``fan_zones`` views over ±``fan_half_width_deg``) again and again,
and every zone result goes to :meth:`BlindAid.update` with the time it was measured. The blind aid
keeps the latest reading of each zone; the nearest valid obstacle within ``clear_m`` drives the cue:

- nothing within ``clear_m``: **silence** (the way is clear);
- between ``danger_m`` and ``clear_m``: parking-sensor **beeps**, faster and higher as it nears;
- at or inside ``danger_m``: a continuous **tone**;
- the rig cannot see: **blind**, a low two-tone warble and the words "cannot see", never silence.

Blind comes from three inputs, whichever says so first: a ``fault`` zone result (a part failed for
that zone: a camera without frames, a unit that does not answer, lasers switched off by their
safety timer), no sign of life from the rig for ``blind_after_s`` (no zone result, and no frame
either, :meth:`BlindAid.alive`, counted from when that frame was taken: a stalled camera blocks
each frame up to its timeout, so the fault result itself comes late; :meth:`BlindAid.tick`,
called on the sound's own clock, notices the silence of the rig first), and
:meth:`BlindAid.set_blinded` (the service says the rig cannot see: lasers switched off by command,
a laser that does not light). It ends with the first result that is not a fault, and the cue
follows the readings again (an obstacle then is announced anew). Silence therefore always means
"seen, and clear".

Everything here is pure: results and times in, :class:`Cue` values out. No clocks, no I/O; the
sound itself is made by :mod:`edge.modes.blindaid.sound`, and the service publishes each cue on ``cue``.

The laws (``u`` = how far into the warning band the obstacle is, 0 at ``clear_m``, 1 at
``danger_m``: ``u = (clear_m − d) / (clear_m − danger_m)``, clipped to [0, 1])::

    interval_s = max_interval_s · (min_interval_s / max_interval_s) ** u     (exponential in d)
    pitch_hz   = pitch_low_hz   · (pitch_high_hz  / pitch_low_hz)   ** u     (log scale in d)

Both are geometric interpolations: every 10 cm nearer shortens the interval and raises the pitch by
the same *ratio*, which is how tempo and pitch are heard (Weber's law: a 10 % change is as easy to
hear at 1 s as at 0.1 s). With the defaults (1.0 → 0.08 s, 400 → 1600 Hz over 3.0 → 0.5 m) each
metre nearer multiplies the beep rate by 2.75 and raises the pitch by 0.8 octave.

Conventions (``shared/spec/geometry.md``): positive pan turns **left**, so a positive bearing is on
the walker's left. The stereo position ``pan`` of a cue runs the other way round, as audio does:
−1 full left … +1 full right.

Zone statuses (``edge.ranging``): ``ok`` is a reading. ``fault`` and ``ambiguous`` say nothing
about the scene, so the zone's last reading is *held* for ``hold_s`` after the first such result,
then dropped. ``no_spot`` and ``out_of_range`` say nothing is in range there, so the zone's reading
is dropped — except when that reading was inside ``danger_m``: the rig cannot range nearer than its
working range (0.25 m), so an obstacle walked into turns into ``no_spot``/``out_of_range``; that
is held for ``hold_s`` as well, rather than falling silent at the worst moment. Any reading older
than ``max_age_s`` is dropped (the fan must revisit each zone faster than that: see
:func:`scan_order`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from edge.ranging import AMBIGUOUS, FAULT, NO_SPOT, OK, OUT_OF_RANGE, ZoneResult
from edge.schema import require

SILENCE, BEEP, TONE, BLIND = "silence", "beep", "tone", "blind"
SOUNDS = (SILENCE, BEEP, TONE, BLIND)
CANNOT_SEE = "cannot see"  # what is said when the aid goes blind
_WAITED = "nothing from the rig"  # the blind reason when no sign of life came for too long
SAMPLE_RATES = (8000, 16000, 22050, 32000, 44100, 48000)


@dataclass(frozen=True)
class BlindAidConfig:
    """The blind aid's fan and sound (``[blindaid]`` in the config). Lengths in m, times in s."""

    fan_zones: int = 7  # views across the fan: odd, so that one looks straight ahead
    fan_half_width_deg: float = 30.0  # the fan spans ±this in pan
    tilt_deg: float = 0.0  # tilt of every view (negative looks down, towards kerbs and steps)
    clear_m: float = 3.0  # nothing nearer than this: silence
    danger_m: float = 0.5  # something this near or nearer: continuous tone
    max_interval_s: float = 1.0  # beep interval at clear_m
    min_interval_s: float = 0.08  # beep interval at danger_m
    pitch_low_hz: float = 400.0  # pitch at clear_m
    pitch_high_hz: float = 1600.0  # pitch at danger_m (and of the tone)
    beep_s: float = 0.05  # length of one beep, ramps included
    ramp_s: float = 0.005  # raised-cosine rise and fall of every sound (no clicks)
    volume: float = 0.6  # 0..1 of full scale
    sample_rate: int = 22050
    ahead_deg: float = 10.0  # bearings within ±this are "ahead" (for speech)
    speak_new: bool = True  # announce a new obstacle (after clear, or in another direction)
    speak_min_gap_s: float = 3.0  # at least this long between two announcements
    hold_s: float = 0.5  # how long a zone's reading outlives a fault in that zone
    max_age_s: float = 1.5  # any reading older than this is dropped
    hysteresis_m: float = 0.05  # against flicker at clear_m, danger_m and between zones
    min_change_m: float = 0.05  # a new cue when the nearest range moves by this much
    speak_button_pin: int = 0  # BCM pin of a push button (to ground) that asks "how far?"; 0: none
    blind_after_s: float = 0.7  # no frame or zone result for this long: "cannot see" (~0.1-0.3 s apart)

    def __post_init__(self) -> None:
        require(3 <= self.fan_zones <= 15 and self.fan_zones % 2 == 1, "fan_zones",
                f"must be odd and 3-15, got {self.fan_zones}")
        require(0 < self.fan_half_width_deg <= 90, "fan_half_width_deg", "must be in (0, 90]")
        require(-90 <= self.tilt_deg <= 90, "tilt_deg", "must be within ±90")
        require(self.danger_m > 0, "danger_m", "must be positive")
        require(self.clear_m > self.danger_m, "clear_m", "must be greater than danger_m")
        require(self.min_interval_s > 0, "min_interval_s", "must be positive")
        require(self.max_interval_s > self.min_interval_s, "max_interval_s",
                "must be greater than min_interval_s")
        require(self.pitch_low_hz >= 50, "pitch_low_hz", "must be >= 50 Hz")
        require(self.pitch_high_hz > self.pitch_low_hz, "pitch_high_hz", "must be greater than pitch_low_hz")
        require(self.sample_rate in SAMPLE_RATES, "sample_rate",
                f"must be one of {', '.join(map(str, SAMPLE_RATES))}, got {self.sample_rate}")
        require(self.pitch_high_hz <= self.sample_rate / 4, "pitch_high_hz",
                f"must be at most a quarter of sample_rate ({self.sample_rate / 4:g} Hz)")
        require(0 < self.ramp_s <= 0.02, "ramp_s", "must be in (0, 0.02] s")
        require(self.beep_s >= 2 * self.ramp_s, "beep_s", "must be at least twice ramp_s")
        require(self.beep_s <= 0.8 * self.min_interval_s, "beep_s",
                "must be at most 0.8 × min_interval_s (beeps need a gap between them)")
        require(0 <= self.volume <= 1, "volume", "must be in [0, 1]")
        require(0 <= self.ahead_deg < self.fan_half_width_deg, "ahead_deg",
                "must be in [0, fan_half_width_deg)")
        require(self.speak_min_gap_s >= 0, "speak_min_gap_s", "must be >= 0")
        require(0 <= self.speak_button_pin <= 27, "speak_button_pin", "must be a BCM pin 1-27, or 0 for none")
        require(self.max_age_s > 0, "max_age_s", "must be positive")
        require(0 <= self.hold_s <= self.max_age_s, "hold_s", "must be in [0, max_age_s]")
        require(0 <= self.hysteresis_m < self.clear_m - self.danger_m, "hysteresis_m",
                "must be >= 0 and less than clear_m - danger_m")
        require(self.min_change_m >= 0, "min_change_m", "must be >= 0")
        # Above 0.9 s the blind cue could not sound within a second of the rig going blind.
        require(0.1 <= self.blind_after_s <= 0.9, "blind_after_s", "must be in [0.1, 0.9] s")

    # --- the laws ---

    def closeness(self, range_m: float) -> float:
        """u: 0 at (or beyond) clear_m, 1 at (or inside) danger_m, linear in between."""
        u = (self.clear_m - range_m) / (self.clear_m - self.danger_m)
        return min(1.0, max(0.0, u))

    def interval_s(self, range_m: float) -> float:
        """Beep interval (onset to onset) for an obstacle at `range_m`: exponential in distance."""
        return self.max_interval_s * (self.min_interval_s / self.max_interval_s) ** self.closeness(range_m)

    def pitch_hz(self, range_m: float) -> float:
        """Pitch for an obstacle at `range_m`: log scale in distance."""
        return self.pitch_low_hz * (self.pitch_high_hz / self.pitch_low_hz) ** self.closeness(range_m)

    def stereo_pan(self, bearing_deg: float) -> float:
        """Stereo position −1 (left) … +1 (right) of a bearing (positive = left, geometry.md); the
        fan's edges are full left and full right."""
        return min(1.0, max(-1.0, -bearing_deg / self.fan_half_width_deg))

    def direction(self, bearing_deg: float) -> str:
        """"left", "ahead" or "right" (positive bearing is left)."""
        if abs(bearing_deg) <= self.ahead_deg:
            return "ahead"
        return "left" if bearing_deg > 0 else "right"


def pan_gains(pan: float) -> tuple[float, float]:
    """Constant-power (sin/cos) pan law: (left, right) gains for a stereo position −1 … +1, with
    left² + right² = 1 everywhere (−3 dB each in the centre)."""
    theta = (min(1.0, max(-1.0, pan)) + 1.0) * math.pi / 4.0
    return math.cos(theta), math.sin(theta)


def fan_poses(config: BlindAidConfig) -> list[tuple[float, float]]:
    """(pan, tilt) in degrees of each fan zone, indexed **left to right**: zone 0 at
    +fan_half_width_deg (left), zone fan_zones // 2 straight ahead, the last at the right edge."""
    n, half = config.fan_zones, config.fan_half_width_deg
    step = 2.0 * half / (n - 1)
    return [(round(half - i * step, 9) + 0.0, config.tilt_deg) for i in range(n)]


def scan_order(config: BlindAidConfig) -> list[int]:
    """Zone indices of one back-and-forth pass: 0 … n−1, then n−2 … 1 (the unit never jumps across
    the fan). Repeat it. An edge zone is revisited every 2(n−1) zones, the centre every n−1 on
    average; ``max_age_s`` must exceed the edge zones' revisit time."""
    n = config.fan_zones
    return list(range(n)) + list(range(n - 2, 0, -1))


@dataclass(frozen=True)
class Cue:
    """What the walker should hear now; the payload of the ``cue`` topic (the service adds ``ts``).

    ``bearing_deg`` (positive = left), ``range_m`` and ``zone`` (fan index, left to right) describe
    the nearest obstacle, or are None when the way is clear. ``interval_s`` is set for beeps only,
    ``pitch_hz`` for beeps and the tone. ``pan`` is the stereo position, −1 left … +1 right.
    ``speech`` is a phrase to say with this cue (an announcement), else None. ``reason`` says, for
    the blind cue only, why the aid cannot see (the part at fault, or how long no result came).
    """

    sound: str = SILENCE
    bearing_deg: float | None = None
    range_m: float | None = None
    zone: int | None = None
    interval_s: float | None = None
    pitch_hz: float | None = None
    pan: float = 0.0
    speech: str | None = None
    reason: str | None = None

    def to_json(self) -> dict:
        def r(v: float | None, nd: int) -> float | None:
            return None if v is None else round(v, nd)

        return {
            "bearing_deg": r(self.bearing_deg, 2),
            "range_m": r(self.range_m, 3),
            "zone": self.zone,
            "sound": self.sound,
            "interval_s": r(self.interval_s, 4),
            "pitch_hz": r(self.pitch_hz, 1),
            "pan": round(self.pan, 3),
            "speech": self.speech,
            "reason": self.reason,
        }


# --- speech ------------------------------------------------------------------------------------

_ONES = ("zero", "one", "two", "three", "four", "five", "six", "seven", "eight", "nine", "ten",
         "eleven", "twelve", "thirteen", "fourteen", "fifteen", "sixteen", "seventeen", "eighteen",
         "nineteen")
_TENS = ("", "", "twenty", "thirty", "forty", "fifty", "sixty", "seventy", "eighty", "ninety")


def integer_words(n: int) -> str:
    """English words for 0 ≤ n ≤ 999."""
    if not 0 <= n <= 999:
        raise ValueError(f"integer_words: {n} is outside 0-999")
    if n < 20:
        return _ONES[n]
    if n < 100:
        tens, ones = divmod(n, 10)
        return _TENS[tens] + (f"-{_ONES[ones]}" if ones else "")
    hundreds, rest = divmod(n, 100)
    return f"{_ONES[hundreds]} hundred" + (f" and {integer_words(rest)}" if rest else "")


def distance_words(range_m: float) -> str:
    """A distance in words to one decimal, rounding halves up: 1.25 → "one point three metres"."""
    tenths = int(math.floor(max(0.0, range_m) * 10.0 + 0.5))
    tenths = min(tenths, 9999)
    whole, frac = divmod(tenths, 10)
    return f"{integer_words(whole)} point {_ONES[frac]} metres"


# --- the blind aid -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Reading:
    """A zone's latest range: when it was measured, and since when it is only held (after a fault)."""

    zone: int
    range_m: float
    bearing_deg: float
    t_s: float
    held_since_s: float | None = None


class BlindAid:
    """Turns the fan's zone results into cues. Feed every zone result to :meth:`update`."""

    def __init__(self, config: BlindAidConfig | None = None) -> None:
        self.config = config or BlindAidConfig()
        self.poses = fan_poses(self.config)
        self._step_deg = 2.0 * self.config.fan_half_width_deg / (self.config.fan_zones - 1)
        self.reset()

    def reset(self) -> None:
        """Forget every reading (e.g. when the mode starts again); the cue becomes silence."""
        self._readings: dict[int, Reading] = {}
        self._cue = Cue()
        self._nearest_zone: int | None = None
        self._announced: str | None = None  # direction last announced; None after clear
        self._last_speech_s = -math.inf
        self._last_blind_speech_s = -math.inf
        self._since_s: float | None = None  # when results were last seen (or first expected)
        self._fault: str | None = None  # why the latest zone result was a fault
        self._blinded: str | None = None  # why the service says the rig cannot see

    @property
    def cue(self) -> Cue:
        """The latest cue returned (silence at first)."""
        return self._cue

    def readings(self) -> dict[int, Reading]:
        return dict(self._readings)

    def zone_of(self, result: ZoneResult) -> int | None:
        """The fan zone a result belongs to, by its pan (nearest fan pose, within half a step);
        None for a view outside the fan."""
        half = self.config.fan_half_width_deg
        i = round((half - result.pan_deg) / self._step_deg)
        if not 0 <= i < self.config.fan_zones:
            return None
        if abs(self.poses[i][0] - result.pan_deg) > self._step_deg / 2 + 1e-9:
            return None
        return int(i)

    def update(self, result: ZoneResult, t_s: float, seen_s: float | None = None) -> Cue | None:
        """Take one zone result measured at `t_s` (seconds, any monotonic origin); `seen_s`, when
        given, is when the rig last showed it worked for it (its last frame's end; default
        `t_s`). Returns the new cue when it changed meaningfully (sound, zone, range by
        ``min_change_m``, or something to say), else None."""
        self.alive(t_s if seen_s is None else seen_s)
        self._fault = _fault_reason(result) if result.status == FAULT else None
        zone = self.zone_of(result)
        if zone is not None:
            self._record(zone, result, t_s)
        return self.tick(t_s)

    def alive(self, t_s: float) -> None:
        """The rig showed at `t_s` that it works, short of a result (a frame's exposure ended): the
        wait for the next sign of life starts again from there (never from earlier)."""
        self._since_s = t_s if self._since_s is None else max(self._since_s, t_s)

    def set_blinded(self, reason: str | None, t_s: float) -> Cue | None:
        """The service says the rig cannot see (`reason`: lasers switched off, a laser that does not
        light…), or, with None, that this is over. Same return as update."""
        self._blinded = reason
        return self.tick(t_s)

    def blind_reason(self, t_s: float) -> str | None:
        """Why the aid cannot see at `t_s`, or None when it can."""
        if self._blinded is not None:
            return self._blinded
        if self._fault is not None:
            return self._fault
        if self._since_s is None:
            self._since_s = t_s  # the first call starts the wait for the first result
        if t_s - self._since_s > self.config.blind_after_s:
            return f"{_WAITED} for {t_s - self._since_s:.1f} s"
        return None

    def tick(self, t_s: float) -> Cue | None:
        """Re-evaluate at `t_s` without a new result (readings age out); same return as update."""
        cue = self._choose(t_s)
        if cue is None:
            return None
        self._cue = cue
        return cue

    def nearest(self, t_s: float) -> Reading | None:
        """The nearest valid reading within clear_m at `t_s` (hysteresis included), or None."""
        self._expire(t_s)
        c = self.config
        limit = c.clear_m + (c.hysteresis_m if self._cue.sound != SILENCE else 0.0)
        near = [r for r in self._readings.values() if r.range_m <= limit]
        if not near:
            return None
        best = min(near, key=lambda r: (r.range_m, abs(r.bearing_deg)))
        current = self._readings.get(self._nearest_zone) if self._nearest_zone is not None else None
        if current is not None and any(r is current for r in near) and current.range_m <= best.range_m + c.hysteresis_m:
            return current  # keep following the same zone unless another is clearly nearer
        return best

    def phrase(self, reading: Reading | None) -> str:
        if reading is None:
            return "way clear"
        return f"{distance_words(reading.range_m)}, {self.config.direction(reading.bearing_deg)}"

    def speak(self, t_s: float) -> str:
        """The phrase for the nearest obstacle now ("one point two metres, left", "way clear",
        "cannot see"), on request. Counts as an announcement for the rate limit."""
        if self.blind_reason(t_s) is not None:
            self._last_speech_s = t_s
            return CANNOT_SEE
        reading = self.nearest(t_s)
        self._last_speech_s = t_s
        self._announced = None if reading is None else self.config.direction(reading.bearing_deg)
        return self.phrase(reading)

    # --- internals ---

    def _record(self, zone: int, result: ZoneResult, t_s: float) -> None:
        old = self._readings.get(zone)
        if result.status == OK and result.range_m is not None:
            self._readings[zone] = Reading(zone, float(result.range_m), float(result.pan_deg), t_s)
        elif result.status in (FAULT, AMBIGUOUS):
            if old is not None and old.held_since_s is None:
                self._readings[zone] = Reading(old.zone, old.range_m, old.bearing_deg, old.t_s, t_s)
        elif result.status in (NO_SPOT, OUT_OF_RANGE):
            if old is not None and old.range_m <= self.config.danger_m:
                if old.held_since_s is None:  # maybe nearer than the rig can see: hold it
                    self._readings[zone] = Reading(old.zone, old.range_m, old.bearing_deg, old.t_s, t_s)
            else:
                self._readings.pop(zone, None)
        else:  # an unknown status: treat as no information
            pass

    def _expire(self, t_s: float) -> None:
        c = self.config
        for zone, r in list(self._readings.items()):
            if t_s - r.t_s > c.max_age_s or (r.held_since_s is not None and t_s - r.held_since_s > c.hold_s):
                del self._readings[zone]

    def _choose(self, t_s: float) -> Cue | None:
        """The cue for now, if it differs meaningfully from the last one; updates speech state."""
        c = self.config
        blind = self.blind_reason(t_s)
        if blind is not None:
            return self._choose_blind(blind, t_s)
        reading = self.nearest(t_s)
        self._nearest_zone = None if reading is None else reading.zone
        if reading is None:
            cue = Cue()
        else:
            d = reading.range_m
            in_danger = d <= c.danger_m or (self._cue.sound == TONE and d <= c.danger_m + c.hysteresis_m)
            near = Cue(bearing_deg=reading.bearing_deg, range_m=d, zone=reading.zone,
                       pan=c.stereo_pan(reading.bearing_deg))
            if in_danger:
                cue = replace(near, sound=TONE, pitch_hz=c.pitch_high_hz)
            else:
                cue = replace(near, sound=BEEP, interval_s=c.interval_s(d), pitch_hz=c.pitch_hz(d))
        speech = self._announcement(reading, t_s)
        if speech is not None:
            return replace(cue, speech=speech)
        last = self._cue
        changed = (
            cue.sound != last.sound
            or cue.zone != last.zone
            or (cue.range_m is not None and last.range_m is not None
                and abs(cue.range_m - last.range_m) >= max(c.min_change_m, 1e-9))
        )
        return cue if changed else None

    def _choose_blind(self, reason: str, t_s: float) -> Cue | None:
        """The blind cue, said aloud on entering it (at most once per speak_min_gap_s); a changed
        reason makes a new cue (for `cue` on MQTT), a stale wait's growing seconds do not."""
        last = self._cue
        self._nearest_zone = None
        self._announced = None  # whatever is seen next is new
        cue = Cue(sound=BLIND, reason=reason)
        if last.sound == BLIND:
            same = last.reason == reason or (reason.startswith(_WAITED)
                                            and (last.reason or "").startswith(_WAITED))
            return None if same else cue
        if t_s - self._last_blind_speech_s >= self.config.speak_min_gap_s:
            self._last_blind_speech_s = t_s
            return replace(cue, speech=CANNOT_SEE)
        return cue

    def _announcement(self, reading: Reading | None, t_s: float) -> str | None:
        """Something new to say: an obstacle after clear, or the nearest one in another direction,
        at most once per speak_min_gap_s (a due announcement waits for the gap, then is said if it
        still holds)."""
        if reading is None:
            self._announced = None
            return None
        if not self.config.speak_new:
            return None
        direction = self.config.direction(reading.bearing_deg)
        if direction == self._announced or t_s - self._last_speech_s < self.config.speak_min_gap_s:
            return None
        self._announced = direction
        self._last_speech_s = t_s
        return self.phrase(reading)


_PART_WORDS = {"camera": "camera", "lasers": "lasers", "ptu": "pan-tilt unit"}


def _fault_reason(result: ZoneResult) -> str:
    """Why a fault result means the aid cannot see: the part that failed, in a few words (the
    details, which change from zone to zone, are in `state` and the log)."""
    return f"{_PART_WORDS.get(result.part or '', 'ranging')} fault"
