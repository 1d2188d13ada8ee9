"""Time and steps for a fresh model to race: DeepRacer's defaults against the racing preset.

Trains from scratch the way a user's job does (camera observations, PPO on the preset's network,
the reward running inside the sandboxed rollout workers, 8 cars in 2 workers), for the two
"Start from" choices of the create-model wizard exactly as it gives them
(:mod:`training.rl.presets`: action space, example reward, hyperparameters). After every policy
update one evaluation drives 3 consecutive laps from the start line (the clock includes it).

- **defaults** (DeepRacer's defaults) stops at three clean 3-lap evaluations in a row;
- **fast** (the racing preset) stops at three clean 3-lap evaluations in a row with every lap
  at most ``--lap-limit`` seconds (10.0).

Each iteration's line says where a failed evaluation left the track (lap, % of that lap), and
after the table one line per setup sums those places over its seeds (by lap, by tenth of the
lap): where the greedy car keeps failing on the way to the goal.

``--modes`` says how the simulation runs (``RACECRAFT_SIMULATION``): ``lockstep``, the
console's default (the trainer steps 8 cars in 2 sandboxed workers, then updates; each
evaluation runs beside the next rollout, or after the update with ``--evaluate-after``), and
``streams`` (2 simulation workers own their episodes and stream them through an embedded
Redis, or ``--redis-url``; they drive evaluation laps while the trainer updates).

Each setup runs ``--seeds`` seeds (0, 1, 2): the figures are medians, with the environment
steps to the goal (the same on any machine for a seed, give or take float differences between
CPUs) beside the wall time (which depends on the machine and its load), and where the time went
(rollouts, policy updates, evaluations). The machine (CPU, cores, load average before and
after) is printed with them.

    .venv/bin/python bench/bench_training.py [--seeds 3] [--minutes 8] [--lap-limit 10.0]
        [--first-seed 0] [--setups defaults fast] [--modes lockstep streams]
        [--evaluate-after] [--trainer-samples] [--track reinvent_base]
        [--tracks-dir DIR] [--redis-url URL] [--device cpu|cuda|cuda:<n>]
        [--target-kl X] [--set KEY=VALUE ...] [--network NAME] [--actions JSON]

A smoke test: ``--seeds 1 --minutes 1``. reinvent_base (DeepRacer's re:Invent 2018 track) is
built in (racing/tracks/deepracer/), like every DeepRacer track; any built-in track works, and
``--tracks-dir`` adds a folder of other track files.

Last line: ``defaults_median_s=… defaults_lap_s=… fast_median_s=… fast_lap_s=… fast_worst_s=…
best_lap_s=… fast_seed_best_s=… ratio=…``: median seconds to the goal, the median lap of the
qualifying evaluations, the slowest seed's seconds to the fast goal (a seed that missed it
counts as ``--minutes``), the best evaluated lap of any run, the median of each racing seed's
best lap (steadier than the best of all, one seed's luck), and ``ratio`` = fast_median_s /
defaults_median_s (what a fast lap costs over a clean slow one, both measured in this run).
``nan`` where a run missed its goal within ``--minutes``. Goals (issue 14, quiet 2-core
machine): fast ≤ 120 s, defaults ≤ 60 s.
These keys are the first mode's; each further mode adds its own, prefixed with its name
(``streams_defaults_median_s=…``), and ``{mode}_ratio=`` = its fast median / the first mode's.

``--suite`` (issue 50) runs the track suite instead: the racing preset on re:Invent 2018, Tokyo's
training track, the 2022 May Open and Pro tracks (the closest to the 2022 Open and Pro tracks'
median lengths) and the 2022 re:Invent championship (``--suite-tracks`` others), ``--seeds`` each,
then DeepRacer's defaults where they finish: on each track their first seed is a probe, the other
seeds run only where it reached the goal (``--defaults-minutes``, default ``--minutes``). Each
track's lap limit is ``--lap-limit`` scaled by its length against re:Invent 2018's 17.71 m
(length / 1.771 m/s, rounded to 0.1 s: 10.0 s there, 36.1 s on the 63.9 m Pro track); the output
says so. A run capped by ``--minutes`` has not reached the goal: its seconds and steps when it
stopped are lower bounds, printed ``>…``, and a median or slowest figure they leave unknown is
``nan`` in the last line. Per track: seeds that reached the goal, steps and seconds to it (median,
slowest), the best lap and the median qualifying lap. ``--json FILE`` writes the figures and every
run; ``--baseline FILE`` reads such a file and adds each track's ratio of median seconds. Last
line: ``suite_<track>_median_s= _worst_s= _steps= _worst_steps= _reached= _best_lap_s= _lap_s=
_defaults_median_s=`` per track (the track id in lower case), with a baseline
``suite_<track>_ratio=`` (``_ratio_at_most=`` where the baseline's median is a lower bound),
``suite_median_ratio=`` and ``suite_worst_ratio=`` over the tracks with an exact ratio, and
``suite_max_spread=``: the largest slowest / median seconds of any track.

    .venv/bin/python bench/bench_training.py --suite [--minutes 6] [--defaults-minutes 3]
        [--suite-tracks T ...] [--json FILE] [--baseline FILE]

``--device`` (default ``RACECRAFT_TORCH_DEVICE``, else ``cpu``) is where the trainer's networks
train, as the console's setting of that name. The CPU is the reference, so the bench never picks
a GPU by itself (TrainingConfig's own default, ``auto``, would); ``RACECRAFT_TORCH_DEVICE=cuda``
measures the same runs with the trainer on the GPU (the simulators, their rewards and the
evaluation laps stay on the CPU). The device is printed under the machine.

``--trainer-samples`` runs lockstep's rollouts the way before: the trainer chooses every
step's actions (SB3's ``collect_rollouts``) instead of the workers drawing them
(``LocalRollouts(sample_in_workers=False)``); the same seed then takes other steps.

``--set KEY=VALUE`` (an experiment, repeatable) trains the setups with these of DeepRacer's
hyperparameters changed (``--set lr=0.001 --set num_epochs=5``), checked as a
``hyperparameters.json`` is; the table's heading prints them. ``--network NAME`` (an
experiment) trains both setups with this network instead of each preset's own
(``--network RACECRAFT_LEAN_CNN``: the racing preset as it trained before the compact network).

``--actions JSON`` (an experiment) trains the racing preset with this discrete action space, a
list in ``model_metadata.json``'s form, checked as the console checks one
(``--actions '[{"steering_angle": 0, "speed": 4}, …]'``: the racing preset before "Why seeds
stall"); DeepRacer's defaults keep theirs.

``--max-steps N`` (an experiment's screen) stops a run that has not reached its goal after N
environment steps, as ``--minutes`` does after its time: a lower bound, printed ``>…``, but the
same on any machine and under any load.

``--ready N`` measures the console's own stop condition instead of the bench's goal: each
run evaluates as a console job does (5 one-lap episodes from starts spread round the track,
not one 3-lap episode from the start line) and the training loop itself stops it once N
evaluations in a row complete every lap (the model setting "Stop when ready",
``TrainingConfig.stop_when_ready``); no lap limit. The steps and seconds printed are then those
to "ready", what a racer who sets it waits.

``--target-kl X`` (an experiment; the presets and the console set none) trains with PPO's
``target_kl`` = X: an update stops its epochs at the first minibatch whose approximate KL
exceeds 1.5 × X. Each iteration's line then adds the epochs its update ran (an epoch stopped
early counts), and each setup's summary the mean epochs per update up to the goal.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import shutil
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "2")
# As every console process (console/celery.py), before torch loads: threads wait passively.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import torch  # noqa: E402

from console.launcher import EmbeddedRedis, Supervisor  # noqa: E402
from racing.actions import ActionSpaceError, ActionSpec  # noqa: E402
from racing.track import Track  # noqa: E402
from racing.tracks import (  # noqa: E402
    BUILTIN_DIR,
    DEEPRACER_DIR,
    deepracer_manifest,
    is_builtin,
)
from training.rewards.examples import EXAMPLES, example_source  # noqa: E402
from training.rl.algorithms import resolve_device  # noqa: E402
from training.rl.hyperparams import (  # noqa: E402
    HyperparameterError,
    Hyperparameters,
    parse_hyperparameters,
)
from training.rl.policies import NetworkError, network_spec  # noqa: E402
from training.rl.presets import DEEPRACER_DEFAULTS, RACING, Preset  # noqa: E402
from training.rl.runner import (  # noqa: E402
    IterationResult,
    TrainingConfig,
    TrainingHooks,
    TrainingLoop,
)
from training.rl.simulation import launch_local  # noqa: E402
from training.rollout.backends import LocalRollouts, StreamRollouts  # noqa: E402
from training.rollout.envs import EnvSpec  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED = DEEPRACER_DIR
"""Where ``--track`` is looked up by default: DeepRacer's track files, built in."""
EVALUATIONS_IN_A_ROW = 3
EVAL_LAPS = 3
MODES = ("lockstep", "streams")


