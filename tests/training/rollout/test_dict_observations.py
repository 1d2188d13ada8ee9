"""Camera + LIDAR observations on the rollout side: the env runner stacks them per sensor and
grabs live frames from the camera; what a worker sends back is checked per sensor (shape,
dtype, finite values) and never trusted."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium import spaces

from racing.race import RaceConfig
from training.rollout.envs import EnvRunner, EnvSpec, camera_image, stack_observations
from training.rollout.vecenv import RolloutError, _WorkerVecEnv
from training.sandbox import checked

SENSORS = ("STEREO_CAMERAS", "SECTOR_LIDAR")
SPEC = EnvSpec(
    track="racecraft_oval",
    action_space=[{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)],
    sensors=SENSORS,
    race=RaceConfig(race_type="HEAD_TO_BOT", number_of_bots=2, bot_speed=0.5).to_dict(),
)


def test_the_runner_stacks_each_sensor_and_grabs_frames_from_the_camera():
    runner = EnvRunner([SPEC.make(None), SPEC.make(None)])
    try:
        obs = runner.reset([1, 2])
        assert set(obs) == set(SENSORS)
        assert obs["STEREO_CAMERAS"].shape == (2, 120, 160, 2)
        assert obs["SECTOR_LIDAR"].shape == (2, 8) and obs["SECTOR_LIDAR"].dtype == np.float32
        runner.want_frames = True
        runner.frames.interval_s = 0.0
        obs, rewards, dones, infos = runner.step(np.array([1, 1]))
        frame = infos[0]["frame"]
        assert frame["camera"][:2].tobytes() == b"\xff\xd8"  # a JPEG of the left camera
        assert len(runner.envs[0].objects) == 2  # the bots are on the track
        for _ in range(400):  # straight on: the car leaves the oval, and the episode ends
            obs, rewards, dones, infos = runner.step(np.array([1, 1]))
            if dones[0]:
                break
        assert dones[0]
        terminal = infos[0]["terminal_observation"]
        assert set(terminal) == set(SENSORS) and terminal["SECTOR_LIDAR"].shape == (8,)
    finally:
        runner.close()


def test_camera_image_and_stacking_of_plain_images():
    image = np.zeros((120, 160, 1), np.uint8)
    assert camera_image(image) is image
    assert camera_image({"LIDAR": np.zeros(64, np.float32), "X": image}) is image
    assert stack_observations([image, image]).shape == (2, 120, 160, 1)


class _Replies(_WorkerVecEnv):
    """A worker vec env whose "workers" are a list of canned replies."""

    def __init__(self, observation_space, replies) -> None:
        self.sizes = [1]
        self.replies = replies
        super().__init__(1, observation_space, spaces.Discrete(3))

    def _exchange(self, messages):
        return [self.replies.pop(0)]

    def close(self) -> None:
        self.replies.clear()


def dict_space():
    return spaces.Dict(
        {
            "FRONT_FACING_CAMERA": spaces.Box(0, 255, (120, 160, 1), np.uint8),
            "LIDAR": spaces.Box(0.15, 1.0, (64,), np.float32),
        }
    )


def good_obs():
    return {"FRONT_FACING_CAMERA": np.zeros((1, 120, 160, 1), np.uint8),
            "LIDAR": np.full((1, 64), 0.5, np.float32)}  # fmt: skip


@pytest.mark.parametrize(
    "obs, words",
    [
        ({"FRONT_FACING_CAMERA": np.zeros((1, 120, 160, 1), np.uint8)}, "expected the keys"),
        ({**good_obs(), "LIDAR": np.full((1, 64), 0.5, np.float64)}, "float32 array"),
        ({**good_obs(), "LIDAR": np.full((1, 32), 0.5, np.float32)}, r"shape \(1, 64\)"),
        ({**good_obs(), "LIDAR": np.full((1, 64), np.nan, np.float32)}, "finite"),
        (np.zeros((1, 120, 160, 1), np.uint8), "expected an object"),
    ],
)  # fmt: skip
def test_malformed_dict_observations_are_refused(obs, words):
    venv = _Replies(dict_space(), [{"obs": obs}])
    with pytest.raises(RolloutError, match=words):
        venv.reset()


def test_a_well_formed_dict_reply_is_taken():
    venv = _Replies(dict_space(), [{"obs": good_obs()}])
    obs = venv.reset()
    assert obs["LIDAR"].shape == (1, 64) and obs["FRONT_FACING_CAMERA"].shape == (1, 120, 160, 1)
    with pytest.raises(checked.Malformed):
        venv._obs({"FRONT_FACING_CAMERA": "x", "LIDAR": 1}, 1)
