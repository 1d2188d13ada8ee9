"""Racing models and their jobs, with DeepRacer's statuses. State changes live in services;
the methods here only describe a row."""

from __future__ import annotations

from django.conf import settings
from django.core.validators import MaxValueValidator, MinValueValidator, RegexValidator
from django.db import models
from django.utils import timezone

MODEL_NAME_RE = r"^[A-Za-z0-9-]{1,64}$"


class RaceType(models.TextChoices):
    TIME_TRIAL = "TIME_TRIAL", "Time trial"
    OBJECT_AVOIDANCE = "OBJECT_AVOIDANCE", "Object avoidance"
    HEAD_TO_BOT = "HEAD_TO_BOT", "Head-to-head against bots"


class Direction(models.TextChoices):
    NATIVE = "native", "Track's own direction"
    COUNTER_CLOCKWISE = "ccw", "Counter-clockwise"
    CLOCKWISE = "cw", "Clockwise"


def stop_condition_words(max_minutes: int, stop_when_ready: int) -> str:
    """A training's stop condition in words: ``60 min, or when ready: 3 evaluations in a row
    complete every lap``."""
    words = f"{max_minutes} min"
    if stop_when_ready:
        evaluations = (
            "an evaluation" if stop_when_ready == 1 else f"{stop_when_ready} evaluations in a row"
        )
        verb = "completes" if stop_when_ready == 1 else "complete"
        words += f", or when ready: {evaluations} {verb} every lap"
    return words


STOPPED_BY_WORDS = {
    "user": "stopped by you",
    "time_limit": "time limit reached",
    "ready": "ready: its evaluations completed every lap",
}
"""How a training job ended (``TrainingJob.stopped_by``), in words."""


class RacingModel(models.Model):
    """A user's model: its configuration (immutable once created, as on DeepRacer) and state."""

    class Status(models.TextChoices):
        QUEUED = "QUEUED", "Queued"
        TRAINING = "TRAINING", "Training"
        EVALUATING = "EVALUATING", "Evaluating"
        STOPPING = "STOPPING", "Stopping"
        READY = "READY", "Ready"
        ERROR = "ERROR", "Error"
        DELETING = "DELETING", "Deleting"

    owner = models.ForeignKey(
        settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="racing_models"
    )
    name = models.CharField(
        max_length=64,
        validators=[RegexValidator(MODEL_NAME_RE, "1-64 letters, digits or hyphens, no spaces")],
    )
    description = models.CharField(max_length=255, blank=True)
    track_id = models.CharField(max_length=64)
    direction = models.CharField(max_length=8, choices=Direction.choices, default=Direction.NATIVE)
    extra_tracks = models.JSONField(default=list, blank=True)
    """Multi-track training: more ``[track_id, direction]`` pairs trained on beside
    ``track_id``/``direction`` (the cars are dealt the tracks in turn); empty: one track."""
    race_type = models.CharField(
        max_length=20, choices=RaceType.choices, default=RaceType.TIME_TRIAL
    )
    race_config = models.JSONField(default=dict, blank=True)
    """The race's boxes or bots (``racing.race.RaceConfig.to_dict()``); {} in a time trial."""
    sensors = models.JSONField(default=list)
    neural_network = models.CharField(max_length=64)
    action_space_type = models.CharField(max_length=12)
    action_space = models.JSONField()
    algorithm = models.CharField(max_length=16)
    hyperparameters = models.JSONField(default=dict)
    reward_function = models.TextField()
    max_minutes = models.PositiveIntegerField(
        default=10, validators=[MinValueValidator(1), MaxValueValidator(1440)]
    )
    stop_when_ready = models.PositiveSmallIntegerField(
        default=0, validators=[MaxValueValidator(20)]
    )
    """The stop condition beside the time: training ends once this many evaluations in a row
    have completed every lap (0: off)."""
    seed = models.PositiveIntegerField(default=0)
    parent = models.ForeignKey(
        "self", null=True, blank=True, on_delete=models.SET_NULL, related_name="clones"
    )
    imported = models.BooleanField(default=False)
    open_to_challenges = models.BooleanField(default=False)
    """Other racers may pick this model as an opponent on their Races page (a frozen copy of
    its best checkpoint races; its owner sees who raced it). Off by default."""
    status = models.CharField(max_length=12, choices=Status.choices, default=Status.READY)
    has_checkpoint = models.BooleanField(default=False)
    error = models.TextField(blank=True)
    created_at = models.DateTimeField(default=timezone.now)
    updated_at = models.DateTimeField(auto_now=True)
    conditions = models.JSONField(default=dict, blank=True)
    """Training for the world outside: ``racing.conditions.ConditionsSpec.to_dict()`` of the
    families (light, look, camera, car, latency) every training episode draws its conditions
    from; {} (the default): off, a clean world. Evaluations stay clean."""
    store_prefix = models.CharField(max_length=96, blank=True, editable=False)
    """The model's folder in the object store, ``u<owner id>-<name>`` (DeepRacer tools read a
    model under its own name), fixed when the row is created; blank for models stored before
    it existed, whose folder is their id."""

    class Meta:
        ordering = ["-created_at"]
        constraints = [
            models.UniqueConstraint(fields=["owner", "name"], name="unique_model_name_per_owner")
        ]

    def __str__(self) -> str:
        return self.name

    def save(self, *args, **kwargs) -> None:
        if self._state.adding and not self.store_prefix:
            self.store_prefix = f"u{self.owner_id}-{self.name}"
        super().save(*args, **kwargs)

    @property
    def store_folder(self) -> str:
        """The folder name in the store: ``store_prefix``, or the id for older models."""
        return self.store_prefix or str(self.pk)

    @property
    def stop_condition(self) -> str:
        return stop_condition_words(self.max_minutes, self.stop_when_ready)

    @property
    def training_tracks(self) -> list[tuple[str, str]]:
        """Every ``(track_id, direction)`` the model trains on, its own track first."""
        return [(self.track_id, self.direction), *((t, d) for t, d in self.extra_tracks)]

    @property
    def is_busy(self) -> bool:
        return self.status in (
            self.Status.QUEUED,
            self.Status.TRAINING,
            self.Status.EVALUATING,
            self.Status.STOPPING,
            self.Status.DELETING,
        )


