"""The wizard's "Outside world" fieldset: off by default, a family turned on with a narrowed
range reaches the model and its page; a bad range is refused on its field, nothing lost."""

from __future__ import annotations

import re

import pytest

from tests.console.test_model_views import create_data, reward_passed  # noqa: F401 - fixture
from training.models import RacingModel

pytestmark = pytest.mark.django_db


def test_off_by_default(alice_client, store_dir, reward_passed) -> None:  # noqa: F811
    page = alice_client.get("/models/new/").content.decode()
    for words in ('id="step-world"', 'name="cond_light"', 'name="cond_latency"',
                  'name="cond_light_brightness_low"', "What the track looks like"):  # fmt: skip
        assert words in page, words
    world = page.split('id="step-world"')[1].split("</section>")[0]
    assert world.count('type="checkbox"') == 5 and " checked" not in world
    assert alice_client.post("/models/new/", create_data()).status_code == 302
    model = RacingModel.objects.get()
    assert model.conditions == {}
    assert "Off: the clean world" in alice_client.get(f"/models/{model.pk}/").content.decode()


def test_a_family_on_with_a_narrowed_range(alice_client, store_dir, reward_passed) -> None:  # noqa: F811
    data = create_data(
        cond_light="on",
        cond_light_brightness_low="-20",
        cond_light_brightness_high="10",
        cond_latency="on",
        cond_camera_blur_low="0.5",
    )  # camera is off: its range is not used
    response = alice_client.post("/models/new/", data)
    assert response.status_code == 302, response.content.decode()[:2000]
    model = RacingModel.objects.get()
    assert list(model.conditions["families"]) == ["light", "latency"]
    assert model.conditions["families"]["light"]["brightness"] == [-20.0, 10.0]
    page = alice_client.get(f"/models/{model.pk}/").content.decode()
    assert 'id="config-conditions"' in page
    assert "Ambient light -20 to 10 gray levels" in page and "<strong>Latency</strong>" in page


@pytest.mark.parametrize(
    ("fields", "field_id", "words"),
    [
        ({"cond_light_brightness_low": "-90"}, "cond_light_brightness_low", "at least -50"),
        (
            {"cond_light_glare_low": "60", "cond_light_glare_high": "20"},
            "cond_light_glare_high",
            "must not be below the low end",
        ),
        ({"cond_light_gamma_high": "lots"}, "cond_light_gamma_high", "enter a number"),
    ],
)
def test_a_bad_range_is_refused_on_its_field(alice_client, store_dir, fields, field_id,
                                             words) -> None:  # fmt: skip
    data = create_data(cond_light="on", **fields)
    response = alice_client.post("/models/new/", data)
    assert response.status_code == 400
    page = response.content.decode()
    assert words in page
    assert f'id="field-{field_id}"' in page or field_id.endswith("_low")
    assert not RacingModel.objects.exists()
    # nothing lost: the family stays on, the typed values and the rest of the form are there
    assert re.search(r'<input type="checkbox" name="cond_light"[^>]* checked>', page)
    for value in fields.values():
        assert f'value="{value}"' in page
    assert 'value="my-first-model"' in page


def test_the_tracks_page_shows_a_track_under_sampled_conditions(client) -> None:
    page = client.get("/tracks/?conditions_track=racecraft_oval").content.decode()
    strip = page.split('id="conditions-strip"')[1].split("</section>")[0]
    assert strip.count("<img") == 4 and "The clean world" in strip
    assert "/tracks/racecraft_oval/conditions/3.png" in strip
    first = client.get("/tracks/racecraft_oval/conditions/1.png")
    assert first.status_code == 200 and first["Content-Type"] == "image/png"
    assert first.content.startswith(b"\x89PNG")
    clean = client.get("/tracks/racecraft_oval/conditions/0.png").content
    assert clean != first.content  # what was drawn shows
    again = client.get("/tracks/racecraft_oval/conditions/1.png", HTTP_IF_NONE_MATCH=first["ETag"])
    assert again.status_code == 304  # cached: the same bytes
    assert client.get("/tracks/racecraft_oval/conditions/4.png").status_code == 404
    assert client.get("/tracks/no_such_track/conditions/0.png").status_code == 404


def test_the_conditions_are_eased_in_by_the_recommended_curriculum_unless_told(
    alice_client,
    store_dir,
    reward_passed,  # noqa: F811
) -> None:
    from racing.conditions import RECOMMENDED_RAMP_EPISODES

    page = alice_client.get("/models/new/").content.decode()
    assert 'name="cond_ramp_episodes"' in page and "Ease them in over" in page
    assert alice_client.post("/models/new/", create_data(cond_light="on")).status_code == 302
    model = RacingModel.objects.get()
    assert model.conditions["ramp_episodes"] == RECOMMENDED_RAMP_EPISODES  # blank: recommended
    shown = alice_client.get(f"/models/{model.pk}/").content.decode()
    assert f"Eased in over each car's first {RECOMMENDED_RAMP_EPISODES} training episodes" in shown
    data = create_data(cond_light="on", cond_ramp_episodes="0", name="no-ramp")
    assert alice_client.post("/models/new/", data).status_code == 302
    assert "ramp_episodes" not in RacingModel.objects.get(name="no-ramp").conditions  # 0: none
    bad = create_data(cond_light="on", cond_ramp_episodes="-3", name="bad-ramp")
    page = alice_client.post("/models/new/", bad).content.decode()
    assert "Ease them in over: 0 or more episodes." in page  # refused on its field
    assert 'value="bad-ramp"' in page and not RacingModel.objects.filter(name="bad-ramp").exists()
