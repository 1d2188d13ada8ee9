"""A policy update's speed-ups change no number they should not: the images prepared once per
update give bit for bit SB3's update (camera, camera + LIDAR); DeepRacer's own CNNs keep SB3's
path; Adam is torch's fused one and stays fused across checkpoints; the greedy action of an
evaluation is what SB3's ``predict`` picks."""

from __future__ import annotations

import copy
import io

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium import spaces
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.vec_env import DummyVecEnv

from training.rl.algorithms import build_model
from training.rl.checkpoints import load_weights
from training.rl.hyperparams import parse_hyperparameters
from training.rl.policies import COMPACT, LEAN, SHALLOW, TINY
from training.rl.prepared import preparable
from training.rollout.greedy import greedy_actions

HP = parse_hyperparameters({"batch_size": 32, "num_epochs": 3})
CAMERA = spaces.Box(0, 255, (120, 160, 1), np.uint8)
LIDAR = spaces.Box(0.15, 12.0, (8,), np.float32)


class Frames(gym.Env):
    """Random camera frames (and a LIDAR vector with ``lidar``), 5 actions."""

    action_space = spaces.Discrete(5)

    def __init__(self, lidar: bool = False) -> None:
        self.observation_space = (
            spaces.Dict({"STEREO_CAMERAS": CAMERA, "LIDAR": LIDAR}) if lidar else CAMERA
        )
        self.observation_space.seed(1)

    def reset(self, seed=None, options=None):
        return self.observation_space.sample(), {}

    def step(self, action):
        return self.observation_space.sample(), 1.0, False, False, {}


def model(network: str, *, lidar: bool = False, prepare: bool = True, envs: int = 2):
    venv = DummyVecEnv([lambda: Frames(lidar)] * envs)
    result = build_model("clipped_ppo", venv, HP, network=network, seed=3)
    result.set_logger(Logger(folder=None, output_formats=[]))
    result.prepare_images = prepare
    return result


def fill(ppo, steps: int = 24) -> None:
    """A complete rollout of random frames, the same for every model (seeded)."""
    ppo.set_rollout_steps(steps)
    rng = np.random.default_rng(0)
    buffer = ppo.rollout_buffer
    observations = buffer.observations
    for array in observations.values() if isinstance(observations, dict) else [observations]:
        if array.dtype == np.uint8:
            array[:] = rng.integers(0, 256, array.shape, dtype=np.uint8)
        else:
            array[:] = rng.uniform(0.15, 12.0, array.shape)
    buffer.actions[:] = rng.integers(0, 5, buffer.actions.shape)
    buffer.advantages[:] = rng.standard_normal(buffer.advantages.shape)
    buffer.returns[:] = rng.standard_normal(buffer.returns.shape)
    buffer.log_probs[:] = -np.log(5)
    buffer.full, buffer.pos = True, steps


def updated(network: str, *, lidar: bool = False, prepare: bool) -> tuple[dict, dict]:
    ppo = model(network, lidar=lidar, prepare=prepare)
    fill(ppo)
    np.random.seed(5)  # the minibatches' order
    ppo.train()
    return ppo.policy.state_dict(), dict(ppo.logger.name_to_value)


@pytest.mark.parametrize(
    ("network", "lidar"),
    [(LEAN, False), (COMPACT, False), (TINY, False), (LEAN, True)],
    ids=["lean", "compact", "tiny", "lidar"],
)
def test_prepared_images_update_exactly_as_sb3(network: str, lidar: bool) -> None:
    ours, our_log = updated(network, lidar=lidar, prepare=True)
    sb3, sb3_log = updated(network, lidar=lidar, prepare=False)
    assert ours.keys() == sb3.keys()
    assert all(torch.equal(ours[k], sb3[k]) for k in ours)
    assert our_log["train/loss"] == sb3_log["train/loss"]
    fresh = model(network, lidar=lidar).policy.state_dict()
    assert any(not torch.equal(ours[k], fresh[k]) for k in ours)  # the update did learn


def test_the_buffer_holds_raw_frames_again_and_the_policy_copies() -> None:
    ppo = model(TINY)
    fill(ppo)
    ppo.train()
    assert ppo.rollout_buffer.observations.dtype == np.float32  # prepared: 15 × 20 floats
    assert ppo.rollout_buffer.observations.shape[-2:] == (15, 20)
    copy.deepcopy(ppo.policy)  # the live view drives a copy: no minibatch's graph is left
    ppo.rollout_buffer.reset()  # what collect_rollouts does first
    assert ppo.rollout_buffer.observations.dtype == np.uint8
    assert ppo.rollout_buffer.observations.shape[-3:] == (1, 120, 160)


def test_deepracers_cnns_keep_sb3s_path() -> None:
    assert preparable(model(LEAN).policy) and preparable(model(TINY).policy)
    shallow = model(SHALLOW, envs=1)
    assert not preparable(shallow.policy)
    fill(shallow, steps=16)
    shallow.train()  # SB3's own path, raw frames
    assert shallow.rollout_buffer.observations.dtype == np.uint8


