"""The league's one answer to training's ``race_finished``: whose race was it?

:func:`league_race_finished` decides once, from the rows that launched the race:

- a race-day turn's race (a solo run, or a bracket match raced live): the race day ends the
  turn (:func:`leaderboard.raceday.race_day_race_finished`) and the queue moves on; when the
  turn was a bracket match, the bracket then records its result
  (:func:`leaderboard.bracket.bracket_race_finished`), after the turn, so that a match whose
  race failed can join the queue again;
- a bracket race run off the race day: only the bracket moves;
- any other race (a racer's own, the command line's): nothing here.

:func:`races_reconcile` is the safety net for a missed signal (the minute's beat task).
"""

from __future__ import annotations

import logging

from leaderboard.bracket import bracket_race_finished, brackets_resume
from leaderboard.models import BracketMatch, RaceDaySlot
from leaderboard.raceday import race_day_race_finished
from training.models import JobStatus

log = logging.getLogger(__name__)
RACE_DAY, BRACKET = "race_day", "bracket"


def league_race_finished(*, race_id: int) -> str | None:
    """Move what race ``race_id`` belongs to: :data:`RACE_DAY` (a turn, and its match if it
    was one), :data:`BRACKET` (a match raced off the race day) or None (not a league race).
    Idempotent; an error in the bracket's bookkeeping is logged, never raised (the race's
    own bookkeeping must not break, and :func:`races_reconcile` retries)."""
    slot = RaceDaySlot.objects.filter(race_id=race_id).only("pk", "match_id").first()
    if slot is not None:
        try:
            race_day_race_finished(race_id=race_id)
        except Exception:  # noqa: BLE001 - never break the job's bookkeeping
            log.exception("could not record the race-day race %s", race_id)
        if slot.match_id is not None:
            _bracket(race_id)
        return RACE_DAY
    if BracketMatch.objects.filter(race_id=race_id).exists():
        _bracket(race_id)
        return BRACKET
    return None


def _bracket(race_id: int) -> None:
    try:
        bracket_race_finished(race_id=race_id)
    except Exception:  # noqa: BLE001 - never break the job's bookkeeping
        log.exception("could not record the bracket race %s", race_id)


def races_reconcile() -> int:
    """A safety net for a missed ``race_finished`` (a worker cut off between the race's end
    and the league's bookkeeping): every race-day turn and bracket match whose race has ended
    is recorded now, and the matches that waited for their organiser's job quota start if
    it has room. Idempotent; returns how many were recorded or started."""
    ended = (JobStatus.COMPLETED, JobStatus.FAILED, JobStatus.CANCELED)
    races = set(RaceDaySlot.objects.filter(status=RaceDaySlot.Status.RUNNING,
                                           race__status__in=ended)
                .values_list("race_id", flat=True))  # fmt: skip
    races |= set(BracketMatch.objects.filter(winner__isnull=True, race__status__in=ended)
                 .values_list("race_id", flat=True))  # fmt: skip
    recorded = sum(league_race_finished(race_id=race_id) is not None for race_id in sorted(races))
    return recorded + brackets_resume()
