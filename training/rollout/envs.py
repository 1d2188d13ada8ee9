"""What runs next to the simulator: env construction from a JSON-able spec, per-episode
bookkeeping (DeepRacer's TrainingMetrics entries), compact per-step info, and live frames.

The same code runs in the trainer's own process (trusted rewards: tests, benchmarks) and inside
a sandboxed rollout worker (users' rewards, see :mod:`training.rollout.vecenv`), so what crosses the
process boundary is plain JSON plus numpy arrays.
"""

from __future__ import annotations

import secrets
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from racing.env import RacingEnv
from racing.rules import STATUS_LABELS, RaceRules, Status
from racing.simtrace import TraceRow
from racing.track import TrackError
from racing.tracks import TrackCatalog

FRAME_INTERVAL_S = 1 / 15
"""Live video: at most 15 frames per second."""
JPEG_QUALITY = 80


@dataclass(frozen=True)
class EnvSpec:
    """Everything needed to build the same :class:`RacingEnv` in any process (JSON-able).

    Multi-track training (as DeepRacer-for-Cloud's workers each drive their own track):
    ``tracks`` lists ``(track, direction)`` pairs and env ``i`` of a run (counted across all
    its workers) drives pair ``i % len(tracks)``: :meth:`for_env` gives its one-track spec.
    Empty ``tracks``: every env drives ``track`` in ``direction``.
    """

    track: str
    track_dirs: tuple[str, ...] = ()
    direction: str = "native"
    action_space: list | dict | None = None
    sensors: tuple[str, ...] = ("FRONT_FACING_CAMERA",)
    start: str = "round_robin"
    alternate_direction: bool = False
    rules: dict = field(default_factory=dict)
    race: dict = field(default_factory=dict)
    """:meth:`racing.race.RaceConfig.to_dict` of the race (boxes, bots); empty = time trial."""
    tracks: tuple[tuple[str, str], ...] = ()
    track_hashes: tuple[tuple[str, str], ...] = ()
    """``(track id, SHA-256 of its file)`` of the imported tracks the run drives: what identifies
    a track's content on every machine (``track_dirs`` is only where this machine keeps them);
    an env whose local copy differs is not built (:meth:`make`)."""
    conditions: dict = field(default_factory=dict)
    """Training for the world outside: :meth:`racing.conditions.ConditionsSpec.to_dict` of the
    families each episode draws its conditions from; empty = the clean world."""
    conditions_seed: int | None = None
    """The seed of the conditions' draws (a league event's: every entrant meets the same
    sequence); None: each env draws from its own seeded generator."""

    def to_json(self) -> dict:
        data = asdict(self)
        data["track_dirs"] = list(self.track_dirs)
        data["track_hashes"] = [list(pair) for pair in self.track_hashes]
        data["sensors"] = list(self.sensors)
        data["tracks"] = [list(pair) for pair in self.tracks]
        return data

    @classmethod
    def from_json(cls, data: dict) -> EnvSpec:
        data = dict(data)
        data["track_dirs"] = tuple(data.get("track_dirs", ()))
        data["sensors"] = tuple(data.get("sensors", ("FRONT_FACING_CAMERA",)))
        data["tracks"] = tuple((str(t), str(d)) for t, d in data.get("tracks", ()))
        data["track_hashes"] = tuple((str(t), str(h)) for t, h in data.get("track_hashes", ()))
        data["conditions"] = dict(data.get("conditions") or {})
        return cls(**data)

    def track_list(self) -> tuple[tuple[str, str], ...]:
        """Every ``(track, direction)`` the run's envs drive, in the order they are dealt."""
        return self.tracks or ((self.track, self.direction),)

    def for_env(self, index: int) -> EnvSpec:
        """The spec env ``index`` (0-based, across all the run's workers) builds: its own
        track and direction, and no ``tracks`` list (a one-track spec)."""
        if not self.tracks:
            return self
        track, direction = self.tracks[index % len(self.tracks)]
        return replace(self, track=track, direction=direction, tracks=())

    def clean(self) -> EnvSpec:
        """The same spec in the clean world (no outside-world conditions): evaluations."""
        return replace(self, conditions={}, conditions_seed=None) if self.conditions else self

    def make(
        self, reward_function: Callable[[dict], float] | None = None, **overrides
    ) -> RacingEnv:
        """A new env; ``overrides`` replace keyword arguments (e.g. ``start``, ``rules``).
        Raises :class:`~racing.track.TrackError` when this machine's copy of an imported track
        is not the content the run drives (``track_hashes``)."""
        catalog = TrackCatalog(list(self.track_dirs))
        track = catalog.load(self.track)
        expected = dict(self.track_hashes).get(self.track)
        if expected is not None and catalog.sha256(self.track) != expected:
            raise TrackError(
                f"this machine's copy of the track {self.track!r} is not the one this run "
                "drives (imported again since?): start the job again"
            )
        kwargs: dict[str, Any] = {
            "direction": self.direction,
            "action_space": self.action_space,
            "sensors": self.sensors,
            "start": self.start,
            "alternate_direction": self.alternate_direction,
            "rules": RaceRules(**self.rules),
            "race": self.race or None,
            "reward_function": reward_function,
        }
        if self.conditions:
            kwargs["conditions"] = self.conditions
            kwargs["conditions_seed"] = self.conditions_seed
        kwargs.update(overrides)
        return RacingEnv(track, **kwargs)


