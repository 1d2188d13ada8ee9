"""Head-to-head races (racing/headtohead.py): several policy-driven cars on one track."""

from __future__ import annotations

import numpy as np
import pytest

from racing.broadcast import BroadcastView
from racing.controllers import PurePursuitDriver
from racing.headtohead import (
    GRID_SPACING_M,
    CarState,
    HeadToHeadRace,
    Racer,
    grid_length_m,
    grid_order,
)
from racing.objects import KIND_BOT, KIND_RACER
from racing.race import RaceConfig, RaceType
from racing.rules import RaceRules, Status
from racing.track import TrackError
from racing.tracks import TrackCatalog

CONTINUOUS = {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.3, "high": 4.0}}
RULES = RaceRules(laps=1, resets=10_000, off_track_penalty_s=2.0, crash_penalty_s=5.0,
                  time_limit_s=60.0)  # fmt: skip


def constant(steering: float, speed: float) -> list[dict]:
    """A discrete action space whose every choice is the same action: a car that always
    drives it, whatever its network says."""
    return [{"steering_angle": steering, "speed": speed}] * 2


@pytest.fixture(scope="module")
def oval():
    return TrackCatalog([]).load("racecraft_oval").in_direction("native")


def drive(race: HeadToHeadRace, drivers, max_steps: int = 2000) -> list[list]:
    """Race the scripted ``drivers`` (one per car) to the end; every step's outcomes."""
    observations = race.reset()
    history = []
    while not race.over and race.steps < max_steps:
        actions = [
            list(d.act(car.pose)) if obs is not None else None
            for d, car, obs in zip(drivers, race.cars, observations, strict=True)
        ]
        history.append(race.step(actions))
        observations = race.observations()
    return history


def test_two_scripted_cars_race_a_lap_and_the_faster_one_wins(oval):
    race = HeadToHeadRace(oval, [Racer(action_space=CONTINUOUS, name="slow"),
                                 Racer(action_space=CONTINUOUS, name="fast")],
                          rules=RULES)  # fmt: skip
    drive(
        race,
        [
            PurePursuitDriver(oval, max_speed=1.2),
            PurePursuitDriver(oval, max_speed=2.4, offset=-0.25),
        ],
    )
    standings = race.standings()
    assert all(car.state is CarState.FINISHED for car in race.cars)
    assert [car.racer.name for car in standings] == ["fast", "slow"]
    fast, slow = standings
    assert fast.finish_time_s < slow.finish_time_s
    assert race.over and race.clock_s == pytest.approx(race.steps / 15.0)
    # Each car's lap counts from its own grid spot: the same distance for everyone.
    assert [len(car.tracker.laps) for car in race.cars] == [1, 1]
    assert fast.lap_records()[0].status is Status.LAP_COMPLETE
    race.close()


def test_the_grid_is_staggered_behind_the_start_line_in_alternating_lanes(oval):
    racers = [Racer(action_space=CONTINUOUS) for _ in range(4)]
    race = HeadToHeadRace(oval, racers, rules=RULES, grid=[2, 0, 3, 1])
    race.reset()
    by_slot = sorted(race.cars, key=lambda car: car.grid_slot)
    assert [car.index for car in by_slot] == [2, 0, 3, 1]
    for slot, car in enumerate(by_slot):
        behind = (oval.length - car.s) % oval.length
        assert behind == pytest.approx(slot * GRID_SPACING_M, abs=0.02)
        loc = oval.locate(*car.point)
        assert loc.distance > 0.1  # in a lane, not on the centre line
    sides = [oval.locate(*car.point).left for car in by_slot]
    assert sides[0] == sides[2] != sides[1] == sides[3]
    race.close()


def test_grid_order_gives_everyone_the_pole_once_over_as_many_rounds():
    rounds = [grid_order(3, r) for r in range(3)]
    assert rounds == [[0, 1, 2], [1, 2, 0], [2, 0, 1]]
    assert {r[0] for r in rounds} == {0, 1, 2}
    assert grid_order(2, 5) == [1, 0]
    assert grid_order(1, 3) == [0]
    with pytest.raises(ValueError, match="1 to 4 cars"):
        grid_order(5, 0)


