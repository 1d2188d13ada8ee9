"""Why a seed of the racing preset stalls: its failed evaluations driven again, three ways.

Trains seeds of the racing preset as ``bench_training.py`` does (its ``run_one``: the same goal,
the same steps per seed), keeping every iteration's checkpoint. A seed stalls once its greedy
car has driven three clean laps and still leaves the track in later evaluations. Each of those
later failed evaluations is driven again here, from the start line, 3 laps, with the
checkpoint it evaluated:

- **greedy**: the car's argmax, as the evaluation drove (it fails again, give or take a
  near-tie that the worker's NumPy network and torch round differently);
- **capped**: the same greedy choices, except that the fastest action is replaced with the
  action of the same steering at the next slower speed (the racing preset's 3.5 m/s straight,
  4 m/s before, becomes 3 m/s straight): the policy unchanged, only its top speed taken away;
- **sampled**: the policy's own probabilities, ``--samples`` times (how the training cars
  drive).

For each failure the table gives where it left the track, the car's top speed over the 15
steps before it left, and how many of those steps took the fastest action. What it showed
with the preset before (docs/benchmarks.md, "Why seeds stall"): the greedy car took the 4 m/s
action on the short straight between two bends and arrived at the second one too fast (capped,
34 of 34 drove 3 clean laps); the camera's single frame does not show the car's speed.

    .venv/bin/python bench/bench_stalls.py [--seeds 12] [--first-seed 0] [--samples 10]
        [--minutes 6] [--track reinvent_base] [--lap-limit 10.0] [--before-clean N]
        [--set KEY=VALUE ...] [--actions JSON]

``--track`` another track: its lap limit scales with its length as in ``bench_training.py
--suite`` (re:Invent 2018's ``--lap-limit``, 10.0 s, for 17.71 m). ``--before-clean N`` also
replays the last N failed evaluations before the first clean one: where a seed that has not
yet driven a clean lap keeps leaving the track (the championship's chicane, for one).

``--actions`` trains the racing preset with another action space, as in ``bench_training.py``
(the preset before "Why seeds stall": ``--actions '[{"steering_angle": 0, "speed": 4}, …]'``).

Last line: ``failed=… greedy_failed=… capped_clean=… sampled_clean=… ratio=…``: the stalled
seeds' failed evaluations, how many of them the greedy replay failed again, how many the capped
car drove clean (3 laps), the share of the sampled drives that were clean, and ``ratio`` =
the capped car's clean share over the sampled drives' (both measured in this run).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "2")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))  # run as a script: its sibling

import bench_training as bt  # noqa: E402
from stable_baselines3.common.vec_env import DummyVecEnv  # noqa: E402

from training.rl.algorithms import load_model, set_torch_threads  # noqa: E402
from training.rl.runner import TrainingConfig, evaluation_spec  # noqa: E402
from training.rollout.greedy import action_probabilities  # noqa: E402

LAPS = bt.EVAL_LAPS
LOOK_BACK = 15
"""Steps before leaving the track that the table describes (1 simulated second)."""


def slower_action(actions: list[dict]) -> dict[int, int]:
    """The fastest actions, each mapped to the action with its steering at the next slower
    speed (none where there is no such action)."""
    top = max(a["speed"] for a in actions)
    out: dict[int, int] = {}
    for i, a in enumerate(actions):
        if a["speed"] != top:
            continue
        slower = [(b["speed"], j) for j, b in enumerate(actions)
                  if b["steering_angle"] == a["steering_angle"] and b["speed"] < top]  # fmt: skip
        if slower:
            out[i] = max(slower)[1]
    return out


@dataclass(frozen=True)
class Drive:
    """One replayed evaluation: clean (every lap complete) or where it left the track."""

    clean: bool
    lap: int
    progress: float
    laps: list[float]
    top_speed: float = 0.0
    """The car's top speed over the last ``LOOK_BACK`` steps."""
    fastest_steps: int = 0
    """Of those steps, how many took a fastest action."""


@dataclass(frozen=True)
class Failure:
    seed: int
    iteration: int
    steps: int
    greedy: Drive
    capped: Drive
    sampled: list[Drive]


