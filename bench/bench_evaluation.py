"""What one step of a training job's evaluation costs: driven by the trainer, or in its worker.

A lockstep job evaluates its policy after every update: one car, 3 laps from the start line in
its own sandboxed worker, which is about 1,400 steps at DeepRacer's defaults' 1 m/s. Two ways
to drive it (:class:`training.rollout.lockstep.Evaluation`):

- **trainer** (the baseline, the way before): the trainer's torch chooses each step's action
  and sends it to the worker, which steps the simulator and the reward and sends the camera
  frame back; a round trip and a torch forward pass per step;
- **worker** (the console's way now): the network goes to the worker once (NumPy), which drives
  32 steps a command; the trainer only takes up the outcome.

First a model is trained on DeepRacer's defaults (the wizard's preset, as bench_training trains
it) until one evaluation completes its 3 laps; then the same 3-lap evaluation of that policy is
driven both ways, alternately, ``--repeats`` times each. Both ways drive the same steps to the
same outcome (checked; a step where the two floats' argmax differ would show here). Printed: the
steps, the wall time and the trainer process's CPU time per step (medians), per seed.

    .venv/bin/python bench/bench_evaluation.py [--seeds 1] [--first-seed 4] [--repeats 3]

Last line: ``trainer_ms_per_step=… worker_ms_per_step=… ratio=…`` (worker / trainer wall time per
step, medians over the seeds' medians) and ``cpu_ratio=…`` (the same for the trainer's CPU).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "2")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_training as bt  # noqa: E402

from training.rl.algorithms import set_torch_threads  # noqa: E402
from training.rl.runner import TrainingLoop, evaluation_spec, experience_request  # noqa: E402
from training.rollout.lockstep import Evaluation, frozen_copy  # noqa: E402
from training.rollout.vecenv import SandboxedVecEnv  # noqa: E402


class UntilCleanEvaluation(bt.TrainingHooks):
    """Stops training once an evaluation has completed all its laps."""

    def __init__(self) -> None:
        self.done = False

    def on_iteration(self, result, checkpoint, rows) -> None:
        self.done = self.done or result.evaluation.all_laps_complete
        print(f"    it {result.iteration} steps={result.total_steps} "
              f"eval {result.evaluation.mean_progress:.1f}%", flush=True)  # fmt: skip

    def should_stop(self) -> bool:
        return self.done


class NoFrames:
    def on_frame(self, frame) -> None:
        pass


def trained_policy(seed: int, args: argparse.Namespace, scratch: Path):
    """A defaults model that drives its 3 laps, and the config it was trained with."""
    setup = bt.Setup("defaults", bt.DEEPRACER_DEFAULTS, None)
    ns = argparse.Namespace(track=args.track, tracks_dir=args.tracks_dir, minutes=args.minutes,
                            evaluate_after=False, device="cpu")  # fmt: skip
    config = bt.TrainingConfig(
        spec=bt.track_spec(ns.track, ns.tracks_dir, scratch, setup.preset),
        algorithm=setup.preset.algorithm, network=setup.preset.network,
        hyperparameters=setup.preset.hyperparameters, max_minutes=ns.minutes,
        reward_source=bt.example_source(setup.preset.reward_example), num_envs=8,
        rollouts=bt.rollouts("lockstep", ""), seed=seed, eval_episodes=1,
        eval_laps=bt.EVAL_LAPS, eval_from_start_line=True, device="cpu",
    )  # fmt: skip
    hooks = UntilCleanEvaluation()
    loop = TrainingLoop(config, hooks)
    loop.run()
    if not hooks.done:
        raise SystemExit(f"seed {seed}: no clean evaluation within {args.minutes} minutes")
    return frozen_copy(loop.model.policy), config


def drive(venv, request, policy, by_worker: bool) -> tuple[int, float, float, object]:
    """One evaluation: (steps, wall s, trainer CPU s, outcome)."""
    counted = []
    evaluation = Evaluation(venv, request, 1, policy if by_worker else None)
    assert evaluation.driven_by_workers == by_worker
    record = evaluation._record

    def counting(*a) -> None:
        counted.append(1)
        record(*a)

    evaluation._record = counting
    wall, cpu = time.perf_counter(), time.process_time()
    evaluation.drive(policy, NoFrames(), want_frames=lambda: False)
    return (len(counted), time.perf_counter() - wall, time.process_time() - cpu,
            evaluation.outcome)  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--first-seed", type=int, default=4,
                        help="seed 4 drives 3 clean laps after 2 updates")  # fmt: skip
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--minutes", type=float, default=3.0, help="training's time limit")
    parser.add_argument("--track", default="reinvent_base")
    parser.add_argument("--tracks-dir", type=Path, default=bt.SHARED)
    args = parser.parse_args()
    set_torch_threads(1)  # as the trainer's inference (PPO's inference_threads)
    print(f"machine: {bt.machine()}", flush=True)
    rows, per_seed = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            print(f"seed {seed}: training DeepRacer's defaults to a clean evaluation", flush=True)
            policy, config = trained_policy(seed, args, Path(tmp))
            set_torch_threads(1)
            request = experience_request(config)
            venv = SandboxedVecEnv(evaluation_spec(config), 1, config.reward_source, num_workers=1,
                                   phase="evaluation")  # fmt: skip
            try:
                got: dict[str, list[tuple[int, float, float]]] = {"trainer": [], "worker": []}
                outcomes = set()
                for _ in range(args.repeats):
                    for way in ("trainer", "worker"):
                        steps, wall, cpu, outcome = drive(venv, request, policy, way == "worker")
                        got[way].append((steps, wall, cpu))
                        outcomes.add(repr(outcome))
            finally:
                venv.close()
            same = len(outcomes) == 1
            medians = {}
            for way, runs in got.items():
                steps = runs[0][0]
                wall = statistics.median(r[1] for r in runs) / steps * 1000
                cpu = statistics.median(r[2] for r in runs) / steps * 1000
                medians[way] = (wall, cpu)
                rows.append((seed, way, steps, wall, cpu, same))
            per_seed.append(medians)
    print()
    print(f"{'seed':>4}  {'driven by':<9}{'steps':>7}{'wall ms/step':>14}"
          f"{'trainer CPU ms/step':>21}  same outcome")  # fmt: skip
    for seed, way, steps, wall, cpu, same in rows:
        print(f"{seed:>4}  {way:<9}{steps:>7}{wall:>14.3f}{cpu:>21.3f}  {'yes' if same else 'NO'}")
    print(f"machine after: {bt.machine()}")
    trainer = statistics.median(m["trainer"][0] for m in per_seed)
    worker = statistics.median(m["worker"][0] for m in per_seed)
    cpu_ratio = statistics.median(m["worker"][1] / m["trainer"][1] for m in per_seed)
    print(
        f"trainer_ms_per_step={trainer:.3f} worker_ms_per_step={worker:.3f} "
        f"ratio={worker / trainer:.2f} cpu_ratio={cpu_ratio:.2f}"
    )


if __name__ == "__main__":
    main()