def test_adam_is_fused_and_stays_fused_across_checkpoints() -> None:
    ppo = model(TINY)
    assert ppo.policy.optimizer.param_groups[0]["fused"] is True
    fill(ppo)
    ppo.train()
    # A checkpoint saved by an unfused Adam (every model trained before): its moments load,
    # the step stays fused and runs.
    old = model(TINY)
    old.policy.optimizer = torch.optim.Adam(old.policy.parameters(), lr=3e-4, eps=1e-5)
    fill(old)
    old.train()
    buffer = io.BytesIO()
    old.save(buffer)
    resumed = model(TINY)
    load_weights(resumed, buffer.getvalue())
    group = resumed.policy.optimizer.param_groups[0]
    assert group["fused"] is True and not group.get("foreach")
    moments = resumed.policy.optimizer.state
    assert moments and all(s["step"].item() == 6 for s in moments.values())  # 2 × 3 epochs
    before = {k: v.clone() for k, v in resumed.policy.state_dict().items()}
    fill(resumed)
    resumed.train()
    assert any(not torch.equal(before[k], v) for k, v in resumed.policy.state_dict().items())


@pytest.mark.parametrize("lidar", [False, True], ids=["camera", "lidar"])
def test_greedy_actions_are_sb3s_deterministic_predictions(lidar: bool) -> None:
    ppo = model(LEAN, lidar=lidar, envs=4)
    venv = ppo.get_env()
    with torch.no_grad():  # spread the logits so that every action wins somewhere
        ppo.policy.action_net.weight.mul_(40.0)
    picked = set()
    for _ in range(25):
        observations = {k: np.stack([s.sample() for _ in range(4)]) for k, s in
                        venv.observation_space.spaces.items()} if lidar else np.stack(
            [CAMERA.sample() for _ in range(4)])  # fmt: skip
        ours = greedy_actions(ppo.policy, observations)
        sb3, _ = ppo.predict(observations, deterministic=True)
        assert np.array_equal(ours, sb3)
        picked.update(ours.tolist())
    assert len(picked) > 1


def test_a_continuous_policy_goes_through_predict() -> None:
    class Steer(Frames):
        action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)

    ppo = build_model("clipped_ppo", DummyVecEnv([Steer]), HP, network=TINY, seed=3)
    observations = np.stack([CAMERA.sample()])
    ours = greedy_actions(ppo.policy, observations)
    sb3, _ = ppo.predict(observations, deterministic=True)
    assert ours.shape == (1, 2) and np.array_equal(ours, sb3)


def test_convolutions_are_channels_last_and_checkpoints_load_anywhere() -> None:
    ppo = model(LEAN)
    conv = ppo.policy.features_extractor.cnn[3].weight  # 16 channels in: the layouts differ
    assert conv.is_contiguous(memory_format=torch.channels_last) and not conv.is_contiguous()
    assert ppo.policy.optimizer.param_groups[0]["params"][0] is next(ppo.policy.parameters())
    frames = torch.rand(8, 1, 120, 160)
    plain = model(LEAN)
    plain.policy.to(memory_format=torch.contiguous_format)
    with torch.no_grad():  # same weights, either layout: the same features
        ours, theirs = ppo.policy.extract_features(frames), plain.policy.extract_features(frames)
    assert torch.allclose(ours, theirs, rtol=1e-6, atol=1e-7)
    fill(ppo)
    ppo.train()
    buffer = io.BytesIO()
    ppo.save(buffer)
    load_weights(plain, buffer.getvalue())
    ours, theirs = ppo.policy.state_dict(), plain.policy.state_dict()
    assert all(torch.equal(ours[k], theirs[k]) for k in ours)


def test_only_the_devices_named_take_channels_last(monkeypatch) -> None:
    from training.rl import algorithms

    assert algorithms.CHANNELS_LAST_DEVICES == ("cpu",)  # an H100 updated slower with it
    monkeypatch.setattr(algorithms, "CHANNELS_LAST_DEVICES", ("cuda",))
    conv = model(LEAN).policy.features_extractor.cnn[3].weight
    assert conv.is_contiguous() and not conv.is_contiguous(memory_format=torch.channels_last)


def test_the_car_graph_of_a_channels_last_model_is_the_same() -> None:
    from training.interchange.carmodel import export_car_graph
    from training.rl.metadata import build_metadata

    actions = [{"steering_angle": a, "speed": 1.0} for a in (-30, -15, 0, 15, 30)]
    meta = build_metadata(action_space=actions, neural_network=LEAN)
    ppo = model(LEAN)
    fill(ppo)
    ppo.train()
    trained = export_car_graph(ppo, meta)
    ppo.policy.to(memory_format=torch.contiguous_format)
    assert export_car_graph(ppo, meta) == trained
