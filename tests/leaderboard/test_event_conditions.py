"""An event's outside-world setting (issue 51): off by default, set on the event's form and
shown on its page, fixed once racers have submitted; every entrant's evaluation meets the same
conditions (the event's seed), read back from what the evaluation records."""

from __future__ import annotations

from datetime import timedelta

import numpy as np
import pytest
from django.utils import timezone
from league_helpers import make_event, make_model

from leaderboard.access import LeagueError
from leaderboard.eventraces import entry_race
from leaderboard.events import event_update
from leaderboard.models import Event, Submission
from leaderboard.services import submission_create
from training import services
from training.rl.checkpoints import checkpoint_bytes, new_model
from training.services.conditions import conditions_check, conditions_draw
from training.store import get_store, keys_for
from training.worker import evaluation as worker
from training.worker.race import race_world

pytestmark = [pytest.mark.django_db, pytest.mark.usefixtures("store_dir")]
WORLD = {"families": {"light": {"brightness": [-30, 30]}, "camera": {}, "car": {}}}
FORM = {"name": "Rainy Open", "description": "", "division": "OPEN",
        "track_id": "racecraft_oval", "direction": "native", "race_type": "TIME_TRIAL",
        "opens_at": "2030-03-01T00:00", "closes_at": "2030-03-31T00:00",
        "ranking_method": "BEST_LAP", "min_laps": 1, "max_laps": 3,
        "off_track_penalty_s": 2, "collision_penalty_s": 5, "max_resets": "",
        "max_submissions_per_racer": 10, "number_of_objects": 0, "bot_count": 0,
        "bot_speed_mps": 1.0}  # fmt: skip


def test_the_event_form_sets_and_shows_the_conditions(client, fran, alice) -> None:
    client.force_login(fran)
    page = client.get("/league/events/new/").content.decode()
    assert 'name="cond_light"' in page and 'name="conditions_seed"' in page
    response = client.post("/league/events/new/", {**FORM, "cond_light_brightness_low": "-99",
                                                   "cond_light": "on"})  # fmt: skip
    assert "at least -50" in response.content.decode() and not Event.objects.exists()
    client.post("/league/events/new/", {**FORM, "name": "Dry Open"})
    assert Event.objects.get(name="Dry Open").conditions == {}  # off by default
    response = client.post("/league/events/new/", {
        **FORM, "cond_light": "on", "cond_light_brightness_low": "-30",
        "cond_light_brightness_high": "30", "cond_camera": "on", "conditions_seed": "99",
    })  # fmt: skip
    event = Event.objects.get(name="Rainy Open")
    assert response["Location"] == f"/league/events/{event.pk}/"
    assert list(event.conditions["families"]) == ["light", "camera"]
    assert event.conditions["families"]["light"]["brightness"] == [-30.0, 30.0]
    assert event.conditions_seed == 99
    page = client.get(f"/league/events/{event.pk}/").content.decode()
    assert 'id="event-conditions"' in page and "Ambient light -30 to 30 gray levels" in page
    assert "seed 99" in page
    # the edit form shows the setting as stored
    edit = client.get(f"/league/events/{event.pk}/edit/").content.decode()
    assert 'value="-30.0"' in edit or 'value="-30"' in edit
    assert 'name="cond_camera" id="id_cond_camera" checked' in edit or (
        'id="id_cond_camera" checked' in edit)  # fmt: skip
    # fixed once racers have submitted, like the track
    Event.objects.filter(pk=event.pk).update(opens_at=timezone.now() - timedelta(hours=1))
    event.refresh_from_db()
    submission_create(event=event, user=alice, model=make_model(alice))
    with pytest.raises(LeagueError, match="can no longer change"):
        event_update(event=event, user=fran, conditions={})


def racer_model(owner, name: str):
    model = make_model(owner, name)
    data = checkpoint_bytes(new_model(services.model_metadata(model)))
    get_store().put_bytes(keys_for(model.pk).best, data)
    return model


class StopSoon:
    """The evaluation's stop flag, raised after a few steps: the conditions are drawn at the
    start, so a few steps are enough to read them back."""

    def __init__(self, job) -> None:
        self.calls = 0

    def __call__(self) -> bool:
        self.calls += 1
        return self.calls >= 5


@pytest.mark.slow
def test_every_entrant_meets_the_same_conditions(fran, alice, bob, monkeypatch) -> None:
    monkeypatch.setattr(worker, "StopFlag", StopSoon)
    monkeypatch.setattr(worker, "sb3_policy", lambda model: lambda obs: np.int64(0))
    outside = make_event(fran, name="Outside", conditions=WORLD, conditions_seed=1234)
    clean = make_event(fran, name="Inside")
    results = []
    for event, user, name in ((outside, alice, "a1"), (outside, bob, "b1"), (clean, alice, "a2")):
        submission = submission_create(event=event, user=user, model=racer_model(user, name))
        job = submission.evaluation
        if event is outside:
            assert job.conditions == conditions_check(WORLD)  # the event's, as stored
            assert job.conditions_seed == 1234
        assert worker.run_evaluation_job(job.pk) == "completed"
        job.refresh_from_db()
        results.append(job.results)
    alice_drew, bob_drew = results[0]["conditions"], results[1]["conditions"]
    assert alice_drew == bob_drew
    assert alice_drew["light"]["brightness"] != 0.0 and alice_drew["car"]["speed_scale"] != 1.0
    assert -30 <= alice_drew["light"]["brightness"] <= 30
    assert alice_drew["look"]["road"] == 53.0  # a family the event left off stays neutral
    assert "conditions" not in results[2]  # an event without the setting: the clean world


def entry(event, racer, name: str) -> Submission:
    model = make_model(racer, name=name)
    return Submission.objects.create(
        event=event, racer=racer, model=model, model_name=model.name,
        status=Submission.Status.RANKED, entered_model_id=model.pk,
        frozen_checkpoint=f"league/event-{event.pk}/{name}.zip",
        model_metadata={"action_space": model.action_space, "sensor": ["FRONT_FACING_CAMERA"]},
    )  # fmt: skip


def test_the_events_head_to_head_races_drive_in_one_draw(fran, alice, bob) -> None:
    outside = make_event(fran, name="Outside", conditions=WORLD, conditions_seed=1234)
    pair = [entry(outside, alice, "a1"), entry(outside, bob, "b1")]
    first = entry_race(outside, pair, laps=1)
    again = entry_race(outside, pair[::-1], laps=1, round_number=2)
    assert first.conditions == again.conditions == conditions_draw(WORLD, 1234)
    drawn = race_world(first)
    assert drawn is not None and not drawn.is_clean
    assert drawn.values["light"]["brightness"] == first.conditions["light"]["brightness"]
    inside = make_event(fran, name="Inside")
    clean = entry_race(inside, [entry(inside, alice, "a2"), entry(inside, bob, "b2")], laps=1)
    assert clean.conditions == {} and race_world(clean) is None
