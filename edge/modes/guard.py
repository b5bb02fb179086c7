"""The area guard (thesis §5.3): learn a room's background, then report what enters it.

Pure logic: sweeps of zone results in, events out; no I/O, no clocks, no MQTT. The service feeds
every sweep to :meth:`Guard.update` and publishes the :class:`GuardEvent`\\ s it returns on
``<p>/<id>/alert`` (``shared/spec/mqtt.md``; the MQTT layer adds ``ts``).

**Background.** The first ``learn_sweeps`` sweeps are learnt, not judged. Each zone keeps the ranges
it gave (with their reported σ) and the statuses it gave (``ok``, ``no_spot``, ``out_of_range``;
``fault`` and ``ambiguous`` say nothing about the room and are not kept). From them:

* *ranged* zone (at least 3 ranges, ``ok`` in at least ``min_ok_fraction`` of its observations): the
  reference is the median; the scale is the largest of 1.4826·MAD, the median reported ``sigma_m``
  and a floor ``sigma_floor_m + sigma_floor_frac·range``. A zone that flickers between two surfaces
  (a beam on an edge) has its *near* mode as reference when at least two of its ranges are nearer
  than the median by more than the threshold — so that an edge zone's normal flicker never alarms.
* *sparse* zone (ranges, but too few or too rarely ``ok``: a dark armchair): the reference is the
  nearest range seen, so only something nearer than anything seen there counts.
* *glimpsed* zone (no range of its own, but where its reference spot was not found another laser's
  spot beside the reference's beam was: a surface too dim for the reference laser most of the time,
  which a camera's noisier frames leave often): a sparse zone whose reference is the median depth of
  those spots (`glimpse`). Taken for open, such a zone alarmed whenever its reference spot showed
  after all, at the same range, twice in a row (the Pi camera's frames through the simulator's ISP:
  a wall 2.3 m away in 6 sweeps of 20).
* *open* zone (no range at all: a doorway onto a dark corridor, beyond the working range): the
  reference is ``open_max_m`` (the working range's far limit): any ``ok`` range nearer than it by more
  than the threshold is foreground — an object in the doorway. Its usual status (``out_of_range``,
  ``no_spot``) is its background and clears a track there.
* a zone with fewer than ⌈learn_sweeps/2⌉ observations when learning ends (faults throughout) goes
  on learning by itself until it has them, and meanwhile is unknown.

**Adaptation** (``adapt``, on by default): after learning, each zone that no track occupies keeps
adding the readings that are *not* foreground (and its ``no_spot``/``out_of_range`` statuses) to
windows of the last ``adapt_window`` observations and recomputes its statistics. Foreground readings never enter, so an
object that arrives stays an intrusion until it leaves or ``relearn``; something taken away (the
background moving farther) is absorbed within about ``adapt_window / 2`` sweeps; slow drifts inside
the threshold are followed. Ranges and statuses have separate windows, so a zone that reads nothing
for a while does not forget its range.

**Detection.** A zone is *foreground* when its result is ``ok`` and
``range < reference − max(k_sigma·max(scale, sigma_m of the reading), min_drop_m)``. A zone is
*background* when ``ok`` and not foreground, or when its status is one it usually gives (at least a
quarter of its observations). Anything else — ``fault``, ``ambiguous``, a zone missing from the
sweep, an unusual ``no_spot``/``out_of_range`` (a dark coat hides the spot), a zone still learning — is
*unknown*: it neither raises nor clears.

**Doorways.** Given the map (``outside_m`` of :meth:`Guard.update`, from the occupancy grid: see
``OccupancyGrid.doorway_m``), a zone whose ray leaves the room through a doorway onto a dark or
long corridor ignores readings beyond the room's end along it (about a metre past the door):
someone walking in the corridor is not in the guarded room. Someone in the doorway or in the room
is, as before. The map cannot tell a corridor from a dark part of the room seen through an opening
(the far arm of an L-shaped room): someone there more than about a metre past the opening is
ignored too. So the service passes the map only with ``ignore_beyond_doorways`` (off by default).

**Blobs.** Foreground zones that are neighbours (index ±1 modulo ``zone_count``: zones 63 and 0 of a
full turn are neighbours) and whose ranges differ by at most ``blob_range_tol_m`` form one blob; the
gap between them may hold up to ``bridge_zones`` unknown zones. A blob's position is the mean of its
zones' base-frame points (``point_base_m``; else from pan, tilt and range, ignoring the laser's
offset), its bearing that position's (base frame, positive to the left), its range the median of
the zones' ranges and its baseline the median of their references. Its zones are listed in sweep
order starting after the largest gap (a blob across the turn lists 63 before 0).

**Tracks and debouncing.** Blobs are matched to tracks greedily by base-frame distance (to the
track's last position or its constant-velocity prediction, whichever is nearer) within a gate of
``gate_m + max_speed_mps·Δt``; further blobs within ``merge_m`` of a matched blob join it (an object
split by a dropped zone). A blob matching no track starts a *pending* track. Debounce rule: a pending
track becomes an ``intrusion`` after ``confirm_sweeps`` *consecutive* sweeps with a matching blob; a
sweep without one drops it silently. So a one-sweep spike, in one zone or several, never alarms.
``confirm_zones`` (off by default) lets a blob of at least that many zones (≥ 2) confirm at once, for
guards that sweep so seldom that an intruder may be seen only once. A confirmed track raises
``moved`` whenever its position is at least ``move_min_m`` from where it was last reported, and
``cleared`` after ``clear_sweeps`` sweeps without a matching blob in which at least one of its last
zones was known (a track whose zones all went unknown is held, not cleared). Velocities are
base-frame finite differences of the last two positions over their times; each blob's time is its
zones' mean time when :meth:`Guard.update` is given per-zone times (a real sweep takes seconds),
else the sweep's time.

Track ids are ``t1``, ``t2``, … in order of confirmation, never reused by one :class:`Guard` (not even
after ``relearn``); pending tracks have none.
"""

