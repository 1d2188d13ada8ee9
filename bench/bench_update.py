"""Where one PPO policy update's time goes, before and after the update's speed-ups.

One update of the racing preset's hyperparameters (10 epochs of minibatches of 32, 6 actions)
over a rollout of ``--steps`` camera frames (2,000 by default: 20 episodes of about 100 steps,
what the preset collects per update on re:Invent 2018), in five ways, measured in the same run
(the first four on the lean network, which the racing preset trained before the compact one):

- **SB3's path** (the baseline): every minibatch turns its raw 160×120 frames into floats and
  averages them to 80×60; Adam's loop of per-tensor steps (torch's ``foreach`` Adam);
- **prepared images**: the frames prepared once per update (training/rl/prepared.py);
- **+ fused Adam**: torch's fused Adam step as well (training/rl/algorithms.py
  ``adam_kwargs``);
- **+ channels-last convolutions**: the convolution weights in torch's channels-last layout
  (``build_model`` does this on a CPU, the console's default there; a GPU keeps the default
  layout, which an H100 ran faster: ``CHANNELS_LAST_DEVICES``);
- **the compact network**: the console's way on the racing preset's network now
  (training/rl/presets.py ``RACING.network``; 40×30, 16 and 16 filters, 128 units).

The frames are random pixels: an update's arithmetic does not depend on what the frames show.
Each way runs ``--repeats`` updates (after one to warm up); the table gives the median seconds
per update and per minibatch, then torch's profile of one update by operation: the baseline,
the console's way on the lean network (marked "now") and on the compact one, on ``--device``.
Last line: ``update_s=`` (the console's way on the racing preset's network)
``lean_update_s=`` (on the lean network) ``baseline_update_s=`` ``ratio=`` (update_s /
baseline), then what the update would gain on both cores while the simulators idle (issue 50):
``both_cores_update_s=`` (the compact network's update on as many torch threads as this
machine has cores, against ``--threads`` for the others), ``both_cores_ratio=`` (that /
update_s) and ``both_cores_same=`` (1 if its weights after an update from the same start and
data are bit for bit those on ``--threads`` threads; 0: a seed would take another path).

    .venv/bin/python bench/bench_update.py [--steps 2000] [--repeats 5] [--threads 2]
        [--device cpu|cuda] [--no-profile]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

os.environ.setdefault("OMP_NUM_THREADS", "2")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from gymnasium import spaces  # noqa: E402
from stable_baselines3.common.logger import Logger  # noqa: E402
from stable_baselines3.common.vec_env import DummyVecEnv  # noqa: E402

from training.rl.algorithms import ADAM_EPS, CHANNELS_LAST_DEVICES, build_model  # noqa: E402
from training.rl.policies import LEAN  # noqa: E402
from training.rl.presets import RACING  # noqa: E402

ENVS = 8  # the console's training cars


class Frames(gym.Env):
    """A stand-in with the car camera's observation space and the preset's actions."""

    observation_space = spaces.Box(0, 255, (120, 160, 1), np.uint8)
    action_space = spaces.Discrete(len(RACING.action_space))

    def reset(self, seed=None, options=None):
        return self.observation_space.sample(), {}

    def step(self, action):
        return self.observation_space.sample(), 0.0, False, False, {}


def make_model(way: str, device: str, network: str = LEAN):
    """The model of ``way`` (the module's list) on ``network``."""
    model = build_model("clipped_ppo", DummyVecEnv([Frames] * ENVS), RACING.hyperparameters,
                        device=device, network=network)  # fmt: skip
    model.set_logger(Logger(folder=None, output_formats=[]))
    if way == "baseline":
        model.prepare_images = False
    # The earlier ways keep the weights' default layout; the last takes channels-last anywhere.
    layout = torch.channels_last if way == "channels_last" else torch.contiguous_format
    model.policy.to(memory_format=layout)
    if way in ("baseline", "prepared"):  # Adam's per-tensor loop
        optimizer = model.policy.optimizer
        model.policy.optimizer = torch.optim.Adam(
            model.policy.parameters(), lr=optimizer.param_groups[0]["lr"], eps=ADAM_EPS
        )
    return model


def fill(model, steps: int, rng: np.random.Generator) -> None:
    """A complete rollout of ``steps`` frames in the model's buffer."""
    model.n_steps = 0
    model.set_rollout_steps(max(1, steps // ENVS))
    buffer = model.rollout_buffer
    buffer.observations[:] = rng.integers(0, 256, buffer.observations.shape, dtype=np.uint8)
    buffer.actions[:] = rng.integers(0, Frames.action_space.n, buffer.actions.shape)
    buffer.advantages[:] = rng.standard_normal(buffer.advantages.shape)
    buffer.returns[:] = rng.standard_normal(buffer.returns.shape)
    buffer.log_probs[:] = -np.log(Frames.action_space.n)
    buffer.values[:] = 0.0
    buffer.full, buffer.pos = True, buffer.buffer_size


def timed_update(model, steps: int, rng: np.random.Generator) -> float:
    fill(model, steps, rng)
    started = time.perf_counter()
    model.train()
    return time.perf_counter() - started


def profile(model, steps: int, rng: np.random.Generator, rows: int) -> str:
    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as torch_profile

    fill(model, steps, rng)
    with torch_profile(activities=[ProfilerActivity.CPU]) as prof:
        model.train()
    return prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=rows)


def both_cores(device: str, steps: int, repeats: int, threads: int, cores: int) -> tuple:
    """The compact network's update on ``cores`` threads: its median seconds (over
    ``repeats``, interleaved with ``threads`` threads), and whether one update from the same
    weights and data gives the same weights bit for bit on both counts."""
    network, way = RACING.network, console_way(device)

    def updated(count: int, seed: int) -> tuple[float, list[torch.Tensor]]:
        torch.set_num_threads(count)
        torch.manual_seed(seed)
        model = make_model(way, device, network)
        seconds = timed_update(model, steps, np.random.default_rng(seed))
        return seconds, [p.detach().clone() for p in model.policy.parameters()]

    try:
        updated(cores, 0)  # warm-up of the thread pool
        times, same = [], True
        for seed in range(repeats):
            _, one = updated(threads, seed)
            seconds, both = updated(cores, seed)
            times.append(seconds)
            same = same and all(torch.equal(a, b) for a, b in zip(one, both, strict=True))
    finally:
        torch.set_num_threads(threads)
    return statistics.median(times), same


def console_way(device: str) -> str:
    """The way a console job updates on ``device``: channels-last on a CPU only."""
    return "channels_last" if torch.device(device).type in CHANNELS_LAST_DEVICES else "fused"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--no-profile", action="store_true")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    rng = np.random.default_rng(0)
    frames = max(1, args.steps // ENVS) * ENVS
    batch = RACING.hyperparameters.batch_size
    minibatches = RACING.hyperparameters.num_epochs * -(-frames // batch)
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"torch {torch.__version__} on {args.device}, {args.threads} threads, "
          f"load average {os.getloadavg()[0]:.1f}")  # fmt: skip
    print(f"one update: {args.steps} frames, {minibatches} minibatches of {batch}, "
          f"median of {args.repeats}\n")  # fmt: skip
    ways = ("baseline", "prepared", "fused", "channels_last", "compact")
    now = console_way(args.device)
    labels = {"baseline": "SB3's path (before)", "prepared": "prepared images",
              "fused": "+ fused Adam", "channels_last": "+ channels-last convolutions",
              "compact": f"the compact network ({RACING.network}), the console's way"}  # fmt: skip
    labels[now] += " (now, the lean network)"
    models = {way: make_model(way, args.device) for way in ways[:-1]}
    models["compact"] = make_model(now, args.device, RACING.network)
    times: dict[str, list[float]] = {way: [] for way in ways}
    for way in ways:
        timed_update(models[way], args.steps, rng)  # warm-up
    for _ in range(args.repeats):  # interleaved, so that a busy moment hits every way alike
        for way in ways:
            times[way].append(timed_update(models[way], args.steps, rng))
    median = {way: statistics.median(times[way]) for way in ways}
    print("| way | s per update | ms per minibatch | vs before |\n|---|---|---|---|")
    for way in ways:
        print(f"| {labels[way]} | {median[way]:.2f} | {median[way] / minibatches * 1000:.1f} | "
              f"{median[way] / median['baseline']:.2f} |")  # fmt: skip
    cores = os.cpu_count() or 1
    both_s, same = both_cores(args.device, args.steps, args.repeats, args.threads, cores)
    weights = "bit for bit the same" if same else "not the same (another path per seed)"
    print(f"\nthe compact network's update on {cores} threads (all cores) against "
          f"{args.threads}: {both_s:.2f} against {median['compact']:.2f} s, "
          f"weights {weights}")  # fmt: skip
    print(f"\nload average after: {os.getloadavg()[0]:.1f}")
    if not args.no_profile:
        for way in ("baseline", now, "compact"):
            print(f"\nprofile of one update, {labels[way]}:")
            print(profile(models[way], args.steps, rng, 14))
    print(f"update_s={median['compact']:.3f} lean_update_s={median[now]:.3f} "
          f"baseline_update_s={median['baseline']:.3f} "
          f"ratio={median['compact'] / median['baseline']:.2f} "
          f"both_cores_update_s={both_s:.3f} "
          f"both_cores_ratio={both_s / median['compact']:.2f} "
          f"both_cores_same={int(same)}")  # fmt: skip


if __name__ == "__main__":
    main()
