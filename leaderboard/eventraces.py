"""An event's race jobs: the one way the league turns its entries into a race
(:func:`entry_race`), for the race day's turns (:mod:`leaderboard.raceday`) and the bracket's
matches (:mod:`leaderboard.bracket`) alike, and whose job quota they count against.

A community race's races count against its organiser's job quota (:func:`race_charged_to`;
``RACECRAFT_MAX_ACTIVE_JOBS_PER_USER``); a public event's, against nobody's.
"""

from __future__ import annotations

from leaderboard.access import LeagueError
from leaderboard.models import Event, Submission
from training.models import RaceJob, RaceType
from training.services import ServiceError
from training.services.conditions import conditions_draw
from training.services.jobs import JobQuotaError
from training.services.races import race_start_entries


class LeagueQuotaError(LeagueError):
    """A race refused because the user it is charged to (a community event's organiser) has
    no job to spare: nothing was queued and nothing is lost; it can run once one finishes."""


def race_charged_to(event: Event):
    """Who an event's races count against: a community race's organiser (they decide when its
    turns and matches run; the entrants do not, so an organiser can never spend an entrant's
    quota); None for a public event, which the operator's facilitators run for the league."""
    return event.organiser if event.is_private else None


def entry_race(
    event: Event,
    submissions: list[Submission],
    *,
    laps: int,
    round_number: int = 0,
    title: str = "",
    paced: bool = False,
    broadcast_group: str = "",
) -> RaceJob:
    """A race job of ``submissions`` (one alone: a solo run) on the event's track, with its
    bots and penalties and its outside world (one draw from the event's conditions seed, the
    same for every race of the event; none: the clean world), each car its frozen entry (so
    deleting or retraining a model changes nothing here), charged to :func:`race_charged_to`.
    Raises :class:`LeagueError`, and :class:`LeagueQuotaError` when the organiser has no job
    to spare (nothing is queued)."""
    entries = []
    for sub in submissions:
        model_id = sub.entered_model_id or sub.model_id
        if model_id is None:
            raise LeagueError(f"{sub.model_name}: no model was recorded for this entry")
        entries.append(
            {
                "model": model_id,
                "name": sub.model_name,
                "tag": sub.pk,
                "checkpoint": sub.frozen_checkpoint,
                "metadata": sub.model_metadata,
            }
        )
    try:
        return race_start_entries(
            entries=entries, track_id=event.track_id, direction=event.direction, laps=laps,
            bots=event.bot_count if event.race_type == RaceType.HEAD_TO_BOT else 0,
            bot_speed=event.bot_speed_mps, round_number=round_number, title=title,
            off_track_penalty_s=event.off_track_penalty_s,
            crash_penalty_s=event.collision_penalty_s, paced=paced,
            broadcast_group=broadcast_group, charged_to=race_charged_to(event),
            world=conditions_draw(event.conditions, event.conditions_seed),  # {}: clean
        )  # fmt: skip
    except JobQuotaError as exc:
        raise LeagueQuotaError(
            f"this community race's races count against its organiser's jobs, and the "
            f"organiser already has {exc.most} queued or running, the most allowed; nothing "
            "was started: try again once one of them finishes"
        ) from None
    except ServiceError as exc:
        raise LeagueError(exc.message) from None
