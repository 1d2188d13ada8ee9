"""Training for the world outside (issue 51): the conditions, what they do to the camera's frame
and to the car's path, and that an env without them is unchanged."""

from __future__ import annotations

import json
import math
import pickle

import numpy as np
import pytest

from racing.conditioned_camera import ConditionedCamera, conditioned, pose_at
from racing.conditions import (
    FAMILIES,
    IMAGE_FAMILIES,
    Actuator,
    Conditions,
    ConditionsError,
    ConditionsSpec,
    parameters,
)
from racing.env import RacingEnv
from racing.headtohead import HeadToHeadRace, Racer
from racing.preview import render_conditions_preview_png
from racing.rules import RaceRules
from racing.sensors import CameraSensor, ground_for

STRAIGHT = [{"steering_angle": 0, "speed": 1.0}, {"steering_angle": 30, "speed": 1.0}]


def frame(track, conditions: Conditions | None, *, kind="FRONT_FACING_CAMERA", seed=0):
    base = CameraSensor(ground_for(track, resolution=0.005, rgb=False), kind)
    camera = conditioned(base, track, conditions, np.random.default_rng(seed))
    return camera.observe(pose_at(track, 0.1))


def only(family: str, name: str, value: float) -> Conditions:
    return Conditions.from_dict({family: {name: value}})


# ------------------------------------------------------------------ the parameters and spec
def test_every_family_has_parameters_with_the_neutral_inside_the_widest_range():
    params = parameters()
    assert tuple(params) == FAMILIES
    for family, infos in params.items():
        assert infos, family
        for name, info in infos.items():
            assert info.low <= info.neutral <= info.high, (family, name)
            assert info.low < info.high and info.label and info.help and info.unit is not None


def test_spec_round_trips_through_json_and_samples_inside_its_ranges():
    spec = ConditionsSpec.from_dict(
        {"families": {"light": {"gamma": [0.9, 1.1]}, "latency": True, "car": {}}}
    )
    again = ConditionsSpec.from_dict(json.loads(json.dumps(spec.to_dict())))
    assert again == spec and again.families == ("light", "car", "latency")
    assert spec.to_dict()["families"]["light"]["gamma"] == [0.9, 1.1]
    assert spec.to_dict()["families"]["light"]["contrast"] == [0.85, 1.2]  # its training range
    draws = [spec.sample(np.random.default_rng(i)) for i in range(40)]
    assert draws[3] == spec.sample(np.random.default_rng(3))  # deterministic for a seed
    for c in draws:
        assert 0.9 <= c.values["light"]["gamma"] <= 1.1
        assert c.values["latency"]["frames"] in (0.0, 1.0, 2.0)
        assert c.family_is_neutral("look") and c.family_is_neutral("camera")
    assert {c.values["latency"]["frames"] for c in draws} == {0.0, 1.0}  # trains up to 1
    assert ConditionsSpec.default().families == FAMILIES


def test_the_default_trains_on_a_subset_of_the_widest_ranges_the_check_tests_up_to():
    default, widest = ConditionsSpec.default().to_dict(), ConditionsSpec.widest().to_dict()
    assert list(default["families"]) == list(widest["families"]) == list(FAMILIES)
    narrower = 0
    for family, infos in parameters().items():
        for name, info in infos.items():
            low, high = default["families"][family][name]
            assert [low, high] == list(info.default) and widest["families"][family][name] == [
                info.low,
                info.high,
            ]
            assert info.low <= low <= info.neutral <= high <= info.high, (family, name)
            narrower += (low, high) != (info.low, info.high)
    assert narrower == sum(len(p) for p in parameters().values())  # every one is narrowed
    assert default["families"]["latency"]["frames"] == [0.0, 1.0]
    assert widest["families"]["latency"]["frames"] == [0.0, 2.0]
    # A racer may still train on anything up to the widest: widening a default is no error.
    assert ConditionsSpec.from_dict(widest) == ConditionsSpec.widest()


