"""Live leaderboard updates: one Channels group per event, fed when a result lands."""

from __future__ import annotations

from leaderboard.models import Submission
from leaderboard.selectors import leaderboard_rows
from training import live
from training.formatting import format_lap_ms

MESSAGE_TYPE = "league.result"


def event_group(event_id: int) -> str:
    """The Channels group of an event's leaderboard: ``league-event-<id>``."""
    return f"league-event-{event_id}"


def result_message(submission: Submission) -> dict:
    """The whole leaderboard plus the submission that just finished (to highlight it)."""
    return {
        "type": MESSAGE_TYPE,
        "event_id": submission.event_id,
        "submission": {
            "id": submission.pk,
            "racer_id": submission.racer_id,
            "status": submission.status,
            "status_label": submission.get_status_display(),
            "time": format_lap_ms(submission.score_ms),
            "reason": submission.reason,
        },
        "rows": [row.as_dict() for row in leaderboard_rows(submission.event)],
    }


def visible_result(message: dict, user_id: int | None) -> dict:
    """What one viewer receives of a result message: the leaderboard (which everyone sees) and
    the submission as the league pages show it to them. Their own submission comes whole;
    someone else's only once ranked, and never with its reason: another racer's failed or
    unranked results are not theirs to read."""
    submission = message["submission"]
    if submission["racer_id"] != user_id:
        if submission["status"] != Submission.Status.RANKED:
            submission = None
        else:
            submission = {k: v for k, v in submission.items() if k != "reason"}
    return {"type": "result", "submission": submission, "rows": message["rows"]}


def broadcast_result(submission_id: int) -> None:
    """Send the event's new leaderboard to everyone watching (best effort)."""
    submission = Submission.objects.select_related("event").filter(pk=submission_id).first()
    if submission is not None:
        live.send(event_group(submission.event_id), result_message(submission))


def bracket_changed(event_id: int) -> None:
    """Tell the event's viewers that its bracket moved on (a race started or ended)."""
    live.send(event_group(event_id), {"type": "league.bracket", "event_id": event_id})


def broadcast_group(event_id: int) -> str:
    """The Channels group of an event's race-day broadcast page: ``league-broadcast-<id>``;
    a race-day race sends its frames there besides its own group."""
    return f"league-broadcast-{event_id}"


def race_day_changed(event_id: int, message: dict) -> None:
    """Tell the broadcast page and the facilitator's page what happened (a race on track, a
    race over with its winner, the queue changed). The message may carry the organisers'
    detail (race and model ids, the error); each viewer who does not run the event gets only
    :func:`spectator_status` of it."""
    live.send(broadcast_group(event_id), {"type": "raceday.status", **message})


SPECTATOR_KEYS = ("started", "title", "over", "winner", "winner_time_s", "standings", "queue",
                  "paused")  # fmt: skip
"""What a spectator's status message may hold: display names, times, positions and flags."""
STANDING_KEYS = ("position", "name", "finished", "laps", "total_time_s")


def spectator_status(message: dict) -> dict:
    """A race-day status message as spectators (anyone who does not run the event) receive it:
    only :data:`SPECTATOR_KEYS` (a whitelist, so a new internal field never leaks by default),
    each standing only :data:`STANDING_KEYS`: no race or model ids, no status or error text."""
    shown = {key: message[key] for key in SPECTATOR_KEYS if key in message}
    if "standings" in shown:
        shown["standings"] = [{key: car[key] for key in STANDING_KEYS if key in car}
                              for car in shown["standings"] or []]  # fmt: skip
    return {**shown, "type": "status"}


def race_standings(cars: list[dict]) -> list[dict]:
    """A finished race's cars as the broadcast shows them (:data:`STANDING_KEYS`)."""
    return [{key: car.get(key) for key in STANDING_KEYS} for car in cars]


ACCESS_MESSAGE_TYPE = "raceday.access"


def broadcast_access_changed(event_id: int) -> bool:
    """Tell every open broadcast socket of the event to check its access again (the spectator
    link was turned off or replaced): those let in only by the old link close at once.
    False when the channel layer could not be reached."""
    return live.send(broadcast_group(event_id), {"type": ACCESS_MESSAGE_TYPE})
