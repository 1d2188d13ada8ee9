"""DeepRacer's hyperparameters mapped onto stable-baselines3's PPO and SAC.

PPO: ``batch_size`` → batch_size, ``num_epochs`` → n_epochs, ``lr`` → learning_rate,
``beta_entropy`` → ent_coef, ``discount_factor`` → gamma, clip 0.2, GAE λ 0.95, Adam ε 1e-5
(DeepRacer's fixed internals), ``loss_type`` → the value loss (Huber or mean squared error).
``num_episodes_between_training`` sets how many episodes each policy update learns from: the
rollout length is re-planned before every update from the average episode length so far.

The trainer's networks live on the device :func:`resolve_device` picks (``auto``: the GPU
when the worker has one, else the CPU); everything else (evaluation jobs, imports, exports,
the simulation side) builds its models on the CPU, the default of :func:`build_model`.

SAC (continuous actions only): ``sac_alpha`` → a fixed ent_coef, ``loss_type`` → the critic
loss, a replay buffer of recent steps, τ = 0.005 (SB3's soft update; DeepRacer's rl_coach used
hard copies, which SB3 does not offer for SAC).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch
import torch.nn.functional as F
from gymnasium import spaces
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.utils import explained_variance, polyak_update
from stable_baselines3.common.vec_env import VecEnv

from training.rl.checkpoints import load_weights
from training.rl.hyperparams import Hyperparameters
from training.rl.policies import LEAN, policy_kwargs, policy_type, sac_policy_kwargs
from training.rl.prepared import evaluate_prepared, preparable, prepare_rollout

# SB3 builds a torch distribution for every step of a rollout and every minibatch of an
# update, and by default torch checks its arguments each time (is every logit a real number,
# is the action one of the categories): 0.1 ms of the 1.07 ms that choosing 8 cars' actions
# took. The networks give real numbers or NaN (a diverged policy), and torch's sampling
# refuses NaN probabilities on its own; the actions come from the action space.
torch.distributions.Distribution.set_default_validate_args(False)

CLIP_RANGE = 0.2
GAE_LAMBDA = 0.95
ADAM_EPS = 1e-5
MIN_ROLLOUT_STEPS = 16
MAX_ROLLOUT_STEPS = 2048
SAC_BUFFER_STEPS = 20_000


class AlgorithmError(ValueError):
    """An algorithm that does not fit the action space."""


class DeviceError(ValueError):
    """A torch device that is misspelt or that this machine does not have."""


def resolve_device(name: str = "auto") -> torch.device:
    """The torch device for ``name``: ``auto`` (CUDA when torch sees a GPU, else the CPU),
    ``cpu``, ``cuda``, ``cuda:<n>``, ``mps`` or any other torch device string.

    Raises :class:`DeviceError` for a string torch cannot read, or a GPU this machine lacks
    (asked for explicitly, a missing GPU is an error, never a silent fall-back to the CPU).
    """
    name = (name or "auto").strip().lower()
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except (RuntimeError, ValueError):
        raise DeviceError(
            f"{name!r} is not a torch device: use auto, cpu, cuda or cuda:<n>"
        ) from None
    if device.type == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise DeviceError(f"{name!r}: this machine has no CUDA GPU (use auto or cpu)")
        if device.index is not None and device.index >= count:
            raise DeviceError(f"{name!r}: this machine has {count} CUDA GPU(s)")
    elif device.type == "mps" and not torch.backends.mps.is_available():
        raise DeviceError(f"{name!r}: this machine has no Apple GPU (use auto or cpu)")
    return device


def value_loss(loss_type: str, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """DeepRacer's ``loss_type`` between values and their targets (same shapes), a scalar.

    ``huber`` is the Huber loss with δ = 1 (``smooth_l1_loss``), ``mean_squared_error`` the
    mean squared error SB3 uses; both are means over the elements and symmetric in a and b
    (the callers pass them in SB3's order, so that its float results are matched exactly).
    """
    if loss_type == "huber":
        return F.smooth_l1_loss(a, b)
    return F.mse_loss(a, b)


class DeepRacerPPO(PPO):
    """SB3's PPO with DeepRacer's loss switch and a rollout length that can change.

    SB3 has no hook for the value loss (``PPO.train`` calls ``F.mse_loss`` inline), so
    ``train`` is SB3 2.9's own, step for step, with the value loss from ``value_loss``; with
    ``mean_squared_error`` an update is exactly SB3's (tests/training/rl/test_algorithms.py holds
    both to that, so an SB3 upgrade that changes its update shows up there).
    """

    loss_type = "huber"
    prepare_images = True
    """Prepare the camera images once per update (:mod:`training.rl.prepared`); False runs
    SB3's own path, which gives the same numbers (bench/bench_update.py's baseline)."""
    between_minibatches: Callable[[], bool] | None = None
    """Called after each minibatch's step of an update; True ends the update there (the loop
    was stopped: what it learnt is not kept). The training loop hands back an evaluation that
    ran beside the update through it."""

    def _excluded_save_params(self) -> list[str]:
        # The hook is the loop's, not the model's: never saved with it.
        return [*super()._excluded_save_params(), "between_minibatches"]

    def train(self) -> None:
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        clip_range = self.clip_range(self._current_progress_remaining)
        if self.clip_range_vf is not None:
            clip_range_vf = self.clip_range_vf(self._current_progress_remaining)
        entropy_losses, pg_losses, value_losses, clip_fractions = [], [], [], []
        continue_training = True
        prepared = self.prepare_images and preparable(self.policy)
        if prepared:
            prepare_rollout(self.policy, self.rollout_buffer)
        for _ in range(self.n_epochs):
            approx_kl_divs = []
            for rollout_data in self.rollout_buffer.get(self.batch_size):
                actions = rollout_data.actions
                if isinstance(self.action_space, spaces.Discrete):
                    actions = rollout_data.actions.long().flatten()
                if prepared:
                    values, log_prob, entropy = evaluate_prepared(
                        self.policy, rollout_data.observations, actions
                    )
                else:
                    values, log_prob, entropy = self.policy.evaluate_actions(
                        rollout_data.observations, actions
                    )
                values = values.flatten()
                advantages = rollout_data.advantages
                if self.normalize_advantage and len(advantages) > 1:
                    advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
                ratio = torch.exp(log_prob - rollout_data.old_log_prob)
                policy_loss_1 = advantages * ratio
                policy_loss_2 = advantages * torch.clamp(ratio, 1 - clip_range, 1 + clip_range)
                policy_loss = -torch.min(policy_loss_1, policy_loss_2).mean()
                pg_losses.append(policy_loss.item())
                clip_fractions.append(
                    torch.mean((torch.abs(ratio - 1) > clip_range).float()).item()
                )
                if self.clip_range_vf is None:
                    values_pred = values
                else:
                    values_pred = rollout_data.old_values + torch.clamp(
                        values - rollout_data.old_values, -clip_range_vf, clip_range_vf
                    )
                loss_v = value_loss(self.loss_type, rollout_data.returns, values_pred)
                value_losses.append(loss_v.item())
                # Without an analytical entropy, -log_prob estimates it.
                entropy_loss = -torch.mean(-log_prob if entropy is None else entropy)
                entropy_losses.append(entropy_loss.item())
                loss = policy_loss + self.ent_coef * entropy_loss + self.vf_coef * loss_v
                with torch.no_grad():
                    log_ratio = log_prob - rollout_data.old_log_prob
                    approx_kl_div = torch.mean((torch.exp(log_ratio) - 1) - log_ratio).cpu().numpy()
                    approx_kl_divs.append(approx_kl_div)
                if self.target_kl is not None and approx_kl_div > 1.5 * self.target_kl:
                    continue_training = False
                    break
                self.policy.optimizer.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
                self.policy.optimizer.step()
                if self.between_minibatches is not None and self.between_minibatches():
                    continue_training = False
                    break
            self._n_updates += 1
            if not continue_training:
                break
        # SB3 keeps the last minibatch's distribution, and with it that minibatch's autograd
        # graph: drop it (a copy of the policy, for the live view, cannot copy a graph).
        if hasattr(self.policy.action_dist, "distribution"):
            self.policy.action_dist.distribution = None

        explained_var = explained_variance(
            self.rollout_buffer.values.flatten(), self.rollout_buffer.returns.flatten()
        )
        self.logger.record("train/entropy_loss", np.mean(entropy_losses))
        self.logger.record("train/policy_gradient_loss", np.mean(pg_losses))
        self.logger.record("train/value_loss", np.mean(value_losses))
        self.logger.record("train/approx_kl", np.mean(approx_kl_divs))
        self.logger.record("train/clip_fraction", np.mean(clip_fractions))
        self.logger.record("train/loss", loss.item())
        self.logger.record("train/explained_variance", explained_var)
        if hasattr(self.policy, "log_std"):
            self.logger.record("train/std", torch.exp(self.policy.log_std).mean().item())
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/clip_range", clip_range)
        if self.clip_range_vf is not None:
            self.logger.record("train/clip_range_vf", clip_range_vf)

    def set_rollout_steps(self, n_steps: int) -> None:
        """Collect ``n_steps`` per env before the next update (a new buffer if it changes)."""
        if n_steps == self.n_steps:
            return
        self.n_steps = n_steps
        # SB3 picked the buffer class for the observation space (a Dict one with a LIDAR).
        self.rollout_buffer = self.rollout_buffer_class(
            n_steps,
            self.observation_space,
            self.action_space,
            device=self.device,
            gamma=self.gamma,
            gae_lambda=self.gae_lambda,
            n_envs=self.n_envs,
            **self.rollout_buffer_kwargs,
        )


class DeepRacerSAC(SAC):
    """SB3's SAC with DeepRacer's loss switch for the critics.

    As with PPO, ``train`` is SB3 2.9's own with the critic loss from ``value_loss``.
    """

    loss_type = "mean_squared_error"

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        self.policy.set_training_mode(True)
        optimizers = [self.actor.optimizer, self.critic.optimizer]
        if self.ent_coef_optimizer is not None:
            optimizers += [self.ent_coef_optimizer]
        self._update_learning_rate(optimizers)
        ent_coef_losses, ent_coefs, actor_losses, critic_losses = [], [], [], []

        for gradient_step in range(gradient_steps):
            replay_data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)
            discounts = replay_data.discounts if replay_data.discounts is not None else self.gamma
            if self.use_sde:
                self.actor.reset_noise()
            actions_pi, log_prob = self.actor.action_log_prob(replay_data.observations)
            log_prob = log_prob.reshape(-1, 1)

            ent_coef_loss = None
            if self.ent_coef_optimizer is not None and self.log_ent_coef is not None:
                ent_coef = torch.exp(self.log_ent_coef.detach())
                ent_coef_loss = -(
                    self.log_ent_coef * (log_prob + self.target_entropy).detach()
                ).mean()
                ent_coef_losses.append(ent_coef_loss.item())
            else:
                ent_coef = self.ent_coef_tensor
            ent_coefs.append(ent_coef.item())
            if ent_coef_loss is not None and self.ent_coef_optimizer is not None:
                self.ent_coef_optimizer.zero_grad()
                ent_coef_loss.backward()
                self.ent_coef_optimizer.step()

            with torch.no_grad():
                next_actions, next_log_prob = self.actor.action_log_prob(
                    replay_data.next_observations
                )
                next_q_values = torch.cat(
                    self.critic_target(replay_data.next_observations, next_actions), dim=1
                )
                next_q_values, _ = torch.min(next_q_values, dim=1, keepdim=True)
                next_q_values = next_q_values - ent_coef * next_log_prob.reshape(-1, 1)
                target_q_values = (
                    replay_data.rewards + (1 - replay_data.dones) * discounts * next_q_values
                )
            current_q_values = self.critic(replay_data.observations, replay_data.actions)
            critic_loss = 0.5 * sum(
                value_loss(self.loss_type, current_q, target_q_values)
                for current_q in current_q_values
            )
            critic_losses.append(critic_loss.item())
            self.critic.optimizer.zero_grad()
            critic_loss.backward()
            self.critic.optimizer.step()

            q_values_pi = torch.cat(self.critic(replay_data.observations, actions_pi), dim=1)
            min_qf_pi, _ = torch.min(q_values_pi, dim=1, keepdim=True)
            actor_loss = (ent_coef * log_prob - min_qf_pi).mean()
            actor_losses.append(actor_loss.item())
            self.actor.optimizer.zero_grad()
            actor_loss.backward()
            self.actor.optimizer.step()

            if gradient_step % self.target_update_interval == 0:
                polyak_update(self.critic.parameters(), self.critic_target.parameters(), self.tau)
                polyak_update(self.batch_norm_stats, self.batch_norm_stats_target, 1.0)

        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/ent_coef", np.mean(ent_coefs))
        self.logger.record("train/actor_loss", np.mean(actor_losses))
        self.logger.record("train/critic_loss", np.mean(critic_losses))
        if len(ent_coef_losses) > 0:
            self.logger.record("train/ent_coef_loss", np.mean(ent_coef_losses))


def adam_kwargs(device: torch.device | str) -> dict:
    """Adam's settings: DeepRacer's ε, and torch's fused Adam on a CPU or a CUDA GPU.

    The fused step does the same arithmetic in one pass over each weight instead of a dozen
    (the lean network's 400,000 weights: 0.3 against 2.6 ms a minibatch on 2 CPU threads,
    bench/bench_update.py); its float rounding differs from the loop's in the last bit, so a
    seed learns along a slightly different path than it did before.
    """
    kwargs: dict = {"eps": ADAM_EPS}
    if torch.device(device).type in ("cpu", "cuda"):
        kwargs["fused"] = True
    return kwargs


def warm_up() -> None:
    """Load now what the first model of a process would wait for: the first optimizer that
    torch builds in a process imports ``torch._dynamo`` (about 70 MB; 1.0-1.7 s on a 2-core
    AMD EPYC), whatever the model. A job worker's process calls this when it starts
    (training/tasks.py), so a user's first job after the console starts does not wait."""
    torch.optim.Adam([torch.zeros(1, requires_grad=True)], **adam_kwargs("cpu"))


