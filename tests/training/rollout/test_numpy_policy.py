"""An evaluation driven in its worker: the policy's network in NumPy (GreedyNet) chooses what
torch's policy chooses, a sandboxed worker drives it a chunk of steps a command, and a forged
network or reply is refused."""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch

from training.rl.algorithms import build_model
from training.rl.hyperparams import parse_hyperparameters
from training.rl.policies import NETWORKS, TINY
from training.rollout.envs import EnvRunner, EnvSpec
from training.rollout.experience import ExperienceRequest
from training.rollout.greedy import export_greedy, greedy_actions
from training.rollout.lockstep import Evaluation
from training.rollout.numpy_policy import GreedyNet, NetError
from training.rollout.vecenv import LocalVecEnv, SandboxedVecEnv

ACTIONS = [{"steering_angle": a, "speed": s} for a in (-30, 0, 30) for s in (1.0, 2.0)]
SPEC = EnvSpec(track="racecraft_oval", action_space=ACTIONS)
REWARD = "def reward_function(params):\n    return 1.0 if params['all_wheels_on_track'] else 0.0\n"
PPO = parse_hyperparameters({}, "clipped_ppo")


def torch_logits(policy, obs) -> np.ndarray:
    with torch.inference_mode():
        tensor, _ = policy.obs_to_tensor(obs)
        features = policy.extract_features(tensor)
        return policy.action_net(policy.mlp_extractor.forward_actor(features)).numpy()


def observations(venv, count: int) -> list[np.ndarray]:
    """``count`` observations along a drive that weaves (not only the start's view)."""
    rng = np.random.default_rng(0)
    obs, out = venv.reset(), []
    for _ in range(count):
        out.append(obs)
        obs, *_ = venv.step(rng.integers(len(ACTIONS), size=venv.num_envs))
    return out


@pytest.mark.parametrize("network", [*NETWORKS, TINY])
def test_the_numpy_network_gives_torchs_logits_and_choices(network):
    venv = LocalVecEnv(SPEC, 2, lambda params: 1.0)
    try:
        policy = build_model("clipped_ppo", venv, PPO, network=network, seed=3).policy
        policy.set_training_mode(False)
        net = GreedyNet.from_message(export_greedy(policy))
        for obs in observations(venv, 12):
            expected = torch_logits(policy, obs)
            assert np.allclose(net.logits(obs), expected, rtol=1e-4, atol=1e-5)
            # The same action wherever the best two are not within rounding of each other.
            top2 = np.sort(expected, axis=1)[:, -2:]
            clear = top2[:, 1] - top2[:, 0] > 1e-4
            assert (net.actions(obs)[clear] == greedy_actions(policy, obs)[clear]).all()
    finally:
        venv.close()