@dataclass(frozen=True)
class Setup:
    """A wizard preset and its goal: ``lap_limit_s`` None = any clean lap counts."""

    name: str
    preset: Preset
    lap_limit_s: float | None


@dataclass
class Run:
    """One seed of one setup: the goal (``seconds``/``steps``, None if missed) and the profile."""

    setup: str
    seed: int
    mode: str = "lockstep"
    seconds: float | None = None
    steps: int | None = None
    iterations: int = 0
    total_steps: int = 0
    qualifying_laps: list[list[float]] = field(default_factory=list)
    best_lap_s: float | None = None
    rollout_s: float = 0.0
    update_s: float = 0.0
    eval_s: float = 0.0
    wall_s: float = 0.0
    exits: list[tuple[int, float]] = field(default_factory=list)
    """Where each evaluation that left the track left it: (lap, % of that lap)."""
    epochs: int = 0
    """PPO epochs the updates ran up to the goal (or to the end), an epoch stopped early by
    ``target_kl`` counting; over ``updates`` (= ``iterations`` until the goal) updates."""
    updates: int = 0
    track: str = ""
    """The track it trained on (``--suite``; ``""``: ``--track``)."""


def exit_point(progress: float, lap: int | None) -> tuple[int, float]:
    """(lap, % of the lap) where an evaluation ended: its progress is the lap's own (0-100);
    lap 0 where the source does not say which lap."""
    return (lap or 0), min(100.0, max(0.0, progress))


class Streak:
    """Consecutive qualifying evaluations: every one of its laps complete (``laps`` of them)
    and, with a ``lap_limit_s``, none slower. ``add`` says whether the goal is reached."""

    def __init__(self, *, needed: int = EVALUATIONS_IN_A_ROW, laps: int = EVAL_LAPS,
                 lap_limit_s: float | None = None) -> None:  # fmt: skip
        self.needed, self.laps, self.lap_limit_s = needed, laps, lap_limit_s
        self.evaluations: list[list[float]] = []

    def qualifies(self, complete: bool, lap_times: list[float]) -> bool:
        if not complete or len(lap_times) < self.laps:
            return False
        return self.lap_limit_s is None or max(lap_times) <= self.lap_limit_s

    def add(self, complete: bool, lap_times: list[float]) -> bool:
        if self.qualifies(complete, lap_times):
            self.evaluations.append(list(lap_times))
        else:
            self.evaluations = []
        return len(self.evaluations) >= self.needed


class UntilGoal(TrainingHooks):
    """Adds each iteration to the run and stops training at the setup's goal."""

    def __init__(self, run: Run, lap_limit_s: float | None, *, show_epochs: bool = False) -> None:
        self.run = run
        self.streak = Streak(lap_limit_s=lap_limit_s)
        self.show_epochs = show_epochs
        self.model: object | None = None
        """The trained model (set once built): its epoch count (SB3's ``_n_updates``)."""
        self.max_steps: int | None = None
        """``--max-steps``: stop a run that has not reached the goal after this many steps."""

    def on_iteration(self, result: IterationResult, checkpoint: bytes, rows: list) -> None:
        run, ev = self.run, result.evaluation
        run.iterations, run.total_steps = result.iteration, result.total_steps
        run.rollout_s += result.rollout_s
        run.update_s += result.update_s
        run.eval_s += result.eval_s
        # An iteration's evaluation comes in before or during the next update: the epochs counted
        # may include the next update's first ones (a few in a run of dozens of updates).
        epochs = int(getattr(self.model, "_n_updates", 0))
        new_epochs = epochs - run.epochs
        if run.seconds is None:
            run.epochs, run.updates = epochs, result.iteration
        laps = [t for times in ev.lap_times for t in times]
        if laps:
            run.best_lap_s = min(laps if run.best_lap_s is None else [*laps, run.best_lap_s])
        if self.streak.add(ev.all_laps_complete, laps) and run.seconds is None:
            run.seconds, run.steps = result.elapsed_s, result.total_steps
            run.qualifying_laps = [list(e) for e in self.streak.evaluations]
        shown = " ".join(f"{t:.2f}" for t in laps) or (ev.statuses[0] if ev.statuses else "")
        laps_ended = ev.ended_in_lap or [None] * len(ev.progress)
        for progress, status, lap in zip(ev.progress, ev.statuses, laps_ended, strict=False):
            if status != "lap_complete":
                run.exits.append(exit_point(progress, lap))
                shown += f" in lap {lap or '?'} at {progress:.0f}% of it"
        print(f"    it {result.iteration:3d} t={result.elapsed_s:6.1f}s "
              f"steps={result.total_steps:6d} train {result.train_progress:5.1f}%  "
              f"eval {ev.mean_progress:5.1f}%  {shown}"
              + (f"  epochs {new_epochs}" if self.show_epochs else ""), flush=True)  # fmt: skip

    def should_stop(self) -> bool:
        if self.max_steps is not None and self.run.total_steps >= self.max_steps:
            return True
        return self.run.seconds is not None


