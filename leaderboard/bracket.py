"""A head-to-head event's bracket: qualifying, then a single-elimination bracket of
one-against-one races.

Qualifying is the event's own submissions (the 2020 league's: 3 laps against 6 bots at
0.75 m/s, total time with penalties; the event's settings). :func:`bracket_seed` puts the top
4, 8, 16 or 32 qualifiers (each racer's best ranked submission, in leaderboard order) into a
bracket (the draw: :mod:`leaderboard.bracket_draw`, 1 against the last, byes to the top
seeds), and every ready match becomes a race job of the two frozen entries
(:func:`leaderboard.eventraces.entry_race`), or a turn in the race-day queue when the event
races its bracket live. When a race ends (:func:`bracket_race_finished`, called by the
league's one ``race_finished`` handler, :mod:`leaderboard.racefinish`) its winner goes through
and the next matches start, so a bracket runs to its champion unattended.

**One source of truth**: the event's ``bracket`` field keeps only the seeding (``seeds``:
submission ids by seed, and ``withdrawn``); who raced and who went through are the
:class:`~leaderboard.models.BracketMatch` rows, and the draw's state is derived from them
(:func:`leaderboard.selectors.bracket_state`, replaying the recorded winners on the seeding).

No bracket is ever left stuck: a match whose race failed is run again once, then the better
seed goes through; a race nobody finished is won by the car furthest on (the race's winner),
or, if no car moved, by the better seed; a withdrawn racer's opponent goes through without a
race. Each such decision is written on the match (``note``).

**An entry deleted mid-bracket** (its racer's account deleted, which deletes their submissions;
:func:`bracket_entry_deleted`, called on ``post_delete`` by :mod:`leaderboard.signals`) is
withdrawn as if its racer had withdrawn: a match not yet raced goes to the opponent ("the
opponent's entry was deleted"), a race already queued runs with the car out, one on track runs
to its end. Its past wins stand: a match's ``winner`` keeps the submission's id after the row is
gone (no database constraint, ``on_delete=DO_NOTHING``), as the seeding does, so the draw
replays exactly as before and a finished bracket keeps its champion; the page names the gone
entry by its seed. (With ``SET_NULL``, the winner was nulled: the draw went back a round, the
next round's decision no longer fitted it and the bracket stuck.) Deleting a *model* changes
nothing: its entry keeps the model's id and frozen checkpoint, and races from them.

A community race's races count against its organiser's job quota
(:func:`~leaderboard.eventraces.race_charged_to`): a match the quota holds back is not
decided, it waits (noted on the match) and starts when a bracket race ends or the minute's
reconcile finds room.

This module knows nothing of the race day's queue beyond putting a match into it: the race
day (:mod:`leaderboard.raceday`) imports this module, never the other way round (an
import-linter contract in pyproject.toml holds that line).
"""

from __future__ import annotations

import logging

from django.db import transaction

from leaderboard import bracket_draw as draws
from leaderboard.access import LeagueError, can_manage_event
from leaderboard.eventraces import LeagueQuotaError, entry_race, race_charged_to
from leaderboard.live import bracket_changed
from leaderboard.models import BracketMatch, Event, Notification, RaceDaySlot, Submission
from leaderboard.selectors import BracketState, bracket_state, leaderboard_rows
from training.models import JobStatus, RaceJob
from training.services import ServiceError

__all__ = [
    "BRACKET_SIZES",
    "QUOTA_WAIT_NOTE",
    "BracketState",
    "LeagueQuotaError",
    "bracket_entry_deleted",
    "bracket_race_finished",
    "bracket_seed",
    "bracket_state",
    "bracket_withdraw",
    "brackets_resume",
    "match_race",
    "race_charged_to",
]
log = logging.getLogger(__name__)
BRACKET_SIZES = (4, 8, 16, 32)
MAX_RACE_ATTEMPTS = 2
QUOTA_WAIT_NOTE = "waits for one of the organiser's jobs to finish (their job quota is full)"
WITHDREW_NOTE = "the opponent withdrew"
DELETED_NOTE = "the opponent's entry was deleted"


