"""Reads for the league pages and the live updates: leaderboards, events, submissions."""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass

from django.db.models import Prefetch, Q, QuerySet
from django.urls import reverse
from django.utils import timezone

from leaderboard import bracket_draw, ranking
from leaderboard.access import can_manage_event, can_view_event, is_facilitator
from leaderboard.divisions import division_for
from leaderboard.models import (
    BracketMatch,
    Event,
    EventEntrant,
    Notification,
    RaceDaySlot,
    RacerProfile,
    Season,
    Submission,
)
from training.formatting import format_lap_ms
from training.models import RacingModel


@dataclass(frozen=True)
class LeaderboardRow:
    """One line of a leaderboard, ready for a template or a websocket message."""

    rank: int
    submission_id: int
    racer_id: int
    alias: str
    country: str
    colour: str
    time: str
    score_ms: int
    gap: str
    off_tracks: int
    collisions: int
    model_name: str
    video_url: str
    detail_url: str

    def as_dict(self) -> dict:
        return asdict(self)


def _removed_racers(event: Event) -> set[int]:
    if not event.is_private:
        return set()
    return set(
        EventEntrant.objects.filter(event=event, removed_at__isnull=False).values_list(
            "racer_id", flat=True
        )
    )


def leaderboard_rows(event: Event) -> list[LeaderboardRow]:
    """The event's leaderboard: each racer's best ranked submission, in rank order."""
    removed = _removed_racers(event)
    ranked = {
        s.pk: s
        for s in Submission.objects.filter(event=event, status=Submission.Status.RANKED)
        .exclude(racer_id__in=removed)
        .select_related("evaluation")
    }
    entries = [
        ranking.Entry(s.pk, s.racer_id, s.score_ms, s.created_at)
        for s in ranked.values()
        if s.score_ms is not None
    ]
    board = ranking.leaderboard(entries)
    profiles = {
        p.user_id: p
        for p in RacerProfile.objects.filter(user_id__in=[r.entry.racer_id for r in board])
    }
    rows = []
    for row in board:
        sub = ranked[row.entry.submission_id]
        profile = profiles.get(sub.racer_id)
        rows.append(
            LeaderboardRow(
                rank=row.rank,
                submission_id=sub.pk,
                racer_id=sub.racer_id,
                alias=(profile.alias if profile and profile.alias else f"racer-{sub.racer_id}"),
                country=profile.country if profile else "",
                colour=profile.colour if profile else "#ff9f1c",
                time=format_lap_ms(row.entry.score_ms),
                score_ms=row.entry.score_ms,
                gap=ranking.format_gap(row.gap_ms),
                off_tracks=sub.off_tracks,
                collisions=sub.collisions,
                model_name=sub.model_name,
                video_url=(
                    reverse("league-submission-video", args=[sub.pk]) if sub.has_video else ""
                ),
                detail_url=reverse("league-submission", args=[sub.pk]),
            )
        )
    return rows


def seasons_with_events(user) -> list[Season]:
    public = Event.objects.filter(is_private=False).order_by("opens_at")
    return list(Season.objects.prefetch_related(Prefetch("events", queryset=public)))


def open_events_for(user) -> QuerySet[Event]:
    """Public events open now; for a signed-in racer, those of their division this month."""
    now = timezone.now()
    events = Event.objects.filter(is_private=False, opens_at__lte=now, closes_at__gt=now)
    if user.is_authenticated and not is_facilitator(user):
        events = events.filter(division=division_for(user, now))
    return events.order_by("closes_at")


def upcoming_and_recent_events() -> tuple[QuerySet[Event], QuerySet[Event]]:
    now = timezone.now()
    public = Event.objects.filter(is_private=False)
    upcoming = public.filter(opens_at__gt=now).order_by("opens_at")[:10]
    recent = public.filter(closes_at__lte=now).order_by("-closes_at")[:10]
    return upcoming, recent


def community_races_for(user) -> QuerySet[Event]:
    if not user.is_authenticated:
        return Event.objects.none()
    return (
        Event.objects.filter(is_private=True)
        .filter(Q(organiser=user) | Q(entrants__racer=user, entrants__removed_at__isnull=True))
        .distinct()
        .order_by("-closes_at")
    )


def submissions_of(event: Event, user) -> QuerySet[Submission]:
    if not user.is_authenticated:
        return Submission.objects.none()
    return Submission.objects.filter(event=event, racer=user).select_related("evaluation")


def all_submissions(event: Event) -> QuerySet[Submission]:
    return Submission.objects.filter(event=event).select_related("evaluation", "racer")


def entrants_of(event: Event) -> QuerySet[EventEntrant]:
    return EventEntrant.objects.filter(event=event).select_related("racer").order_by("joined_at")