# ------------------------------------------------------------------------------ summaries
def median_or_none(values: list[float | None]) -> float | None:
    """The median, or None when any run missed its goal (a median of a partial set would
    flatter the setup) or there are none."""
    if not values or any(v is None for v in values):
        return None
    return float(statistics.median(values))  # type: ignore[type-var]


@dataclass(frozen=True)
class SetupSummary:
    median_s: float | None
    median_steps: float | None
    lap_s: float | None
    """Median lap of the qualifying evaluations of every run that reached the goal."""
    best_lap_s: float | None
    reached: int
    runs: int
    worst_s: float | None = None
    """The slowest seed's seconds to the goal, a seed that missed it counting as its time limit
    (None: no runs, or a miss with no limit given)."""
    seed_best_s: float | None = None
    """The median of each seed's best lap (seeds that drove none left out): where a typical
    seed's fastest lap lies. ``best_lap_s``, the fastest of them all, is one seed's luck: over
    30 seeds of the racing preset a third drove 5.5 s or less (docs/benchmarks.md, "Faster
    laps")."""


def summarise(runs: list[Run], limit_s: float | None = None) -> SetupSummary:
    laps = [t for r in runs for ev in r.qualifying_laps for t in ev]
    bests = [r.best_lap_s for r in runs if r.best_lap_s is not None]
    times = [r.seconds if r.seconds is not None else limit_s for r in runs]
    return SetupSummary(
        median_s=median_or_none([r.seconds for r in runs]),
        median_steps=median_or_none([None if r.steps is None else float(r.steps) for r in runs]),
        lap_s=float(statistics.median(laps)) if laps else None,
        best_lap_s=min(bests) if bests else None,
        reached=sum(r.seconds is not None for r in runs),
        runs=len(runs),
        worst_s=max(times) if times and None not in times else None,  # type: ignore[type-var]
        seed_best_s=float(statistics.median(bests)) if bests else None,
    )


def fmt(value: float | None, digits: int = 1) -> str:
    return "nan" if value is None else f"{value:.{digits}f}"


def median_ratio(over: SetupSummary, under: SetupSummary) -> float | None:
    """``over``'s median seconds / ``under``'s; None when either missed its goal."""
    if under.median_s and over.median_s is not None:
        return over.median_s / under.median_s
    return None


def key_values(defaults: SetupSummary, fast: SetupSummary) -> str:
    """The last line: medians, laps and the ratio fast / defaults (both from this run)."""
    bests = [b for b in (defaults.best_lap_s, fast.best_lap_s) if b is not None]
    ratio = median_ratio(fast, defaults)
    return (
        f"defaults_median_s={fmt(defaults.median_s)} defaults_lap_s={fmt(defaults.lap_s, 2)} "
        f"fast_median_s={fmt(fast.median_s)} fast_lap_s={fmt(fast.lap_s, 2)} "
        f"fast_worst_s={fmt(fast.worst_s)} "
        f"best_lap_s={fmt(min(bests) if bests else None, 2)} "
        f"fast_seed_best_s={fmt(fast.seed_best_s, 2)} ratio={fmt(ratio, 2)}"
    )


def mode_key_values(mode: str, defaults: SetupSummary, fast: SetupSummary,
                    baseline_fast: SetupSummary) -> str:  # fmt: skip
    """A further mode's keys, prefixed with its name; ``{mode}_ratio`` = its fast median over
    the first mode's (below 1: this mode reaches a fast lap sooner)."""
    ratio = median_ratio(fast, baseline_fast)
    return (
        f"{mode}_defaults_median_s={fmt(defaults.median_s)} "
        f"{mode}_defaults_lap_s={fmt(defaults.lap_s, 2)} "
        f"{mode}_fast_median_s={fmt(fast.median_s)} {mode}_fast_lap_s={fmt(fast.lap_s, 2)} "
        f"{mode}_fast_worst_s={fmt(fast.worst_s)} {mode}_ratio={fmt(ratio, 2)}"
    )


def machine() -> str:
    """CPU model, cores and the load average (1, 5, 15 minutes), for the figures' context."""
    model = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = " ".join(f"{x:.2f}" for x in os.getloadavg())
    return f"{model}, {os.cpu_count()} cores, load average {load}"


def device_label(device: torch.device) -> str:
    """The trainer's device for the figures' context: ``cpu``, or ``cuda:0 (NVIDIA H200)``."""
    if device.type != "cuda":
        return str(device)
    index = device.index if device.index is not None else torch.cuda.current_device()
    return f"cuda:{index} ({torch.cuda.get_device_name(index)})"


# ------------------------------------------------------------------------------ running
def track_spec(track: str, tracks_dir: Path, scratch: Path, preset: Preset) -> EnvSpec:
    """The env a model created in the wizard drives (its EnvSpec defaults), on ``track``; a
    track file found in ``tracks_dir`` is imported into a scratch catalogue, unless built in."""
    found = tracks_dir / f"{track}.npy"
    dirs: tuple[str, ...] = ()
    if found.exists() and not is_builtin(track):
        shutil.copy(found, scratch / found.name)
        dirs = (str(scratch),)
    return EnvSpec(track=track, track_dirs=dirs, action_space=preset.actions())


def rollouts(mode: str, redis_url: str, *, beside: bool = True,
             sample: bool = True) -> LocalRollouts | StreamRollouts:  # fmt: skip
    """What a console job gets in ``mode``: 2 sandboxed workers on this machine; ``beside``
    False: lockstep evaluates after the update instead of beside the next rollout (the way
    before, to measure against)."""
    if mode == "streams":
        return StreamRollouts(redis_url=redis_url, workers=2, launch=launch_local, prefix="bench:")
    return LocalRollouts(num_workers=2, overlap_evaluation=beside, sample_in_workers=sample)


