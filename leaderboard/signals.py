"""The league learns about finished evaluations: ``post_save`` on EvaluationJob (rows saved
with ``save()``) and training's ``evaluation_finished`` (jobs finished with ``update()``).
Both lead to the idempotent :func:`~leaderboard.services.submission_record_result`. Finished
races have one receiver, which asks :func:`~leaderboard.racefinish.league_race_finished`
whose race it was (a race-day turn or a bracket match)."""

from __future__ import annotations

import logging

from django.db.models.signals import post_delete, post_save
from django.dispatch import receiver

from leaderboard.bracket import bracket_entry_deleted
from leaderboard.models import Event, Submission
from leaderboard.racefinish import league_race_finished
from leaderboard.services import submission_record_result
from training.models import FINISHED_JOB_STATUSES, EvaluationJob, RaceJob
from training.signals import evaluation_finished, race_finished

log = logging.getLogger(__name__)


def _record(evaluation_id: int) -> None:
    try:
        submission_record_result(evaluation_id=evaluation_id)
    except Exception:  # noqa: BLE001 - never break the job's own bookkeeping; reconcile retries
        log.exception("could not record the result of evaluation %s", evaluation_id)


@receiver(post_save, sender=EvaluationJob, dispatch_uid="league-evaluation-saved")
def evaluation_saved(sender, instance: EvaluationJob, **kwargs) -> None:
    if instance.purpose == "submission" and instance.status in FINISHED_JOB_STATUSES:
        _record(instance.pk)


@receiver(evaluation_finished, sender=EvaluationJob, dispatch_uid="league-evaluation-finished")
def evaluation_done(sender, evaluation_id: int, **kwargs) -> None:
    _record(evaluation_id)


@receiver(race_finished, sender=RaceJob, dispatch_uid="league-race-finished")
def race_done(sender, race_id: int, **kwargs) -> None:
    """A race ended: the race day or the bracket moves on, as the race was theirs."""
    try:
        league_race_finished(race_id=race_id)
    except Exception:  # noqa: BLE001 - never break the job's bookkeeping
        log.exception("could not record the league race %s", race_id)


@receiver(post_delete, sender=Submission, dispatch_uid="bracket-entry-deleted")
def submission_deleted(sender, instance: Submission, origin=None, **kwargs) -> None:
    """An entry deleted mid-bracket is withdrawn
    (:func:`~leaderboard.bracket.bracket_entry_deleted`); not when its event is being deleted
    (the bracket goes with it)."""
    if isinstance(origin, Event) or getattr(origin, "model", None) is Event:
        return
    bracket_entry_deleted(event_id=instance.event_id, submission_id=instance.pk)