@pytest.mark.parametrize(
    "data, message",
    [
        ({"families": {"weather": {}}}, "unknown conditions family 'weather'"),
        ({"families": {"light": {"fog": [0, 1]}}}, "unknown parameter 'fog' of the light family"),
        ({"families": {"light": {"gamma": [float("nan"), 1]}}}, "light.gamma low must be finite"),
        ({"families": {"light": {"gamma": [1.2, 0.9]}}}, "light.gamma: low 1.2 is above high 0.9"),
        ({"families": {"camera": {"noise": [0, 50]}}}, "wider than its widest range 0..12"),
        ({"families": {"car": {"speed_scale": 1.0}}}, "car.speed_scale must be a range"),
        ({"families": {"latency": {"frames": [0.2, 0.8]}}}, "holds no whole number"),
        ({"light": {}}, 'with a "families" key'),
    ],
)
def test_spec_validation_names_the_family_and_parameter(data, message):
    with pytest.raises(ConditionsError, match=message.replace(".", r"\.").replace("(", r"\(")):
        ConditionsSpec.from_dict(data)


def test_conditions_clean_strength_and_dict_form():
    assert Conditions.clean().is_clean
    assert Conditions.at_strength("camera", 0.0, np.random.default_rng(0)).is_clean
    full = Conditions.at_strength("light", 1.0, np.random.default_rng(0))
    for name, info in parameters()["light"].items():
        assert full.values["light"][name] in (info.low, info.high), name
    assert all(full.family_is_neutral(f) for f in FAMILIES if f != "light")
    half = Conditions.at_strength("latency", 0.5, np.random.default_rng(0))
    assert half.values["latency"]["frames"] == 1.0
    assert Conditions.from_dict(json.loads(json.dumps(full.to_dict()))) == full
    assert pickle.loads(pickle.dumps(full)) == full and hash(full) == hash(
        Conditions.from_dict(full.to_dict())
    )
    spec = ConditionsSpec.default(["camera"])
    assert (
        pickle.loads(pickle.dumps(spec)) == spec
        and len({spec, ConditionsSpec.default(["camera"])}) == 1
    )
    with pytest.raises(ConditionsError, match="camera.noise = 99 is outside 0..12"):
        Conditions.from_dict({"camera": {"noise": 99}})
    with pytest.raises(ConditionsError, match="strength must be 0-1"):
        Conditions.at_strength("light", 1.5, np.random.default_rng(0))
    with pytest.raises(ConditionsError, match="unknown conditions family"):
        Conditions.at_strength("weather", 0.5, np.random.default_rng(0))


def test_a_curriculum_round_trips_and_a_setting_without_one_reads_as_before():
    plain = ConditionsSpec.default(["light", "latency"])
    ramped = plain.with_ramp(30)
    assert "ramp_episodes" not in plain.to_dict() and plain.ramp_episodes == 0
    data = json.loads(json.dumps(ramped.to_dict()))
    assert data["ramp_episodes"] == 30 and data["families"] == plain.to_dict()["families"]
    assert ConditionsSpec.from_dict(data) == ramped != plain
    assert pickle.loads(pickle.dumps(ramped)) == ramped and hash(ramped) != hash(plain)
    assert ramped.with_ramp(0) == plain  # an old setting (no field) is the same as ramp 0
    assert [ramped.strength_at(e) for e in (0, 15, 30, 99)] == [0.0, 0.5, 1.0, 1.0]
    assert plain.strength_at(0) == 1.0
    for bad in (-1, 2.5, True, "10", 10**6):
        with pytest.raises(ConditionsError, match="ramp_episodes must be"):
            ConditionsSpec.from_dict({"families": {"light": {}}, "ramp_episodes": bad})
    with pytest.raises(ConditionsError, match="unknown conditions key 'ramp'"):
        ConditionsSpec.from_dict({"families": {}, "ramp": 3})


