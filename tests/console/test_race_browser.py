"""The race settings in Chromium: the create-model wizard and the evaluation form show the
settings of the race type chosen (boxes for object avoidance, bot cars for head-to-bot, none
for a time trial), from the pages' own scripts (CSP: no inline script). daphne serves the
console on the test database."""

from __future__ import annotations

import re

import pytest
from django.contrib.auth import get_user_model

from training import services
from training.models import RacingModel

PASSWORD = "pw-racer-123"
ACTIONS = [{"steering_angle": a, "speed": 1.0} for a in (-30, 0, 30)]

pytestmark = [pytest.mark.browser, pytest.mark.slow, pytest.mark.django_db(transaction=True),
              pytest.mark.timeout(600)]  # fmt: skip


@pytest.fixture
def racer_model(store_dir) -> RacingModel:
    user = get_user_model().objects.create_user("racer", password=PASSWORD)
    model = services.model_create(
        owner=user, name="boxes", track_id="racecraft_oval", action_space=ACTIONS,
        reward_function="def reward_function(params):\n    return 1.0\n",
        validate_reward=False, race_type="OBJECT_AVOIDANCE",
        race_config={"number_of_objects": 2},
    )  # fmt: skip
    RacingModel.objects.filter(pk=model.pk).update(has_checkpoint=True)
    return model


@pytest.fixture
def browser_page(browser):
    """A desktop-sized page, the script errors it raised, closed after the test."""
    context = browser.new_context(viewport={"width": 1280, "height": 900})
    context.set_default_timeout(30_000)
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    yield page, errors
    context.close()


def loaded_width(page, image) -> int:
    """The picture's natural width once it has loaded (-1: still loading; polled from Python:
    the page's CSP allows no string evaluation)."""
    width = -1
    for _ in range(300):
        width = image.evaluate("img => img.complete && img.naturalWidth ? img.naturalWidth : -1")
        if width >= 0:
            break
        page.wait_for_timeout(100)
    return width


def test_the_settings_follow_the_race_type(browser_page, daphne, racer_model):
    from playwright.sync_api import expect

    page, errors = browser_page
    page.goto(f"{daphne.url}/accounts/login/")
    page.fill("#id_username", "racer")
    page.fill("#id_password", PASSWORD)
    page.click("button[type=submit]")
    expect(page).not_to_have_url(f"{daphne.url}/accounts/login/")

    page.goto(f"{daphne.url}/models/new/")
    boxes, bots = page.locator("#race-settings-boxes"), page.locator("#race-settings-bots")
    expect(boxes).to_be_hidden()  # a time trial has no settings
    expect(bots).to_be_hidden()
    expect(page.locator("#race-layout")).to_be_hidden()
    page.check("input[name=track_id][value=racecraft_oval]")
    page.check("input[name=race_type][value=OBJECT_AVOIDANCE]")
    expect(boxes).to_be_visible()
    expect(bots).to_be_hidden()
    # The layout of the boxes on the chosen track, and a refused setting in words.
    layout = page.locator("#race-layout-img")
    expect(layout).to_have_attribute("src", re.compile(r"^/tracks/racecraft_oval/race\.png\?"))
    assert loaded_width(page, layout) == 480
    page.fill("#id_object_positions", "0.5")
    expect(page.locator("#race-layout-note")).to_contain_text("No preview: Box 1: write each")
    page.fill("#id_object_positions", "0.3,1;0.6,-1")
    expect(layout).to_have_attribute("src", re.compile("object_positions=0.3%2C1%3B0.6%2C-1"))
    assert loaded_width(page, layout) == 480
    page.check("input[name=race_type][value=HEAD_TO_BOT]")
    expect(bots).to_be_visible()
    expect(page.locator("#id_bot_speed")).to_have_value("0.5")
    expect(boxes).to_be_hidden()
    expect(page.locator("#id_lidar option[value=SECTOR_LIDAR]")).to_have_count(1)

    page.goto(f"{daphne.url}/models/{racer_model.pk}/")
    form = page.locator("#evaluate-form")
    expect(form.locator("select[name=race_type]")).to_have_value("OBJECT_AVOIDANCE")
    expect(form.locator("[data-race=OBJECT_AVOIDANCE]")).to_be_visible()
    expect(form.locator("input[name=number_of_objects]")).to_have_value("2")
    form.locator("select[name=race_type]").select_option("HEAD_TO_BOT")
    expect(form.locator("[data-race=HEAD_TO_BOT]")).to_be_visible()
    expect(form.locator("[data-race=OBJECT_AVOIDANCE]")).to_be_hidden()
    form.locator("select[name=race_type]").select_option("")
    expect(form.locator("[data-race=HEAD_TO_BOT]")).to_be_hidden()
    assert errors == []


def test_the_tracks_page_previews_a_race_layout(browser_page, daphne):
    from playwright.sync_api import expect

    page, errors = browser_page
    page.goto(f"{daphne.url}/tracks/")
    form = page.locator("#layout-form")
    form.locator("select[name=track]").select_option("racecraft_oval")
    expect(form.locator("[data-race=OBJECT_AVOIDANCE]")).to_be_visible()  # the page's default
    form.locator("select[name=race_type]").select_option("HEAD_TO_BOT")
    expect(form.locator("[data-race=HEAD_TO_BOT]")).to_be_visible()
    expect(form.locator("[data-race=OBJECT_AVOIDANCE]")).to_be_hidden()
    form.locator("input[name=number_of_bots]").fill("4")
    page.click("#layout-preview-button")
    image = page.locator("#layout-preview img")
    expect(image).to_be_visible()
    assert loaded_width(page, image) == 480
    expect(form.locator("input[name=number_of_bots]")).to_have_value("4")  # kept

    form.locator("select[name=race_type]").select_option("OBJECT_AVOIDANCE")
    form.locator("input[name=object_positions]").fill("0.3,1;0.35,-1")
    page.click("#layout-preview-button")
    expect(page.locator("#field-object_positions .field-error")).to_contain_text("0.13")
    expect(page.locator("#layout-preview")).to_have_count(0)
    assert errors == []
