"""Vectorised envs for stable-baselines3: in-process (trusted rewards) or in sandboxed workers.

:class:`SandboxedVecEnv` runs the simulator and the user's reward function together inside
locked-down child processes (:mod:`training.sandbox`): the reward is called in-process there,
at full speed, and the trainer only exchanges actions for observations, rewards and compact
infos over a pipe (JSON + raw arrays; nothing from a worker is ever unpickled). Each worker
hosts several envs, each with its own instance of the user's module, so module-level state in a
reward function (a common DeepRacer idiom) stays per car, as on DeepRacer.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from training.rollout.envs import EnvRunner, EnvSpec
from training.rollout.numpy_policy import GreedyNet
from training.sandbox import SandboxCrashed, SandboxLimits, SandboxProcess, checked

ROLLOUT_LIMITS = SandboxLimits(
    per_call_seconds=1.0,
    cpu_seconds=24 * 3600,
    memory_bytes=3 << 30,
    open_files=256,
    start_seconds=60.0,
)
"""A rollout worker: a second per reward call, 3 GiB more than its imports, a day of CPU."""

STEP_SLACK_S = 5.0
"""What a step of a worker's envs may take beyond its reward calls (physics, cameras)."""
DRIVE_STEP_SLACK_S = 0.25
"""What each step of each env of a ``drive`` command may take beyond its reward call (the
simulator and the policy's forward pass take about a millisecond)."""
RESET_SLACK_S = 30.0
"""What a reset may take beyond loading and calling the reward (placing objects, a slow start)."""


def reply_timeout(cmd: str, size: int, limits: SandboxLimits, steps: int = 1) -> float:
    """Seconds a worker hosting ``size`` envs has to answer ``cmd``, on the trainer's clock:
    one reward call per env and step (``steps`` of them for ``drive`` and ``sample``), each within
    ``limits.per_call_seconds`` (a reset may also load the user's module once per env), plus
    slack for the simulator. The child's own heartbeat cannot stretch it."""
    chunked = cmd in ("drive", "sample")
    calls = size * (2 if cmd == "reset" else steps if chunked else 1)
    slack = RESET_SLACK_S if cmd == "reset" else STEP_SLACK_S
    if chunked:
        slack += steps * size * DRIVE_STEP_SLACK_S
    return calls * limits.per_call_seconds + slack


#: The keys of a compact info (training.rollout.envs.compact_info) a worker may send.
INFO_KEYS = frozenset(
    {"status", "progress", "lap", "trace", "TimeLimit.truncated", "lap_times", "frame",
     "terminal_observation", "episode_entry"}
)  # fmt: skip
MAX_FRAME_BYTES = 4 << 20
DRIVE_STEPS = 32
"""Steps of an evaluation a worker drives per command (about 30 ms): short enough that the
trainer takes them up soon and a stop waits little, long enough that the exchange is cheap."""
MAX_DRIVE_STEPS = 256
"""Steps one ``drive`` command may ask of a worker (its reply holds one record per step)."""


def first_envs(sizes: list[int]) -> list[int]:
    """The index of each worker's first env in the run (workers host ``sizes[i]`` envs):
    with :meth:`EnvSpec.for_env`, what tells a worker which tracks its envs drive."""
    return [sum(sizes[:i]) for i in range(len(sizes))]


class SampledSteps(NamedTuple):
    """A chunk of a rollout that the envs' side drove (:meth:`_RunnerVecEnv.receive_sample`),
    for ``steps`` steps of ``n`` envs: ``obs`` (steps, n, ...) each step's observations before
    its action, ``actions``, ``rewards`` and ``dones`` (steps, n), ``infos`` (steps lists of
    n), ``next_obs`` (n, ...) the observations after the last step."""

    obs: np.ndarray
    actions: np.ndarray
    rewards: np.ndarray
    dones: np.ndarray
    infos: list[list[dict]]
    next_obs: np.ndarray


class RolloutError(RuntimeError):
    """A rollout worker failed; the message is for the user (it names the reward error)."""