def test_a_curriculum_scales_each_range_about_neutral_and_draws_the_same_numbers():
    spec = ConditionsSpec.default(FAMILIES)
    infos = parameters()
    for seed in range(20):
        full = spec.sample(np.random.default_rng(seed))
        assert spec.sample(np.random.default_rng(seed), 1.0) == full  # strength 1: as before
        assert spec.sample(np.random.default_rng(seed), 0.0).is_clean
        half = spec.sample(np.random.default_rng(seed), 0.5)
        for family, names in spec.ranges.items():
            for name, (low, high) in names.items():
                info, value = infos[family][name], half.values[family][name]
                if info.integer:  # latency: the whole-range draw or none (below)
                    assert value in (info.neutral, full.values[family][name])
                    continue
                assert math.isclose(value - info.neutral,
                                    0.5 * (full.values[family][name] - info.neutral),
                                    abs_tol=1e-9), (family, name)  # fmt: skip
                lo, hi = sorted((info.neutral + 0.5 * (low - info.neutral),
                                 info.neutral + 0.5 * (high - info.neutral)))  # fmt: skip
                assert lo - 1e-9 <= value <= hi + 1e-9
        # The draw uses the generator alike at every strength: what follows it is the same.
        a, b = np.random.default_rng(seed), np.random.default_rng(seed)
        spec.sample(a, 0.3), spec.sample(b)
        assert a.random() == b.random()
    # An integer parameter (latency) cannot be scaled to a fraction of a frame: it comes late
    # as at full strength in a share of the episodes that grows with the strength, so that a
    # curriculum eases it in too (its scaled range would hold only 0 frames until the end).
    late = ConditionsSpec.from_dict({"families": {"latency": {"frames": [2, 2]}}})
    for strength, share in ((0.0, 0.0), (0.25, 0.25), (0.5, 0.5), (0.9, 0.9), (1.0, 1.0)):
        frames = [late.sample(np.random.default_rng(seed), strength).values["latency"]["frames"]
                  for seed in range(400)]  # fmt: skip
        assert set(frames) <= {0.0, 2.0}
        assert abs(frames.count(2.0) / len(frames) - share) < 0.08, strength
    default = ConditionsSpec.default(["latency"])  # 0-1 frame: late in about half the episodes
    halfway = [default.sample(np.random.default_rng(seed), 0.5).values["latency"]["frames"]
               for seed in range(400)]  # fmt: skip
    assert 0.15 < halfway.count(1.0) / len(halfway) < 0.35  # 1 frame in 1/2 × 1/2 of them
    assert [late.sample(np.random.default_rng(7), 0.5) for _ in range(2)] == [
        late.sample(np.random.default_rng(7), 0.5)
    ] * 2  # deterministic for a seed
    with pytest.raises(ConditionsError, match="strength must be 0-1"):
        spec.sample(np.random.default_rng(0), 1.5)


def test_an_envs_curriculum_grows_with_its_own_episodes_deterministically(reinvent):
    spec = ConditionsSpec.default(["light", "car"])

    def episodes(conditions, seed=5, n=6):
        env = RacingEnv(reinvent, conditions=conditions)
        out = [env.reset(seed=seed)[1]["conditions"]]
        out += [env.reset()[1]["conditions"] for _ in range(n - 1)]
        return out

    ramped, plain = episodes(spec.with_ramp(4)), episodes(spec)
    assert Conditions.from_dict(ramped[0]).is_clean  # episode 0: strength 0
    light = [abs(e["light"]["brightness"]) for e in ramped]
    assert 0 < light[1] <= 25 / 4 and 0 < light[2] <= 25 / 2  # 1/4, then 1/2 of the range
    assert ramped[4:] == plain[4:]  # from the ramp's end: the whole ranges, the same draws
    assert ramped[1:4] != plain[1:4]
    assert episodes(spec.with_ramp(4).to_dict()) == ramped  # deterministic for a seed
    again = RacingEnv(reinvent, conditions=spec.with_ramp(4))
    again.reset(seed=5)
    for _ in range(4):
        again.reset()
    assert again.reset(seed=5)[1]["conditions"] == ramped[0]  # a seeded reset starts it over
    # An event's entrants (a conditions seed) drive at full strength from the first episode.
    event = RacingEnv(reinvent, conditions=spec.with_ramp(4), conditions_seed=3)
    same = RacingEnv(reinvent, conditions=spec, conditions_seed=3)
    assert event.reset(seed=1)[1]["conditions"] == same.reset(seed=1)[1]["conditions"]


