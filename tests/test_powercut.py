"""A power cut (SIGKILL) while a calibration or a recording is being written: afterwards each is
either the old one, the new one, or absent — never half-written (the outgoing queue has its own
test in test_outbox.py)."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from edge.calibration.file import Calibration, read_calibration, write_calibration
from edge.fsutil import atomic_write_bytes
from edge.recording import RecordingWriter, read_recording
from edge.rig import default_rig

CHILD = textwrap.dedent('''
    import sys, numpy as np
    from dataclasses import replace
    from edge.calibration.file import Calibration, write_calibration
    from edge.recording import RecordingWriter
    from edge.rig import default_rig
    rig = default_rig()
    out = sys.argv[1]
    k = 0
    while True:
        k += 1
        cal = Calibration(rig.lasers, replace(rig.camera, fx=500.0 + k), (0.5, 1.0, 2.0), {}, f"run {k}")
        write_calibration(out + "/cal.json", cal)
        with RecordingWriter(out + "/rec", rig, device=f"run {k}") as w:
            for z in range(3):
                img = np.full((rig.camera.height, rig.camera.width, 3), (k + z) % 255, np.uint8)
                w.add_zone(z, 10.0 * z, 0.0, [(img, [], {}), (img, ["center"], {})])
        print(k, flush=True)
''')


@pytest.mark.slow
def test_killed_writers_leave_whole_files_or_none(tmp_path: Path) -> None:
    rng = random.Random(5)
    last = 0
    for _ in range(8):
        proc = subprocess.Popen([sys.executable, "-c", CHILD, str(tmp_path)], stdout=subprocess.PIPE, text=True)
        first = proc.stdout.readline()  # its first files are whole (a loaded machine starts it slowly)...
        time.sleep(rng.random() * 1.0)  # ...then a kill anywhere in what it writes next
        os.kill(proc.pid, signal.SIGKILL)
        out, _ = proc.communicate()
        done = [int(x) for x in (first + out).split()]
        last = max([last, *done])
        cal = tmp_path / "cal.json"
        if cal.exists():
            read_calibration(cal)  # whole: it parses, every key checked
        rec = tmp_path / "rec"
        if rec.exists():
            recording = read_recording(rec)
            assert [z.index for z in recording.zones] == [0, 1, 2]
            assert len({recording.device}) == 1
    assert last >= 1  # the writers did finish files between the kills
    # Nothing half-written is lying where a reader looks; leftovers are hidden temporaries.
    names = {p.name for p in tmp_path.iterdir()}
    assert {"cal.json", "rec"} <= names
    # (a writer killed mid-swap leaves the previous recording as rec.old-<pid>: kept, never read)
    assert all(n in ("cal.json", "rec") or n.startswith(".") or ".partial-" in n or ".old-" in n for n in names), names
    # The next writer of the recording cleans up what the killed ones left (their pids are gone).
    rig = default_rig()
    img = np.zeros((rig.camera.height, rig.camera.width, 3), np.uint8)
    with RecordingWriter(tmp_path / "rec", rig, device="after the kills") as w:
        for z in range(3):
            w.add_zone(z, 10.0 * z, 0.0, [(img, [], {}), (img, ["center"], {})])
    assert read_recording(tmp_path / "rec").device == "after the kills"
    # ...and the next writer of the calibration the temporaries of killed ones.
    write_calibration(tmp_path / "cal.json", Calibration.from_rig(rig))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cal.json", "rec"]


def test_the_next_atomic_write_removes_temporaries_of_dead_writers_only(tmp_path: Path) -> None:
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    dead = child.pid
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        left = {
            f".cal.json.{dead}.x1y2.tmp": False,  # a killed writer's: removed
            f".cal.json.{sleeper.pid}.x1y2.tmp": True,  # still being written: kept
            f".cal.json.{os.getpid()}.x1y2.tmp": True,  # maybe another thread of ours: kept
            f".other.json.{dead}.x1y2.tmp": True,  # another file's business
            f".cal.json.{dead}.x1y2": True,  # not a temporary's name
        }
        for name in left:
            (tmp_path / name).write_text("half")
        atomic_write_bytes(tmp_path / "cal.json", b"{}")
        assert (tmp_path / "cal.json").read_bytes() == b"{}"
        assert {n: (tmp_path / n).exists() for n in left} == left
    finally:
        sleeper.kill()
        sleeper.wait()