def episode_entry(
    env: RacingEnv,
    *,
    total_reward: float,
    phase: str,
    episode: int,
    status: str,
    start_s: float,
    car: int = 0,
) -> dict:
    """One ``TrainingMetrics.json`` entry (DeepRacer's fields) for a finished episode.

    Times are the car's simulation clock in milliseconds, as SimApp writes them (ROS time):
    ``start_time`` when the episode began (``start_s``, seconds), ``metric_time`` when it
    ended, ``elapsed_time_in_milliseconds`` the simulated time in between. ``car`` and
    ``env_episode`` say which car drove it and its episode number on that car, so the log
    writer can find its sim-trace rows; ``track`` the track it drove (multi-track training)."""
    elapsed_s = float(env.tracker.sim_time)
    return {
        "reward_score": int(round(total_reward)),
        "metric_time": int(round((start_s + elapsed_s) * 1000)),
        "start_time": int(round(start_s * 1000)),
        "elapsed_time_in_milliseconds": int(round(elapsed_s * 1000)),
        "episode": episode,
        "trial": episode + 1,
        "phase": phase,
        "car": car,
        "env_episode": env.episode,
        "track": env.track.track_id,
        "completion_percentage": int(env.tracker.progress)
        if status != Status.LAP_COMPLETE.value
        else 100,
        "episode_status": STATUS_LABELS[Status(status)],
        "laps": len(env.tracker.laps),
        "steps": env.tracker.steps,
        "progress": round(env.tracker.progress, 3),
        "total_reward": total_reward,
    }


class EpisodeBook:
    """Per-env running totals, turned into a metrics entry when an episode ends, and the
    car's sim-trace rows as DeepRacer writes them.

    Each car has a clock that runs on across its episodes (``clock_s``, simulated seconds,
    as SimApp's ROS time does): a row's ``tstamp`` is that clock, not the episode's own time,
    and an episode's first row is its ``prepare`` row, stamped at the episode's start, so
    "last tstamp - prepare tstamp" is the episode's simulated time. ``car`` is a random
    48-bit id (under the 1e15 a sandbox may send): unique among the cars of a run, whichever
    process or machine drives them.
    """

    def __init__(self, env: RacingEnv, phase: str = "training") -> None:
        self.env = env
        self.phase = phase
        self.car = secrets.randbits(48)
        self.episodes = 0
        self.reward = 0.0
        self.clock_s = 0.0
        self.first_step = True

    def reset(self) -> None:
        self.reward = 0.0
        self.first_step = True

    def trace(self, row: TraceRow, done: bool) -> list:
        """The step's sim-trace row on the car's clock (``wall_clock`` now), then the car's
        id: JSON scalars only, as a sandboxed worker may send them."""
        if self.first_step:
            row = row._replace(tstamp=self.clock_s)
            if not done:
                row = row._replace(episode_status=Status.PREPARE.value)
        else:
            row = row._replace(tstamp=self.clock_s + row.tstamp)
        self.first_step = False
        if isinstance(row.action, tuple):  # a continuous action, as SimApp writes it: text
            row = row._replace(action=f"[{row.action[0]:.2f} {row.action[1]:.2f}]")
        return [*row.stamped(), self.car]

    def step(self, reward: float, info: dict, done: bool) -> dict | None:
        self.reward += reward
        if not done:
            return None
        entry = episode_entry(
            self.env,
            total_reward=self.reward,
            phase=self.phase,
            episode=self.episodes,
            status=info["status"],
            start_s=self.clock_s,
            car=self.car,
        )
        self.clock_s += float(self.env.tracker.sim_time)
        self.episodes += 1
        return entry


