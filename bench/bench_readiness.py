"""Does training for the world outside pay? The racing preset with and without it, then the
readiness check (issue 51).

Trains the racing preset on re:Invent 2018 to bench_training.py's usual goal (three clean 3-lap
evaluations in a row, every lap at most ``--lap-limit`` s, 10.0) the way a user's job does
(bench_training.py's ``run_one``: 8 cars in 2 sandboxed workers, lockstep), ``--seeds`` seeds
(0, 1, 2) in each world:

- **clean**: the simulator as it is;
- **randomised**: the outside-world setting a racer should use, the recommended families
  (light, look, camera, car: :data:`racing.conditions.RECOMMENDED_FAMILIES`) at their default
  training ranges with the recommended curriculum (``--ramp-episodes``, default
  :data:`racing.conditions.RECOMMENDED_RAMP_EPISODES`: the draws' strength grows over each
  env's first 80 episodes; 0 turns it off) (``RacingEnv(conditions=ConditionsSpec.default(
  RECOMMENDED_FAMILIES).with_ramp(80))``: each training episode draws its own conditions; the
  evaluations that judge the goal drive in the clean world). For diagnosis, ``--families``
  trains under other families (``latency`` too), ``--widest`` at their widest ranges
  (``ConditionsSpec.widest()``, what the check tests up to), ``--conditions`` under a whole
  setting given as JSON, and ``--max-steps`` also stops
  a run after that many environment steps (steps compare across machine loads; seconds do
  not).

Then each model (its checkpoint at the goal, or its last one when it missed it) goes through the
readiness check (:func:`training.rl.readiness.check_readiness`: the clean baseline and every
family at ``--strengths``, ``--laps`` laps per cell, ``--episodes`` episodes, the check's own
seeds, no video). The table has one line per model, its completion in each family (over the
strengths) and its verdict.

Last line: ``completion_ratio=… clean_lap_loss_pct=… steps_loss_pct=… clean_completion_pct=…
randomised_completion_pct=… clean_lap_s=… randomised_lap_s=… clean_steps=… randomised_steps=…``:
the laps the randomised models complete under the check's conditions (every cell but the
baseline, every seed together) over the clean models' (``inf`` when the clean ones complete
none); how much slower their median qualifying lap is in the clean world (%), and how many more
environment steps they took to the goal (medians, %); ``nan`` where a seed missed its goal
within ``--minutes``. Goals (issue 51; same machine, 3 seeds each): completion_ratio >= 2,
clean_lap_loss_pct <= 10, steps_loss_pct <= 50.

    .venv/bin/python bench/bench_readiness.py [--seeds 3] [--first-seed 0] [--minutes 8]
        [--lap-limit 10.0] [--track reinvent_base] [--worlds clean randomised]
        [--strengths 0.33 0.67 1.0] [--laps 2] [--episodes 1] [--device cpu]
        [--families light look ...] [--widest] [--ramp-episodes N] [--conditions JSON]
        [--max-steps N]

A smoke test: ``--seeds 1 --minutes 1 --laps 1 --strengths 1.0``. The machine (CPU, cores,
load average before and after) is printed with the figures: training shares the cores.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # run as a script: its sibling

import bench_training as bt  # noqa: E402

from racing.conditions import (  # noqa: E402
    FAMILIES,
    RECOMMENDED_FAMILIES,
    RECOMMENDED_RAMP_EPISODES,
    ConditionsSpec,
)
from training.rl.algorithms import resolve_device, set_torch_threads  # noqa: E402
from training.rl.checkpoints import load_checkpoint  # noqa: E402
from training.rl.evaluation import sb3_policy  # noqa: E402
from training.rl.metadata import build_metadata  # noqa: E402
from training.rl.presets import RACING  # noqa: E402
from training.rl.readiness import CLEAN, ReadinessPlan, check_readiness  # noqa: E402
from training.rollout.envs import EnvSpec  # noqa: E402

WORLDS = ("clean", "randomised")
GOALS = {"completion_ratio": 2.0, "clean_lap_loss_pct": 10.0, "steps_loss_pct": 50.0}


class KeepGoal(bt.UntilGoal):
    """bench_training's goal, keeping the checkpoint that reached it (and the last one)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.goal_checkpoint: bytes | None = None
        self.last_checkpoint: bytes | None = None
        self.max_steps: int | None = None
        self.train_steps: int | None = None
        """``--train-steps``: train on past the goal to this many steps; the last checkpoint
        is the one checked."""
        self.episodes = 0
        """Training episodes so far, every env together (a curriculum counts each env's)."""
        self.goal_episodes: int | None = None

    def should_stop(self) -> bool:
        over = self.max_steps is not None and self.run.total_steps >= self.max_steps
        if self.train_steps is not None:
            return over or self.run.total_steps >= self.train_steps
        return super().should_stop() or over

    def on_iteration(self, result, checkpoint: bytes, rows: list) -> None:
        super().on_iteration(result, checkpoint, rows)
        self.last_checkpoint = checkpoint
        self.episodes += int(result.episodes)
        if self.run.seconds is not None and self.goal_checkpoint is None:
            self.goal_checkpoint = checkpoint
            self.goal_episodes = self.episodes


