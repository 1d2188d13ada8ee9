"""The readiness check: how a model drives in conditions it never trained on, before it goes to
the real car (issue 51).

The check drives the policy from the start line for a few laps in each cell of a plan: the
clean world (the baseline row), then each family of :mod:`racing.conditions` (light, look,
camera, car, latency) alone at several strengths (0..1 of the way to the edge of that family's
widest range, :meth:`racing.conditions.Conditions.at_strength`). A lap counts as completed only
when the car finishes it without leaving the track or crashing (no resets: on the real car a
lap off the track is a lap lost), so an episode of ``laps`` laps ends at the first failure and
the laps it did not reach count as attempted and not completed.

The result is a JSON-able table (:class:`ReadinessTable`): per cell, laps completed / attempted,
completion %, median lap time (simulated seconds) of the completed laps, mean progress (%); the
worst cells; a one-line verdict (:func:`verdict`); and, on request, MP4s of the worst cells
(driven again with the same seeds, so the video shows the run the table measured).

Seeds: every cell draws its conditions and its env reset from
``SeedSequence([seed, family index, strength index, episode, SEED_TAG])``. Training runs seed
their generators with one small integer (a model's ``seed``, a job's conditions seed), i.e. a
one-word entropy; the check's five-word entropy ends in the non-zero ``SEED_TAG``, so it equals
no integer below 2**128 and no training run can have drawn the check's conditions.

No user code runs here (the reward is not needed: completion and lap times come from the lap
tracker), and like an evaluation it refuses to run in a process that ever loaded a reward
function (:mod:`training.sandbox.taint`).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np

from racing.env import Observation, RacingEnv
from racing.rules import RaceRules, Status
from racing.sensors import ground_for
from racing.video import ChaseView
from training.rl.evaluation import MAX_LAP_SECONDS, VideoWriter
from training.rollout.envs import EnvSpec, camera_image
from training.sandbox.taint import refuse_if_tainted

SEED_TAG = 0x52454459
"""``"REDY"``: the last word of every seed the check draws (see the module's docstring)."""
DEFAULT_STRENGTHS = (0.33, 0.67, 1.0)
DEFAULT_LAPS = 2
"""Laps per episode of a cell (one episode per cell by default: minutes on two cores)."""
MAX_LAPS, MAX_EPISODES, MAX_STRENGTHS = 5, 5, 5
READY_PCT = 80.0
"""A family passes when the model completes at least this share of its laps at the plan's
medium strength, and the model drives at all when it does in the clean world."""
WORST_CELLS = 2
"""How many of the worst cells get a video."""
CLEAN = "clean"

PolicyFactory = Callable[[RacingEnv], Callable[[Observation], object]]
"""Builds the policy (observation → action) for the env the check drives: an SB3 model's
``predict`` ignores the env; a scripted driver (tests, benches) reads the car's pose from it."""


class ReadinessError(ValueError):
    """A plan outside what the check allows."""


def _families() -> tuple[str, ...]:
    from racing.conditions import FAMILIES

    return tuple(FAMILIES)


@dataclass(frozen=True)
class ReadinessPlan:
    """Which cells the check drives: ``families`` × ``strengths`` (each 0 < s <= 1), plus the
    clean baseline; ``episodes`` episodes of ``laps`` laps per cell; ``seed`` picks another
    draw of the check's own seeds (the job records it)."""

    families: tuple[str, ...] = ()
    strengths: tuple[float, ...] = DEFAULT_STRENGTHS
    laps: int = DEFAULT_LAPS
    episodes: int = 1
    seed: int = 0

    def __post_init__(self) -> None:
        known = _families()
        if not self.families:
            object.__setattr__(self, "families", known)
        unknown = [f for f in self.families if f not in known]
        if unknown:
            raise ReadinessError(f"unknown condition families: {', '.join(unknown)}")
        if not self.strengths or len(self.strengths) > MAX_STRENGTHS:
            raise ReadinessError(f"a check runs 1 to {MAX_STRENGTHS} strengths")
        if any(not 0 < s <= 1 for s in self.strengths):
            raise ReadinessError("strengths are between 0 (excluded) and 1")
        if list(self.strengths) != sorted(self.strengths):
            raise ReadinessError("strengths go from the weakest to the strongest")
        if not 1 <= self.laps <= MAX_LAPS:
            raise ReadinessError(f"a cell drives 1 to {MAX_LAPS} laps")
        if not 1 <= self.episodes <= MAX_EPISODES:
            raise ReadinessError(f"a cell drives 1 to {MAX_EPISODES} episodes")
        if not 0 <= self.seed < 2**31:
            raise ReadinessError("the seed is 0 to 2**31 - 1")

    @property
    def medium(self) -> float:
        """The strength the verdict judges by: the middle one of the plan."""
        return self.strengths[len(self.strengths) // 2]

    def cells(self) -> list[tuple[str, float]]:
        """``(family, strength)`` of every cell, the clean baseline (strength 0) first."""
        return [(CLEAN, 0.0), *((f, s) for f in self.families for s in self.strengths)]

    def to_dict(self) -> dict:
        data = asdict(self)
        data["families"], data["strengths"] = list(self.families), list(self.strengths)
        return data

    @classmethod
    def from_dict(cls, data: dict) -> ReadinessPlan:
        return cls(
            families=tuple(data.get("families") or ()),
            strengths=tuple(float(s) for s in data.get("strengths") or DEFAULT_STRENGTHS),
            laps=int(data.get("laps", DEFAULT_LAPS)),
            episodes=int(data.get("episodes", 1)),
            seed=int(data.get("seed", 0)),
        )


@dataclass
class Cell:
    """One row of the table. Times in simulated seconds, ``mean_progress`` in % of a lap over
    the laps attempted (a completed lap counts 100)."""

    family: str
    strength: float
    laps_attempted: int = 0
    laps_completed: int = 0
    lap_times_s: list[float] = field(default_factory=list)
    progress: list[float] = field(default_factory=list)
    statuses: list[str] = field(default_factory=list)
    conditions: list[dict] = field(default_factory=list)
    """Each episode's values of the cell's family (``{}`` in the clean world)."""
    steps: int = 0

    @property
    def completion_pct(self) -> float:
        return 100.0 * self.laps_completed / self.laps_attempted if self.laps_attempted else 0.0

    @property
    def median_lap_s(self) -> float | None:
        return round(statistics.median(self.lap_times_s), 3) if self.lap_times_s else None

    @property
    def mean_progress(self) -> float:
        return round(sum(self.progress) / len(self.progress), 2) if self.progress else 0.0

    def to_dict(self) -> dict:
        return {
            "family": self.family,
            "strength": self.strength,
            "laps_attempted": self.laps_attempted,
            "laps_completed": self.laps_completed,
            "completion_pct": round(self.completion_pct, 1),
            "median_lap_s": self.median_lap_s,
            "mean_progress": self.mean_progress,
            "lap_times_s": [round(t, 3) for t in self.lap_times_s],
            "statuses": list(self.statuses),
            "conditions": list(self.conditions),
        }


def _badness(cell: dict) -> tuple:
    """Worst first: fewer laps completed, less progress, slower laps."""
    return (cell["completion_pct"], cell["mean_progress"], -(cell["median_lap_s"] or 0.0))


def worst_cells(cells: Sequence[dict], n: int = WORST_CELLS) -> list[dict]:
    """The ``n`` worst cells under conditions (the baseline is not one of them)."""
    return sorted((c for c in cells if c["family"] != CLEAN), key=_badness)[:n]


def _pct(value: float) -> str:
    return f"{value:.0f} %"


def verdict(cells: Sequence[dict], medium: float) -> tuple[bool, str]:
    """``(ready, one line)`` from a table's cells, by three rules in order:

    1. the clean baseline completes less than ``READY_PCT`` % of its laps: "Not ready: ...";
    2. some family at the ``medium`` strength completes less than ``READY_PCT`` %: "Fragile to
       <family>: ..." (the weakest such family; ties in the plan's order);
    3. else "Ready: completes at least <the lowest> % of laps under every family at medium
       strength".
    """
    base = next((c for c in cells if c["family"] == CLEAN), None)
    if base is None or base["completion_pct"] < READY_PCT:
        pct = base["completion_pct"] if base else 0.0
        return False, f"Not ready: completes {_pct(pct)} of laps even in the clean world"
    at_medium = [c for c in cells if c["family"] != CLEAN and c["strength"] == medium]
    if not at_medium:
        return True, f"Ready: completes {_pct(base['completion_pct'])} of laps (no family tested)"
    weakest = min(at_medium, key=lambda c: c["completion_pct"])  # min keeps the first of ties
    if weakest["completion_pct"] < READY_PCT:
        return False, (
            f"Fragile to {weakest['family']}: completes {_pct(weakest['completion_pct'])} of "
            f"laps at strength {medium:g}"
        )
    return True, (
        f"Ready: completes at least {_pct(weakest['completion_pct'])} of laps under every "
        "family at medium strength"
    )


@dataclass
class ReadinessTable:
    plan: ReadinessPlan
    cells: list[dict]
    ready: bool
    verdict: str
    stopped: bool = False
    steps: int = 0
    wall_s: float = 0.0
    videos: dict[str, bytes] = field(default_factory=dict)
    """MP4s of the worst cells, keyed by :func:`cell_key`."""

    @property
    def worst(self) -> list[dict]:
        return worst_cells(self.cells)

    def to_json(self) -> dict:
        return {
            "version": 1,
            "plan": self.plan.to_dict(),
            "seed_tag": SEED_TAG,
            "cells": self.cells,
            "worst": [cell_key(c["family"], c["strength"]) for c in self.worst],
            "ready": self.ready,
            "verdict": self.verdict,
            "stopped": self.stopped,
            "steps": self.steps,
            "wall_s": round(self.wall_s, 1),
        }


def cell_key(family: str, strength: float) -> str:
    """A cell's name in object keys and JSON: ``light-0_67``, ``clean-0``."""
    return f"{family}-{strength:g}".replace(".", "_")


def cell_seed(plan: ReadinessPlan, family: str, strength: float, episode: int):
    """The check's own seed for one episode of one cell (see the module's docstring)."""
    fam = 0 if family == CLEAN else 1 + plan.families.index(family)
    strength_index = 0 if family == CLEAN else 1 + plan.strengths.index(strength)
    return np.random.SeedSequence([plan.seed, fam, strength_index, episode, SEED_TAG])


def cell_conditions(plan: ReadinessPlan, family: str, strength: float, episode: int):
    """The conditions one episode of one cell drives in, and its env reset seed."""
    from racing.conditions import Conditions

    seq = cell_seed(plan, family, strength, episode)
    rng = np.random.default_rng(seq)
    reset_seed = int(seq.generate_state(1)[0] & 0x7FFFFFFF)
    if family == CLEAN:
        return Conditions.clean(), reset_seed
    return Conditions.at_strength(family, strength, rng), reset_seed


def check_env(spec: EnvSpec, plan: ReadinessPlan) -> RacingEnv:
    """The check's env: from the start line, ``plan.laps`` laps, no resets, no reward."""
    rules = RaceRules(laps=plan.laps, resets=0, time_limit_s=plan.laps * MAX_LAP_SECONDS)
    return spec.make(lambda params: 0.0, start="start_line", alternate_direction=False,
                     rules=rules)  # fmt: skip


def _episode(
    env: RacingEnv,
    policy: Callable[[Observation], object],
    conditions,
    reset_seed: int,
    should_stop: Callable[[], bool] | None,
    video: VideoWriter | None = None,
    chase: ChaseView | None = None,
) -> tuple[list, float, bool]:
    """Drive one episode; returns ``(finished laps, progress of the lap it ended in, stopped)``."""
    env.set_conditions(conditions)
    obs, _ = env.reset(seed=reset_seed)
    while True:
        obs, _, terminated, truncated, _ = env.step(policy(obs))
        if video is not None and chase is not None:
            video.add(chase.render(env.pose, env.objects), camera_image(obs)[..., 0])
        if terminated or truncated:
            return list(env.tracker.laps), float(env.tracker.progress), False
        if should_stop is not None and should_stop():
            return list(env.tracker.laps), float(env.tracker.progress), True


def _drive_cell(env, policy, plan, family, strength, should_stop) -> tuple[Cell, bool]:
    cell = Cell(family=family, strength=strength)
    for episode in range(plan.episodes):
        conditions, reset_seed = cell_conditions(plan, family, strength, episode)
        laps, progress, stopped = _episode(env, policy, conditions, reset_seed, should_stop)
        if stopped:
            return cell, True
        cell.steps += env.tracker.steps
        # The cell's own family's parameters (the others are neutral): what the page shows.
        cell.conditions.append({} if family == CLEAN else conditions.to_dict()[family])
        done = [lap for lap in laps if lap.status is Status.LAP_COMPLETE]
        cell.laps_attempted += plan.laps
        cell.laps_completed += len(done)
        cell.lap_times_s += [float(lap.time_s) for lap in done]
        cell.statuses += [lap.status.value for lap in laps]
        failed = plan.laps - len(done)
        if failed:  # the lap it ended in, then the laps it never reached
            cell.statuses.append(str(env.tracker.current_lap.status.value))
            cell.progress += [100.0] * len(done) + [progress] + [0.0] * (failed - 1)
        else:
            cell.progress += [100.0] * len(done)
    return cell, False


def check_readiness(
    policy_for: PolicyFactory,
    spec: EnvSpec,
    plan: ReadinessPlan | None = None,
    *,
    videos: int = WORST_CELLS,
    on_progress: Callable[[dict], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
) -> ReadinessTable:
    """Drive the policy through every cell of ``plan`` on ``spec``'s track and direction (a
    one-track spec; its race's boxes or bots stay on the track) and return the table, the
    verdict and MP4s of the ``videos`` worst cells. ``on_progress`` gets ``{"cells_done",
    "cells_total", "family", "strength"}`` after each cell; ``should_stop`` is polled every
    step (a stopped check keeps the cells it finished, and gets no video)."""
    refuse_if_tainted("A readiness check")
    plan = plan or ReadinessPlan()
    started = time.monotonic()
    env = check_env(spec, plan)
    policy = policy_for(env)
    cells: list[dict] = []
    stopped = False
    steps = 0
    try:
        todo = plan.cells()
        for family, strength in todo:
            cell, stopped = _drive_cell(env, policy, plan, family, strength, should_stop)
            steps += cell.steps
            if stopped:
                break
            cells.append(cell.to_dict())
            if on_progress is not None:
                on_progress({"cells_done": len(cells), "cells_total": len(todo),
                             "family": family, "strength": strength})  # fmt: skip
        mp4s = {} if stopped else _videos(env, policy, plan, worst_cells(cells, videos))
    finally:
        env.close()
    ready, line = verdict(cells, plan.medium) if not stopped else (False, "Stopped")
    return ReadinessTable(plan=plan, cells=cells, ready=ready, verdict=line, stopped=stopped,
                          steps=steps, wall_s=time.monotonic() - started,
                          videos=mp4s)  # fmt: skip


def _videos(env, policy, plan: ReadinessPlan, worst: list[dict]) -> dict[str, bytes]:
    """MP4s of the worst cells' first episodes, driven again with the same seeds."""
    out: dict[str, bytes] = {}
    if not worst:
        return out
    chase = ChaseView(ground_for(env.track, resolution=0.01, rgb=True))
    for cell in worst:
        conditions, reset_seed = cell_conditions(plan, cell["family"], cell["strength"], 0)
        video = VideoWriter()
        _episode(env, policy, conditions, reset_seed, None, video=video, chase=chase)
        mp4 = video.finish()
        if mp4:
            out[cell_key(cell["family"], cell["strength"])] = mp4
    return out
