"""Shared characters and shortcuts of the league tests.

Alice and Bob are racers; Charlie must never see what he was not invited to; Fran is a race
facilitator. Models are created READY with a checkpoint flag set (no training here), and an
evaluation is "finished" by writing its results, as the evaluator would (the evaluation itself
is covered by tests/training).
"""

from __future__ import annotations

from collections.abc import Sequence
from datetime import timedelta

from django.contrib.auth import get_user_model
from django.contrib.auth.models import Group
from django.utils import timezone

from leaderboard.models import FACILITATORS_GROUP, Event, RacerProfile
from training.models import EvaluationJob, JobStatus, RacingModel

TRACK = "racecraft_oval"
ACTIONS = [{"steering_angle": 0, "speed": 1.0}, {"steering_angle": 30, "speed": 1.0}]


def make_user(name: str, *, alias: str | None = None, facilitator: bool = False, **extra):
    user = get_user_model().objects.create_user(name, password=f"pw-{name}-123", **extra)
    if alias:
        RacerProfile.objects.create(user=user, alias=alias)
    if facilitator:
        user.groups.add(Group.objects.get_or_create(name=FACILITATORS_GROUP)[0])
    return user


def with_alias(user, alias: str):
    """``user`` with a racer profile under ``alias``."""
    RacerProfile.objects.create(user=user, alias=alias)
    return user


def make_model(owner, name: str = "fast-one", **extra) -> RacingModel:
    fields = {
        "track_id": TRACK,
        "sensors": ["FRONT_FACING_CAMERA"],
        "neural_network": "RACECRAFT_LEAN_CNN",
        "action_space_type": "discrete",
        "action_space": ACTIONS,
        "algorithm": "clipped_ppo",
        "reward_function": "def reward_function(params):\n    return 1.0\n",
        "status": RacingModel.Status.READY,
        "has_checkpoint": True,
        **extra,
    }
    return RacingModel.objects.create(owner=owner, name=name, **fields)


def make_event(organiser, **overrides) -> Event:
    now = timezone.now()
    fields = {
        "name": "Oval sprint",
        "track_id": TRACK,
        "opens_at": now - timedelta(hours=1),
        "closes_at": now + timedelta(days=7),
        "ranking_method": "BEST_LAP",
        "min_laps": 1,
        "max_laps": 3,
        **overrides,
    }
    return Event.objects.create(organiser=organiser, **fields)


def lap(time_s: float, status: str = "lap_complete", *, off_tracks: int = 0, crashes: int = 0,
        resets: int = 0, trial: int = 1) -> dict:  # fmt: skip
    """One row of an evaluation's lap table, as training.rl.evaluation writes it."""
    return {
        "trial": trial, "time_s": time_s, "progress": 100.0 if status == "lap_complete" else 42.0,
        "status": status, "off_tracks": off_tracks, "off_track_penalty_s": off_tracks * 1.0,
        "crashes": crashes, "crash_penalty_s": crashes * 1.0, "resets": resets,
        "reversals": 0, "immobilizations": 0,
    }  # fmt: skip


def finish_evaluation(
    job: EvaluationJob,
    laps: Sequence[dict] | None = None,
    *,
    status: str = JobStatus.COMPLETED,
    error: str = "",
) -> EvaluationJob:
    """Finish an evaluation as the worker would, with ``save()`` (so post_save fires)."""
    rows = [dict(row, trial=i) for i, row in enumerate(laps or [], 1)]
    job.refresh_from_db()
    job.status = status
    job.error = error
    job.finished_at = timezone.now()
    job.results = {"laps": rows, "completed_laps": sum(r["status"] == "lap_complete" for r in rows)}
    job.laps_done = job.results["completed_laps"]
    job.save()
    RacingModel.objects.filter(pk=job.model_id).update(status=RacingModel.Status.READY)
    return job