from __future__ import annotations

import itertools
import math
from collections import Counter, deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from edge.ranging import NO_SPOT, OK, OUT_OF_RANGE, ZoneResult
from edge.rig import Laser, wrap_deg
from edge.schema import require

INTRUSION, MOVED, CLEARED = "intrusion", "moved", "cleared"
EVENTS = (INTRUSION, MOVED, CLEARED)

_MAD_TO_SIGMA = 1.4826  # MAD of a normal distribution → σ
_USUAL_FRACTION = 0.25  # a non-ok status this common in a zone is part of its background
_KEPT_STATUSES = (OK, NO_SPOT, OUT_OF_RANGE)  # statuses that tell something about the room
_FG, _BG, _UNKNOWN = "foreground", "background", "unknown"
_OPEN, _SPARSE, _RANGED = "open", "sparse", "ranged"
# Another laser's spot tells the reference's background where it lands this near the reference's beam
# (across the view, at its own depth: a surface goes on that far, mostly) and is bright enough to
# believe. (The default rig's parallel laser lands 4 cm beside it at every depth; the sloped one
# 0.17 × the depth below it, on another surface beyond about 0.6 m.)
GLIMPSE_APART_M = 0.1
GLIMPSE_MIN_SNR = 10.0


def glimpse(res: ZoneResult, reference: Laser) -> float | None:
    """The depth (m) of the nearest spot of another laser than `reference` that a zone whose
    reference spot was not found (``no_spot``) holds within GLIMPSE_APART_M of where the reference's
    beam would be at that depth, of SNR GLIMPSE_MIN_SNR or more; None where there is none."""
    (ox, oy, oz), (dx, dy, dz) = reference.origin_m, reference.direction
    if res.status != NO_SPOT or dz <= 0:
        return None
    near = []
    for name, m in res.lasers.items():
        x, y, z = m.point_m.tolist()
        if name == reference.name or m.snr < GLIMPSE_MIN_SNR or not z > 0:
            continue
        t = (z - oz) / dz  # (along the reference's beam to that depth)
        if math.hypot(x - (ox + t * dx), y - (oy + t * dy)) <= GLIMPSE_APART_M:
            near.append(float(m.depth_m))
    return min(near, default=None)


