"""Issue 51's loose end: a racer entering an event that sets conditions sees them, in words
(the families and how strong each is), where they submit and on their submission's page; an
event in the clean world says nothing of it. Fran runs the event; Alice enters."""

from __future__ import annotations

import pytest
from league_helpers import make_event, make_model

from leaderboard.conditions_words import conditions_in_words, reach, strength_words
from leaderboard.models import Submission
from racing.conditions import parameters
from training.services.conditions import conditions_build

pytestmark = pytest.mark.django_db


def test_a_family_s_strength_is_how_far_its_ranges_reach_towards_the_widest() -> None:
    brightness = parameters()["light"]["brightness"]  # neutral 0, widest -50 to 50
    assert reach(brightness, -25, 25) == 0.5
    assert reach(brightness, -10, 40) == 0.8  # the further side
    assert reach(brightness, 0, 0) == 0.0 and reach(brightness, -50, 50) == 1.0
    assert [strength_words(s) for s in (0.2, 0.5, 0.8, 1.0)] == [
        "mild", "moderate", "strong", "at its widest",
    ]  # fmt: skip
    stored = conditions_build(["light", "latency"], {"light.brightness": (-50, 50)})
    rows = conditions_in_words(stored)
    assert [(r["family"], r["words"], r["percent"]) for r in rows] == [
        ("light", "at its widest", 100), ("latency", "moderate", 50),
    ]  # fmt: skip
    assert rows[0]["ranges"] == [("Ambient light", "-50 to 50 gray levels")]
    defaults = conditions_in_words(conditions_build(["camera"]))
    assert defaults[0]["words"] == "moderate" and defaults[0]["ranges"] == []
    assert conditions_in_words({}) == [] and conditions_in_words(None) == []


def test_the_racer_sees_the_event_s_conditions_where_they_submit_and_after(
    client, fran, alice
) -> None:
    world = conditions_build(["light", "car"], {"light.brightness": (-40, 40)})
    event = make_event(fran, name="Rainy Open", conditions=world, conditions_seed=7)
    make_model(alice, "alice-car")
    client.force_login(alice)
    page = client.get(f"/league/events/{event.pk}/").content.decode()
    box = page.split('id="submit-world"')[1].split("</div>")[0]
    assert 'action="/league/events/' in page.split('id="submit-world"')[1]  # above the form
    assert "This event races in the outside world" in box and "(seed 7)" in box
    assert "<strong>Light</strong>: strong (80 % of the way to its widest range)" in box
    assert "Ambient light -40 to 40 gray levels" in box
    assert "<strong>The car</strong>: moderate (50 % of the way to its widest range)" in box
    sub = Submission.objects.create(event=event, racer=alice, model_name="alice-car",
                                    status=Submission.Status.RANKED)  # fmt: skip
    page = client.get(f"/league/submissions/{sub.pk}/").content.decode()
    assert 'id="submission-world"' in page and "<strong>Light</strong>: strong" in page


def test_a_clean_world_event_says_nothing_of_it(client, fran, alice) -> None:
    event = make_event(fran)
    client.force_login(alice)
    page = client.get(f"/league/events/{event.pk}/").content.decode()
    assert 'id="submit-world"' not in page and "races in the outside world" not in page