# ------------------------------------------------------------------ the camera's frame
def test_each_family_changes_the_frame_and_only_the_image_families_do(reinvent):
    clean = frame(reinvent, None)
    for family in FAMILIES:
        c = Conditions.at_strength(family, 0.8, np.random.default_rng(1))
        seen = frame(reinvent, c)
        if family in IMAGE_FAMILIES:
            assert not np.array_equal(seen, clean), family
            assert np.array_equal(seen, frame(reinvent, c)), f"{family} is not deterministic"
        else:
            assert np.array_equal(seen, clean), family
    # A neutral draw of every family is the clean frame, byte for byte.
    assert np.array_equal(frame(reinvent, Conditions.clean()), clean)


@pytest.mark.parametrize("family", IMAGE_FAMILIES)
def test_every_image_parameter_changes_the_frame_on_its_own(reinvent, family):
    clean = frame(reinvent, None)
    for name, info in parameters()[family].items():
        edge = info.high if info.high != info.neutral else info.low
        assert not np.array_equal(frame(reinvent, only(family, name, edge)), clean), name


def test_the_look_recolours_the_road_and_the_walls_where_they_are(reinvent):
    clean = frame(reinvent, None)[..., 0].astype(int)
    light_road = frame(reinvent, only("look", "road", 140))[..., 0].astype(int)
    near_road = (slice(110, 120), slice(30, 60))  # just ahead of the car, left of centre
    assert clean[near_road].mean() == pytest.approx(53, abs=3)
    assert light_road[near_road].mean() == pytest.approx(140, abs=3)
    sky = (slice(0, 5), slice(None))
    assert np.array_equal(light_road[sky], clean[sky])  # the wall keeps its gray
    bright_wall = frame(reinvent, only("look", "wall", 200))[..., 0]
    assert bright_wall[sky].mean() == pytest.approx(200, abs=1)


def test_noise_differs_per_seed_and_per_frame_but_repeats_for_a_seed(reinvent):
    c = only("camera", "noise", 8.0)
    assert not np.array_equal(frame(reinvent, c, seed=1), frame(reinvent, c, seed=2))
    base = CameraSensor(ground_for(reinvent, resolution=0.005, rgb=False))
    camera = ConditionedCamera(base, reinvent, c, np.random.default_rng(0))
    pose = pose_at(reinvent, 0.1)
    first, second = camera.observe(pose), camera.observe(pose)
    assert not np.array_equal(first, second)
    noise = first.astype(int) - frame(reinvent, None).astype(int)
    assert 5 < noise.std() < 11


def test_stereo_cameras_see_the_conditions_in_both_lenses(reinvent):
    clean = frame(reinvent, None, kind="STEREO_CAMERAS")
    seen = frame(reinvent, only("look", "floor", 30), kind="STEREO_CAMERAS")
    assert seen.shape == (120, 160, 2)
    for lens in range(2):
        assert not np.array_equal(seen[..., lens], clean[..., lens])


def test_mount_yaw_turns_the_view_the_right_way(reinvent):
    """Turned left, the lens sees the track's features further right in the frame."""
    clean = frame(reinvent, None)[..., 0].astype(float)
    turned = frame(reinvent, only("camera", "yaw_deg", 3.0))[..., 0].astype(float)
    row = 100  # near the car: the centre line's dashes

    def centre_column(image):
        return float(np.argmax(np.convolve(image[row], np.ones(5), "same")[20:140])) + 20

    assert centre_column(turned) > centre_column(clean)


