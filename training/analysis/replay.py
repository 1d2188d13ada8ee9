"""Reward replay: DeepRacer's ``params`` rebuilt for every step of a recorded episode, so a
new reward function can be run on what the car really did (in the sandbox, by the caller).

A sim-trace row holds the reported point (``X, Y``, metres), the heading (``yaw``, degrees),
the commanded steering (degrees) and speed (m/s), progress (%), the step number, whether all
wheels were on the track and the episode's status; the rest of ``params`` (distance from the
centre, closest waypoints, track width, ...) comes from the track, as the simulator computes
it (:func:`racing.params.build_params`). Objects are not logged, so object keys are empty
(as in a time trial).

``sim_time`` comes from the recorded ``tstamp``, relative to the episode's start, as the
reward saw it (:func:`sim_times`): DeepRacer stamps an episode's first row, ``prepare``, at
the episode's start (``tstamp`` is the car's running clock), though the reward of that first
step already saw one control step (1/15 s) go by.
"""

from __future__ import annotations

import csv
import io
import math

from racing.car import CONTROL_HZ, REPORTED_POINT_AHEAD_M, Pose
from racing.params import build_params
from racing.track import Track

MAX_REPLAY_STEPS = 5000
"""A replay covers at most this many steps (a long lap at 15 steps a second is ~1500)."""


class ReplayError(ValueError):
    """The episode is not in the file, or its rows are malformed."""


def episode_rows(data: bytes, episode: int) -> list[dict[str, str]]:
    """The rows of ``episode`` in a sim-trace file, in step order (``dict`` per row)."""
    reader = csv.DictReader(io.StringIO(data.decode("utf-8", "replace")))
    wanted = str(int(episode))
    rows = [row for row in reader if row.get("episode") == wanted]
    if not rows:
        raise ReplayError(f"episode {episode} is not in this file")
    if len(rows) > MAX_REPLAY_STEPS:
        raise ReplayError(f"episode {episode} has more than {MAX_REPLAY_STEPS} steps")
    try:
        rows.sort(key=lambda r: float(r["steps"]))
    except (KeyError, ValueError):
        raise ReplayError("the sim-trace rows are malformed") from None
    return rows


def _flag(text: str) -> bool:
    return text.strip().lower() == "true"


def sim_times(rows: list[dict[str, str]]) -> list[float]:
    """The simulated time (s) each row's reward saw, from the rows' ``tstamp``.

    The episode started at the ``prepare`` row's stamp when the first row is one (DeepRacer's
    files and ours); otherwise (a trace cut from the simulator's own rows, whose stamps are
    the episode's time after each step) one control step per step before the first row.
    A step's time is its stamp minus the start; the ``prepare`` row, stamped at the start,
    saw its own step's time. Raises ``KeyError``/``ValueError`` for malformed rows.
    """
    dt = 1.0 / CONTROL_HZ
    first = rows[0]
    prepare = first.get("episode_status", "") == "prepare"
    start = float(first["tstamp"]) - (0.0 if prepare else float(first["steps"]) * dt)
    times = [float(row["tstamp"]) - start for row in rows]
    if prepare:
        times[0] = float(first["steps"]) * dt
    return [round(t, 6) for t in times]


def step_params(rows: list[dict[str, str]], track: Track) -> list[dict]:
    """``params`` for each row, as the reward function saw them (see the module's doc)."""
    out = []
    try:
        times = sim_times(rows)
        hint = None
        for row, sim_time in zip(rows, times, strict=True):
            x, y = float(row["X"]), float(row["Y"])
            yaw = math.radians(float(row["yaw"]))
            status = row.get("episode_status", "")
            loc = track.locate(x, y, hint)
            hint = loc.segment
            pose = Pose(x - REPORTED_POINT_AHEAD_M * math.cos(yaw),
                        y - REPORTED_POINT_AHEAD_M * math.sin(yaw), yaw)  # fmt: skip
            on_track = _flag(row["all_wheels_on_track"])
            out.append(build_params(
                track=track, pose=pose, loc=loc,
                wheels_on_track=4 if on_track else (0 if status == "off_track" else 2),
                steering_angle=float(row["steer"]), speed=float(row["throttle"]),
                progress=float(row["progress"]), steps=int(float(row["steps"])),
                is_crashed=status == "crashed", sim_time=sim_time,
            ))  # fmt: skip
    except (KeyError, ValueError) as exc:
        raise ReplayError(f"the sim-trace rows are malformed: {exc}") from None
    return out


def replay_table(rows: list[dict[str, str]], new_rewards: list[float | None]) -> dict:
    """Step by step and in total: the recorded reward next to the new one (None where the
    new function failed)."""
    old = [float(r["reward"]) for r in rows]
    new_total = sum(v for v in new_rewards if v is not None)
    return {
        "steps": [int(float(r["steps"])) for r in rows],
        "x": [float(r["X"]) for r in rows],
        "y": [float(r["Y"]) for r in rows],
        "old_reward": [round(v, 4) for v in old],
        "new_reward": [None if v is None else round(v, 4) for v in new_rewards],
        "old_total": round(sum(old), 3),
        "new_total": round(new_total, 3),
        "failed_steps": sum(v is None for v in new_rewards),
    }
