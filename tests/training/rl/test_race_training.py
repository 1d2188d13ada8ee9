"""Training and evaluating in every race type with every sensor combination: boxes and bot cars
on the track, camera + LIDAR and stereo + LIDAR networks (DeepRacer's LIDAR embedder), the
sandboxed rollout workers sending Dict observations, checkpoints that load for the model's
metadata, and evaluation with Dict observations and objects in the video."""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
import pytest
import torch

from racing.race import RaceConfig, RaceType
from training.rl.checkpoints import load_checkpoint
from training.rl.evaluation import EvaluationSettings, evaluate, sb3_policy
from training.rl.hyperparams import parse_hyperparameters
from training.rl.metadata import build_metadata
from training.rl.policies import (
    LEAN,
    TINY,
    CameraExtractor,
    CameraLidarExtractor,
    NetworkError,
    policy_kwargs,
    policy_type,
)
from training.rl.runner import TrainingConfig, TrainingHooks, train
from training.rollout.envs import EnvSpec, camera_image

DISCRETE = [{"steering_angle": a, "speed": 0.8} for a in (-30, 0, 30)]
REWARD = """
def reward_function(params):
    if params["is_crashed"] or not params["all_wheels_on_track"]:
        return 1e-3
    return 1.0
"""
BOXES = RaceConfig(race_type=RaceType.OBJECT_AVOIDANCE, number_of_objects=2).to_dict()
BOTS = RaceConfig(race_type=RaceType.HEAD_TO_BOT, number_of_bots=1, bot_speed=0.4).to_dict()


class Collect(TrainingHooks):
    def __init__(self, iterations: int) -> None:
        self.iterations = iterations
        self.results, self.checkpoints, self.rows = [], [], []

    def on_iteration(self, result, checkpoint, rows) -> None:
        self.results.append(result)
        self.checkpoints.append(checkpoint)
        self.rows.append(rows)

    def should_stop(self) -> bool:
        return len(self.results) >= self.iterations


def test_lidar_extractor_is_deepracers_embedder_next_to_the_camera():
    """Camera + LIDAR: the camera network's features then two 256-unit dense layers over the
    LIDAR, concatenated; a camera-only model keeps its extractor (and its weight names)."""
    meta = build_metadata(action_space=DISCRETE, sensor=["STEREO_CAMERAS", "LIDAR"])
    space = gym.spaces.Dict(
        {
            "STEREO_CAMERAS": gym.spaces.Box(0, 1, (2, 120, 160), np.float32),
            "LIDAR": meta.observation_space.spaces["LIDAR"],
        }
    )
    assert policy_type(space) == "MultiInputPolicy"
    assert policy_kwargs(LEAN, space)["features_extractor_class"] is CameraLidarExtractor
    extractor = CameraLidarExtractor(space, LEAN)
    assert [m.out_features for m in extractor.lidar if isinstance(m, torch.nn.Linear)] == [
        256,
        256,
    ]
    assert extractor.features_dim == extractor.camera.features_dim + 256
    out = extractor({"STEREO_CAMERAS": torch.zeros(3, 2, 120, 160), "LIDAR": torch.ones(3, 64)})
    assert out.shape == (3, extractor.features_dim)
    camera_only = gym.spaces.Box(0, 1, (1, 120, 160), np.float32)
    assert policy_type(camera_only) == "CnnPolicy"
    assert policy_kwargs(LEAN, camera_only)["features_extractor_class"] is CameraExtractor
    with pytest.raises(NetworkError, match="one camera image and one LIDAR"):
        CameraLidarExtractor(gym.spaces.Dict({"LIDAR": space.spaces["LIDAR"]}), LEAN)


@pytest.mark.slow  # the sandboxed workers' start, not the (tiny) network, takes the time
@pytest.mark.parametrize(
    "race, sensors, algorithm, actions",
    [
        (BOXES, ("FRONT_FACING_CAMERA", "LIDAR"), "clipped_ppo", DISCRETE),
        (BOTS, ("STEREO_CAMERAS", "SECTOR_LIDAR"), "sac",
         {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 1.0}}),
        (BOXES, ("STEREO_CAMERAS",), "clipped_ppo", DISCRETE),
    ],
    ids=["boxes-camera-lidar-ppo", "bots-stereo-sector-lidar-sac", "boxes-stereo-ppo"],
)  # fmt: skip
def test_a_race_trains_in_sandboxed_workers_and_evaluates(race, sensors, algorithm, actions):
    """One iteration in sandboxed workers (the Dict observations cross the pipe), then the
    checkpoint loads for the model's metadata (nothing unpickled) and drives an evaluation
    in the same race: the objects are on the track, in the video and in the metrics. The
    network is the test-only tiny one: the subject here is the sensors and the race."""
    spec = EnvSpec(track="racecraft_oval", action_space=actions, sensors=sensors, race=race)
    hooks = Collect(iterations=1)
    summary = train(
        TrainingConfig(
            spec=spec,
            algorithm=algorithm,
            network=TINY,
            hyperparameters=parse_hyperparameters(
                {"num_episodes_between_training": 4, "num_epochs": 3, "batch_size": 32},
                algorithm,
            ),
            max_minutes=60,  # the hooks stop it after one iteration, however loaded
            reward_source=REWARD,
            num_envs=2,
            eval_episodes=1,
        ),
        hooks,
    )
    assert summary.iterations == 1 and hooks.results[0].steps > 0
    assert hooks.rows[0]  # the sim-trace of the iteration came back from the workers
    metadata = build_metadata(action_space=actions, training_algorithm=algorithm,
                              sensor=list(sensors))  # fmt: skip
    metadata = dataclasses.replace(metadata, neural_network=TINY)  # no user's metadata names it
    model = load_checkpoint(hooks.checkpoints[0], metadata)
    assert model.num_timesteps == hooks.results[0].total_steps
    report = evaluate(
        sb3_policy(model), spec, EvaluationSettings(laps=3, crash_penalty_s=5.0, resets=0)
    )
    assert report.laps and report.video_mp4[4:8] == b"ftyp"
    assert len(report.rows) == report.steps > 0
    assert {"crash_count", "reset_count"} <= set(report.metrics[0])


def test_evaluation_drives_a_dict_observation_policy_among_boxes():
    """evaluate() hands the policy the Dict observation (camera + LIDAR) and draws the video
    from its camera image; the boxes are in the race."""
    spec = EnvSpec(track="racecraft_oval", action_space=DISCRETE,
                   sensors=("FRONT_FACING_CAMERA", "LIDAR"), race=BOXES)  # fmt: skip
    seen = []

    def policy(obs):
        seen.append(obs)
        return 1  # straight on: it hits a box or leaves the track, and no resets are left

    report = evaluate(policy, spec, EvaluationSettings(laps=3, resets=0, record_video=True))
    first = seen[0]
    assert set(first) == {"FRONT_FACING_CAMERA", "LIDAR"}
    assert camera_image(first).shape == (120, 160, 1) and first["LIDAR"].shape == (64,)
    assert report.laps[0].status in ("crashed", "off_track")
    assert report.video_mp4 is not None
    env = spec.make(None)
    env.reset(seed=0)
    assert len(env.objects) == 2  # the spec carries the race to the env
    env.close()
