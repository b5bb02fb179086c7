"""The blind aid on the simulated rig: the fan scan, cues, the sound, the "how far?" button."""

from __future__ import annotations

import logging
import time
import wave
from pathlib import Path

from edge.config import load_config
from edge.modes.blindaid.runner import BlindAidRunner
from edge.parts import open_parts


def test_fan_scan_cues_the_nearest_wall_and_the_button_speaks(tmp_path: Path, caplog) -> None:
    wav = tmp_path / "fan.wav"
    config = load_config(None, [f'audio.out="{wav}"', "blindaid.speak_button_pin=5", "blindaid.speak_new=false",
                                 "blindaid.blind_after_s=0.9"])  # late frames on a loaded machine: rarer "cannot see"
    cues = []
    with open_parts(config) as parts:
        runner = BlindAidRunner(config, parts, on_cue=cues.append)
        try:
            runner.scan(lambda: False)
            button = parts.lasers.factory.pin(5)
            button.drive_low()  # pressed (to ground, against the pull-up)
            time.sleep(0.1)
            button.drive_high()
            with caplog.at_level(logging.INFO):
                runner.scan(lambda: False)
        finally:
            runner.close()
    # The office ahead of the device: the east wall 2.4 m away, nearer (2.0 m) to the right. (A
    # loaded machine may keep the rig from framing for blind_after_s: "cannot see" then, honestly.)
    # After a "cannot see" the first zones seen may all be clear (the fan's far left): silence.
    seen = [c for c in cues if c.sound == "beep"]
    assert seen and all(c.sound in ("beep", "blind", "silence") for c in cues)
    nearest = min(seen, key=lambda c: c.range_m)
    assert 1.8 < nearest.range_m < 2.2 and nearest.bearing_deg < 0 and nearest.pan > 0  # right
    asked = [r.getMessage() for r in caplog.records if "asked" in r.getMessage()]
    assert asked and ("metres" in asked[0] or asked[0].endswith("cannot see"))  # blind then: says so
    with wave.open(str(wav)) as w:
        assert w.getnchannels() == 2 and w.getnframes() > 0.5 * w.getframerate()