@dataclass(frozen=True)
class GuardConfig:
    """Tuning of the area guard (``[guard]`` in the config). See the module doc for the rules."""

    learn_sweeps: int = 5  # sweeps to learn the background
    k_sigma: float = 4.0  # how many σ nearer than the background counts
    min_drop_m: float = 0.15  # and at least this much nearer
    confirm_sweeps: int = 2  # consecutive sweeps a new object must be seen before `intrusion`
    confirm_zones: int = 0  # a blob of at least this many zones confirms at once (0: off; else >= 2)
    clear_sweeps: int = 2  # sweeps without the object (its zones known) before `cleared`
    move_min_m: float = 0.2  # position change that makes a `moved`
    open_max_m: float = 5.0  # zones with no background: an ok range nearer than this is foreground
    min_ok_fraction: float = 0.5  # a zone giving ranges less often than this is "sparse"
    sigma_floor_m: float = 0.01  # noise floor of a zone's background: this …
    sigma_floor_frac: float = 0.005  # … plus this fraction of its range
    adapt: bool = True  # keep learning the background from readings that are not foreground
    adapt_window: int = 20  # observations a zone's background is computed from
    blob_range_tol_m: float = 0.5  # neighbouring foreground zones belong to one blob within this
    bridge_zones: int = 1  # unknown zones a blob may span
    gate_m: float = 0.5  # association gate: this …
    max_speed_mps: float = 2.5  # … plus this speed times the time since the track was last seen
    merge_m: float = 0.6  # blobs this close together are one object
    # The service passes the map's doorways to `update` (outside_m): off by default, for a dark part
    # of the room itself seen through an opening (an L-shaped room's far arm) looks like a corridor.
    ignore_beyond_doorways: bool = False

    def __post_init__(self) -> None:
        require(1 <= self.learn_sweeps <= 1000, "learn_sweeps", f"must be 1-1000, got {self.learn_sweeps}")
        require(self.k_sigma > 0, "k_sigma", f"must be positive, got {self.k_sigma}")
        require(self.min_drop_m >= 0, "min_drop_m", f"must be >= 0, got {self.min_drop_m}")
        require(1 <= self.confirm_sweeps <= 100, "confirm_sweeps", f"must be 1-100, got {self.confirm_sweeps}")
        require(self.confirm_zones == 0 or self.confirm_zones >= 2, "confirm_zones",
                f"must be 0 (off) or >= 2 (one zone must never alarm at once), got {self.confirm_zones}")
        require(1 <= self.clear_sweeps <= 100, "clear_sweeps", f"must be 1-100, got {self.clear_sweeps}")
        require(self.move_min_m > 0, "move_min_m", f"must be positive, got {self.move_min_m}")
        require(self.open_max_m > 0, "open_max_m", f"must be positive, got {self.open_max_m}")
        require(0 < self.min_ok_fraction <= 1, "min_ok_fraction", f"must be in (0, 1], got {self.min_ok_fraction}")
        require(self.sigma_floor_m >= 0, "sigma_floor_m", f"must be >= 0, got {self.sigma_floor_m}")
        require(self.sigma_floor_frac >= 0, "sigma_floor_frac", f"must be >= 0, got {self.sigma_floor_frac}")
        require(1 <= self.adapt_window <= 10000, "adapt_window", f"must be 1-10000, got {self.adapt_window}")
        require(self.blob_range_tol_m > 0, "blob_range_tol_m", f"must be positive, got {self.blob_range_tol_m}")
        require(0 <= self.bridge_zones <= 8, "bridge_zones", f"must be 0-8, got {self.bridge_zones}")
        require(self.gate_m > 0, "gate_m", f"must be positive, got {self.gate_m}")
        require(self.max_speed_mps >= 0, "max_speed_mps", f"must be >= 0, got {self.max_speed_mps}")
        require(self.merge_m >= 0, "merge_m", f"must be >= 0, got {self.merge_m}")