def ready_models_of(user) -> QuerySet[RacingModel]:
    if not user.is_authenticated:
        return RacingModel.objects.none()
    return RacingModel.objects.filter(
        owner=user, status=RacingModel.Status.READY, has_checkpoint=True
    ).order_by("name")


def notifications_for(user, limit: int = 20) -> list[Notification]:
    if not user.is_authenticated:
        return []
    return list(Notification.objects.filter(user=user)[:limit])


def can_watch_submission(user, submission: Submission) -> bool:
    """Anyone who can see the event may watch a ranked run; the racer and the event's
    managers may watch every run."""
    event = submission.event
    if user.is_authenticated and submission.racer_id == user.pk:
        return True
    if can_manage_event(user, event):
        return True
    return submission.status == Submission.Status.RANKED and can_view_event(user, event)


@dataclass
class MatchView:
    """One match of the bracket page: its two entries (alias and model), its state."""

    round: int
    index: int
    top: str
    bottom: str
    top_seed: int | None
    bottom_seed: int | None
    winner: str
    state: str
    note: str
    race_id: int | None
    has_video: bool


@dataclass(frozen=True)
class BracketState:
    """A seeded bracket: the draw with every recorded winner, the entries by seed
    (submission ids; seed ``k`` is ``seeds[k - 1]``) and the withdrawn entries."""

    draw: bracket_draw.Bracket
    seeds: list[int]
    withdrawn: set[int]


def bracket_state(event: Event) -> BracketState | None:
    """The event's bracket (None before it is seeded): the event keeps only its seeding, the
    match rows who went through (one source of truth, :mod:`leaderboard.bracket`); the draw
    is the seeding's with each decided match's winner replayed, round by round."""
    data = event.bracket
    if not data or not data.get("seeds"):
        return None
    seeds = [int(s) for s in data["seeds"]]
    draw = bracket_draw.seed_bracket(len(seeds))
    seed_of = {sub: k for k, sub in enumerate(seeds, start=1)}
    decided = BracketMatch.objects.filter(event=event, winner__isnull=False).order_by(
        "round", "index"
    )
    for match in decided.values("round", "index", "winner_id"):
        try:
            draw = bracket_draw.record_winner(
                draw, match["round"], match["index"], seed_of.get(match["winner_id"], 0)
            )
        except ValueError:  # a winner whose entry was deleted since: the match stays open
            logging.getLogger(__name__).warning(
                "event %s: round %s match %s does not fit its bracket",
                event.pk, match["round"], match["index"],
            )  # fmt: skip
    return BracketState(draw, seeds, {int(s) for s in data.get("withdrawn", [])})


def bracket_rounds(event: Event) -> list[list[MatchView]]:
    """The bracket, round by round, as the page shows it (empty before it is seeded)."""
    bracket = bracket_state(event)
    if bracket is None:
        return []
    state, seeds = bracket.draw, bracket.seeds
    subs = {s.pk: s for s in Submission.objects.filter(pk__in=seeds).select_related("racer")}
    aliases = {p.user_id: p.alias for p in RacerProfile.objects.filter(
        user_id__in=[s.racer_id for s in subs.values()])}  # fmt: skip
    matches = {(m.round, m.index): m for m in BracketMatch.objects.filter(event=event)
               .select_related("race")}  # fmt: skip

    def label(seed: int | None) -> str:
        if seed is None:
            return ""
        sub = subs.get(seeds[seed - 1])
        if sub is None:
            return f"Seed {seed}"
        return f"{aliases.get(sub.racer_id) or f'racer-{sub.racer_id}'} · {sub.model_name}"

    withdrawn = bracket.withdrawn
    rounds = []
    for games in state.rounds:
        row = []
        for game in games:
            record = matches.get((game.round, game.index))
            race = record.race if record else None
            if game.bye:
                status = "bye"
            elif game.winner is not None:
                status = "decided"
            elif race is not None and race.status in ("INITIALIZING", "IN_PROGRESS"):
                status = "racing"
            elif race is not None:
                status = "queued"
            else:
                status = "waiting"
            top_out = game.top is not None and seeds[game.top - 1] in withdrawn
            bottom_out = game.bottom is not None and seeds[game.bottom - 1] in withdrawn
            row.append(MatchView(
                round=game.round, index=game.index,
                top=label(game.top) + (" (withdrawn)" if top_out else ""),
                bottom=label(game.bottom) + (" (withdrawn)" if bottom_out else ""),
                top_seed=game.top, bottom_seed=game.bottom, winner=label(game.winner),
                state=status, note=record.note if record else "",
                race_id=race.pk if race else None, has_video=bool(race and race.has_video),
            ))  # fmt: skip
        rounds.append(row)
    return rounds


def race_day_queue(event: Event) -> list[RaceDaySlot]:
    """The race day's turns in order, with what the page shows of each."""
    return list(RaceDaySlot.objects.filter(event=event).select_related(
        "submission", "match__top", "match__bottom", "race"))  # fmt: skip
