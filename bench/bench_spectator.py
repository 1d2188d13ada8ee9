"""What a viewer costs a lockstep training run: the same run with nobody watching and watched.

While someone watches a lockstep job (the console's default), the trainer drives the
evaluation env with a frozen copy of the policy during every policy update (the "spare lap"
that keeps the live view going, :class:`training.rollout.lockstep.Spectator`), and the training envs
render a frame per step. Both take cycles from the update on a 2-core machine. This bench runs
each seed twice in one process, unwatched then watched, with the console's defaults otherwise
(:func:`bench_training.run_one`'s configuration: DeepRacer's defaults or the racing preset, 8
cars in 2 sandboxed workers). Lockstep is deterministic, so a seed drives the same steps both
times (the table checks it): the update seconds differ only by what watching takes. The frames
are counted, not shown: a viewer on another machine, no browser here.

    .venv/bin/python bench/bench_spectator.py [--setup defaults|fast] [--iterations 6]
                                              [--seeds 3] [--track reinvent_base]

Prints per seed the steps, the update, rollout and evaluation seconds of both runs and the
frames the watched run delivered (frames/s over its training time), then the medians over the
seeds. Last line: ``unwatched_update_s=… watched_update_s=… watched_fps=… ratio=…`` (medians of
the total update seconds per run; ratio = watched / unwatched, what watching costs the update).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "2")
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_training import SHARED, Setup, machine, rollouts, track_spec  # noqa: E402

from training.rewards.examples import example_source  # noqa: E402
from training.rl.presets import DEEPRACER_DEFAULTS, RACING  # noqa: E402
from training.rl.runner import (  # noqa: E402
    IterationResult,
    TrainingConfig,
    TrainingHooks,
    train,
)


@dataclass
class Watch:
    """One run: its iterations' figures and, watched, the frames it delivered."""

    watched: bool
    steps: list[int] = field(default_factory=list)
    update_s: float = 0.0
    rollout_s: float = 0.0
    eval_s: float = 0.0
    frames: int = 0
    spare_frames: int = 0
    train_s: float = 0.0


class Hooks(TrainingHooks):
    """Stops after ``iterations``; watched, wants every frame and counts them."""

    def __init__(self, run: Watch, iterations: int) -> None:
        self.run, self.iterations = run, iterations

    def frames_wanted(self) -> bool:
        return self.run.watched

    def on_frame(self, frame: dict) -> None:
        self.run.frames += 1
        self.run.spare_frames += bool(frame.get("spare"))

    def on_iteration(self, result: IterationResult, checkpoint: bytes, rows: list) -> None:
        run = self.run
        run.steps.append(result.total_steps)
        run.update_s += result.update_s
        run.rollout_s += result.rollout_s
        run.eval_s += result.eval_s

    def should_stop(self) -> bool:
        return len(self.run.steps) >= self.iterations


def run_once(setup: Setup, seed: int, watched: bool, args: argparse.Namespace,
             scratch: Path) -> Watch:  # fmt: skip
    preset = setup.preset
    config = TrainingConfig(
        spec=track_spec(args.track, args.tracks_dir, scratch, preset),
        algorithm=preset.algorithm, network=preset.network,
        hyperparameters=preset.hyperparameters, max_minutes=30.0,
        reward_source=example_source(preset.reward_example), num_envs=8,
        rollouts=rollouts("lockstep", ""), seed=seed, eval_episodes=1, eval_laps=3,
        eval_from_start_line=True,
    )  # fmt: skip
    run = Watch(watched)
    start = time.monotonic()
    train(config, Hooks(run, args.iterations))
    run.train_s = time.monotonic() - start
    return run


def median(values: list[float]) -> float:
    return float(statistics.median(values)) if values else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--setup", choices=("defaults", "fast"), default="defaults")
    parser.add_argument("--iterations", type=int, default=6)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--track", default="reinvent_base")
    parser.add_argument("--tracks-dir", type=Path, default=SHARED)
    args = parser.parse_args()
    preset = DEEPRACER_DEFAULTS if args.setup == "defaults" else RACING
    setup = Setup(args.setup, preset, None)
    print(f"machine: {machine()}", flush=True)
    pairs: list[tuple[int, Watch, Watch]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.seeds):
            unwatched = run_once(setup, seed, False, args, Path(tmp))
            watched = run_once(setup, seed, True, args, Path(tmp))
            pairs.append((seed, unwatched, watched))
            print(f"seed {seed}: update {unwatched.update_s:.1f} s unwatched, "
                  f"{watched.update_s:.1f} s watched", flush=True)  # fmt: skip
    print(f"machine after: {machine()}")
    print(f"\n{preset.label}, {args.iterations} iterations on {args.track}, lockstep, 8 cars "
          "in 2 workers")  # fmt: skip
    print(f"{'seed':>4}{'run':>11}{'steps':>8}{'same':>6}{'update s':>10}{'rollout s':>11}"
          f"{'eval s':>8}{'frames':>8}{'spare':>7}{'fps':>6}")  # fmt: skip
    for seed, *runs in pairs:
        same = "yes" if runs[0].steps == runs[1].steps else "NO"
        for r in runs:
            fps = r.frames / r.train_s if r.watched and r.train_s else 0.0
            print(f"{seed:>4}{'watched' if r.watched else 'unwatched':>11}"
                  f"{r.steps[-1] if r.steps else 0:>8}{same:>6}{r.update_s:>10.1f}"
                  f"{r.rollout_s:>11.1f}{r.eval_s:>8.1f}{r.frames:>8}{r.spare_frames:>7}"
                  f"{fps:>6.1f}")  # fmt: skip
    base = median([u.update_s for _, u, _ in pairs])
    seen = median([w.update_s for _, _, w in pairs])
    fps = median([w.frames / w.train_s for _, _, w in pairs if w.train_s])
    ratio = seen / base if base else float("nan")
    print(f"\nmedian update seconds: {base:.1f} unwatched, {seen:.1f} watched ({ratio:.2f}×)")
    print(f"unwatched_update_s={base:.1f} watched_update_s={seen:.1f} watched_fps={fps:.1f} "
          f"ratio={ratio:.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
