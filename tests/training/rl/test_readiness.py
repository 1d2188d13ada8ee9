"""The readiness check's driver (issue 51): its table on a model that drives (the pure-pursuit
driver stands in for a trained policy) and on one that does not (full left lock), the verdict's
rules, the plan's limits and the check's own seeds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from racing.controllers import PurePursuitDriver
from training.rl.readiness import (
    SEED_TAG,
    ReadinessError,
    ReadinessPlan,
    cell_conditions,
    cell_key,
    cell_seed,
    check_readiness,
    verdict,
    worst_cells,
)
from training.rollout.envs import EnvSpec

CONTINUOUS = {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 4}}
SPEC = EnvSpec(track="racecraft_oval", action_space=CONTINUOUS)
PLAN = ReadinessPlan(families=("light", "latency"), strengths=(0.33, 0.67, 1.0), laps=1)


def pure_pursuit(env):
    driver = PurePursuitDriver(env.track)
    return lambda obs: env.actions.encode(*driver.act(env.pose))


def full_left(env):
    return lambda obs: np.array([30.0, 2.0], dtype=np.float32)


def cell(family: str, strength: float, pct: float, progress: float = 50.0) -> dict:
    return {"family": family, "strength": strength, "completion_pct": pct,
            "mean_progress": progress, "median_lap_s": 9.0 if pct else None}  # fmt: skip


def test_a_model_that_drives_completes_its_laps_and_gets_videos_of_its_worst_cells():
    progress = []
    table = check_readiness(pure_pursuit, SPEC, PLAN, videos=1, on_progress=progress.append)
    cells = {cell_key(c["family"], c["strength"]): c for c in table.cells}
    assert list(cells) == ["clean-0", "light-0_33", "light-0_67", "light-1", "latency-0_33",
                           "latency-0_67", "latency-1"]  # fmt: skip
    clean = cells["clean-0"]
    assert (clean["laps_completed"], clean["laps_attempted"], clean["completion_pct"]) == (
        1,
        1,
        100,
    )
    assert 5.0 < clean["median_lap_s"] < 15.0 and clean["conditions"] == [{}]
    assert set(cells["light-1"]["conditions"][0]) and table.steps > 0
    # Light changes the camera image only: the driver (which reads the pose) is not fooled;
    # two frames of latency at full strength put it off the track.
    assert all(cells[f"light-{s}"]["completion_pct"] == 100 for s in ("0_33", "0_67", "1"))
    assert cells["latency-1"]["completion_pct"] == 0 and cells["latency-1"]["median_lap_s"] is None
    assert table.ready and table.verdict == (
        "Ready: completes at least 100 % of laps under every family at medium strength"
    )
    assert [p["cells_done"] for p in progress] == [1, 2, 3, 4, 5, 6, 7]
    assert table.to_json()["worst"][0] == "latency-1" and list(table.videos) == ["latency-1"]
    assert next(iter(table.videos.values()))[4:8] == b"ftyp"
    data = table.to_json()
    assert data["plan"]["families"] == ["light", "latency"] and data["seed_tag"] == SEED_TAG


def test_a_model_that_does_not_drive_completes_nothing_and_is_not_ready():
    table = check_readiness(full_left, SPEC, PLAN, videos=0)
    assert len(table.cells) == 7
    assert all(c["laps_completed"] == 0 and c["completion_pct"] == 0 for c in table.cells)
    assert all(c["median_lap_s"] is None and c["mean_progress"] < 50 for c in table.cells)
    assert not table.ready
    assert table.verdict == "Not ready: completes 0 % of laps even in the clean world"
    assert table.videos == {}


def test_stopping_keeps_the_cells_driven_and_gives_no_verdict():
    calls = {"n": 0}

    def stop_in_the_second_cell() -> bool:
        calls["n"] += 1
        return calls["n"] > 200  # the clean lap takes fewer steps than this

    table = check_readiness(pure_pursuit, SPEC, PLAN, should_stop=stop_in_the_second_cell)
    assert table.stopped and [c["family"] for c in table.cells] == ["clean"]
    assert (table.ready, table.verdict, table.videos) == (False, "Stopped", {})


@pytest.mark.parametrize(
    ("cells", "ready", "line"),
    [
        ([cell("clean", 0, 50), cell("light", 0.67, 100)], False,
         "Not ready: completes 50 % of laps even in the clean world"),
        ([cell("clean", 0, 100), cell("light", 0.67, 20), cell("look", 0.67, 20),
          cell("car", 0.67, 90)], False,
         "Fragile to light: completes 20 % of laps at strength 0.67"),
        ([cell("clean", 0, 100), cell("light", 0.67, 90), cell("light", 1.0, 0),
          cell("car", 0.67, 80)], True,
         "Ready: completes at least 80 % of laps under every family at medium strength"),
        ([cell("clean", 0, 100), cell("light", 0.33, 0), cell("light", 0.67, 79)], False,
         "Fragile to light: completes 79 % of laps at strength 0.67"),
    ],
)  # fmt: skip
def test_the_verdict_rules(cells, ready, line):
    assert verdict(cells, 0.67) == (ready, line)


def test_the_worst_cells_leave_out_the_baseline():
    cells = [cell("clean", 0, 0, 10), cell("light", 0.5, 50, 60), cell("car", 0.5, 50, 40),
             cell("look", 0.5, 100, 100)]  # fmt: skip
    assert [c["family"] for c in worst_cells(cells)] == ["car", "light"]


def test_the_plan_refuses_what_it_cannot_run():
    for bad in (dict(families=("weather",)), dict(strengths=(0.0, 0.5)), dict(strengths=(1.0, 0.5)),
                dict(laps=0), dict(laps=6), dict(episodes=9), dict(strengths=())):  # fmt: skip
        with pytest.raises(ReadinessError):
            ReadinessPlan(**bad)
    plan = ReadinessPlan()
    assert plan.families == ("light", "look", "camera", "car", "latency")
    assert plan.medium == 0.67 and len(plan.cells()) == 16
    assert ReadinessPlan.from_dict(plan.to_dict()) == plan


def test_the_check_draws_its_own_seeds():
    """Every cell and episode its own draw; none equal to a one-word training seed's."""
    plan = ReadinessPlan()
    states = {tuple(cell_seed(plan, f, s, e).generate_state(4)) for f, s in plan.cells()
              for e in range(3)}  # fmt: skip
    assert len(states) == 3 * len(plan.cells())
    training = {tuple(np.random.SeedSequence(seed).generate_state(4)) for seed in range(1000)}
    assert not states & training
    first, _ = cell_conditions(plan, "light", 0.67, 0)
    again, _ = cell_conditions(plan, "light", 0.67, 0)
    assert first.to_dict() == again.to_dict() and not first.is_clean
    clean, _ = cell_conditions(plan, "clean", 0.0, 0)
    assert clean.is_clean


