"""Submitting a model and turning its finished evaluation into a result: the limits (each with
a clear message), the evaluation under the event's rules, and the signals that record a
ranked, unranked or failed submission (EvaluationJob rows finished by hand; no Celery)."""

from __future__ import annotations

from datetime import timedelta

import pytest
from django.utils import timezone
from league_helpers import finish_evaluation, lap, make_event, make_model, make_user

from leaderboard.access import LeagueError
from leaderboard.models import Submission
from leaderboard.selectors import leaderboard_rows
from leaderboard.services import submission_create, submissions_reconcile
from training.models import EvaluationJob, JobStatus, RacingModel
from training.services import job_fail, job_stop

pytestmark = pytest.mark.django_db


def test_a_submission_is_an_evaluation_under_the_events_rules(fran, alice):
    event = make_event(fran, track_id="racecraft_summit", max_laps=5, min_laps=2,
                       off_track_penalty_s=3.0, collision_penalty_s=4.0)  # fmt: skip
    submission = submission_create(event=event, user=alice, model=make_model(alice))
    job = submission.evaluation
    assert submission.status == Submission.Status.PENDING
    assert (job.track_id, job.laps, job.off_track_penalty_s, job.crash_penalty_s, job.purpose) == (
        "racecraft_summit", 5, 3.0, 4.0, "submission",
    )  # fmt: skip
    assert job.status == JobStatus.QUEUED


def test_the_evaluation_runs_at_least_three_laps(event, alice):
    event.max_laps = 1
    event.save()
    job = submission_create(event=event, user=alice, model=make_model(alice)).evaluation
    assert job.laps == 3


def test_maximum_submissions(fran, alice):
    event = make_event(fran, max_submissions_per_racer=2)
    for i in range(2):
        sub = submission_create(event=event, user=alice, model=make_model(alice, f"m{i}"))
        finish_evaluation(sub.evaluation, [lap(10.0)])
    with pytest.raises(LeagueError, match="used all 2 submissions"):
        submission_create(event=event, user=alice, model=make_model(alice, "m9"))


def test_a_failed_evaluation_does_not_use_up_a_submission(fran, alice):
    event = make_event(fran, max_submissions_per_racer=1)
    model = make_model(alice)
    sub = submission_create(event=event, user=alice, model=model)
    finish_evaluation(sub.evaluation, status=JobStatus.FAILED, error="worker lost")
    sub.refresh_from_db()
    assert sub.status == Submission.Status.FAILED and sub.reason == "worker lost"
    submission_create(event=event, user=alice, model=model)


def test_one_running_submission_per_racer_and_event(event, alice, bob):
    submission_create(event=event, user=alice, model=make_model(alice, "one"))
    with pytest.raises(LeagueError, match="still being evaluated"):
        submission_create(event=event, user=alice, model=make_model(alice, "two"))
    submission_create(event=event, user=bob, model=make_model(bob, "one"))  # others may


@pytest.mark.parametrize(
    ("opens", "closes", "message"),
    [(timedelta(hours=-3), timedelta(hours=-1), "has closed"),
     (timedelta(hours=1), timedelta(hours=3), "opens on")],
)  # fmt: skip
def test_closed_and_not_yet_open_events_refuse(fran, alice, opens, closes, message):
    now = timezone.now()
    event = make_event(fran, opens_at=now + opens, closes_at=now + closes)
    with pytest.raises(LeagueError, match=message):
        submission_create(event=event, user=alice, model=make_model(alice))


def test_not_your_own_model(event, alice, bob):
    with pytest.raises(LeagueError, match="your own models"):
        submission_create(event=event, user=bob, model=make_model(alice))


@pytest.mark.parametrize(
    ("status", "checkpoint", "message"),
    [(RacingModel.Status.TRAINING, False, "is training; submit it once it is ready"),
     (RacingModel.Status.EVALUATING, True, "is evaluating"),
     (RacingModel.Status.READY, False, "train fast-one before")],
)  # fmt: skip
def test_model_not_ready(event, alice, status, checkpoint, message):
    model = make_model(alice, status=status, has_checkpoint=checkpoint)
    with pytest.raises(LeagueError, match=message):
        submission_create(event=event, user=alice, model=model)


def test_an_alias_is_needed_before_racing(event):
    newbie = make_user("newbie")
    with pytest.raises(LeagueError, match="alias"):
        submission_create(event=event, user=newbie, model=make_model(newbie))


