"""A race's results rank as its live timing tower does (racing/timing.py decides positions)."""

from __future__ import annotations

from racing.headtohead import Racer
from racing.tracks import TrackCatalog
from training.rl.race import RaceEntry, RaceSettings, run_race


def constant(name: str, speed: float) -> Racer:
    return Racer(action_space=[{"steering_angle": 0, "speed": speed}] * 2, name=name)


def test_the_results_take_their_positions_from_the_timing() -> None:
    oval = TrackCatalog([]).load("racecraft_oval").in_direction("native")
    entries = [
        RaceEntry(key=i, name=name, racer=constant(name, speed), policy=lambda obs: 0)
        for i, (name, speed) in enumerate([("one", 1.0), ("two", 1.0), ("three", 0.6)], start=1)
    ]
    headers: list[dict] = []
    steps = iter(range(40))
    report = run_race(entries, oval, RaceSettings(laps=1, time_limit_s=12.0, record_video=False),
                      on_frame=lambda rgb, header: headers.append(header),
                      should_stop=lambda: next(steps, None) is None)  # fmt: skip
    tower = headers[-1]["timing"]["cars"]
    assert [c["name"] for c in tower] == [car.name for car in report.cars]
    assert [c["position"] for c in tower] == [car.position for car in report.cars] == [1, 2, 3]