@dataclasses.dataclass
class Model:
    world: str
    run: bt.Run
    checkpoint: bytes | None
    episodes: int | None = None
    """Training episodes (every env together) to the goal, or to the end when it missed it."""
    cells: list[dict] = dataclasses.field(default_factory=list)
    verdict: str = ""
    check_s: float = 0.0

    def laps(self, *, baseline: bool) -> tuple[int, int]:
        """(completed, attempted) over the baseline row, or over every other cell."""
        cells = [c for c in self.cells if (c["family"] == CLEAN) == baseline]
        return sum(c["laps_completed"] for c in cells), sum(c["laps_attempted"] for c in cells)


@contextlib.contextmanager
def outside_world(
    world: str,
    families: tuple[str, ...] = RECOMMENDED_FAMILIES,
    *,
    widest: bool = False,
    ramp_episodes: int = 0,
    setting: dict | None = None,
):
    """bench_training's env spec, with the outside-world setting (``families`` at their
    default training ranges, or at their ``widest``; a curriculum of ``ramp_episodes``
    episodes per env; or ``setting``, a whole :meth:`ConditionsSpec.to_dict`) in the randomised
    world."""
    if world == "clean":
        yield
        return
    plain = bt.track_spec
    make = ConditionsSpec.widest if widest else ConditionsSpec.default
    if setting is None:
        setting = make(families).with_ramp(ramp_episodes).to_dict()
    else:
        setting = ConditionsSpec.from_dict(setting).to_dict()

    def randomised(*args, **kwargs) -> EnvSpec:
        return dataclasses.replace(plain(*args, **kwargs), conditions=setting)

    bt.track_spec = randomised
    try:
        yield
    finally:
        bt.track_spec = plain


def train(world: str, seed: int, args: argparse.Namespace, scratch: Path) -> Model:
    hooks: list[KeepGoal] = []

    def make_hooks(*a, **k) -> KeepGoal:
        hooks.append(KeepGoal(*a, **k))
        hooks[-1].max_steps = args.max_steps
        hooks[-1].train_steps = getattr(args, "train_steps", None)
        return hooks[-1]

    with outside_world(world, tuple(args.families), widest=args.widest,
                       ramp_episodes=args.ramp_episodes, setting=args.conditions):  # fmt: skip
        run = bt.run_one(bt.racing_setup(args), seed, args, scratch, make_hooks=make_hooks)
    hook = hooks[-1]
    kept = hook.goal_checkpoint or hook.last_checkpoint
    if hook.train_steps is not None:
        kept = hook.last_checkpoint
    episodes = hook.goal_episodes if hook.goal_episodes is not None else hook.episodes
    return Model(world, run, kept, episodes)