@dataclass(frozen=True)
class GuardEvent:
    """One alert, as published on ``alert`` (mqtt.md) less its ``ts``."""

    event: str  # "intrusion" | "moved" | "cleared"
    id: str  # track id, stable while followed
    zones: tuple[int, ...]  # in sweep order (a blob across the turn: 63 before 0)
    bearing_deg: float  # of the object's centroid, base frame, (-180, 180], positive to the left
    range_m: float  # median range of its zones
    baseline_m: float  # median background range of those zones (open zones count as open_max_m)
    velocity_mps: tuple[float, float] | None  # base-frame (vx, vy); None until two positions
    sweep: int

    def to_json(self) -> dict:
        return {
            "event": self.event,
            "id": self.id,
            "zones": list(self.zones),
            "bearing_deg": round(self.bearing_deg, 2),
            "range_m": round(self.range_m, 3),
            "baseline_m": round(self.baseline_m, 3),
            "velocity_mps": None if self.velocity_mps is None else [round(v, 3) for v in self.velocity_mps],
            "sweep": self.sweep,
        }


@dataclass(frozen=True)
class Track:
    """A followed object as the guard last saw it (confirmed tracks only)."""

    id: str
    zones: tuple[int, ...]
    position_m: tuple[float, float]  # base frame x, y of the centroid
    velocity_mps: tuple[float, float] | None
    bearing_deg: float
    range_m: float
    baseline_m: float
    first_sweep: int  # the sweep of its `intrusion`
    last_seen_sweep: int

    def to_json(self) -> dict:
        return {
            "id": self.id,
            "zones": list(self.zones),
            "position_m": [round(c, 3) for c in self.position_m],
            "velocity_mps": None if self.velocity_mps is None else [round(v, 3) for v in self.velocity_mps],
            "bearing_deg": round(self.bearing_deg, 2),
            "range_m": round(self.range_m, 3),
            "baseline_m": round(self.baseline_m, 3),
            "first_sweep": self.first_sweep,
            "last_seen_sweep": self.last_seen_sweep,
        }


# --- per-zone background ----------------------------------------------------------------------


@dataclass(frozen=True)
class _Background:
    kind: str  # _OPEN, _SPARSE or _RANGED
    ref_m: float  # what a reading is compared with
    scale_m: float  # 1-σ noise of the background (0 for open zones)
    ok_fraction: float
    usual: frozenset[str]  # non-ok statuses that are this zone's normal


class _Zone:
    """One zone's memory: its background ranges and statuses."""

    def __init__(self, window: int) -> None:
        self.ranges: deque[tuple[float, float]] = deque(maxlen=window)  # (range, reported σ)
        self.statuses: deque[str] = deque(maxlen=window)
        self.glimpses: deque[float] = deque(maxlen=window)  # depths of `glimpse`
        self.learned = False
        self._bg: _Background | None = None

    def add(self, status: str, range_m: float | None = None, sigma_m: float | None = None,
            glimpsed_m: float | None = None) -> None:
        if glimpsed_m is not None:
            self.glimpses.append(glimpsed_m)
        if status == OK:
            if range_m is None:
                raise ValueError("an ok reading needs its range")
            self.ranges.append((float(range_m), float(sigma_m or 0.0)))
        self.statuses.append(status)
        self._bg = None

    def learn(self, res: ZoneResult, glimpsed_m: float | None = None) -> None:
        r = _ok_range(res)
        if r is not None:
            self.add(OK, r, res.sigma_m)
        elif res.status in _KEPT_STATUSES and res.status != OK:
            self.add(res.status, glimpsed_m=glimpsed_m)

    @property
    def observations(self) -> int:
        return len(self.statuses)

    def background(self, cfg: GuardConfig) -> _Background:
        if self._bg is None:
            self._bg = self._compute(cfg)
        return self._bg

    def _compute(self, cfg: GuardConfig) -> _Background:
        n = len(self.statuses)
        counts = Counter(self.statuses)
        ok_fraction = counts[OK] / n if n else 0.0
        usual = frozenset(s for s, c in counts.items() if s != OK and c >= _USUAL_FRACTION * n)

        def floor(at: float) -> float:
            return cfg.sigma_floor_m + cfg.sigma_floor_frac * at

        if not self.ranges and self.glimpses:  # dim, not empty: the median, one stray spot aside
            ref = float(np.median(self.glimpses))
            return _Background(_SPARSE, ref, floor(ref), ok_fraction, usual)
        if not self.ranges:
            return _Background(_OPEN, cfg.open_max_m, 0.0, ok_fraction, usual)
        r = np.array([x for x, _ in self.ranges])
        reported = float(np.median([s for _, s in self.ranges]))

        if len(r) < 3 or ok_fraction < cfg.min_ok_fraction:
            ref = float(r.min())
            return _Background(_SPARSE, ref, max(reported, floor(ref)), ok_fraction, usual)
        med = float(np.median(r))
        scale = max(_MAD_TO_SIGMA * float(np.median(np.abs(r - med))), reported, floor(med))
        near = r[r < med - max(cfg.k_sigma * scale, cfg.min_drop_m)]
        if len(near) >= 2:  # a zone flickering between two surfaces: its near one is background
            ref = float(np.median(near))
            mad = _MAD_TO_SIGMA * float(np.median(np.abs(near - ref)))
            return _Background(_RANGED, ref, max(mad, reported, floor(ref)), ok_fraction, usual)
        return _Background(_RANGED, med, scale, ok_fraction, usual)


