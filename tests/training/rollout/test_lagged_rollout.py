"""``lagged_rollout`` (an experiment, off by default): where the workers draw the training cars'
actions, each rollout after the first is driven while the update before it runs, with the
policy that drove the rollout before, and the buffer gets that policy's values and
log-probabilities (the importance ratio of PPO's clipped loss is then against the policy that
chose the actions). Trusted in-process reward and the tiny network: a few seconds."""

from __future__ import annotations

import pytest
import torch

from training.rl.hyperparams import parse_hyperparameters
from training.rl.policies import TINY
from training.rl.runner import TrainingConfig, TrainingHooks, train
from training.rollout import lockstep
from training.rollout.envs import EnvSpec

ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]
SPEC = EnvSpec(track="racecraft_oval", action_space=ACTIONS)
HP = parse_hyperparameters({"num_episodes_between_training": 2, "num_epochs": 3,
                            "batch_size": 32})  # fmt: skip
pytestmark = pytest.mark.slow


def reward(params: dict) -> float:
    return 1.0 if params["all_wheels_on_track"] else 1e-3


class Three(TrainingHooks):
    def __init__(self) -> None:
        self.results = []

    def on_iteration(self, result, checkpoint, rows) -> None:
        self.results.append(result)

    def should_stop(self) -> bool:
        return len(self.results) >= 3


def weights(policy) -> dict[str, torch.Tensor]:
    return {k: v.detach().clone() for k, v in policy.state_dict().items()}


def test_a_lagged_rollout_is_driven_beside_the_update_by_the_policy_before(monkeypatch):
    fills: list[tuple[bool, dict, dict]] = []
    fill = lockstep.fill_sampled_rollout

    def watched(model, chunks, policy=None):
        driver = model.policy if policy is None else policy
        fills.append((driver is model.policy, weights(driver), weights(model.policy)))
        return fill(model, chunks, policy)

    came_in: list[int] = []
    beside = lockstep.LockstepExperience._beside_update

    def counted(self, learner):
        beside(self, learner)
        if self._ahead is not None:
            came_in.append(len(self._ahead.received))

    monkeypatch.setattr(lockstep, "fill_sampled_rollout", watched)
    monkeypatch.setattr(lockstep.LockstepExperience, "_beside_update", counted)
    hooks = Three()
    threads = torch.get_num_threads()
    try:
        config = TrainingConfig(spec=SPEC, network=TINY, hyperparameters=HP,
                                reward_function=reward, num_envs=2, eval_episodes=1, seed=7,
                                device="cpu", lagged_rollout=True)  # fmt: skip
        summary = train(config, hooks)
    finally:
        torch.set_num_threads(threads)
    assert summary.iterations == 3 and len(fills) >= 3
    # The first rollout is the current policy's; each one after, the policy before the
    # update that ran beside it: the model's when the rollout before was filled.
    first_is_current, _, _ = fills[0]
    assert first_is_current
    for (_, _, before), (is_current, driver, current) in zip(fills, fills[1:], strict=False):
        assert not is_current
        assert all(torch.equal(driver[k], before[k]) for k in driver)
        assert any(not torch.equal(driver[k], current[k]) for k in driver)  # one update behind
    assert max(came_in) > 0  # chunks came in between the update's minibatches
    steps = [r.steps for r in hooks.results]
    assert [r.total_steps for r in hooks.results] == [sum(steps[: i + 1]) for i in range(3)]
