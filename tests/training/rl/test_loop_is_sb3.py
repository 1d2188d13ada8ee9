"""The one training loop's lockstep iteration is stable-baselines3's own ``learn()``, bit for
bit, where the trainer chooses the actions (``sample_in_workers=False``, and every policy that
cannot travel to the workers): the experience source's ``collect_rollouts`` and the loop's
``train`` are the two halves of it, so a seed's steps and weights are what they were when the
loop called ``learn()``. (Where the workers draw the actions, the buffer they fill is held to
``collect_rollouts``'s in tests/training/rollout/test_sampled_rollout.py.) Trusted in-process
reward and the tiny test network: no sandbox, a second or two."""

from __future__ import annotations

import pytest
import torch

from training.rl.algorithms import build_model
from training.rl.checkpoints import load_weights
from training.rl.hyperparams import parse_hyperparameters
from training.rl.policies import TINY
from training.rl.runner import TrainingConfig, TrainingHooks, train, update_threads
from training.rollout.backends import LocalRollouts
from training.rollout.envs import EnvSpec
from training.rollout.lockstep import INITIAL_EPISODE_STEPS, plan_rollout_steps
from training.rollout.vecenv import LocalVecEnv

ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]
SPEC = EnvSpec(track="racecraft_oval", action_space=ACTIONS)
pytestmark = pytest.mark.slow  # about 3 s quiet, 9 s on a loaded 2-core machine
HP = parse_hyperparameters({"num_episodes_between_training": 2, "num_epochs": 3,
                            "batch_size": 32})  # fmt: skip


def reward(params: dict) -> float:
    return 1.0 if params["all_wheels_on_track"] else 1e-3


class One(TrainingHooks):
    def __init__(self) -> None:
        self.results, self.checkpoints = [], []

    def on_iteration(self, result, checkpoint, rows) -> None:
        self.results.append(result)
        self.checkpoints.append(checkpoint)

    def should_stop(self) -> bool:
        return bool(self.results)


def test_a_lockstep_iteration_is_sb3_learn_bit_for_bit():
    hooks = One()
    train(TrainingConfig(spec=SPEC, network=TINY, hyperparameters=HP, reward_function=reward,
                         num_envs=2, eval_episodes=1, seed=7, device="cpu",
                         rollouts=LocalRollouts(sample_in_workers=False)), hooks)  # fmt: skip
    [result] = hooks.results
    assert result.evaluation.ended_in_lap == [1]  # one 1-lap evaluation: it ended in lap 1

    venv = LocalVecEnv(SPEC, 2, reward)
    try:
        venv.seed(7)
        model = build_model("clipped_ppo", venv, HP, network=TINY, seed=7)
        n_steps = plan_rollout_steps(2, INITIAL_EPISODE_STEPS, 2)
        model.set_rollout_steps(n_steps)
        # The loop's update leaves a core to the evaluation beside it: as many threads here
        # (1 and 2 threads round differently; driving comes out the same on either).
        threads = torch.get_num_threads()
        torch.set_num_threads(update_threads(TrainingConfig(spec=SPEC).torch_threads, 1))
        try:
            model.learn(total_timesteps=n_steps * 2, reset_num_timesteps=False)
        finally:
            torch.set_num_threads(threads)
        assert result.steps == result.total_steps == model.num_timesteps == n_steps * 2
        looped = build_model("clipped_ppo", venv, HP, network=TINY, seed=0)
        load_weights(looped, hooks.checkpoints[0])
        ours, sb3 = looped.policy.state_dict(), model.policy.state_dict()
        assert ours.keys() == sb3.keys()
        assert all(torch.equal(ours[k], sb3[k]) for k in ours)
        fresh = build_model("clipped_ppo", venv, HP, network=TINY, seed=7).policy.state_dict()
        assert any(not torch.equal(ours[k], fresh[k]) for k in ours)  # the update did learn
    finally:
        venv.close()


def test_ppo_drives_on_one_thread_and_updates_on_the_configured_ones(monkeypatch):
    import torch

    from training.rl import algorithms
    from training.rollout.lockstep import Evaluation, LockstepExperience

    seen: dict[str, list[int]] = {"gather": [], "train": [], "evaluate": []}
    gather, evaluate = LockstepExperience.gather, Evaluation.send
    update = algorithms.DeepRacerPPO.train

    def watched(name, fn):
        def call(*args, **kwargs):
            seen[name].append(torch.get_num_threads())
            return fn(*args, **kwargs)

        return call

    monkeypatch.setattr(LockstepExperience, "gather", watched("gather", gather))
    monkeypatch.setattr(Evaluation, "send", watched("evaluate", evaluate))  # each chunk of steps
    monkeypatch.setattr(algorithms.DeepRacerPPO, "train", watched("train", update))
    before = torch.get_num_threads()
    try:
        train(TrainingConfig(spec=SPEC, network=TINY, hyperparameters=HP, reward_function=reward,
                             num_envs=2, eval_episodes=1, seed=7, device="cpu",
                             torch_threads=2, inference_threads=1), One())  # fmt: skip
    finally:
        torch.set_num_threads(before)
    # The evaluation runs beside the second rollout (and the second update, if it lasts that
    # long); its end stops the run (One iteration). Every update leaves a core to an
    # evaluation beside it: 2 threads where there are 3 cores, 1 where there are 2.
    assert seen["gather"] == [1, 1] and seen["train"]
    assert set(seen["train"]) == {update_threads(2, 1)}
    assert seen["evaluate"] and set(seen["evaluate"]) == {1}
