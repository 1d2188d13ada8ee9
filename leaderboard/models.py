"""The league: seasons, events, divisions, racer profiles, submissions and notifications.

Rules live in services (leaderboard/services.py, events.py, divisions.py, profiles.py) and
scores in the pure leaderboard/ranking.py; the methods here only describe a row.
"""

from __future__ import annotations

import secrets
from datetime import datetime

from django.conf import settings
from django.core.validators import MaxValueValidator, MinValueValidator, RegexValidator
from django.db import models
from django.utils import timezone

from training.models import Direction, EvaluationJob, RaceJob, RaceType, RacingModel
from training.services.checks import track_catalog

MIN_EVALUATION_LAPS = 3
"""The evaluator runs 3-5 laps: an event whose maximum is lower still runs 3."""
FACILITATORS_GROUP = "Race facilitators"


def new_invite_token() -> str:
    return secrets.token_urlsafe(24)


class Division(models.TextChoices):
    OPEN = "OPEN", "Open"
    PRO = "PRO", "Pro"


class RankingMethod(models.TextChoices):
    BEST_LAP = "BEST_LAP", "Best lap time"
    AVERAGE_LAP = "AVERAGE_LAP", "Average lap time"
    TOTAL_TIME = "TOTAL_TIME", "Total time"


class Season(models.Model):
    name = models.CharField(max_length=80, unique=True)
    description = models.TextField(blank=True)
    starts_on = models.DateField()
    ends_on = models.DateField()

    class Meta:
        ordering = ["-starts_on"]

    def __str__(self) -> str:
        return self.name


class Event(models.Model):
    """A race: a track and rules, open between two instants, for one division.

    A private event is a community race: reachable only through ``/league/join/<invite_token>/``
    until it closes; the division rule does not apply to it. Object-avoidance races use the
    box settings, head-to-bot races the bot settings (``leaderboard.events.event_race``).
    """

    season = models.ForeignKey(
        Season, null=True, blank=True, on_delete=models.SET_NULL, related_name="events"
    )
    name = models.CharField(max_length=80)
    description = models.TextField(blank=True)
    track_id = models.CharField(max_length=64)
    direction = models.CharField(max_length=8, choices=Direction.choices, default=Direction.NATIVE)
    race_type = models.CharField(
        max_length=20, choices=RaceType.choices, default=RaceType.TIME_TRIAL
    )
    # Object avoidance.
    number_of_objects = models.PositiveSmallIntegerField(
        default=0, validators=[MaxValueValidator(12)]
    )
    randomize_objects = models.BooleanField(default=False)
    # Head-to-bot.
    bot_count = models.PositiveSmallIntegerField(default=0, validators=[MaxValueValidator(6)])
    bot_speed_mps = models.FloatField(
        default=1.0, validators=[MinValueValidator(0.2), MaxValueValidator(6.0)]
    )
    bot_lane_changes = models.BooleanField(default=False)
    # The world outside (issue 51): off ({}) by default, racing stays in the clean world.
    conditions = models.JSONField(default=dict, blank=True)
    """``racing.conditions.ConditionsSpec.to_dict()`` of the conditions every entrant's
    evaluation drives in; {}: the clean world."""
    conditions_seed = models.PositiveIntegerField(default=0)
    """The seed of the conditions' draws: every entrant meets the same sequence."""

    opens_at = models.DateTimeField()
    closes_at = models.DateTimeField()
    division = models.CharField(max_length=4, choices=Division.choices, default=Division.OPEN)
    ranking_method = models.CharField(
        max_length=12, choices=RankingMethod.choices, default=RankingMethod.BEST_LAP
    )
    min_laps = models.PositiveSmallIntegerField(
        default=1, validators=[MinValueValidator(1), MaxValueValidator(5)]
    )
    max_laps = models.PositiveSmallIntegerField(
        default=3, validators=[MinValueValidator(1), MaxValueValidator(5)]
    )
    off_track_penalty_s = models.FloatField(
        default=1.0, validators=[MinValueValidator(0), MaxValueValidator(60)]
    )
    collision_penalty_s = models.FloatField(
        default=1.0, validators=[MinValueValidator(0), MaxValueValidator(60)]
    )
    max_resets = models.PositiveIntegerField(
        null=True, blank=True, help_text="Empty means unlimited resets."
    )
    max_submissions_per_racer = models.PositiveSmallIntegerField(
        default=99, validators=[MinValueValidator(1), MaxValueValidator(999)]
    )
    is_private = models.BooleanField(default=False)
    invite_token = models.CharField(max_length=64, unique=True, default=new_invite_token)
    # Head-to-head: after qualifying (this event's submissions), a single-elimination bracket.
    bracket_size = models.PositiveSmallIntegerField(
        default=0, help_text="0: no bracket; else the top 4, 8, 16 or 32 qualifiers race it."
    )
    bracket_laps = models.PositiveSmallIntegerField(
        default=2, validators=[MinValueValidator(1), MaxValueValidator(10)]
    )
    bracket_on_race_day = models.BooleanField(
        default=False, help_text="Matches wait in the race-day queue instead of running at once."
    )
    bracket = models.JSONField(default=dict, blank=True)
    """The seeding, once seeded: ``{"seeds": [submission ids by seed], "withdrawn": [submission
    ids]}``. Who went through is the BracketMatch rows' (``leaderboard.bracket``)."""
    # Race day: a facilitator's queue and the broadcast page.
    spectator_token = models.CharField(max_length=64, blank=True)
    """Non-empty: anyone with ``?watch=<token>`` sees the broadcast page without an account."""
    race_day_paused = models.BooleanField(default=False)
    live_speed_control = models.BooleanField(
        default=False,
        help_text="During their race-day turn, a racer sets their car's speed (0.5×-1.5×) "
        "from their phone.",
    )
    organiser = models.ForeignKey(
        settings.AUTH_USER_MODEL, on_delete=models.PROTECT, related_name="organised_events"
    )
    created_at = models.DateTimeField(default=timezone.now)

    class Meta:
        ordering = ["-opens_at", "-pk"]
        indexes = [models.Index(fields=["is_private", "division", "closes_at"])]
        constraints = [
            models.CheckConstraint(
                condition=models.Q(min_laps__lte=models.F("max_laps")), name="event_min_le_max"
            ),
            models.CheckConstraint(
                condition=models.Q(opens_at__lt=models.F("closes_at")), name="event_opens_first"
            ),
        ]

    def __str__(self) -> str:
        return self.name

    @property
    def track_name(self) -> str:
        """The track's display name (its id when the track is no longer in the catalogue)."""
        try:
            return track_catalog().info(self.track_id).name
        except (KeyError, ValueError, OSError):
            return self.track_id

    def is_open(self, now: datetime | None = None) -> bool:
        now = now or timezone.now()
        return self.opens_at <= now < self.closes_at

    def is_closed(self, now: datetime | None = None) -> bool:
        return (now or timezone.now()) >= self.closes_at

    @property
    def evaluation_laps(self) -> int:
        """Laps the evaluation runs: the event's maximum, but at least 3 (the evaluator's)."""
        return max(MIN_EVALUATION_LAPS, self.max_laps)