def test_preview_shows_what_the_model_sees_under_each_conditions(reinvent):
    conditions = [Conditions.clean(), only("look", "road", 140), only("look", "road", 140)]
    pngs = render_conditions_preview_png(reinvent, conditions, at=0.1)
    assert len(pngs) == 3 and all(p.startswith(b"\x89PNG") for p in pngs)
    assert pngs[0] != pngs[1] and pngs[1] == pngs[2]
    import cv2

    image = cv2.imdecode(np.frombuffer(pngs[0], np.uint8), cv2.IMREAD_UNCHANGED)
    assert image.shape == (240, 320)
    assert np.array_equal(image[::2, ::2], frame(reinvent, None)[..., 0])


# ------------------------------------------------------------------ the car's path
def test_actuator_applies_the_cars_errors_and_the_latency():
    car = Actuator(Conditions.from_dict({"car": {"steering_offset_deg": 2, "steering_gain": 1.1,
                                                 "speed_scale": 1.2}}))  # fmt: skip
    assert car(10.0, 1.0) == pytest.approx((13.0, 1.2))
    assert car(30.0, 4.0) == pytest.approx((30.0, 4.0))  # clipped to the car's limits
    late = Actuator(Conditions.from_dict({"latency": {"frames": 2}}))
    assert [late(float(a), 1.0) for a in (1, 2, 3, 4)] == [(0, 0), (0, 0), (1, 1), (2, 1)]


def drive(conditions: Conditions | None, actions, **kwargs):
    env = RacingEnv("reinvent_base", start="start_line", action_space=STRAIGHT, **kwargs)
    env.set_conditions(conditions)
    _, info = env.reset(seed=0)
    poses, params = [env.pose], []
    for a in actions:
        _, _, _, _, step_info = env.step(a)
        poses.append(env.pose)
        params.append(step_info["params"])
    env.close()
    return poses, params, info


def test_a_steering_offset_bends_a_straight_run_the_way_it_pulls():
    def left_of_start(poses):
        p0, p = poses[0], poses[-1]
        dx, dy = p.x - p0.x, p.y - p0.y
        return -math.sin(p0.yaw) * dx + math.cos(p0.yaw) * dy

    straight = [0] * 20
    clean, clean_params, info = drive(None, straight)
    assert "conditions" not in info
    pulled_left, params, info = drive(only("car", "steering_offset_deg", 3.0), straight)
    pulled_right, _, _ = drive(only("car", "steering_offset_deg", -3.0), straight)
    assert info["conditions"]["car"]["steering_offset_deg"] == 3.0
    assert left_of_start(pulled_left) > left_of_start(clean) + 0.05
    assert left_of_start(pulled_right) < left_of_start(clean) - 0.05
    # params keep the action the model chose, as DeepRacer's do.
    assert [p["steering_angle"] for p in params] == [p["steering_angle"] for p in clean_params]
    fast, _, _ = drive(only("car", "speed_scale", 1.2), straight)

    def distance(poses):
        return math.hypot(poses[-1].x - poses[0].x, poses[-1].y - poses[0].y)

    assert distance(fast) > 1.1 * distance(clean)


@pytest.mark.parametrize("k", [1, 2])
def test_latency_delays_the_cars_response_by_k_steps(k):
    actions = [0] * 10 + [1] * 8  # straight, then hard left
    clean, _, _ = drive(None, actions)
    late, _, _ = drive(only("latency", "frames", k), actions)
    for a, b in zip(late[k:], clean[:-k], strict=True):  # the same path, k steps later
        assert (a.x, a.y, a.yaw) == pytest.approx((b.x, b.y, b.yaw), abs=1e-4)
    turned = [abs(p.yaw - clean[0].yaw) > 0.01 for p in late]
    assert turned.index(True) == [abs(p.yaw - clean[0].yaw) > 0.01 for p in clean].index(True) + k


# ------------------------------------------------------------------ the env
def rollout(env: RacingEnv, steps: int = 60):
    obs, info = env.reset(seed=5)
    frames, rewards = [obs], []
    for i in range(steps):
        obs, reward, done, truncated, _ = env.step(i % 10)
        frames.append(obs)
        rewards.append(reward)
        if done or truncated:
            obs, _ = env.reset()
            frames.append(obs)
    return np.stack(frames), rewards, env.np_random.bit_generator.state