class KeepCheckpoints(bt.UntilGoal):
    """UntilGoal that also keeps each iteration's checkpoint and whether its evaluation was
    clean (all laps complete)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.kept: list[tuple[int, int, bool, bytes]] = []

    def on_iteration(self, result, checkpoint: bytes, rows: list) -> None:
        super().on_iteration(result, checkpoint, rows)
        ev = result.evaluation
        self.kept.append((result.iteration, result.total_steps, ev.all_laps_complete, checkpoint))


def stalled(kept: list[tuple[int, int, bool, bytes]],
            before: int = 0) -> list[tuple[int, int, bytes]]:  # fmt: skip
    """The failed evaluations after the first clean one: (iteration, steps, checkpoint); with
    ``before``, also the last ``before`` failed ones ahead of it (where a seed that has not yet
    driven clean keeps leaving the track; a seed never clean: its last ``before`` failures)."""
    first = next((i for i, (_, _, clean, _) in enumerate(kept) if clean), None)
    ahead = [(it, steps, cp) for it, steps, clean, cp in kept[:first] if not clean]
    out = ahead[-before:] if before > 0 else []
    if first is None:
        return out
    return out + [(it, steps, cp) for it, steps, clean, cp in kept[first + 1 :] if not clean]


def drive(
    policy,
    spec,
    *,
    rng: np.random.Generator | None = None,
    replace: dict[int, int] | None = None,
    fastest: frozenset[int] = frozenset(),
) -> Drive:
    """``LAPS`` laps from the start line: greedy (``rng`` None) or sampled, each chosen action
    that ``replace`` names replaced."""
    env = spec.make(lambda params: 0.0)
    try:
        obs, _ = env.reset(seed=0)
        recent: list[tuple[float, bool]] = []
        while True:
            p = action_probabilities(policy, obs[None])[0].cpu().numpy().astype(np.float64)
            action = int(p.argmax()) if rng is None else int(rng.choice(len(p), p=p / p.sum()))
            action = (replace or {}).get(action, action)
            obs, _, terminated, truncated, info = env.step(action)
            recent = [*recent[-(LOOK_BACK - 1) :], (env.pose.speed, action in fastest)]
            if terminated or truncated:
                break
        laps = [round(lap.time_s, 2) for lap in env.tracker.laps]
        return Drive(
            clean=len(laps) >= LAPS, lap=int(info["lap"]), progress=float(info["progress"]),
            laps=laps, top_speed=max(s for s, _ in recent),
            fastest_steps=sum(f for _, f in recent),
        )  # fmt: skip
    finally:
        env.close()


def replay(seed: int, stalls: list[tuple[int, int, bytes]], spec, eval_spec, preset,
           samples: int) -> list[Failure]:  # fmt: skip
    actions = preset.actions()
    replace = slower_action(actions)
    fastest = frozenset(replace)
    venv = DummyVecEnv([lambda: spec.make(lambda params: 0.0)])
    out = []
    for iteration, steps, checkpoint in stalls:
        model = load_model(preset.algorithm, checkpoint, venv, preset.hyperparameters,
                           network=preset.network, seed=seed)  # fmt: skip
        policy = model.policy
        out.append(Failure(
            seed, iteration, steps,
            greedy=drive(policy, eval_spec, fastest=fastest),
            capped=drive(policy, eval_spec, replace=replace, fastest=fastest),
            sampled=[drive(policy, eval_spec, rng=np.random.default_rng(k), fastest=fastest)
                     for k in range(samples)],
        ))  # fmt: skip
    venv.close()
    return out


def track_lap_limit(track: str, tracks_dir: Path, reference_limit_s: float) -> float:
    """``track``'s lap limit as ``bench_training.py --suite`` sets it: re:Invent 2018's
    ``reference_limit_s`` scaled by the track's length."""
    reference = bt.track_length(bt.REFERENCE_TRACK)
    return bt.lap_limit_for(bt.track_length(track, tracks_dir), reference, reference_limit_s)


def where(d: Drive) -> str:
    return "3 clean laps" if d.clean else f"lap {d.lap} at {d.progress:.0f}%"


def print_table(failures: list[Failure]) -> None:
    print(
        f"{'seed':>4} {'it':>4} {'steps':>7}  {'greedy replay':<16} {'top m/s':>7} "
        f"{'fastest':>7}  {'capped':<16} {'capped laps':<18} {'sampled clean':>13}"
    )
    for f in failures:
        clean = sum(d.clean for d in f.sampled)
        laps = " ".join(f"{t:.2f}" for t in f.capped.laps) if f.capped.clean else ""
        print(
            f"{f.seed:>4} {f.iteration:>4} {f.steps:>7}  {where(f.greedy):<16} "
            f"{f.greedy.top_speed:>7.2f} {f.greedy.fastest_steps:>4}/{LOOK_BACK:<2}  "
            f"{where(f.capped):<16} {laps:<18} {clean:>5} of {len(f.sampled):<3}"
        )


