"""Crashes come from PyBullet contacts: into a box, into a bot (or a bot into the car), the
training end, the evaluation penalty and respawn, determinism and a scripted avoider."""

from __future__ import annotations

import numpy as np
import pytest

from racing.controllers import AvoidingDriver
from racing.env import RacingEnv
from racing.objects import Lanes
from racing.race import RaceConfig
from racing.rules import RaceRules

STRAIGHT = 5
"""Default action 5 of 10: straight ahead at 1 m/s."""
SLOW = 4
"""Default action 4 of 10: straight ahead at 0.5 m/s."""
BOX_AT = 0.1
"""Where the test box stands on reinvent_base: at the end of the start straight."""


def box_env(track, **kwargs) -> RacingEnv:
    race = RaceConfig(race_type="OBJECT_AVOIDANCE", object_positions=((BOX_AT, 1),))
    return RacingEnv(track, race=race, start="start_line", **kwargs)


def start_behind(env: RacingEnv, metres: float, lane: int) -> dict:
    """Reset with the car ``metres`` before the box, on lane ``lane``'s midline."""
    s = BOX_AT * env.track.length - metres
    offset = Lanes(env.track).offset(s, lane)
    return env.reset(
        seed=0, options={"start_progress": 100 * s / env.track.length, "offset": offset}
    )[1]


def drive_until_done(env: RacingEnv, action: int = STRAIGHT, limit: int = 120):
    for _ in range(limit):
        obs, reward, terminated, truncated, info = env.step(action)
        if terminated or truncated or info["reset"]:
            return terminated, info
    raise AssertionError("the episode never ended")


def test_driving_into_a_box_is_a_crash_that_ends_training(reinvent):
    env = box_env(reinvent)
    start_behind(env, 1.5, lane=1)
    box_body = env.world.bodies.body_ids[0]
    for _ in range(120):
        *_, terminated, _, info = env.step(STRAIGHT)
        contacts = env.sim.client.getContactPoints(bodyA=env.sim.car, bodyB=box_body)
        if terminated:
            break
        assert not contacts and info["params"]["is_crashed"] is False
    assert info["status"] == "crashed" and info["params"]["is_crashed"] is True
    assert contacts  # PyBullet reports the contact that ended it
    # About 1.5 m less the car's nose and half the box, at 1 m/s and 15 steps a second.
    assert 15 < info["params"]["steps"] < 25
    # The same drive in the other lane passes the box.
    start_behind(env, 1.5, lane=-1)
    for _ in range(40):
        *_, terminated, _, info = env.step(STRAIGHT)
        assert info["status"] != "crashed"
    env.close()


def test_evaluation_crash_costs_the_penalty_and_respawns_behind_the_box(reinvent):
    env = box_env(reinvent, rules=RaceRules(resets=3, crash_penalty_s=5.0))
    start_behind(env, 1.5, lane=1)
    box_s = env.world.locations[0].s
    time_before = None
    for _ in range(120):
        time_before = env.sim_time
        *_, terminated, _, info = env.step(STRAIGHT)
        if info["reset"]:
            break
    assert not terminated and info["status"] == "crashed" and info["penalty_s"] == 5.0
    assert env.sim_time == pytest.approx(time_before + 1 / 15 + 5.0)
    lap = env.tracker.current_lap
    assert (lap.crashes, lap.resets, lap.penalty_s) == (1, 1, 5.0)
    # 1 m behind the box, in the other lane (outer: right on this counter-clockwise track).
    loc = reinvent.locate(*env.car.point)
    assert box_s - loc.s == pytest.approx(1.0, abs=0.02)
    assert loc.left is False and loc.distance == pytest.approx(0.19, abs=0.03)
    assert env.sim.pose().speed == pytest.approx(0.0, abs=1e-6)
    # Progress went back with the car, and the lap goes on from there.
    assert info["progress"] < 100 * (box_s - 0.9) / reinvent.length
    *_, terminated, _, info = env.step(STRAIGHT)
    assert info["status"] == "in_progress" and not terminated
    env.close()


def bot_env(track, speed: float = 0.3, **kwargs) -> RacingEnv:
    race = RaceConfig(race_type="HEAD_TO_BOT", number_of_bots=1, bot_speed=speed)
    return RacingEnv(track, race=race, start="start_line", **kwargs)


def test_running_into_a_bot_from_behind_is_a_crash(reinvent):
    env = bot_env(reinvent)
    # The bot starts 2 m along the track in the inner lane; the car starts 1 m behind it.
    offset = Lanes(reinvent).offset(1.0, 1)
    env.reset(seed=0, options={"start_progress": 100 * 1.0 / reinvent.length, "offset": offset})
    terminated, info = drive_until_done(env)  # 1 m/s against the bot's 0.3 m/s
    assert terminated and info["status"] == "crashed" and info["params"]["is_crashed"]
    env.close()


def test_a_bot_running_into_the_car_is_not_its_fault(reinvent):
    env = bot_env(reinvent, speed=1.5, rules=RaceRules(bot_pause_s=2.0))
    # The car crawls 0.4 m ahead of a faster bot, in its lane: the bot drives into its back.
    offset = Lanes(reinvent).offset(2.6, 1)
    env.reset(seed=0, options={"start_progress": 100 * 2.6 / reinvent.length, "offset": offset})
    paused = False
    for _ in range(20):
        *_, terminated, _, info = env.step(SLOW)
        assert info["status"] != "crashed" and not terminated
        paused = paused or env.world.fleet.paused
    assert paused  # the bots stopped for the penalty instead
    env.close()