class JobStatus(models.TextChoices):
    QUEUED = "QUEUED", "Queued"
    INITIALIZING = "INITIALIZING", "Initializing"
    IN_PROGRESS = "IN_PROGRESS", "In progress"
    STOPPING = "STOPPING", "Stopping"
    COMPLETED = "COMPLETED", "Completed"
    FAILED = "FAILED", "Failed"
    CANCELED = "CANCELED", "Canceled"


ACTIVE_JOB_STATUSES = (
    JobStatus.QUEUED,
    JobStatus.INITIALIZING,
    JobStatus.IN_PROGRESS,
    JobStatus.STOPPING,
)
RUNNING_JOB_STATUSES = (JobStatus.INITIALIZING, JobStatus.IN_PROGRESS, JobStatus.STOPPING)
"""A worker holds the job (and sends heartbeats)."""
FINISHED_JOB_STATUSES = (JobStatus.COMPLETED, JobStatus.FAILED, JobStatus.CANCELED)


class Job(models.Model):
    """What training and evaluation jobs share: DeepRacer's lifecycle, timestamps, an error
    in plain words, a cooperative stop flag and a heartbeat for noticing dead workers."""

    status = models.CharField(max_length=16, choices=JobStatus.choices, default=JobStatus.QUEUED)
    created_at = models.DateTimeField(default=timezone.now)
    started_at = models.DateTimeField(null=True, blank=True)
    finished_at = models.DateTimeField(null=True, blank=True)
    heartbeat_at = models.DateTimeField(null=True, blank=True)
    stop_requested = models.BooleanField(default=False)
    error = models.TextField(blank=True)
    task_id = models.CharField(max_length=64, blank=True)
    worker = models.CharField(max_length=255, blank=True)
    attempts = models.PositiveSmallIntegerField(default=0)
    """How many times a worker claimed the job (a job whose worker died is queued again)."""

    class Meta:
        abstract = True
        ordering = ["-created_at"]

    @property
    def is_active(self) -> bool:
        return self.status in ACTIVE_JOB_STATUSES

    @property
    def elapsed_seconds(self) -> float:
        if self.started_at is None:
            return 0.0
        end = self.finished_at or timezone.now()
        return max(0.0, (end - self.started_at).total_seconds())