def test_running_into_another_racer_from_behind_is_a_crash_for_the_car_behind_only(oval):
    # The pole car turns across into the outer lane; the second car comes fast behind it.
    race = HeadToHeadRace(oval, [Racer(action_space=constant(-30, 0.5), name="turner"),
                                 Racer(action_space=constant(5, 1.5), name="rammer")],
                          rules=RULES)  # fmt: skip
    race.reset()
    crash = None
    while crash is None and race.steps < 60:
        outcomes = race.step([0, 0])
        if outcomes[1] is not None and outcomes[1].status is Status.CRASHED:
            crash = outcomes
    assert crash is not None, "the cars never touched"
    turner, rammer = race.cars
    assert rammer.tracker.current_lap.crashes == 1 and turner.tracker.current_lap.crashes == 0
    assert crash[1].reset and crash[1].penalty_s == 5.0
    assert crash[0] is None or crash[0].status is not Status.CRASHED
    # The crashed car sits out its 5 s where it was while the other drives on.
    parked, clock = rammer.pose, race.clock_s
    turner_before = turner.tracker.steps
    for _ in range(30):
        outcomes = race.step([0, 0])
        assert outcomes[1] is None
    assert (rammer.pose.x, rammer.pose.y) == (parked.x, parked.y)
    assert turner.tracker.steps > turner_before
    assert rammer.tracker.sim_time == pytest.approx(clock + 5.0)
    race.close()


def test_each_racer_sees_the_others_in_its_camera_and_lidar(oval):
    # Grid: slot 0 on the inner lane, slot 1 beside and behind it, slot 2 right behind slot 0.
    racers = [Racer(action_space=CONTINUOUS), Racer(action_space=CONTINUOUS),
              Racer(("FRONT_FACING_CAMERA", "LIDAR"), action_space=CONTINUOUS)]  # fmt: skip
    race = HeadToHeadRace(oval, racers, rules=RULES)
    seen = race.reset()[2]
    assert set(seen) == {"FRONT_FACING_CAMERA", "LIDAR"}
    race.retire(0, "withdrawn")  # the car ahead in the same lane leaves: out of the camera
    no_leader = race.observations()[2]
    assert not np.array_equal(seen["FRONT_FACING_CAMERA"], no_leader["FRONT_FACING_CAMERA"])
    race.retire(1, "withdrawn")  # the car ahead to the side leaves: out of the LIDAR
    alone = race.observations()[2]
    assert seen["LIDAR"].min() < 1.0 and alone["LIDAR"].min() == 1.0
    race.close()


def test_a_retired_car_leaves_the_track_and_the_race_goes_on(oval):
    racers = [Racer(action_space=CONTINUOUS, name="a"), Racer(action_space=CONTINUOUS, name="b")]
    race = HeadToHeadRace(oval, racers, rules=RULES)
    race.reset()
    race.retire(0, "its racer withdrew")
    assert [o.kind for o in race.objects()] == [KIND_RACER]
    drive(race, [PurePursuitDriver(oval), PurePursuitDriver(oval, max_speed=2.0)])
    a, b = race.cars
    assert a.state is CarState.OUT and a.reason == "its racer withdrew"
    assert b.state is CarState.FINISHED
    assert race.standings() == [b, a]
    race.close()


def test_an_action_outside_the_space_retires_that_car_with_the_reason(oval):
    race = HeadToHeadRace(oval, [Racer(action_space=constant(0, 1.0)),
                                 Racer(action_space=constant(0, 1.0))], rules=RULES)  # fmt: skip
    race.reset()
    outcomes = race.step([7, 0])
    assert outcomes[0] is None and outcomes[1] is not None
    assert race.cars[0].state is CarState.OUT
    assert "impossible action" in race.cars[0].reason


def test_at_the_time_limit_the_cars_still_running_are_ranked_by_distance(oval):
    rules = RaceRules(laps=3, resets=10_000, time_limit_s=6.0)
    race = HeadToHeadRace(oval, [Racer(action_space=CONTINUOUS, name="slow"),
                                 Racer(action_space=CONTINUOUS, name="quick")],
                          rules=rules)  # fmt: skip
    drive(
        race,
        [
            PurePursuitDriver(oval, max_speed=0.8),
            PurePursuitDriver(oval, max_speed=2.0, offset=-0.25),
        ],
    )
    assert race.steps == 90 and race.over
    assert all(car.state is CarState.TIME_UP for car in race.cars)
    first, second = race.standings()
    assert first.racer.name == "quick"
    assert first.distance_m(oval.length) > second.distance_m(oval.length) > 0
    assert first.lap_records()[-1].status is Status.TIME_UP


def test_bots_drive_among_the_racers_and_everyone_sees_them(oval):
    config = RaceConfig(race_type=RaceType.HEAD_TO_BOT, number_of_bots=2, bot_speed=0.75)
    race = HeadToHeadRace(oval, [Racer(action_space=CONTINUOUS) for _ in range(2)],
                          rules=RULES, race=config)  # fmt: skip
    race.reset()
    kinds = [o.kind for o in race.objects()]
    assert kinds == [KIND_BOT, KIND_BOT, KIND_RACER, KIND_RACER]
    before = [(b.x, b.y) for b in race.bots]
    race.step([[0, 1.0], [0, 1.0]])
    assert [(b.x, b.y) for b in race.bots] != before
    race.close()