def check(model: Model, plan: ReadinessPlan, track: str) -> None:
    """The readiness check of ``model``'s checkpoint (its cells, its verdict)."""
    if model.checkpoint is None:
        model.verdict = "no checkpoint"
        return
    meta = build_metadata(action_space=RACING.actions(), neural_network=RACING.network)
    policy = load_checkpoint(model.checkpoint, meta)
    set_torch_threads(1)
    started = time.monotonic()
    table = check_readiness(lambda env: sb3_policy(policy),
                            EnvSpec(track=track, action_space=RACING.actions()), plan,
                            videos=0)  # fmt: skip
    model.cells, model.verdict = table.cells, table.verdict
    model.check_s = time.monotonic() - started


def completion(models: list[Model], *, baseline: bool = False) -> float | None:
    done = [m.laps(baseline=baseline) for m in models]
    attempted = sum(a for _, a in done)
    return 100.0 * sum(c for c, _ in done) / attempted if attempted else None


def ratio(over: float | None, under: float | None) -> float | None:
    if over is None or under is None:
        return None
    if under == 0:
        return math.inf if over > 0 else None
    return over / under


def loss_pct(now: float | None, before: float | None) -> float | None:
    return None if now is None or not before else 100.0 * (now - before) / before


def fmt(value: float | None, digits: int = 1) -> str:
    if value is not None and math.isinf(value):
        return "inf"
    return bt.fmt(value, digits)


def print_table(models: list[Model], families: tuple[str, ...]) -> None:
    print(f"{'world':<12}{'seed':>5}{'to goal':>10}{'steps':>9}{'lap':>7}{'clean':>8}"
          + "".join(f"{f:>9}" for f in families) + "  verdict")  # fmt: skip
    for m in models:
        r = m.run
        took = f"{r.seconds:.1f} s" if r.seconds is not None else f">{r.wall_s:.0f} s"
        steps = str(r.steps) if r.steps is not None else f">{r.total_steps}"
        laps = [t for ev in r.qualifying_laps for t in ev]
        lap = f"{statistics.median(laps):.2f}" if laps else "-"
        done, tried = m.laps(baseline=True)
        row = [f"{done}/{tried}"]
        for family in families:
            cells = [c for c in m.cells if c["family"] == family]
            row.append(f"{sum(c['laps_completed'] for c in cells)}/"
                       f"{sum(c['laps_attempted'] for c in cells)}")  # fmt: skip
        print(f"{m.world:<12}{r.seed:>5}{took:>10}{steps:>9}{lap:>7}{row[0]:>8}"
              + "".join(f"{x:>9}" for x in row[1:]) + f"  {m.verdict}")  # fmt: skip