def parse_overrides(pairs: list[str]) -> dict[str, str]:
    """``--set KEY=VALUE`` pairs as a dict; a malformed pair or an unknown key stops the bench."""
    known = {f.name for f in fields(Hyperparameters)}
    out: dict[str, str] = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or key.strip() not in known:
            names = ", ".join(sorted(known))
            raise SystemExit(f"--set {pair!r}: use KEY=VALUE with KEY one of {names}")
        out[key.strip()] = value.strip()
    return out


def checked_network(name: str) -> str:
    """``--network``: empty (each preset trains its own network) or a network's name (the
    test-only ones included); an unknown name stops the bench."""
    if name:
        try:
            network_spec(name)
        except NetworkError as error:
            raise SystemExit(f"--network: {error}") from None
    return name


def checked_actions(text: str) -> tuple[dict, ...] | None:
    """``--actions``: empty (the racing preset's own, None) or a JSON list of discrete actions,
    checked as a model's ``action_space``; anything else stops the bench."""
    if not text:
        return None
    try:
        spec = ActionSpec.parse(json.loads(text))
    except (ValueError, ActionSpaceError) as error:  # JSON's errors are ValueErrors
        raise SystemExit(f"--actions: {error}") from None
    if spec.kind != "discrete":
        raise SystemExit("--actions: give a list of discrete actions, not ranges")
    return tuple({"steering_angle": a, "speed": v} for a, v in spec.actions)


def described(actions) -> str:
    """An action space in a line: "0° at 3.5 m/s, 0° at 3 m/s, -10° at 3 m/s, …"."""
    return ", ".join(f"{a['steering_angle']:g}° at {a['speed']:g} m/s" for a in actions)


def racing_setup(args: argparse.Namespace) -> Setup:
    """The racing preset and its goal, with ``args.actions`` where given."""
    preset = RACING
    if args.actions:
        preset = dataclasses.replace(RACING, action_space=args.actions)
    if getattr(args, "reward_example", ""):
        preset = dataclasses.replace(preset, reward_example=args.reward_example)
    return Setup("fast", preset, args.lap_limit)


def overridden(preset: Preset, overrides: dict[str, str]) -> Hyperparameters:
    """The preset's hyperparameters with ``overrides``, validated as a hyperparameters.json."""
    if not overrides:
        return preset.hyperparameters
    data = {**asdict(preset.hyperparameters), **overrides}
    try:
        return parse_hyperparameters(data, preset.algorithm)
    except HyperparameterError as error:
        raise SystemExit(f"--set: {error}") from None


def reward_source(preset: Preset, args: argparse.Namespace) -> str:
    """The reward a run trains with: ``--reward-file``'s text where given (for the racing preset;
    DeepRacer's defaults keep theirs), else the preset's example."""
    path = getattr(args, "reward_file", None)
    if path is not None and preset.id == RACING.id:
        try:
            return path.read_text()
        except OSError as error:
            raise SystemExit(f"--reward-file: {error}") from None
    return example_source(preset.reward_example)


def evaluation_settings(ready: int) -> dict:
    """TrainingConfig's evaluation: the bench's goal (one 3-lap episode from the start line),
    or with ``ready`` (``--ready``) the console's (its defaults: 5 one-lap episodes from spread
    starts) and its "stop when ready" condition."""
    if ready:
        console = {f.name: f.default for f in dataclasses.fields(TrainingConfig)}
        keys = ("eval_episodes", "eval_laps", "eval_from_start_line")
        return {**{key: console[key] for key in keys}, "stop_when_ready": ready}
    return {"eval_episodes": 1, "eval_laps": EVAL_LAPS, "eval_from_start_line": True}


def run_one(setup: Setup, seed: int, args: argparse.Namespace, scratch: Path, *,
            mode: str = "lockstep", redis_url: str = "",
            make_hooks: Callable[..., UntilGoal] | None = None) -> Run:  # fmt: skip
    """One seed of ``setup`` to its goal or ``args.minutes``; ``make_hooks`` (UntilGoal, or
    what builds a subclass of it, as bench_stalls.py's) makes what follows its iterations."""
    run = Run(setup.name, seed, mode)
    preset = setup.preset
    ready = getattr(args, "ready", 0)
    config = TrainingConfig(
        spec=track_spec(args.track, args.tracks_dir, scratch, preset),
        algorithm=preset.algorithm,
        network=args.network or preset.network,
        hyperparameters=overridden(preset, args.overrides),
        max_minutes=args.minutes,
        reward_source=reward_source(preset, args),
        num_envs=8,
        rollouts=rollouts(
            mode, redis_url, beside=not args.evaluate_after, sample=not args.trainer_samples
        ),
        seed=seed,
        **evaluation_settings(ready),
        device=args.device,
        lagged_rollout=getattr(args, "lagged_rollout", False),
    )
    hooks = (make_hooks or UntilGoal)(
        run, None if ready else setup.lap_limit_s, show_epochs=args.target_kl is not None
    )
    if ready:  # the console's condition, which the loop stops at by itself
        hooks.streak = Streak(needed=ready, laps=1)
    start = time.monotonic()
    loop = TrainingLoop(config, hooks)  # as train() does, with the model at hand
    if args.target_kl is not None:
        if not hasattr(loop.model, "target_kl"):
            loop.close()
            raise SystemExit(f"--target-kl: {preset.algorithm} has no target_kl (PPO only)")
        loop.model.target_kl = args.target_kl
    hooks.model = loop.model
    hooks.max_steps = getattr(args, "max_steps", None)
    loop.run()
    run.wall_s = time.monotonic() - start
    return run


def print_table(runs: list[Run], *, tracks: bool = False) -> None:
    """One line per run; ``tracks``: a first column names its track (``--suite``)."""
    width = max((len(r.track) for r in runs), default=0) + 2 if tracks else 0
    print(f"{'track' if width else '':<{width}}"
          f"{'mode':<10}{'setup':<10}{'seed':>5}{'to goal':>10}{'steps':>8}{'iters':>7}"
          f"{'rollout':>9}{'update':>8}{'eval':>7}{'best lap':>10}"
          "  laps of the qualifying evaluations (s)")  # fmt: skip
    for r in runs:
        took = f"{r.seconds:.1f} s" if r.seconds is not None else f">{r.wall_s:.0f} s"
        steps = str(r.steps) if r.steps is not None else f">{r.total_steps}"
        laps = "; ".join(" ".join(f"{t:.2f}" for t in ev) for ev in r.qualifying_laps) or "-"
        print(f"{r.track if width else '':<{width}}"
              f"{r.mode:<10}{r.setup:<10}{r.seed:>5}{took:>10}{steps:>8}{r.iterations:>7}"
              f"{r.rollout_s:>8.1f}s{r.update_s:>7.1f}s{r.eval_s:>6.1f}s"
              f"{fmt(r.best_lap_s, 2):>10}  {laps}")  # fmt: skip