def _state(event: Event) -> tuple[draws.Bracket, list[int], set[int]]:
    state = bracket_state(event)
    assert state is not None, "the bracket is seeded"
    return state.draw, state.seeds, state.withdrawn


def _save(event: Event, seeds: list[int], withdrawn: set[int]) -> None:
    """The seeding (the only part of the bracket the event keeps; results are the rows)."""
    event.bracket = {"seeds": seeds, "withdrawn": sorted(withdrawn)}
    event.save(update_fields=["bracket"])


def bracket_seed(*, event: Event, user) -> draws.Bracket:
    """Seed the event's bracket from its qualifying leaderboard and start the first races.
    Refused unless the user runs the event, the event has a bracket and at least two ranked
    qualifiers, and it is not seeded yet."""
    if not can_manage_event(user, event):
        raise LeagueError("only the event's organiser or a race facilitator runs its bracket")
    if event.bracket_size not in BRACKET_SIZES:
        raise LeagueError("this event has no bracket (set its size to 4, 8, 16 or 32)")
    with transaction.atomic():
        event = Event.objects.select_for_update(no_key=True).get(pk=event.pk)
        if event.bracket:
            raise LeagueError("the bracket is already seeded")
        rows = leaderboard_rows(event)
        if len(rows) < 2:
            raise LeagueError("a bracket needs at least two ranked qualifiers")
        bracket = draws.seed_bracket(len(rows), cap=event.bracket_size)
        seeds = [row.submission_id for row in rows[: bracket.entries]]
        _save(event, seeds, set())
        _advance(event)
    return bracket


def bracket_withdraw(*, event: Event, user, submission: Submission) -> None:
    """Withdraw ``submission`` from the bracket (its racer, or whoever runs the event): a match
    not yet raced goes to the opponent; a race already queued runs with the car out."""
    if submission.racer_id != user.pk and not can_manage_event(user, event):
        raise LeagueError("only the racer or the event's organiser can withdraw an entry")
    with transaction.atomic():
        event = Event.objects.select_for_update(no_key=True).get(pk=event.pk)
        if not event.bracket:
            raise LeagueError("the bracket is not seeded yet")
        _, seeds, withdrawn = _state(event)
        if submission.pk not in seeds:
            raise LeagueError("this entry is not in the bracket")
        _withdraw(event, seeds, withdrawn, submission.pk, "its racer withdrew")


def _withdraw(event: Event, seeds: list[int], withdrawn: set[int], sub_id: int,
              why: str) -> None:  # fmt: skip
    """Take ``sub_id`` out (the event's row is locked): its queued race runs with its car
    out, its matches not yet raced go to the opponent."""
    withdrawn.add(sub_id)
    _save(event, seeds, withdrawn)
    for match in BracketMatch.objects.filter(event=event, winner__isnull=True,
                                             race__isnull=False):  # fmt: skip
        race = match.race
        if race.status == JobStatus.QUEUED and sub_id in _sides(event, match, seeds):
            entries = race.entries
            for entry in entries:
                if entry.get("tag") == sub_id:
                    entry["withdrawn"] = why
            RaceJob.objects.filter(pk=race.pk).update(entries=entries)
    _advance(event)


def bracket_entry_deleted(*, event_id: int, submission_id: int) -> None:
    """A submission was deleted (its racer's account, say): if it is in its event's bracket,
    it is withdrawn (see the module's docstring). ``leaderboard.signals`` calls this on
    ``post_delete``, except when the event itself is being deleted (its bracket goes with it)."""
    with transaction.atomic():
        event = Event.objects.select_for_update(no_key=True).filter(pk=event_id).first()
        if event is None or not event.bracket:
            return
        _, seeds, withdrawn = _state(event)
        if submission_id in seeds and submission_id not in withdrawn:
            _withdraw(event, seeds, withdrawn, submission_id, "its entry was deleted")