class _RunnerVecEnv(VecEnv):
    """Shared VecEnv plumbing over a list of groups, each stepping ``sizes[i]`` envs."""

    def __init__(self, num_envs: int, observation_space, action_space) -> None:
        super().__init__(num_envs, observation_space, action_space)
        self._actions: np.ndarray | None = None
        self.want_frames = False
        self._seeds: list[int | None] = [None] * num_envs
        self._samples: deque = deque()
        """What each :meth:`send_sample` not yet received asked for, oldest first (a second
        may go before the first one's steps are back)."""

    def seed(self, seed: int | None = None) -> Sequence[None | int]:
        if seed is None:
            seed = int(np.random.randint(0, 2**31 - 1))
        self._seeds = [seed + i for i in range(self.num_envs)]
        return self._seeds

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions)

    def send_step(self, actions: np.ndarray) -> None:
        """A step in two halves: the actions go out now, :meth:`receive_step` returns what
        ``step`` would. Envs in worker processes step in between, while the caller goes on;
        here the whole step happens in :meth:`receive_step`."""
        self.step_async(actions)

    def receive_step(self):
        return self.step_wait()

    def send_drive(self, net: dict | None, steps: int) -> None:
        """An evaluation driven by the envs' own side, ``steps`` steps at most: each env drives
        with ``net`` (a :class:`~training.rollout.numpy_policy.GreedyNet` message; None: the
        last one sent) from where the last reset or step left it, until every env's episode
        has ended since the reset. :meth:`receive_drive` returns the steps;
        :meth:`drive_ready` says whether that would not wait."""
        if not 0 < steps <= MAX_DRIVE_STEPS:
            raise ValueError(f"steps must be 1 to {MAX_DRIVE_STEPS}")

    def drive_ready(self) -> bool:
        return True

    def receive_drive(self) -> list[tuple[np.ndarray, np.ndarray, list[dict]]]:
        """The steps of the :meth:`send_drive` under way: ``(rewards, dones, infos)`` per step
        for every env, as ``step`` returns them (without observations). An env whose worker
        stopped early (all its envs had ended) reads 0, not done and an empty info."""
        raise NotImplementedError

    def send_sample(self, net: dict | None, steps: int, seed: int | None = None) -> None:
        """A PPO rollout driven by the envs' own side, ``steps`` steps of every env: each
        draws its actions from ``net``'s probabilities (a
        :class:`~training.rollout.numpy_policy.GreedyNet` message; None: the last one sent)
        with a generator of its side's, which ``seed`` (given: the run's first chunk) seeds
        anew. :meth:`receive_sample` returns the steps; a second command may go before the
        first one's steps are received (the envs' side drives them one after the other)."""
        if not 0 < steps <= MAX_DRIVE_STEPS:
            raise ValueError(f"steps must be 1 to {MAX_DRIVE_STEPS}")

    def sample_ready(self) -> bool:
        return True

    def filenos(self) -> list[int]:
        """Descriptors that become readable when a worker's reply arrives (none here: the
        envs step in :meth:`receive_sample` or :meth:`receive_drive` themselves)."""
        return []

    def receive_sample(self) -> SampledSteps:
        """The steps of the :meth:`send_sample` under way."""
        raise NotImplementedError

    def get_attr(self, attr_name: str, indices=None) -> list[Any]:
        if attr_name == "render_mode":
            return [None] * len(self._get_indices(indices))
        raise AttributeError(f"{type(self).__name__} does not expose {attr_name!r}")

    def set_attr(self, attr_name: str, value: Any, indices=None) -> None:
        raise AttributeError(f"{type(self).__name__} does not allow setting {attr_name!r}")

    def env_method(self, method_name: str, *args, indices=None, **kwargs) -> list[Any]:
        raise AttributeError(f"{type(self).__name__} does not allow calling {method_name!r}")

    def env_is_wrapped(self, wrapper_class, indices=None) -> list[bool]:
        return [False] * len(self._get_indices(indices))


