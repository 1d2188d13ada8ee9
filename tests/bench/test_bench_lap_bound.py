"""bench/bench_lap_bound.py on a short drive: the world goes back exactly to a snapshot, the
search driver laps and its replay from reset gives the same laps, and the last line."""

from __future__ import annotations

import math

import pytest

from racing.car import CarSim
from tests.bench.loader import load_bench


@pytest.fixture(scope="module")
def bench():
    with load_bench("bench_lap_bound") as module:
        yield module


def test_a_snapshot_brings_the_car_back_to_the_same_poses() -> None:
    sim = CarSim()
    try:
        sim.place(0.0, 0.0, 0.0)
        for _ in range(5):
            sim.step(10.0, 2.0)
        state = sim.snapshot()
        ahead = [sim.step(20.0, 3.0) for _ in range(10)]
        sim.restore(state)
        again = [sim.step(20.0, 3.0) for _ in range(10)]
        sim.forget(state)
    finally:
        sim.close()
    assert again == ahead


@pytest.mark.slow
def test_the_search_laps_and_its_replay_agrees(bench) -> None:
    from training.rl.presets import RACING

    actions = RACING.actions()
    drive = bench.search_drive("reinvent_base", actions, 1, depth=1, horizon=8, lookahead=1.3)
    assert drive.status == "lap_complete" and len(drive.laps) == 1
    assert drive.replayed is True  # the env's own tracker, from reset, times the same lap
    baseline = bench.policy_drive("reinvent_base", actions, 1, "pursuit",
                                  bench.one_frame_driver(1.3))  # fmt: skip
    assert baseline.status == "lap_complete"
    # Knowing the car's speed and looking ahead beats one frame's worth of knowledge.
    assert drive.laps[0] < baseline.laps[0]


def test_the_last_line_takes_the_best_lap_of_finished_drives(bench) -> None:
    drive = bench.Drive
    search = [drive("a", (), (5.2, 4.9, 5.0), "lap_complete", 1.0, True),
              drive("b", (), (5.1, 4.8), "off_track", 1.0, True),  # unfinished: left out
              drive("c", (), (5.0, 5.1, 5.3), "lap_complete", 1.0, True)]  # fmt: skip
    baseline = [drive("p", (), (5.9, 5.6, 5.8), "lap_complete", 0.1)]
    figures = bench.summary(search, baseline, laps=3)
    assert figures["bound_lap_s"] == 4.9 and figures["bound_start_lap_s"] == 5.0
    assert figures["bound_median_lap_s"] == pytest.approx(5.05) and figures["pursuit_lap_s"] == 5.6
    assert figures["ratio"] == pytest.approx(4.9 / 5.6)
    assert math.isnan(bench.summary([], [], laps=3)["ratio"])