def print_exits(runs: list[Run]) -> None:
    """Where the evaluations that failed left the track, per setup: by lap and by tenth of
    the lap (every seed together)."""
    for mode, setup in dict.fromkeys((r.mode, r.setup) for r in runs):
        exits = [e for r in runs if (r.mode, r.setup) == (mode, setup) for e in r.exits]
        if not exits:
            continue
        by_lap = [sum(lap == n for lap, _ in exits) for n in range(1, EVAL_LAPS + 1)]
        unknown = sum(lap == 0 for lap, _ in exits)
        by_tenth = [sum(min(int(at // 10), 9) == b for _, at in exits) for b in range(10)]
        laps = ", ".join(f"{n + 1}: {c}" for n, c in enumerate(by_lap))
        laps += f", unknown: {unknown}" if unknown else ""
        tenths = " ".join(f"{10 * b}-{10 * b + 10}%: {c}" for b, c in enumerate(by_tenth))
        print(f"{mode} {setup}: {len(exits)} evaluations left the track; by lap {laps}; "
              f"by tenth of the lap {tenths}")  # fmt: skip


def seeds_of(args: argparse.Namespace) -> range:
    """The seeds each setup runs: ``--first-seed`` K and on, ``--seeds`` of them."""
    return range(args.first_seed, args.first_seed + args.seeds)


# ------------------------------------------------------------------------------ the track suite
SUITE_TRACKS = (
    "reinvent_base",
    "Tokyo_Training_track",
    "2022_may_open",
    "2022_may_pro",
    "2022_reinvent_champ",
)
"""``--suite``'s tracks: re:Invent 2018 (17.7 m, the bench's own), Tokyo's training track
(22.6 m of tight bends, narrow), the 2022 league's May Open and Pro tracks (Ross Raceway 46.1 m,
Ross Super Speedway 63.9 m: the 2022 Open tracks run 40.2-50.3 m, median 45.7; the Pro tracks
57.9-76.8 m, median 63.0; May's are the closest to both medians, where March's Pro track is the
longest of all) and the 2022 re:Invent championship (33.3 m, 0.95 m wide)."""
REFERENCE_TRACK = "reinvent_base"
"""The track whose lap limit (``--lap-limit``, 10.0 s) the others' scale from."""


def track_length(track: str, tracks_dir: Path = SHARED) -> float:
    """The centre line's length in metres: the built-in manifest's (measured by our simulator
    on the file), else measured on ``tracks_dir``'s file."""
    meta = deepracer_manifest().get(track)
    if meta is not None:
        return float(meta["length_m"])
    found = BUILTIN_DIR / f"{track}.npy" if is_builtin(track) else tracks_dir / f"{track}.npy"
    if not found.exists():
        raise SystemExit(f"--suite-tracks: no track {track!r} (built in, or in --tracks-dir)")
    return float(Track.from_file(str(found), name=track).length)


def lap_limit_for(length_m: float, reference_length_m: float, reference_limit_s: float) -> float:
    """A track's lap limit: its length at the reference track's average speed at its limit
    (re:Invent 2018: 17.71 m in 10.0 s, 1.77 m/s, about half the racing preset's 3.5 m/s top
    speed), rounded to 0.1 s. The reference track itself keeps its limit."""
    return round(length_m * reference_limit_s / reference_length_m, 1)


def lap_limit_formula(reference_length_m: float, reference_limit_s: float, top_speed: float) -> str:
    speed = reference_length_m / reference_limit_s
    return (
        f"lap limit = length / {speed:.3f} m/s, rounded to 0.1 s: re:Invent 2018's "
        f"{reference_limit_s:.1f} s for {reference_length_m:.2f} m (--lap-limit), an average of "
        f"{speed / top_speed:.0%} of the racing preset's top speed ({top_speed:g} m/s)"
    )


@dataclass(frozen=True)
class Bound:
    """A figure over runs that may have missed their goal: ``exact``, or a lower bound
    (``>value``: a missed run's goal lies beyond what it reached before its time limit);
    ``value`` None where there are no runs."""

    value: float | None
    exact: bool = True

    def text(self, digits: int = 1, thousands: bool = False) -> str:
        if self.value is None:
            return "nan"
        shown = f"{self.value:,.{digits}f}" if thousands else f"{self.value:.{digits}f}"
        return shown if self.exact else f">{shown}"

    def key(self, digits: int = 1) -> str:
        """For the last line: the value where exact, else ``nan``."""
        return fmt(self.value if self.exact else None, digits)


def censored_median(values: list[tuple[float, bool]]) -> Bound:
    """The median of ``(value, reached)`` pairs, a missed run's value being a lower bound: exact
    where the misses cannot move it (they sort above the middle whatever they turn out to be),
    else the lower bound that the misses at their bounds give."""
    if not values:
        return Bound(None)
    low = statistics.median(v for v, _ in values)
    high = statistics.median(v if reached else float("inf") for v, reached in values)
    return Bound(float(low), exact=low == high)


def censored_max(values: list[tuple[float, bool]]) -> Bound:
    """The largest value: exact where every run reached its goal, else a lower bound."""
    if not values:
        return Bound(None)
    return Bound(float(max(v for v, _ in values)), exact=all(reached for _, reached in values))


@dataclass(frozen=True)
class TrackSummary:
    """One setup's runs on one track: seconds and steps to the goal, with lower bounds where a
    seed missed it (a missed run's seconds and steps when it stopped)."""

    track: str
    setup: str
    runs: int
    reached: int
    median_s: Bound
    worst_s: Bound
    median_steps: Bound
    worst_steps: Bound
    best_lap_s: float | None
    lap_s: float | None
    """Median lap of the qualifying evaluations of every run that reached the goal."""


def summarise_track(track: str, setup: str, runs: list[Run]) -> TrackSummary:
    mine = [r for r in runs if r.track == track and r.setup == setup]
    secs = [(r.seconds, True) if r.seconds is not None else (r.wall_s, False) for r in mine]
    steps = [(float(r.steps), True) if r.steps is not None else (float(r.total_steps), False)
             for r in mine]  # fmt: skip
    laps = [t for r in mine for ev in r.qualifying_laps for t in ev]
    bests = [r.best_lap_s for r in mine if r.best_lap_s is not None]
    return TrackSummary(
        track=track,
        setup=setup,
        runs=len(mine),
        reached=sum(r.seconds is not None for r in mine),
        median_s=censored_median(secs),
        worst_s=censored_max(secs),
        median_steps=censored_median(steps),
        worst_steps=censored_max(steps),
        best_lap_s=min(bests) if bests else None,
        lap_s=float(statistics.median(laps)) if laps else None,
    )


def suite_ratio(now: Bound, before: Bound) -> Bound:
    """This run's median over the baseline's: exact where both are; ``exact=False`` here means
    an upper bound (the baseline's median is only a lower bound), None where nothing is known."""
    if now.value is None or before.value is None or not now.exact or not before.value:
        return Bound(None)
    return Bound(now.value / before.value, exact=before.exact)


def key_name(track: str) -> str:
    return track.lower()


def suite_key_values(tracks: list[str], fast: dict[str, TrackSummary],
                     defaults: dict[str, TrackSummary],
                     baseline: dict[str, dict] | None = None) -> str:  # fmt: skip
    """The suite's last line: per track the racing preset's median and slowest seconds and
    steps to the goal (``nan`` where a seed's miss leaves it unknown), seeds that reached it,
    best and median qualifying lap, DeepRacer's defaults' median; with a baseline, each track's
    ratio of medians (``_ratio``, or ``_ratio_at_most`` where the baseline's median is a lower
    bound), ``suite_median_ratio`` and ``suite_worst_ratio`` over the tracks with an exact one;
    ``suite_max_spread``: the largest slowest/median seconds of any track."""
    out: list[str] = []
    ratios: list[float] = []
    spreads: list[float] = []
    for track in tracks:
        k, s = key_name(track), fast.get(track)
        if s is not None:
            out += [
                f"suite_{k}_median_s={s.median_s.key()}",
                f"suite_{k}_worst_s={s.worst_s.key()}",
                f"suite_{k}_steps={s.median_steps.key(0)}",
                f"suite_{k}_worst_steps={s.worst_steps.key(0)}",
                f"suite_{k}_reached={s.reached}",
                f"suite_{k}_best_lap_s={fmt(s.best_lap_s, 2)}",
                f"suite_{k}_lap_s={fmt(s.lap_s, 2)}",
            ]
            if s.median_s.exact and s.worst_s.exact and s.median_s.value:
                spreads.append(s.worst_s.value / s.median_s.value)  # type: ignore[operator]
            if baseline is not None and track in baseline:
                ratio = suite_ratio(s.median_s, bound_of(baseline[track]["median_s"]))
                if ratio.value is not None and ratio.exact:
                    ratios.append(ratio.value)
                    out.append(f"suite_{k}_ratio={fmt(ratio.value, 2)}")
                elif ratio.value is not None:
                    out.append(f"suite_{k}_ratio_at_most={fmt(ratio.value, 2)}")
                else:
                    out.append(f"suite_{k}_ratio=nan")
        d = defaults.get(track)
        if d is not None:
            out.append(f"suite_{k}_defaults_median_s={d.median_s.key()}")
    if baseline is not None:
        out.append(f"suite_median_ratio={fmt(statistics.median(ratios) if ratios else None, 2)}")
        out.append(f"suite_worst_ratio={fmt(max(ratios) if ratios else None, 2)}")
    out.append(f"suite_max_spread={fmt(max(spreads) if spreads else None, 2)}")
    return " ".join(out)


def bound_of(data: dict) -> Bound:
    return Bound(data.get("value"), bool(data.get("exact", True)))


def read_baseline(path: Path) -> dict[str, dict]:
    """``--baseline FILE``: a previous ``--suite --json FILE``'s racing preset per track."""
    try:
        data = json.loads(path.read_text())
        return {t: v["fast"] for t, v in data["tracks"].items() if v.get("fast")}
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as error:
        raise SystemExit(f"--baseline {path}: not a --suite --json file ({error})") from None


def print_suite_tables(tracks: list[str], info: dict[str, tuple[float, float]],
                       summaries: dict[tuple[str, str], TrackSummary],
                       baseline: dict[str, dict] | None) -> None:  # fmt: skip
    """Per track and setup: seeds that reached the goal, steps and seconds to it (median and
    slowest, ``>`` a lower bound where a seed missed it), the best lap and the median lap of
    the qualifying evaluations; with a baseline, the ratio of median seconds."""
    head = (f"{'track':<22}{'length':>8}{'limit':>7}  {'setup':<9}{'reached':>8}"
            f"{'steps median':>14}{'slowest':>10}{'s median':>10}{'slowest':>9}"
            f"{'best lap':>10}{'qual lap':>10}")  # fmt: skip
    print(head + ("  vs baseline" if baseline is not None else ""))
    for track in tracks:
        length, limit = info[track]
        for setup in ("fast", "defaults"):
            s = summaries.get((track, setup))
            if s is None:
                continue
            shown_limit = f"{limit:.1f}s" if setup == "fast" else "any"
            line = (f"{track:<22}{length:>7.2f}m{shown_limit:>7}  {setup:<9}"
                    f"{f'{s.reached}/{s.runs}':>8}{s.median_steps.text(0, True):>14}"
                    f"{s.worst_steps.text(0, True):>10}{s.median_s.text():>10}"
                    f"{s.worst_s.text():>9}{fmt(s.best_lap_s, 2):>10}"
                    f"{fmt(s.lap_s, 2):>10}")  # fmt: skip
            if baseline is not None and setup == "fast" and track in baseline:
                before = bound_of(baseline[track]["median_s"])
                ratio = suite_ratio(s.median_s, before)
                line += f"  {before.text()} s before, ratio " + (
                    "nan"
                    if ratio.value is None
                    else f"{ratio.value:.2f}"
                    if ratio.exact
                    else f"<={ratio.value:.2f}"
                )
            print(line)


def run_suite(args: argparse.Namespace, scratch: Path, mode: str, redis_url: str,
              info: dict[str, tuple[float, float]]) -> list[Run]:  # fmt: skip
    """The racing preset's seeds on every track first, then DeepRacer's defaults where they
    finish: on each track its first seed is a probe, and only where the probe reaches the goal
    within ``--minutes`` do the other seeds run."""
    runs: list[Run] = []
    fast = racing_setup(args)

    ready = getattr(args, "ready", 0)

    def one(setup: Setup, track: str, seed: int, minutes: float) -> Run:
        print(f"{mode}: {setup.name} ({setup.preset.label}) seed {seed} on {track}"
              + (f", lap limit {setup.lap_limit_s:.1f} s" if setup.lap_limit_s and not ready
                 else f", until ready ({ready} evaluations in a row)" if ready else ""),
              flush=True)  # fmt: skip
        on_track = argparse.Namespace(**{**vars(args), "track": track, "minutes": minutes})
        run = run_one(setup, seed, on_track, scratch, mode=mode, redis_url=redis_url)
        run.track = track
        if run.seconds is None:
            print(f"    not reached within {minutes:g} min ({run.total_steps} steps)",
                  flush=True)  # fmt: skip
        return run

    if "fast" in args.setups:
        for track in args.suite_tracks:
            setup = dataclasses.replace(fast, lap_limit_s=info[track][1])
            for seed in seeds_of(args):
                runs.append(one(setup, track, seed, args.minutes))
    if "defaults" in args.setups:
        defaults = Setup("defaults", DEEPRACER_DEFAULTS, None)
        for track in args.suite_tracks:
            seeds = list(seeds_of(args))
            probe = one(defaults, track, seeds[0], args.defaults_minutes)
            runs.append(probe)
            if probe.seconds is None:
                print(f"defaults on {track}: the probe seed {seeds[0]} missed the goal within "
                      f"{args.defaults_minutes:g} min; its other seeds skipped",
                      flush=True)  # fmt: skip
                continue
            for seed in seeds[1:]:
                runs.append(one(defaults, track, seed, args.defaults_minutes))
    return runs


def suite_main(args: argparse.Namespace, device: torch.device, modes: list[str]) -> None:
    """``--suite``: the racing preset and DeepRacer's defaults on :data:`SUITE_TRACKS` (or
    ``--suite-tracks``), each track's lap limit scaled from re:Invent 2018's ``--lap-limit``."""
    mode = modes[0]
    baseline = read_baseline(args.baseline) if args.baseline else None
    reference = track_length(REFERENCE_TRACK)
    top_speed = max(float(a["speed"]) for a in racing_setup(args).preset.actions())
    info = {}
    for track in args.suite_tracks:
        length = track_length(track, args.tracks_dir)
        info[track] = (length, lap_limit_for(length, reference, args.lap_limit))
    before = machine()
    print(f"machine: {before}", flush=True)
    print(f"trainer device: {device_label(device)}", flush=True)
    library = Path(sys.modules[TrainingLoop.__module__].__file__ or "").parents[2]
    print(f"code measured: {library}", flush=True)
    print(f"suite: {mode}, seeds {', '.join(map(str, seeds_of(args)))} on every track, each "
          f"run capped at {args.minutes:g} min (DeepRacer's defaults at "
          f"{args.defaults_minutes:g} min): a capped run has not reached the goal, printed as "
          ">its seconds and steps; DeepRacer's defaults after the racing preset on every track, "
          "where their first seed (a probe) reaches the goal", flush=True)  # fmt: skip
    print(lap_limit_formula(reference, args.lap_limit, top_speed), flush=True)
    for track in args.suite_tracks:
        print(f"  {track}: {info[track][0]:.2f} m, lap limit {info[track][1]:.1f} s", flush=True)
    with tempfile.TemporaryDirectory() as tmp, Supervisor() as sup:
        redis_url = args.redis_url
        if mode == "streams" and not redis_url:
            redis = EmbeddedRedis(Path(tmp) / "redis.sock", persist=False)
            sup.start(redis.spec())
            sup.wait_until(redis.ping, what="embedded Redis", timeout=30)
            redis_url = redis.url
        runs = run_suite(args, Path(tmp), mode, redis_url, info)
    print()
    print_table(runs, tracks=True)
    for track in args.suite_tracks:
        if any(r.exits for r in runs if r.track == track):
            print(f"\n{track}:")
            print_exits([r for r in runs if r.track == track])
    summaries = {
        (track, setup): summarise_track(track, setup, runs)
        for track in args.suite_tracks
        for setup in ("fast", "defaults")
        if any(r.track == track and r.setup == setup for r in runs)
    }
    print()
    print_suite_tables(args.suite_tracks, info, summaries, baseline)
    after = machine()
    print(f"machine after: {after}")
    if args.json:
        write_suite_json(args, info, summaries, runs, before, after, device)
    fast = {t: s for (t, setup), s in summaries.items() if setup == "fast"}
    defaults = {t: s for (t, setup), s in summaries.items() if setup == "defaults"}
    print(suite_key_values(args.suite_tracks, fast, defaults, baseline))


def write_suite_json(args: argparse.Namespace, info: dict[str, tuple[float, float]],
                     summaries: dict[tuple[str, str], TrackSummary], runs: list[Run],
                     before: str, after: str, device: torch.device) -> None:  # fmt: skip
    """``--json FILE``: what ``--baseline FILE`` reads back, and every run."""
    data = {
        "command": " ".join(sys.argv),
        "machine": before,
        "machine_after": after,
        "device": device_label(device),
        "minutes": args.minutes,
        "seeds": list(seeds_of(args)),
        "tracks": {
            track: {
                "length_m": info[track][0],
                "lap_limit_s": info[track][1],
                **{
                    setup: asdict(summaries[track, setup])
                    for setup in ("fast", "defaults")
                    if (track, setup) in summaries
                },
            }
            for track in args.suite_tracks
        },
        "runs": [asdict(r) for r in runs],
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(data, indent=1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3, help="seeds 0..N-1 per setup")
    parser.add_argument("--first-seed", type=int, default=0,
                        help="start at this seed (K..K+N-1): one process per seed runs them side "
                             "by side")  # fmt: skip
    parser.add_argument("--minutes", type=float, default=8.0, help="time limit of one run")
    parser.add_argument("--max-steps", type=int, default=None,
                        help="an experiment's screen: stop a run that has not reached the "
                        "goal after this many environment steps (a lower bound, as "
                        "--minutes)")  # fmt: skip
    parser.add_argument("--lap-limit", type=float, default=10.0, help="fast: slowest lap (s)")
    parser.add_argument("--ready", type=int, default=0, metavar="N",
                        help="the console's evaluation and its stop condition: stop once N "
                        "evaluations in a row complete every lap (no lap limit)")  # fmt: skip
    parser.add_argument("--setups", nargs="+", choices=("defaults", "fast"),
                        default=["defaults", "fast"])  # fmt: skip
    parser.add_argument(
        "--modes",
        nargs="+",
        choices=MODES,
        default=["lockstep"],
        help="how the simulation runs; the first mode gives the main keys",
    )
    parser.add_argument("--evaluate-after", action="store_true",
                        help="lockstep: evaluate after the update, not beside the next rollout "
                             "(the way before)")  # fmt: skip
    parser.add_argument("--track", default="reinvent_base")
    parser.add_argument("--tracks-dir", type=Path, default=SHARED)
    parser.add_argument("--redis-url", default="", help="streams: this Redis, not an embedded one")
    parser.add_argument(
        "--device",
        default=os.environ.get("RACECRAFT_TORCH_DEVICE", "cpu"),
        help="the trainer's torch device: cpu (default, the reference), cuda, cuda:<n>",
    )
    parser.add_argument("--target-kl", type=float, default=None,
                        help="PPO's target_kl for the trained model (default none, as the "
                             "presets): an update stops its epochs once the approximate KL "
                             "exceeds 1.5 × X")  # fmt: skip
    reward = parser.add_mutually_exclusive_group()
    reward.add_argument("--reward-example", default="", choices=["", *(e.id for e in EXAMPLES)],
                        help="an experiment: train the racing preset with this example reward "
                             "(an id of training.rewards.examples)")  # fmt: skip
    reward.add_argument("--reward-file", type=Path, default=None,
                        help="an experiment: train the racing preset with the reward function "
                             "in this file (as the wizard's editor would)")  # fmt: skip
    parser.add_argument("--lagged-rollout", action="store_true",
                        help="lockstep: the next rollout is driven beside the update, by "
                             "the policy one update behind (an experiment)")  # fmt: skip
    parser.add_argument("--trainer-samples", action="store_true",
                        help="lockstep: the trainer chooses every step's actions (SB3's "
                             "collect_rollouts, the way before), not the workers")  # fmt: skip
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="an experiment: train with this hyperparameter changed "
                             "(repeatable; DeepRacer's names, e.g. lr=0.001)")  # fmt: skip
    parser.add_argument("--network", default="",
                        help="an experiment: train with this network instead of the preset's "
                             "(a name of training.rl.policies)")  # fmt: skip
    parser.add_argument("--actions", default="",
                        help="an experiment: train the racing preset with this action space "
                             "(a JSON list of {steering_angle, speed})")  # fmt: skip
    parser.add_argument("--suite", action="store_true",
                        help="the track suite: the racing preset, then DeepRacer's defaults where "
                             "they finish, on re:Invent 2018, Tokyo, 2022 May Open and Pro and "
                             "the 2022 re:Invent championship, each with a lap limit scaled "
                             "from --lap-limit by its length")  # fmt: skip
    parser.add_argument("--suite-tracks", nargs="+", default=list(SUITE_TRACKS), metavar="TRACK",
                        help="--suite: these tracks instead")  # fmt: skip
    parser.add_argument(
        "--defaults-minutes",
        type=float,
        default=None,
        help="--suite: DeepRacer's defaults' time limit (default --minutes)",
    )
    parser.add_argument(
        "--json",
        type=Path,
        default=None,
        help="--suite: write the figures and every run to this file",
    )
    parser.add_argument("--baseline", type=Path, default=None,
                        help="--suite: a previous --json file; adds each track's ratio of "
                             "median seconds to it")  # fmt: skip
    args = parser.parse_args()
    args.overrides = parse_overrides(args.set)
    args.network = checked_network(args.network)
    args.actions = checked_actions(args.actions)
    device = resolve_device(args.device)  # a GPU asked for that this machine lacks fails here
    setups = [Setup("defaults", DEEPRACER_DEFAULTS, None), racing_setup(args)]
    modes = list(dict.fromkeys(args.modes))
    if args.suite:
        if args.defaults_minutes is None:
            args.defaults_minutes = args.minutes
        return suite_main(args, device, modes)
    print(f"machine: {machine()}", flush=True)
    print(f"trainer device: {device_label(device)}", flush=True)
    if args.network:
        print(f"network: {args.network}", flush=True)
    if args.actions:
        print(f"racing preset's actions: {described(args.actions)}", flush=True)
    if args.overrides:
        print("hyperparameters changed: "
              + ", ".join(f"{k}={v}" for k, v in args.overrides.items()), flush=True)  # fmt: skip
    runs: list[Run] = []
    with tempfile.TemporaryDirectory() as tmp, Supervisor() as sup:
        redis_url = args.redis_url
        if "streams" in modes and not redis_url:
            redis = EmbeddedRedis(Path(tmp) / "redis.sock", persist=False)
            sup.start(redis.spec())
            sup.wait_until(redis.ping, what="embedded Redis", timeout=30)
            redis_url = redis.url
        for mode in modes:
            for setup in (s for s in setups if s.name in args.setups):
                for seed in seeds_of(args):
                    print(f"{mode}: {setup.name} ({setup.preset.label}) seed {seed} on "
                          f"{args.track}", flush=True)  # fmt: skip
                    runs.append(run_one(setup, seed, args, Path(tmp), mode=mode,
                                        redis_url=redis_url))  # fmt: skip

    print()
    print_table(runs)
    print()
    print_exits(runs)
    summaries = {
        (mode, s.name): summarise(
            [r for r in runs if r.mode == mode and r.setup == s.name], limit_s=args.minutes * 60
        )
        for mode in modes
        for s in setups
    }
    print()
    for (mode, name), s in summaries.items():
        if s.runs:
            print(f"{mode} {name}: median {fmt(s.median_s)} s, {fmt(s.median_steps, 0)} steps "
                  f"to the goal ({s.reached} of {s.runs} seeds reached it; slowest "
                  f"{fmt(s.worst_s)} s), median qualifying lap {fmt(s.lap_s, 2)} s, "
                  f"best lap {fmt(s.best_lap_s, 2)} s (each seed's best: median "
                  f"{fmt(s.seed_best_s, 2)} s)")  # fmt: skip
            if args.target_kl is not None:
                mine = [r for r in runs if (r.mode, r.setup) == (mode, name)]
                updates = sum(r.updates for r in mine)
                print(f"{mode} {name}: target_kl {args.target_kl:g}, "
                      f"{sum(r.epochs for r in mine) / max(updates, 1):.2f} epochs per update "
                      f"(mean over the {updates} updates up to the goal)")  # fmt: skip
    if args.target_kl is not None:
        print(f"target_kl={args.target_kl:g}")
    print(f"machine after: {machine()}")
    first = modes[0]
    line = [key_values(summaries[first, "defaults"], summaries[first, "fast"])]
    for mode in modes[1:]:
        line.append(mode_key_values(mode, summaries[mode, "defaults"], summaries[mode, "fast"],
                                    summaries[first, "fast"]))  # fmt: skip
    print(" ".join(line))


if __name__ == "__main__":
    main()