class EventEntrant(models.Model):
    """A racer admitted to a private event through its invite link. A removed entrant keeps
    the row (so the link cannot readmit them) and leaves the leaderboard."""

    event = models.ForeignKey(Event, on_delete=models.CASCADE, related_name="entrants")
    racer = models.ForeignKey(
        settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="league_entries"
    )
    joined_at = models.DateTimeField(default=timezone.now)
    removed_at = models.DateTimeField(null=True, blank=True)

    class Meta:
        constraints = [
            models.UniqueConstraint(fields=["event", "racer"], name="unique_entrant_per_event")
        ]

    def __str__(self) -> str:
        return f"{self.racer} in {self.event}"


class DivisionMembership(models.Model):
    """The racer's division in one calendar month (``month`` is its first day, UTC)."""

    racer = models.ForeignKey(
        settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="division_memberships"
    )
    month = models.DateField()
    division = models.CharField(max_length=4, choices=Division.choices)
    reason = models.CharField(max_length=120, blank=True)
    created_at = models.DateTimeField(default=timezone.now)

    class Meta:
        ordering = ["-month"]
        constraints = [
            models.UniqueConstraint(fields=["racer", "month"], name="unique_division_per_month")
        ]

    def __str__(self) -> str:
        return f"{self.racer} {self.division} {self.month:%Y-%m}"


class RacerProfile(models.Model):
    alias = models.CharField(
        max_length=32,
        unique=True,
        null=True,
        blank=True,
        validators=[RegexValidator(r"^[A-Za-z0-9_-]{3,32}$", "3-32 letters, digits, - or _")],
    )
    user = models.OneToOneField(
        settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="racer_profile"
    )
    country = models.CharField(max_length=2, blank=True, help_text="ISO 3166 code, e.g. DE")
    colour = models.CharField(
        max_length=7,
        default="#ff9f1c",
        validators=[RegexValidator(r"^#[0-9a-fA-F]{6}$", "a colour like #ff9f1c")],
    )

    def __str__(self) -> str:
        return self.alias or f"user {self.user_id}"


