"""The worker side of :class:`~training.rollout.vecenv.SandboxedVecEnv`: what a sandboxed
rollout worker runs, before lock-down (:func:`worker_prepare`: imports, track files, envs) and
after (:func:`worker_main`: reset and step commands until told to close).

It imports the simulator and nothing of the trainer's: no torch, no stable-baselines3. Those
cost a worker about 3.5 s of imports (and a few hundred MB) when it was started from the
trainer's module, and a training job starts three workers.
"""

from __future__ import annotations

import numpy as np

from training.rollout.envs import EnvRunner, EnvSpec
from training.rollout.numpy_policy import GreedyNet


def worker_prepare(args: dict) -> EnvRunner:
    """Runs in the worker BEFORE lock-down: imports and builds the envs (files are read here)."""
    import cv2

    # The live view's chase camera, imported now: without Landlock, seccomp refuses every
    # open() after lock-down, and the first frame would fail to import it.
    import racing.video  # noqa: F401

    cv2.setNumThreads(1)  # no thread pool: the locked-down worker may not start threads
    spec = EnvSpec.from_json(args["spec"])
    first = int(args.get("first_env", 0))  # this worker's envs, counted across the run
    envs = [spec.for_env(first + i).make(None) for i in range(args["num_envs"])]
    return EnvRunner(envs, phase=args.get("phase", "training"))


def worker_main(ctx) -> dict:
    """Runs in the worker AFTER lock-down: serves reset/step commands until told to close, and
    ``drive`` (an evaluation driven here, a chunk of steps at a time, by the network the first
    chunk brings: :class:`~training.rollout.numpy_policy.GreedyNet`) and ``sample`` (a PPO
    rollout driven here, the actions drawn from the network the first chunk of each rollout
    brings, with a generator the first chunk of the run seeds)."""
    runner: EnvRunner = ctx.prepared
    net: GreedyNet | None = None
    rng = np.random.default_rng()
    for env in runner.envs:
        # One instance of the user's module per car, as on DeepRacer (one car per process).
        env.reward_function = ctx.new_reward() if hasattr(ctx, "new_reward") else ctx.reward
    while True:
        msg = ctx.recv()
        if msg is None or msg.get("cmd") == "close":
            break
        if msg["cmd"] == "reset":
            ctx.send({"obs": runner.reset(msg["seeds"], msg.get("options"))})
        elif msg["cmd"] == "step":
            runner.want_frames = bool(msg.get("frames"))
            obs, rewards, dones, infos = runner.step(msg["actions"])
            ctx.send({"obs": obs, "rewards": rewards, "dones": dones, "infos": infos})
        elif msg["cmd"] == "drive":
            if msg.get("net") is not None:
                net = GreedyNet.from_message(msg["net"])
            if net is None:
                raise RuntimeError("drive without a network")
            runner.want_frames = bool(msg.get("frames"))
            ctx.send(runner.drive(net, int(msg["steps"])))
        elif msg["cmd"] == "sample":
            if msg.get("net") is not None:
                net = GreedyNet.from_message(msg["net"])
            if net is None:
                raise RuntimeError("sample without a network")
            if msg.get("seed") is not None:
                rng = np.random.default_rng([int(n) for n in msg["seed"]])
            runner.want_frames = bool(msg.get("frames"))
            ctx.send(runner.sample(net, int(msg["steps"]), rng))
    runner.close()
    return {"closed": True}
