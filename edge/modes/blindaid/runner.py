"""The blind aid on the rig: scan the fan, turn each zone's range into a cue, play it.

The pure part (which obstacle, which sound) is :mod:`edge.modes.blindaid.logic`, the sound is
:mod:`edge.modes.blindaid.sound`; this module moves the unit through the fan one zone at a time, feeds each
result to the :class:`~edge.modes.blindaid.BlindAid`, and keeps the sound going: a timer on the rig's
clock (:mod:`edge.clock`; a thread of its own in real time) advances the
:class:`~edge.modes.blindaid.sound.CuePlayer` every few milliseconds, whatever the unit is doing, so
beeps keep their rhythm while the head moves. That timer also ticks the blind aid: when the rig
stops giving results (a camera that stalls blocks the loop for its
timeout on every frame) the "cannot see" cue sounds within ``blindaid.blind_after_s``, long before
the zone's fault comes back. Speech is synthesised in a thread of its own (espeak-ng takes
50-200 ms on a Pi) and mixed in when ready.

Every zone result also goes to `on_zone` with the lasers seen lit when off (the service publishes it
on ``range`` and feeds the rig's health, which restarts a stalled camera, as in the other modes).

Times are seconds of the rig's clock since the runner started: the stream time of the sound, so
that a WAV of a run is its timeline (its simulated timeline on a simulated rig).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Set
from dataclasses import replace

from edge.capture import Capture
from edge.config import Config
from edge.hw.base import Frame
from edge.modes.blindaid.logic import BLIND, BlindAid, Cue, fan_poses, scan_order
from edge.modes.blindaid.sound import AplaySink, CuePlayer, NullSink, Synth, WavSink, speak_to_frames
from edge.ranging import Ranger, ZoneResult

log = logging.getLogger(__name__)


def open_audio(config: Config):
    """The configured sink and whether it plays live (``[audio] out``)."""
    out, rate = config.audio.out, config.blindaid.sample_rate
    if not out:
        return NullSink(rate), False
    if out == "alsa" or out.startswith("alsa:"):
        device = out[5:] or None
        return AplaySink(rate, device=device, buffer_ms=int(config.audio.lead_ms * 2) or 40), True
    return WavSink(out, rate), False


class BlindAidRunner:
    """The blind aid's loop step and its sound, on opened parts."""

    def __init__(self, config: Config, parts, on_cue: Callable[[Cue], None],
                 on_zone: Callable[[ZoneResult, Set[str]], None] | None = None,
                 ranger: Ranger | None = None) -> None:
        from edge.sweep import sweeper_for

        self.config = config
        self.aid = BlindAid(config.blindaid)
        # The loop's thread (zone results) and the sound's (ticks) both move the blind aid.
        self._lock = threading.Lock()
        self.poses = fan_poses(config.blindaid)
        self.order = scan_order(config.blindaid)
        # One laser-off/on pair a zone: the blind aid wants fresh ranges, not the last millimetre.
        fan = replace(config, sweep=replace(config.sweep, pairs_per_zone=1))
        # Every frame delivered is a sign that the rig still works: the blind aid's "nothing for too
        # long" counts from the latest one's exposure, not only from the last zone's result, so that
        # a slow zone (a loaded machine) is not taken for a stalled part. From the exposure, not
        # from its delivery: a frame exposed before a stall but delivered after it proves nothing.
        capture = Capture(parts.camera, parts.lasers, fan, on_frame=self._seen, clock=parts.clock)
        self.sweeper = sweeper_for(parts, config=fan, ranger=ranger, capture=capture)
        self.on_cue = on_cue
        self.on_zone = on_zone
        self._cue_frames: list[tuple[float, float]] = []  # (cue time, frame end time)
        sink, live = open_audio(config)
        self.clock = parts.clock
        self._t0_ns = self.clock.now_ns()
        self.player = CuePlayer(Synth.from_config(config.blindaid), sink, chunk_s=config.audio.chunk_ms / 1000,
                                lead_s=config.audio.lead_ms / 1000 if live else 0.0)
        self._stop = threading.Event()
        self._asked = threading.Event()  # the button was pressed: say where the nearest thing is
        self._button = parts.button  # opened with the parts (edge.parts), when wired
        if self._button is not None:
            self._button.when_pressed = self._asked.set
        self._period_ns = round(self.player.chunk_n / self.player.sample_rate / 2 * 1e9)
        self._ticker = self.clock.timer(self._tick, "blind-aid sound")
        self._ticker.arm(self._t0_ns + self._period_ns)

    @property
    def t0_ns(self) -> int:
        """The rig's time (ns) of stream time 0: the origin of `now()` and of the sound."""
        return self._t0_ns

    def now(self) -> float:
        return (self.clock.now_ns() - self._t0_ns) / 1e9

    def _tick(self) -> None:
        try:
            t = self.now()
            with self._lock:
                if self._stop.is_set():
                    return
                cue = self.aid.tick(t)  # readings age out; no results for too long: blind
                if cue is not None:
                    self._play_cue(cue, t, None)
                self.player.advance(t)
        except Exception as exc:  # a sound card gone must not take the ranging with it
            log.error("blind aid: sound stopped: %s", exc)
            return
        self._ticker.arm(self.clock.now_ns() + self._period_ns)

    def _seen(self, frame: Frame) -> None:
        with self._lock:
            self.aid.alive((frame.t_end_ns - self._t0_ns) / 1e9)

    def set_blinded(self, reason: str | None) -> None:
        """The rig cannot see (`reason`: lasers switched off, a laser that does not light), or, with
        None, can again: the blind cue sounds until this ends (and the zones see)."""
        t = self.now()
        with self._lock:
            cue = self.aid.set_blinded(reason, t)
            if cue is not None:
                self._play_cue(cue, t, None)

    def scan(self, should_stop: Callable[[], bool]) -> None:
        """One pass over the fan (there and back), a cue whenever the picture changes."""
        for i, k in enumerate(self.order):
            if should_stop():
                return
            following = self.order[(i + 1) % len(self.order)]  # the pass repeats
            self.sweeper.foresee(*self.poses[following])
            pan, tilt = self.poses[k]
            result = self.sweeper.zone(k, pan, tilt)
            t = self.now()
            frame_t = (self.sweeper.last_frame_end_ns - self._t0_ns) / 1e9
            with self._lock:
                cue = self.aid.update(result, t, seen_s=frame_t)
                if cue is not None:
                    self._play_cue(cue, t, frame_t)
            if self.on_zone is not None:
                self.on_zone(result, frozenset(self.sweeper.lit_when_off))
            if self._asked.is_set():
                self._asked.clear()
                log.info("blind aid: asked: %s", self.speak())

    def speak(self) -> str:
        """Say where the nearest obstacle is now (the button on the device asks for it)."""
        t = self.now()
        with self._lock:
            text = self.aid.speak(t)
        self._say(text, t)
        return text

    def _play_cue(self, cue: Cue, t: float, frame_t: float | None) -> None:
        """Play and publish `cue` (from the loop's thread with the frame that made it, or from the
        sound's clock with None). Called under the lock, so the player gets cues in their order."""
        self.player.set_cue(cue, t)
        log.debug("cue at %.3f s: %s", t, cue.to_json())
        if cue.sound == BLIND:
            log.warning("blind aid: cannot see: %s", cue.reason)
        if frame_t is not None:
            self._cue_frames.append((t, frame_t))
        self.on_cue(cue)
        if cue.speech:
            self._say(cue.speech, t)

    def _say(self, text: str, t: float) -> None:
        def work() -> None:
            frames = speak_to_frames(text, self.player.sample_rate)
            # Simulated time does not pass while the computer synthesises: the words follow at once.
            self.player.say(frames, t if self.clock.simulated else self.now())

        threading.Thread(target=work, name="blind-aid speech", daemon=True).start()

    def sound_latencies_s(self) -> list[float]:
        """For each cue: from the end of the frame that produced it to its sound's first sample
        in the stream (add the sink's buffer for a live sound card)."""
        frame_of = dict(self._cue_frames)
        return [start - frame_of[t] for t, start in self.player.starts if t in frame_of]

    def close(self) -> None:
        if self._button is not None:
            self._button.when_pressed = None  # the button stays open with the parts; we stop listening
        with self._lock:
            self._stop.set()
        self._ticker.close()
        self.player.close(self.now())