class Submission(models.Model):
    """A model entered into an event: one evaluation under the event's rules, then a score."""

    class Status(models.TextChoices):
        PENDING = "PENDING", "Evaluating"
        RANKED = "RANKED", "Ranked"
        UNRANKED = "UNRANKED", "Not ranked"
        FAILED = "FAILED", "Failed"

    event = models.ForeignKey(Event, on_delete=models.CASCADE, related_name="submissions")
    racer = models.ForeignKey(
        settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="submissions"
    )
    model = models.ForeignKey(
        RacingModel, null=True, on_delete=models.SET_NULL, related_name="submissions"
    )
    model_name = models.CharField(max_length=64)
    evaluation = models.OneToOneField(
        EvaluationJob, null=True, on_delete=models.SET_NULL, related_name="submission"
    )
    status = models.CharField(max_length=8, choices=Status.choices, default=Status.PENDING)
    reason = models.CharField(max_length=255, blank=True)
    created_at = models.DateTimeField(default=timezone.now)
    finished_at = models.DateTimeField(null=True, blank=True)
    # Results, in milliseconds (penalties included); null when there is no such lap.
    best_lap_ms = models.PositiveIntegerField(null=True, blank=True)
    average_lap_ms = models.PositiveIntegerField(null=True, blank=True)
    total_time_ms = models.PositiveIntegerField(null=True, blank=True)
    consecutive_laps = models.PositiveSmallIntegerField(default=0)
    off_tracks = models.PositiveIntegerField(default=0)
    collisions = models.PositiveIntegerField(default=0)
    resets = models.PositiveIntegerField(default=0)
    ranked = models.BooleanField(default=False)
    score_ms = models.PositiveIntegerField(null=True, blank=True)
    laps = models.JSONField(default=list, blank=True)
    entered_model_id = models.PositiveIntegerField(null=True, blank=True)
    """The model's id when entered (kept when the model is deleted)."""
    frozen_checkpoint = models.CharField(max_length=200, blank=True)
    """A copy of the model's weights when entered: what its races drive (store key)."""
    model_metadata = models.JSONField(default=dict, blank=True)

    class Meta:
        ordering = ["-created_at", "-pk"]
        indexes = [models.Index(fields=["event", "racer", "status"])]

    def __str__(self) -> str:
        return f"{self.model_name} in {self.event}"

    @property
    def has_video(self) -> bool:
        return bool(self.evaluation_id and self.evaluation and self.evaluation.has_video)


class BracketMatch(models.Model):
    """One race of an event's bracket: who races (``top``: the better seed), its race job,
    and who went through. ``note`` says why a match was decided without a finish."""

    event = models.ForeignKey(Event, on_delete=models.CASCADE, related_name="matches")
    round = models.PositiveSmallIntegerField()
    index = models.PositiveSmallIntegerField()
    top = models.ForeignKey(Submission, null=True, on_delete=models.SET_NULL, related_name="+")
    bottom = models.ForeignKey(Submission, null=True, on_delete=models.SET_NULL, related_name="+")
    # The result outlives the entry: a deleted submission's id stays here (no constraint), as
    # it stays in the event's seeding, so the draw replays as it was (leaderboard/bracket.py).
    winner = models.ForeignKey(
        Submission, null=True, blank=True, on_delete=models.DO_NOTHING, db_constraint=False,
        related_name="+",
    )  # fmt: skip
    race = models.ForeignKey(
        RaceJob, null=True, blank=True, on_delete=models.SET_NULL, related_name="bracket_matches"
    )
    attempts = models.PositiveSmallIntegerField(default=0)
    note = models.CharField(max_length=255, blank=True)
    created_at = models.DateTimeField(default=timezone.now)

    class Meta:
        ordering = ["event", "round", "index"]
        constraints = [
            models.UniqueConstraint(fields=["event", "round", "index"], name="unique_match_slot")
        ]

    def __str__(self) -> str:
        return f"{self.event} round {self.round} match {self.index + 1}"


class RaceDaySlot(models.Model):
    """One turn in a race day's queue: a racer's solo run (``submission``) or a bracket
    ``match``, in the facilitator's ``position`` order."""

    class Status(models.TextChoices):
        WAITING = "WAITING", "Waiting"
        RUNNING = "RUNNING", "On track"
        DONE = "DONE", "Done"
        SKIPPED = "SKIPPED", "Skipped"

    event = models.ForeignKey(Event, on_delete=models.CASCADE, related_name="race_day_slots")
    position = models.PositiveIntegerField()
    submission = models.ForeignKey(
        Submission, null=True, blank=True, on_delete=models.CASCADE, related_name="+"
    )
    match = models.ForeignKey(
        BracketMatch, null=True, blank=True, on_delete=models.CASCADE, related_name="+"
    )
    status = models.CharField(max_length=8, choices=Status.choices, default=Status.WAITING)
    race = models.ForeignKey(
        RaceJob, null=True, blank=True, on_delete=models.SET_NULL, related_name="race_day_slots"
    )
    notified = models.BooleanField(default=False)
    created_at = models.DateTimeField(default=timezone.now)

    class Meta:
        ordering = ["event", "position", "pk"]

    def __str__(self) -> str:
        return f"{self.event} slot {self.position}"


class Notification(models.Model):
    user = models.ForeignKey(
        settings.AUTH_USER_MODEL, on_delete=models.CASCADE, related_name="league_notifications"
    )
    message = models.CharField(max_length=255)
    link = models.CharField(max_length=200, blank=True)
    created_at = models.DateTimeField(default=timezone.now)
    read_at = models.DateTimeField(null=True, blank=True)

    class Meta:
        ordering = ["-created_at", "-pk"]

    def __str__(self) -> str:
        return self.message
