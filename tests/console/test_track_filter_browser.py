"""Track search and filters in Chromium, from static/js/track_filter.js (CSP: no inline script):
the Tracks page narrows its cards as you type, and the wizard's track picker and multi-track
list narrow together, never hiding the chosen track. daphne serves the console on the test
database."""

from __future__ import annotations

import pytest
from django.contrib.auth import get_user_model

PASSWORD = "pw-racer-123"

pytestmark = [pytest.mark.browser, pytest.mark.slow, pytest.mark.django_db(transaction=True),
              pytest.mark.timeout(600)]  # fmt: skip


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


def test_the_tracks_page_filters_as_you_type(browser_page, daphne):
    from playwright.sync_api import expect

    page, errors = browser_page
    page.goto(f"{daphne.url}/tracks/")
    cards = page.locator("#gallery .track-card")
    total = cards.count()
    assert total >= 81
    page.fill("#id_f-q", "smile")
    expect(page.locator("#gallery .track-card:visible")).to_have_count(3)  # and its cw/ccw
    expect(page.locator("#track-reInvent2019_track")).to_be_visible()
    expect(page.locator("#track-filter-count")).to_have_text(f"Showing 3 of {total} tracks.")
    page.fill("#id_f-q", "")
    page.select_option("#id_f-season", "2024")
    expect(page.locator("#gallery .track-card:visible")).to_have_count(2)
    page.click("#track-filter-button")  # the same filter, sent: the server's list
    sent = "f-q=&f-season=2024&f-direction=&f-source=&f-min_length=&f-max_length=&f-min_width="
    expect(page).to_have_url(f"{daphne.url}/tracks/?{sent}&f-max_width=#gallery")
    expect(page.locator("#gallery .track-card")).to_have_count(2)
    expect(page.locator("#track-filter-count")).to_have_text(f"Showing 2 of {total} tracks.")
    assert errors == []


def test_the_wizard_picker_filters_and_keeps_the_choice(browser_page, daphne):
    from playwright.sync_api import expect

    get_user_model().objects.create_user("racer", password=PASSWORD)
    page, errors = browser_page
    page.goto(f"{daphne.url}/accounts/login/")
    page.fill("#id_username", "racer")
    page.fill("#id_password", PASSWORD)
    page.click("button[type=submit]")
    expect(page).not_to_have_url(f"{daphne.url}/accounts/login/")

    page.goto(f"{daphne.url}/models/new/")
    bar = page.locator(".picker-filter")
    expect(bar).to_be_visible()  # the script shows it
    options = page.locator("#track-pick-list .track-option")
    assert options.count() >= 81
    page.check("input[name=track_id][value=racecraft_oval]")
    page.fill("#tf-q", "re:invent 2018")
    page.keyboard.press("Enter")  # filters; never sends the wizard
    expect(page).to_have_url(f"{daphne.url}/models/new/")
    visible = page.locator("#track-pick-list .track-option:visible input")
    # the four re:Invent 2018 files, and the chosen track, which stays shown
    expect(visible).to_have_count(5)
    expect(page.locator("input[name=track_id][value=reinvent_base]")).to_be_visible()
    expect(page.locator("input[name=track_id][value=racecraft_oval]")).to_be_checked()
    page.check("input[name=track_id][value=reinvent_base]")
    page.select_option("#tf-season", "2018")
    expect(page.locator("#tf-season option[value='2022']")).to_have_count(1)
    page.locator("#multi-track summary").click()
    expect(page.locator("#extra-track-list label:visible")).to_have_count(4)
    page.fill("#tf-q", "")
    page.select_option("#tf-season", "")
    expect(options.locator("input:visible")).to_have_count(options.count())
    expect(page.locator("#track-pick-count")).to_have_text("")
    assert errors == []