def test_head_to_bot_submissions_carry_the_bots(fran, alice):
    event = make_event(fran, race_type="HEAD_TO_BOT", bot_count=3, bot_speed_mps=0.75,
                       collision_penalty_s=5.0)  # fmt: skip
    job = submission_create(event=event, user=alice, model=make_model(alice)).evaluation
    assert job.race_type == "HEAD_TO_BOT" and job.crash_penalty_s == 5.0
    assert (job.race_config["number_of_bots"], job.race_config["bot_speed"]) == (3, 0.75)


# ------------------------------------------------------------------ results
def test_a_finished_evaluation_becomes_a_ranked_result(fran, alice):
    event = make_event(fran, ranking_method="AVERAGE_LAP", min_laps=2)
    sub = submission_create(event=event, user=alice, model=make_model(alice))
    finish_evaluation(sub.evaluation, [lap(12.5, off_tracks=1), lap(10.25), lap(11.0, crashes=2)])
    sub.refresh_from_db()
    assert sub.status == Submission.Status.RANKED and sub.ranked
    assert sub.score_ms == 10625  # best window: (10.25 + 11.0) / 2
    assert (sub.best_lap_ms, sub.total_time_ms, sub.consecutive_laps) == (10250, 22750, 3)
    assert (sub.off_tracks, sub.collisions) == (1, 2)
    assert len(sub.laps) == 3 and sub.finished_at is not None
    (row,) = leaderboard_rows(event)
    assert (row.alias, row.time, row.gap) == ("Alice-R", "00:10.625", "—")


def test_too_few_consecutive_laps_is_unranked(fran, alice):
    event = make_event(fran, min_laps=3)
    sub = submission_create(event=event, user=alice, model=make_model(alice))
    finish_evaluation(sub.evaluation, [lap(10.0), lap(10.0), lap(4.0, "off_track")])
    sub.refresh_from_db()
    assert sub.status == Submission.Status.UNRANKED and sub.score_ms is None
    assert sub.reason == "completed 2 consecutive laps; this event ranks 3 consecutive laps"
    assert leaderboard_rows(event) == []


def test_the_leaderboard_keeps_each_racers_best(event, alice, bob):
    model = make_model(alice)
    for time_s in (11.0, 9.5, 10.0):
        sub = submission_create(event=event, user=alice, model=model)
        finish_evaluation(sub.evaluation, [lap(time_s)])
    sub = submission_create(event=event, user=bob, model=make_model(bob))
    finish_evaluation(sub.evaluation, [lap(9.75)])
    rows = leaderboard_rows(event)
    assert [(r.rank, r.alias, r.time, r.gap) for r in rows] == [
        (1, "Alice-R", "00:09.500", "—"), (2, "BobRacer", "00:09.750", "+0.250"),
    ]  # fmt: skip


def test_training_signal_records_jobs_finished_with_update(event, alice):
    """The evaluator finishes jobs with QuerySet.update (no post_save): training's
    evaluation_finished signal, sent by job_fail and job_stop, reaches the league."""
    sub = submission_create(event=event, user=alice, model=make_model(alice))
    job_fail(job=sub.evaluation, error="the worker running this job stopped unexpectedly")
    sub.refresh_from_db()
    assert sub.status == Submission.Status.FAILED and "stopped unexpectedly" in sub.reason

    model = make_model(alice, "second")
    sub = submission_create(event=event, user=alice, model=model)
    job_stop(job=sub.evaluation, user=alice)  # a queued job is canceled at once
    sub.refresh_from_db()
    assert sub.status == Submission.Status.FAILED


def test_reconcile_catches_up_missed_results(event, alice):
    sub = submission_create(event=event, user=alice, model=make_model(alice))
    EvaluationJob.objects.filter(pk=sub.evaluation_id).update(
        status=JobStatus.COMPLETED,
        finished_at=timezone.now(),
        results={"laps": [lap(12.0)], "completed_laps": 1},
    )  # fmt: skip  (no signal at all)
    assert Submission.objects.get(pk=sub.pk).status == Submission.Status.PENDING
    assert submissions_reconcile() == 1
    assert Submission.objects.get(pk=sub.pk).status == Submission.Status.RANKED
    assert submissions_reconcile() == 0


def test_a_submission_whose_model_is_deleted_fails(event, alice):
    model = make_model(alice)
    sub = submission_create(event=event, user=alice, model=model)
    model.delete()  # cascades to the evaluation
    assert submissions_reconcile() == 1
    sub.refresh_from_db()
    assert sub.status == Submission.Status.FAILED and sub.model_name == "fast-one"
