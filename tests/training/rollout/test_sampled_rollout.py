"""A rollout that the workers drive (PPO with a camera network, the actions drawn in NumPy on
the simulation's side) fills the update's buffer as stable-baselines3's ``collect_rollouts``
does: given the same actions, the same observations, rewards, episode starts and time-limit
bootstraps, and the policy's values, log-probabilities, advantages and returns."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from training.rl.algorithms import build_model
from training.rl.hyperparams import parse_hyperparameters
from training.rl.policies import LEAN
from training.rollout.envs import EnvSpec
from training.rollout.greedy import export_greedy
from training.rollout.lockstep import fill_sampled_rollout
from training.rollout.numpy_policy import GreedyNet
from training.rollout.vecenv import LocalVecEnv, SampledSteps, SandboxedVecEnv

ACTIONS = [{"steering_angle": a, "speed": s} for a, s in ((-30, 1.0), (0, 2.0), (30, 1.0))]
HP = parse_hyperparameters({"num_epochs": 3, "batch_size": 32, "discount_factor": 0.9})


def reward(params: dict) -> float:
    return float(params["speed"]) if params["all_wheels_on_track"] else 1e-3


def make(max_steps: int | None) -> tuple[LocalVecEnv, object]:
    venv = LocalVecEnv(EnvSpec(track="racecraft_oval", action_space=ACTIONS), 2, reward)
    if max_steps is not None:  # episodes cut by the time limit (before the first reset)
        for env in venv.runner.envs:
            env.rules = replace(env.rules, max_steps=max_steps)
    venv.seed(3)
    return venv, build_model("clipped_ppo", venv, HP, network=LEAN, seed=3, initial_steps=24)


@pytest.mark.parametrize("max_steps", [None, 10])
def test_the_buffer_is_what_collect_rollouts_fills_for_the_same_actions(max_steps):
    steps = 24
    venv, model = make(max_steps)
    model.set_rollout_steps(steps)
    model._setup_learn(steps * 2, None, reset_num_timesteps=False)
    from stable_baselines3.common.callbacks import BaseCallback

    class Nothing(BaseCallback):
        def _on_step(self) -> bool:
            return True

    callback = Nothing()
    callback.init_callback(model)
    starts_before = model._last_episode_starts.copy()
    assert model.collect_rollouts(model.env, callback, model.rollout_buffer, n_rollout_steps=steps)
    sb3 = {k: getattr(model.rollout_buffer, k).copy() for k in
           ("observations", "actions", "rewards", "episode_starts", "values", "log_probs",
            "advantages", "returns")}  # fmt: skip
    venv.close()

    # The same actions again, from the same start, driven on "the workers' side".
    replay, model2 = make(max_steps)
    model2.policy.load_state_dict(model.policy.state_dict())
    model2.set_rollout_steps(steps)
    model2._setup_learn(steps * 2, None, reset_num_timesteps=False)
    model2._last_episode_starts = starts_before
    actions = sb3["actions"].reshape(steps, 2).astype(np.int64)
    obs, rewards, dones, infos = [], [], [], []
    current = replay.runner.obs
    for t in range(steps):
        obs.append(current)
        current, r, d, i = replay.runner.step(actions[t])
        rewards.append(r)
        dones.append(d)
        infos.append(i)
    assert any(d.any() for d in dones)  # an episode ended inside the rollout
    cut = [i.get("TimeLimit.truncated", False) for step in infos for i in step]
    assert any(cut) == (max_steps is not None)  # ... and one was cut: γ·V(last obs) added
    chunk = SampledSteps(np.stack(obs), actions, np.array(rewards), np.array(dones), infos,
                         current)  # fmt: skip
    fill_sampled_rollout(model2, [chunk])
    ours = model2.rollout_buffer
    for key in ("observations", "actions", "episode_starts"):
        assert np.array_equal(getattr(ours, key), sb3[key]), key
    # The values come from one batch here and one step at a time there: equal to rounding
    # (a cut episode's last reward holds γ × one of them).
    for key in ("rewards", "values", "log_probs", "advantages", "returns"):
        assert np.allclose(getattr(ours, key), sb3[key], atol=1e-5), key
    assert ours.full and ours.pos == steps
    replay.close()


def test_the_workers_draw_each_action_as_often_as_the_policy_gives_it():
    venv, model = make(None)
    try:
        net = GreedyNet.from_message(export_greedy(model.policy))
        obs = venv.reset()
        with torch.no_grad():
            tensor, _ = model.policy.obs_to_tensor(obs)
            probs = model.policy.get_distribution(tensor).distribution.probs.numpy()
        rng = np.random.default_rng(0)
        draws = np.stack([net.sample(obs, rng) for _ in range(20_000)])
        for env in range(2):
            counts = np.bincount(draws[:, env], minlength=len(ACTIONS))
            expected = probs[env] * len(draws)
            # Each count within 5 binomial standard deviations of what the policy gives.
            assert np.all(np.abs(counts - expected) <= 5 * np.sqrt(expected * (1 - probs[env])))
        again = np.stack([net.sample(obs, np.random.default_rng(0)) for _ in range(3)])
        assert (again == draws[0]).all()  # a seed gives the same draws
    finally:
        venv.close()


def test_a_certain_action_is_always_drawn():
    net = GreedyNet([("flatten",), ("dense", np.eye(3, dtype=np.float32),
                                    np.array([0, 50, 0], np.float32))],
                    (1, 1, 3), 1.0)  # fmt: skip
    obs = np.zeros((4, 1, 3, 1), np.uint8)
    rng = np.random.default_rng(1)
    assert all((net.sample(obs, rng) == 1).all() for _ in range(1000))


SOURCE = """
def reward_function(params):
    return float(params["speed"]) if params["all_wheels_on_track"] else 1e-3
"""


@pytest.mark.slow  # two sandboxed workers twice: about 10 s
def test_sandboxed_workers_draw_the_same_rollout_for_the_same_seed():
    """Each worker draws with a generator of its own that the run's seed and its first car
    seed: the same seed gives the same actions and steps, and the workers' draws differ."""
    spec = EnvSpec(track="racecraft_oval", action_space=ACTIONS)
    parts = []
    for _ in range(2):
        venv = SandboxedVecEnv(spec, 4, SOURCE, num_workers=2)
        try:
            venv.seed(11)
            model = build_model("clipped_ppo", venv, HP, network=LEAN, seed=11)
            net = export_greedy(model.policy)
            venv.reset()
            venv.send_sample(net, 20, seed=11)
            first = venv.receive_sample()
            venv.send_sample(None, 12)  # on with the same network and generator
            parts.append((first, venv.receive_sample()))
        finally:
            venv.close()
    (a1, a2), (b1, b2) = parts
    for x, y in ((a1, b1), (a2, b2)):
        assert np.array_equal(x.actions, y.actions) and np.array_equal(x.obs, y.obs)
        assert np.array_equal(x.rewards, y.rewards) and np.array_equal(x.next_obs, y.next_obs)
    assert a1.obs.shape == (20, 4, 120, 160, 1) and a2.actions.shape == (12, 4)
    assert np.array_equal(a2.obs[0], a1.next_obs)  # the second chunk goes on from the first
    assert not np.array_equal(a1.actions[:, :2], a1.actions[:, 2:])  # two generators