def key_values(failures: list[Failure]) -> str:
    n = len(failures)
    sampled = [d.clean for f in failures for d in f.sampled]
    capped = sum(f.capped.clean for f in failures)
    capped_share = capped / n if n else float("nan")
    sampled_share = sum(sampled) / len(sampled) if sampled else float("nan")
    ratio = capped_share / sampled_share if sampled_share else float("nan")
    return (
        f"failed={n} greedy_failed={sum(not f.greedy.clean for f in failures)} "
        f"capped_clean={capped} sampled_clean={sampled_share:.2f} ratio={ratio:.2f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12, help="seeds K..K+N-1")
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--samples", type=int, default=10, help="sampled drives per failure")
    parser.add_argument("--minutes", type=float, default=6.0, help="time limit of one seed")
    parser.add_argument("--track", default="reinvent_base")
    parser.add_argument("--tracks-dir", type=Path, default=bt.SHARED)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--actions", default="", help="the racing preset's actions (JSON)")
    parser.add_argument("--lap-limit", type=float, default=10.0,
                        help="re:Invent 2018's lap limit (s); another track's scales with its "
                             "length, as in bench_training.py --suite")  # fmt: skip
    parser.add_argument("--before-clean", type=int, default=0, metavar="N",
                        help="also replay the last N failed evaluations before the first clean "
                             "one (where a seed learns a bend, not where it stalls)")  # fmt: skip
    args = parser.parse_args()
    if args.before_clean < 0:
        parser.error("--before-clean: give a number of evaluations, 0 or more")
    args.overrides = bt.parse_overrides(args.set)
    args.actions = bt.checked_actions(args.actions)
    args.network, args.device, args.target_kl = "", "cpu", None
    args.lap_limit = track_lap_limit(args.track, args.tracks_dir, args.lap_limit)
    args.evaluate_after = args.trainer_samples = False
    setup = bt.racing_setup(args)
    preset = setup.preset
    print(f"machine: {bt.machine()}", flush=True)
    print(f"racing preset's actions: {bt.described(preset.actions())}", flush=True)
    print(f"{args.track}: lap limit {args.lap_limit:.1f} s (as bench_training.py --suite)",
          flush=True)  # fmt: skip
    failures: list[Failure] = []
    runs: list[bt.Run] = []
    made: list[KeepCheckpoints] = []

    def hooks(*a, **kw) -> KeepCheckpoints:
        made.append(KeepCheckpoints(*a, **kw))
        return made[-1]

    with tempfile.TemporaryDirectory() as tmp:
        spec = bt.track_spec(args.track, args.tracks_dir, Path(tmp), preset)
        eval_spec = evaluation_spec(TrainingConfig(spec=spec, eval_laps=LAPS,
                                                   eval_from_start_line=True))  # fmt: skip
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            print(f"racing preset seed {seed} on {args.track}", flush=True)
            runs.append(bt.run_one(setup, seed, args, Path(tmp), make_hooks=hooks))
            stalls = stalled(made[-1].kept, args.before_clean)
            print(f"  seed {seed}: {runs[-1].steps} steps to the goal, {len(stalls)} failed "
                  "evaluations to replay", flush=True)  # fmt: skip
            set_torch_threads(1)
            failures += replay(seed, stalls, spec, eval_spec, preset, args.samples)
    print()
    print_table(failures)
    steps = [r.steps for r in runs if r.steps is not None]
    print()
    print(f"seeds: {len(runs)}, steps to the goal: "
          f"{' / '.join(str(r.steps) for r in runs)} (median "
          f"{statistics.median(steps) if steps else 'nan'})")  # fmt: skip
    if failures:
        top = [f.greedy.top_speed for f in failures if not f.greedy.clean]
        print(f"greedy failures: top speed in the last second, median "
              f"{statistics.median(top) if top else float('nan'):.2f} m/s")  # fmt: skip
    print(f"machine after: {bt.machine()}")
    print(key_values(failures))


if __name__ == "__main__":
    main()
