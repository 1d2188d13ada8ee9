"""Evaluating a model as DeepRacer does: 3 to 5 laps back to back from the start line, with
resets and penalties, per-lap results, EvaluationMetrics entries, a sim-trace (one episode per
lap, as DeepRacer writes it) and an MP4.

No user code runs here: an evaluation drives the policy; the reward column of the sim-trace is
0 (DeepRacer's evaluations do not train, so nothing reads it). It refuses to run in a process
that ever loaded a reward function (:mod:`training.sandbox.taint`): a leaderboard's lap is
never judged by a simulator the racer's code could have touched.
"""

from __future__ import annotations

import io
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import cv2
import numpy as np

from racing.env import Observation, RacingEnv
from racing.rules import STATUS_LABELS, LapRecord, Status
from racing.sensors import ground_for
from racing.simtrace import TraceRow
from racing.video import ChaseView
from training.rollout.envs import EnvSpec, FrameGrabber, camera_image
from training.sandbox.taint import refuse_if_tainted

MIN_LAPS, MAX_LAPS = 3, 5
DEFAULT_RESETS = 10_000
"""DeepRacer on AWS allows this many resets in an evaluation: effectively unlimited."""
MAX_LAP_SECONDS = 180.0
"""A lap not finished within this many simulated seconds ends the evaluation (time up)."""
VIDEO_FPS = 15
PIP_SCALE = 0.5


class EvaluationError(ValueError):
    """Settings outside what an evaluation allows."""


@dataclass(frozen=True)
class EvaluationSettings:
    """``laps`` 3-5; penalties in seconds (DeepRacer: off track 2 s, crash 5 s)."""

    laps: int = 3
    off_track_penalty_s: float = 2.0
    crash_penalty_s: float = 5.0
    resets: int = DEFAULT_RESETS
    record_video: bool = True

    def __post_init__(self) -> None:
        if not MIN_LAPS <= self.laps <= MAX_LAPS:
            raise EvaluationError(f"an evaluation runs {MIN_LAPS} to {MAX_LAPS} laps")
        for name in ("off_track_penalty_s", "crash_penalty_s"):
            value = getattr(self, name)
            if not 0 <= value <= 60:
                raise EvaluationError(f"{name.replace('_', ' ')} must be 0-60 seconds")
        if self.resets < 0:
            raise EvaluationError("resets cannot be negative")


@dataclass
class LapResult:
    """One trial (lap) of an evaluation, as the DeepRacer results table shows it."""

    trial: int
    time_s: float
    progress: float
    status: str
    off_tracks: int
    off_track_penalty_s: float
    crashes: int
    crash_penalty_s: float
    resets: int
    reversals: int = 0
    immobilizations: int = 0

    @property
    def status_label(self) -> str:
        return STATUS_LABELS[Status(self.status)]

    @property
    def completed(self) -> bool:
        return self.status == Status.LAP_COMPLETE.value


@dataclass
class EvaluationReport:
    laps: list[LapResult]
    metrics: list[dict]
    rows: list[list]
    video_mp4: bytes | None = None
    stopped: bool = False
    steps: int = 0
    wall_s: float = 0.0
    extra: dict = field(default_factory=dict)

    @property
    def completed_laps(self) -> int:
        return sum(1 for lap in self.laps if lap.completed)

    def metrics_json(self) -> dict:
        """``EvaluationMetrics.json`` in DeepRacer's shape."""
        return {"metrics": self.metrics, "version": 2}

    def to_json(self) -> dict:
        """The results a job stores; ``conditions``: the outside-world conditions driven in
        (:meth:`racing.conditions.Conditions.to_dict`), when not the clean world."""
        extra = {"conditions": self.extra["conditions"]} if self.extra.get("conditions") else {}
        return {"laps": [asdict(lap) for lap in self.laps], "completed_laps": self.completed_laps,
                "stopped": self.stopped, "steps": self.steps, **extra}  # fmt: skip


def _lap_result(lap: LapRecord, settings: EvaluationSettings) -> LapResult:
    return LapResult(
        trial=lap.lap,
        time_s=round(lap.time_s, 3),
        progress=round(lap.progress, 2),
        status=lap.status.value,
        off_tracks=lap.off_tracks,
        off_track_penalty_s=lap.off_tracks * settings.off_track_penalty_s,
        crashes=lap.crashes,
        crash_penalty_s=lap.crashes * settings.crash_penalty_s,
        resets=lap.resets,
        reversals=lap.reversals,
        immobilizations=lap.immobilizations,
    )


