"""The outside-world setting in Chromium: the wizard's "Outside world" panel is off by default;
a racer turns a family on, narrows a range, creates the model and finds the setting on the
model's page; the Tracks page shows a track under a few sampled conditions. daphne serves the
console (CSP: the pages' own scripts only)."""

from __future__ import annotations

import pytest
from django.contrib.auth import get_user_model

from training.catalog import example_source
from training.services import rewards

PASSWORD = "pw-outside-123"
pytestmark = [pytest.mark.browser, pytest.mark.slow, pytest.mark.django_db(transaction=True),
              pytest.mark.timeout(600)]  # fmt: skip


@pytest.fixture
def racer(store_dir):
    user = get_user_model().objects.create_user("outside", password=PASSWORD)
    # The wizard's reward function, validated as a worker would have (no worker needed here).
    rewards.reward_validation_remember(user_id=user.pk, source=example_source(),
                                       track_id="racecraft_oval", direction="native")  # fmt: skip
    return user


def loaded_width(page, image) -> int:
    """The picture's natural width once loaded (-1: still loading; polled from Python: the
    page's CSP allows no string evaluation)."""
    width = -1
    for _ in range(300):
        width = image.evaluate("img => img.complete && img.naturalWidth ? img.naturalWidth : -1")
        if width >= 0:
            break
        page.wait_for_timeout(100)
    return width


def test_the_wizards_setting_reaches_the_model_page(browser, daphne, racer) -> None:
    from playwright.sync_api import expect

    context = browser.new_context(viewport={"width": 1280, "height": 900})
    context.set_default_timeout(30_000)
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(f"{daphne.url}/accounts/login/")
    page.fill("#id_username", "outside")
    page.fill("#id_password", PASSWORD)
    page.click("button[type=submit]")
    expect(page).not_to_have_url(f"{daphne.url}/accounts/login/")

    page.goto(f"{daphne.url}/models/new/")
    world = page.locator("#step-world")
    expect(world.locator("input[type=checkbox]")).to_have_count(5)
    for family in ("light", "look", "camera", "car", "latency"):
        expect(page.locator(f"#id_cond_{family}")).not_to_be_checked()  # off by default
    page.fill("#id_name", "rainy-day")
    page.check("input[name=track_id][value=racecraft_oval]")
    page.check("#id_cond_light")
    page.locator("#field-cond_light details summary").click()
    page.fill("#id_cond_light_brightness_low", "-20")
    page.fill("#id_cond_light_brightness_high", "20")
    page.check("#id_cond_latency")
    page.click("#create-submit")
    expect(page.locator("h1")).to_contain_text("rainy-day", timeout=120_000)
    setting = page.locator("#config-conditions")
    expect(setting).to_contain_text("Ambient light -20 to 20 gray levels")
    expect(setting).to_contain_text("Latency")
    expect(setting).not_to_contain_text("Camera")

    page.goto(f"{daphne.url}/tracks/?conditions_track=racecraft_oval#conditions-preview")
    pictures = page.locator("#conditions-strip img")
    expect(pictures).to_have_count(4)
    expect(page.locator("#conditions-strip figcaption").first).to_contain_text("clean world")
    assert [loaded_width(page, pictures.nth(i)) for i in range(4)] == [320] * 4
    assert errors == []
    context.close()