class LocalVecEnv(_RunnerVecEnv):
    """All envs in this process, with a trusted reward callable (tests, benchmarks)."""

    def __init__(
        self, spec: EnvSpec, num_envs: int, reward_function: Callable[[dict], float] | None
    ) -> None:
        envs = [spec.for_env(i).make(reward_function) for i in range(num_envs)]
        self.runner = EnvRunner(envs)
        super().__init__(num_envs, envs[0].observation_space, envs[0].action_space)

    def reset(self) -> np.ndarray:
        obs = self.runner.reset(self._seeds, self._options)
        self._seeds = [None] * self.num_envs
        self._reset_options()
        return obs

    def step_wait(self):
        self.runner.want_frames = self.want_frames
        obs, rewards, dones, infos = self.runner.step(self._actions)
        return obs, rewards, dones, infos

    def send_drive(self, net: dict | None, steps: int) -> None:
        super().send_drive(net, steps)
        if net is not None:
            self._net = GreedyNet.from_message(net)
        self._drive_steps = steps

    def receive_drive(self) -> list[tuple[np.ndarray, np.ndarray, list[dict]]]:
        self.runner.want_frames = self.want_frames
        part = self.runner.drive(self._net, self._drive_steps)
        return list(zip(part["rewards"], part["dones"], part["infos"], strict=True))

    def send_sample(self, net: dict | None, steps: int, seed: int | None = None) -> None:
        super().send_sample(net, steps, seed)
        if net is not None:
            self._net = GreedyNet.from_message(net)
        if seed is not None:
            self._rng = np.random.default_rng([seed, 0])
        self._samples.append(steps)

    def receive_sample(self) -> SampledSteps:
        self.runner.want_frames = self.want_frames
        part = self.runner.sample(self._net, self._samples.popleft(), self._rng)
        return SampledSteps(part["obs"], part["actions"], part["rewards"], part["dones"],
                            part["infos"], part["next_obs"])  # fmt: skip

    def close(self) -> None:
        self.runner.close()


# ----------------------------------------------------------------------- sandboxed workers
WORKER_MAIN = "training.rollout.hosted:worker_main"
WORKER_PREPARE = "training.rollout.hosted:worker_prepare"
"""The worker side (:mod:`training.rollout.hosted`): it imports neither torch nor
stable-baselines3, so a worker starts in about a second instead of several."""


