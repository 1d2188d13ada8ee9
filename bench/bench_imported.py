"""How well real AWS-trained DeepRacer models drive in Racecraft's simulator, next to a model
trained here.

The AWS models are the sample model of deepracer-utils 1.5.6 (its tests' ``model_<n>.pb``, three
checkpoints of one 3-layer-CNN PPO model trained on AWS, with its ``model_metadata.json``),
fetched once with pip into ``var/cache`` and imported as car archives through
:mod:`training.interchange.deepracer`. The Racecraft model is a lean-network PPO trained here
from scratch for a fixed budget of environment steps (``--steps``) on the same track, with the
AWS model's action space and a simple progress reward (stay on the track, near the centre line).

Every model drives the same episodes on re:Invent 2018 (``reinvent_base``, built in:
``racing/tracks/deepracer/``), both directions, ``--episodes`` per direction from start points
spread evenly round the lap, with the deterministic policy and training's episode rules (one lap, no
resets: an episode ends off track, reversed, immobilized or at the lap). The figures are
progress and steps, not times: they do not depend on the machine's load.

    .venv/bin/python bench/bench_imported.py [--episodes 8] [--steps 3000] [--seed 0]
        [--tracks-dir DIR]

Last line: ``aws_median_progress=… racecraft_median_progress=… ratio=…`` (the AWS models'
median episode progress over all their episodes, the Racecraft model's, and AWS / Racecraft).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "2")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # tests.training.interchange.deepracer_support fetches the samples

import numpy as np  # noqa: E402
import torch  # noqa: E402

from racing.env import RacingEnv  # noqa: E402
from racing.rules import Status  # noqa: E402
from racing.track import Track  # noqa: E402
from racing.tracks import DEEPRACER_DIR  # noqa: E402
from training.interchange.deepracer import import_car_archive  # noqa: E402
from training.interchange.tarball import deterministic_tar_gz  # noqa: E402
from training.rl.checkpoints import load_checkpoint  # noqa: E402
from training.rl.policies import LEAN  # noqa: E402
from training.rl.presets import RACING  # noqa: E402 - the racing preset's PPO settings
from training.rl.runner import IterationResult, TrainingConfig, TrainingHooks, train  # noqa: E402
from training.rollout.backends import LocalRollouts  # noqa: E402
from training.rollout.envs import EnvSpec  # noqa: E402

SHARED = DEEPRACER_DIR  # DeepRacer's track files, built in
TRACK = "reinvent_base"
DIRECTIONS = ("ccw", "cw")

# The simple progress reward: on the track, more near the centre line; nearly nothing off it.
REWARD = """
def reward_function(params):
    if params["is_offtrack"] or not params["all_wheels_on_track"]:
        return 1e-3
    half = params["track_width"] / 2
    return max(1e-3, 1.0 - (params["distance_from_center"] / half) ** 2)
"""


@dataclass
class Drive:
    """One model's episodes: progress (%) and steps of each, whether the lap was completed."""

    name: str
    progress: list[float] = field(default_factory=list)
    steps: list[int] = field(default_factory=list)
    laps: int = 0
    by_direction: dict[str, list[float]] = field(default_factory=dict)


def aws_models():
    """(name, SB3 model, action space) of each AWS sample checkpoint, imported as car models."""
    from tests.training.interchange.deepracer_support import aws_samples

    samples = aws_samples()
    for iteration, graph in sorted(samples.graphs.items()):
        upload = deterministic_tar_gz(
            {"agent/model.pb": graph, "model_metadata.json": samples.metadata}
        )
        imported = import_car_archive(upload)
        model = load_checkpoint(imported.checkpoint_bytes, imported.metadata)
        yield f"aws model_{iteration}.pb", model, imported.metadata.actions.to_metadata()


def drive(name: str, model, actions, track: Track, episodes: int) -> Drive:
    result = Drive(name)
    for direction in DIRECTIONS:
        env = RacingEnv(track, direction=direction, action_space=actions, start="start_line")
        got = result.by_direction.setdefault(direction, [])
        try:
            for i in range(episodes):
                obs, _ = env.reset(seed=i, options={"start_progress": 100.0 * i / episodes})
                steps = 0
                while True:
                    action, _ = model.predict(obs, deterministic=True)
                    obs, _, terminated, truncated, info = env.step(action)
                    steps += 1
                    if terminated or truncated:
                        break
                done = info["status"] == Status.LAP_COMPLETE.value
                progress = 100.0 if done else float(info["progress"])
                result.progress.append(progress)
                result.steps.append(steps)
                result.laps += int(done)
                got.append(progress)
        finally:
            env.close()
    return result