def _sides(event: Event, match: BracketMatch, seeds: list[int]) -> tuple[int, int]:
    """The match's two submission ids, from the seeding (they outlive the submission rows,
    whose ``top``/``bottom`` become NULL when deleted)."""
    game = bracket_state(event).draw.rounds[match.round - 1][match.index]
    if game.top is None or game.bottom is None:  # not reached (a match row is made ready)
        return (match.top_id or 0, match.bottom_id or 0)
    return seeds[game.top - 1], seeds[game.bottom - 1]


def _better_seed(event: Event, match: BracketMatch) -> int:
    """Who goes through when a match is decided without a winner on track: the top seed,
    unless they are out of the bracket (withdrawn, or their entry deleted) and the other
    is not."""
    _, seeds, withdrawn = _state(event)
    top, bottom = _sides(event, match, seeds)
    return bottom if top in withdrawn and bottom not in withdrawn else top


def bracket_race_finished(*, race_id: int) -> BracketMatch | None:
    """A bracket's race ended: its winner goes through and the next matches start (idempotent:
    a match already decided is left alone). Returns the match, if the race was one. A match
    raced on the race day is recorded after its turn ended (:mod:`leaderboard.racefinish`)."""
    match = BracketMatch.objects.filter(race_id=race_id).select_related("race").first()
    if match is None:
        return None
    with transaction.atomic():
        event = Event.objects.select_for_update(no_key=True).get(pk=match.event_id)
        match = BracketMatch.objects.select_related("race").get(pk=match.pk)
        race = match.race
        if match.winner_id is not None or race is None or race.pk != race_id:
            return match
        if race.status == JobStatus.COMPLETED:
            winner, note = _race_winner(match, race)
            _decide(event, match, winner if winner is not None else _better_seed(event, match),
                    note)  # fmt: skip
        elif race.status in (JobStatus.FAILED, JobStatus.CANCELED):
            if match.attempts < MAX_RACE_ATTEMPTS and event.bracket_on_race_day:
                match.race = None  # back in the race-day queue (_advance)
                match.save(update_fields=["race"])
            elif match.attempts < MAX_RACE_ATTEMPTS:
                _launch(event, match)
            else:
                _decide(event, match, _better_seed(event, match), f"the race could not be run "
                        f"({race.error}); the better qualifier goes through")  # fmt: skip
        _advance(event)
    return match


def _race_winner(match: BracketMatch, race: RaceJob) -> tuple[int | None, str]:
    """The race's winner's submission id (None: no car moved) and the note."""
    winner_model = race.results.get("winner") if isinstance(race.results, dict) else None
    for entry in race.entries:
        if winner_model is not None and entry.get("model") == winner_model:
            car = next((c for c in race.car_rows if c.get("model") == winner_model), {})
            note = "" if car.get("finished") else "won on distance at the time limit"
            return entry.get("tag"), note
    return None, "no car moved; the better qualifier goes through"


def _decide(event: Event, match: BracketMatch, winner: int | None, note: str) -> None:
    bracket, seeds, _ = _state(event)
    seed = seeds.index(winner) + 1 if winner in seeds else None
    if seed is None:
        return
    bracket = draws.record_winner(bracket, match.round, match.index, seed)  # checks the move
    match.winner_id, match.note = winner, note[:255]
    match.save(update_fields=["winner", "note"])  # the one record of the result
    transaction.on_commit(lambda: bracket_changed(event.pk))
    champion = draws.champion(bracket)
    if champion is not None:
        sub = Submission.objects.filter(pk=seeds[champion - 1]).first()
        if sub is not None:  # a gone entry has no racer left to tell
            Notification.objects.create(user=sub.racer,
                                        message=f"You won the {event.name} bracket!",
                                        link=f"/league/events/{event.pk}/bracket/")  # fmt: skip