def compact_info(info: dict, *, truncated: bool = False, trace: list | None = None) -> dict:
    """The part of an env step's info that leaves the worker: small and JSON-able. ``trace``
    replaces the env's sim-trace row (e.g. :meth:`EpisodeBook.trace`: the row and the car)."""
    if trace is None and info.get("trace") is not None:
        trace = list(info["trace"])
    out = {
        "status": info["status"],
        "progress": info["progress"],
        "lap": info.get("lap", 1),
        "trace": trace,
    }
    if truncated:
        out["TimeLimit.truncated"] = True
    if info.get("lap_finished"):
        out["lap_times"] = [lap.time_s for lap in info["laps"]]
    return out


def camera_image(observation: np.ndarray | dict) -> np.ndarray:
    """The camera image ``(120, 160, C)`` of an observation: the observation itself, or its
    camera entry when a LIDAR makes it a dict."""
    if isinstance(observation, dict):
        return next(v for v in observation.values() if v.ndim == 3)
    return observation


def stack_observations(observations: list) -> np.ndarray | dict[str, np.ndarray]:
    """One batch of env observations: an array, or a dict of arrays for Dict observations."""
    if observations and isinstance(observations[0], dict):
        return {k: np.stack([o[k] for o in observations]) for k in observations[0]}
    return np.stack(observations)


class FrameGrabber:
    """Encodes JPEG frames of one env (the car's camera and the chase view), 15 fps at most.

    Frames keep a fixed cadence: each is due one interval after the last was due, not after
    it was sent, so steps of 40 ms still give 15 frames a second (counting from the last frame
    gave every other step: 12.5). After a pause (an update, a reset) the cadence starts again
    rather than catching up with a burst. :meth:`restart` makes the next frame due at once: a
    new episode's first step is always shown, however soon the episode ends (an evaluation
    that leaves the track within a frame's interval of the lap before it sent none)."""

    def __init__(self, env: RacingEnv, interval_s: float = FRAME_INTERVAL_S) -> None:
        self.env = env
        self.interval_s = interval_s
        self._due = 0.0
        self._chase = None

    def restart(self) -> None:
        """The next frame is due at once (a reset starts a new episode)."""
        self._due = 0.0

    def due(self, now: float) -> bool:
        """Whether a frame is due at ``now``; if so, schedules the next one."""
        if now < self._due:
            return False
        late = now - self._due >= self.interval_s
        self._due = (now if late else self._due) + self.interval_s
        return True

    def grab(self, observation: np.ndarray | dict) -> dict | None:
        if not self.due(time.monotonic()):
            return None
        if self._chase is None:
            from racing.sensors import ground_for
            from racing.video import ChaseView

            self._chase = ChaseView(ground_for(self.env.track, resolution=0.01, rgb=True))
        camera = camera_image(observation)[..., 0]
        camera = cv2.resize(camera, (320, 240), interpolation=cv2.INTER_NEAREST)
        chase = cv2.cvtColor(self._chase.render(self.env.pose, self.env.objects), cv2.COLOR_RGB2BGR)
        params = [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY]
        ok1, cam_jpg = cv2.imencode(".jpg", camera, params)
        ok2, chase_jpg = cv2.imencode(".jpg", chase, params)
        if not (ok1 and ok2):
            return None
        return {
            "camera": np.frombuffer(cam_jpg.tobytes(), dtype=np.uint8),
            "chase": np.frombuffer(chase_jpg.tobytes(), dtype=np.uint8),
            "progress": round(self.env.tracker.progress, 2),
            "lap": self.env.tracker.lap_number,
        }


def _safe_options(options: object) -> dict:
    """Only the reset options the env knows, as numbers."""
    if not isinstance(options, dict):
        return {}
    keys = ("start_progress", "offset", "heading_offset_deg")
    return {k: float(options[k]) for k in keys if isinstance(options.get(k), int | float)}


DRIVE_INFO_KEYS = frozenset({"status", "progress", "lap", "lap_times", "frame"})
"""What :meth:`EnvRunner.drive` keeps of a step's compact info: what an evaluation reads."""