class StepBudget(TrainingHooks):
    def __init__(self, budget: int) -> None:
        self.budget = budget
        self.steps = 0
        self.checkpoint: bytes | None = None

    def on_iteration(self, result: IterationResult, checkpoint: bytes, rows: list) -> None:
        self.steps = result.total_steps
        self.checkpoint = checkpoint
        print(
            f"  it {result.iteration:3d} steps={result.total_steps:6d} "
            f"train progress {result.train_progress:5.1f}%  eval {result.eval_progress:5.1f}%",
            flush=True,
        )

    def should_stop(self) -> bool:
        return self.steps >= self.budget


def train_racecraft(actions, budget: int, seed: int, scratch: Path, metadata_of, tracks: Path):
    shutil.copy(tracks / f"{TRACK}.npy", scratch / f"{TRACK}.npy")
    spec = EnvSpec(
        track=TRACK, track_dirs=(str(scratch),), action_space=actions, alternate_direction=True
    )
    config = TrainingConfig(
        spec=spec,
        network=LEAN,
        hyperparameters=RACING.hyperparameters,
        max_minutes=30.0,  # a safety net: the step budget stops it
        reward_source=REWARD,
        num_envs=8,
        rollouts=LocalRollouts(num_workers=2),
        seed=seed,
        eval_episodes=1,
    )
    hooks = StepBudget(budget)
    started = time.monotonic()
    train(config, hooks)
    print(f"  trained {hooks.steps} steps in {time.monotonic() - started:.0f} s", flush=True)
    return load_checkpoint(hooks.checkpoint, metadata_of(LEAN)), hooks.steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=8, help="per direction")
    parser.add_argument("--steps", type=int, default=3_000, help="Racecraft training budget")
    parser.add_argument("--tracks-dir", type=Path, default=SHARED, help="holds reinvent_base.npy")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-train", action="store_true", help="only the AWS models")
    parser.add_argument("--no-aws", action="store_true", help="only the model trained here")
    args = parser.parse_args()
    torch.set_num_threads(2)
    track = Track.from_file(args.tracks_dir / f"{TRACK}.npy")

    drives: list[Drive] = []
    actions = None
    for name, model, model_actions in aws_models():
        actions = model_actions  # the Racecraft model gets the AWS model's action space
        if args.no_aws:
            break
        print(f"{name}: driving", flush=True)
        drives.append(drive(name, model, model_actions, track, args.episodes))
    aws = list(drives)

    trained_steps = 0
    if not args.no_train:
        from training.rl.metadata import build_metadata

        def metadata_of(network: str):
            return build_metadata(action_space=actions, neural_network=network)

        print(f"racecraft lean PPO: training {args.steps} steps on {TRACK}", flush=True)
        with tempfile.TemporaryDirectory() as tmp:
            model, trained_steps = train_racecraft(
                actions, args.steps, args.seed, Path(tmp), metadata_of, args.tracks_dir
            )
        drives.append(
            drive(f"racecraft lean {trained_steps // 1000}k", model, actions, track, args.episodes)
        )

    print()
    print(
        f"{'model':<22}{'episodes':>9}{'median %':>10}{'max %':>8}{'laps':>6}"
        f"{'ccw med %':>11}{'cw med %':>10}{'median steps':>14}  progress per episode"
    )
    for d in drives:
        per = " ".join(f"{p:.0f}" for p in d.progress)
        print(
            f"{d.name:<22}{len(d.progress):>9}{np.median(d.progress):>10.1f}"
            f"{max(d.progress):>8.1f}{d.laps:>6}{np.median(d.by_direction['ccw']):>11.1f}"
            f"{np.median(d.by_direction['cw']):>10.1f}{np.median(d.steps):>14.0f}  {per}"
        )
    aws_progress = [p for d in aws for p in d.progress] or [float("nan")]
    aws_median = float(np.median(aws_progress))
    aws_laps = sum(d.laps for d in aws)
    line = f"aws_median_progress={aws_median:.1f} aws_max_progress="
    line += f"{max(aws_progress):.1f} aws_laps={aws_laps}"
    if len(drives) > len(aws):
        ours = drives[-1]
        ours_median = float(np.median(ours.progress))
        ratio = aws_median / ours_median if ours_median else float("nan")
        line += (
            f" racecraft_median_progress={ours_median:.1f} racecraft_laps={ours.laps}"
            f" racecraft_steps={trained_steps} ratio={ratio:.2f}"
        )
    print(line)


if __name__ == "__main__":
    main()
