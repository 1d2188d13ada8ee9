"""How fast an action space can lap a track: a search driver's laps against a one-frame driver's.

Issue 50 asks the racing preset for a best lap of at most 5.0 s on re:Invent 2018 and a median
qualifying lap of at most 5.6 s; trained models give 5.33 s and 5.8-5.9 s. Is that the models
or the six actions? This bench drives the same env (the same physics, rules and laps as an
evaluation: standing start on the start line, ``--laps`` laps) two ways:

- **the search driver** knows the whole state (pose, speed, the steering servo) and looks ahead
  in the simulator itself: at every step it tries each sequence of ``depth`` actions followed by
  ``horizon - depth`` steps of a safe continuation (pure pursuit of a point ``lookahead`` metres
  ahead, the nearest steering at its slowest speed), from a snapshot of the world
  (:meth:`racing.car.CarSim.snapshot`), and takes the first action of the sequence that gets
  furthest without leaving the track. Each setting of the grid (``--depths``, ``--horizons``,
  ``--lookaheads``) is one drive; the chosen actions are then replayed from reset in a fresh
  env, whose own tracker gives the laps (the table says whether the replay agreed);
- **the baseline**, measured in the same run: a driver that knows no more than one camera
  frame shows, like the one issue 51 drove through its check (pure pursuit of a point 0.6-1.5 m
  ahead and each of ``--lookaheads``, the nearest steering at its fastest speed, straight ahead
  slower where the track within 1 m bends; no speed, no memory), its best lap.

A search lap is what the actions and the physics allow, not what a policy that sees one camera
frame can learn; the grid's best lap is one the actions can drive, so the fastest lap they allow
is at most that, and may be faster.
Last line: ``bound_lap_s=`` (the best lap of any search drive), ``bound_start_lap_s=`` (its best
first lap, from a standing start), ``bound_median_lap_s=`` (the median lap over the grid's
drives that finished), ``pursuit_lap_s=`` (the baseline's best lap) and ``ratio=`` (bound over
baseline).

    .venv/bin/python bench/bench_lap_bound.py [--track reinvent_base] [--laps 3]
        [--actions JSON] [--depths 2 3] [--horizons 6 10] [--lookaheads 1.3 1.6 2.0]
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import itertools
import json
import math
import os
import platform
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from racing.car import WHEELBASE_M
from racing.env import RacingEnv
from racing.rules import RaceRules
from training.rl.presets import RACING

FAILED = ("off_track", "crashed", "reversed", "immobilized")
PURSUIT_LOOKAHEADS = (0.6, 0.9, 1.2, 1.5)
"""The baseline's look-aheads, metres (with ``--lookaheads``): a short one laps tight tracks."""


@dataclass(frozen=True)
class Drive:
    """One drive: its setting, the actions chosen, the laps (seconds) and how it ended."""

    setting: str
    actions: tuple[int, ...]
    laps: tuple[float, ...]
    status: str
    seconds: float
    replayed: bool | None = None


def make_env(track: str, actions: list[dict], laps: int) -> RacingEnv:
    return RacingEnv(track=track, action_space=actions, rules=RaceRules(laps=laps),
                     start="start_line")  # fmt: skip


def pursuit(env: RacingEnv, lookahead: float, fast: bool) -> int:
    """Pure pursuit of the centre line ``lookahead`` metres ahead, quantised to the env's
    nearest steering; at that steering the fastest speed (``fast``) or the slowest."""
    choices = [(float(a["steering_angle"]), float(a["speed"]))
               for a in env.actions.to_metadata()]  # fmt: skip
    pose, track = env.pose, env.track
    loc = track.locate(pose.x, pose.y)
    tx, ty = track.point_at(loc.s + lookahead, 0.0)
    alpha = math.atan2(ty - pose.y, tx - pose.x) - pose.yaw
    alpha = math.atan2(math.sin(alpha), math.cos(alpha))
    dist = max(math.hypot(tx - pose.x, ty - pose.y), 1e-6)
    steer = math.degrees(math.atan2(2 * WHEELBASE_M * math.sin(alpha), dist))
    sign = -1.0 if fast else 1.0
    return min(range(len(choices)),
               key=lambda i: (abs(choices[i][0] - steer), sign * choices[i][1]))  # fmt: skip


class Snapshots:
    """The env's state at a step, to try actions from it and come back."""

    def __init__(self, env: RacingEnv) -> None:
        self.env = env

    def take(self):
        car = self.env.car
        return (car.sim.snapshot(), copy.deepcopy(car.pose), car.point, car.hint, car.s,
                copy.deepcopy(car.tracker), self.env.sim_time)  # fmt: skip

    def back(self, state) -> None:
        world, pose, point, hint, s, tracker, sim_time = state
        car = self.env.car
        car.sim.restore(world)
        car.pose, car.point, car.hint, car.s = copy.deepcopy(pose), point, hint, s
        car.tracker = copy.deepcopy(tracker)
        self.env.sim_time = sim_time

    def forget(self, state) -> None:
        self.env.car.sim.forget(state[0])


def reached(env: RacingEnv) -> float:
    """Laps driven, in percent of a lap."""
    tracker = env.car.tracker
    return tracker.progress + 100.0 * len(tracker.laps)


def try_ahead(env: RacingEnv, first: Sequence[int], horizon: int, lookahead: float) -> float:
    """Drive ``first``, then the safe continuation up to ``horizon`` steps: how far it got (a
    finish counts by its time; leaving the track by far less than anything on it)."""
    for step in range(horizon):
        action = first[step] if step < len(first) else pursuit(env, lookahead, fast=False)
        _, _, done, _, info = env.step(action)
        if info["status"] in FAILED:
            return -1e9 + reached(env)
        if done:
            return 1e6 - env.sim_time
    return reached(env)