class TrainingJob(Job):
    model = models.ForeignKey(RacingModel, on_delete=models.CASCADE, related_name="training_jobs")
    max_minutes = models.PositiveIntegerField()
    stop_when_ready = models.PositiveSmallIntegerField(default=0)
    """The model's setting when the job was queued (0: the time limit alone)."""
    iterations = models.PositiveIntegerField(default=0)
    total_steps = models.PositiveBigIntegerField(default=0)
    episodes = models.PositiveIntegerField(default=0)
    best_iteration = models.PositiveIntegerField(null=True, blank=True)
    best_eval_progress = models.FloatField(default=0.0)
    stopped_by = models.CharField(max_length=16, blank=True)
    resumed_from = models.CharField(max_length=500, blank=True)
    """What the job's network started from, in words (a checkpoint, a parent, a fresh net)."""

    @property
    def stop_condition(self) -> str:
        return stop_condition_words(self.max_minutes, self.stop_when_ready)

    @property
    def stop_condition_short(self) -> str:
        """The stop condition for a small space: ``60 min or ready (3 in a row)``."""
        ready = f" or ready ({self.stop_when_ready} in a row)" if self.stop_when_ready else ""
        return f"{self.max_minutes} min{ready}"

    @property
    def stopped_by_words(self) -> str:
        """How the job ended, in words ("" while it runs, or when it failed)."""
        return STOPPED_BY_WORDS.get(self.stopped_by, self.stopped_by)

    @property
    def remaining_seconds(self) -> float:
        if self.started_at is None or not self.is_active:
            return 0.0
        return max(0.0, self.max_minutes * 60 - self.elapsed_seconds)

    def __str__(self) -> str:
        return f"training #{self.pk} of {self.model}"


class IterationMetric(models.Model):
    """One point of DeepRacer's reward graph, plus where the time went."""

    job = models.ForeignKey(TrainingJob, on_delete=models.CASCADE, related_name="iterations_set")
    iteration = models.PositiveIntegerField()
    episodes = models.PositiveIntegerField()
    steps = models.PositiveIntegerField()
    total_steps = models.PositiveBigIntegerField()
    train_reward = models.FloatField()
    train_progress = models.FloatField()
    eval_progress = models.FloatField()
    eval_reward = models.FloatField(default=0.0)
    eval_laps_completed = models.PositiveIntegerField(default=0)
    is_best = models.BooleanField(default=False)
    elapsed_s = models.FloatField()
    rollout_s = models.FloatField(default=0.0)
    update_s = models.FloatField(default=0.0)
    eval_s = models.FloatField(default=0.0)
    created_at = models.DateTimeField(default=timezone.now)

    class Meta:
        ordering = ["job", "iteration"]
        constraints = [
            models.UniqueConstraint(fields=["job", "iteration"], name="unique_iteration_per_job")
        ]

    def as_point(self) -> dict:
        return {
            "iteration": self.iteration,
            "train_reward": round(self.train_reward, 3),
            "train_progress": round(self.train_progress, 2),
            "eval_progress": round(self.eval_progress, 2),
            "is_best": self.is_best,
            "elapsed_s": round(self.elapsed_s, 1),
            "total_steps": self.total_steps,
        }


