"""What training under conditions costs (issue 51): env steps per second, clean against every
family on (``ConditionsSpec.default()``: each episode draws light, look, camera, car and
latency over their widest ranges), the image families (light, look, camera) and each alone.

Each setup drives ``--steps`` steps in ``--runs`` runs, each run in chunks of ``--chunk`` steps
with the setups taking turns chunk by chunk (so a load that comes and goes hits them alike), on
the same track with the same random actions, its episodes going on from chunk to chunk. A row
gives the median over the runs of steps per second of wall-clock time and of this process's CPU
time. The goal: conditions cost at most 15 % of the clean steps per second.

    .venv/bin/python bench/bench_conditions.py [--track ID] [--steps N] [--runs N] [--chunk N]

Last line: ``clean_steps_per_s=… conditions_steps_per_s=… ratio=… cost_pct=… render_cost_pct=…``
(ratio = all families / clean, on CPU time; cost_pct = 100 × (1 − ratio); render_cost_pct the
same for the three image families alone: what rendering under conditions costs, without the car
and latency families' other episodes).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from racing.conditions import ConditionsSpec  # noqa: E402
from racing.env import RacingEnv  # noqa: E402

cv2.setNumThreads(1)

SETUPS = {
    "clean": None,
    "light only": ConditionsSpec.default(["light"]),
    "look only": ConditionsSpec.default(["look"]),
    "camera only": ConditionsSpec.default(["camera"]),
    "image families": ConditionsSpec.default(["light", "look", "camera"]),
    "all families": ConditionsSpec.default(),
}


def measure(env: RacingEnv, actions: np.ndarray) -> tuple[float, float]:
    """Seconds of wall-clock time and of this process's CPU time to drive ``actions`` (episodes
    reset inside the timing, as in training: a reset draws the episode's conditions)."""
    start, cpu_start = time.perf_counter(), time.process_time()
    for a in actions:
        _, _, terminated, truncated, _ = env.step(int(a))
        if terminated or truncated:
            env.reset()
    return time.perf_counter() - start, time.process_time() - cpu_start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--track", default="reinvent_base")
    parser.add_argument("--steps", type=int, default=4000)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--chunk", type=int, default=200)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    actions = rng.choice(
        10, size=args.steps, p=[0.05, 0.05, 0.1, 0.1, 0.15, 0.15, 0.1, 0.1, 0.1, 0.1]
    )
    envs = {
        name: RacingEnv(args.track, conditions=spec, conditions_seed=0 if spec else None)
        for name, spec in SETUPS.items()
    }
    for env in envs.values():
        env.reset(seed=0)
        measure(env, actions[:300])  # warm-up: textures, class textures, grain views
    results: dict[str, list[tuple[float, float]]] = {name: [] for name in envs}
    for _ in range(args.runs):
        spent = {name: [0.0, 0.0] for name in envs}
        for start in range(0, args.steps, args.chunk):
            for name, env in envs.items():
                wall_s, cpu_s = measure(env, actions[start : start + args.chunk])
                spent[name][0] += wall_s
                spent[name][1] += cpu_s
        for name, (wall_s, cpu_s) in spent.items():
            results[name].append((args.steps / wall_s, args.steps / cpu_s))
    wall = {n: statistics.median(r[0] for r in runs) for n, runs in results.items()}
    cpu = {n: statistics.median(r[1] for r in runs) for n, runs in results.items()}
    print(f"{args.track}, {args.steps} steps x {args.runs} runs, load average "
          f"{' '.join(f'{v:.2f}' for v in os.getloadavg())}")  # fmt: skip
    print(f"{'setup':<16} {'wall steps/s':>13} {'CPU steps/s':>12} {'vs clean (CPU)':>15}")
    for name in envs:
        print(f"{name:<16} {wall[name]:>13,.0f} {cpu[name]:>12,.0f} "
              f"{cpu[name] / cpu['clean']:>15.3f}")  # fmt: skip
    ratio = cpu["all families"] / cpu["clean"]
    render = cpu["image families"] / cpu["clean"]
    print(
        f"clean_steps_per_s={cpu['clean']:.0f} conditions_steps_per_s={cpu['all families']:.0f} "
        f"ratio={ratio:.3f} cost_pct={100 * (1 - ratio):.1f} "
        f"render_cost_pct={100 * (1 - render):.1f}"
    )


if __name__ == "__main__":
    main()
