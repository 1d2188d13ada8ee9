"""The wizard's multi-track choice: extra tracks chosen with check boxes, driven in the chosen
direction, refused with a message on the field, shown on the model's page."""

from __future__ import annotations

import re

import pytest

from tests.console.test_model_views import create_data
from training.models import RacingModel
from training.services import rewards

pytestmark = pytest.mark.django_db


def test_the_wizard_offers_every_track_as_an_extra(alice_client) -> None:
    page = alice_client.get("/models/new/").content.decode()
    offered = re.findall(r'name="extra_track_ids" value="([^"]+)"', page)
    assert {"racecraft_oval", "racecraft_summit", "racecraft_technical"} <= set(offered)
    assert "Multi-track training" in page


def test_a_model_created_on_two_tracks(alice, alice_client, store_dir) -> None:
    """The reward function is validated on a worker on each track before the model is saved:
    the page validates the first track without a pass, posts again, and so on."""
    data = create_data(name="two-tracks", direction="cw",
                       extra_track_ids=["racecraft_summit", "racecraft_oval"])  # fmt: skip
    for track in ("racecraft_oval", "racecraft_summit"):
        response = alice_client.post("/models/new/", data)
        assert response.status_code == 202, response.content.decode()[:3000]
        assert not RacingModel.objects.exists()
        rewards.reward_validation_remember(
            user_id=alice.pk, source=data["reward_function"], track_id=track, direction="cw"
        )
    response = alice_client.post("/models/new/", data)
    assert response.status_code == 302, response.content.decode()[:3000]
    model = RacingModel.objects.get(name="two-tracks")
    # the model's own track is never an extra; extras take the chosen direction
    assert model.training_tracks == [("racecraft_oval", "cw"), ("racecraft_summit", "cw")]
    page = alice_client.get(f"/models/{model.pk}/").content.decode()
    assert re.search(r"Also trains on</dt><dd>racecraft_summit \(cw\)</dd>", page)


def test_too_many_tracks_is_an_error_on_the_field(alice_client, store_dir, monkeypatch) -> None:
    monkeypatch.setattr("training.services.checks.MAX_TRAINING_TRACKS", 2)
    data = create_data(name="three", extra_track_ids=["racecraft_summit", "racecraft_technical"])
    response = alice_client.post("/models/new/", data)
    page = response.content.decode()
    assert response.status_code == 400
    assert re.search(r'id="field-extra_track_ids">.*?at most 2 tracks at once', page, re.S)
    assert re.search(r'value="racecraft_technical"[^>]*checked', page)  # kept as chosen
    assert not RacingModel.objects.exists()


def test_an_unknown_extra_track_is_refused(alice_client, store_dir) -> None:
    response = alice_client.post("/models/new/", create_data(extra_track_ids=["nowhere"]))
    assert response.status_code == 400
    assert "Select a valid choice. nowhere is not one of the available choices." in (
        response.content.decode()
    )
