"""A simulation worker that owns its episodes (issue 14): DeepRacer's SimApp, on our sandbox.

A worker is this driver process plus two sandboxed simulator processes (training and
evaluation envs, with the user's reward inside, :class:`~training.rollout.vecenv.SandboxedVecEnv`).
The driver holds a CPU copy of the current policy and drives whole episodes with it, so a step
costs a pipe round trip to its own sandbox, never a trip to the trainer. Hostile reward code
never sees the policy, Redis or the network: the driver is ours, the sandbox is theirs.

Between episodes it takes the next ticket of the current policy version
(:mod:`training.rollout.streams`): a training episode, streamed in chunks of experience; else an
evaluation lap of that version (deterministic actions), whose result is streamed too; else,
while someone watches, a spare evaluation lap for the live view. So while the trainer updates,
the workers evaluate the policy that collected the update's experience - DeepRacer's overlap.

Started locally as ``python -m training.rl.simulation`` (its arguments as JSON on stdin, see
:func:`launch_local`) or remotely by the ``simulation`` queue's Celery task; either way it ends
when the trainer says stop, or when the trainer's heartbeat is gone.
"""

from __future__ import annotations

import json
import logging
import os
import subprocess
import sys
import threading
import time
import uuid

import numpy as np
import torch
from gymnasium import spaces

from training.rl.algorithms import build_model, set_torch_threads
from training.rl.hyperparams import Hyperparameters
from training.rollout.envs import EnvSpec
from training.rollout.greedy import export_greedy, greedy_actions
from training.rollout.streams import CHUNK_STEPS, HEARTBEAT_S, Session, chunk_message
from training.rollout.vecenv import DRIVE_STEPS, SandboxedVecEnv
from training.sandbox import RewardFunctionError, SandboxError

log = logging.getLogger(__name__)
TRAINER_GONE_S = 60.0
"""A worker whose trainer has not stamped its heartbeat for this long ends."""
IDLE_SLEEP_S = 0.05
LOCAL_NICENESS = 5
"""A worker on the trainer's own machine yields to it: the policy update runs at full speed
and the evaluation laps that overlap it take the cycles it leaves."""


class _Beat:
    """The worker's heartbeat, and what it learns from Redis once a second (stop, watch), on
    a thread of its own: a long episode never lets the heartbeat lapse."""

    def __init__(self, session: Session, worker: str, parent_pid: int | None = None) -> None:
        self.session = Session(session.redis_url, session.keys.prefix, session.keys.session)
        self.worker = worker
        self.parent_pid = parent_pid
        self.stop = threading.Event()
        self.watched = False
        self._trainer_seen = time.monotonic()
        self._thread = threading.Thread(target=self._run, name=f"beat-{worker}", daemon=True)

    def start(self) -> None:
        self._beat()
        self._thread.start()

    def _beat(self) -> None:
        s = self.session
        s.heartbeat(self.worker)
        now = time.monotonic()
        if s.r.exists(s.keys.trainer):
            self._trainer_seen = now
        orphaned = self.parent_pid is not None and os.getppid() != self.parent_pid
        gone = now - self._trainer_seen > TRAINER_GONE_S
        if orphaned or gone or s.stopped() or s.revoked(self.worker):
            self.stop.set()
        self.watched = s.watching() == self.worker

    def _run(self) -> None:
        while not self.stop.wait(HEARTBEAT_S):
            try:
                self._beat()
            except Exception:  # noqa: BLE001 - Redis gone for long ends the worker below
                log.warning("simulation worker %s: heartbeat failed", self.worker, exc_info=True)
                if time.monotonic() - self._trainer_seen > TRAINER_GONE_S:
                    self.stop.set()

    def close(self) -> None:
        self.stop.set()
        self._thread.join(timeout=5)
        self.session.close()


