"""DeepRacer's hyperparameters mapped onto stable-baselines3's PPO and SAC.

PPO: ``batch_size`` → batch_size, ``num_epochs`` → n_epochs, ``lr`` → learning_rate,
``beta_entropy`` → ent_coef, ``discount_factor`` → gamma, clip 0.2, GAE λ 0.95, Adam ε 1e-5
(DeepRacer's fixed internals), ``loss_type`` → the value loss (Huber or mean squared error).
``num_episodes_between_training`` sets how many episodes each policy update learns from: the
rollout length is re-planned before every update from the average episode length so far.

SAC (continuous actions only): ``sac_alpha`` → a fixed ent_coef, ``loss_type`` → the critic
loss, a replay buffer of recent steps, τ = 0.005 (SB3's soft update; DeepRacer's rl_coach used
hard copies, which SB3 does not offer for SAC).
"""

from __future__ import annotations

import contextlib
import math
import types

import torch
import torch.nn.functional as F
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.vec_env import VecEnv

from training.rl.checkpoints import load_weights
from training.rl.hyperparams import Hyperparameters
from training.rl.policies import LEAN, policy_kwargs, sac_policy_kwargs

CLIP_RANGE = 0.2
GAE_LAMBDA = 0.95
ADAM_EPS = 1e-5
MIN_ROLLOUT_STEPS = 16
MAX_ROLLOUT_STEPS = 2048
SAC_BUFFER_STEPS = 20_000


class AlgorithmError(ValueError):
    """An algorithm that does not fit the action space."""


@contextlib.contextmanager
def _value_loss(module, loss_type: str):
    """Swap the mean-squared error SB3 uses for its value/critic loss with Huber, for one
    update. SB3 computes that loss with ``F.mse_loss`` and has no switch for it."""
    if loss_type != "huber":
        yield
        return
    original = module.F
    patched = types.SimpleNamespace(**{k: getattr(F, k) for k in dir(F) if not k.startswith("__")})
    patched.mse_loss = F.smooth_l1_loss
    module.F = patched
    try:
        yield
    finally:
        module.F = original


class DeepRacerPPO(PPO):
    """SB3's PPO with DeepRacer's loss switch and a rollout length that can change."""

    loss_type = "huber"

    def train(self) -> None:
        import stable_baselines3.ppo.ppo as ppo_module

        with _value_loss(ppo_module, self.loss_type):
            super().train()

    def set_rollout_steps(self, n_steps: int) -> None:
        """Collect ``n_steps`` per env before the next update (a new buffer if it changes)."""
        if n_steps == self.n_steps:
            return
        self.n_steps = n_steps
        self.rollout_buffer = RolloutBuffer(
            n_steps,
            self.observation_space,
            self.action_space,
            device=self.device,
            gamma=self.gamma,
            gae_lambda=self.gae_lambda,
            n_envs=self.n_envs,
        )


class DeepRacerSAC(SAC):
    loss_type = "mean_squared_error"

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        import stable_baselines3.sac.sac as sac_module

        with _value_loss(sac_module, self.loss_type):
            super().train(gradient_steps, batch_size)


def plan_rollout_steps(episodes: int, mean_episode_steps: float, num_envs: int) -> int:
    """Steps per env so that about ``episodes`` episodes finish before the next update."""
    steps = math.ceil(episodes * max(mean_episode_steps, 1.0) / num_envs)
    return int(min(MAX_ROLLOUT_STEPS, max(MIN_ROLLOUT_STEPS, steps)))


def build_model(
    algorithm: str,
    env: VecEnv,
    hp: Hyperparameters,
    *,
    network: str = LEAN,
    seed: int = 0,
    initial_steps: int = 64,
) -> DeepRacerPPO | DeepRacerSAC:
    """A new SB3 model for ``algorithm`` (``clipped_ppo`` or ``sac``) on ``env``."""
    continuous = not hasattr(env.action_space, "n")
    if algorithm == "clipped_ppo":
        kwargs = policy_kwargs(network)
        kwargs["optimizer_kwargs"] = {"eps": ADAM_EPS}
        model = DeepRacerPPO(
            "CnnPolicy",
            env,
            learning_rate=hp.lr,
            n_steps=initial_steps,
            batch_size=hp.batch_size,
            n_epochs=hp.num_epochs,
            gamma=hp.discount_factor,
            gae_lambda=GAE_LAMBDA,
            clip_range=CLIP_RANGE,
            ent_coef=hp.beta_entropy,
            policy_kwargs=kwargs,
            seed=seed,
            device="cpu",
            verbose=0,
        )
    elif algorithm == "sac":
        if not continuous:
            raise AlgorithmError("SAC needs a continuous action space")
        model = DeepRacerSAC(
            "CnnPolicy",
            env,
            learning_rate=hp.lr,
            buffer_size=SAC_BUFFER_STEPS,
            learning_starts=200,
            batch_size=hp.batch_size,
            gamma=hp.discount_factor,
            ent_coef=hp.sac_alpha if hp.sac_alpha > 0 else 1e-8,
            train_freq=(1, "step"),
            gradient_steps=1,
            policy_kwargs=sac_policy_kwargs(network),
            optimize_memory_usage=False,
            seed=seed,
            device="cpu",
            verbose=0,
        )
    else:
        raise AlgorithmError(f"unknown algorithm {algorithm!r}: use clipped_ppo or sac")
    model.loss_type = hp.loss_type
    return model


def load_model(
    algorithm: str,
    data: bytes,
    env: VecEnv,
    hp: Hyperparameters,
    *,
    network: str = LEAN,
    seed: int = 0,
) -> DeepRacerPPO | DeepRacerSAC:
    """A model built for ``env`` with the weights of a saved one (``model.save`` bytes), to
    train further or to drive. Nothing in ``data`` is unpickled (see training.rl.checkpoints)."""
    model = build_model(algorithm, env, hp, network=network, seed=seed)
    load_weights(model, data)
    return model


def set_torch_threads(threads: int) -> None:
    torch.set_num_threads(max(1, threads))