def search_drive(track: str, actions: list[dict], laps: int, depth: int, horizon: int,
                 lookahead: float, max_steps: int = 5000) -> Drive:  # fmt: skip
    sequences = list(itertools.product(range(len(actions)), repeat=depth))

    def search(env: RacingEnv) -> int:
        snapshots = Snapshots(env)
        here = snapshots.take()
        scores = []
        for sequence in sequences:
            snapshots.back(here)
            scores.append((try_ahead(env, sequence, horizon, lookahead), sequence[0]))
        snapshots.back(here)
        snapshots.forget(here)
        return max(scores, key=lambda pair: pair[0])[1]  # the first of equals: stable

    setting = f"search depth {depth}, horizon {horizon}, look-ahead {lookahead:g} m"
    drive = policy_drive(track, actions, laps, setting, search, max_steps)
    return replay(drive, track, actions, laps)


def replay(drive: Drive, track: str, actions: list[dict], laps: int) -> Drive:
    """The drive's actions from reset in a fresh env: its laps, and whether they agree."""
    taken = iter(drive.actions)
    again = policy_drive(track, actions, laps, drive.setting, lambda env: next(taken),
                         max_steps=len(drive.actions))  # fmt: skip
    return dataclasses.replace(drive, laps=again.laps, status=again.status,
                               replayed=again.laps == drive.laps)  # fmt: skip


def policy_drive(track: str, actions: list[dict], laps: int, setting: str,
                 act: Callable[[RacingEnv], int], max_steps: int = 5000) -> Drive:  # fmt: skip
    """``act`` drives ``laps`` laps from the start line, for at most ``max_steps`` steps."""
    env = make_env(track, actions, laps)
    env.reset(seed=0)
    chosen: list[int] = []
    started = time.perf_counter()
    info: dict = {"status": "prepare", "laps": []}
    try:
        for _ in range(max_steps):
            action = act(env)
            _, _, done, truncated, info = env.step(action)
            chosen.append(action)
            if done or truncated:
                break
    finally:
        env.close()
    return Drive(setting, tuple(chosen), lap_times(info), info["status"],
                 time.perf_counter() - started)  # fmt: skip


def lap_times(info: dict) -> tuple[float, ...]:
    return tuple(round(lap.time_s, 3) for lap in info["laps"] if lap.status.value == "lap_complete")


def one_frame_driver(lookahead: float) -> Callable[[RacingEnv], int]:
    """A driver that sees one frame: pursuit at the fastest speed of the steering, the slowest
    straight ahead where the track within 1 m bends."""

    def act(env: RacingEnv) -> int:
        index = pursuit(env, lookahead, fast=True)
        action = env.actions.to_metadata()[index]
        if float(action["steering_angle"]) == 0.0:
            loc = env.track.locate(env.pose.x, env.pose.y)
            return pursuit(env, lookahead, fast=env.track.curvature_ahead(loc.s, 1.0) < 0.5)
        return index

    return act


def summary(search: list[Drive], baseline: list[Drive], laps: int) -> dict[str, float]:
    finished = [d for d in search if len(d.laps) == laps]
    every = [t for d in finished for t in d.laps]
    pursued = [t for d in baseline for t in d.laps]
    bound = min(every) if every else math.nan
    start = min((d.laps[0] for d in finished), default=math.nan)
    pursuit_lap = min(pursued) if pursued else math.nan
    return {
        "bound_lap_s": bound,
        "bound_start_lap_s": start,
        "bound_median_lap_s": statistics.median(every) if every else math.nan,
        "pursuit_lap_s": pursuit_lap,
        "ratio": bound / pursuit_lap if every and pursued else math.nan,
    }


def table(drives: list[Drive]) -> str:
    rows = ["| driver | laps (s) | ended | replay agrees | wall s |", "|---|---|---|---|---|"]
    for d in drives:
        laps = " / ".join(f"{t:.2f}" for t in d.laps) or "-"
        agrees = {None: "-", True: "yes", False: "NO"}[d.replayed]
        rows.append(f"| {d.setting} | {laps} | {d.status} | {agrees} | {d.seconds:.0f} |")
    return "\n".join(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--track", default="reinvent_base")
    parser.add_argument("--laps", type=int, default=3)
    parser.add_argument("--actions", help="a JSON list of {steering_angle, speed}; default: "
                        "the racing preset's")  # fmt: skip
    parser.add_argument("--depths", type=int, nargs="+", default=[2, 3])
    parser.add_argument("--horizons", type=int, nargs="+", default=[6, 10])
    parser.add_argument("--lookaheads", type=float, nargs="+", default=[1.3, 1.6, 2.0])
    args = parser.parse_args()
    actions = json.loads(args.actions) if args.actions else RACING.actions()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.1f}")  # fmt: skip
    print(f"track {args.track}, {args.laps} laps from the start line, {len(actions)} actions: "
          f"{json.dumps(actions)}\n")  # fmt: skip
    baseline = [policy_drive(args.track, actions, args.laps,
                             f"one-frame pursuit, look-ahead {look:g} m", one_frame_driver(look))
                for look in sorted({*PURSUIT_LOOKAHEADS, *args.lookaheads})]  # fmt: skip
    search = [search_drive(args.track, actions, args.laps, depth, horizon, look)
              for depth in args.depths for horizon in args.horizons
              for look in args.lookaheads]  # fmt: skip
    print(table(baseline + search))
    figures = summary(search, baseline, args.laps)
    print("\n" + " ".join(f"{k}={v:.3f}" if k == "ratio" else f"{k}={v:.2f}"
                          for k, v in figures.items()))  # fmt: skip


if __name__ == "__main__":
    main()