def _horizontal_m(res: ZoneResult, range_m: float) -> float:
    """How far from the pan axis a zone's point lies, horizontally (base frame)."""
    if res.point_base_m is not None:
        return float(math.hypot(res.point_base_m[0], res.point_base_m[1]))
    return range_m * math.cos(math.radians(res.tilt_deg))


def _ok_range(res: ZoneResult) -> float | None:
    """The range of an ok zone, if it is a usable one (finite, positive); else None."""
    r = res.range_m
    return float(r) if res.status == OK and r is not None and math.isfinite(r) and r > 0 else None


# --- blobs and tracks -------------------------------------------------------------------------


@dataclass(frozen=True)
class _Reading:
    """A foreground zone."""

    zone: int
    range_m: float
    ref_m: float
    xy: tuple[float, float]
    t_s: float


@dataclass(frozen=True)
class _Blob:
    zones: tuple[int, ...]
    xy: tuple[float, float]
    t_s: float
    range_m: float
    baseline_m: float

    @property
    def bearing_deg(self) -> float:
        return wrap_deg(math.degrees(math.atan2(self.xy[1], self.xy[0])))


def _blob(readings: Sequence[_Reading], zone_count: int) -> _Blob:
    zones = _sweep_order([r.zone for r in readings], zone_count)
    return _Blob(
        zones,
        (float(np.mean([r.xy[0] for r in readings])), float(np.mean([r.xy[1] for r in readings]))),
        float(np.mean([r.t_s for r in readings])),
        float(np.median([r.range_m for r in readings])),
        float(np.median([r.ref_m for r in readings])),
    )


def _sweep_order(zones: Sequence[int], n: int) -> tuple[int, ...]:
    """Zones in sweep order, starting after the largest circular gap (63, 0 for a blob across the
    turn)."""
    z = sorted(set(zones))
    if len(z) < 2:
        return tuple(z)
    gaps = [(z[(i + 1) % len(z)] - z[i]) % n for i in range(len(z))]
    start = (max(range(len(z)), key=lambda i: gaps[i]) + 1) % len(z)
    return tuple(z[start:] + z[:start])




class _TrackState:
    def __init__(self, blob: _Blob, sweep: int) -> None:
        self.id: str | None = None
        self.blob = blob
        self.history: deque[tuple[float, float, float]] = deque(maxlen=2)  # (t, x, y)
        self.history.append((blob.t_s, *blob.xy))
        self.velocity: tuple[float, float] | None = None
        self.hits = 1
        self.misses = 0
        self.reported_xy: tuple[float, float] | None = None
        self.first_sweep = sweep
        self.last_seen_sweep = sweep

    @property
    def confirmed(self) -> bool:
        return self.id is not None

    def observe(self, blob: _Blob, sweep: int) -> None:
        t0, x0, y0 = self.history[-1]
        if blob.t_s - t0 > 1e-6:
            self.velocity = ((blob.xy[0] - x0) / (blob.t_s - t0), (blob.xy[1] - y0) / (blob.t_s - t0))
        self.history.append((blob.t_s, *blob.xy))
        self.blob = blob
        self.last_seen_sweep = sweep

    def predict(self, t_s: float) -> tuple[float, float]:
        x, y = self.blob.xy
        if self.velocity is None:
            return x, y
        dt = max(t_s - self.blob.t_s, 0.0)
        return x + self.velocity[0] * dt, y + self.velocity[1] * dt

    def event(self, kind: str, sweep: int) -> GuardEvent:
        b = self.blob
        return GuardEvent(kind, self.id or "", b.zones, b.bearing_deg, b.range_m, b.baseline_m, self.velocity, sweep)

    def public(self) -> Track:
        b = self.blob
        return Track(
            self.id or "", b.zones, b.xy, self.velocity, b.bearing_deg, b.range_m, b.baseline_m,
            self.first_sweep, self.last_seen_sweep,
        )