class EpisodeMetric(models.Model):
    """One episode: the fields of DeepRacer's TrainingMetrics.json. ``episode`` counts from 1
    across the run, ``trial`` from 1 in each iteration (of the log: see
    :class:`training.worker.training.JobHooks`); an ``evaluation`` row carries the episode and
    trial of the training row before it. Times are simulated milliseconds."""

    job = models.ForeignKey(TrainingJob, on_delete=models.CASCADE, related_name="episode_metrics")
    iteration = models.PositiveIntegerField()
    episode = models.PositiveIntegerField()
    trial = models.PositiveIntegerField(default=0)
    phase = models.CharField(max_length=12, default="training")
    reward_score = models.IntegerField()
    completion_percentage = models.PositiveSmallIntegerField()
    episode_status = models.CharField(max_length=20)
    elapsed_time_in_milliseconds = models.PositiveBigIntegerField()
    start_time = models.PositiveBigIntegerField()
    metric_time = models.PositiveBigIntegerField()
    track = models.CharField(max_length=64, blank=True)
    """The track the episode was driven on, for a model that trains on several; else blank."""

    class Meta:
        ordering = ["job", "pk"]
        indexes = [models.Index(fields=["job", "iteration"])]

    def as_deepracer(self) -> dict:
        return {
            "reward_score": self.reward_score,
            "metric_time": self.metric_time,
            "start_time": self.start_time,
            "elapsed_time_in_milliseconds": self.elapsed_time_in_milliseconds,
            "episode": self.episode,
            "trial": self.trial,
            "phase": self.phase,
            "completion_percentage": self.completion_percentage,
            "episode_status": self.episode_status,
            **({"track": self.track} if self.track else {}),  # multi-track training
        }


class EvaluationJob(Job):
    """An evaluation: 3-5 laps on a track under DeepRacer's rules, with results and a video."""

    model = models.ForeignKey(RacingModel, on_delete=models.CASCADE, related_name="evaluations")
    track_id = models.CharField(max_length=64)
    direction = models.CharField(max_length=8, choices=Direction.choices, default=Direction.NATIVE)
    race_type = models.CharField(
        max_length=20, choices=RaceType.choices, default=RaceType.TIME_TRIAL
    )
    race_config = models.JSONField(default=dict, blank=True)
    """The race's boxes or bots (``racing.race.RaceConfig.to_dict()``); {} in a time trial."""
    laps = models.PositiveSmallIntegerField(
        default=3, validators=[MinValueValidator(3), MaxValueValidator(5)]
    )
    off_track_penalty_s = models.FloatField(default=2.0)
    crash_penalty_s = models.FloatField(default=5.0)
    checkpoint = models.CharField(max_length=8, default="best")
    purpose = models.CharField(max_length=16, default="user")  # user | submission
    results = models.JSONField(default=dict, blank=True)
    laps_done = models.PositiveSmallIntegerField(default=0)
    has_video = models.BooleanField(default=False)
    log_stamp = models.CharField(max_length=14, blank=True)
    """``YYYYMMDDhhmmss`` (UTC) of DeepRacer-for-Cloud's ``evaluation-<stamp>/`` folder and
    ``EvaluationMetrics-<stamp>.json``; blank for evaluations stored under their id."""
    conditions = models.JSONField(default=dict, blank=True)
    """The outside-world conditions the evaluation drives in (``ConditionsSpec.to_dict()``,
    a league event's setting); {} (the default): the clean world."""
    conditions_seed = models.PositiveIntegerField(null=True, blank=True)
    """The seed of those conditions' draws (the event's: every entrant meets the same)."""

    def __str__(self) -> str:
        return f"evaluation #{self.pk} of {self.model}"

    @property
    def lap_rows(self) -> list[dict]:
        return list(self.results.get("laps", [])) if isinstance(self.results, dict) else []


