"""The race-timing model (racing/timing.py) against races computed by hand.

The hand-made track is 30 m long, one lap: timing lines at 0, 10, 20 and 30 m of each car's
race. A crossing is interpolated between the two steps around it.
"""

from __future__ import annotations

import json

import pytest

from racing.timing import (
    CRASH,
    FINISHED,
    OFF_TRACK,
    RETIRED,
    CarReading,
    Incident,
    RaceTiming,
    public_reason,
)


def car(index: int, distance: float, **kw) -> CarReading:
    return CarReading(index=index, name=kw.pop("name", f"R{index}"), distance_m=distance,
                      grid_slot=kw.pop("grid_slot", index), **kw)  # fmt: skip


def test_sectors_gaps_and_the_winner_from_the_timing_lines() -> None:
    timing = RaceTiming(30.0, laps=1)
    timing.record(1.0, [car(0, 5.0), car(1, 4.0)])
    t = timing.record(2.0, [car(0, 15.0), car(1, 8.0)])
    # A crossed line 1 (10 m) at 1 + 5/10 = 1.5 s; B has crossed nothing yet: no gap.
    assert [c.index for c in t.cars] == [0, 1]
    assert t.cars[0].sectors == [pytest.approx(1.5)]
    assert t.cars[1].gap_s is None and t.cars[1].sectors == []
    t = timing.record(3.0, [car(0, 25.0), car(1, 12.0)])
    # A: line 2 (20 m) at 2 + 5/10 = 2.5 s. B: line 1 at 2 + 2/4 = 2.5 s: 1.0 s behind A there.
    a, b = t.cars
    assert a.sectors == [pytest.approx(1.5), pytest.approx(1.0)]
    assert b.gap_s == pytest.approx(1.0) and b.interval_s == pytest.approx(1.0)
    assert a.gap_s is None and a.position == 1 and b.position == 2
    t = timing.record(3.5, [car(0, 30.0, state=FINISHED, laps_done=1, lap_times_s=(3.4,),
                                finish_time_s=3.4), car(1, 14.0)], over=False)  # fmt: skip
    a = t.cars[0]
    assert a.sectors == [pytest.approx(1.5), pytest.approx(1.0), pytest.approx(0.9)]
    assert a.status == FINISHED and a.finish_s == 3.4 and a.last_lap_s == 3.4
    assert a.sector_colours == ["purple", "purple", "purple"]
    assert t.winner is None  # not over yet
    done = car(0, 30.0, state=FINISHED, laps_done=1, lap_times_s=(3.4,), finish_time_s=3.4)
    t = timing.record(20.0, [done, car(1, 14.0, state="time_up")], over=True)
    assert t.winner is not None and t.winner.name == "R0"
    data = t.to_dict()
    assert json.loads(json.dumps(data)) == data
    assert data["winner"] == {"index": 0, "name": "R0", "time_s": 3.4}
    assert data["cars"][0]["sectors"] == [1.5, 1.0, 0.9]


def test_penalties_are_counted_and_an_incident_is_reported_once() -> None:
    timing = RaceTiming(30.0, laps=2)
    timing.record(1.0, [car(0, 3.0), car(1, 2.0)])
    t = timing.record(2.0, [car(0, 6.0), car(1, 2.0, penalties=1, penalty_s=5.0, crashes=1)])
    assert t.incidents == [Incident(1, CRASH)]
    b = t.car(1)
    assert b.penalties == 1 and b.penalty_s == 5.0
    assert b.to_dict()["penalty_s"] == 5.0
    t = timing.record(3.0, [car(0, 9.0), car(1, 2.0, penalties=1, penalty_s=5.0, crashes=1)])
    assert t.incidents == []  # the same crash is not news twice
    t = timing.record(4.0, [car(0, 9.0, penalties=1, penalty_s=2.0, off_tracks=1),
                            car(1, 2.0, penalties=1, penalty_s=5.0, crashes=1)])  # fmt: skip
    assert t.incidents == [Incident(0, OFF_TRACK)]
    # A sat out its penalty: its second sector (10->20 m) takes the 2 s it stood still.
    t = timing.record(5.0, [car(0, 10.0, penalties=1, penalty_s=2.0, off_tracks=1), car(1, 3.0)])
    t = timing.record(7.0, [car(0, 20.0, penalties=1, penalty_s=2.0, off_tracks=1), car(1, 5.0)])
    assert t.car(0).sectors == [pytest.approx(5.0), pytest.approx(2.0)]
    assert t.car(0).sector_colours == ["purple", "purple"]


def test_a_retired_car_drops_behind_the_racers_with_a_public_reason_and_no_gap() -> None:
    timing = RaceTiming(30.0, laps=1)
    timing.record(1.0, [car(0, 5.0), car(1, 12.0), car(2, 3.0)])
    t = timing.record(2.0, [
        car(0, 11.0), car(1, 14.0, state=RETIRED,
                          reason="its policy failed: RuntimeError: /srv/secret/model.zip"),
        car(2, 10.5)])  # fmt: skip
    assert [c.index for c in t.cars] == [0, 2, 1]  # out, though it went furthest
    out = t.car(1)
    assert out.status == RETIRED and out.reason == "car failure"
    assert out.gap_s is None and out.interval_s is None
    assert "secret" not in json.dumps(t.to_dict())
    # Car 0 crossed 10 m at 1 + 5/6 s, car 2 at 1 + 7/7.5 s.
    assert t.car(2).gap_s == pytest.approx((1 + 7 / 7.5) - (1 + 5 / 6))
    assert public_reason("off track, no resets left") == "off track, no resets left"
    assert public_reason("withdrawn by its racer") == "withdrawn"
    assert public_reason("anything else") == "retired"