def rollout(env: RacingEnv, seed: int, steps: int = 150) -> tuple[list, list, list]:
    obs, info = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    observations, rewards, params = [obs], [], [info["params"]]
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(int(rng.integers(10)))
        observations.append(obs)
        rewards.append(reward)
        params.append(info["params"])
        if terminated or truncated:
            obs, info = env.reset()
            observations.append(obs)
    return observations, rewards, params


@pytest.mark.parametrize("race_type", ["OBJECT_AVOIDANCE", "HEAD_TO_BOT"])
def test_same_seed_same_episode(reinvent, race_type):
    race = RaceConfig(
        race_type=race_type, randomize_objects=True, randomize_bots=True, bot_lane_change=True
    )
    a = RacingEnv(reinvent, race=race, sensors=["STEREO_CAMERAS", "LIDAR"])
    b = RacingEnv(reinvent, race=race, sensors=["STEREO_CAMERAS", "LIDAR"])
    oa, ra, pa = rollout(a, seed=5)
    ob, rb, pb = rollout(b, seed=5)
    assert len(oa) == len(ob)
    for x, y in zip(oa, ob, strict=True):
        assert np.array_equal(x["STEREO_CAMERAS"], y["STEREO_CAMERAS"])
        assert np.array_equal(x["LIDAR"], y["LIDAR"])
    assert ra == rb
    assert [p["objects_location"] for p in pa] == [p["objects_location"] for p in pb]
    assert [p["is_crashed"] for p in pa] == [p["is_crashed"] for p in pb]
    a.close()
    b.close()


@pytest.mark.slow
def test_a_scripted_driver_avoids_six_boxes_for_three_clean_laps(reinvent):
    positions = ((0.15, 1), (0.30, -1), (0.45, 1), (0.60, -1), (0.75, 1), (0.90, -1))
    race = RaceConfig(race_type="OBJECT_AVOIDANCE", object_positions=positions)
    continuous = {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.1, "high": 4}}
    env = RacingEnv(
        reinvent, race=race, rules=RaceRules(laps=3), start="start_line", action_space=continuous
    )
    driver = AvoidingDriver(env.track, max_speed=1.5)
    env.reset(seed=0)
    for _ in range(2000):
        steer, speed = driver.act_among(env.pose, env.objects)
        *_, terminated, truncated, info = env.step(np.array([steer, speed], dtype=np.float32))
        if terminated or truncated:
            break
    assert info["status"] == "lap_complete"
    laps = info["laps"]
    assert len(laps) == 3
    assert all(lap.crashes == 0 and lap.off_tracks == 0 and lap.resets == 0 for lap in laps)
    env.close()


def test_evaluation_crash_into_a_bot_freezes_the_car_where_it_is(reinvent):
    env = bot_env(reinvent, rules=RaceRules(resets=3, crash_penalty_s=5.0))
    offset = Lanes(reinvent).offset(1.0, 1)
    env.reset(seed=0, options={"start_progress": 100 * 1.0 / reinvent.length, "offset": offset})
    for _ in range(120):
        bot_before = env.world.locations[0].s
        *_, terminated, _, info = env.step(STRAIGHT)
        if info["reset"]:
            break
    assert info["status"] == "crashed" and not terminated and info["penalty_s"] == 5.0
    # The car stays where it hit the bot, at rest; the bot drove on for the 5 s penalty.
    assert reinvent.locate(*env.car.point).s == pytest.approx(info["params"]["projection_distance"])
    assert env.sim.pose().speed == pytest.approx(0.0, abs=1e-6)
    assert env.world.locations[0].s - bot_before == pytest.approx(0.3 * (5.0 + 1 / 15), abs=0.03)
    *_, terminated, _, info = env.step(STRAIGHT)
    assert info["status"] == "in_progress"
    env.close()


def test_bots_change_lane_within_the_configured_interval(reinvent):
    race = RaceConfig(
        race_type="HEAD_TO_BOT",
        number_of_bots=1,
        bot_lane_change=True,
        lane_change_min_s=2.0,
        lane_change_max_s=3.0,
        bot_speed=1.0,
    )
    env = RacingEnv(reinvent, race=race)
    env.reset(seed=4)
    fleet = env.world.fleet
    changes = []
    lane = fleet.bots[0].lane
    for step in range(1, 15 * 20):
        env.world.advance(1 / 15)
        if fleet.bots[0].target != lane:
            changes.append(step / 15)
            lane = fleet.bots[0].target
    # A change starts 2-3 s after the previous one ended; each lasts 1 m at 1 m/s.
    waits = np.diff([0.0, *changes])
    assert len(changes) >= 5
    assert waits[0] == pytest.approx(2.5, abs=0.55)
    assert all(3.0 - 0.1 <= w <= 4.0 + 0.1 for w in waits[1:])
    env.close()


def test_mercy_reset_puts_the_car_past_a_box_it_keeps_hitting(reinvent):
    env = box_env(reinvent, rules=RaceRules(resets=10, mercy_resets=3))
    env.reset(seed=0)
    box_s = env.world.locations[0].s
    spots = [env.world.respawn_spot(box_s - 0.3).s for _ in range(4)]
    assert spots == pytest.approx([box_s - 1.0, box_s - 1.0, box_s + 1.0, box_s - 1.0])
    assert env.world.respawn_spot(box_s + 3.0) is None  # no box within 1 m: the usual respawn
    plain = box_env(reinvent, rules=RaceRules(resets=10))
    plain.reset(seed=0)
    assert [plain.world.respawn_spot(box_s - 0.3).s for _ in range(4)] == pytest.approx(
        [box_s - 1.0] * 4
    )
    with pytest.raises(ValueError, match="mercy_resets must be at least 1"):
        RaceRules(mercy_resets=0)
