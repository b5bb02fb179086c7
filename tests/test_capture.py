"""Synchronised capture in the simulator: the naive way (switch, take the next frame) gives
half-lit spots; synchronised capture never does, wherever the switches fall in the frame clock.

The simulated camera runs on the rig's simulated clock with a rolling shutter and reads the laser
pins' history, so these tests exercise the real timing logic — lasers switched through gpiozero
(mock pins), frames chosen by timestamp — with switches exactly where the test puts them, on any
machine and under any load (on the real clock a busy machine's late wake-ups moved them).
"""

from __future__ import annotations

import numpy as np
import pytest

from edge.capture import Capture, Shot
from edge.clock import SimClock
from edge.config import load_config
from edge.parts import open_lasers
from edge.sim.camera import SimCamera
from edge.sim.light import LaserLight
from edge.sim.record import flat_target_scene, true_rig
from edge.sim.render import Renderer

SWITCHES = 10
RADIUS = 6  # px: the spot-sum window's half-size (spots are ~2 px wide at 1.5 m)


# The frames: rendered at 640 × 480, or as the Pi camera's ISP hands them over from its 1640 × 1232
# sensor (whose rows the rolling shutter reads out, each frame row from two or three of them).
FRAMES = {"640x480": [], "isp": ["sim.sensor.isp=true", 'sim.sensor.bayer="ea"']}