class SimulationWorker:
    """Drives tickets until told to stop. See the module's docstring."""

    def __init__(self, session: Session, worker: str, *, spec: EnvSpec, eval_spec: EnvSpec,
                 reward_source: str, algorithm: str, network: str, hyperparameters: dict,
                 seed: int, parent_pid: int | None = None) -> None:  # fmt: skip
        self.session = session
        self.worker = worker
        self.train_env = SandboxedVecEnv(spec, 1, reward_source, num_workers=1, phase="training")
        try:
            self.eval_env = SandboxedVecEnv(eval_spec, 1, reward_source, num_workers=1,
                                            phase="evaluation")  # fmt: skip
        except BaseException:
            self.train_env.close()
            raise
        self.train_env.seed(seed)
        self.eval_env.seed(seed + 7919)
        hp = Hyperparameters(**hyperparameters)
        self.model = build_model(algorithm, self.train_env, hp, network=network, seed=seed)
        self.policy = self.model.policy
        self.policy.set_training_mode(False)
        self.version: int | None = None
        self.obs: np.ndarray | None = None
        self.beat = _Beat(session, worker, parent_pid)

    # ---------------------------------------------------------------- the policy
    def _load(self, version: int) -> bool:
        weights = self.session.policy(version)
        if weights is None:
            return False
        state = {k: torch.from_numpy(np.array(v)) for k, v in weights.items()}
        self.policy.load_state_dict(state)
        self.version = version
        return True

    def _act(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
        """(action for the env, action as stored, log-probability, value) for one obs."""
        with torch.no_grad():
            obs_t, _ = self.policy.obs_to_tensor(obs)
            actions, values, log_probs = self.policy(obs_t)
        raw = actions.cpu().numpy()
        env_action = raw
        if isinstance(self.policy.action_space, spaces.Box):
            env_action = np.clip(raw, self.policy.action_space.low, self.policy.action_space.high)
        return env_action, raw[0], float(log_probs[0]), float(values[0])

    def _value(self, obs: np.ndarray) -> float:
        with torch.no_grad():
            obs_t, _ = self.policy.obs_to_tensor(obs[None])
            return float(self.policy.predict_values(obs_t)[0, 0])

    # ---------------------------------------------------------------- frames
    def _frame(self, info: dict, phase: str) -> None:
        frame = info.pop("frame", None)
        if frame is None or not self.beat.watched:
            return
        iteration = self.version + 1 if phase == "training" else self.version
        self.session.send_frame({**frame, "phase": phase, "version": self.version,
                                 "iteration": iteration, "worker": self.worker})  # fmt: skip

    # ---------------------------------------------------------------- episodes
    def training_episode(self, ticket: str) -> bool:
        """One whole episode for ``ticket``; False when stopped before its end."""
        env = self.train_env
        if self.obs is None:
            self.obs = env.reset()
        attempt = uuid.uuid4().hex[:16]
        seq = 0
        part: dict[str, list] = {k: [] for k in ("obs", "actions", "log_probs", "values",
                                                  "rewards", "infos")}  # fmt: skip

        def flush(last: bool, terminated: bool = False, bootstrap: float = 0.0) -> None:
            nonlocal seq
            self.session.send(chunk_of(part, ticket=ticket, attempt=attempt, seq=seq,
                                       worker=self.worker, version=self.version, last=last,
                                       terminated=terminated, bootstrap=bootstrap))  # fmt: skip
            seq += 1
            for v in part.values():
                v.clear()

        while not self.beat.stop.is_set():
            env.want_frames = self.beat.watched
            env_action, raw, log_prob, value = self._act(self.obs)
            next_obs, rewards, dones, infos = env.step(env_action)
            info = infos[0]
            self._frame(info, "training")
            terminal = info.pop("terminal_observation", None)
            for key, v in zip(part, (self.obs[0], raw, log_prob, value, float(rewards[0]), info),
                              strict=True):  # fmt: skip
                part[key].append(v)
            self.obs = next_obs
            if dones[0]:
                truncated = bool(info.get("TimeLimit.truncated", False))
                bootstrap = self._value(terminal) if truncated and terminal is not None else 0.0
                flush(True, terminated=not truncated, bootstrap=bootstrap)
                return True
            if len(part["rewards"]) >= CHUNK_STEPS:
                flush(False)
        return False

    def evaluation_lap(self, start_progress: float | None, ticket: str | None) -> bool:
        """One deterministic episode of the eval env; its result goes to the trainer when it
        has a ``ticket`` (a spare lap only feeds the live view)."""
        env = self.eval_env
        if start_progress is not None:
            env.set_options([{"start_progress": start_progress}])
        started = time.monotonic()
        obs = env.reset()
        # A scored lap is driven in the env's worker, its network sent with the lap's first
        # chunk (as training.rollout.lockstep.Evaluation does); a spare lap for the live view,
        # and a network that cannot travel, step by step with the policy here.
        net = export_greedy(self.policy) if ticket is not None else None
        first, total = True, 0.0
        while not self.beat.stop.is_set():
            env.want_frames = self.beat.watched
            if net is not None:
                env.send_drive(net if first else None, DRIVE_STEPS)
                steps = env.receive_drive()
            else:
                obs, rewards, dones, infos = env.step(greedy_actions(self.policy, obs))
                steps = [(rewards, dones, infos)]
            first = False
            for rewards, dones, infos in steps:
                info = infos[0]
                self._frame(info, "evaluation")
                total += float(rewards[0])
                if not dones[0]:
                    continue
                if ticket is not None:
                    self.session.send({
                        "kind": "eval", "ticket": ticket, "version": self.version,
                        "worker": self.worker, "progress": float(info["progress"]),
                        "status": str(info["status"]), "reward": total,
                        "lap_times": [float(t) for t in info.get("lap_times", [])],
                        "wall_s": time.monotonic() - started,
                    })  # fmt: skip
                return True
        return False

    def run(self) -> str:
        self.beat.start()
        s, worker = self.session, self.worker
        while not self.beat.stop.is_set():
            version = s.current_version()
            if version is None or (version != self.version and not self._load(version)):
                time.sleep(IDLE_SLEEP_S)
                continue
            claim = s.claim(worker, version)
            if claim is None:
                if self.beat.watched:
                    self.evaluation_lap(None, None)  # the live view never stops
                else:
                    time.sleep(IDLE_SLEEP_S)
                continue
            kind, ticket = claim
            if kind == "train":
                finished = self.training_episode(ticket)
            else:
                start = float(ticket.split(":")[3])
                finished = self.evaluation_lap(start if start >= 0 else None, ticket)
            if finished:
                s.done(worker, ticket)
        s.release(worker)  # a ticket taken just before the stop is driven by another worker
        return "stopped"

    def close(self) -> None:
        self.beat.close()
        for env in (self.train_env, self.eval_env):
            try:
                env.close()
            except Exception:  # noqa: BLE001 - closing must not hide the real error
                pass


def chunk_of(part: dict[str, list], **fields) -> dict:
    """An experience message of the steps gathered in ``part``."""
    return chunk_message(
        obs=np.stack(part["obs"]), actions=np.asarray(part["actions"], np.float32),
        log_probs=np.asarray(part["log_probs"]), values=np.asarray(part["values"]),
        rewards=np.asarray(part["rewards"]), infos=list(part["infos"]), **fields,
    )  # fmt: skip


def serve_simulation(*, redis_url: str, prefix: str, session: str, worker: str, spec: dict,
                     eval_spec: dict, reward_source: str, algorithm: str, network: str,
                     hyperparameters: dict, seed: int, parent_pid: int | None = None,
                     ) -> str:  # fmt: skip
    """Run one simulation worker until the trainer is done: "stopped" or "failed" (the error
    went to the trainer on the experience stream, in words). A local worker also ends when
    its trainer process (``parent_pid``) is gone."""
    set_torch_threads(1)
    if parent_pid is not None:
        os.nice(LOCAL_NICENESS)  # its sandboxed simulators inherit it
    s = Session(redis_url, prefix, session)
    try:
        try:
            sim = SimulationWorker(s, worker, spec=EnvSpec.from_json(spec),
                                   eval_spec=EnvSpec.from_json(eval_spec),
                                   reward_source=reward_source, algorithm=algorithm,
                                   network=network, hyperparameters=hyperparameters,
                                   seed=seed, parent_pid=parent_pid)  # fmt: skip
        except Exception as exc:  # noqa: BLE001 - the trainer reports it to the user
            s.send(_error(worker, exc))
            return "failed"
        try:
            return sim.run()
        except Exception as exc:  # noqa: BLE001 - the trainer reports it to the user
            log.warning("simulation worker %s failed", worker, exc_info=True)
            s.send(_error(worker, exc))
            return "failed"
        finally:
            sim.close()
    finally:
        s.close()


def _error(worker: str, exc: Exception) -> dict:
    """The error message for the trainer: a reward function's error keeps its line."""
    msg = {"kind": "error", "worker": worker}
    if isinstance(exc, RewardFunctionError):
        msg["reward_error"] = exc.error.to_dict()
        msg["step"] = exc.step
    if isinstance(exc, SandboxError):
        msg["message"] = str(exc)
    else:
        msg["message"] = f"a simulation worker failed: {type(exc).__name__}: {exc}"
    return msg


def launch_local(**kwargs) -> subprocess.Popen:
    """A simulation worker as a child process of this machine (its arguments on stdin)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "training.rl.simulation"],
        stdin=subprocess.PIPE,
        start_new_session=True,
    )
    assert proc.stdin is not None
    proc.stdin.write(json.dumps({**kwargs, "parent_pid": os.getpid()}).encode())
    proc.stdin.close()
    return proc


if __name__ == "__main__":
    logging.basicConfig(level=logging.WARNING)
    serve_simulation(**json.loads(sys.stdin.read()))
