"""The rig's clock: simulated time moves only by waiting, fires timers in order at their times; the
real clock's timers are threads; and a simulated rig gives the same results on any machine."""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import pytest

from edge.clock import REAL, SIM_START_NS, SimClock


def test_simulated_time_stands_still_while_the_computer_works_and_jumps_when_the_rig_waits():
    clock = SimClock()
    t0 = clock.now_ns()
    assert t0 == SIM_START_NS
    time.sleep(0.02)  # the computer's time passes; the rig's does not
    assert clock.now_ns() == t0
    clock.sleep(1.5)
    assert clock.now_ns() == t0 + 1_500_000_000
    clock.sleep_until_ns(t0)  # never backwards
    assert clock.now_ns() == t0 + 1_500_000_000


@pytest.mark.parametrize("pace", [1.0, 4.0])
def test_a_paced_clock_never_runs_ahead_of_pace_times_real_time(pace):
    clock = SimClock(paced=True, pace=pace)
    began = time.monotonic()
    for _ in range(4):
        clock.sleep(0.1)
    # A lower bound only: a busy machine may hold it back, never push it ahead.
    assert time.monotonic() - began >= 0.4 / pace - 0.005
    assert clock.now_ns() == SIM_START_NS + 400_000_000


def test_a_pace_must_be_positive():
    with pytest.raises(ValueError, match="pace"):
        SimClock(paced=True, pace=0.0)


def test_simulated_timers_fire_in_time_order_at_their_own_times():
    clock = SimClock()
    t0 = clock.now_ns()
    fired: list[tuple[str, int]] = []
    timers = {name: clock.timer(lambda name=name: fired.append((name, clock.now_ns())), name)
              for name in ("a", "b", "c")}
    timers["b"].arm(t0 + 300)
    timers["a"].arm(t0 + 100)
    timers["c"].arm(t0 + 2_000)
    clock.sleep_until_ns(t0 + 1_000)
    assert fired == [("a", t0 + 100), ("b", t0 + 300)]
    assert clock.now_ns() == t0 + 1_000
    timers["c"].disarm()
    clock.sleep(10.0)
    assert [name for name, _ in fired] == ["a", "b"]


def test_a_simulated_timer_rearmed_from_its_function_ticks_on_its_period():
    clock = SimClock()
    t0 = clock.now_ns()
    ticks: list[int] = []

    def tick() -> None:
        ticks.append(clock.now_ns() - t0)
        if len(ticks) < 5:
            timer.arm(clock.now_ns() + 10_000_000)

    timer = clock.timer(tick, "tick")
    timer.arm(t0 + 10_000_000)
    clock.sleep(1.0)
    assert ticks == [10_000_000 * k for k in range(1, 6)]


def test_a_rearming_replaces_the_earlier_one_and_a_closed_timer_never_fires():
    clock = SimClock()
    t0 = clock.now_ns()
    fired: list[int] = []
    timer = clock.timer(lambda: fired.append(clock.now_ns()), "t")
    timer.arm(t0 + 100)
    timer.arm(t0 + 500)  # the watchdog moves its deadline when a laser is switched
    clock.sleep_until_ns(t0 + 1_000)
    assert fired == [t0 + 500]
    timer.arm(t0 + 2_000)
    timer.close()
    timer.arm(t0 + 3_000)
    clock.sleep(10.0)
    assert fired == [t0 + 500]


def test_a_timer_that_fails_does_not_stop_the_clock(caplog):
    clock = SimClock()
    after: list[int] = []
    clock.timer(lambda: 1 / 0, "broken").arm(clock.now_ns() + 10)
    clock.timer(lambda: after.append(clock.now_ns()), "fine").arm(clock.now_ns() + 20)
    clock.sleep(1.0)
    assert len(after) == 1
    assert "broken: timer failed" in caplog.text


def test_idle_waits_in_real_time_for_a_person_or_a_broker_and_counts_it():
    clock = SimClock()
    t0 = clock.now_ns()
    event = threading.Event()
    began = time.monotonic()
    assert not clock.idle(event, 0.05)
    assert time.monotonic() - began >= 0.04  # it did wait: a paused device is not in a hurry
    assert 0 < clock.now_ns() - t0 <= 50_000_000
    event.set()
    assert clock.idle(event, 5.0)


def test_the_real_clock_is_monotonic_time_and_its_timers_are_threads():
    t0 = REAL.now_ns()
    assert abs(t0 - time.monotonic_ns()) < 50_000_000
    fired = threading.Event()
    where: list[str] = []

    def fn() -> None:
        where.append(threading.current_thread().name)
        fired.set()

    timer = REAL.timer(fn, "real-timer")
    timer.arm(REAL.now_ns() + 20_000_000)
    assert fired.wait(5.0)
    assert where == ["real-timer"]
    fired.clear()
    timer.arm(REAL.now_ns() + 50_000_000)
    timer.close()
    assert not fired.wait(0.2)


@pytest.mark.slow
def test_a_simulated_sweep_is_the_same_on_any_machine_under_any_load():
    # Two sweeps of the office, one with the other core kept busy: the simulated rig's timing (and
    # so every frame, range and duration) is a function of the configuration and seed alone.
    from edge.config import load_config
    from edge.sweep import run_configured_sweep

    config = load_config(None, ["sim.scene=kitchen", "sweep.zones=4", "sweep.pan_start_deg=-60.0",
                                "sweep.pan_step_deg=15.0"])
    quiet = run_configured_sweep(config).report
    # Two busy loops in processes of their own, as `yes > /dev/null` on both cores.
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        loaded = run_configured_sweep(config).report
    finally:
        for b in burners:
            b.kill()
            b.wait()
    assert [r.to_json() for r in loaded.results] == [r.to_json() for r in quiet.results]
    assert loaded.duration_s == quiet.duration_s
    assert quiet.duration_s <= 1.05 * quiet.limit_s