class Rig:
    """The simulated lasers and camera in front of a flat wall at 1.5 m, with noise-free
    references: the spots fully lit for a whole exposure, and the room alone."""

    def __init__(self, frames: list[str]) -> None:
        # No flicker and dim room light: the spots' sums then vary by ~1 % from frame to frame.
        self.config = load_config(None, ["sim.ambient.flicker=0.0", "sim.ambient.white_e_per_ms=60.0", *frames])
        self.clock = SimClock()
        self.lasers = open_lasers(self.config, clock=self.clock)
        rig = true_rig(self.config)
        self.renderer = Renderer(flat_target_scene(1.5), rig, self.config.sim, self.config.camera)
        self.settle_ns = int(self.config.lasers.settle_ms * 1e6)
        wiring = LaserLight(self.config.rig.wiring(), self.lasers.factory, self.settle_ns)
        self.camera = SimCamera(self.renderer, wiring, self.config.camera, clock=self.clock)
        self.capture = Capture(self.camera, self.lasers, self.config, clock=self.clock)
        self.names = self.lasers.names
        self.pixels = {n: s.pixel for n, s in self.renderer.spots(0.0, 0.0).items()}
        assert all(s.visible for s in self.renderer.spots(0.0, 0.0).values())
        self.dark = self._red(self.renderer.render(0.0, 0.0, {}, 0.0, None, noise=False))
        full = self._red(self.renderer.render(0.0, 0.0, {n: 1.0 for n in self.names}, 0.0, None, noise=False))
        self.full = {n: self._sum(full, n) for n in self.names}

    @staticmethod
    def _red(image: np.ndarray) -> np.ndarray:
        return image[..., 2].astype(np.float64)

    def _sum(self, red: np.ndarray, name: str) -> float:
        u, v = (int(round(c)) for c in self.pixels[name])
        window = np.s_[v - RADIUS : v + RADIUS + 1, u - RADIUS : u + RADIUS + 1]
        return float((red[window] - self.dark[window]).sum())

    def brightness(self, shot: Shot) -> dict[str, float]:
        """Each spot's summed brightness as a fraction of a whole exposure's."""
        red = self._red(shot.frame.image)
        return {n: self._sum(red, n) / self.full[n] for n in self.names}

    def wait_for_phase(self, phase_ns: int, at_least_ns: int = 0) -> None:
        """Sleep until `phase_ns` into a frame of the camera's clock, at least `at_least_ns` on."""
        cam = self.camera
        earliest = self.clock.now_ns() + at_least_ns
        k = -((cam.frame_start_ns(0) - earliest) // cam.frame_ns)
        self.clock.sleep_until_ns(cam.frame_start_ns(k) + phase_ns)


@pytest.fixture(scope="module", params=list(FRAMES))
def rig(request):
    r = Rig(FRAMES[request.param])
    r.camera.start()
    yield r
    r.lasers.close()
    r.camera.stop()


def _phases(rng: np.random.Generator, period: int) -> list[int]:
    """Random times within the frame period, one in each tenth of it, in random order (so that
    every part of the frame is hit, whatever the seed)."""
    return [int((k + rng.random()) * period / SWITCHES) for k in rng.permutation(SWITCHES)]


def test_naive_capture_gives_half_lit_spots(rig):
    rng = np.random.default_rng(7)
    period = rig.camera.frame_ns
    taken, straddled, partial, wrong = 0, 0, 0, 0
    for phase in _phases(rng, period):
        rig.lasers.off()
        rig.wait_for_phase(phase, at_least_ns=3 * period // 2)  # the off state well settled
        shot = rig.capture.naive_take(rig.names)
        lo, hi = shot.frame.metadata["laser_fraction_range"]["center"]
        straddled += lo < 1.0 and hi > 0.0  # the laser switched during this frame's exposure
        b = rig.brightness(shot)["center"]
        partial += 0.1 < b < 0.9
        wrong += abs(b - 1.0) > 0.05
        taken += 1
    rig.lasers.off()
    assert straddled >= 0.8 * taken
    assert partial >= 1, "no half-lit spot: the rolling-shutter simulation is not doing its job"
    assert wrong >= taken // 2


def test_synchronised_capture_never_straddles_a_switch(rig):
    rng = np.random.default_rng(11)
    period = rig.camera.frame_ns
    dropped = rig.capture.dropped
    shots = []
    for i, phase in enumerate(_phases(rng, period)):
        rig.wait_for_phase(phase)
        shots.append(rig.capture.take(rig.names if i % 2 == 0 else ()))
    rig.lasers.off()
    for i, shot in enumerate(shots):
        frame, on = shot.frame, i % 2 == 0
        assert shot.lasers_on == (rig.names if on else ())
        # The whole exposure, every row, after the switch took effect ...
        assert frame.t_start_ns >= shot.laser_switch_ns + rig.settle_ns
        # ... and before the next switch.
        if i + 1 < len(shots):
            assert shots[i + 1].laser_switch_ns >= frame.t_end_ns
        truth = frame.metadata["laser_fraction_range"]
        assert all(truth[n] == ((1.0, 1.0) if on else (0.0, 0.0)) for n in rig.names), truth
        for name, b in rig.brightness(shot).items():
            assert (abs(b - 1.0) < 0.05) if on else (abs(b) < 0.05), (i, name, b)
    assert rig.capture.dropped > dropped  # frames that straddled the switches were skipped


def test_zone_takes_off_on_pairs_and_leaves_the_lasers_off(rig):
    nudges: list[tuple[int, int]] = []

    def nudge(i: int) -> None:
        assert rig.lasers.lit == frozenset()  # no beam while the unit moves
        rig.clock.sleep(0.03)
        nudges.append((i, rig.clock.now_ns()))

    shots = rig.capture.zone(3, nudge)
    assert [s.lasers_on for s in shots] == [(), rig.names] * 3
    assert [i for i, _ in nudges] == [1, 2]
    assert shots[2].frame.t_start_ns >= nudges[0][1] and shots[4].frame.t_start_ns >= nudges[1][1]
    seqs = [s.frame.sequence for s in shots]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    assert rig.lasers.lit == frozenset()
    for shot in shots:
        b = rig.brightness(shot)["center"]
        assert abs(b - (1.0 if shot.lasers_on else 0.0)) < 0.05


def test_zone_leaves_the_lasers_off_when_it_fails(rig):
    def nudge(i: int) -> None:
        raise RuntimeError("pan-tilt unit stalled")

    rig.lasers.set(rig.names)
    with pytest.raises(RuntimeError, match="stalled"):
        rig.capture.zone(2, nudge)
    assert rig.lasers.lit == frozenset()
    assert all(rig.lasers.factory.pin(p).state is False for p in (17, 27, 22))
