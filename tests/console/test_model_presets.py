"""The create-model wizard's "Start from": each preset fills the action table, hyperparameters
and reward function, keeps what the user typed elsewhere, and creates a valid model."""

from __future__ import annotations

import html
import re

import pytest

from tests.console.test_model_views import create_data
from training.models import RacingModel
from training.rewards.examples import example_source
from training.rl.presets import DEEPRACER_DEFAULTS, RACING
from training.services import rewards

pytestmark = pytest.mark.django_db


def _rows(page: str) -> list[tuple[str, str]]:
    steering = re.findall(r'name="action_steering" value="([^"]+)"', page)
    speeds = re.findall(r'name="action_speed" value="([^"]+)"', page)
    return list(zip(steering, speeds, strict=True))


def _value(page: str, name: str) -> str:
    match = re.search(rf'name="{name}"[^>]*value="([^"]*)"', page)
    assert match, name
    return match.group(1)


def test_the_wizard_offers_both_presets_labelled(alice_client) -> None:
    page = alice_client.get("/models/new/").content.decode()
    for chosen in (DEEPRACER_DEFAULTS, RACING):
        assert f'name="start_from" value="{chosen.id}"' in page
        assert html.escape(chosen.label) in page and html.escape(chosen.summary) in page
    assert re.search(r'value="deepracer_defaults"\s+checked', page)


def test_start_from_racing_fills_the_form_and_keeps_the_rest(alice_client, store_dir) -> None:
    data = create_data(name="keep-me", start_from="racing", use_preset="1")
    response = alice_client.post("/models/new/", data)
    page = response.content.decode()
    assert response.status_code == 200 and _value(page, "name") == "keep-me"
    expected = [(f"{a['steering_angle']:g}", f"{a['speed']:g}") for a in RACING.actions()]
    assert _rows(page) == expected
    assert _value(page, "discount_factor") == "0.98"
    assert re.search(r'<option value="32" selected>', page)  # the batch size
    assert html.escape(example_source("speed_along_track")) in page
    assert re.search(r'value="racing"\s+checked', page)
    assert not RacingModel.objects.exists()  # filling in creates nothing


def test_a_preset_link_fills_the_form(alice_client) -> None:
    page = alice_client.get("/models/new/?start_from=racing").content.decode()
    last = RACING.actions()[-1]
    assert _rows(page)[-1] == (f"{last['steering_angle']:g}", f"{last['speed']:g}") == ("20", "2")
    assert html.escape(example_source("speed_along_track")) in page
    assert re.search(r'<option value="RACECRAFT_COMPACT_CNN" selected>', page)  # its network


def test_an_unknown_preset_is_a_clear_error_and_keeps_the_form(alice_client) -> None:
    data = create_data(name="keep-me", start_from="turbo", use_preset="1")
    page = alice_client.post("/models/new/", data).content.decode()
    assert "Unknown preset &#x27;turbo&#x27;: use one of deepracer_defaults, racing." in page
    assert _value(page, "name") == "keep-me"
    assert _rows(page) == [("-30", "1"), ("0", "1.5"), ("30", "1")]


@pytest.mark.parametrize("chosen", [DEEPRACER_DEFAULTS, RACING], ids=lambda p: p.id)
def test_a_filled_in_preset_creates_its_model(alice, alice_client, store_dir, chosen) -> None:
    # Validated on a worker first (the page's way there: tests/console/test_reward_saving.py).
    source = example_source(chosen.reward_example)
    rewards.reward_validation_remember(
        user_id=alice.pk, source=source, track_id="racecraft_oval", direction="native"
    )
    page = alice_client.get(f"/models/new/?start_from={chosen.id}").content.decode()
    rows = _rows(page)
    hp = chosen.hyperparameters
    data = create_data(
        name=f"from-{chosen.id.replace('_', '-')}",
        track_id="racecraft_oval",
        action_steering=[s for s, _ in rows],
        action_speed=[v for _, v in rows],
        batch_size=str(hp.batch_size),
        num_epochs=str(hp.num_epochs),
        lr=str(hp.lr),
        beta_entropy=str(hp.beta_entropy),
        discount_factor=str(hp.discount_factor),
        loss_type=hp.loss_type,
        num_episodes_between_training=str(hp.num_episodes_between_training),
        reward_function=example_source(chosen.reward_example),
        neural_network=re.search(r'<option value="(\w+)" selected>[^<]*CNN', page).group(1),
        start_from=chosen.id,
    )
    response = alice_client.post("/models/new/", data)
    assert response.status_code == 302, response.content.decode()[:2000]
    model = RacingModel.objects.get(name=data["name"])
    assert model.action_space == [
        {**a, "index": i} if "index" in model.action_space[0] else a
        for i, a in enumerate(chosen.actions())
    ]
    assert model.hyperparameters["discount_factor"] == hp.discount_factor
    assert model.reward_function == example_source(chosen.reward_example)
    assert model.neural_network == chosen.network