def test_no_bot_starts_on_the_grid(oval):
    config = RaceConfig(race_type=RaceType.HEAD_TO_BOT, number_of_bots=6, bot_speed=0.75)
    race = HeadToHeadRace(oval, [Racer(action_space=CONTINUOUS) for _ in range(4)],
                          rules=RULES, race=config)  # fmt: skip
    race.reset()
    grid_starts = oval.length - grid_length_m(4)
    assert all(2.0 - 1e-6 <= oval.locate(b.x, b.y).s <= grid_starts for b in race.bots)
    race.close()


def test_the_same_seed_gives_the_same_race(oval):
    def run() -> list:
        config = RaceConfig(race_type=RaceType.HEAD_TO_BOT, number_of_bots=2, bot_speed=0.75,
                            randomize_bots=True)  # fmt: skip
        racers = [Racer(("STEREO_CAMERAS", "LIDAR"), action_space=CONTINUOUS),
                  Racer(action_space=CONTINUOUS)]  # fmt: skip
        race = HeadToHeadRace(oval, racers, rules=RULES, race=config, seed=7)
        history = drive(race, [PurePursuitDriver(oval, max_speed=1.5),
                               PurePursuitDriver(oval, max_speed=2.5)], max_steps=150)  # fmt: skip
        rows = [[o.trace for o in step if o is not None] for step in history]
        lidar = race.observations()[0]
        race.close()
        return [rows, None if lidar is None else lidar["LIDAR"].tolist()]

    assert run() == run()


def test_the_broadcast_view_is_the_tv_camera_with_the_map_and_each_racer_s_camera(oval):
    racers = [Racer(action_space=CONTINUOUS, name="Ada"), Racer(action_space=CONTINUOUS, name="Bo")]
    race = HeadToHeadRace(oval, racers, rules=RULES)
    observations = race.reset()
    view = BroadcastView(race, title="Final")
    frame = view.render(observations)
    assert frame.shape == (720, 1280, 3) and frame.dtype == np.uint8
    layout = view.header()["layout"]
    x, y, w, h = layout["map"]
    on_map = frame[y : y + h, x : x + w]
    for car in race.cars:  # each car is a dot of its colour on the map, and in the TV picture
        assert np.all(on_map == car.colour, axis=-1).sum() > 20
    assert view.shot is not None and view.shot.car == race.standings()[0].index
    for pip in layout["pips"]:  # exactly what the model sees, in gray
        px, py, pw, ph = pip["rect"]
        picture = frame[py : py + ph, px : px + pw]
        seen = observations[pip["car"]][..., 0]
        assert np.array_equal(picture[..., 0], seen) and np.array_equal(picture[..., 1], seen)
    assert [p["name"] for p in layout["pips"]] == ["Ada", "Bo"]
    timing = view.header()["timing"]  # the tower is data, not pixels
    assert [c["name"] for c in timing["cars"]] == [race.standings()[0].racer.name,
                                                   race.standings()[1].racer.name]  # fmt: skip
    replay = view.replay_frame(frame)  # the MP4 burns the tower in
    assert replay.shape == frame.shape and not np.array_equal(replay, frame)
    race.retire(1, "withdrawn")
    assert not np.array_equal(view.render(), frame)
    assert view.header()["timing"]["cars"][1]["status"] == "retired"


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"racers": 0}, "1 to 4 cars"),
        ({"racers": 5}, "1 to 4 cars"),
        ({"race": RaceConfig(race_type=RaceType.OBJECT_AVOIDANCE)}, "bot cars or nothing"),
        ({"rules": RaceRules(laps=1)}, "time limit"),
        ({"grid": [0, 0]}, "every entry index once"),
    ],
)
def test_a_race_refuses_what_it_cannot_run(oval, kwargs, message):
    count = kwargs.pop("racers", 2)
    args = {"rules": RULES, **kwargs}
    with pytest.raises(ValueError, match=message):
        HeadToHeadRace(oval, [Racer(action_space=CONTINUOUS)] * count, **args)


def test_a_race_needs_a_loop(oval):
    from racing.track import Track

    open_track = Track(oval._rows[:40], closed=False, track_id="stub", name="Stub")
    with pytest.raises(TrackError, match="not a loop"):
        HeadToHeadRace(open_track, [Racer(action_space=CONTINUOUS)] * 2, rules=RULES)
