"""A whole head-to-head bracket runs unattended: seeded from qualifying, every match a race
job on a real Celery worker (PostgreSQL, Redis, the store), winners going through as races
end, until a champion is left; each match keeps its video.

``RACECRAFT_BRACKET_ENTRIES`` (default 4) and ``RACECRAFT_BRACKET_LAPS`` (default 1) size it:
``RACECRAFT_BRACKET_ENTRIES=8 RACECRAFT_BRACKET_LAPS=2 pytest -s`` this file runs the
issue's 8-entry bracket (7 matches of 2 laps) and prints how long it took.
"""

from __future__ import annotations

import os
import time

import pytest
import torch
from league_helpers import make_event, make_user

from leaderboard import bracket as league_bracket
from leaderboard.bracket_draw import champion
from leaderboard.models import BracketMatch, Event, Submission
from tests.support import constant
from training import services
from training.interchange.export import checkpoint_bytes
from training.models import JobStatus
from training.rl.checkpoints import new_model
from training.store import get_store, keys_for

pytestmark = [pytest.mark.slow, pytest.mark.django_db(transaction=True)]
ENTRIES = int(os.environ.get("RACECRAFT_BRACKET_ENTRIES", "4"))
LAPS = int(os.environ.get("RACECRAFT_BRACKET_LAPS", "1"))


def qualifier(event: Event, rank: int, speed: float) -> Submission:
    racer = make_user(f"racer{rank}", alias=f"Racer-{rank}")
    model = services.model_create(
        owner=racer,
        name=f"car-{rank}",
        track_id="racecraft_oval",
        action_space=constant(0, speed),
        validate_reward=False,
        reward_function="def reward_function(p):\n    return 1.0\n",
    )
    torch.manual_seed(rank)
    get_store().put_bytes(keys_for(model.pk).best,
                          checkpoint_bytes(new_model(services.model_metadata(model))))  # fmt: skip
    services.model_mark_checkpoint(model=model)
    sub = Submission.objects.create(
        event=event, racer=racer, model=model, model_name=model.name,
        status=Submission.Status.RANKED, ranked=True, score_ms=30_000 + rank,
        entered_model_id=model.pk, model_metadata=services.model_metadata(model).to_json(),
    )  # fmt: skip
    sub.frozen_checkpoint = services.model_freeze(model=model, scope=f"event-{event.pk}",
                                                  entry=sub.pk)  # fmt: skip
    sub.save()
    return sub


def test_a_bracket_runs_to_its_champion_on_a_celery_worker(celery_worker):
    fran = make_user("fran", alias="Fran", facilitator=True)
    event = make_event(
        fran,
        name="Bracket night",
        bracket_size=8 if ENTRIES <= 8 else 16,
        bracket_laps=LAPS,
        off_track_penalty_s=0.0,
        collision_penalty_s=0.0,
    )
    # Straight-driving cars: the faster laps the oval sooner (about 9 s of race clock at 4 m/s
    # without penalties, so each match's video is a third of the frames it is at 2 m/s).
    subs = [qualifier(event, rank, 4.0 - 0.1 * rank) for rank in range(ENTRIES)]
    started = time.monotonic()
    league_bracket.bracket_seed(event=event, user=fran)
    deadline = started + 240 * ENTRIES
    while time.monotonic() < deadline:
        event.refresh_from_db()
        if champion(league_bracket.bracket_state(event).draw) is not None:
            break
        time.sleep(1.0)
    wall_s = time.monotonic() - started
    bracket = league_bracket.bracket_state(event).draw
    assert champion(bracket) is not None, "the bracket did not finish"
    matches = list(BracketMatch.objects.filter(event=event).select_related("race"))
    raced = [m for m in matches if m.race_id]
    assert len(raced) == ENTRIES - 1
    assert all(m.race.status == JobStatus.COMPLETED and m.race.has_video for m in raced)
    assert all(m.winner_id in (m.top_id, m.bottom_id) for m in raced)
    race_clock = sum(m.race.race_time_s for m in raced)
    print(f"\nbracket: {ENTRIES} entries, {len(raced)} races of {LAPS} lap(s), "
          f"{wall_s:.1f} s wall, {race_clock:.1f} s of race clock, champion seed "
          f"{champion(bracket)} ({subs[champion(bracket) - 1].model_name})")  # fmt: skip