def _advance(event: Event) -> None:
    """Start (or queue for the race day) every ready match that has no race yet; a match
    against a withdrawn racer is decided at once."""
    for _ in range(64):  # decisions can make more matches ready; a bracket has < 64 rounds
        bracket, seeds, withdrawn = _state(event)
        alive = set(Submission.objects.filter(pk__in=seeds).values_list("pk", flat=True))
        progressed = False
        for ready in draws.next_matches(bracket):
            top, bottom = seeds[ready.top - 1], seeds[ready.bottom - 1]
            match, _ = BracketMatch.objects.get_or_create(
                event=event, round=ready.round, index=ready.index,
                defaults={"top_id": top if top in alive else None,
                          "bottom_id": bottom if bottom in alive else None},
            )  # fmt: skip
            if (top in withdrawn or bottom in withdrawn) and match.race_id is None:
                through, out = (bottom, top) if top in withdrawn else (top, bottom)
                _decide(event, match, through, WITHDREW_NOTE if out in alive else DELETED_NOTE)
                progressed = True
                break
            if match.race_id is None:
                if event.bracket_on_race_day:
                    queued = RaceDaySlot.objects.filter(match=match, status__in=(
                        RaceDaySlot.Status.WAITING, RaceDaySlot.Status.RUNNING))  # fmt: skip
                    if not queued.exists():
                        _queue_on_race_day(event, match)
                else:
                    _launch(event, match)
        if not progressed:
            return


def _queue_on_race_day(event: Event, match: BracketMatch) -> None:
    last = RaceDaySlot.objects.filter(event=event).order_by("-position").first()
    RaceDaySlot.objects.create(event=event, match=match, position=(last.position + 1) if last
                               else 1)  # fmt: skip


def match_race(event: Event, match: BracketMatch, *, paced: bool = False,
               broadcast_group: str = "") -> RaceJob:  # fmt: skip
    """A race job of the match's two frozen entries (top seed on pole in odd rounds, the other
    in even ones: the grid swaps between rounds)."""
    subs = [match.top, match.bottom]
    return entry_race(event, subs, laps=event.bracket_laps, round_number=match.round - 1,
                      title=f"{event.name}: round {match.round}, match {match.index + 1}",
                      paced=paced, broadcast_group=broadcast_group)  # fmt: skip


def _launch(event: Event, match: BracketMatch) -> None:
    try:
        race = match_race(event, match)
    except LeagueQuotaError:
        # Not a reason to decide the match: it waits (race None) and starts when a race of
        # the bracket ends or the minute's reconcile finds the organiser a free job.
        if match.note != QUOTA_WAIT_NOTE:
            match.note = QUOTA_WAIT_NOTE
            match.save(update_fields=["note"])
            transaction.on_commit(lambda: bracket_changed(event.pk))
        return
    except (LeagueError, ServiceError) as exc:
        message = getattr(exc, "message", str(exc))
        _decide(event, match, _better_seed(event, match), f"the race could not start "
                f"({message}); the better qualifier goes through")  # fmt: skip
        return
    match.race, match.attempts, match.note = race, match.attempts + 1, ""
    match.save(update_fields=["race", "attempts", "note"])
    transaction.on_commit(lambda: bracket_changed(event.pk))


def brackets_resume() -> int:
    """Start the bracket matches that waited for their organiser's job quota (a safety net
    beside the start that follows each bracket race's end). Returns how many started."""
    waiting = BracketMatch.objects.filter(
        winner__isnull=True, race__isnull=True, event__bracket_on_race_day=False,
        note=QUOTA_WAIT_NOTE,
    )  # fmt: skip
    started = 0
    for event_id in set(waiting.values_list("event_id", flat=True)):
        with transaction.atomic():
            event = Event.objects.select_for_update(no_key=True).get(pk=event_id)
            before = BracketMatch.objects.filter(event=event, race__isnull=False).count()
            _advance(event)
            started += BracketMatch.objects.filter(event=event, race__isnull=False).count() - before
    return started