def key_values(models: list[Model], minutes: float) -> str:
    by_world = {w: [m for m in models if m.world == w] for w in WORLDS}
    summaries = {w: bt.summarise([m.run for m in ms], limit_s=minutes * 60)
                 for w, ms in by_world.items()}  # fmt: skip
    clean_pct, rand_pct = completion(by_world["clean"]), completion(by_world["randomised"])
    clean, rand = summaries["clean"], summaries["randomised"]
    return (
        f"completion_ratio={fmt(ratio(rand_pct, clean_pct), 2)} "
        f"clean_lap_loss_pct={fmt(loss_pct(rand.lap_s, clean.lap_s))} "
        f"steps_loss_pct={fmt(loss_pct(rand.median_steps, clean.median_steps))} "
        f"clean_completion_pct={fmt(clean_pct)} randomised_completion_pct={fmt(rand_pct)} "
        f"clean_lap_s={fmt(clean.lap_s, 2)} randomised_lap_s={fmt(rand.lap_s, 2)} "
        f"clean_steps={fmt(clean.median_steps, 0)} randomised_steps={fmt(rand.median_steps, 0)}"
    )


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3, help="seeds 0..N-1 per world")
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--minutes", type=float, default=8.0, help="time limit of one run")
    parser.add_argument("--lap-limit", type=float, default=10.0, help="the goal's slowest lap")
    parser.add_argument("--track", default="reinvent_base")
    parser.add_argument("--worlds", nargs="+", choices=WORLDS, default=list(WORLDS))
    parser.add_argument("--strengths", nargs="+", type=float, default=[0.33, 0.67, 1.0])
    parser.add_argument("--laps", type=int, default=2, help="laps per cell of the check")
    parser.add_argument("--episodes", type=int, default=1, help="episodes per cell")
    parser.add_argument(
        "--families",
        nargs="+",
        choices=FAMILIES,
        default=list(RECOMMENDED_FAMILIES),
        help="the families the randomised world trains under (default: the recommended "
        "light, look, camera and car)",
    )
    parser.add_argument(
        "--widest",
        action="store_true",
        help="the randomised world at the widest ranges, not the training ones",
    )
    parser.add_argument(
        "--ramp-episodes",
        type=int,
        default=RECOMMENDED_RAMP_EPISODES,
        help="the randomised world's curriculum: the draws' strength grows over each env's "
        f"first N episodes (ConditionsSpec.ramp_episodes; default {RECOMMENDED_RAMP_EPISODES}, "
        "the recommended one; 0: none)",
    )
    parser.add_argument(
        "--conditions",
        type=json.loads,
        default=None,
        help="diagnosis: the randomised world's whole setting as JSON "
        "(ConditionsSpec.to_dict(); overrides --families, --widest, --ramp-episodes)",
    )
    parser.add_argument(
        "--max-steps",
        type=int,
        default=None,
        help="also stop a run after this many environment steps",
    )
    parser.add_argument(
        "--train-steps",
        type=int,
        default=None,
        help="diagnosis: train every model on past the goal to this many environment steps "
        "and check its last checkpoint (steps and laps to the goal are still reported)",
    )
    parser.add_argument(
        "--reward-file",
        type=Path,
        default=None,
        help="an experiment: train with the reward function in this file, not the preset's",
    )
    parser.add_argument("--device", default=None, help="the trainer's device (default cpu)")
    args = parser.parse_args(argv)
    # What bench_training's run_one reads, at its defaults.
    args.tracks_dir, args.network, args.overrides, args.actions = bt.SHARED, "", {}, None
    args.evaluate_after = args.trainer_samples = False
    args.target_kl = None
    args.device = str(resolve_device(args.device or "cpu"))
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    plan = ReadinessPlan(strengths=tuple(args.strengths), laps=args.laps, episodes=args.episodes)
    print(f"machine: {bt.machine()}", flush=True)
    print(f"trainer device: {args.device}; the check: {len(plan.cells())} cells of "
          f"{plan.episodes} x {plan.laps} laps, strengths {list(plan.strengths)}",
          flush=True)  # fmt: skip
    models: list[Model] = []
    with tempfile.TemporaryDirectory() as tmp:
        for world in args.worlds:
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                print(f"{world}: racing preset seed {seed} on {args.track}", flush=True)
                model = train(world, seed, args, Path(tmp))
                check(model, plan, args.track)
                print(f"    training episodes, every env together: {model.episodes}; readiness "
                      f"check ({model.check_s:.0f} s): {model.verdict}", flush=True)  # fmt: skip
                models.append(model)
    print()
    print_table(models, tuple(f for f in FAMILIES if f in plan.families))
    print(f"machine after: {bt.machine()}")
    print("goals: " + ", ".join(f"{k} {'>=' if k == 'completion_ratio' else '<='} {v:g}"
                                for k, v in GOALS.items()))  # fmt: skip
    print(key_values(models, args.minutes))


if __name__ == "__main__":
    main()