class _WorkerVecEnv(_RunnerVecEnv):
    """Envs hosted by workers that answer reset/step commands (``sizes[i]`` envs each);
    subclasses say how a command reaches them (:meth:`_exchange`, or :meth:`_send` and
    :meth:`_receive` apart). Replies are checked, never trusted: a malformed one is an error."""

    sizes: list[int]
    _sent: list[dict] | None = None

    def _exchange(self, messages: list[dict]) -> list[dict]:
        """Each worker's message out, each one's reply back, in order."""
        raise NotImplementedError

    def _send(self, messages: list[dict]) -> None:
        """The messages out, where a subclass can send them apart from :meth:`_receive`;
        here the whole exchange happens in :meth:`_receive`."""

    def _receive(self, messages: list[dict]) -> list[dict]:
        return self._exchange(messages)

    def _obs(self, part: Any, size: int) -> Any:
        """``size`` observations from a worker, checked against the observation space: an
        image array, or (camera + LIDAR) a dict of one array per sensor with finite values."""
        space = self.observation_space
        if not isinstance(space, spaces.Dict):
            shape = (size, *space.shape)
            return checked.array(part, "observations", dtype=np.uint8, shape=shape)
        part = checked.mapping(part, "observations")
        if set(part) != set(space.spaces):
            raise checked.Malformed(f"observations: expected the keys {sorted(space.spaces)}")
        out = {}
        for key, sub in space.spaces.items():
            value = checked.array(part[key], f"observations {key}", dtype=sub.dtype,
                                  shape=(size, *sub.shape))  # fmt: skip
            if value.dtype.kind == "f" and not np.all(np.isfinite(value)):
                raise checked.Malformed(f"observations {key}: values must be finite")
            out[key] = value
        return out

    @staticmethod
    def _concat(parts: list) -> Any:
        if parts and isinstance(parts[0], dict):
            return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
        return np.concatenate(parts)

    @staticmethod
    def _first(obs: Any) -> Any:
        if isinstance(obs, dict):
            return {k: v[0] for k, v in obs.items()}
        return obs[0]

    def reset(self) -> np.ndarray:
        seeds, options, msgs, start = self._seeds, self._options, [], 0
        for size in self.sizes:
            msgs.append({"cmd": "reset", "seeds": seeds[start : start + size],
                         "options": options[start : start + size]})  # fmt: skip
            start += size
        self._seeds = [None] * self.num_envs
        self._reset_options()
        replies = self._exchange(msgs)
        try:
            parts = [
                self._obs(checked.mapping(r, "reset reply").get("obs"), s)
                for r, s in zip(replies, self.sizes, strict=True)
            ]
        except checked.Malformed as exc:
            raise RolloutError(f"a simulation worker sent malformed data ({exc})") from None
        return self._concat(parts)

    def step_wait(self):
        self.send_step(self._actions)
        return self.receive_step()

    def send_step(self, actions: np.ndarray) -> None:
        """The actions go out at once and the workers step while the caller goes on;
        :meth:`receive_step` waits for their replies."""
        actions = np.asarray(actions)
        msgs, start = [], 0
        for i, size in enumerate(self.sizes):
            part = actions[start : start + size]
            msgs.append({"cmd": "step", "actions": part, "frames": self.want_frames and i == 0})
            start += size
        self._send(msgs)
        self._sent = msgs

    def receive_step(self):
        """The replies to :meth:`send_step`: ``obs, rewards, dones, infos`` as ``step``."""
        msgs, self._sent = self._sent, None
        if msgs is None:
            raise RuntimeError("receive_step without send_step")
        replies = self._receive(msgs)
        obs, rewards, dones, infos = [], [], [], []
        try:
            for reply, size in zip(replies, self.sizes, strict=True):
                reply = checked.mapping(reply, "step reply")
                obs.append(self._obs(reply.get("obs"), size))
                rewards.append(checked.rewards(reply.get("rewards"), "rewards", size=size))
                dones.append(checked.array(reply.get("dones"), "dones", dtype=bool, shape=(size,)))
                info = reply.get("infos")
                if not isinstance(info, list) or len(info) != size:
                    raise checked.Malformed("infos: expected one per env")
                infos.extend(self._info(item) for item in info)
        except checked.Malformed as exc:
            raise RolloutError(f"a simulation worker sent malformed data ({exc})") from None
        return self._concat(obs), np.concatenate(rewards), np.concatenate(dones), infos

    def send_drive(self, net: dict | None, steps: int) -> None:
        super().send_drive(net, steps)
        msgs = [
            {"cmd": "drive", "net": net, "steps": steps, "frames": self.want_frames and i == 0}
            for i in range(len(self.sizes))
        ]
        self._send(msgs)
        self._sent = msgs

    def receive_drive(self) -> list[tuple[np.ndarray, np.ndarray, list[dict]]]:
        msgs, self._sent = self._sent, None
        if msgs is None or msgs[0].get("cmd") != "drive":
            raise RuntimeError("receive_drive without send_drive")
        steps = msgs[0]["steps"]
        replies = self._receive(msgs)
        parts = []
        try:
            for reply, size in zip(replies, self.sizes, strict=True):
                reply = checked.mapping(reply, "drive reply")
                infos = reply.get("infos")
                if not isinstance(infos, list) or len(infos) > steps:
                    raise checked.Malformed(f"drive infos: expected at most {steps} steps")
                parts.append(self._chunk(reply, len(infos), size))
        except checked.Malformed as exc:
            raise RolloutError(f"a simulation worker sent malformed data ({exc})") from None
        out = []
        for t in range(max((len(p[2]) for p in parts), default=0)):
            rewards, dones, infos = [], [], []
            for (r, d, i), size in zip(parts, self.sizes, strict=True):
                if t < len(i):
                    rewards.append(r[t])
                    dones.append(d[t])
                    infos.extend(i[t])
                else:  # this worker's envs had all ended
                    rewards.append(np.zeros(size, np.float32))
                    dones.append(np.zeros(size, bool))
                    infos.extend({} for _ in range(size))
            out.append((np.concatenate(rewards), np.concatenate(dones), infos))
        return out

    def send_sample(self, net: dict | None, steps: int, seed: int | None = None) -> None:
        super().send_sample(net, steps, seed)
        msgs = [
            {"cmd": "sample", "net": net, "steps": steps, "frames": self.want_frames and i == 0,
             "seed": None if seed is None else [seed, first]}
            for i, first in enumerate(first_envs(self.sizes))
        ]  # fmt: skip
        self._send(msgs)
        self._samples.append(msgs)

    def sample_ready(self) -> bool:
        return self.drive_ready()

    def receive_sample(self) -> SampledSteps:
        """The replies to the oldest :meth:`send_sample` not yet received, checked: every
        worker's ``steps`` steps, each action one of the action space's."""
        if not self._samples:
            raise RuntimeError("receive_sample without send_sample")
        msgs = self._samples.popleft()
        k = msgs[0]["steps"]
        replies = self._receive(msgs)
        obs, actions, rewards, dones, infos, last = [], [], [], [], [[] for _ in range(k)], []
        try:
            for reply, size in zip(replies, self.sizes, strict=True):
                reply = checked.mapping(reply, "sample reply")
                obs.append(self._obs(self._flat(reply.get("obs"), k, size), k * size)
                           .reshape(k, size, *self.observation_space.shape))  # fmt: skip
                last.append(self._obs(reply.get("next_obs"), size))
                chosen = checked.array(reply.get("actions"), "actions", dtype=np.int64,
                                       shape=(k, size))  # fmt: skip
                if chosen.size and (chosen.min() < 0 or chosen.max() >= self.action_space.n):
                    raise checked.Malformed("actions: not in the action space")
                actions.append(chosen)
                steps = reply.get("infos")
                if not isinstance(steps, list) or len(steps) != k:
                    raise checked.Malformed(f"sample infos: expected {k} steps")
                part_rewards, part_dones, part_infos = self._chunk(reply, k, size)
                rewards.append(part_rewards)
                dones.append(part_dones)
                for t, step in enumerate(part_infos):
                    infos[t].extend(step)
        except checked.Malformed as exc:
            raise RolloutError(f"a simulation worker sent malformed data ({exc})") from None
        return SampledSteps(np.concatenate(obs, axis=1), np.concatenate(actions, axis=1),
                            np.concatenate(rewards, axis=1), np.concatenate(dones, axis=1),
                            infos, np.concatenate(last))  # fmt: skip

    def _chunk(self, reply: dict, k: int, size: int) -> tuple[np.ndarray, np.ndarray, list]:
        """``k`` steps of ``size`` envs from a ``drive`` or ``sample`` reply, checked:
        rewards and dones (k, size), and each step's infos (one per env)."""
        rewards = checked.array(reply.get("rewards"), "rewards", dtype=np.float32,
                                shape=(k, size))  # fmt: skip
        checked.rewards(rewards.reshape(-1), "rewards", size=k * size)
        dones = checked.array(reply.get("dones"), "dones", dtype=bool, shape=(k, size))
        infos = reply.get("infos")
        for step in infos:
            if not isinstance(step, list) or len(step) != size:
                raise checked.Malformed("infos: expected one per env")
        return rewards, dones, [[self._info(item) for item in step] for step in infos]

    @staticmethod
    def _flat(part: Any, steps: int, size: int) -> Any:
        """A (steps, size, ...) array as (steps × size, ...) for :meth:`_obs`'s check."""
        if isinstance(part, np.ndarray) and part.ndim >= 2 and part.shape[:2] == (steps, size):
            return part.reshape(steps * size, *part.shape[2:])
        raise checked.Malformed("observations: expected one per step and env")

    def _info(self, item: Any) -> dict:
        """One env's compact info (:func:`training.rollout.envs.compact_info`), checked."""
        info = checked.mapping(item, "info")
        unknown = set(info) - INFO_KEYS
        if unknown:
            raise checked.Malformed(f"info: unexpected keys {sorted(unknown)[:3]}")
        checked.text(info.get("status"), "info status", limit=64)
        checked.number(info.get("progress"), "info progress", bound=1e6)
        checked.integer(info.get("lap", 1), "info lap", high=10_000)
        if info.get("trace") is not None:
            _check_trace(info["trace"])
        if "lap_times" in info:
            checked.scalars(info["lap_times"], "info lap_times", limit=10_000)
        if type(info.get("TimeLimit.truncated", True)) is not bool:
            raise checked.Malformed("info TimeLimit.truncated: expected a bool")
        if info.get("terminal_observation") is not None:
            term = info["terminal_observation"]
            if isinstance(term, dict):
                term = {k: v[None] if isinstance(v, np.ndarray) else v for k, v in term.items()}
            elif isinstance(term, np.ndarray):
                term = term[None]
            info["terminal_observation"] = self._first(self._obs(term, 1))
        if info.get("episode_entry") is not None:
            entry = checked.mapping(info["episode_entry"], "episode entry")
            checked.scalars(list(entry.values()), "episode entry", limit=64)
        if info.get("frame") is not None:
            self._frame(info["frame"])
        return info

    @staticmethod
    def _frame(value: Any) -> None:
        frame = checked.mapping(value, "frame")
        for key in ("camera", "chase"):
            jpeg = frame.get(key)
            if not isinstance(jpeg, np.ndarray) or jpeg.dtype != np.uint8 or jpeg.ndim != 1:
                raise checked.Malformed(f"frame {key}: expected JPEG bytes")
            if jpeg.size > MAX_FRAME_BYTES:
                raise checked.Malformed(f"frame {key}: over {MAX_FRAME_BYTES} bytes")
        checked.number(frame.get("progress"), "frame progress", bound=1e6)
        checked.integer(frame.get("lap"), "frame lap", high=10_000)