def one_frame_driver(env):
    """A driver that knows no more than one camera frame shows (the car's place and heading
    on the track ahead; not its speed, its yaw rate or the commands it sent) and picks one of
    the env's discrete actions: pure pursuit of a point 1.5 m ahead, the
    steering quantised to 0, 10 or 20 degrees, each with its fastest action (straight ahead:
    the slowest one where the track ahead bends)."""
    from racing.car import WHEELBASE_M

    actions = [(float(a["steering_angle"]), float(a["speed"])) for a in env.actions.to_metadata()]

    def pick(steer: float, fast: bool = True) -> int:
        speeds = sorted((v, i) for i, (a, v) in enumerate(actions) if a == steer)
        return speeds[-1][1] if fast else speeds[0][1]

    def act(obs):
        pose, track = env.pose, env.track
        loc = track.locate(pose.x, pose.y)
        tx, ty = track.point_at(loc.s + 1.5, 0.0)
        alpha = math.atan2(ty - pose.y, tx - pose.x) - pose.yaw
        alpha = math.atan2(math.sin(alpha), math.cos(alpha))
        dist = max(math.hypot(tx - pose.x, ty - pose.y), 1e-6)
        steer = math.degrees(math.atan2(2 * WHEELBASE_M * math.sin(alpha), dist))
        if abs(steer) >= 12.0:
            return pick(math.copysign(20.0, steer))
        if abs(steer) >= 5.0:
            return pick(math.copysign(10.0, steer))
        return pick(0.0, fast=track.curvature_ahead(loc.s, 1.0) < 0.5)

    return act


SIX_ACTIONS = [
    {"steering_angle": 0.0, "speed": 3.5},
    {"steering_angle": 0.0, "speed": 3.0},
    {"steering_angle": -10.0, "speed": 3.0},
    {"steering_angle": 10.0, "speed": 3.0},
    {"steering_angle": -20.0, "speed": 2.0},
    {"steering_angle": 20.0, "speed": 2.0},
]
"""The racing preset's six grip-graded actions as issue 51 measured it (straight at 3.5 and 3 m/s,
10 degrees at 3, 20 at 2)."""


def test_the_latency_cells_of_one_frame_can_be_driven_with_six_grip_graded_actions():
    """The check's latency family at 0.33 and 0.67 is one frame late (1.0: two). A policy that
    sees one frame and has no memory, restricted to six discrete actions, laps re:Invent 2018
    through it: what no trained model has done yet is not out of reach."""
    spec = EnvSpec(track="reinvent_base", action_space=SIX_ACTIONS)
    plan = ReadinessPlan(families=("latency",), strengths=(0.33, 0.67), laps=2)
    cells = {c["strength"]: c for c in check_readiness(one_frame_driver, spec, plan,
                                                      videos=0).cells}  # fmt: skip
    assert [c["conditions"] for c in cells.values()] == [[{}], [{"frames": 1.0}], [{"frames": 1.0}]]
    assert all(c["laps_completed"] == 2 for c in cells.values())
    assert all(t < 7.0 for c in cells.values() for t in c["lap_times_s"])
