"""The Gymnasium env: the checker, determinism, starts, traces, rendering and bad input."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import racing
from racing.actions import ActionSpaceError
from racing.env import RacingEnv, RewardValueError
from racing.simtrace import SIMTRACE_COLUMNS, to_csv
from racing.track import TrackError
from racing.tracks import UnknownTrackError

CONTINUOUS = {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 4}}


@pytest.mark.parametrize(
    "kwargs",
    [
        {},
        {"action_space": CONTINUOUS},
        {"sensors": ["STEREO_CAMERAS"], "render_mode": "rgb_array"},
        {"direction": "cw", "alternate_direction": True},
        {  # the race as the training side sends it: a plain dict
            "race": {"race_type": "HEAD_TO_BOT", "number_of_bots": 3, "bot_lane_change": True},
            "sensors": ["STEREO_CAMERAS", "SECTOR_LIDAR"],
            "render_mode": "rgb_array",
        },
    ],
)
def test_gymnasium_env_checker_passes(reinvent, kwargs):
    env = gym.make(racing.ENV_ID, track=reinvent, **kwargs)
    with warnings.catch_warnings():
        # The checker recommends [-1, 1] Box actions; ours are DeepRacer's degrees and m/s.
        warnings.filterwarnings("ignore", message=".*symmetric and normalized space")
        check_env(env.unwrapped, skip_render_check=False)
    env.close()


def rollout(env: RacingEnv, seed: int, steps: int = 120):
    obs, _ = env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    frames, rewards, statuses = [obs], [], []
    for _ in range(steps):
        obs, reward, terminated, truncated, info = env.step(int(rng.integers(10)))
        frames.append(obs)
        rewards.append(reward)
        statuses.append(info["status"])
        if terminated or truncated:
            obs, _ = env.reset()
            frames.append(obs)
    return np.stack(frames), np.array(rewards), statuses


def test_same_seed_same_rollout(reinvent):
    a = RacingEnv(reinvent)
    b = RacingEnv(reinvent)
    fa, ra, sa = rollout(a, seed=7)
    fb, rb, sb = rollout(b, seed=7)
    assert np.array_equal(fa, fb)
    assert np.array_equal(ra, rb)
    assert sa == sb
    a.close()
    b.close()


def test_observation_is_a_grayscale_camera_image(reinvent):
    env = RacingEnv(reinvent)
    obs, _ = env.reset(seed=0)
    assert obs.shape == (120, 160, 1) and obs.dtype == np.uint8
    # DeepRacer's dark walls fill the top rows; the road (lighter than the walls) the lower middle.
    assert obs[:20].mean() < 30 < obs[100:, 60:100].mean()
    stereo = RacingEnv(reinvent, sensors=["STEREO_CAMERAS"])
    obs2, _ = stereo.reset(seed=0)
    assert obs2.shape == (120, 160, 2)
    assert not np.array_equal(obs2[..., 0], obs2[..., 1])  # two lenses, two views


def test_round_robin_starts_advance_five_percent(reinvent):
    env = RacingEnv(reinvent)
    starts = []
    for i in range(3):
        _, info = env.reset(seed=0 if i == 0 else None)
        starts.append(info["start_s"])
    step = reinvent.length * 0.05
    assert starts[1] - starts[0] == pytest.approx(step, abs=0.01)
    assert starts[2] - starts[1] == pytest.approx(step, abs=0.01)
    line = RacingEnv(reinvent, start="start_line")
    assert line.reset(seed=0)[1]["start_s"] == pytest.approx(0.0, abs=1e-6)
    assert line.reset()[1]["start_s"] == pytest.approx(0.0, abs=1e-6)


def test_alternating_direction(reinvent):
    env = RacingEnv(reinvent, alternate_direction=True)
    seen = []
    for i in range(3):
        _, info = env.reset(seed=0 if i == 0 else None)
        seen.append(info["params"]["is_reversed"])
    assert seen == [False, True, False]


def test_trace_rows_have_deepracers_19_columns(reinvent):
    env = RacingEnv(reinvent, start="start_line")
    env.reset(seed=0)
    rows = []
    for _ in range(5):
        *_, info = env.step(5)
        rows.append(info["trace"])
    assert len(SIMTRACE_COLUMNS) == 19
    text = to_csv(rows).splitlines()
    assert text[0].split(",") == list(SIMTRACE_COLUMNS)
    first = text[1].split(",")
    assert len(first) == 19
    assert first[0] == "0" and first[1] == "1"
    assert first[7] == "5" and first[9] == "False" and first[15] == "in_progress"
    assert float(first[18]) > 1e9  # stamped with the wall clock when written


def test_continuous_trace_action_format(reinvent):
    env = RacingEnv(reinvent, action_space=CONTINUOUS, start="start_line")
    env.reset(seed=0)
    *_, info = env.step(np.array([10.0, 2.0], dtype=np.float32))
    assert info["trace"].format().split(",")[7] == "[10.00 2.00]"


@pytest.mark.parametrize("view, shape", [("chase", (240, 320, 3)), ("top_down", None)])
def test_rgb_render(reinvent, view, shape):
    env = RacingEnv(reinvent, render_mode="rgb_array", render_view=view)
    env.reset(seed=0)
    frame = env.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    if shape:
        assert frame.shape == shape
    else:
        assert frame.shape[1] == 480
    # The red car is in the picture.
    red = (frame[..., 0] > 180) & (frame[..., 1] < 90) & (frame[..., 2] < 90)
    assert red.sum() > 20


def test_action_outside_the_space_raises_clearly(reinvent):
    env = RacingEnv(reinvent)
    env.reset(seed=0)
    with pytest.raises(ActionSpaceError, match="outside the discrete space of 10 actions"):
        env.step(10)
    cont = RacingEnv(reinvent, action_space=CONTINUOUS)
    cont.reset(seed=0)
    with pytest.raises(ActionSpaceError, match="outside"):
        cont.step(np.array([45.0, 1.0]))
    with pytest.raises(ActionSpaceError):
        cont.step(np.array([np.nan, 1.0]))
    # The env is still usable afterwards.
    assert cont.step(np.array([0.0, 1.0], dtype=np.float32))[4]["status"] == "in_progress"


def test_unknown_track_and_bad_settings_raise_clearly(tmp_path):
    with pytest.raises(UnknownTrackError, match="unknown track 'no_such_track'"):
        RacingEnv("no_such_track")
    with pytest.raises(TrackError):
        RacingEnv(42)
    with pytest.raises(ValueError, match="start"):
        RacingEnv("racecraft_oval", start="anywhere")
    with pytest.raises(ValueError, match="render_mode"):
        RacingEnv("racecraft_oval", render_mode="human")


def test_malformed_track_file_raises_track_error(tmp_path):
    (tmp_path / "bad.npy").write_bytes(np.zeros((10, 5)).tobytes())  # not even a .npy file
    with pytest.raises(TrackError, match="not a NumPy"):
        RacingEnv("bad", track_dirs=[tmp_path])
    np.save(tmp_path / "five.npy", np.zeros((10, 5)))
    with pytest.raises(TrackError, match=r"shape \(N, 6\)"):
        RacingEnv("five", track_dirs=[tmp_path])


@pytest.mark.parametrize("value", [float("nan"), float("inf"), 1e6, "fast", None])
def test_bad_reward_values_name_the_step(reinvent, value):
    env = RacingEnv(reinvent, reward_function=lambda params: value)
    env.reset(seed=0)
    with pytest.raises(RewardValueError, match="step 1"):
        env.step(5)


def test_reward_function_receives_params_and_sets_the_reward(reinvent):
    seen = []

    def reward(params):
        seen.append(params["steps"])
        return params["progress"] + 1.0

    env = RacingEnv(reinvent, reward_function=reward, start="start_line")
    env.reset(seed=0)
    _, r1, *_ = env.step(5)
    _, r2, *_ = env.step(5)
    assert seen == [1, 2]
    assert r2 > r1 >= 1.0


def test_reset_penalty_and_respawn_in_evaluation(reinvent):
    from racing.rules import RaceRules

    env = RacingEnv(
        reinvent, rules=RaceRules(resets=3, off_track_penalty_s=2.0), start="start_line"
    )
    env.reset(seed=0)
    info = {}
    for _ in range(200):  # hard left at full lock drives off the track
        *_, terminated, truncated, info = env.step(9)
        if info["reset"]:
            break
    assert info["reset"] and info["status"] == "off_track" and info["penalty_s"] == 2.0
    # Respawned on the track, the lap goes on.
    assert info["trace"].pause_duration == 2.0
    *_, terminated, _, info = env.step(5)
    assert info["params"]["all_wheels_on_track"] and not terminated
