"""The value loss switch of DeepRacerPPO and DeepRacerSAC, on tiny networks and gymnasium's
classic-control tasks: with ``mean_squared_error`` an update is exactly SB3's own, with
``huber`` the value loss is torch's Huber loss, and SB3's modules are never touched."""

from __future__ import annotations

import gymnasium as gym
import pytest
import stable_baselines3.ppo.ppo as sb3_ppo
import stable_baselines3.sac.sac as sb3_sac
import torch
import torch.nn.functional as F
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.base_class import BaseAlgorithm

from training.rl.algorithms import DeepRacerPPO, DeepRacerSAC, value_loss

TINY = {"net_arch": [16]}


def ppo(cls: type[PPO], loss_type: str | None = None, steps: int = 128, **kwargs) -> PPO:
    """A tiny PPO on CartPole after ``steps`` steps of learning (seeded: the same every time)."""
    options = {"n_steps": 64, "batch_size": 32, "n_epochs": 2, **kwargs}
    model = cls("MlpPolicy", gym.make("CartPole-v1"), policy_kwargs=TINY, seed=7, device="cpu",
                **options)  # fmt: skip
    if loss_type:
        model.loss_type = loss_type
    return model.learn(steps)


def sac(cls: type[SAC], loss_type: str | None = None) -> SAC:
    """A tiny SAC on Pendulum after 64 steps of learning (32 of them updates)."""
    model = cls("MlpPolicy", gym.make("Pendulum-v1"), buffer_size=1000, learning_starts=32,
                batch_size=32, policy_kwargs=TINY, seed=7, device="cpu")  # fmt: skip
    if loss_type:
        model.loss_type = loss_type
    return model.learn(64)


def weights(model: BaseAlgorithm) -> list[torch.Tensor]:
    return [p.detach().clone() for p in model.policy.parameters()]


def same(a: list[torch.Tensor], b: list[torch.Tensor]) -> bool:
    return all(torch.equal(x, y) for x, y in zip(a, b, strict=True))


def test_value_loss_is_huber_or_mean_squared_error() -> None:
    values = torch.tensor([0.0, 0.5, 3.0, -4.0])
    targets = torch.tensor([0.2, 0.0, 0.0, 0.0])  # errors inside and outside Huber's δ = 1
    huber = value_loss("huber", values, targets)
    mse = value_loss("mean_squared_error", values, targets)
    assert torch.equal(huber, F.huber_loss(values, targets))
    assert torch.equal(mse, F.mse_loss(values, targets))
    assert huber < mse


def test_ppo_with_mean_squared_error_learns_exactly_as_sb3() -> None:
    ours, theirs = ppo(DeepRacerPPO, "mean_squared_error"), ppo(PPO)
    assert same(weights(ours), weights(theirs))


def test_ppo_value_loss_of_a_batch_is_huber() -> None:
    model = ppo(DeepRacerPPO, "huber", steps=64, n_epochs=1, batch_size=64)
    # One more update on the same rollout, in one batch: the value loss it logs is the Huber
    # loss between the rollout's returns and what the value head predicts before the update.
    batch = next(model.rollout_buffer.get(64))
    with torch.no_grad():
        values, _, _ = model.policy.evaluate_actions(
            batch.observations, batch.actions.long().flatten()
        )
    expected = F.huber_loss(batch.returns, values.flatten()).item()
    assert expected != pytest.approx(F.mse_loss(batch.returns, values.flatten()).item())
    model.train()
    assert model.logger.name_to_value["train/value_loss"] == pytest.approx(expected, rel=1e-6)


def test_huber_changes_the_update_and_leaves_sb3_alone() -> None:
    ours, theirs = ppo(DeepRacerPPO, "huber"), ppo(PPO)
    assert not same(weights(ours), weights(theirs))
    sac(DeepRacerSAC, "huber")
    assert sb3_ppo.F is F and sb3_sac.F is F
    assert F.mse_loss is torch.nn.functional.mse_loss


def test_sac_with_mean_squared_error_learns_exactly_as_sb3_and_huber_differs() -> None:
    ours, theirs = sac(DeepRacerSAC, "mean_squared_error"), sac(SAC)
    huber = sac(DeepRacerSAC, "huber")
    assert same(weights(ours), weights(theirs))
    assert not same(weights(huber), weights(theirs))