class LapTrace:
    """Sim-trace rows of an evaluation as DeepRacer writes them: one episode per lap
    (``episode`` = lap - 1), ``steps`` from 1 in each lap, the lap's first row ``prepare`` and
    stamped at the lap's start, ``tstamp`` the evaluation's simulated clock (seconds), the
    lap's last row ``done`` with the lap's progress (100 for a finished lap, as DeepRacer's)."""

    def __init__(self) -> None:
        self.rows: list[list] = []
        self.lap = 0
        self.lap_start_s = 0.0
        self.step = 0

    def add(self, row: TraceRow, *, finished: LapRecord | None, done: bool) -> None:
        """One step; ``finished`` is the lap this step ended, if it ended one."""
        self.step += 1
        lap_finished = finished is not None
        row = row._replace(episode=self.lap, steps=self.step, done=lap_finished or done)
        if finished is not None:
            row = row._replace(progress=float(finished.progress))
        if self.step == 1:
            row = row._replace(tstamp=self.lap_start_s)
            if not row.done:
                row = row._replace(episode_status=Status.PREPARE.value)
        self.rows.append(list(row.stamped()))
        if lap_finished:
            self.lap, self.lap_start_s, self.step = self.lap + 1, row.tstamp, 0


def _metric(lap: LapRecord, start_s: float) -> dict:
    """One ``EvaluationMetrics`` entry: a lap (``trial``), times in simulated milliseconds from
    the evaluation's start (``start_s``: seconds when the lap began), as SimApp writes them."""
    return {
        "trial": lap.lap,
        "completion_percentage": int(lap.progress),
        "elapsed_time_in_milliseconds": int(round(lap.time_s * 1000)),
        "metric_time": int(round((start_s + lap.time_s) * 1000)),
        "start_time": int(round(start_s * 1000)),
        "episode_status": STATUS_LABELS[lap.status],
        "crash_count": lap.crashes,
        "immobilized_count": lap.immobilizations,
        "off_track_count": lap.off_tracks,
        "reversed_count": lap.reversals,
        "reset_count": lap.resets,
    }


class VideoWriter:
    """H.264 MP4 in memory at 15 frames/s: the chase view with the car's camera inset
    (:meth:`add`), or any frames of the writer's size (:meth:`add_frame`)."""

    def __init__(self, width: int = 320, height: int = 240) -> None:
        import av

        self.buffer = io.BytesIO()
        self.container = av.open(self.buffer, mode="w", format="mp4")
        self.stream = self.container.add_stream("libx264", rate=VIDEO_FPS)
        self.stream.width, self.stream.height = width, height
        self.stream.pix_fmt = "yuv420p"
        self.stream.options = {"preset": "veryfast", "crf": "26"}
        self.frames = 0
        self._av = av

    def add(self, chase_rgb: np.ndarray, camera_gray: np.ndarray) -> None:
        """A frame of the chase view with the car's camera inset at its top right."""
        frame = chase_rgb.copy()
        h, w = camera_gray.shape[:2]
        inset = cv2.resize(camera_gray, (int(w * PIP_SCALE * 1.5), int(h * PIP_SCALE * 1.5)))
        ih, iw = inset.shape[:2]
        frame[6 : 6 + ih, -6 - iw : -6] = inset[..., None]
        cv2.rectangle(
            frame, (frame.shape[1] - 7 - iw, 5), (frame.shape[1] - 6, 6 + ih), (255, 255, 255), 1
        )
        self.add_frame(frame)

    def add_frame(self, rgb: np.ndarray) -> None:
        """One ``(height, width, 3)`` RGB frame as it is. OpenCV converts it to the encoder's
        YUV 4:2:0 (several times faster than libswscale's default path here)."""
        yuv = cv2.cvtColor(rgb, cv2.COLOR_RGB2YUV_I420)
        video_frame = self._av.VideoFrame.from_ndarray(yuv, format="yuv420p")
        for packet in self.stream.encode(video_frame):
            self.container.mux(packet)
        self.frames += 1

    def finish(self) -> bytes | None:
        for packet in self.stream.encode():
            self.container.mux(packet)
        self.container.close()
        return self.buffer.getvalue() if self.frames else None