def plan_rollout_steps(episodes: int, mean_episode_steps: float, num_envs: int) -> int:
    """Steps per env so that about ``episodes`` episodes finish before the next update."""
    steps = math.ceil(episodes * max(mean_episode_steps, 1.0) / num_envs)
    return int(min(MAX_ROLLOUT_STEPS, max(MIN_ROLLOUT_STEPS, steps)))


CHANNELS_LAST_DEVICES = ("cpu",)
"""Where :func:`build_model` puts the convolution weights in torch's channels-last layout: the
same numbers (torch picks other kernels; the lean network's forward and gradients come out bit
for bit equal), about half the time of a convolution on a CPU. On an H100 (cuDNN) an update
took longer with it (1.88 against 1.63 s, ``bench/bench_update.py --device cuda``), so a GPU
keeps the default layout. The parameters stay the same objects, so the optimizer keeps them;
checkpoints load into either layout."""


def build_model(
    algorithm: str,
    env: VecEnv,
    hp: Hyperparameters,
    *,
    network: str = LEAN,
    seed: int = 0,
    initial_steps: int = 64,
    device: torch.device | str = "cpu",
) -> DeepRacerPPO | DeepRacerSAC:
    """A new SB3 model for ``algorithm`` (``clipped_ppo`` or ``sac``) on ``env``, its
    networks on ``device`` (the trainer passes :func:`resolve_device`'s choice)."""
    continuous = not hasattr(env.action_space, "n")
    if algorithm == "clipped_ppo":
        kwargs = policy_kwargs(network, env.observation_space)
        kwargs["optimizer_kwargs"] = adam_kwargs(device)
        model = DeepRacerPPO(
            policy_type(env.observation_space),
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
            device=device,
            verbose=0,
        )
    elif algorithm == "sac":
        if not continuous:
            raise AlgorithmError("SAC needs a continuous action space")
        model = DeepRacerSAC(
            policy_type(env.observation_space),
            env,
            learning_rate=hp.lr,
            buffer_size=SAC_BUFFER_STEPS,
            learning_starts=200,
            batch_size=hp.batch_size,
            gamma=hp.discount_factor,
            ent_coef=hp.sac_alpha if hp.sac_alpha > 0 else 1e-8,
            train_freq=(1, "step"),
            gradient_steps=1,
            policy_kwargs=sac_policy_kwargs(network, env.observation_space),
            optimize_memory_usage=False,
            seed=seed,
            device=device,
            verbose=0,
        )
    else:
        raise AlgorithmError(f"unknown algorithm {algorithm!r}: use clipped_ppo or sac")
    model.loss_type = hp.loss_type
    if model.device.type in CHANNELS_LAST_DEVICES:
        model.policy.to(memory_format=torch.channels_last)
    return model


def load_model(
    algorithm: str,
    data: bytes,
    env: VecEnv,
    hp: Hyperparameters,
    *,
    network: str = LEAN,
    seed: int = 0,
    device: torch.device | str = "cpu",
) -> DeepRacerPPO | DeepRacerSAC:
    """A model built for ``env`` on ``device`` with the weights of a saved one (``model.save``
    bytes, saved on any device), to train further or to drive. Nothing in ``data`` is
    unpickled (see training.rl.checkpoints)."""
    model = build_model(algorithm, env, hp, network=network, seed=seed, device=device)
    load_weights(model, data)
    return model


def set_torch_threads(threads: int) -> None:
    torch.set_num_threads(max(1, threads))
