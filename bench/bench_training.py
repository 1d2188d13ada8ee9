"""Wall time for a fresh model to drive three clean 3-lap evaluations in a row.

Trains from scratch the way a user's job does: camera observations, DeepRacer's default
discrete action space shape (5 steering angles x 2 speeds), PPO, the reward below running
inside the sandboxed rollout workers, and after every policy update one evaluation of 3
consecutive laps from the start line (the clock includes those evaluations). Stops when three
evaluations in a row each complete 3 laps, or at the time limit.

Runs each track with Racecraft's lean default network and with DeepRacer's 3-layer CNN; the
ratio is the 3-layer CNN's time over the default's (both measured in this run).

    .venv/bin/python bench/bench_training.py [--tracks racecraft_summit reinvent_base]
        [--networks RACECRAFT_LEAN_CNN DEEP_CONVOLUTIONAL_NETWORK_SHALLOW] [--minutes 6]

reinvent_base is read from ../shared/tracks (DeepRacer's re:Invent 2018 track) when present.
Last line: ``default_s=… cnn3_s=… ratio=…`` (sums over the tracks; goal: default ≤ 120 s each).
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "2")

from training.rl.hyperparams import Hyperparameters  # noqa: E402
from training.rl.policies import LEAN, SHALLOW  # noqa: E402
from training.rl.runner import IterationResult, TrainingConfig, TrainingHooks, train  # noqa: E402
from training.rollout.backends import LocalRollouts  # noqa: E402
from training.rollout.envs import EnvSpec  # noqa: E402

SHARED = Path(__file__).resolve().parents[2] / "shared" / "tracks"
ACTIONS = [{"steering_angle": a, "speed": v} for a in (-30, -15, 0, 15, 30) for v in (1.5, 3.0)]

# Pays the speed made good along the track, more near the centre line; nearly nothing off it.
REWARD = """
import math

def reward_function(params):
    if params["is_offtrack"] or not params["all_wheels_on_track"]:
        return 1e-3
    waypoints = params["waypoints"]
    behind, ahead = params["closest_waypoints"]
    dx = waypoints[ahead][0] - waypoints[behind][0]
    dy = waypoints[ahead][1] - waypoints[behind][1]
    error = math.radians(params["heading"]) - math.atan2(dy, dx)
    along = params["speed"] * math.cos(error)
    centre = 1.0 - params["distance_from_center"] / (params["track_width"] / 2)
    return max(1e-3, along * (0.5 + 0.5 * centre))
"""


@dataclass
class Run:
    track: str
    network: str
    seconds: float | None = None
    iterations: int = 0
    steps: int = 0
    lap_times: list[list[float]] = field(default_factory=list)
    rollout_s: float = 0.0
    update_s: float = 0.0
    eval_s: float = 0.0
    wall_s: float = 0.0


class UntilThreeCleanEvaluations(TrainingHooks):
    def __init__(self, run: Run) -> None:
        self.run = run
        self.streak: list[list[float]] = []

    def on_iteration(self, result: IterationResult, checkpoint: bytes, rows: list) -> None:
        run = self.run
        run.iterations = result.iteration
        run.steps = result.total_steps
        run.rollout_s += result.rollout_s
        run.update_s += result.update_s
        run.eval_s += result.eval_s
        ev = result.evaluation
        self.streak = self.streak + ev.lap_times if ev.all_laps_complete else []
        if len(self.streak) >= 3 and run.seconds is None:
            run.seconds = result.elapsed_s
            run.lap_times = self.streak[-3:]
        print(
            f"  it {result.iteration:3d} t={result.elapsed_s:6.1f}s steps={result.total_steps:6d} "
            f"train progress {result.train_progress:5.1f}%  eval {ev.mean_progress:5.1f}% "
            f"{ev.statuses[0] if ev.statuses else ''}",
            flush=True,
        )

    def should_stop(self) -> bool:
        return self.run.seconds is not None


def track_spec(name: str, scratch: Path) -> EnvSpec:
    shared = SHARED / f"{name}.npy"
    if shared.exists():  # a DeepRacer file: import it into a scratch catalogue folder
        shutil.copy(shared, scratch / shared.name)
        return EnvSpec(track=name, track_dirs=(str(scratch),), action_space=ACTIONS)
    return EnvSpec(track=name, action_space=ACTIONS)


BENCH_HYPERPARAMETERS = Hyperparameters(
    batch_size=64, num_epochs=10, lr=3e-4, discount_factor=0.99, num_episodes_between_training=20
)
"""The benchmarks' PPO settings (this one and bench_imported.py train with the same)."""


def run_one(track: str, network: str, minutes: float, scratch: Path, seed: int) -> Run:
    run = Run(track, network)
    config = TrainingConfig(
        spec=track_spec(track, scratch),
        network=network,
        hyperparameters=BENCH_HYPERPARAMETERS,
        max_minutes=minutes,
        reward_source=REWARD,
        num_envs=8,
        rollouts=LocalRollouts(num_workers=2),
        seed=seed,
        eval_episodes=1,
        eval_laps=3,
        eval_from_start_line=True,
    )
    start = time.monotonic()
    train(config, UntilThreeCleanEvaluations(run))
    run.wall_s = time.monotonic() - start
    return run


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tracks", nargs="+", default=["racecraft_summit", "reinvent_base"])
    parser.add_argument("--networks", nargs="+", default=[LEAN, SHALLOW])
    parser.add_argument("--minutes", type=float, default=6.0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    runs: list[Run] = []
    with tempfile.TemporaryDirectory() as tmp:
        for track in args.tracks:
            for network in args.networks:
                print(f"{track} / {network}", flush=True)
                runs.append(run_one(track, network, args.minutes, Path(tmp), args.seed))

    print()
    header = (
        f"{'track':<18}{'network':<36}{'to 3x3 laps':>12}{'iters':>7}{'steps':>8}"
        f"{'rollout':>9}{'update':>8}{'eval':>7}  lap times of the 3 evaluations (s)"
    )
    print(header)
    for r in runs:
        took = f"{r.seconds:.1f} s" if r.seconds is not None else f">{r.wall_s:.0f} s"
        laps = "; ".join(" ".join(f"{t:.2f}" for t in ev) for ev in r.lap_times) or "-"
        print(f"{r.track:<18}{r.network:<36}{took:>12}{r.iterations:>7}{r.steps:>8}"
              f"{r.rollout_s:>8.1f}s{r.update_s:>7.1f}s{r.eval_s:>6.1f}s  {laps}")  # fmt: skip

    def total(network: str) -> float | None:
        times = [r.seconds for r in runs if r.network == network]
        return None if not times or None in times else sum(times)  # type: ignore[arg-type]

    lean, cnn3 = total(LEAN), total(SHALLOW)
    fmt = lambda v: "nan" if v is None else f"{v:.1f}"  # noqa: E731
    ratio = "nan" if lean is None or cnn3 is None else f"{cnn3 / lean:.2f}"
    print(f"default_s={fmt(lean)} cnn3_s={fmt(cnn3)} ratio={ratio}")


if __name__ == "__main__":
    main()
