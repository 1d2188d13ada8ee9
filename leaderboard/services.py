"""Submissions: enter a model into an event, and turn its finished evaluation into a result.

Keyword-only functions; refusals raise :class:`~leaderboard.access.LeagueError` with a message
a racer can act on. Live updates go out after the database commit.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable

from django.db import transaction
from django.utils import timezone

from leaderboard import ranking
from leaderboard.access import LeagueError
from leaderboard.events import event_entry_check, event_race
from leaderboard.live import broadcast_result
from leaderboard.models import Event, RacerProfile, Submission
from leaderboard.profiles import profile_for
from training.errors import StoreError
from training.models import EvaluationJob, JobStatus, RacingModel
from training.services import ServiceError, evaluation_start, model_freeze, model_metadata
from training.services.jobs import JobQuotaError

log = logging.getLogger(__name__)


def submission_create(*, event: Event, user, model: RacingModel) -> Submission:
    """Submit the racer's READY model to an open event: an evaluation under the event's rules
    (its track, direction, race with its boxes or bots, laps and penalties: an off track or a
    collision freezes the car for the penalty and respawns it, so lap times include them) on
    the evaluation queue.

    The evaluation is the racer's job: it counts against their job quota
    (``RACECRAFT_MAX_ACTIVE_JOBS_PER_USER``) and waits its turn in the fair order of
    evaluations (:mod:`training.services.job_queue`) like their own.

    Refused (LeagueError) when the event is not open or not for this racer, the racer has no
    alias yet, the model is not theirs or not ready, a submission of theirs to this event is
    still being evaluated, they have used the event's submissions, or they already have their
    quota of jobs queued or running (the submission is then not counted: they submit again).
    """
    event_entry_check(event=event, user=user)
    if model.owner_id != user.pk:
        raise LeagueError("you can only submit your own models", field="model")
    if model.status != RacingModel.Status.READY:
        raise LeagueError(
            f"{model.name} is {model.get_status_display().lower()}; submit it once it is ready",
            field="model",
        )
    if not model.has_checkpoint:
        raise LeagueError(f"train {model.name} before submitting it", field="model")
    with transaction.atomic():
        # One racer's submissions are serialised on their profile row.
        profile = RacerProfile.objects.select_for_update().get(pk=profile_for(user).pk)
        if not profile.alias:
            raise LeagueError("choose your racer alias on the League page before racing")
        mine = Submission.objects.filter(event=event, racer=user)
        if mine.filter(status=Submission.Status.PENDING).exists():
            raise LeagueError(
                "your previous submission to this event is still being evaluated; "
                "wait for its result"
            )
        used = mine.exclude(status=Submission.Status.FAILED).count()
        if used >= event.max_submissions_per_racer:
            raise LeagueError(
                f"you have used all {event.max_submissions_per_racer} submissions "
                "allowed for this event"
            )
        try:
            job = evaluation_start(
                model=model,
                user=user,
                track_id=event.track_id,
                direction=event.direction,
                race_type=event.race_type,
                race_config=event_race(event),
                laps=event.evaluation_laps,
                off_track_penalty_s=event.off_track_penalty_s,
                crash_penalty_s=event.collision_penalty_s,
                purpose="submission",
                # The event's outside world ({}: clean), the same draws for every entrant.
                conditions=event.conditions or None,
                conditions_seed=event.conditions_seed,
            )
        except JobQuotaError as exc:
            raise LeagueError(
                f"you already have {exc.most} jobs queued or running, the most allowed, and a "
                "submission's evaluation is one more; this submission was not used: submit "
                "again once one of them finishes (or stop one)",
                field="model",
            ) from None
        except ServiceError as exc:
            raise LeagueError(exc.message, field="model") from None
        submission = Submission.objects.create(
            event=event, racer=user, model=model, model_name=model.name, evaluation=job,
            entered_model_id=model.pk, model_metadata=model_metadata(model).to_json(),
        )  # fmt: skip
        try:  # the weights it races with from now on, whatever happens to the model
            submission.frozen_checkpoint = model_freeze(
                model=model, scope=f"event-{event.pk}", entry=submission.pk
            )
            submission.save(update_fields=["frozen_checkpoint"])
        except StoreError:  # its evaluation reads the same file and says what is wrong
            log.warning("could not keep the weights of submission %s", submission.pk,
                        exc_info=True)  # fmt: skip
        return submission


def laps_from_results(rows: Iterable[dict]) -> list[ranking.Lap]:
    """Ranking laps from an evaluation's lap table (``EvaluationJob.results["laps"]``).

    ``time_s`` already includes the penalties (the car sits frozen while the clock runs).
    """
    laps = []
    for row in rows:
        try:
            laps.append(
                ranking.Lap(
                    time_ms=round(float(row["time_s"]) * 1000),
                    completed=row.get("status") == "lap_complete",
                    off_tracks=int(row.get("off_tracks", 0)),
                    collisions=int(row.get("crashes", 0)),
                    resets=int(row.get("resets", 0)),
                )
            )
        except (KeyError, TypeError, ValueError):
            log.warning("skipping a malformed lap row %r", row)
    return laps


def _unranked_reason(event: Event, consecutive: int) -> str:
    laps = "lap" if event.min_laps == 1 else "consecutive laps"
    return (
        f"completed {consecutive} consecutive lap{'s' if consecutive != 1 else ''}; "
        f"this event ranks {event.min_laps} {laps}"
    )


def submission_record_result(*, evaluation_id: int) -> Submission | None:
    """Score the submission behind a finished evaluation (idempotent).

    COMPLETED → RANKED or UNRANKED with its stats and lap table; FAILED/CANCELED → FAILED.
    Returns the submission when this call recorded it, else None (no submission, evaluation
    not finished, or already recorded). The live update is sent after commit.
    """
    with transaction.atomic():
        submission = (
            Submission.objects.select_for_update()
            .select_related("event", "evaluation")
            .filter(evaluation_id=evaluation_id, status=Submission.Status.PENDING)
            .first()
        )
        if submission is None:
            return None
        job: EvaluationJob = submission.evaluation
        event = submission.event
        if job.status == JobStatus.COMPLETED:
            rows = job.lap_rows
            score = ranking.score_laps(
                laps_from_results(rows),
                ranking.Rules(event.ranking_method, event.min_laps, event.max_resets),
            )
            submission.laps = rows
            for name in ("best_lap_ms", "average_lap_ms", "total_time_ms", "consecutive_laps",
                         "off_tracks", "collisions", "resets", "ranked", "score_ms"):  # fmt: skip
                setattr(submission, name, getattr(score, name))
            submission.status = (
                Submission.Status.RANKED if score.ranked else Submission.Status.UNRANKED
            )
            submission.reason = (
                "" if score.ranked else _unranked_reason(event, score.consecutive_laps)
            )
        elif job.status in (JobStatus.FAILED, JobStatus.CANCELED):
            submission.status = Submission.Status.FAILED
            submission.reason = (job.error or "the evaluation was stopped")[:255]
            submission.laps = job.lap_rows
        else:
            return None
        submission.finished_at = job.finished_at or timezone.now()
        submission.save()
        pk = submission.pk

        transaction.on_commit(lambda: broadcast_result(pk))
    return submission


def submission_fail_orphan(*, submission: Submission) -> None:
    """A pending submission whose evaluation row is gone (its model was deleted)."""
    Submission.objects.filter(pk=submission.pk, status=Submission.Status.PENDING).update(
        status=Submission.Status.FAILED,
        reason="the model was deleted before its evaluation finished",
        finished_at=timezone.now(),
    )


def submissions_reconcile() -> int:
    """Record every pending submission whose evaluation has finished; a safety net for a
    missed signal. Returns how many were recorded."""
    recorded = 0
    pending = Submission.objects.filter(status=Submission.Status.PENDING)
    for submission in pending.filter(evaluation__isnull=True):
        submission_fail_orphan(submission=submission)
        recorded += 1
    finished = pending.filter(
        evaluation__status__in=(JobStatus.COMPLETED, JobStatus.FAILED, JobStatus.CANCELED)
    ).values_list("evaluation_id", flat=True)
    for evaluation_id in list(finished):
        if submission_record_result(evaluation_id=evaluation_id) is not None:
            recorded += 1
    return recorded