def _dist(a: tuple[float, float], b: tuple[float, float]) -> float:
    return math.hypot(a[0] - b[0], a[1] - b[1])


# --- the guard --------------------------------------------------------------------------------


class Guard:
    """Learns the background of `zone_count` zones, then turns sweeps into guard events.

    Track ids are ``t1``, ``t2``, … or, given `new_id`, whatever it returns for each new track (the
    service's are unique across restarts and across guards: ``b7-t1``)."""

    def __init__(self, config: GuardConfig, zone_count: int, new_id: Callable[[], str] | None = None,
                 reference: Laser | None = None) -> None:
        """`reference`: the rig's reference laser, whose beam says which other lasers' spots tell
        a zone's background where its own spot was not found (`glimpse`; None: none do)."""
        if zone_count < 1:
            raise ValueError(f"zone_count must be >= 1, got {zone_count}")
        self.config = config
        self.zone_count = zone_count
        self.reference = reference
        numbers = itertools.count(1)
        self._new_id = new_id or (lambda: f"t{next(numbers)}")
        self._last_sweep: int | None = None
        self._reset()

    def _reset(self) -> None:
        window = max(self.config.adapt_window, self.config.learn_sweeps)
        self._zones = [_Zone(window) for _ in range(self.zone_count)]
        self._learned_sweeps = 0
        self._tracks: list[_TrackState] = []

    @property
    def _zone_min_observations(self) -> int:
        return math.ceil(self.config.learn_sweeps / 2)

    # --- public ---------------------------------------------------------------------------

    @property
    def learning(self) -> bool:
        return self._learned_sweeps < self.config.learn_sweeps

    @property
    def tracks(self) -> list[Track]:
        """The confirmed tracks (pending ones are not yet objects)."""
        return [t.public() for t in self._tracks if t.confirmed]

    def relearn(self) -> list[GuardEvent]:
        """Forget the background and every track and learn again. Returns a `cleared` for each
        confirmed track (at the last sweep seen), for the caller to publish so that consumers do
        not keep an object that is no longer followed; ignoring them is harmless otherwise."""
        sweep = self._last_sweep if self._last_sweep is not None else 0
        events = [t.event(CLEARED, sweep) for t in self._tracks if t.confirmed]
        self._reset()
        return events

    def state(self) -> dict:
        """For the device's ``state`` topic."""
        cfg = self.config
        learned = [z for z in self._zones if z.learned]
        kinds = Counter(z.background(cfg).kind for z in learned)
        return {
            "learning": self.learning,
            "learned_sweeps": min(self._learned_sweeps, cfg.learn_sweeps),
            "learn_sweeps": cfg.learn_sweeps,
            "zones": self.zone_count,
            "zones_with_background": kinds[_RANGED] + kinds[_SPARSE],
            "open_zones": [i for i, z in enumerate(self._zones) if z.learned and z.background(cfg).kind == _OPEN],
            "unlearned_zones": [] if self.learning else [i for i, z in enumerate(self._zones) if not z.learned],
            "tracks": [t.to_json() for t in self.tracks],
            "pending_tracks": sum(1 for t in self._tracks if not t.confirmed),
        }

    def update(
        self,
        results: Sequence[ZoneResult],
        sweep: int,
        t_s: float,
        zone_t_s: Mapping[int, float] | None = None,
        outside_m: Mapping[int, float] | None = None,
    ) -> list[GuardEvent]:
        """Take one sweep's zone results (any order; zones may be missing or not ok) and return
        the events it raises. `t_s` is the sweep's time in seconds; `zone_t_s`, when given, the
        time each zone was measured (zones absent from it take `t_s`), for better velocities.
        `outside_m`, when given, says for the zones whose rays leave the room through a doorway
        how far (horizontally from the pan axis) the room ends (``GridKeeper.outside_m``, from the
        map): a reading beyond is outside the guarded room — someone passing in the corridor —
        and is background, never foreground, and not learnt."""
        by_zone: dict[int, ZoneResult] = {}
        for res in results:
            if not 0 <= res.index < self.zone_count:
                raise ValueError(f"zone index {res.index} outside 0..{self.zone_count - 1}")
            by_zone[res.index] = res
        self._last_sweep = sweep
        if self.learning:
            for k, res in by_zone.items():
                self._zones[k].learn(res, self._glimpsed(res))
            self._learned_sweeps += 1
            if not self.learning:
                for z in self._zones:
                    z.learned = z.observations >= self._zone_min_observations
            return []
        times = zone_t_s or {}
        states, readings = self._classify(by_zone, times, t_s, outside_m or {})
        blobs = self._blobs(readings, states)
        return self._follow(blobs, states, sweep)

    # --- zones ----------------------------------------------------------------------------

    def _glimpsed(self, res: ZoneResult) -> float | None:
        return None if self.reference is None else glimpse(res, self.reference)

    def _classify(
        self, by_zone: Mapping[int, ZoneResult], times: Mapping[int, float], t_s: float,
        outside_m: Mapping[int, float],
    ) -> tuple[list[str], dict[int, _Reading]]:
        cfg = self.config
        states = [_UNKNOWN] * self.zone_count
        readings: dict[int, _Reading] = {}
        occupied = {k for tr in self._tracks for k in tr.blob.zones}
        for k, zone in enumerate(self._zones):
            adapt = cfg.adapt and k not in occupied
            res = by_zone.get(k)
            if res is None:
                continue
            if not zone.learned:
                zone.learn(res, self._glimpsed(res))
                zone.learned = zone.observations >= self._zone_min_observations
                continue
            bg = zone.background(cfg)
            r = _ok_range(res)
            if r is not None and k in outside_m and _horizontal_m(res, r) > outside_m[k]:
                states[k] = _BG  # seen through a doorway, beyond the room: not the guard's
                continue
            if r is not None:
                sigma = max(bg.scale_m, float(res.sigma_m or 0.0))
                if r < bg.ref_m - max(cfg.k_sigma * sigma, cfg.min_drop_m):
                    states[k] = _FG
                    readings[k] = _Reading(k, r, bg.ref_m, _xy(res, r), float(times.get(k, t_s)))
                    continue
                states[k] = _BG
                if adapt:
                    zone.add(OK, r, res.sigma_m)
            elif res.status in _KEPT_STATUSES and res.status != OK:
                if res.status in bg.usual:
                    states[k] = _BG
                if adapt:
                    zone.add(res.status, glimpsed_m=self._glimpsed(res))
        return states, readings

    def _blobs(self, readings: Mapping[int, _Reading], states: Sequence[str]) -> list[_Blob]:
        cfg, n = self.config, self.zone_count
        parent = {k: k for k in readings}

        def find(k: int) -> int:
            while parent[k] != k:
                parent[k] = parent[parent[k]]
                k = parent[k]
            return k

        for k in readings:
            for step in range(1, cfg.bridge_zones + 2):
                j = (k + step) % n
                if j == k:
                    break
                if j in readings:
                    if abs(readings[j].range_m - readings[k].range_m) <= cfg.blob_range_tol_m:
                        parent[find(j)] = find(k)
                    break
                if states[j] != _UNKNOWN:
                    break
        groups: dict[int, list[_Reading]] = {}
        for k in sorted(readings):
            groups.setdefault(find(k), []).append(readings[k])
        return [_blob(g, n) for g in groups.values()]

    # --- tracks ---------------------------------------------------------------------------

    def _follow(self, blobs: list[_Blob], states: Sequence[str], sweep: int) -> list[GuardEvent]:
        cfg = self.config
        tracks = self._tracks
        pairs = []
        for ti, tr in enumerate(tracks):
            for bi, b in enumerate(blobs):
                gate = cfg.gate_m + cfg.max_speed_mps * max(b.t_s - tr.blob.t_s, 0.0)
                d = min(_dist(b.xy, tr.blob.xy), _dist(b.xy, tr.predict(b.t_s)))
                if d <= gate:
                    pairs.append((d, not tr.confirmed, ti, bi))
        pairs.sort()
        assigned: dict[int, list[int]] = {}
        used: set[int] = set()
        for _, _, ti, bi in pairs:
            if bi not in used and ti not in assigned:
                assigned[ti] = [bi]
                used.add(bi)
        # Blobs beside a matched one are the same object, split (a dropped zone, an arm).
        for bi, b in enumerate(blobs):
            if bi in used:
                continue
            near = [(_dist(b.xy, blobs[bis[0]].xy), ti) for ti, bis in assigned.items()]
            near = [x for x in near if x[0] <= cfg.merge_m]
            if near:
                assigned[min(near)[1]].append(bi)
                used.add(bi)
        # The rest are new objects; those close together are one.
        fresh: list[list[_Blob]] = []
        for bi, b in enumerate(blobs):
            if bi in used:
                continue
            for group in fresh:
                if any(_dist(b.xy, o.xy) <= cfg.merge_m for o in group):
                    group.append(b)
                    break
            else:
                fresh.append([b])

        events: list[GuardEvent] = []
        kept: list[_TrackState] = []
        for ti, tr in enumerate(tracks):
            if ti in assigned:
                tr.observe(self._merged([blobs[i] for i in assigned[ti]]), sweep)
                tr.misses = 0
                kept.append(tr)
                if not tr.confirmed:
                    tr.hits += 1
                    if self._confirms(tr):
                        events.append(self._confirm(tr, sweep))
                else:
                    assert tr.reported_xy is not None  # `_confirm` sets it with the id
                    if _dist(tr.blob.xy, tr.reported_xy) < cfg.move_min_m:
                        continue
                    tr.reported_xy = tr.blob.xy
                    events.append(tr.event(MOVED, sweep))
                continue
            if not tr.confirmed:
                continue  # debounce: a pending object must be seen in consecutive sweeps
            if any(states[k] != _UNKNOWN for k in tr.blob.zones):
                tr.misses += 1
            if tr.misses >= cfg.clear_sweeps:
                events.append(tr.event(CLEARED, sweep))
                continue
            kept.append(tr)
        for group in fresh:
            tr = _TrackState(self._merged(group), sweep)
            kept.append(tr)
            if self._confirms(tr):
                events.append(self._confirm(tr, sweep))
        self._tracks = kept
        return events

    def _merged(self, blobs: list[_Blob]) -> _Blob:
        if len(blobs) == 1:
            return blobs[0]
        w = [len(b.zones) for b in blobs]
        total = sum(w)
        zones = _sweep_order([z for b in blobs for z in b.zones], self.zone_count)
        xy = (sum(wi * b.xy[0] for wi, b in zip(w, blobs)) / total,
              sum(wi * b.xy[1] for wi, b in zip(w, blobs)) / total)
        t = sum(wi * b.t_s for wi, b in zip(w, blobs)) / total
        ranges = [b.range_m for b, wi in zip(blobs, w) for _ in range(wi)]
        bases = [b.baseline_m for b, wi in zip(blobs, w) for _ in range(wi)]
        return _Blob(zones, xy, t, float(np.median(ranges)), float(np.median(bases)))

    def _confirms(self, tr: _TrackState) -> bool:
        cfg = self.config
        return tr.hits >= cfg.confirm_sweeps or (cfg.confirm_zones >= 2 and len(tr.blob.zones) >= cfg.confirm_zones)

    def _confirm(self, tr: _TrackState, sweep: int) -> GuardEvent:
        tr.id = self._new_id()
        tr.first_sweep = sweep
        tr.reported_xy = tr.blob.xy
        return tr.event(INTRUSION, sweep)


def _xy(res: ZoneResult, range_m: float) -> tuple[float, float]:
    """Base-frame x, y of an ok zone's point: `point_base_m`, else from pan, tilt and its range
    (the reference laser's small offset from the pan axis ignored)."""
    if res.point_base_m is not None:
        p = np.asarray(res.point_base_m, dtype=np.float64)
        return float(p[0]), float(p[1])
    d = range_m * math.cos(math.radians(res.tilt_deg))
    pan = math.radians(res.pan_deg)
    return d * math.cos(pan), d * math.sin(pan)
