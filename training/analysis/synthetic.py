"""Synthetic training sim-traces on a real track, for the analysis benchmark and tests: cars
that follow the centre line with some wander, at 15 steps a simulated second, in DeepRacer's
format (whole episodes with a ``prepare`` first row, numbered across the run)."""

from __future__ import annotations

import io

import numpy as np

from racing.simtrace import SIMTRACE_COLUMNS
from racing.track import Track

STEP_S = 1 / 15


def synthetic_iteration(
    track: Track,
    *,
    iteration: int,
    episodes: int,
    num_actions: int,
    seed: int = 0,
    mean_steps: int = 100,
    continuous: tuple[tuple[float, float], tuple[float, float]] | None = None,
) -> bytes:
    """One ``<iteration>-iteration.csv``: ``episodes`` episodes numbered from
    ``iteration * episodes``; about one in four completes a lap, the rest go off track.
    ``continuous``: the steering (degrees) and speed (m/s) ranges of a continuous action
    space, whose actions are then drawn from them and logged as ``[steer speed]``."""
    rng = np.random.default_rng(seed + iteration)
    out = io.StringIO()
    out.write(",".join(SIMTRACE_COLUMNS) + "\n")
    clock = iteration * episodes * mean_steps * STEP_S
    lap_steps = int(track.length / 2.0 / STEP_S)  # a lap at 2 m/s
    line = np.vstack([track.centre, track.centre[:1]]) if track.closed else track.centre
    for k in range(episodes):
        number = iteration * episodes + k
        complete = rng.random() < 0.25
        n = lap_steps if complete else int(rng.integers(10, max(11, 2 * mean_steps)))
        start = rng.random() * track.length
        speed = rng.uniform(*(continuous[1] if continuous else (1.0, 3.0)), n)
        s = start + np.cumsum(speed * STEP_S)
        progress = np.minimum(100.0, 100.0 * (s - start) / track.length)
        if complete:
            progress[-1] = 100.0
        along = s % track.length
        x = np.interp(along, track.cumulative, line[:, 0])
        y = np.interp(along, track.cumulative, line[:, 1])
        x += rng.normal(0, 0.05, n)
        y += rng.normal(0, 0.05, n)
        action = rng.integers(0, max(1, num_actions), n).astype(str)
        steer = np.zeros(n)
        if continuous is not None:
            steer = rng.uniform(*continuous[0], n)
            action = np.array([f"[{a:.2f} {v:.2f}]" for a, v in zip(steer, speed, strict=True)])
        reward = rng.uniform(0, 1, n)
        waypoint = (along / track.length * track.num_waypoints).astype(int)
        for i in range(n):
            last = i == n - 1
            end = "lap_complete" if complete else "off_track"
            status = "prepare" if i == 0 else (end if last else "in_progress")
            out.write(
                f"{number},{i + 1},{x[i]:.4f},{y[i]:.4f},0.0,{steer[i]:.2f},{speed[i]:.2f},"
                f"{action[i]},{reward[i]:.4f},{last},{not last or complete},{progress[i]:.4f},"
                f"{waypoint[i]},{track.length:.2f},{clock + i * STEP_S:.3f},{status},0.00,0,0.0\n"
            )
        clock += n * STEP_S
    return out.getvalue().encode()