class SandboxedVecEnv(_WorkerVecEnv):
    """``num_envs`` envs spread over ``num_workers`` sandboxed processes running the user's
    reward source. Raises :class:`RolloutError` with a plain message when a worker fails."""

    def __init__(
        self,
        spec: EnvSpec,
        num_envs: int,
        reward_source: str,
        *,
        num_workers: int = 2,
        limits: SandboxLimits = ROLLOUT_LIMITS,
        phase: str = "training",
        python_guards: bool = True,
    ) -> None:
        if num_envs < 1:
            raise ValueError("num_envs must be at least 1")
        num_workers = max(1, min(num_workers, num_envs))
        sizes = [
            num_envs // num_workers + (1 if i < num_envs % num_workers else 0)
            for i in range(num_workers)
        ]
        # Spaces come from a local env (the worker's reply is never trusted for them).
        probe = spec.make(None)
        obs_space, act_space = probe.observation_space, probe.action_space
        probe.close()
        self.sizes = sizes
        self.workers: list[SandboxProcess] = []
        try:
            for first, size in zip(first_envs(sizes), sizes, strict=True):
                worker = SandboxProcess(
                    target=WORKER_MAIN,
                    prepare=WORKER_PREPARE,
                    reward_source=reward_source,
                    args={
                        "spec": spec.to_json(),
                        "num_envs": size,
                        "phase": phase,
                        "first_env": first,
                    },
                    limits=limits,
                    python_guards=python_guards,  # False in tests only: the OS layers alone
                )
                worker.launch()  # the workers load at once, each on its own core
                self.workers.append(worker)
            for worker in self.workers:
                worker.wait_started()
        except BaseException:
            for worker in self.workers:
                worker.close()
            raise
        super().__init__(num_envs, obs_space, act_space)
        self.layers = self.workers[0].layers if self.workers else {}

    def _exchange(self, messages: list[dict]) -> list[dict]:
        self._send(messages)
        return self._receive(messages)

    def _send(self, messages: list[dict]) -> None:
        for worker, msg in zip(self.workers, messages, strict=True):
            try:
                worker.send(msg)
            except SandboxCrashed as exc:
                raise RolloutError(str(exc)) from exc

    def drive_ready(self) -> bool:
        return all(worker.ready() for worker in self.workers)

    def filenos(self) -> list[int]:
        return [worker.fileno() for worker in self.workers]

    def _receive(self, messages: list[dict]) -> list[dict]:
        replies = []
        for worker, msg, size in zip(self.workers, messages, self.sizes, strict=True):
            timeout = reply_timeout(msg["cmd"], size, worker.limits, msg.get("steps", 1))
            try:
                reply = worker.recv(timeout=timeout)
            except SandboxCrashed as exc:
                raise RolloutError(str(exc)) from exc
            if reply.kind != "message" or not isinstance(reply.value, dict):
                raise RolloutError("a simulation worker stopped unexpectedly")
            replies.append(reply.value)
        return replies

    def close(self) -> None:
        for worker in self.workers:
            try:
                worker.send({"cmd": "close"})
            except Exception:  # noqa: BLE001 - a dead worker is closed below all the same
                pass
            worker.close(grace_seconds=2.0)
        self.workers = []


def _check_trace(row: Any) -> None:
    """A sim-trace row: scalars, except the action, which a continuous action space reports
    as its (steering, speed) pair."""
    if not isinstance(row, list):
        raise checked.Malformed("info trace: expected a list")
    pairs = [v for v in row if isinstance(v, list)]
    if len(pairs) > 1:
        raise checked.Malformed("info trace: more than one list in a row")
    for pair in pairs:
        checked.scalars(pair, "info trace action", limit=2)
    checked.scalars([v for v in row if not isinstance(v, list)], "info trace")