def test_an_env_without_conditions_is_unchanged_bit_for_bit(reinvent):
    plain = rollout(RacingEnv(reinvent))
    none = rollout(RacingEnv(reinvent, conditions=None))
    assert np.array_equal(plain[0], none[0]) and plain[1] == none[1]
    # Conditions that change only the action draw from their own stream: np_random's draws
    # (objects, LIDAR noise) are the same.
    with_car = rollout(RacingEnv(reinvent, conditions={"families": {"car": {}}}))
    assert with_car[2] == plain[2]
    assert np.array_equal(with_car[0][0], plain[0][0])  # the camera: unchanged at the start


def test_episodes_draw_their_conditions_the_same_for_a_conditions_seed(reinvent):
    def draws(env, seed):
        env.reset(seed=seed)
        out = [env.conditions.to_dict()]
        for _ in range(2):
            _, info = env.reset()
            out.append(info["conditions"])
        return out

    spec = ConditionsSpec.default()
    a = draws(RacingEnv(reinvent, conditions=spec, conditions_seed=11), seed=1)
    b = draws(RacingEnv(reinvent, conditions=spec.to_dict(), conditions_seed=11), seed=2)
    assert a == b and a[0] != a[1]
    c = draws(RacingEnv(reinvent, conditions=spec), seed=1)
    assert c == draws(RacingEnv(reinvent, conditions=spec), seed=1) and c != a
    env = RacingEnv(reinvent, conditions=spec, conditions_seed=11)
    fixed = Conditions.at_strength("look", 0.5, np.random.default_rng(0))
    env.set_conditions(fixed)
    assert env.reset(seed=0)[1]["conditions"] == fixed.to_dict()
    env.set_conditions(None)
    assert env.reset(seed=0)[1]["conditions"] == a[0]
    with pytest.raises(ConditionsError, match="fast camera"):
        RacingEnv(reinvent, conditions=spec, camera_backend="pybullet")


def test_a_head_to_head_race_shows_the_conditions_in_every_camera():
    from racing.tracks import TrackCatalog

    oval = TrackCatalog([]).load("racecraft_oval").in_direction("native")
    rules = RaceRules(laps=1, time_limit_s=10.0)
    racers = [Racer(name="a"), Racer(name="b")]
    clean = HeadToHeadRace(oval, racers, rules=rules).reset()
    dark = only("light", "brightness", -50.0)
    seen = HeadToHeadRace(oval, racers, rules=rules, conditions=dark).reset()
    for before, after in zip(clean, seen, strict=True):
        assert after.mean() < before.mean() - 20


def test_the_look_path_draws_boxes_toned_like_the_clean_path(reinvent):
    """A look at DeepRacer's own colours (a colour cast of 1e-9 takes the class texture's
    path) with dim light gives the gray path's frame, boxes included, to rounding."""
    from racing.preview import race_objects
    from racing.race import RaceConfig, RaceType

    boxes = race_objects(reinvent, RaceConfig(race_type=RaceType.OBJECT_AVOIDANCE))
    s = reinvent.locate(boxes[0].x, boxes[0].y).s
    pose = pose_at(reinvent, (s - 0.8) / reinvent.length)
    base = CameraSensor(ground_for(reinvent, resolution=0.005, rgb=False))
    dim = {"brightness": -30.0, "gamma": 1.2}
    frames = []
    for light in (dim, {**dim, "cast": 1e-9}):
        c = Conditions.from_dict({"light": light})
        camera = ConditionedCamera(base, reinvent, c, np.random.default_rng(0))
        frames.append(camera.observe(pose, boxes)[..., 0].astype(int))
    assert not np.array_equal(base.observe(pose), base.observe(pose, boxes))  # a box in view
    diff = np.abs(frames[0] - frames[1])
    assert diff.max() <= 5 and diff.mean() < 0.2  # rounding on anti-aliased edges