def test_ties_go_to_the_first_across_the_last_line_then_to_the_grid() -> None:
    timing = RaceTiming(30.0, laps=1)
    timing.record(1.0, [car(0, 8.0), car(1, 12.0)])
    t = timing.record(2.0, [car(0, 12.0), car(1, 12.0)])  # car 1 stopped at 12 m
    # Same distance: car 1 crossed 10 m first (at 1 - ... clamped into step 1), car 0 at 1.5 s.
    assert [c.index for c in t.cars] == [1, 0]
    assert t.cars[1].gap_s == pytest.approx(1.5 - 1.0 * (10 / 12))
    same = RaceTiming(30.0, laps=1)
    t = same.record(1.0, [car(0, 4.0, grid_slot=1), car(1, 4.0, grid_slot=0)])
    assert [c.index for c in t.cars] == [1, 0]  # nothing else between them: the grid


def test_the_speed_multiplier_travels_with_the_timing() -> None:
    t = RaceTiming(30.0, laps=1).record(1.0, [car(0, 1.0, speed_multiplier=1.25), car(1, 0.5)])
    assert t.car(0).to_dict()["speed_multiplier"] == 1.25
    assert t.car(1).to_dict()["speed_multiplier"] == 1.0


def test_it_reads_a_real_race(oval_race) -> None:
    race = oval_race
    timing = RaceTiming(race.track.length, race.rules.laps)
    for _ in range(20):
        race.step([[0.0, 2.0]] * len(race.cars))
        t = timing.update(race)
    assert [c.index for c in t.cars] == [car.index for car in race.standings()]
    assert t.clock_s == pytest.approx(race.clock_s)
    assert all(c.speed_multiplier == getattr(race.cars[c.index], "speed_multiplier", 1.0)
               for c in t.cars)  # fmt: skip
    assert {c["name"] for c in t.to_dict()["cars"]} == {"Ada", "Bo"}


@pytest.fixture
def oval_race():
    from racing.headtohead import HeadToHeadRace, Racer
    from racing.rules import RaceRules
    from racing.tracks import TrackCatalog

    track = TrackCatalog([]).load("racecraft_oval").in_direction("native")
    space = {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.3, "high": 4.0}}
    race = HeadToHeadRace(track, [Racer(action_space=space, name="Ada"),
                                  Racer(action_space=space, name="Bo")],
                          rules=RaceRules(laps=1, time_limit_s=60.0))  # fmt: skip
    race.reset()
    yield race
    race.close()


def test_the_timing_carries_names_times_and_positions_only() -> None:
    """Spectators get the frames as they are (one payload for every viewer): a new field in
    the timing is a deliberate change of what a spectator sees, made here."""
    t = RaceTiming(30.0, laps=1).record(1.0, [car(0, 1.0), car(1, 0.5, state=RETIRED,
                                                           reason="its model failed")])  # fmt: skip
    data = t.to_dict()
    assert set(data) == {"clock_s", "laps", "lap", "over", "sectors", "winner", "cars"}
    assert set(data["cars"][0]) == {
        "index", "name", "colour", "position", "status", "reason", "lap", "laps_done", "gap_s",
        "interval_s", "last_lap_s", "best_lap_s", "sectors", "sector_colours", "penalties",
        "penalty_s", "finish_s", "speed_multiplier",
    }  # fmt: skip
    assert data["cars"][1]["reason"] == "car failure"


def test_a_car_passed_after_a_line_gets_its_gap_on_the_road_not_plus_zero() -> None:
    """Staggered grid: car 1 crosses line 1 (10 m) first, then car 0 passes it. Car 1's gap is
    the time since car 0 was where car 1 is now, not ``max(0, 1.0 - 1.333) = 0``."""
    timing = RaceTiming(30.0, laps=1)
    timing.record(1.0, [car(0, 8.0), car(1, 10.0, grid_slot=1)])
    t = timing.record(2.0, [car(0, 14.0), car(1, 12.0, grid_slot=1)])
    # car 0 crossed 10 m at 1 + 2/6 = 1.333 s, after car 1 (1.0 s), and leads now (14 > 12 m).
    # It was at 12 m at 1 + (12 - 8)/6 = 1.667 s: car 1 is 2.0 - 1.667 = 0.333 s behind.
    assert [c.index for c in t.cars] == [0, 1]
    assert t.cars[1].gap_s == pytest.approx(1.0 / 3.0)
    assert t.cars[1].interval_s == pytest.approx(1.0 / 3.0)
    assert t.cars[1].to_dict()["gap_s"] == 0.333


def test_the_results_rank_as_the_tower_does_on_a_tie(oval_race) -> None:
    """One rule decides positions: HeadToHeadRace.standings() (the results' order) is the
    timing's. Both cars 12 m in; car 1 (the worse grid slot) crossed 10 m first: it leads, on
    the tower and in the standings (distance then grid alone would put car 0 first)."""
    race = oval_race
    race.timing.record(1.0, [car(0, 8.0, grid_slot=0), car(1, 10.0, grid_slot=1)])
    t = race.timing.record(2.0, [car(0, 12.0, grid_slot=0), car(1, 12.0, grid_slot=1)])
    assert [c.index for c in t.cars] == [1, 0]
    assert [c.index for c in race.standings()] == [1, 0]


def test_the_race_keeps_one_timing_that_the_standings_read(oval_race) -> None:
    race = oval_race
    for _ in range(10):
        race.step([[0.0, 2.0]] * len(race.cars))
    latest = race.timing.latest
    assert latest is not None and latest.clock_s == pytest.approx(race.clock_s)
    assert [c.index for c in latest.cars] == [car.index for car in race.standings()]
    race.retire(0, "withdrawn")  # out between steps: the tower and the standings at once
    assert race.timing.latest.car(0).status == RETIRED
    assert race.standings()[-1].index == 0