class EnvRunner:
    """Steps a group of envs with auto-reset, as a SB3 VecEnv worker does.

    Returns stacked observations, rewards, dones and compact infos; finished episodes carry
    ``terminal_observation`` and ``episode_entry`` in their info.
    """

    def __init__(self, envs: list[RacingEnv], phase: str = "training") -> None:
        self.envs = envs
        self.books = [EpisodeBook(env, phase) for env in envs]
        self.frames = FrameGrabber(envs[0])
        self.want_frames = False
        self.obs: Any = None
        """The observations the last reset or step returned (what :meth:`drive` goes on from)."""
        self.finished = np.zeros(len(envs), dtype=bool)
        """Envs whose episode has ended since the last reset (:meth:`drive` stops at all)."""

    def reset(self, seeds: list[int | None], options: list[dict] | None = None):
        obs = []
        options = options or [{}] * len(self.envs)
        for env, book, seed, opts in zip(self.envs, self.books, seeds, options, strict=True):
            o, _ = env.reset(seed=seed, options=_safe_options(opts))
            book.reset()
            obs.append(o)
        self.obs = stack_observations(obs)
        self.finished[:] = False
        self.frames.restart()
        return self.obs

    def step(self, actions: np.ndarray) -> tuple[Any, np.ndarray, np.ndarray, list[dict]]:
        n = len(self.envs)
        obs_out, rewards, dones, infos = [], np.zeros(n, np.float32), np.zeros(n, bool), []
        for i, (env, book) in enumerate(zip(self.envs, self.books, strict=True)):
            action = actions[i]
            if env.actions.kind == "discrete":
                action = int(action)
            obs, reward, terminated, truncated, info = env.step(action)
            done = terminated or truncated
            trace = book.trace(info["trace"], done) if info.get("trace") is not None else None
            compact = compact_info(info, truncated=truncated and not terminated, trace=trace)
            entry = book.step(reward, info, done)
            if i == 0 and self.want_frames:
                frame = self.frames.grab(obs)
                if frame is not None:
                    compact["frame"] = frame
            if done:
                compact["terminal_observation"] = obs
                compact["episode_entry"] = entry
                obs, _ = env.reset()
                book.reset()
            obs_out.append(obs)
            rewards[i] = reward
            dones[i] = done
            infos.append(compact)
        self.obs = stack_observations(obs_out)
        return self.obs, rewards, dones, infos

    def drive(self, net, steps: int) -> dict:
        """Up to ``steps`` steps with ``net``'s greedy actions (a
        :class:`~training.rollout.numpy_policy.GreedyNet`), on from the last reset or step,
        stopping once every env's episode has ended since the last reset: an evaluation
        driven here. Per step, the rewards, dones and the infos an evaluation reads
        (:data:`DRIVE_INFO_KEYS`), stacked: ``rewards`` and ``dones`` (steps × envs)."""
        if self.obs is None:
            raise RuntimeError("drive before reset")
        rewards, dones, infos = [], [], []
        for _ in range(steps):
            if self.finished.all():
                break
            _obs, r, d, i = self.step(net.actions(self.obs))
            self.finished |= d
            rewards.append(r)
            dones.append(d)
            infos.append([{k: v for k, v in info.items() if k in DRIVE_INFO_KEYS} for info in i])
        n = len(self.envs)
        return {
            "rewards": np.array(rewards, dtype=np.float32).reshape(-1, n),
            "dones": np.array(dones, dtype=bool).reshape(-1, n),
            "infos": infos,
        }

    def sample(self, net, steps: int, rng: np.random.Generator) -> dict:
        """``steps`` training steps of every env, each action drawn from ``net``'s
        probabilities with ``rng`` (:meth:`GreedyNet.sample
        <training.rollout.numpy_policy.GreedyNet.sample>`), on from the last reset or step,
        ending episodes resetting as :meth:`step` does: a PPO rollout driven here. Stacked
        per step: ``obs`` (each step's observations before its action), ``actions``,
        ``rewards``, ``dones`` and ``infos`` (as :meth:`step` gives them; a terminal
        observation only where the time limit cut the episode), and ``next_obs``, the
        observations after the last step."""
        if self.obs is None:
            raise RuntimeError("sample before reset")
        if not isinstance(self.obs, np.ndarray):
            raise RuntimeError("sample drives camera observations only")
        obs, actions, rewards, dones, infos = [], [], [], [], []
        for _ in range(steps):
            chosen = net.sample(self.obs, rng)
            obs.append(self.obs)
            actions.append(chosen)
            _next, r, d, i = self.step(chosen)
            for info in i:
                if not info.get("TimeLimit.truncated", False):
                    info.pop("terminal_observation", None)
            rewards.append(r)
            dones.append(d)
            infos.append(i)
        n = len(self.envs)
        return {
            "obs": np.stack(obs),
            "actions": np.array(actions, dtype=np.int64).reshape(-1, n),
            "rewards": np.array(rewards, dtype=np.float32).reshape(-1, n),
            "dones": np.array(dones, dtype=bool).reshape(-1, n),
            "infos": infos,
            "next_obs": self.obs,
        }

    def close(self) -> None:
        for env in self.envs:
            env.close()