def test_networks_it_cannot_run_stay_with_the_trainer():
    """SAC (continuous actions) and camera + LIDAR: None, so the trainer drives with torch."""
    lidar = EnvSpec(track="racecraft_oval", action_space=ACTIONS,
                    sensors=("STEREO_CAMERAS", "SECTOR_LIDAR"))  # fmt: skip
    venv = LocalVecEnv(lidar, 1, lambda params: 1.0)
    try:
        assert export_greedy(build_model("clipped_ppo", venv, PPO, network=TINY).policy) is None
    finally:
        venv.close()
    continuous = EnvSpec(track="racecraft_oval", action_space={
        "steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 2}})  # fmt: skip
    venv = LocalVecEnv(continuous, 1, lambda params: 1.0)
    try:
        sac = parse_hyperparameters({}, "sac")
        assert export_greedy(build_model("sac", venv, sac, network=TINY).policy) is None
    finally:
        venv.close()


def good_message() -> dict:
    venv = LocalVecEnv(SPEC, 1, lambda params: 1.0)
    try:
        return export_greedy(build_model("clipped_ppo", venv, PPO, network=TINY).policy)
    finally:
        venv.close()


def forged(change) -> dict:
    message = good_message()
    change(message)
    return message


def _conv(message) -> dict:
    return next(layer for layer in message["layers"] if layer["op"] == "conv")


FORGED = {
    "not_a_mapping": lambda m: m.clear(),
    "unknown_op": lambda m: m["layers"].append({"op": "softmax"}),
    "no_layers": lambda m: m.update(layers=[]),
    "too_many_layers": lambda m: m.update(layers=[{"op": "relu"}] * 65),
    "weights_nan": lambda m: _conv(m)["weight"].__setitem__((0, 0, 0, 0), np.nan),
    "weights_float64": lambda m: _conv(m).update(weight=_conv(m)["weight"].astype(np.float64)),
    "bias_short": lambda m: _conv(m).update(bias=_conv(m)["bias"][:-1]),
    "stride_zero": lambda m: _conv(m).update(stride=0),
    "kernel_over_the_image": lambda m: _conv(m).update(
        weight=np.zeros((4, 1, 64, 64), np.float32)
    ),  # fmt: skip
    "input_shape": lambda m: m.update(input_shape=[1, 120]),
    "divisor_zero": lambda m: m.update(divisor=0),
    "ends_in_an_image": lambda m: m.update(layers=m["layers"][:2]),
}


@pytest.mark.parametrize("change", FORGED.values(), ids=list(FORGED))
def test_a_network_message_it_cannot_run_is_refused(change):
    with pytest.raises(NetError):
        GreedyNet.from_message(forged(change))


def test_the_runner_drives_until_every_episode_has_ended():
    """A chunk goes on from the last step, stops at the end of the last episode (its env has
    started the next one) and keeps only what an evaluation reads of the infos."""
    runner = EnvRunner([SPEC.make(lambda p: 1.0), SPEC.make(lambda p: 1.0)])
    try:
        with pytest.raises(RuntimeError, match="before reset"):
            runner.drive(GreedyNet.from_message(good_message()), 4)
        runner.reset([1, 2])
        net = GreedyNet.from_message(good_message())
        ended = np.zeros(2, bool)
        steps = 0
        for _ in range(200):
            part = runner.drive(net, 32)
            k = len(part["infos"])
            assert part["rewards"].shape == (k, 2) and part["dones"].shape == (k, 2)
            assert all(set(info) <= {"status", "progress", "lap", "lap_times"}
                       for step in part["infos"] for info in step)  # fmt: skip
            ended |= part["dones"].any(axis=0)
            steps += k
            if k < 32:
                break
        assert ended.all() and runner.finished.all() and 0 < steps < 200 * 32
        assert runner.drive(net, 32)["infos"] == []  # nothing more until the next reset
    finally:
        runner.close()


def request(eval_episodes: int) -> ExperienceRequest:
    return ExperienceRequest(
        spec=SPEC, eval_spec=SPEC, algorithm="clipped_ppo", network=TINY, hyperparameters={},
        episodes_per_update=2, num_envs=2, eval_episodes=eval_episodes,
        spread_eval_starts=True, seed=0, reward_source=REWARD, reward_function=None,
    )  # fmt: skip


class NoFrames:
    def on_frame(self, frame) -> None:
        raise AssertionError("no frames were asked for")


def test_a_sandboxed_worker_drives_the_evaluation_the_trainer_would():
    """Three evaluation cars on two sandboxed workers: driven in the workers (the network
    sent once, then chunks of steps) and driven by the trainer's torch, the same outcome."""
    venv = SandboxedVecEnv(SPEC, 3, REWARD, num_workers=2)
    try:
        policy = build_model("clipped_ppo", venv, PPO, network=TINY, seed=11).policy
        outcomes = []
        for driven_by_workers in (True, False):
            evaluation = Evaluation(venv, request(3), 1, policy if driven_by_workers else None)
            assert evaluation.driven_by_workers == driven_by_workers
            sent = []
            while not evaluation.finished:
                evaluation.send(policy)
                sent.append(venv._sent[0].get("net") is not None)
                while not evaluation.ready():
                    time.sleep(0.001)  # the workers drive; the trainer is free meanwhile
                evaluation.receive(NoFrames())
            if driven_by_workers:
                assert sent[0] and not any(sent[1:])  # the network once
            outcomes.append(evaluation.outcome)
        assert outcomes[0] == outcomes[1]
        assert all(status for status in outcomes[0].statuses)
    finally:
        venv.close()


def test_a_reward_that_hangs_while_the_worker_drives_is_stopped_with_its_line():
    """The evaluation's reward function loops forever on its third call, inside a chunk the
    worker drives: the worker is killed at the per-call limit, the trainer's error names the
    reward function's step, and nothing is left behind."""
    from tests.training.sandbox.sandbox_support import host_intact
    from training.rollout.vecenv import RolloutError
    from training.sandbox import SandboxLimits

    hangs = (
        "calls = 0\n"
        "def reward_function(params):\n"
        "    global calls\n"
        "    calls += 1\n"
        "    while calls >= 3:\n"
        "        pass\n"
        "    return 1.0\n"
    )
    limits = SandboxLimits(per_call_seconds=1.0, cpu_seconds=600, memory_bytes=3 << 30,
                           open_files=256, start_seconds=60.0)  # fmt: skip
    with host_intact():
        venv = SandboxedVecEnv(SPEC, 1, hangs, num_workers=1, limits=limits)
        try:
            policy = build_model("clipped_ppo", venv, PPO, network=TINY, seed=1).policy
            evaluation = Evaluation(venv, request(1), 1, policy)
            started = time.monotonic()
            with pytest.raises(RolloutError, match="reward_function at step") as caught:
                evaluation.drive(None, NoFrames(), want_frames=lambda: False)
            assert time.monotonic() - started < 30  # the per-call limit, not the reply's
            assert "1 s" in str(caught.value) or "1.0 s" in str(caught.value)
        finally:
            venv.close()