def evaluation_env(spec: EnvSpec, settings: EvaluationSettings) -> RacingEnv:
    rules = {
        "laps": settings.laps,
        "resets": settings.resets,
        "off_track_penalty_s": settings.off_track_penalty_s,
        "crash_penalty_s": settings.crash_penalty_s,
        "time_limit_s": settings.laps * MAX_LAP_SECONDS,
    }
    return spec.make(lambda params: 0.0, start="start_line", alternate_direction=False,
                     rules=_rules(rules))  # fmt: skip


def _rules(data: dict):
    from racing.rules import RaceRules

    return RaceRules(**data)


def evaluate(
    policy: Callable[[Observation], object],
    spec: EnvSpec,
    settings: EvaluationSettings,
    *,
    on_progress: Callable[[dict], None] | None = None,
    should_stop: Callable[[], bool] | None = None,
    on_frame: Callable[[dict], None] | None = None,
    frames_wanted: Callable[[], bool] | None = None,
) -> EvaluationReport:
    """Drive ``policy`` (observation → action) for ``settings.laps`` laps from the start line,
    in ``spec``'s race (its boxes or bots on the track and in the video; an observation is the
    camera image, or a dict of the camera and the LIDAR).

    ``on_progress`` gets ``{"lap", "laps_done", "progress", "frame"?}`` about 15 times per
    simulated second of driving; ``should_stop`` is polled every step (a stopped evaluation
    keeps what it measured); ``on_frame`` gets live JPEG frames (camera and chase view, 15 fps
    at most) while ``frames_wanted()`` says someone watches.
    """
    refuse_if_tainted("An evaluation")  # the judge never shares a process with user code
    started = time.monotonic()
    env = evaluation_env(spec, settings)
    video = VideoWriter() if settings.record_video else None
    chase = ChaseView(ground_for(env.track, resolution=0.01, rgb=True)) if video else None
    obs, reset_info = env.reset(seed=0)
    # The outside-world conditions the episode drew (a league event's), recorded with the laps.
    drawn = reset_info.get("conditions") if isinstance(reset_info, dict) else None
    grabber = FrameGrabber(env) if on_frame is not None else None
    trace = LapTrace()
    stopped = False
    info: dict = {}
    try:
        while True:
            action = policy(obs)
            obs, _, terminated, truncated, info = env.step(action)
            finished = info["laps"][-1] if info.get("lap_finished") and info["laps"] else None
            trace.add(info["trace"], finished=finished, done=terminated or truncated)
            if video is not None and chase is not None:
                video.add(chase.render(env.pose, env.objects), camera_image(obs)[..., 0])
            if (
                grabber is not None
                and on_frame is not None
                and (frames_wanted is None or frames_wanted())
            ):
                frame = grabber.grab(obs)
                if frame is not None:
                    on_frame(frame)
            if on_progress is not None:
                on_progress({"lap": info["lap"], "laps_done": len(info["laps"]),
                             "progress": info["progress"], "status": info["status"]})  # fmt: skip
            if terminated or truncated:
                break
            if should_stop is not None and should_stop():
                stopped = True
                break
    finally:
        env.close()
    laps = list(env.tracker.laps)
    current = env.tracker.current_lap
    if current not in laps and len(laps) < settings.laps:
        if current.status is Status.IN_PROGRESS:
            current.status = Status.TIME_UP if not stopped else Status.IN_PROGRESS
        current.time_s = env.tracker.sim_time - env.tracker.lap_start_time
        current.progress = env.tracker.progress
        laps.append(current)
    starts = np.cumsum([0.0] + [lap.time_s for lap in laps])
    return EvaluationReport(
        laps=[_lap_result(lap, settings) for lap in laps],
        metrics=[_metric(lap, float(start)) for lap, start in zip(laps, starts, strict=False)],
        rows=trace.rows,
        video_mp4=video.finish() if video else None,
        stopped=stopped,
        steps=env.tracker.steps,
        wall_s=time.monotonic() - started,
        extra={"conditions": drawn} if drawn else {},
    )


def sb3_policy(model) -> Callable[[Observation], object]:
    """A deterministic policy function from an SB3 model (image or Dict observations)."""

    def act(obs: Observation):
        action, _ = model.predict(obs, deterministic=True)
        return action

    return act