class RaceJob(Job):
    """A head-to-head race of 2-4 racers' models (``racing.headtohead``), run on an evaluation
    worker. ``entries`` lists the cars in entry order: ``{"model": id, "name": ...,
    "checkpoint": key}``; a ``checkpoint`` key names a frozen copy of the model's weights in
    the store (a league entry), else the model's best checkpoint is raced as it is when the
    race starts. The broadcast MP4 and each car's sim-trace go to the store under
    ``races/<id>/``."""

    owner = models.ForeignKey(
        settings.AUTH_USER_MODEL, null=True, blank=True, on_delete=models.SET_NULL,
        related_name="races",
    )  # fmt: skip
    title = models.CharField(max_length=120, blank=True)
    purpose = models.CharField(max_length=16, default="race")  # race | league
    entries = models.JSONField(default=list)
    track_id = models.CharField(max_length=64)
    direction = models.CharField(max_length=8, choices=Direction.choices, default=Direction.NATIVE)
    laps = models.PositiveSmallIntegerField(
        default=3, validators=[MinValueValidator(1), MaxValueValidator(10)]
    )
    bots = models.PositiveSmallIntegerField(default=0, validators=[MaxValueValidator(6)])
    bot_speed = models.FloatField(default=0.75)
    seed = models.PositiveIntegerField(default=0)
    round_number = models.PositiveSmallIntegerField(default=0)
    off_track_penalty_s = models.FloatField(default=5.0)
    crash_penalty_s = models.FloatField(default=5.0)
    time_limit_s = models.FloatField(null=True, blank=True)
    results = models.JSONField(default=dict, blank=True)
    has_video = models.BooleanField(default=False)
    race_time_s = models.FloatField(default=0.0)
    paced = models.BooleanField(default=False)
    """Run at real time (a live race day's broadcast), not as fast as the worker can."""
    broadcast_group = models.CharField(max_length=80, blank=True)
    """A Channels group that gets the live frames besides the race's own (a race day's)."""
    conditions = models.JSONField(default=dict, blank=True)
    """The outside-world conditions every car's camera sees (``racing.conditions.Conditions.
    to_dict()``: one draw, a league event's); {} (the default): the clean world."""
    opponents = models.ManyToManyField(
        settings.AUTH_USER_MODEL, blank=True, related_name="challenged_races"
    )
    """The owners of the models a racer challenged from the Races page (not the challenger,
    who is :attr:`owner`): who sees the result row and the replay of the race."""

    def __str__(self) -> str:
        return self.title or f"race #{self.pk}"

    @property
    def model_ids(self) -> list[int]:
        return [int(entry["model"]) for entry in self.entries]

    @property
    def car_rows(self) -> list[dict]:
        return list(self.results.get("cars", [])) if isinstance(self.results, dict) else []


class ReadinessCheck(Job):
    """A readiness check (issue 51): the model's best checkpoint driven from the start line
    under each family of conditions at several strengths (``training.rl.readiness``), on its
    own queue. ``results`` is the table (``ReadinessTable.to_json()``); ``videos`` the cell
    keys (``light-0_67``) of the worst cells whose MP4 is in the store, under the model's
    folder (``ModelKeys.video(readiness_video_id(check, key))``)."""

    model = models.ForeignKey(
        RacingModel, on_delete=models.CASCADE, related_name="readiness_checks"
    )
    track_id = models.CharField(max_length=64)
    direction = models.CharField(max_length=8, choices=Direction.choices, default=Direction.NATIVE)
    plan = models.JSONField(default=dict, blank=True)
    """``ReadinessPlan.to_dict()``: families, strengths, laps and episodes per cell, seed."""
    results = models.JSONField(default=dict, blank=True)
    verdict = models.CharField(max_length=300, blank=True)
    ready = models.BooleanField(null=True, blank=True)
    cells_done = models.PositiveSmallIntegerField(default=0)
    cells_total = models.PositiveSmallIntegerField(default=0)
    videos = models.JSONField(default=list, blank=True)

    def __str__(self) -> str:
        return f"readiness check #{self.pk} of {self.model}"

    @property
    def cells(self) -> list[dict]:
        return list(self.results.get("cells", [])) if isinstance(self.results, dict) else []


class TrackFile(models.Model):
    """An imported track's file (DeepRacer's ``.npy`` waypoints, as the catalogue stores it),
    kept in the database so that every machine gets it by content: a worker that shares no disk
    with the web writes it into its own ``RACECRAFT_TRACKS_DIR`` before a job needs it
    (``services.tracks_sync``). Built-in tracks ship with the code and have no row."""

    track_id = models.CharField(max_length=64, unique=True)
    name = models.CharField(max_length=200, blank=True)
    sha256 = models.CharField(max_length=64)
    data = models.BinaryField()
    created_by = models.ForeignKey(
        settings.AUTH_USER_MODEL, null=True, blank=True, on_delete=models.SET_NULL,
        related_name="+",
    )  # fmt: skip
    created_at = models.DateTimeField(default=timezone.now)

    def __str__(self) -> str:
        return f"{self.track_id} ({self.sha256[:12]})"
