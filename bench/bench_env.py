"""Env steps per second: the camera-only time trial (fast path against PyBullet rendering) and
object avoidance with 6 boxes seen by the stereo camera and the LIDAR.

All run in this one process, on the same track, with the same random actions and the default
reward. Each row gives steps per second of wall-clock time and of the process's CPU time (the
two differ when other work shares the machine). The reference renders every observation with
PyBullet's getCameraImage (TinyRenderer) instead of the homography camera; everything else is
the same env. The objects row places 6 boxes at random each episode and observes
``STEREO_CAMERAS`` + ``LIDAR`` (a Dict observation).

    .venv/bin/python bench/bench_env.py [--track ID_OR_PATH] [--steps N]

Last line: ``steps_per_s=… reference_steps_per_s=… ratio=… objects_steps_per_s=…`` (targets:
≥ 2,000, ≥ 15× and ≥ 1,000 steps/s per core).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from racing.env import RacingEnv  # noqa: E402
from racing.race import RaceConfig, RaceType  # noqa: E402
from racing.track import Track  # noqa: E402

cv2.setNumThreads(1)


def load_track(name: str) -> Track | str:
    """A ``.npy`` file's track, or ``name`` as a catalogue id (DeepRacer's tracks are built in)."""
    path = Path(name)
    if path.suffix == ".npy" and path.exists():
        return Track.from_file(path)
    return name  # a catalogue id


def measure(env: RacingEnv, actions: np.ndarray) -> tuple[float, float, int]:
    """Steps per second of wall-clock time and of this process's CPU time, and episodes run.

    On a machine shared with other work the wall clock also counts the time other processes
    held the core; CPU time does not, so the two together say how loaded the run was."""
    env.reset(seed=0)
    episodes = 1
    start, cpu_start = time.perf_counter(), time.process_time()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(int(a))
        if terminated or truncated:
            env.reset()
            episodes += 1
    wall = len(actions) / (time.perf_counter() - start)
    return wall, len(actions) / (time.process_time() - cpu_start), episodes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--track", default="reinvent_base")
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--reference-steps", type=int, default=600)
    args = parser.parse_args()
    track = load_track(args.track)
    rng = np.random.default_rng(0)
    # Mostly straight-ish actions so episodes last a while, as during real training.
    actions = rng.choice(
        10, size=args.steps, p=[0.05, 0.05, 0.1, 0.1, 0.15, 0.15, 0.1, 0.1, 0.1, 0.1]
    )

    fast_env = RacingEnv(track, start="round_robin")
    measure(fast_env, actions[:500])  # warm-up: textures, caches
    fast, fast_cpu, fast_eps = measure(fast_env, actions)
    race = RaceConfig(
        race_type=RaceType.OBJECT_AVOIDANCE, number_of_objects=6, randomize_objects=True
    )
    objects_env = RacingEnv(
        track, start="round_robin", sensors=["STEREO_CAMERAS", "LIDAR"], race=race
    )
    measure(objects_env, actions[:500])
    objects, objects_cpu, objects_eps = measure(objects_env, actions)
    objects_env.close()
    ref_env = RacingEnv(track, start="round_robin", camera_backend="pybullet")
    measure(ref_env, actions[:20])
    ref, ref_cpu, ref_eps = measure(ref_env, actions[: args.reference_steps])
    fast_env.close()
    ref_env.close()

    name = track if isinstance(track, str) else track.track_id
    print(f"track: {name}   observation: 160x120 grayscale front camera   one process")
    print(f"{'path':<36}{'steps':>8}{'episodes':>10}{'steps/s':>10}{'CPU steps/s':>13}")
    rows = (
        ("fast (homography camera)", args.steps, fast_eps, fast, fast_cpu),
        ("6 boxes, stereo + LIDAR", args.steps, objects_eps, objects, objects_cpu),
        ("reference (pybullet getCameraImage)", args.reference_steps, ref_eps, ref, ref_cpu),
    )
    for label, steps, eps, wall, cpu in rows:
        print(f"{label:<36}{steps:>8}{eps:>10}{wall:>10.0f}{cpu:>13.0f}")
    print(
        f"steps_per_s={fast:.0f} reference_steps_per_s={ref:.0f} ratio={fast / ref:.1f} "
        f"objects_steps_per_s={objects:.0f}"
    )


if __name__ == "__main__":
    main()
