"""The TV director (racing/director.py) on scripted races: a lone leader, a battle, a crash.

Each race is scripted as distances per car per step (15 steps a second) on a 30 m, 3-lap
track, through the real timing model (racing/timing.py)."""

from __future__ import annotations

from racing.director import BATTLE, INCIDENT, LEADER, WIDE, Director
from racing.timing import CarReading, RaceTiming

DT = 1.0 / 15.0


def film(speeds, seconds: float, crash_at: dict[int, float] | None = None):
    """The shots of a race where car ``i`` drives at ``speeds[i]`` m/s (from its own grid
    spot); ``crash_at``: car -> race clock of a crash (it stands still 5 s after)."""
    timing, director = RaceTiming(30.0, laps=3), Director()
    crash_at = crash_at or {}
    shots, distance = [], [0.0] * len(speeds)
    for step in range(1, int(seconds * 15) + 1):
        clock = step * DT
        readings = []
        for i, v in enumerate(speeds):
            crashed = i in crash_at and clock >= crash_at[i]
            if not (crashed and clock < crash_at[i] + 5.0):
                distance[i] += v * DT
            readings.append(CarReading(index=i, name=f"R{i}", distance_m=distance[i],
                                       grid_slot=i, crashes=int(crashed),
                                       penalties=int(crashed)))  # fmt: skip
        shots.append((clock, director.decide(timing.record(clock, readings))))
    return shots, director


def runs(shots):
    """The shots as (car, kind, start clock, length) runs."""
    out = []
    for clock, shot in shots:
        if out and (out[-1][0], out[-1][1]) == (shot.car, shot.kind):
            out[-1][3] = clock - out[-1][2] + DT
        else:
            out.append([shot.car, shot.kind, clock, DT])
    return out


def test_a_lone_leader_is_followed_and_never_cut_away_from() -> None:
    shots, director = film([2.0, 1.0], seconds=20)  # car 1 falls ever further behind
    assert {(s.car, s.kind) for _, s in shots} == {(0, LEADER)}
    assert director.cuts == 1


def test_a_close_battle_is_cut_to_framing_the_chaser_and_held() -> None:
    # Car 1 is 0.5 s behind car 0 from the first timing line on; car 2 far back.
    shots, _ = film([2.0, 1.9, 1.0], seconds=20)
    seq = runs(shots)
    assert seq[0][:2] == [0, LEADER]
    assert [1, BATTLE] in [r[:2] for r in seq]
    first_battle = next(r for r in seq if r[1] == BATTLE)
    assert first_battle[2] >= 3.0 - 1e-9  # the opening shot was held its minimum
    for car, kind, _, length in seq[:-1]:  # every shot but the running one: >= 3 s
        assert length >= 3.0 - 1e-9, (car, kind, length)


def test_a_crash_is_cut_to_then_the_camera_goes_back_to_the_race() -> None:
    shots, director = film([2.0, 1.0], seconds=16, crash_at={1: 5.0})
    seq = runs(shots)
    assert [r[:2] for r in seq] == [[0, LEADER], [1, INCIDENT], [0, LEADER]]
    incident = seq[1]
    assert 5.0 <= incident[2] <= 5.0 + 2 * DT  # cut at once: the leader shot was 5 s old
    assert incident[3] >= 3.0 - 1e-9
    assert shots[int(6 * 15)][1].camera == WIDE


def test_an_incident_during_a_young_shot_waits_for_the_minimum_length() -> None:
    shots, _ = film([2.0, 1.0], seconds=10, crash_at={1: 1.0})
    seq = runs(shots)
    assert seq[0][:2] == [0, LEADER] and seq[0][3] >= 3.0 - 1e-9
    assert seq[1][:2] == [1, INCIDENT]


def test_the_same_race_gives_the_same_shots() -> None:
    a, _ = film([2.0, 1.95, 1.5, 1.2], seconds=12, crash_at={2: 4.0})
    b, _ = film([2.0, 1.95, 1.5, 1.2], seconds=12, crash_at={2: 4.0})
    assert a == b
